"""Build the kernels ahead of time: ``python -m imu_dcm._kernels.build [--out DIR]``.

Compiles every entry point of :data:`imu_dcm._kernels.entries.ENTRIES` (the same functions, with
the same signatures, that numba compiles on first use otherwise) into one extension module,
``imu_dcm._kernels._aot``, with numba's ahead-of-time compiler (``numba.pycc``, which needs a C
compiler). Installing the package runs it (``setup.py``); run it again after editing the
kernels' sources, which :mod:`imu_dcm._kernels.loader` otherwise notices (a digest of them) and
answers by compiling with numba. The module needs only numpy at run time; importing it takes
about a millisecond where numba's import and cache take about half a second.

``numba.pycc`` is pending deprecation since numba 0.57 (numba 0.68 still ships it, and its
removal waits for a replacement): importing it raises a ``NumbaPendingDeprecationWarning``,
which :func:`build` silences, so it reaches no one; nothing but this module imports it, and only
inside :func:`build`, so a replay or a live run never does. Should a numba without it come, the
build fails, the install says so in one line, and the kernels are compiled on first use.

The build writes into a temporary folder beside the target and renames the finished module into
place, so a failed build leaves the old module (or none), never half of one.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

from numba.core.errors import NumbaPendingDeprecationWarning

from imu_dcm._kernels.entries import ENTRIES
from imu_dcm._kernels.loader import AOT_MODULE, digest_entry

__all__ = ["PACKAGE_DIR", "build", "main"]

#: Where the module goes by default: this package's folder.
PACKAGE_DIR = Path(__file__).parent


def _marker() -> int:
    """The module's digest marker (its name carries the digest; it returns nothing useful)."""
    return 0


def build(out_dir: Path = PACKAGE_DIR) -> Path:
    """Build ``_aot`` into ``out_dir``; return the module's path. Raises what numba or the C
    compiler raise when the build fails (the old module, if any, is left as it was)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = AOT_MODULE.rsplit(".", 1)[1]
    with (
        warnings.catch_warnings(),
        tempfile.TemporaryDirectory(dir=out_dir, prefix=f".{name}-") as tmp,
    ):
        # numba.pycc warns on import and on compile that it is pending deprecation (see above);
        # imported here, not with this module, so that only a build ever loads it
        warnings.simplefilter("ignore", NumbaPendingDeprecationWarning)
        from numba.pycc import CC

        cc = CC(name)
        cc.output_dir = tmp
        cc.verbose = False
        for entry, (fn, signature) in ENTRIES.items():
            cc.export(entry, signature)(fn)
        cc.export(digest_entry(), "int64()")(_marker)
        cc.compile()
        (built,) = Path(tmp).glob(f"{name}.*")
        target = out_dir / built.name
        shutil.move(str(built), str(target))  # same folder: a rename
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m imu_dcm._kernels.build",
        description="Build imu_dcm's compiled kernels ahead of time (needs a C compiler).",
    )
    parser.add_argument(
        "--out", type=Path, default=PACKAGE_DIR, help="folder (default: the package's own)"
    )
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    print(f"imu_dcm: building the integrator kernel ({len(ENTRIES)} entry points)")
    try:
        path = build(args.out)
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        print(f"imu_dcm: the kernel was not built: {type(e).__name__}: {first}", file=sys.stderr)
        return 1
    print(f"imu_dcm: built {path.name} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
