"""imu_dcm: strapdown attitude from body angular rates by the direction-cosine-matrix recursion.

Conventions (see README "Frames and units"): ``R_w_b`` / ``q_w_b`` map body to world (active);
quaternions are Hamilton ``[x, y, z, w]``; ``omega_b`` is the body rate relative to the world in
body axes, rad/s; increments multiply on the right, ``R_{i+1} = R_i · exp([φ_i×])``; time ``t_s``
in seconds.

``import imu_dcm`` is cheap (numpy only): scipy and numba are imported on first use (the
streaming integrator on first access, the compiled kernel on the first integration), so command
lines that only print their help start fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from imu_dcm.errors import GapWarning, ImuDcmError, ImuDcmWarning, InputError, LogError
from imu_dcm.integrate import DELTA_METHODS, METHODS, integrate, integrate_delta

if TYPE_CHECKING:
    from imu_dcm.streaming import DcmIntegrator

__all__ = [
    "DELTA_METHODS",
    "METHODS",
    "DcmIntegrator",
    "GapWarning",
    "ImuDcmError",
    "ImuDcmWarning",
    "InputError",
    "LogError",
    "integrate",
    "integrate_delta",
]
__version__ = "0.1.0"

# Loaded on first access (module __getattr__): streaming imports the compiled kernel (numba).
_LAZY = {"DcmIntegrator": "imu_dcm.streaming"}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'imu_dcm' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
