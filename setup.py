"""Install step: build the compiled kernels ahead of time (``imu_dcm/_kernels/build.py``).

Everything else about the package is in ``pyproject.toml``. The kernels are one extension module
compiled from ``imu_dcm/_kernels/`` by numba's ahead-of-time compiler; an install (or
``pip install -e .``, which builds it into the package folder) then runs without compiling.
When the build fails (no C compiler, say) the install goes on and says why: the kernel is then
compiled by numba on first use, as ``imu_dcm._kernels.loader`` explains.
"""

import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent


class BuildKernel(build_ext):
    """Builds ``imu_dcm._kernels._aot`` with :func:`imu_dcm._kernels.build.build` (no C sources)."""

    def run(self) -> None:
        for ext in self.extensions:
            out_dir = Path(self.get_ext_fullpath(ext.name)).parent  # in place for -e
            sys.path.insert(0, str(ROOT))
            try:
                from imu_dcm._kernels.build import build

                print(f"imu_dcm: building the integrator kernel ahead of time into {out_dir}")
                build(out_dir)
            except Exception as e:
                first = (str(e).strip().splitlines() or [""])[0]
                print(
                    f"imu_dcm: the kernel was not built ahead of time ({type(e).__name__}: "
                    f"{first}); it is compiled on first use instead",
                    file=sys.stderr,
                )
            finally:
                sys.path.remove(str(ROOT))

    def get_outputs(self) -> list[str]:
        return [p for p in super().get_outputs() if Path(p).exists()]

    def get_output_mapping(self) -> dict[str, str]:
        return {k: v for k, v in super().get_output_mapping().items() if Path(k).exists()}


setup(
    ext_modules=[Extension("imu_dcm._kernels._aot", sources=[])],
    cmdclass={"build_ext": BuildKernel},
)
