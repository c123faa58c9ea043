"""Live: the streaming integrator fed from a running robot or sensor, shown in rerun as it happens.

``python -m imu_dcm.live SOURCE [options]`` or :func:`run`; SOURCE is ``ws://HOST:PORT`` (a
Foxglove WebSocket server such as ``foxglove_bridge``), ``udp://HOST:PORT`` or ``-`` (stdin)
with line samples. See :mod:`imu_dcm.live.pipeline` for what happens to each sample.
"""

from imu_dcm.live.pipeline import LiveResult
from imu_dcm.live.session import run

__all__ = ["LiveResult", "run"]
