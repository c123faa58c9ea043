"""Live: the streaming integrator fed from a running robot or sensor, shown in rerun as it happens.

``python -m imu_dcm.live SOURCE [options]`` or :func:`run`; SOURCE is ``ws://HOST:PORT`` (a
Foxglove WebSocket server such as ``foxglove_bridge``), ``udp://HOST:PORT`` or ``-`` (stdin)
with line samples. See :mod:`imu_dcm.live.pipeline` for what happens to each sample. The names
load lazily, so the command starts (and answers Ctrl-C with one line) before numpy is imported.
"""

from __future__ import annotations

__all__ = ["LiveResult", "run"]


def __getattr__(name: str):
    if name == "run":
        from imu_dcm.live.session import run

        return run
    if name == "LiveResult":
        from imu_dcm.live.summary import LiveResult

        return LiveResult
    raise AttributeError(f"module 'imu_dcm.live' has no attribute {name!r}")
