"""Speed of the core integrator against its peers, measured in one run (issue 2's targets).

Run: ``python -m benchmarks.core_speed`` (``--quick`` for a smoke run, ``--rounds N``).

Method (STYLE.md "Benchmarks"): one BLAS/OpenMP thread (environment set before numpy is
imported, plus a ``threadpoolctl`` limit); every case runs once as a warm-up, then ``rounds``
interleaved rounds; each figure is the median over rounds. Targets are ratios between cases of
the same run, so a loaded machine slows both sides. Inputs: random-walk body rates at 1 kHz.

Targets (issue 2):

* batch ``magnus4`` on 10^6 samples >= 0.35x the throughput of vqf's C++ ``updateBatch``
  (gyro only) and >= 40x the reference document's per-sample loop (timed on a subset, per sample);
* streaming ``update`` within 3x of imufusion's per-sample update (``update_no_magnetometer`` +
  ``get_quaternion``, both return the attitude as an array);
* ``update_many`` on chunks of 1000 within 2x of the batch throughput.

A second section measures the two ways of streaming ``magnus4`` (the one-sample look-ahead):
lag one sample (the chosen one) against a causal one-sided cubic, on analytic coning.
"""

from __future__ import annotations

from benchmarks.timing import limit_threads_env

limit_threads_env(1)

import argparse
import platform
import time

import numpy as np
from scipy.spatial.transform import Rotation

from benchmarks.peers import reference_loop
from benchmarks.timing import interleaved_medians, single_thread
from data_synth.analytic import coning_attitude, coning_rates
from imu_dcm.integrate import exp_parts, integrate, phi_parts
from imu_dcm.scan import prefix_product_parts
from imu_dcm.streaming import DcmIntegrator

RATE_HZ = 1000.0


def make_rates(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random-walk body rates (rad/s) at 1 kHz and their stamps (s)."""
    rng = np.random.default_rng(seed)
    omega = np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)
    return omega, np.arange(n) / RATE_HZ


def _vqf_raw(gyr: np.ndarray, acc: np.ndarray):
    import vqf

    def run():
        v = vqf.VQF(1.0 / RATE_HZ, restBiasEstEnabled=False, motionBiasEstEnabled=False,
                    magDistRejectionEnabled=False)
        v.updateBatch(gyr, acc)
    return run


def _imufusion_loop(omega: np.ndarray):
    import imufusion

    gyr_dps = np.degrees(omega)
    zeros = np.zeros(3)

    def run():
        ahrs = imufusion.Ahrs()
        ahrs.set_settings(imufusion.AhrsSettings(sample_rate=RATE_HZ, gain=0.0,
                                                 gyroscope_range=0.0))
        ahrs.skip_startup()
        for g in gyr_dps:
            ahrs.update_no_magnetometer(g, zeros)
            ahrs.get_quaternion()
    return run


def _update_loop(omega: np.ndarray, t: np.ndarray, method: str):
    rows = list(omega)  # (3,) arrays, as a live source would hand them over
    stamps = t.tolist()

    def run():
        integ = DcmIntegrator([0.0, 0.0, 0.0, 1.0], method)
        for w, ts in zip(rows, stamps):
            integ.update(w, ts)
    return run


def _update_many(omega: np.ndarray, t: np.ndarray, chunk: int):
    def run():
        integ = DcmIntegrator([0.0, 0.0, 0.0, 1.0], "magnus4")
        for i in range(0, len(t), chunk):
            integ.update_many(omega[i:i + chunk], t[i:i + chunk])
    return run


def speed(n_batch: int, n_loop: int, n_many: int, rounds: int, wall: bool = False) -> dict:
    omega, t = make_rates(n_batch)
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    gyr = np.ascontiguousarray(omega)
    acc = np.zeros_like(gyr)
    sub_w, sub_t = omega[:n_loop], t[:n_loop]
    cases = {
        "batch magnus4": (lambda: integrate(omega, t, q0, "magnus4"), n_batch),
        "batch trapezoid": (lambda: integrate(omega, t, q0, "trapezoid"), n_batch),
        "vqf updateBatch (C++)": (_vqf_raw(gyr, acc), n_batch),
        "reference loop (numpy 3x3)": (lambda: reference_loop(sub_w, sub_t, q0), n_loop),
        "imufusion update": (_imufusion_loop(sub_w), n_loop),
        "DcmIntegrator.update magnus4": (_update_loop(sub_w, sub_t, "magnus4"), n_loop),
        "DcmIntegrator.update trapezoid": (_update_loop(sub_w, sub_t, "trapezoid"), n_loop),
        "update_many x1000 magnus4": (_update_many(omega[:n_many], t[:n_many], 1000), n_many),
    }
    with single_thread():
        clock = time.perf_counter if wall else time.process_time
        return interleaved_medians(cases, rounds=rounds, warmup=1, clock=clock)


def report_speed(res: dict) -> list[tuple[str, float, float, bool]]:
    print(f"{'case':34s} {'samples/s':>12s} {'ns/sample':>10s}")
    for name, r in res.items():
        print(f"{name:34s} {r.items_per_s:12.4g} {r.ns_per_item:10.1f}")
    b = res["batch magnus4"].items_per_s
    checks = [
        ("batch magnus4 / vqf updateBatch", b / res["vqf updateBatch (C++)"].items_per_s, 0.35),
        ("batch magnus4 / reference loop", b / res["reference loop (numpy 3x3)"].items_per_s,
         40.0),
        ("DcmIntegrator.update magnus4 / imufusion update",
         res["DcmIntegrator.update magnus4"].items_per_s / res["imufusion update"].items_per_s,
         1 / 3),
        ("DcmIntegrator.update trapezoid / imufusion update",
         res["DcmIntegrator.update trapezoid"].items_per_s / res["imufusion update"].items_per_s,
         1 / 3),
        ("update_many x1000 / batch magnus4", res["update_many x1000 magnus4"].items_per_s / b,
         0.5),
    ]
    print("\nratio (throughput)                                   measured   target   met")
    out = []
    for name, ratio, target in checks:
        met = ratio >= target
        print(f"{name:52s} {ratio:8.3g}   >= {target:<6.3g} {'yes' if met else 'NO'}")
        out.append((name, ratio, target, met))
    return out


# -- look-ahead: lag one sample vs causal --------------------------------------------------------

def coning(t: np.ndarray, beta: float = 0.3, freq_hz: float = 2.0):
    """Pure coning truth (``Rotation``) and body rates from data_synth's closed form."""
    return (Rotation.from_quat(coning_attitude(t, beta, freq_hz)),
            coning_rates(t, beta, freq_hz))


def causal_magnus4(omega: np.ndarray, t: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """magnus4 closing step i at once: ω_{i+2} replaced by its extrapolation on the cubic through
    ω_{i-2..i+1} (uniform stamps: 4 ω_{i+1} - 6 ω_i + 4 ω_{i-1} - ω_{i-2}); the first two steps
    use the batch start rule."""
    n = len(t)
    h = t[1] - t[0]
    w = omega
    ghost = 4 * w[3:] - 6 * w[2:-1] + 4 * w[1:-2] - w[:-3]  # for steps 2..n-2
    steps = np.arange(2, n - 1)
    wm, w0, w1, w2 = w[steps - 1], w[steps], w[steps + 1], ghost
    hh = np.full(len(steps), h)
    phi_tail = phi_parts("magnus4", tuple(wm.T), tuple(w0.T), tuple(w1.T), tuple(w2.T),
                         hh, hh, hh)
    head = integrate(w[:4], t[:4], q0, "magnus4").as_quat()[2]  # steps 0, 1 (start ghost)
    return prefix_product_parts(head, exp_parts(*phi_tail))  # attitudes at samples 2..n-1


def lookahead() -> None:
    print("\nmagnus4 streaming look-ahead on pure coning (half-angle 0.3 rad, 2 Hz, 1 s),")
    print("max attitude error (deg) of the attitude each variant returns after sample k:")
    print(f"{'rate':>6s} {'lag 1 (at t_k-1)':>18s} {'lag 1 taken as t_k':>19s} "
          f"{'causal (at t_k)':>16s}")
    for rate in (100, 200, 400, 1000):
        t = np.linspace(0.0, 1.0, rate + 1)
        truth, omega = coning(t)
        q0 = truth[0].as_quat()
        batch = integrate(omega, t, q0)
        lag = np.degrees((batch.inv() * truth).magnitude()[:-1].max())
        stale = np.degrees((batch[:-1].inv() * truth[1:]).magnitude().max())
        causal = Rotation.from_quat(causal_magnus4(omega, t, q0))
        c_err = np.degrees((causal.inv() * truth[2:]).magnitude().max())
        print(f"{rate:6d} {lag:18.3g} {stale:19.3g} {c_err:16.3g}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small inputs, 3 rounds (smoke run)")
    ap.add_argument("--rounds", type=int, default=7, help="timed rounds (default 7)")
    ap.add_argument("--wall", action="store_true",
                    help="time with the wall clock (default: CPU time of this process, which "
                         "leaves out the time other processes hold the CPU)")
    args = ap.parse_args(argv)
    n_batch, n_loop, n_many = (100_000, 2_000, 20_000) if args.quick else (1_000_000, 50_000,
                                                                          200_000)
    rounds = 3 if args.quick else max(5, args.rounds)
    clock = "wall time" if args.wall else "CPU time"
    print(f"imu_dcm core speed: {platform.python_implementation()} {platform.python_version()}, "
          f"numpy {np.__version__}, {platform.machine()}, one thread, {clock}, median of "
          f"{rounds} interleaved rounds; batch N = {n_batch:,}, per-sample loops N = "
          f"{n_loop:,}\n")
    report_speed(speed(n_batch, n_loop, n_many, rounds, wall=args.wall))
    lookahead()


if __name__ == "__main__":
    main()
