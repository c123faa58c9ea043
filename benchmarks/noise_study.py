"""Noise study: when does Kalman pre-filtering (or RTS smoothing) of gyro rates help?

``python -m benchmarks.noise_study --out DIR [--quick]`` (also ``run(out_dir, quick)`` from
``python -m benchmarks``) writes ``noise_study.png`` and ``noise_study.md`` into ``DIR``; the
chart and the tables are drawn by :mod:`benchmarks.noise_report`.

What is measured, for the pre-filter modes ``none`` / ``kalman`` / ``rts`` of
:func:`imu_dcm.gyro.prefilter.prefilter` (noise density given = the simulated one, process noise by
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
* **No rest**: the same scenes with nothing given, the noise density estimated from the log's
  spectrum (the scenes never rest), then ``rts``.
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
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from benchmarks.noise_cases import (
    EULER_MODES,
    EULER_TORQUE_NOISE,
    MODES,
    SCENES,
    BroadResult,
    Condition,
    ModeStats,
    att_err_deg,
)
from imu_dcm.gyro.prefilter import PrefilterConfig, euler_prefilter, prefilter
from imu_dcm.integrator.batch import integrate
from imu_dcm.metrics import attitude_error_deg

DENSITIES = (1e-4, 1e-3, 1e-2)
RATES_HZ = (200.0, 1000.0)
QUANT_STEP_RAD_S = math.radians(0.061)
BROAD_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"


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
    est_density, est_rate, est_att = [], [], []
    for seed in range(seeds):
        rec = data_synth.synthetic_gyro(traj, rate_hz, model=model, seed=seed)
        t = rec.t_s
        q_true, w_true = traj.at(t)
        outs, clean, accel = _filter_runs(rec.values, t, w_true, density, euler, traj)
        accels.append(accel)
        if not quantize:
            # nothing given: these scenes never rest, so N comes from the log's spectrum
            res_e = prefilter(rec.values, t, "rts")
            est_density.append(res_e.config.noise_density_rad_s_sqrt_hz)
            est_rate.append(float(np.mean((res_e.omega_b - w_true) ** 2)))
            est_att.append(float(np.mean(att_err_deg(res_e.omega_b, t, q_true) ** 2)))
        truth = (t, q_true, w_true, rate_hz)
        for m in modes_here:
            series.setdefault(m, []).append(_score(acc[m], outs[m], clean[m], truth))
    n = min(len(v) for a in series.values() for v in a)  # stamps may jitter in count
    rms_series = {m: np.sqrt(np.mean([v[:n] for v in a], axis=0)) for m, a in series.items()}
    return Condition(
        label,
        density,
        rate_hz,
        seeds,
        float(np.median(accels)),
        {m: _pooled(acc[m]) for m in modes_here},
        t[:n],
        rms_series,
        float(np.mean(est_density)) if est_density else math.nan,
        math.sqrt(np.mean(est_rate)) if est_rate else math.nan,
        math.sqrt(np.mean(est_att)) if est_att else math.nan,
    )


def _filter_runs(
    z: NDArray, t: NDArray, w_true: NDArray, density: float, euler: bool, traj
) -> tuple[dict[str, NDArray], dict[str, NDArray | None], float]:
    """Each mode on the measured rates ``z`` and on the exact rates ``w_true`` (the model-based
    modes on the measured ones only: costly), with kalman's fitted process noise for all; and
    that fitted angular acceleration, rad/s²."""
    res_k = prefilter(z, t, "kalman", PrefilterConfig(noise_density_rad_s_sqrt_hz=density))
    cfg = res_k.config  # the fitted process noise, reused by rts and the noise-free runs
    outs = {"none": z, "kalman": res_k.omega_b, "rts": prefilter(z, t, "rts", cfg).omega_b}
    clean = {
        "none": w_true,
        "kalman": prefilter(w_true, t, "kalman", cfg).omega_b,
        "rts": prefilter(w_true, t, "rts", cfg).omega_b,
    }
    if euler:
        inertia = traj.params["inertia_kg_m2"]
        for m in EULER_MODES:
            outs[m] = euler_prefilter(
                z,
                t,
                inertia,
                m.split("-")[1],
                noise_density_rad_s_sqrt_hz=density,
                torque_noise_n_m_sqrt_hz=EULER_TORQUE_NOISE,
            ).omega_b
            clean[m] = None  # not run on exact rates (costly); reported as "–"
    return outs, clean, cfg.angular_accel_rad_s2


def _score(
    acc: dict[str, list[float]], out: NDArray, clean: NDArray | None, truth: tuple
) -> NDArray:
    """Add one seed's figures of one mode to ``acc`` (mean squares, max, lag); return its squared
    attitude error over time. ``truth``: (t_s, q_true, w_true, rate_hz)."""
    t, q_true, w_true, rate_hz = truth
    e = out - w_true
    a = att_err_deg(out, t, q_true)
    d = att_err_deg(clean, t, q_true) if clean is not None else np.nan
    acc["rate_rms_rad_s"].append(float(np.mean(e * e)))
    acc["att_rms_deg"].append(float(np.mean(a * a)))
    acc["att_max_deg"].append(float(a.max()))
    acc["lag_samples"].append(_lag_samples(e, np.gradient(w_true, t, axis=0), rate_hz))
    acc["distortion_rate_rms_rad_s"].append(
        float(np.mean((clean - w_true) ** 2)) if clean is not None else np.nan
    )
    acc["distortion_att_rms_deg"].append(float(np.mean(d * d)))
    return a * a


def _pooled(v: dict[str, list[float]]) -> ModeStats:
    """One mode's figures over the seeds: RMS of the mean squares, mean of the rest."""
    return ModeStats(
        rate_rms_rad_s=math.sqrt(np.mean(v["rate_rms_rad_s"])),
        att_rms_deg=math.sqrt(np.mean(v["att_rms_deg"])),
        att_max_deg=float(np.mean(v["att_max_deg"])),
        lag_samples=float(np.mean(v["lag_samples"])),
        distortion_rate_rms_rad_s=math.sqrt(np.mean(v["distortion_rate_rms_rad_s"])),
        distortion_att_rms_deg=math.sqrt(np.mean(v["distortion_att_rms_deg"])),
    )


# ------------------------------------------------------------------------------------------------
# BROAD


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


def run(
    out_dir: str | Path, quick: bool = False, progress: Callable[[str], None] = print
) -> list[str]:
    """Run the whole study; write ``noise_study.png`` and ``noise_study.md``; return markdown."""
    from benchmarks.noise_report import example_series, markdown, plot

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
    ex = example_series(quick)
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
