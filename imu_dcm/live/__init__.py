"""Live: the streaming integrator fed from a running robot or sensor, shown in rerun as it happens.

``python -m imu_dcm.live SOURCE [options]`` or :func:`run`; SOURCE is ``ws://HOST:PORT`` (a
Foxglove WebSocket server such as ``foxglove_bridge``), ``udp://HOST:PORT`` or ``-`` (stdin)
with line samples, or ``mavlink:...``. The names load lazily, so the command starts (and answers
Ctrl-C with one line) before numpy is imported.

Modules: :mod:`~imu_dcm.live.session` (:func:`run`: options, start, stop),
:mod:`~imu_dcm.live.loop` (the session's loop), :mod:`~imu_dcm.live.pipeline` (what happens to
each sample), :mod:`~imu_dcm.live.summary` (:class:`LiveResult`), :mod:`~imu_dcm.live.events`
(what a source queues), :mod:`~imu_dcm.live.sources` (one source a file),
:mod:`~imu_dcm.live.lines` (the line format), :mod:`~imu_dcm.live.reorder`,
:mod:`~imu_dcm.live.latency` and :mod:`~imu_dcm.live.recorder` (``--record``). The view is
viz's (:mod:`imu_dcm.viz.live`).
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
