"""``--compare magnus4,trapezoid,end,vqf,imufusion``: several integrators on one log, in one run.

The log is replayed once (:func:`imu_dcm.replay.replay`, with the first method); every method
then integrates the **same rates** (bias removed, mounting applied, pre-filtered: the replay's
``omega_b``) from the **same start** (the truth at each anchor, the first scored sample and each
re-anchoring after a truth jump), and is scored with the same statistics
(:func:`imu_dcm.replay.stats.evaluate`). Names are this project's methods
(:data:`imu_dcm.integrator.methods.METHODS`) and the peers of :mod:`imu_dcm.integrator.peers`,
gyro-only:

=============== ======================================= =========================
name            peer                                    installed by
=============== ======================================= =========================
``vqf``         ``vqf_batch`` (vqf ``updateBatch``)      ``pip install vqf``
``imufusion``   ``imufusion_gain0`` (x-io Fusion)        ``pip install imufusion``
``ahrs``        ``ahrs_angular_rate``                   ``pip install ahrs``
``reference``   ``reference_loop`` (numpy 3x3 loop)     (always)
``scipy``       ``scipy_loop``                          (always)
=============== ======================================= =========================

(``pip install 'imu_dcm[bench]'`` installs all three libraries.) The cost is the wall time of
that method's integration of all scored segments, after a warm-up call on the first 1000
samples, divided by the samples: ns per sample, measured in this run on this machine.
"""

from __future__ import annotations

import importlib.util
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import row_finite
from imu_dcm.errors import Diagnostics, InputError
from imu_dcm.integrator.batch import integrate_quat
from imu_dcm.integrator.methods import METHODS
from imu_dcm.integrator.peers import PEERS
from imu_dcm.metrics import AttitudeError, attitude_error_deg
from imu_dcm.replay.stats import evaluate

__all__ = ["PEER_NAMES", "CompareRow", "compare_methods", "compare_lines", "parse_compare"]

#: Short name -> (peers.PEERS key, the module it needs or None).
PEER_NAMES = {
    "vqf": ("vqf_batch", "vqf"),
    "imufusion": ("imufusion_gain0", "imufusion"),
    "ahrs": ("ahrs_angular_rate", "ahrs"),
    "reference": ("reference_loop", None),
    "scipy": ("scipy_loop", None),
}
_BENCH = "pip install 'imu_dcm[bench]'"
_WARMUP = 1000


def parse_compare(text: str) -> tuple[str, ...]:
    """The method names of ``--compare a,b,c``, checked (known, installed, no repeats)."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    known = (*METHODS, *PEER_NAMES)
    if not names:
        raise InputError(f"Expected --compare with method names from {', '.join(known)}, got ''")
    for n in names:
        if n not in known:
            raise InputError(f"Expected --compare names from {', '.join(known)}, got {n!r}")
        module = PEER_NAMES.get(n, (None, None))[1]
        if module and importlib.util.find_spec(module) is None:
            raise InputError(
                f"Expected the peer {n!r} installed for --compare, got no module {module!r}: "
                f"pip install {module} (or {_BENCH})"
            )
    if len(set(names)) != len(names):
        raise InputError(f"Expected each --compare name once, got {text!r}")
    return names


@dataclass(frozen=True, slots=True)
class CompareRow:
    """One method of a comparison: its estimate, errors, statistics and cost.

    Attributes
    ----------
    name : the method's name as given.
    q_est : (N, 4) ``q_w_b`` ``[x, y, z, w]``, NaN before the first anchor.
    error : per-sample errors, deg (NaN where not scored).
    evaluation : :func:`imu_dcm.replay.stats.evaluate`'s dict, or None without truth.
    ns_per_sample : wall time of the integration per sample, ns.
    """

    name: str
    q_est: NDArray[np.float64]
    error: AttitudeError
    evaluation: dict | None
    ns_per_sample: float


def _anchors(result) -> list[int]:
    """The samples the replay integrated from: its start and each re-anchoring."""
    anchors = [int(result.start_index)]
    for seg in result.summary.scored_segments[1:]:
        anchors.append(int(np.searchsorted(result.t_s, seg["start_s"])))
    return anchors


def _integrator(name: str):
    """The method or peer as ``fn(omega_b, t_s, q0)``; a method's warnings (the gaps, its
    own) were said once, by the replay."""
    if name in METHODS:
        return lambda w, t, q0: integrate_quat(w, t, q0, name, diagnostics=Diagnostics())
    return PEERS[PEER_NAMES[name][0]].fn


def _run(fn, omega, t_s, q_start, anchors) -> tuple[NDArray, float]:
    """Integrate every segment from its anchor; the estimate and its wall time, s."""
    n = len(t_s)
    q_est = np.full((n, 4), np.nan)
    ends = [*anchors[1:], n]
    t0 = time.perf_counter()
    for a, b in zip(anchors, ends, strict=True):
        q_est[a:b] = fn(omega[a:b], t_s[a:b], q_start[a]) if b - a >= 2 else q_start[a]
    return q_est, time.perf_counter() - t0


def _score(q_est: NDArray, q_truth: NDArray) -> tuple[AttitudeError, NDArray]:
    both = row_finite(q_truth) & row_finite(q_est)
    unit = np.array([0.0, 0.0, 0.0, 1.0])
    err = attitude_error_deg(
        np.where(both[:, None], q_est, unit), np.where(both[:, None], q_truth, unit)
    )
    fields = (err.total_deg, err.inclination_deg, err.heading_deg)
    return AttitudeError(*(np.where(both, a, np.nan) for a in fields)), both


def compare_methods(result, names: tuple[str, ...]) -> list[CompareRow]:
    """Integrate ``result.omega_b`` with every method of ``names`` from the replay's anchors.

    ``result`` is a :class:`imu_dcm.replay.summary.ReplayResult`; its estimate's start
    attitudes (``q_est`` at each anchor: the truth there, or the initial attitude) are reused.
    """
    t_s, omega = result.t_s, np.ascontiguousarray(result.omega_b)
    anchors = _anchors(result)
    rows = []
    for name in names:
        fn = _integrator(name)
        a = anchors[0]
        k = min(len(t_s), a + _WARMUP)
        if k - a >= 2:
            fn(omega[a:k], t_s[a:k], result.q_est[a])  # warm-up: imports, first calls
        q_est, elapsed = _run(fn, omega, t_s, result.q_est, anchors)
        error, both = _score(q_est, result.q_truth)
        ev = evaluate(t_s, q_est, result.q_truth, both, anchors, error, result.summary.bias_rad_s)
        samples = len(t_s) - anchors[0]
        rows.append(CompareRow(name, q_est, error, ev, 1e9 * elapsed / max(samples, 1)))
    return rows


def _g(x: float) -> str:
    """Three significant digits, trailing zeros kept (3.00, 0.0216), no lone point (123)."""
    return f"{x:#.3g}".rstrip(".") if np.isfinite(x) else "n/a"


def compare_lines(rows: list[CompareRow]) -> list[str]:
    """A table for the console: one line per method (angles deg, drift °/h, cost ns/sample)."""
    head = (
        f"{'compare':10s} {'method':11s} {'total RMS':>10s} {'p95':>9s} {'max':>9s} "
        f"{'incl. RMS':>10s} {'head. RMS':>10s} {'drift °/h':>10s} {'ns/sample':>10s}"
    )
    lines = [head]
    for r in rows:
        ev = r.evaluation
        if ev is None:
            cells = f"{'n/a':>10s} {'':>9s} {'':>9s} {'':>10s} {'':>10s} {'':>10s}"
        else:
            t, i, h = ev["total_deg"], ev["inclination_deg"], ev["heading_deg"]
            drift = ev["drift"]["total"]["rate_deg_h"]
            cells = (
                f"{_g(t['rms']):>9s}° {_g(t['p95']):>8s}° {_g(t['max']):>8s}° "
                f"{_g(i['rms']):>9s}° {_g(h['rms']):>9s}° {_g(drift):>10s}"
            )
        lines.append(f"{'':10s} {r.name:11s} {cells} {r.ns_per_sample:10.0f}")
    return lines


def compare_json(rows: list[CompareRow]) -> list[dict]:
    """The comparison for the summary JSON: name, cost and the statistics of each method."""
    return [
        {"method": r.name, "ns_per_sample": r.ns_per_sample, "evaluation": r.evaluation}
        for r in rows
    ]
