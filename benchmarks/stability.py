"""Stability study charts: ``run(out_dir, quick)`` draws the eight scenes of
:mod:`data_synth.stability` into ``stability_*.png`` and returns the markdown for the results.

The scenes themselves (pure functions returning frozen results, also asserted by
``tests/test_stability.py``) live in :mod:`data_synth.stability`; the deliberately wrong or
first-order integrators they compare against in :mod:`imu_dcm.integrator.reference`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from data_synth.stability import (
    DCM_METHODS,
    free_box,
    gimbal_lock,
    large_steps,
    long_run,
    naive_dcm_drift,
    noise_growth,
    rotvec_sum_shortcut,
    steady_top,
    truncated_update,
)
from data_synth.stability.common import _EPS
from imu_dcm.outputs import save_figure

__all__ = ["run"]


# ----------------------------------------------------------------------------------------------
# Charts and table
# ----------------------------------------------------------------------------------------------

_MARKERS = {
    "start": "v",
    "end": "^",
    "trapezoid": "s",
    "coning": "D",
    "magnus4": "o",
    "truncated": "x",
    "euler_zxz": "P",
    "rotvec_sum": "*",
}
_LABELS = {
    "start": "imu_dcm start (1st order)",
    "end": "imu_dcm end (1st, end-of-step rate)",
    "trapezoid": "imu_dcm trapezoid (2nd)",
    "coning": "imu_dcm coning (2nd)",
    "magnus4": "imu_dcm magnus4 (4th)",
    "truncated": "truncated q + ½q⊗ωdt, normalised",
    "euler_zxz": "ZXZ Euler angles (Heun)",
    "rotvec_sum": "rotvec_sum R0·exp(Σω dt)",
}


def _fmt(x: float) -> str:
    if not np.isfinite(x):
        return "nan"
    if x == 0:
        return "0"
    return f"{x:.2g}" if abs(x) < 1e-2 or abs(x) >= 1e4 else f"{x:.3g}"


def _floor(y: NDArray, lo: float = 1e-13) -> NDArray:
    """Errors clipped from below for log axes (an exact 0 is shown at ``lo``)."""
    return np.maximum(np.asarray(y, dtype=float), lo)


def _scene_gimbal_lock(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 1. gimbal lock: chart and markdown lines."""
    md: list[str] = []
    progress("stability 1/8: gimbal lock (Euler angles vs DCM)")
    closest = (
        [0.0, 0.01, 0.1, 1.0, 10.0, 30.0]
        if quick
        else [0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0]
    )
    g_rates = (100.0, 1000.0)
    gl = {(c, r): gimbal_lock(c, r) for c in closest for r in g_rates}
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.6))
    ex = gl[(0.0, 1000.0)]
    a1.semilogy(
        ex.t_s, _floor(ex.euler_err_deg), "P-", ms=3, markevery=100, label="ZXZ Euler angles (Heun)"
    )
    a1.semilogy(
        ex.t_s, _floor(ex.dcm_err_deg), "s-", ms=3, markevery=100, label="DCM, imu_dcm trapezoid"
    )
    a1b = a1.twinx()
    a1b.plot(ex.t_s, ex.theta_deg, "k:", lw=1)
    a1b.set_ylabel("true θ (z axis from vertical), deg (dotted)")
    a1.set_xlabel("time, s")
    a1.set_ylabel("attitude error, deg")
    a1.set_title("Axis through the vertical (θ = 0), 1000 Hz")
    a1.legend(loc="upper left", fontsize=8)
    cs = np.array([max(c, 1e-3) for c in closest])
    for r, ls in zip(g_rates, ("--", "-"), strict=True):
        a2.loglog(
            cs,
            _floor([gl[(c, r)].euler_max_deg for c in closest]),
            "P" + ls,
            label=f"Euler angles, {r:.0f} Hz",
        )
        a2.loglog(
            cs,
            _floor([gl[(c, r)].dcm_max_deg for c in closest]),
            "s" + ls,
            label=f"DCM trapezoid, {r:.0f} Hz",
        )
    a2.set_xlabel("closest approach of z axis to vertical, deg (0 plotted at 1e-3)")
    a2.set_ylabel("max attitude error, deg")
    a2.set_title("Error against closeness to gimbal lock")
    a2.legend(fontsize=8)
    fig.suptitle("Scene 1: gimbal lock — same samples, same order, Euler angles vs DCM")
    fig.tight_layout()
    save_figure(fig, out / "stability_gimbal_lock.png", dpi=110)
    plt.close(fig)
    md += [
        "### 1. Gimbal lock (chart `stability_gimbal_lock.png`)",
        "",
        (
            "Body z axis passing ε from the vertical (R = Rx(ε)·Ry(0.5 (t−1))·Rz(2t), 2 s); "
            "ZXZ Euler angles integrated with Heun's rule vs imu_dcm `trapezoid` (both 2nd order, "
            "same samples). Max total error, deg:"
        ),
        "",
        "| closest approach ε, deg | rate, Hz | Euler angles | DCM trapezoid |",
        "|---|---|---|---|",
    ]
    for c in closest:
        for r in g_rates:
            g = gl[(c, r)]
            md.append(f"| {c:g} | {r:.0f} | {_fmt(g.euler_max_deg)} | {_fmt(g.dcm_max_deg)} |")
    md.append("")
    return md


def _scene_rotvec_sum(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 2. rotvec_sum: chart and markdown lines."""
    md: list[str] = []
    progress("stability 2/8: rotation-vector-sum shortcut")
    rs = rotvec_sum_shortcut()
    fig, ax = plt.subplots(figsize=(8, 4.6))
    ax.plot(rs.t_s, rs.rotvec_sum_err_deg, "-", label="rotvec_sum R0·exp(Σω dt), wraps at 180°")
    whole = np.isclose(rs.t_s, np.round(rs.t_s))
    ax.plot(
        rs.t_s[whole],
        rs.predicted_deg[whole],
        "ko",
        mfc="none",
        label="analytic (1 − cos β) Ω t at whole cycles",
    )
    ax.plot(
        rs.t_s,
        rs.magnus4_err_deg,
        "-",
        label=f"imu_dcm magnus4 (max {_fmt(rs.magnus4_err_deg.max())}°)",
    )
    ax.set_xlabel("time, s")
    ax.set_ylabel("attitude error, deg")
    ax.set_title("Scene 2: R0·exp(Σω dt) under coning (β = 30°, 1 Hz, 1000 Hz samples)")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, out / "stability_rotvec_sum.png", dpi=110)
    plt.close(fig)
    md += [
        "### 2. Rotation-vector sum R0·exp(Σω dt) (chart `stability_rotvec_sum.png`)",
        "",
        (
            f"Coning β = 30°, 1 Hz, 1000 Hz, 5 s: rotation-vector sum max error "
            f"{_fmt(rs.rotvec_sum_err_deg.max())}° (analytic (1 − cos β)Ωt: "
            f"{_fmt(rs.predicted_deg[-1])}° at 5 s, measured {_fmt(rs.rotvec_sum_err_deg[-1])}°); "
            f"magnus4 {_fmt(rs.magnus4_err_deg.max())}°. "
            "Fixed axis (commuting): rotation-vector sum "
            f"{_fmt(rs.fixed_axis_err_deg)}°."
        ),
        "",
    ]
    return md


def _scene_large_steps(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 3. large steps: chart and markdown lines."""
    md: list[str] = []
    progress("stability 3/8: large steps |ω|dt 0.01..3 rad")
    ls_res = large_steps(tuple(np.geomspace(0.01, 3.0, 7 if quick else 13)))
    fig, ax = plt.subplots(figsize=(9, 5))
    for m, e in ls_res.err_deg.items():
        ax.loglog(ls_res.step_rad, _floor(e), marker=_MARKERS[m], label=_LABELS[m])
    ax.set_xlabel("step |ω| dt, rad")
    ax.set_ylabel("max attitude error over 5 s, deg")
    ax.set_title("Scene 3: large steps (precession dφ/dt = 2π rad/s, θ = 30°, dψ/dt = 0.2π rad/s)")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    save_figure(fig, out / "stability_large_steps.png", dpi=110)
    plt.close(fig)
    names = list(ls_res.err_deg)
    md += [
        "### 3. Large steps (chart `stability_large_steps.png`)",
        "",
        (
            "Max total error (deg) over 5 s of steady precession; every imu_dcm quaternion stays "
            f"unit to {_fmt(max(ls_res.max_norm_dev[m].max() for m in DCM_METHODS))}."
        ),
        "",
        "| \\|ω\\| dt, rad | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    for k, s in enumerate(ls_res.step_rad):
        md.append(f"| {s:.3g} | " + " | ".join(_fmt(ls_res.err_deg[m][k]) for m in names) + " |")
    md.append("")
    return md


def _scene_long_run(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 4. long run: chart and markdown lines."""
    md: list[str] = []
    n_long = 1_000_000 if quick else 10_000_000
    progress(f"stability 4/8: long run, {n_long:.0e} steps (batch, chunked)")
    lr = long_run(n_long, method="magnus4", chunk=n_long // 10)
    lr2 = long_run(n_long, method="trapezoid", chunk=n_long // 10)
    n_naive = 100_000 if quick else n_long
    progress(f"stability 4/8: plain un-normalised 3x3 DCM loop, {n_naive:.0e} steps")
    nd = naive_dcm_drift(n_naive)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.6))
    a1.loglog(lr.step_idx, _floor(lr.err_deg), "o-", label="imu_dcm magnus4, error")
    a1.loglog(lr2.step_idx, _floor(lr2.err_deg), "s-", label="imu_dcm trapezoid, error")
    a1.loglog(nd.step_idx, _floor(nd.err_deg), "^-", label="plain 3x3 DCM loop (end rule), error")
    a1.set_xlabel("steps (1000 Hz)")
    a1.set_ylabel("attitude error, deg")
    a1.set_title("Error against truth (coning β = 1°, 0.5 Hz)")
    a1.legend(fontsize=8)
    a2.loglog(
        lr.step_idx,
        _floor(lr.orthonormality, 1e-17),
        "o-",
        label="imu_dcm magnus4 (unit quaternion)",
    )
    a2.loglog(
        nd.step_idx,
        _floor(nd.orthonormality, 1e-17),
        "^-",
        label="plain 3x3 DCM loop, no re-orthonormalisation",
    )
    a2.loglog(nd.step_idx, nd.step_idx * _EPS, "k:", label="N·ε (linear roundoff)")
    a2.loglog(nd.step_idx, np.sqrt(nd.step_idx) * _EPS, "k--", label="√N·ε (random walk)")
    a2.set_xlabel("steps")
    a2.set_ylabel("max |RᵀR − I| (exact 0 plotted at 1e-17)")
    a2.set_title("Orthonormality")
    a2.legend(fontsize=8)
    fig.suptitle(f"Scene 4: long runs, up to {n_long:.0e} steps")
    fig.tight_layout()
    save_figure(fig, out / "stability_long_run.png", dpi=110)
    plt.close(fig)
    md += [
        "### 4. Long runs (chart `stability_long_run.png`)",
        "",
        (
            f"Coning β = 1°, 0.5 Hz, 1000 Hz, {n_long:.0e} steps ({n_long / 1000:.0f} s), batch "
            "integrator in chunks of 10⁶: "
            f"magnus4 final error {_fmt(lr.err_deg[-1])}°, trapezoid {_fmt(lr2.err_deg[-1])}°, "
            f"max |RᵀR − I| {_fmt(lr.orthonormality.max())}. The plain 3x3 DCM loop "
            f"without re-orthonormalisation after {n_naive:.0e} steps: |RᵀR − I| = "
            f"{_fmt(nd.orthonormality[-1])}, error {_fmt(nd.err_deg[-1])}°."
        ),
        "",
    ]
    return md


def _scene_free_box(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 5. free box: chart and markdown lines."""
    md: list[str] = []
    progress("stability 5/8: free box, intermediate-axis flips")
    fb_rates = (20.0, 100.0) if quick else (20.0, 50.0, 100.0, 1000.0)
    fbs = {r: free_box(r) for r in fb_rates}
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.6))
    f1 = fbs[100.0]
    a1.plot(f1.t_s, f1.y_along_l, "k-", label="body y along L (truth, I2 ω2/|L|)")
    a1.set_xlabel("time, s")
    a1.set_ylabel("ŷ_b · L̂")
    a1.set_title(f"Flips: {f1.flips_true} in 30 s (ω0 = (0.05, 3, 0.05) rad/s)")
    a1.legend(fontsize=8)
    for m in DCM_METHODS:
        a2.semilogy(
            f1.t_s,
            _floor(f1.l_drift_deg[m]),
            marker=_MARKERS[m],
            markevery=300,
            ms=4,
            label=_LABELS[m],
        )
    a2.set_xlabel("time, s")
    a2.set_ylabel("drift of world angular momentum direction, deg")
    a2.set_title("Conservation of L_w, 100 Hz")
    a2.legend(fontsize=8)
    fig.suptitle("Scene 5: free box (2 × 1.5 × 1 m) about its intermediate axis")
    fig.tight_layout()
    save_figure(fig, out / "stability_free_box.png", dpi=110)
    plt.close(fig)
    md += [
        "### 5. Free box, intermediate axis (chart `stability_free_box.png`)",
        "",
        (
            "Max drift of the world angular-momentum direction over 30 s, deg (a conservation "
            "law: exact attitude gives 0), and flips seen (truth: "
            f"{fbs[fb_rates[0]].flips_true}):"
        ),
        "",
        "| rate, Hz | " + " | ".join(DCM_METHODS) + " |",
        "|---" * (len(DCM_METHODS) + 1) + "|",
    ]
    for r, f in fbs.items():
        md.append(
            f"| {r:.0f} | "
            + " | ".join(f"{_fmt(f.l_drift_deg[m].max())} ({f.flips_est[m]})" for m in DCM_METHODS)
            + " |"
        )
    md.append("")
    return md


def _scene_tops(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 6. tops: chart and markdown lines."""
    md: list[str] = []
    progress("stability 6/8: sleeping top and fast top at high spin")
    top_rates = (200.0, 1000.0, 5000.0) if quick else (200.0, 500.0, 1000.0, 2000.0, 5000.0)
    tops = [
        steady_top("sleeping", 100.0, top_rates),
        steady_top("fast", 20.0, top_rates),
        steady_top("fast", 100.0, top_rates),
        steady_top("slow", 100.0, top_rates),
    ]
    fig, axes = plt.subplots(1, len(tops), figsize=(16, 4.8), sharey=True)
    for ax, tp in zip(axes, tops, strict=True):
        for m, e in tp.err_deg.items():
            ax.loglog(tp.rates_hz, _floor(e), marker=_MARKERS[m], label=_LABELS[m])
        ax.set_xlabel("sample rate, Hz")
        ax.set_xticks(tp.rates_hz, [f"{r:g}" for r in tp.rates_hz])
        ax.minorticks_off()
        ax.set_title(
            f"{tp.kind} top, spin {tp.spin_hz:g} Hz\n"
            f"precession dφ/dt = {tp.precession_rad_s:.3g} rad/s"
        )
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("max attitude error over 1 s, deg (NaN → 180)")
    h, lab = axes[0].get_legend_handles_labels()
    fig.legend(h, lab, loc="lower center", ncol=4, fontsize=8)
    fig.suptitle("Scene 6: heavy top, sleeping and steady precession (closed-form truth)")
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    save_figure(fig, out / "stability_tops.png", dpi=110)
    plt.close(fig)
    tm = list(tops[0].err_deg)
    md += [
        "### 6. Sleeping top and fast top (chart `stability_tops.png`)",
        "",
        (
            "Max total error over 1 s, deg (180 = the method produced NaN). In steady "
            "precession the Euler-angle rates are constant, so Euler-angle integration is exact "
            "there (roundoff only); the sleeping top sits on its singularity θ = 0. Spin 100 Hz "
            "sampled at 200 Hz is |ω| dt ≈ π per step."
        ),
        "",
        "| top | rate, Hz | " + " | ".join(tm) + " |",
        "|---" * (len(tm) + 2) + "|",
    ]
    for tp in tops:
        for k, r in enumerate(tp.rates_hz):
            md.append(
                f"| {tp.kind}, {tp.spin_hz:g} Hz spin | {r:.0f} | "
                + " | ".join(_fmt(tp.err_deg[m][k]) for m in tm)
                + " |"
            )
    md.append("")
    return md


def _scene_noise(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 7. noise: chart and markdown lines."""
    md: list[str] = []
    progress("stability 7/8: noise and bias growth laws")
    ng = noise_growth(n_seeds=50 if quick else 200)
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.loglog(ng.t_s, ng.white_rms_deg, "o", label=f"white noise, RMS of {ng.n_seeds} seeds")
    ax.loglog(ng.t_s, ng.white_law_deg, "k--", label="N √(3T)")
    ax.loglog(ng.t_s, ng.bias_deg, "s", label="constant bias")
    ax.loglog(ng.t_s, ng.bias_law_deg, "k:", label="|b| T")
    ax.set_xlabel("integration time T, s")
    ax.set_ylabel("attitude error, deg")
    ax.set_title(
        f"Scene 7: N = 1e-3 rad/s/√Hz, |b| = 3e-4 rad/s, 100 Hz\n"
        f"fitted exponents {ng.white_exponent:.3f} (white), {ng.bias_exponent:.3f} (bias)"
    )
    ax.legend()
    fig.tight_layout()
    save_figure(fig, out / "stability_noise.png", dpi=110)
    plt.close(fig)
    md += [
        "### 7. Noise and bias (chart `stability_noise.png`)",
        "",
        (
            f"Gyro at rest, 100 Hz, 100 s: white noise error grows as T^{ng.white_exponent:.3f} "
            f"(law 0.5; RMS of {ng.n_seeds} seeds), bias error as T^{ng.bias_exponent:.3f} "
            "(law 1)."
        ),
        "",
    ]
    return md


def _scene_truncated(out: Path, quick: bool, progress: Callable[[str], None], plt) -> list[str]:
    """Scene 8. truncated: chart and markdown lines."""
    md: list[str] = []
    progress("stability 8/8: first-order truncated updates vs exact exponential")
    tr = truncated_update()
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.loglog(tr.step_rad, _floor(tr.truncated_err_deg), "x-", label="truncated, normalised")
    ax.loglog(
        tr.step_rad, _floor(tr.predicted_deg), "k--", label="n (|ω|dt − 2 atan(|ω|dt/2)) (analytic)"
    )
    ax.loglog(tr.step_rad, _floor(tr.exact_err_deg), "o-", label="exact exponential (imu_dcm end)")
    ax.set_xlabel("step |ω| dt, rad")
    ax.set_ylabel(f"error after {tr.n_steps} steps, deg")
    ax.set_title("Scene 8: fixed-axis spin, truncated first-order step vs exact exp")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, out / "stability_truncated.png", dpi=110)
    plt.close(fig)
    md += [
        "### 8. Truncated first-order update (chart `stability_truncated.png`)",
        "",
        f"Fixed-axis spin, {tr.n_steps} steps; error, deg, and |q| without normalisation:",
        "",
        "| \\|ω\\| dt, rad | truncated | analytic | exact exp | unnormalised \\|q\\| |",
        "|---|---|---|---|---|",
    ]
    for k, s in enumerate(tr.step_rad):
        md.append(
            f"| {s:.3g} | {_fmt(tr.truncated_err_deg[k])} | {_fmt(tr.predicted_deg[k])} "
            f"| {_fmt(tr.exact_err_deg[k])} | {_fmt(tr.unnormalised_norm[k])} |"
        )
    md.append("")
    return md


_SCENES = (
    _scene_gimbal_lock,
    _scene_rotvec_sum,
    _scene_large_steps,
    _scene_long_run,
    _scene_free_box,
    _scene_tops,
    _scene_noise,
    _scene_truncated,
)


def run(
    out_dir: str | Path, quick: bool = False, progress: Callable[[str], None] = print
) -> list[str]:
    """Run all eight scenes, write ``stability_*.png`` into ``out_dir``; return markdown lines.

    ``quick`` uses fewer points and 10⁶ instead of 10⁷ steps in the long run.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    md: list[str] = ["## Stability scenes", ""]
    for scene in _SCENES:
        md += scene(out, quick, progress, plt)
    return md
