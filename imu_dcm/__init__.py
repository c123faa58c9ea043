"""imu_dcm: strapdown attitude from body angular rates by the direction-cosine-matrix recursion.

Conventions (see README "Frames and units"): ``R_w_b`` / ``q_w_b`` map body to world (active);
quaternions are Hamilton ``[x, y, z, w]``; ``omega_b`` is the body rate relative to the world in
body axes, rad/s; increments multiply on the right, ``R_{i+1} = R_i · exp([φ_i×])``; time ``t_s``
in seconds.

``import imu_dcm`` is cheap (no numpy, scipy or numba): the names below load on first use, so
command lines that only print their help start fast.
"""

import importlib

from imu_dcm.errors import GapWarning, ImuDcmError, ImuDcmWarning, InputError, LogError

_LAZY = {  # loaded on first use, so a command's --help does not import the numerical stack
    "DELTA_METHODS": "imu_dcm.integrator.batch",
    "METHODS": "imu_dcm.integrator.batch",
    "integrate": "imu_dcm.integrator.batch",
    "integrate_delta": "imu_dcm.integrator.batch",
    "DcmIntegrator": "imu_dcm.integrator.streaming",
    "Method": "imu_dcm.integrator.methods",
    "DeltaMethod": "imu_dcm.integrator.methods",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'imu_dcm' has no attribute {name!r}")


__all__ = [
    "DELTA_METHODS",
    "METHODS",
    "DcmIntegrator",
    "DeltaMethod",
    "GapWarning",
    "ImuDcmError",
    "ImuDcmWarning",
    "InputError",
    "LogError",
    "Method",
    "integrate",
    "integrate_delta",
]
__version__ = "0.1.0"
