"""JSON IMU channels: ``{"header": {"stamp": {"sec", "nanosec"}}, "angular_velocity": {x, y, z}}``.

Parsed message by message with :mod:`json`. A message that is not an object, nests too deep,
lacks ``angular_velocity`` or carries a stamp that is not a finite number within int64
nanoseconds (1e300, 2**70, Infinity) is dropped and counted, never a traceback.
"""

from __future__ import annotations

import json
import math

import numpy as np

from imu_dcm.logio.ros.collect import Conn, Payloads

__all__ = ["is_json_imu", "json_imu_columns", "json_msg", "json_stamp"]


_INT64 = 2**63


def json_msg(raw: bytes) -> dict | None:
    try:
        m = json.loads(raw)
    except (ValueError, RecursionError):
        return None
    return m if isinstance(m, dict) else None


def is_json_imu(m: dict | None) -> bool:
    av = (m or {}).get("angular_velocity")
    return isinstance(av, dict) and all(k in av for k in "xyz")


def json_stamp(m: dict) -> int | None:
    st = (m.get("header") or {}).get("stamp") if isinstance(m.get("header"), dict) else None
    st = st if st is not None else m.get("stamp")
    if not isinstance(st, dict):
        return None
    sec, nsec = st.get("sec", 0), st.get("nanosec", st.get("nsec", 0))
    if not all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        for v in (sec, nsec)
    ):
        raise ValueError("stamp not a finite number")
    t = int(sec) * 1_000_000_000 + int(nsec)
    if not -_INT64 <= t < _INT64:
        raise ValueError("stamp beyond int64 nanoseconds")
    return t


def json_imu_columns(c: Conn, p: Payloads):
    n = len(p)
    omega = np.full((n, 3), np.nan)
    t_ns = p.log_time.copy()
    good = np.zeros(n, dtype=bool)
    for i in range(n):
        m = json_msg(p.payload(i))
        if not is_json_imu(m):
            continue
        av = m["angular_velocity"]
        try:
            omega[i] = [float(av["x"]), float(av["y"]), float(av["z"])]
            st = json_stamp(m)
        except (TypeError, ValueError, OverflowError):
            continue
        if st is not None:
            t_ns[i] = st
        good[i] = True
    return t_ns, omega, None, good, "json", ""
