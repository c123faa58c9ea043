"""Noise study report: the chart ``noise_study.png`` and the markdown tables.

The figures come from :mod:`benchmarks.noise_study` (``run`` calls :func:`plot` and
:func:`markdown` with what it measured, in the records of :mod:`benchmarks.noise_cases`); the
chart's panel (c) draws a heavy-top excerpt from :func:`example_series`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from benchmarks.noise_cases import (
    COLORS,
    EULER_MODES,
    EULER_TORQUE_NOISE,
    MODES,
    SCENES,
    BroadResult,
    Condition,
    att_err_deg,
)
from imu_dcm.gyro.prefilter import PrefilterConfig, prefilter
from imu_dcm.outputs import save_figure

__all__ = ["example_series", "markdown", "plot"]


def example_series(quick: bool) -> dict:
    """A heavy-top excerpt for the chart's panel (c)."""
    import data_synth

    out = {}
    scene, params, _, _ = SCENES["heavy top, cusp"]
    traj = data_synth.simulate(scene, duration_s=2.0, **params)
    density = 1e-3
    rec = data_synth.synthetic_gyro(
        traj, 1000.0, model=data_synth.GyroModel(noise_density_rad_s_sqrt_hz=density), seed=0
    )
    q_true, w_true = traj.at(rec.t_s)
    res_k = prefilter(
        rec.values, rec.t_s, "kalman", PrefilterConfig(noise_density_rad_s_sqrt_hz=density)
    )
    rates = {
        "none": rec.values,
        "kalman": res_k.omega_b,
        "rts": prefilter(rec.values, rec.t_s, "rts", res_k.config).omega_b,
    }
    sel = (rec.t_s >= 1.0) & (rec.t_s <= 1.1)
    clean = {
        m: prefilter(w_true, rec.t_s, m, res_k.config).omega_b[sel, 0] for m in ("kalman", "rts")
    }
    out["top"] = {
        "t": rec.t_s[sel],
        "truth": w_true[sel, 0],
        "density": density,
        "sigma": density * math.sqrt(1000.0),
        "clean": clean,
        "att": {m: att_err_deg(rates[m], rec.t_s, q_true) for m in MODES},
        "t_all": rec.t_s,
    }
    return out


def plot(
    conds: list[Condition], quant: list[Condition], broad: list[BroadResult], ex: dict, path: Path
) -> None:
    """The 2x2 chart: (a) rate gained against attitude paid, (b) the free box's error over time,
    (c) what the filters do to fast motion, (d) BROAD."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 2, figsize=(14, 10.5))
    _plot_tradeoff(axs[0, 0], conds, quant)
    _plot_box(axs[0, 1], conds)
    _plot_fast_motion(axs[1, 0], ex["top"])
    _plot_broad(axs[1, 1], broad)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def _plot_tradeoff(ax, conds: list[Condition], quant: list[Condition]) -> None:
    """(a) what the rate gains against what the attitude pays, per condition and mode."""
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter

    markers = dict(zip(SCENES, ["o", "s", "^", "D"], strict=True))
    for c in conds + quant:
        raw = c.modes["none"]
        for m in [k for k in c.modes if k != "none"]:
            s = c.modes[m]
            ax.scatter(
                raw.rate_rms_rad_s / s.rate_rms_rad_s,
                s.att_rms_deg / raw.att_rms_deg,
                marker=markers[c.scene],
                s=30 + 25 * math.log10(c.density / 1e-5),
                facecolors=COLORS[m] if c in conds else "none",
                edgecolors=COLORS[m],
                alpha=0.8,
                linewidths=1.2,
            )
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhspan(0.95, 1.05, color="#1b9e77", alpha=0.08)
    ax.set_xscale("log")
    ax.set_yscale("log")
    fmt = FuncFormatter(lambda v, _: f"{v:g}")
    ax.yaxis.set_major_formatter(fmt)
    ax.yaxis.set_minor_formatter(fmt)
    ax.xaxis.set_major_formatter(fmt)
    ax.tick_params(axis="y", which="minor", labelsize=7)
    ax.set_xlabel("rate error cut: raw RMS / filtered RMS  (higher = better rate)")
    ax.set_ylabel("attitude error RMS, filtered / none  (lower = better attitude)")
    ax.set_title(
        "(a) synthetic: rate gained vs attitude paid; colour = mode (euler = model-\n"
        "based, free box), marker = scene, size = noise density, hollow = quantized"
    )
    handles = [
        Line2D([], [], ls="", marker="o", color=COLORS[m], label=m)
        for m in ("kalman", "rts") + EULER_MODES
    ]
    handles += [Line2D([], [], ls="", marker=markers[s], color="gray", label=s) for s in SCENES]
    ax.legend(handles=handles, fontsize=8, loc="upper right")
    ax.grid(True, which="both", alpha=0.3)


def _plot_box(ax, conds: list[Condition]) -> None:
    """(b) the attitude random walk is not removed by a unity-gain low-pass."""
    box = next(
        c
        for c in conds
        if c.scene.startswith("free box") and c.density == 1e-2 and c.rate_hz == 1000.0
    )
    for m, err in box.att_rms_series_deg.items():
        ax.plot(
            box.t_s,
            err,
            color=COLORS[m],
            lw=1.4,
            label=m + (" (model-based, knows the inertia)" if m.startswith("euler") else ""),
        )
    env = np.degrees(box.density * np.sqrt(3 * box.t_s))
    ax.plot(box.t_s, env, "k--", lw=1, label="ARW, expected RMS N·√(3t)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("attitude error (deg, total)")
    ax.set_title(
        f"(b) free box, N = {box.density:g} rad/s/√Hz, 1000 Hz, RMS over {box.seeds} "
        "seed(s):\nrts leaves the angle random walk, kalman adds lag error"
    )
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)


def _plot_fast_motion(ax, tp: dict) -> None:
    """(c) what the filters do to fast motion: heavy top excerpt, errors on the exact rates."""
    ax.plot(tp["t"], tp["truth"] / 1000.0, color="#bbbbbb", lw=3, label="truth ω_x / 1000")
    ax.axhspan(
        -tp["sigma"], tp["sigma"], color=COLORS["none"], alpha=0.08, label="raw gyro noise ±1σ"
    )
    for m in ("kalman", "rts"):
        error = tp["clean"][m] - tp["truth"]
        ax.plot(tp["t"], error, color=COLORS[m], lw=1.8, label=f"{m} error")
    att = {m: float(np.sqrt(np.mean(tp["att"][m] ** 2))) for m in MODES}
    ax.set_xlabel("t (s)")
    ax.set_ylabel("ω_x error, body (rad/s)")
    ax.set_title(
        f"(c) heavy top, 1000 Hz, filters tuned for N = {tp['density']:g}, on exact "
        "rates\nattitude RMS (noisy, 2 s): " + ", ".join(f"{m} {att[m]:.3f}°" for m in MODES)
    )
    ax.legend(fontsize=8, loc="lower left", ncol=2)
    ax.grid(True, alpha=0.3)


def _plot_broad(ax, broad: list[BroadResult]) -> None:
    """(d) BROAD: the change of the attitude error against no filtering, per trial."""
    if not broad:
        ax.text(0.5, 0.5, "BROAD bags not found", ha="center", va="center")
        ax.set_axis_off()
        return
    x = np.arange(len(broad))
    for j, m in enumerate(("kalman", "rts")):
        d = [1e3 * (r.att_rms_deg[m] - r.att_rms_deg["none"]) for r in broad]
        ax.bar(x + (j - 0.5) * 0.38, d, 0.38, color=COLORS[m], label=f"{m} − none")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(x, [f"{r.trial[:2]}\nnone {r.att_rms_deg['none']:.2f}°" for r in broad])
    ax.set_xlabel("BROAD trial")
    ax.set_ylabel("change of attitude RMS vs none (millidegrees)")
    ax.set_title(
        "(d) BROAD bags: gyro-only from the first truth sample, rest bias removed;\n"
        "noise and process noise estimated from each log"
    )
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)


def _fmt(x: float, nd: int = 3) -> str:
    if not math.isfinite(x):
        return "–"
    return f"{x:.{nd}g}"


def _modes(value, modes: tuple[str, ...], nd: int = 3) -> str:
    """``value(m)`` of each mode, formatted, joined by `` / ``."""
    return " / ".join(_fmt(value(m), nd) for m in modes)


def _table(intro: str, header: str, rows: list[str]) -> list[str]:
    """A markdown section: the introduction, the table (its separator from the header), a blank
    line."""
    sep = "|" + "---|" * header.count(" |")
    return [intro, "", header, sep, *rows, ""]


def markdown(
    conds: list[Condition],
    quant: list[Condition],
    broad: list[BroadResult],
    spd: dict[str, float],
    command: str,
    elapsed_s: float,
) -> list[str]:
    """The study's markdown: the synthetic table, the no-rest table, the model-based table (when
    run), BROAD (when found) and the speed, as lines."""
    md = [
        "## Noise study: pre-filtering gyro rates (none / kalman / rts)",
        "",
        f"Generated by `{command}` in {elapsed_s:.0f} s. Chart: `noise_study.png`.",
        "",
    ]
    md += _synthetic_table(conds, quant) + _no_rest_table(conds) + _euler_table(conds)
    if broad:
        md += _broad_table(broad)
    if spd:
        md += _table(
            "Pre-filter speed (60 000 samples x 3 axes at 285.7 Hz, one BLAS thread, median of "
            "interleaved rounds):",
            "| case | ns / sample |",
            [f"| {k} | {v:,.0f} |" for k, v in spd.items()],
        )
    return md


def _synthetic_table(conds: list[Condition], quant: list[Condition]) -> list[str]:
    rows = []
    for c in conds + quant:
        s = c.modes
        name = c.scene + (" (quantized 0.061 °/s)" if c in quant else "")
        rows.append(
            f"| {name} | {_fmt(c.density)} | {c.rate_hz:g} | {_fmt(c.accel_rad_s2)} | "
            + _modes(lambda m, s=s: s[m].rate_rms_rad_s, MODES)
            + " | "
            + _modes(lambda m, s=s: s[m].distortion_rate_rms_rad_s, ("kalman", "rts"))
            + " | "
            + " / ".join(f"{s[m].lag_samples:+.2f}" for m in ("kalman", "rts"))
            + " | "
            + _modes(lambda m, s=s: s[m].att_rms_deg, MODES)
            + " | "
            + _modes(lambda m, s=s: s[m].att_max_deg, MODES)
            + " | "
            + _modes(lambda m, s=s: s[m].distortion_att_rms_deg, MODES)
            + " |"
        )
    return _table(
        "Synthetic scenes (data_synth truth, white noise of density N, seeds pooled; quantized "
        "rows: no noise, 0.061 °/s steps, N = step/√12/√rate). Errors are RMS over time; "
        "'distortion' = the same filter (same fitted σ_α) run on the exact rates: what it does "
        "to the signal alone (for `none` the attitude distortion is the integrator's own "
        "error); lag in samples from regressing the rate error on ω̇ (+ = late).",
        "| scene | N rad/s/√Hz | Hz | σ_α fit rad/s² | rate RMS none / kalman / rts (rad/s) | "
        "distortion rate RMS kalman / rts (rad/s) | lag kalman / rts (samples) | "
        "attitude RMS none / kalman / rts (°) | attitude max none / kalman / rts (°) | "
        "distortion attitude RMS none / kalman / rts (°) |",
        rows,
    )


def _no_rest_table(conds: list[Condition]) -> list[str]:
    rows = []
    for c in conds:
        raw = c.modes["none"]
        rows.append(
            f"| {c.scene} | {_fmt(c.density)} | {c.rate_hz:g} | "
            f"{c.noise_est_rad_s_sqrt_hz / c.density:.3f} | "
            f"{raw.rate_rms_rad_s / c.rts_est_rate_rms_rad_s:.2f}x | "
            f"{c.rts_est_att_rms_deg / raw.att_rms_deg:.3f} |"
        )
    return _table(
        'Nothing given (`prefilter(..., "rts")` with no parameters, as `--prefilter rts` '
        "without `--gyro-noise-density`): these scenes never rest, so the noise density "
        "comes from the upper band of the log's spectrum; rts then runs with it. Rate cut = "
        "raw rate RMS / rts rate RMS; attitude ratio = rts attitude RMS / raw attitude RMS "
        "(< 1: better):",
        "| scene | N rad/s/√Hz | Hz | N estimated / N | rate cut | attitude ratio |",
        rows,
    )


def _euler_table(conds: list[Condition]) -> list[str]:
    with_euler = [c for c in conds if all(m in c.modes for m in EULER_MODES)]
    if not with_euler:
        return []
    order = ("none", "rts") + EULER_MODES
    rows = [
        f"| {c.scene} | {_fmt(c.density)} | {c.rate_hz:g} | "
        + _modes(lambda m, c=c: c.modes[m].rate_rms_rad_s, order)
        + " | "
        + _modes(lambda m, c=c: c.modes[m].att_rms_deg, order)
        + " |"
        for c in with_euler
    ]
    return _table(
        "Model-based (stretch): `euler_prefilter`, filterpy UKF / unscented RTS with "
        "Euler's equations and the box's inertia, told an unmodelled torque of "
        f"{EULER_TORQUE_NOISE:g} N·m/√Hz (the box is torque-free), same data as above:",
        "| scene | N rad/s/√Hz | Hz | rate RMS none / rts / euler-kalman / euler-rts "
        "(rad/s) | attitude RMS none / rts / euler-kalman / euler-rts (°) |",
        rows,
    )


def _broad_table(broad: list[BroadResult]) -> list[str]:
    rows = []
    for r in broad:
        s = r.summary
        rows.append(
            f"| {r.trial} | {', '.join(f'{v:.3g}' for v in s['angle_random_walk_deg_sqrt_h'])}"
            f" | {', '.join(f'{v:.3g}' for v in s['bias_instability_deg_h'])} | "
            f"{_fmt(s['angular_accel_rad_s2'])} | {s['stationary_rate_std_rad_s']:.3g} / "
            f"{s['raw_rate_std_rad_s']:.3g} | "
            + _modes(r.att_rms_deg.get, MODES, 5)
            + " | "
            + _modes(r.att_max_deg.get, MODES, 5)
            + " | "
            + _modes(r.rate_change_rms_rad_s.get, ("kalman", "rts"))
            + " |"
        )
    return _table(
        "BROAD bags (rest bias removed; noise density from the Allan deviation of the "
        "first rest, process noise by maximum likelihood; attitude error over the movement "
        "phases against the optical truth):",
        "| trial | ARW °/√h (x, y, z) | bias instability °/h (x, y, z) | σ_α fit rad/s² | "
        "filtered rate std / raw (rad/s) | attitude RMS none / kalman / rts (°) | "
        "attitude max none / kalman / rts (°) | RMS change of the rate kalman / rts "
        "(rad/s) |",
        rows,
    )
