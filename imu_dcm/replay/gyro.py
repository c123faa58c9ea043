"""The gyro side of one replay: the time base, the cleaning (:mod:`imu_dcm.replay.clean`), the
units, stamps no IMU produces, and the accelerometer and the autopilot's state on the kept rows.

Conventions: ``omega_b`` body rate in body axes, rad/s; ``t_ns`` int64 stamps, ``t_s`` float64
seconds since the first kept gyro sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import row_finite
from imu_dcm.errors import Diagnostics, LogError
from imu_dcm.gyro.stamps import NS_PER_UNIT, timing_doubt
from imu_dcm.logio import LogData
from imu_dcm.replay.clean import CleanedImu, clean_imu
from imu_dcm.replay.settings import ReplaySettings
from imu_dcm.replay.truth import choose_time

__all__ = ["DEG", "Gyro", "prepare_gyro"]

DEG = np.pi / 180.0


@dataclass(slots=True, frozen=True)
class Gyro:
    """The cleaned gyro of a replay: time base ("header" or "log"), the cleaning, stamps (ns,
    and s since the first kept sample), rates (rad/s, body axes), accelerometer (m/s², or None),
    and the autopilot's (landed, armed) state on its rows (or None)."""

    base: str
    clean: CleanedImu
    t_ns: NDArray[np.int64]
    t_s: NDArray[np.float64]
    omega: NDArray[np.float64]
    accel: NDArray[np.float64] | None
    vehicle: tuple[NDArray, NDArray] | None = None


def prepare_gyro(log: LogData, s: ReplaySettings, notes: Diagnostics) -> Gyro:
    """Time base, cleaning and units of the gyro samples."""
    imu, truth = log.imu, log.truth
    base, why = choose_time(
        s.time,
        imu.t_ns,
        imu.log_t_ns,
        truth.t_ns if truth is not None else None,
        truth.log_t_ns if truth is not None else None,
    )
    if why:
        notes.add(f"time: using log time, not header stamps: {why}")
    imu_t = imu.t_ns if base == "header" else imu.log_t_ns
    scale = DEG if s.gyro_units == "deg/s" else 1.0
    omega = np.asarray(imu.omega_b, dtype=float)
    w = omega * scale if scale != 1.0 else omega  # no copy
    clean = clean_imu(imu_t, w, imu.topic, diagnostics=notes)
    n = len(clean.t_ns)
    if n < 2:
        hint = ""
        if base == "header" and len(np.unique(imu.log_t_ns[:1000])) > 1:
            hint = "; the log times differ: try --time log"
        raise LogError(f"Expected at least 2 valid gyro samples on {imu.topic}, got {n}{hint}")
    doubt = timing_doubt(clean.t_ns, omega_b=clean.omega_b)
    if doubt is not None:
        clause, fix = doubt
        factor = NS_PER_UNIT["s"] // NS_PER_UNIT[fix] if fix else 0
        # a log's stamps have no declared unit: say the factor, not a unit read as seconds
        clause = clause.replace(f"; as {fix}:", f"; with steps {factor}x shorter:")
        hint = (
            f"; was it converted with a time unit {factor}x too large (for a CSV declared in "
            f"s: convert-csv --time-units {fix})?"
        )
        notes.add(f"{imu.topic}: stamps no IMU produces: {clause}{hint if fix else ''}")
    t_s = np.empty(n)  # (t - t0) * 1e-9: the difference exact in int64, one array
    np.subtract(clean.t_ns, clean.t_ns[0], out=t_s, casting="unsafe")
    t_s *= 1e-9
    vehicle = None if log.vehicle_state is None else log.vehicle_state.at(clean.t_ns)
    accel = _accel(imu, clean, notes)
    return Gyro(base, clean, clean.t_ns, t_s, clean.omega_b, accel, vehicle)


def _accel(imu, clean: CleanedImu, notes: Diagnostics) -> NDArray | None:
    """The accelerometer on the cleaned gyro rows, m/s², or None (absent or incomplete)."""
    if imu.accel_b is None:
        return None
    acc = np.asarray(imu.accel_b, dtype=float)[clean.index]
    finite = row_finite(acc)
    if not finite.all():
        bad = int(np.count_nonzero(~finite))
        notes.add(
            f"{imu.topic}: accelerometer missing on {bad} of {len(acc)} samples; rest judged "
            f"from the gyro alone",
            None,  # in the summary, not warned
        )
        return None
    return acc
