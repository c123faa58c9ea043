"""Build the integrator kernel ahead of time: ``python -m imu_dcm.kernel_build [--out DIR]``.

Compiles every entry point of :mod:`imu_dcm.kernel_jit` (the same functions, with the same
signatures, that numba compiles on first use otherwise) into one extension module,
``imu_dcm._kernel_aot``, with numba's ahead-of-time compiler (``numba.pycc``, which needs a C
compiler). Installing the package runs it (``setup.py``); run it again after editing the
kernel's sources, which :mod:`imu_dcm.kernel` otherwise notices (a digest of them) and answers
by compiling with numba. The module needs only numpy at run time; importing it takes about a
millisecond where numba's import and cache take about half a second.

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

from imu_dcm import kernel, kernel_jit

PACKAGE_DIR = Path(kernel.__file__).parent


def _marker() -> int:
    """The module's digest marker (its name carries the digest; it returns nothing useful)."""
    return 0


def build(out_dir: Path = PACKAGE_DIR) -> Path:
    """Build ``_kernel_aot`` into ``out_dir``; return the module's path. Raises what numba or
    the C compiler raise when the build fails (the old module, if any, is left as it was)."""
    from numba.core.errors import NumbaPendingDeprecationWarning
    from numba.pycc import CC

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = kernel.AOT_MODULE.rsplit(".", 1)[1]
    with tempfile.TemporaryDirectory(dir=out_dir, prefix=f".{name}-") as tmp:
        cc = CC(name)
        cc.output_dir = tmp
        cc.verbose = False
        for entry, (fn, signature) in kernel_jit.ENTRIES.items():
            cc.export(entry, signature)(fn)
        cc.export(kernel.digest_entry(), "int64()")(_marker)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NumbaPendingDeprecationWarning)
            cc.compile()
        (built,) = Path(tmp).glob(f"{name}.*")
        target = out_dir / built.name
        shutil.move(str(built), str(target))  # same folder: a rename
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m imu_dcm.kernel_build",
        description="Build imu_dcm's integrator kernel ahead of time (needs a C compiler).",
    )
    parser.add_argument(
        "--out", type=Path, default=PACKAGE_DIR, help="folder (default: the package's own)"
    )
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    print(f"imu_dcm: building the integrator kernel ({len(kernel_jit.ENTRIES)} entry points)")
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
