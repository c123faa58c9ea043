"""The statistics of a scored replay: error statistics, per-axis errors, drift rates and the bias
self-check (:func:`evaluate`), and their console lines (:func:`evaluation_lines`).

Definitions (:mod:`imu_dcm.metrics`): total, inclination and heading errors in degrees; the
world error ``e_w = log(q_est ⊗ q_true*)`` and the body error ``e_b = log(q_true* ⊗ q_est)``
(rad, ``R_est = R_true exp(e_b×)``). Drift rates are least-squares slopes through the error's
growth over the scored samples, one slope shared by the segments between truth jumps (each with
its own intercept), in °/h:

* heading: the slope of ``e_w``'s world-z component (signed: + is counter-clockwise seen from
  above);
* inclination: the length of the slopes of its world x and y components;
* total: the length of all three slopes;
* body axes: the slope of each component of ``e_b``.

**Bias self-check.** A constant bias error ``δb`` left in the rates (body axes) makes ``e_w``
grow at ``R_true δb``, whose average over any motion is no longer than ``|δb|``: the total world
drift rate is a lower bound on the residual bias. When it is at least :data:`DOUBT_RATIO` of the
bias that was removed (``|mean bias|`` over the estimated samples, in the same °/h) and the
error grows as a line (R² ≥ :data:`LINE_R2`), the removed bias is off by half of itself or more
(or a scale-factor error of that size acts), and the bias is called doubtful.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imu_dcm._kernels.calls import error_vectors
from imu_dcm.arrays import BLOCK_ROWS, true_span
from imu_dcm.metrics import (
    S_PER_H,
    AttitudeError,
    DriftFit,
    DriftSums,
    error_stats,
)

__all__ = ["DOUBT_RATIO", "LINE_R2", "evaluate", "evaluation_lines"]

#: The residual drift is "about as large as the bias removed" from this fraction on.
DOUBT_RATIO = 0.5
#: A fitted line explains at least this share of the error's variance to be called drift.
LINE_R2 = 0.5
_DEG_H = np.degrees(1.0) * S_PER_H  # rad/s -> °/h
_AXES = ("x", "y", "z")


def _stats(x: NDArray) -> dict:
    s = error_stats(x)
    return {
        "rms": s.rms,
        "mean": s.mean,
        "median": s.median,
        "std": s.std,
        "p95": s.p95,
        "max": s.max,
        "samples": s.samples,
    }


def _norm_fit(fit: DriftFit, rows: list[int]) -> dict:
    """The length of the slopes of ``rows`` (rad/s) as °/h, its propagated standard error and
    the fit's R² over those rows."""
    s, se = fit.slope[rows], fit.stderr[rows]
    n = float(np.sqrt(s @ s))
    err = float(np.sqrt(((s / n) ** 2) @ (se**2))) if n > 0 else float(np.sqrt(se @ se))
    return {"rate_deg_h": n * _DEG_H, "stderr_deg_h": err * _DEG_H, "r2": fit.r2(rows)}


def _drift(fit: DriftFit, t: NDArray, seg: NDArray | None) -> dict:
    """Drift rates from one joint fit of the world (rows 0-2) and body (rows 3-5) errors."""
    return {
        "total": _norm_fit(fit, [0, 1, 2]),
        "inclination": _norm_fit(fit, [0, 1]),
        "heading": {
            "rate_deg_h": float(fit.slope[2]) * _DEG_H,
            "stderr_deg_h": float(fit.stderr[2]) * _DEG_H,
            "r2": fit.r2([2]),
        },
        "body_deg_h": {a: float(fit.slope[3 + i]) * _DEG_H for i, a in enumerate(_AXES)},
        "body_stderr_deg_h": {a: float(fit.stderr[3 + i]) * _DEG_H for i, a in enumerate(_AXES)},
        "body_r2": fit.r2([3, 4, 5]),
        "samples": fit.samples,
        "segments": 1 if seg is None else int(seg[-1] - seg[0] + 1),
        "from_s": float(t[0]),
        "to_s": float(t[-1]),
    }


def _bias_check(drift: dict, bias_rad_s) -> dict:
    removed = float(np.linalg.norm(bias_rad_s)) * _DEG_H
    residual = drift["total"]["rate_deg_h"]
    r2 = drift["total"]["r2"]
    ratio = residual / removed if removed > 0 else None
    doubtful = bool(
        ratio is not None and np.isfinite(residual) and ratio >= DOUBT_RATIO and r2 >= LINE_R2
    )
    return {
        "residual_drift_deg_h": residual,
        "bias_removed_deg_h": removed,
        "ratio": ratio,
        "line_r2": r2,
        "doubtful": doubtful,
    }


class _BodySums:
    """Per body axis (rows of the blocks of ``e_b`` handed to :meth:`add`, rad): RMS, signed
    mean and largest magnitude, deg."""

    def __init__(self) -> None:
        self.n, self.sq, self.sum = 0, np.zeros(3), np.zeros(3)
        self.hi, self.lo = np.full(3, -np.inf), np.full(3, np.inf)

    def add(self, e_b: NDArray) -> None:
        self.n += e_b.shape[1]
        self.sq += np.einsum("ij,ij->i", e_b, e_b)
        self.sum += e_b.sum(axis=1)
        self.hi = np.maximum(self.hi, e_b.max(axis=1))
        self.lo = np.minimum(self.lo, e_b.min(axis=1))

    def stats(self) -> dict:
        n = self.n
        return {
            a: {
                "rms": float(np.degrees(np.sqrt(self.sq[i] / n))),
                "mean_signed": float(np.degrees(self.sum[i] / n)),
                "max_abs": float(np.degrees(max(self.hi[i], -self.lo[i]))),
            }
            for i, a in enumerate(_AXES)
        }


def _scored_rows(scored: NDArray) -> slice | NDArray | None:
    """The scored rows: a slice when they are one stretch (the usual case: views, no copies),
    else their indices; None when none is."""
    span = true_span(scored)
    if span is None:
        return None
    first, last, count = span
    return slice(first, last + 1) if last - first + 1 == count else np.flatnonzero(scored)


def evaluate(
    t_s: NDArray,
    q_est: NDArray,
    q_truth: NDArray,
    scored: NDArray,
    anchors: list[int],
    error: AttitudeError,
    bias_rad_s,
) -> dict | None:
    """Statistics, per-axis errors, drift rates and the bias self-check of a scored replay.

    Parameters
    ----------
    t_s : (N,) s; q_est, q_truth : (N, 4) ``q_w_b`` ``[x, y, z, w]``; scored : (N,) bool, the
    samples with both; anchors : first sample of each integrated segment; error : per-sample
    errors, deg; bias_rad_s : (3,) mean bias removed, rad/s.

    Returns
    -------
    dict or None
        JSON-ready (angles deg, rates °/h); None when nothing was scored.
    """
    idx = _scored_rows(scored)
    if idx is None:
        return None
    seg = None
    if len(anchors) > 1:
        seg = np.searchsorted(np.asarray(anchors), np.arange(len(t_s))[idx], side="right")
    qe, qt = q_est[idx], q_truth[idx]
    total = error.total_deg[idx]
    # world rows, then body rows (their angle is the total error, already computed), a block
    # at a time: each sample's vector is its own, and the fit and the body statistics are sums
    t = t_s[idx]
    sums = DriftSums(t, 6, seg)
    body = _BodySums()
    for a in range(0, len(total), BLOCK_ROWS):
        k = slice(a, a + BLOCK_ROWS)
        e = np.empty((6, len(total[k])))  # the same formulas in one compiled pass
        error_vectors(
            np.ascontiguousarray(qe[k]), np.ascontiguousarray(qt[k]), np.radians(total[k]), e
        )
        sums.add(a, e)
        body.add(e[3:])
    drift = _drift(sums.fit(), t, seg)
    del sums  # its centred stamps go before the statistics' sorted copies come
    return {
        "total_deg": _stats(total),
        "inclination_deg": _stats(error.inclination_deg[idx]),
        "heading_deg": _stats(error.heading_deg[idx]),
        "body_axes_deg": body.stats(),
        "drift": drift,
        "bias_check": _bias_check(drift, bias_rad_s),
    }


def _f(x: float | None, unit: str = "°") -> str:
    if x is None or not np.isfinite(x):
        return "n/a"
    return f"{x:.2f}{unit}" if x == 0.0 or abs(x) >= 0.01 else f"{x:.2g}{unit}"


def _rate(d: dict, signed: bool = False) -> str:
    rate = d["rate_deg_h"]
    if rate is None or not np.isfinite(rate):
        return "drift n/a"
    num = f"{rate:+.3g}" if signed else f"{rate:.3g}"
    return f"drift {num} °/h (±{d['stderr_deg_h']:.2g}, R² {d['r2']:.2f})"


def evaluation_lines(ev: dict | None) -> list[str]:
    """One console line per quantity (``error      total ...``, inclination, heading, body
    axes), and the bias check's line when the bias is doubtful."""
    if not ev:
        return []
    lines = []
    drift = ev["drift"]
    for label, key, signed in (
        ("total", "total", False),
        ("inclination", "inclination", False),
        ("heading", "heading", True),
    ):
        s = ev[f"{key}_deg"]
        lines.append(
            f"error      {label} RMS {_f(s['rms'])}, mean {_f(s['mean'])}, "
            f"median {_f(s['median'])}, "
            f"std {_f(s['std'])}, p95 {_f(s['p95'])}, max {_f(s['max'])}; "
            f"{_rate(drift[key], signed)}"
        )
    b = ev["body_axes_deg"]
    rms_ = ", ".join(f"{a} {_f(b[a]['rms'])}" for a in _AXES)
    mean_ = ", ".join(f"{a} {b[a]['mean_signed']:+.2f}°" for a in _AXES)
    rates = ", ".join(f"{a} {drift['body_deg_h'][a]:+.3g}" for a in _AXES)
    lines.append(
        f"error      body axes RMS {rms_}; mean {mean_}; drift {rates} °/h "
        f"(R² {drift['body_r2']:.2f})"
    )
    chk = ev["bias_check"]
    if chk["doubtful"]:
        lines.append(
            f"bias check DOUBTFUL: the residual drift {chk['residual_drift_deg_h']:.3g} °/h is "
            f"{chk['ratio']:.0%} of the bias removed ({chk['bias_removed_deg_h']:.3g} °/h) and "
            f"grows as a line (R² {chk['line_r2']:.2f}): the bias (or a scale factor) is off "
            f"by about half of itself or more"
        )
    return lines
