"""Noise study: when does Kalman pre-filtering (or RTS smoothing) of gyro rates help?

``python -m benchmarks.noise_study --out DIR [--quick]`` (also ``run(out_dir, quick)`` from
``python -m benchmarks``) writes ``noise_study.png`` and ``noise_study.md`` into ``DIR``.

What is measured, for the pre-filter modes ``none`` / ``kalman`` / ``rts`` of
:func:`imu_dcm.prefilter.prefilter` (noise density given = the simulated one, process noise by
maximum likelihood), with the attitude integrated by ``imu_dcm.integrate`` (magnus4) from the
true initial attitude:

* **Synthetic** (data_synth truth, white rate noise from ``data_synth.synthetic_gyro``, seeded):
  heavy top (cusp), free box about its intermediate axis, coning at 1 Hz and 5 Hz; noise
  densities 1e-4, 1e-3, 1e-2 rad/s/√Hz; 200 and 1000 Hz. Rate error RMS (rad/s), attitude
  error RMS and max (deg, total angle), the lag (samples, from regressing the rate error on the
  true angular acceleration: ``e ≈ −lag · ω̇``), and the attitude error the filter causes on
  *noise-free* rates (its signal distortion alone).
* **Quantization**: a noise-free gyro quantized to 0.061 °/s steps (a common MEMS LSB); the
  filter is told the quantization noise ``q / √12`` as a white density.
* **BROAD** (real recordings, ../shared/data/broad): the rest-bias (``imu_dcm.replay.bias``) is
  removed first, the same for every mode; noise density and process noise are estimated from the
  log; attitude error against the optical truth over the movement phases.
* **Speed** of the pre-filter on a BROAD-sized record (60 000 samples x 3 axes).

Conventions: ``omega_b`` body rate relative to the world in body axes, rad/s; quaternions
``[x, y, z, w]``, ``q_w_b`` body to world; ``t_s`` seconds.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.integrate import integrate
from imu_dcm.metrics import attitude_error_deg
from imu_dcm.prefilter import PrefilterConfig, euler_prefilter, prefilter

MODES = ("none", "kalman", "rts")
#: model-based modes (``euler_prefilter``), run on the free box only (its inertia is known)
EULER_MODES = ("euler-kalman", "euler-rts")
#: unmodelled-torque density told to the model-based filter, N·m/√Hz (the box is torque-free)
EULER_TORQUE_NOISE = 1e-4
#: scene label -> (data_synth scene, parameters, duration s, quick duration s)
SCENES: dict[str, tuple[str, dict, float, float]] = {
    "heavy top, cusp": ("heavy-top", {"motion": "cusp"}, 4.0, 2.0),
    "free box, intermediate axis": ("free-body", {"case": "intermediate"}, 20.0, 10.0),
    "coning 10°, 1 Hz": ("coning", {"half_angle_deg": 10.0, "freq_hz": 1.0}, 10.0, 5.0),
    "coning 10°, 5 Hz": ("coning", {"half_angle_deg": 10.0, "freq_hz": 5.0}, 10.0, 5.0),
}
DENSITIES = (1e-4, 1e-3, 1e-2)
RATES_HZ = (200.0, 1000.0)
QUANT_STEP_RAD_S = math.radians(0.061)
BROAD_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"
COLORS = {
    "none": "#444444",
    "kalman": "#d95f02",
    "rts": "#1b9e77",
    "euler-kalman": "#e7298a",
    "euler-rts": "#7570b3",
}


@dataclass(frozen=True)
class ModeStats:
    """Pooled figures of one pre-filter mode in one condition (over seeds)."""

    rate_rms_rad_s: float
    att_rms_deg: float
    att_max_deg: float
    lag_samples: float
    distortion_rate_rms_rad_s: float  # rate error when the same filter runs on the exact rates
    distortion_att_rms_deg: float  # attitude error from the exact rates through the same filter


@dataclass(frozen=True)
class Condition:
    scene: str
    density: float
    rate_hz: float
    seeds: int
    accel_rad_s2: float
    modes: dict[str, ModeStats]
    t_s: NDArray  # sample times of the seeds' common grid, s
    att_rms_series_deg: dict[str, NDArray]  # attitude error RMS over the seeds at each t_s, deg


def _att_err_deg(omega_b: NDArray, t_s: NDArray, q_true: NDArray) -> NDArray:
    q = integrate(omega_b, t_s, q_true[0], "magnus4").as_quat()
    return attitude_error_deg(q, q_true).total_deg


def _lag_samples(err: NDArray, accel: NDArray, rate_hz: float) -> float:
    den = float(np.sum(accel * accel))
    return float(-np.sum(err * accel) / den * rate_hz) if den > 0 else float("nan")


def synthetic_condition(
    label: str,
    density: float,
    rate_hz: float,
    seeds: int,
    quick: bool = False,
    quantize: bool = False,
) -> Condition:
    """Run none / kalman / rts on one scene, noise density and rate, pooled over seeds."""
    import data_synth

    scene, params, dur, dur_quick = SCENES[label]
    traj = data_synth.simulate(scene, duration_s=dur_quick if quick else dur, **params)
    model = (
        data_synth.GyroModel(quantization_rad_s=QUANT_STEP_RAD_S)
        if quantize
        else data_synth.GyroModel(noise_density_rad_s_sqrt_hz=density)
    )
    euler = scene == "free-body" and not quantize and (rate_hz <= 200.0 or not quick)
    modes_here = MODES + (EULER_MODES if euler else ())
    acc: dict[str, dict[str, list[float]]] = {
        m: {k: [] for k in ModeStats.__dataclass_fields__} for m in modes_here
    }
    accels = []
    series: dict[str, list[NDArray]] = {}
    for seed in range(seeds):
        rec = data_synth.synthetic_gyro(traj, rate_hz, model=model, seed=seed)
        t = rec.t_s
        q_true, w_true = traj.at(t)
        w_dot = np.gradient(w_true, t, axis=0)
        att_ref = _att_err_deg(w_true, t, q_true)
        res_k = prefilter(
            rec.values, t, "kalman", PrefilterConfig(noise_density_rad_s_sqrt_hz=density)
        )
        cfg = res_k.config  # the fitted process noise, reused by rts and the noise-free runs
        accels.append(cfg.angular_accel_rad_s2)
        outs = {
            "none": rec.values,
            "kalman": res_k.omega_b,
            "rts": prefilter(rec.values, t, "rts", cfg).omega_b,
        }
        clean = {
            "none": w_true,
            "kalman": prefilter(w_true, t, "kalman", cfg).omega_b,
            "rts": prefilter(w_true, t, "rts", cfg).omega_b,
        }
        if euler:
            inertia = traj.params["inertia_kg_m2"]
            for m in EULER_MODES:
                outs[m] = euler_prefilter(
                    rec.values,
                    t,
                    inertia,
                    m.split("-")[1],
                    noise_density_rad_s_sqrt_hz=density,
                    torque_noise_n_m_sqrt_hz=EULER_TORQUE_NOISE,
                ).omega_b
                clean[m] = None  # not run on exact rates (costly); reported as "–"
        for m in modes_here:
            e = outs[m] - w_true
            a = _att_err_deg(outs[m], t, q_true)
            series.setdefault(m, []).append(a * a)
            d = (
                att_ref
                if m == "none"
                else _att_err_deg(clean[m], t, q_true)
                if clean[m] is not None
                else np.nan
            )
            acc[m]["rate_rms_rad_s"].append(float(np.mean(e * e)))
            acc[m]["att_rms_deg"].append(float(np.mean(a * a)))
            acc[m]["att_max_deg"].append(float(a.max()))
            acc[m]["lag_samples"].append(_lag_samples(e, w_dot, rate_hz))
            acc[m]["distortion_rate_rms_rad_s"].append(
                float(np.mean((clean[m] - w_true) ** 2)) if clean[m] is not None else np.nan
            )
            acc[m]["distortion_att_rms_deg"].append(float(np.mean(d * d)))
    modes = {}
    for m in modes_here:
        v = acc[m]
        modes[m] = ModeStats(
            rate_rms_rad_s=math.sqrt(np.mean(v["rate_rms_rad_s"])),
            att_rms_deg=math.sqrt(np.mean(v["att_rms_deg"])),
            att_max_deg=float(np.mean(v["att_max_deg"])),
            lag_samples=float(np.mean(v["lag_samples"])),
            distortion_rate_rms_rad_s=math.sqrt(np.mean(v["distortion_rate_rms_rad_s"])),
            distortion_att_rms_deg=math.sqrt(np.mean(v["distortion_att_rms_deg"])),
        )
    n = min(len(v) for a in series.values() for v in a)  # stamps may jitter in count
    rms_series = {m: np.sqrt(np.mean([v[:n] for v in a], axis=0)) for m, a in series.items()}
    return Condition(
        label, density, rate_hz, seeds, float(np.median(accels)), modes, t[:n], rms_series
    )


# ------------------------------------------------------------------------------------------------
# BROAD


@dataclass(frozen=True)
class BroadResult:
    trial: str
    n_samples: int
    summary: dict
    att_rms_deg: dict[str, float]
    att_max_deg: dict[str, float]
    rate_change_rms_rad_s: dict[str, float]  # |filtered - raw| RMS: how much the filter moved


def broad_trial(path: Path) -> BroadResult:
    """none / kalman / rts on one BROAD bag, rest bias removed first, errors over movement."""
    from imu_dcm.logio import read_log
    from imu_dcm.replay.bias import estimate_bias

    log = read_log(path)
    t_ns = log.imu.t_ns
    t = (t_ns - t_ns[0]) * 1e-9
    bias = estimate_bias(log.imu.omega_b, t, "auto").bias_b
    w = log.imu.omega_b - bias
    # the prefilter estimates its noise from the raw log's rest (bias included in the mean only)
    res_k = prefilter(log.imu.omega_b, t, "kalman")
    cfg = res_k.config
    outs = {
        "none": w,
        "kalman": prefilter(w, t, "kalman", cfg).omega_b,
        "rts": prefilter(w, t, "rts", cfg).omega_b,
    }
    # truth at IMU stamps (BROAD stamps both with the same sample index)
    idx = np.searchsorted(t_ns, log.truth.t_ns)
    ok = (idx < len(t_ns)) & (t_ns[np.minimum(idx, len(t_ns) - 1)] == log.truth.t_ns)
    idx, q_truth = idx[ok], log.truth.q_w_b[ok]
    intervals = json.loads(log.custom_data.get("broad.movement_intervals_index", "[]"))
    move = np.zeros(len(t_ns), bool)
    for a, b in intervals:
        move[a : b + 1] = True
    i0 = int(idx[0])
    sel = move[idx]
    att_rms, att_max, change = {}, {}, {}
    for m in MODES:
        q = integrate(outs[m][i0:], t[i0:], q_truth[0], "magnus4").as_quat()
        err = attitude_error_deg(q[idx[sel] - i0], q_truth[sel]).total_deg
        att_rms[m] = float(np.sqrt(np.mean(err * err)))
        att_max[m] = float(err.max())
        change[m] = float(np.sqrt(np.mean((outs[m] - w) ** 2)))
    return BroadResult(path.name, len(t), res_k.summary, att_rms, att_max, change)


# ------------------------------------------------------------------------------------------------
# speed


def speed(n: int = 60_000, rounds: int = 3) -> dict[str, float]:
    """ns per sample (3 axes) of the pre-filter on a 285.7 Hz record of n samples."""
    from benchmarks.timing import interleaved_medians, single_thread

    rng = np.random.default_rng(0)
    t = np.arange(n) / 285.714
    w = np.stack([np.sin(t), np.cos(0.7 * t), np.sin(1.3 * t)], axis=1)
    z = w + 0.002 * rng.standard_normal((n, 3))
    given = PrefilterConfig(noise_density_rad_s_sqrt_hz=1.2e-4, angular_accel_rad_s2=50.0)
    fit = PrefilterConfig(noise_density_rad_s_sqrt_hz=1.2e-4)
    t_j = t + rng.uniform(-2e-4, 2e-4, n)  # jittered stamps: no stationary shortcut
    cases = {
        "kalman, parameters given": (lambda: prefilter(z, t, "kalman", given), n),
        "rts, parameters given": (lambda: prefilter(z, t, "rts", given), n),
        "rts, process noise fitted (ML)": (lambda: prefilter(z, t, "rts", fit), n),
        "rts, jittered stamps": (lambda: prefilter(z, t_j, "rts", given), n),
        "kalman via filterpy (reference), 3000 samples": (
            lambda: prefilter(z[:3000], t[:3000], "kalman", given, engine="filterpy"),
            3000,
        ),
    }
    with single_thread():
        res = interleaved_medians(cases, rounds=rounds)
    return {k: v.ns_per_item for k, v in res.items()}


# ------------------------------------------------------------------------------------------------
# chart and tables


def _example_series(quick: bool) -> dict:
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
        "att": {m: _att_err_deg(rates[m], rec.t_s, q_true) for m in MODES},
        "t_all": rec.t_s,
    }
    return out


def plot(
    conds: list[Condition], quant: list[Condition], broad: list[BroadResult], ex: dict, path: Path
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 2, figsize=(14, 10.5))
    # (a) what the rate gains against what the attitude pays
    ax = axs[0, 0]
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
    from matplotlib.ticker import FuncFormatter

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
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], ls="", marker="o", color=COLORS[m], label=m)
        for m in ("kalman", "rts") + EULER_MODES
    ]
    handles += [Line2D([], [], ls="", marker=markers[s], color="gray", label=s) for s in SCENES]
    ax.legend(handles=handles, fontsize=8, loc="upper right")
    ax.grid(True, which="both", alpha=0.3)
    # (b) the attitude random walk is not removed by a unity-gain low-pass
    ax = axs[0, 1]
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
    # (c) what the filters do to fast motion: heavy top excerpt, errors on the exact rates
    ax = axs[1, 0]
    tp = ex["top"]
    ax.plot(tp["t"], tp["truth"] / 1000.0, color="#bbbbbb", lw=3, label="truth ω_x / 1000")
    ax.axhspan(
        -tp["sigma"], tp["sigma"], color=COLORS["none"], alpha=0.08, label="raw gyro noise ±1σ"
    )
    ax.plot(
        tp["t"],
        tp["clean"]["kalman"] - tp["truth"],
        color=COLORS["kalman"],
        lw=1.8,
        label="kalman error",
    )
    ax.plot(
        tp["t"], tp["clean"]["rts"] - tp["truth"], color=COLORS["rts"], lw=1.8, label="rts error"
    )
    att = {m: float(np.sqrt(np.mean(tp["att"][m] ** 2))) for m in MODES}
    ax.set_xlabel("t (s)")
    ax.set_ylabel("ω_x error, body (rad/s)")
    ax.set_title(
        f"(c) heavy top, 1000 Hz, filters tuned for N = {tp['density']:g}, on exact "
        "rates\nattitude RMS (noisy, 2 s): " + ", ".join(f"{m} {att[m]:.3f}°" for m in MODES)
    )
    ax.legend(fontsize=8, loc="lower left", ncol=2)
    ax.grid(True, alpha=0.3)
    # (d) BROAD: differences to no filtering
    ax = axs[1, 1]
    if broad:
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
    else:
        ax.text(0.5, 0.5, "BROAD bags not found", ha="center", va="center")
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fmt(x: float, nd: int = 3) -> str:
    if not math.isfinite(x):
        return "–"
    return f"{x:.{nd}g}"


def markdown(
    conds: list[Condition],
    quant: list[Condition],
    broad: list[BroadResult],
    spd: dict[str, float],
    command: str,
    elapsed_s: float,
) -> list[str]:
    md = [
        "## Noise study: pre-filtering gyro rates (none / kalman / rts)",
        "",
        f"Generated by `{command}` in {elapsed_s:.0f} s. Chart: `noise_study.png`.",
        "",
        (
            "Synthetic scenes (data_synth truth, white noise of density N, seeds pooled; quantized "
            "rows: no noise, 0.061 °/s steps, N = step/√12/√rate). Errors are RMS over time; "
            "'distortion' = the same filter (same fitted σ_α) run on the exact rates: what it does "
            "to the signal alone (for `none` the attitude distortion is the integrator's own "
            "error); lag in samples from regressing the rate error on ω̇ (+ = late)."
        ),
        "",
        (
            "| scene | N rad/s/√Hz | Hz | σ_α fit rad/s² | rate RMS none / kalman / rts (rad/s) | "
            "distortion rate RMS kalman / rts (rad/s) | lag kalman / rts (samples) | "
            "attitude RMS none / kalman / rts (°) | attitude max none / kalman / rts (°) | "
            "distortion attitude RMS none / kalman / rts (°) |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in conds + quant:
        s = c.modes
        name = c.scene + (" (quantized 0.061 °/s)" if c in quant else "")
        md.append(
            f"| {name} | {_fmt(c.density)} | {c.rate_hz:g} | {_fmt(c.accel_rad_s2)} | "
            + " / ".join(_fmt(s[m].rate_rms_rad_s) for m in MODES)
            + " | "
            + " / ".join(_fmt(s[m].distortion_rate_rms_rad_s) for m in ("kalman", "rts"))
            + " | "
            + " / ".join(f"{s[m].lag_samples:+.2f}" for m in ("kalman", "rts"))
            + " | "
            + " / ".join(_fmt(s[m].att_rms_deg) for m in MODES)
            + " | "
            + " / ".join(_fmt(s[m].att_max_deg) for m in MODES)
            + " | "
            + " / ".join(_fmt(s[m].distortion_att_rms_deg) for m in MODES)
            + " |"
        )
    md.append("")
    with_euler = [c for c in conds if all(m in c.modes for m in EULER_MODES)]
    if with_euler:
        md += [
            (
                "Model-based (stretch): `euler_prefilter`, filterpy UKF / unscented RTS with "
                "Euler's equations and the box's inertia, told an unmodelled torque of "
                f"{EULER_TORQUE_NOISE:g} N·m/√Hz (the box is torque-free), same data as above:"
            ),
            "",
            (
                "| scene | N rad/s/√Hz | Hz | rate RMS none / rts / euler-kalman / euler-rts "
                "(rad/s) | attitude RMS none / rts / euler-kalman / euler-rts (°) |"
            ),
            "|---|---|---|---|---|",
        ]
        order = ("none", "rts") + EULER_MODES
        for c in with_euler:
            md.append(
                f"| {c.scene} | {_fmt(c.density)} | {c.rate_hz:g} | "
                + " / ".join(_fmt(c.modes[m].rate_rms_rad_s) for m in order)
                + " | "
                + " / ".join(_fmt(c.modes[m].att_rms_deg) for m in order)
                + " |"
            )
        md.append("")
    if broad:
        md += [
            (
                "BROAD bags (rest bias removed; noise density from the Allan deviation of the "
                "first rest, process noise by maximum likelihood; attitude error over the movement "
                "phases against the optical truth):"
            ),
            "",
            (
                "| trial | ARW °/√h (x, y, z) | bias instability °/h (x, y, z) | σ_α fit rad/s² | "
                "filtered rate std / raw (rad/s) | attitude RMS none / kalman / rts (°) | "
                "attitude max none / kalman / rts (°) | RMS change of the rate kalman / rts "
                "(rad/s) |"
            ),
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in broad:
            s = r.summary
            md.append(
                f"| {r.trial} | {', '.join(f'{v:.3g}' for v in s['angle_random_walk_deg_sqrt_h'])}"
                f" | {', '.join(f'{v:.3g}' for v in s['bias_instability_deg_h'])} | "
                f"{_fmt(s['angular_accel_rad_s2'])} | {s['stationary_rate_std_rad_s']:.3g} / "
                f"{s['raw_rate_std_rad_s']:.3g} | "
                + " / ".join(_fmt(r.att_rms_deg[m], 5) for m in MODES)
                + " | "
                + " / ".join(_fmt(r.att_max_deg[m], 5) for m in MODES)
                + " | "
                + " / ".join(_fmt(r.rate_change_rms_rad_s[m]) for m in ("kalman", "rts"))
                + " |"
            )
        md.append("")
    if spd:
        md += [
            (
                "Pre-filter speed (60 000 samples x 3 axes at 285.7 Hz, one BLAS thread, median of "
                "interleaved rounds):"
            ),
            "",
            "| case | ns / sample |",
            "|---|---|",
        ]
        md += [f"| {k} | {v:,.0f} |" for k, v in spd.items()]
        md.append("")
    return md


def run(
    out_dir: str | Path, quick: bool = False, progress: Callable[[str], None] = print
) -> list[str]:
    """Run the whole study; write ``noise_study.png`` and ``noise_study.md``; return markdown."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    seeds = 1 if quick else 3
    densities = (1e-3, 1e-2) if quick else DENSITIES
    conds, quant = [], []
    for label in SCENES:
        for density in densities:
            for rate in RATES_HZ:
                progress(f"noise study: {label}, N = {density:g}, {rate:g} Hz")
                conds.append(synthetic_condition(label, density, rate, seeds, quick))
        q_density = QUANT_STEP_RAD_S / math.sqrt(12.0) / math.sqrt(1000.0)
        quant.append(synthetic_condition(label, q_density, 1000.0, 1, quick, quantize=True))
    ex = _example_series(quick)
    broad: list[BroadResult] = []
    if BROAD_DIR.is_dir():
        trials = sorted(p for p in BROAD_DIR.iterdir() if (p / "metadata.yaml").is_file())
        for p in trials[:2] if quick else trials:
            progress(f"noise study: BROAD {p.name}")
            broad.append(broad_trial(p))
    progress("noise study: speed")
    spd = speed(rounds=1 if quick else 3)
    plot(conds, quant, broad, ex, out / "noise_study.png")
    command = "python -m benchmarks.noise_study" + (" --quick" if quick else "") + " --out DIR"
    md = markdown(conds, quant, broad, spd, command, time.perf_counter() - t0)
    (out / "noise_study.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    progress(f"noise study: wrote {out / 'noise_study.png'} and noise_study.md")
    return md


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.noise_study",
        description="When does pre-filtering gyro rates help?",
    )
    parser.add_argument("--out", required=True, type=Path, help="output folder (created)")
    parser.add_argument("--quick", action="store_true", help="fewer conditions, one seed")
    args = parser.parse_args(argv)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(
            f"noise_study: Expected a writable output folder, got {args.out} ({exc.strerror})",
            file=sys.stderr,
        )
        return 2
    t0 = time.perf_counter()
    run(
        args.out,
        args.quick,
        progress=lambda s: print(f"[{time.perf_counter() - t0:6.1f} s] {s}", flush=True),
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
