"""Speed of the core integrator against its peers, measured in one run.

Run: ``python -m benchmarks.core_speed`` (``--quick`` for a smoke run, ``--rounds N``).

Method: one BLAS/OpenMP thread (environment set before numpy is imported, plus a
``threadpoolctl`` limit); every case runs once as a warm-up (which also loads the compiled
kernel), then ``rounds`` interleaved rounds; each figure is the median over rounds. Targets are
ratios between cases of the same run, so a loaded machine slows both sides. Inputs: random-walk
body rates at 1 kHz.

Targets:

* batch ``magnus4`` on 10^6 samples >= 1.5x the throughput of vqf's C++ ``updateBatch``
  (gyro only) and >= 150x the classic per-sample DCM loop (numpy 3x3 per step, timed on a
  subset, per sample);
* streaming ``update`` (``magnus4`` and ``trapezoid``) at least as fast as imufusion's
  per-sample update (``update_no_magnetometer`` + ``get_quaternion``, both return the attitude
  as an array);
* ``update_many`` on chunks of 1000 >= 0.9x the batch throughput.

Start-up (fresh processes, CPU and wall time, medians of interleaved rounds after a warm-up):
``python -m imu_dcm.replay --help`` (target <= 0.3 s CPU); a replay of the shipped trial without
the view against the import baseline ``python -c "import numpy, scipy.spatial.transform"``
(target <= 1.5x its CPU); the same replay with an empty ``NUMBA_CACHE_DIR`` and again with that
cache, as installed (the kernel built ahead of time: no compile, no notice) and with
``IMU_DCM_KERNEL=jit`` (numba compiles; target: at most 4 s CPU more than the warm one, the
notice once, then never); and the CPU the install spends building the kernel. ``--only
streaming`` runs the streaming ratio alone.

A second section measures the two ways of streaming ``magnus4`` (the one-sample look-ahead):
lag one sample (the chosen one) against a causal one-sided cubic, on analytic coning.
"""

from __future__ import annotations

from benchmarks.timing import limit_threads_env

limit_threads_env(1)

import argparse
import importlib.util
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from benchmarks.peers import reference_loop
from benchmarks.timing import interleaved_medians, single_thread
from data_synth.analytic import coning_attitude, coning_rates
from imu_dcm.integrator.batch import integrate, integrate_delta
from imu_dcm.integrator.streaming import DcmIntegrator

RATE_HZ = 1000.0


def make_rates(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random-walk body rates (rad/s) at 1 kHz and their stamps (s)."""
    rng = np.random.default_rng(seed)
    omega = np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)
    return omega, np.arange(n) / RATE_HZ


def _vqf_raw(gyr: np.ndarray, acc: np.ndarray):
    import vqf

    def run():
        v = vqf.VQF(
            1.0 / RATE_HZ,
            restBiasEstEnabled=False,
            motionBiasEstEnabled=False,
            magDistRejectionEnabled=False,
        )
        v.updateBatch(gyr, acc)

    return run


def _imufusion_loop(omega: np.ndarray):
    import imufusion

    gyr_dps = np.degrees(omega)
    zeros = np.zeros(3)

    def run():
        ahrs = imufusion.Ahrs()
        ahrs.set_settings(
            imufusion.AhrsSettings(sample_rate=RATE_HZ, gain=0.0, gyroscope_range=0.0)
        )
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
        for w, ts in zip(rows, stamps, strict=False):
            integ.update(w, ts)

    return run


def _update_many(omega: np.ndarray, t: np.ndarray, chunk: int, quat: bool = False):
    """Chunks through ``update_many`` (a ``Rotation`` each) or ``update_many_quat`` (arrays)."""

    def run():
        integ = DcmIntegrator([0.0, 0.0, 0.0, 1.0], "magnus4")
        update = integ.update_many_quat if quat else integ.update_many
        for i in range(0, len(t), chunk):
            update(omega[i : i + chunk], t[i : i + chunk])

    return run


def speed(
    n_batch: int, n_loop: int, n_many: int, rounds: int, wall: bool = False, streaming: bool = False
) -> dict:
    """Interleaved medians of every throughput case (``streaming``: only imufusion's
    per-sample update and ``DcmIntegrator.update``)."""
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
        "update_many_quat x1000 magnus4": (
            _update_many(omega[:n_many], t[:n_many], 1000, quat=True),
            n_many,
        ),
    }
    if streaming:
        cases = {k: v for k, v in cases.items() if k in STREAMING_CASES}
    with single_thread():
        clock = time.perf_counter if wall else time.process_time
        return interleaved_medians(cases, rounds=rounds, warmup=1, clock=clock)


STREAMING_CASES = (
    "imufusion update",
    "DcmIntegrator.update magnus4",
    "DcmIntegrator.update trapezoid",
)


def report_streaming(res: dict) -> None:
    """The per-sample figures and ``DcmIntegrator.update`` over imufusion's update (throughput;
    above 1: faster)."""
    ref = res["imufusion update"]
    for name in STREAMING_CASES:
        r = res[name]
        print(f"{name:34s} {r.ns_per_item:8.1f} ns/sample  {ref.ns_per_item / r.ns_per_item:6.3g}x")


def report_speed(res: dict) -> list[tuple[str, float, float, bool]]:
    print(f"{'case':34s} {'samples/s':>12s} {'ns/sample':>10s}")
    for name, r in res.items():
        print(f"{name:34s} {r.items_per_s:12.4g} {r.ns_per_item:10.1f}")
    b = res["batch magnus4"].items_per_s
    checks = [
        ("batch magnus4 / vqf updateBatch", b / res["vqf updateBatch (C++)"].items_per_s, 1.5),
        (
            "batch magnus4 / reference loop",
            b / res["reference loop (numpy 3x3)"].items_per_s,
            150.0,
        ),
        (
            "DcmIntegrator.update magnus4 / imufusion update",
            res["DcmIntegrator.update magnus4"].items_per_s / res["imufusion update"].items_per_s,
            1.0,
        ),
        (
            "DcmIntegrator.update trapezoid / imufusion update",
            res["DcmIntegrator.update trapezoid"].items_per_s / res["imufusion update"].items_per_s,
            1.0,
        ),
        (
            "update_many x1000 / batch magnus4",
            res["update_many x1000 magnus4"].items_per_s / b,
            0.9,
        ),
        (
            "update_many_quat x1000 / batch magnus4",
            res["update_many_quat x1000 magnus4"].items_per_s / b,
            0.9,
        ),
    ]
    print("\nratio (throughput)                                   measured   target   met")
    out = []
    for name, ratio, target in checks:
        met = ratio >= target
        print(f"{name:62s} {ratio:8.3g}   >= {target:<6.3g} {'yes' if met else 'NO'}")
        out.append((name, ratio, target, met))
    return out


# -- look-ahead: lag one sample vs causal --------------------------------------------------------


def coning(t: np.ndarray, beta: float = 0.3, freq_hz: float = 2.0):
    """Pure coning truth (``Rotation``) and body rates from data_synth's closed form."""
    return (Rotation.from_quat(coning_attitude(t, beta, freq_hz)), coning_rates(t, beta, freq_hz))


def causal_magnus4(omega: np.ndarray, t: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """magnus4 closing step i at once: ω_{i+2} replaced by its extrapolation on the cubic through
    ω_{i-2..i+1} (uniform stamps: 4 ω_{i+1} - 6 ω_i + 4 ω_{i-1} - ω_{i-2}); the first two steps
    use the batch start rule. Attitudes at samples 2..n-1."""
    h = t[1] - t[0]
    w = omega
    ghost = 4 * w[3:] - 6 * w[2:-1] + 4 * w[1:-2] - w[:-3]  # for steps 2..n-2
    wm, w0, w1 = w[1:-2], w[2:-1], w[3:]
    # Uniform steps: φ = h/24 (-ω_{i-1} + 13 ω_i + 13 ω_{i+1} - ω_{i+2}) + h²/12 ω_i × ω_{i+1}.
    phi = h / 24 * (-wm + 13 * w0 + 13 * w1 - ghost) + h * h / 12 * np.cross(w0, w1)
    head = integrate(w[:4], t[:4], q0, "magnus4").as_quat()[2]  # steps 0, 1 (start ghost)
    # integrate_delta "plain" is the bare recursion q <- q ⊗ exp(φ) over the given φ.
    return integrate_delta(phi, t[2:], head, "plain").as_quat()


def lookahead() -> None:
    print("\nmagnus4 streaming look-ahead on pure coning (half-angle 0.3 rad, 2 Hz, 1 s),")
    print("max attitude error (deg) of the attitude each variant returns after sample k:")
    print(
        f"{'rate':>6s} {'lag 1 (at t_k-1)':>18s} {'lag 1 taken as t_k':>19s} "
        f"{'causal (at t_k)':>16s}"
    )
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


# -- start-up: fresh processes ------------------------------------------------------------------

REPO = Path(__file__).resolve().parents[1]
SHIPPED_TRIAL = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"
#: What the kernel's compile notice says (imu_dcm._kernels.jit), to count it in a first run's
#: stderr.
COMPILE_NOTICE = "compiling the integrator kernel once"
DECODE_LOOP = "mcap + mcap_ros2 decode loop over the shipped trial"


def _child_env(cache: str | None = None, **extra: str) -> dict[str, str]:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        **extra,
    }
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # a user's install has its bytecode cached
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    return env


def _run_s(
    args: list[str], cache: str | None = None, cwd: str | None = None, **extra: str
) -> tuple[float, float, str]:
    """Wall time, CPU time (user + system, s, its own children included) and stderr of one
    child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(
        args,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=_child_env(cache, **extra),
        cwd=cwd,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), res.stderr


def startup_cases() -> dict[str, list[str]]:
    """The fresh-process cases: the import baseline, the bare interpreter, ``--help``, a
    replay of the shipped trial without the view, and (with ``mcap_ros2`` installed) a plain
    ``mcap`` + ``mcap_ros2`` decode loop over the same trial, start-up included as for the
    replay."""
    py = sys.executable
    cases = {
        "import numpy, scipy.spatial.transform (baseline)": [
            py,
            "-c",
            "import numpy, scipy.spatial.transform",
        ],
        "python -c pass": [py, "-c", "pass"],
        "python -m imu_dcm.replay --help": [py, "-m", "imu_dcm.replay", "--help"],
        "replay shipped trial, warm cache": [
            py,
            "-m",
            "imu_dcm.replay",
            str(SHIPPED_TRIAL),
            "--rerun",
            "off",
            "--quiet",
        ],
    }
    if importlib.util.find_spec("mcap_ros2") is not None:  # the bench extra
        cases[DECODE_LOOP] = [
            py,
            "-c",
            (
                "import sys; from pathlib import Path; from benchmarks.replay_speed import "
                "decode_loop; decode_loop(Path(sys.argv[1]))"
            ),
            str(next(SHIPPED_TRIAL.glob("*.mcap"))),
        ]
    return cases


def startup(runs: int) -> dict[str, tuple[float, float]]:
    """Median (wall, CPU) seconds of each fresh-process case over ``runs`` interleaved rounds
    after one warm-up round (which also fills the kernel cache)."""
    cases = startup_cases()
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in cases}
    with tempfile.TemporaryDirectory() as cwd:  # the replay writes nothing, but not here if so
        for r in range(runs + 1):
            for name, args in cases.items():
                wall, cpu, _ = _run_s(args, cwd=cwd)
                if r:
                    times[name].append((wall, cpu))
    return {
        name: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v))
        for name, v in times.items()
    }


def startup_against(tree: Path, runs: int) -> dict[str, tuple[float, float]]:
    """Median CPU seconds of each fresh-process case run from this checkout and from ``tree``
    (another checkout of imu_dcm, say the commit before a change), over ``runs`` rounds
    interleaved case by case, after one warm-up round: ``{case: (this, other)}``."""
    cases = startup_cases()
    here: dict[str, list[float]] = {name: [] for name in cases}
    there: dict[str, list[float]] = {name: [] for name in cases}
    with tempfile.TemporaryDirectory() as cwd:
        for r in range(runs + 1):
            for name, args in cases.items():
                cpu_here = _run_s(args, cwd=cwd)[1]
                cpu_there = _run_s(args, cwd=cwd, PYTHONPATH=str(tree))[1]
                if r:
                    here[name].append(cpu_here)
                    there[name].append(cpu_there)
    return {n: (statistics.median(here[n]), statistics.median(there[n])) for n in cases}


def report_against(res: dict[str, tuple[float, float]], tree: Path) -> None:
    print(
        f"\n{'start-up CPU s, fresh process (median)':52s} {'this':>7s} {'other':>7s} {'ratio':>6s}"
    )
    for name, (this, other) in res.items():
        print(f"{name:52s} {this:7.3f} {other:7.3f} {this / other:6.2f}")
    print(f"(other: {tree}; ratio = this / other, under 1 is faster)")


def first_run(runs: int) -> dict[str, float]:
    """The replay of the shipped trial with an empty ``NUMBA_CACHE_DIR``, then again with that
    cache: as installed (the kernel built ahead of time: nothing to compile) and with
    ``IMU_DCM_KERNEL=jit`` (numba compiles it in the first run, loads it in the second). Median
    CPU seconds over ``runs`` fresh caches, and how many times the compile notice was printed in
    each run (-1: not the same in every run). Plus the build itself (``python -m
    imu_dcm._kernels.build`` into a temporary folder, its C compiler included): what an install
    spends once."""
    replay = startup_cases()["replay shipped trial, warm cache"]
    out: dict[str, float] = {}
    for label, extra in (("as installed", {}), ("IMU_DCM_KERNEL=jit", {"IMU_DCM_KERNEL": "jit"})):
        first, second, said_first, said_second = [], [], [], []
        for _ in range(runs):
            with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as cwd:
                _, cpu1, err1 = _run_s(replay, cache=cache, cwd=cwd, **extra)
                _, cpu2, err2 = _run_s(replay, cache=cache, cwd=cwd, **extra)
            first.append(cpu1)
            second.append(cpu2)
            said_first.append(err1.count(COMPILE_NOTICE))
            said_second.append(err2.count(COMPILE_NOTICE))
        out[f"first replay, empty cache, {label} (CPU s)"] = statistics.median(first)
        out[f"second replay, same cache, {label} (CPU s)"] = statistics.median(second)
        for which, said in (("first", said_first), ("second", said_second)):
            out[f"compile notices, {which} run, {label}"] = (
                said[0] if min(said) == max(said) else -1
            )
    with tempfile.TemporaryDirectory() as build_dir:
        build = [sys.executable, "-m", "imu_dcm._kernels.build", "--out", build_dir]
        out["kernel build at install (CPU s)"] = _run_s(build)[1]
    return out


def report_startup(res: dict[str, tuple[float, float]], first: dict[str, float]) -> list:
    print(f"\n{'start-up, fresh process (median)':62s} {'wall s':>7s} {'CPU s':>7s}")
    for name, (wall, cpu) in res.items():
        print(f"{name:62s} {wall:7.3f} {cpu:7.3f}")
    for name, v in first.items():
        print(f"{name:62s} {'':7s} {v:7.3f}" if "CPU" in name else f"{name:62s} {v:>15g}")
    base = res["import numpy, scipy.spatial.transform (baseline)"][1]
    warm = res["replay shipped trial, warm cache"][1]
    checks = [
        ("replay --help, CPU s", res["python -m imu_dcm.replay --help"][1], 0.3, "<="),
        ("warm replay / import baseline, CPU", warm / base, 1.5, "<="),
    ]
    if DECODE_LOOP in res:
        checks.append(
            ("replay end to end: decode loop / replay, CPU", res[DECODE_LOOP][1] / warm, 10, ">=")
        )
    for label, said_first in (("as installed", 0), ("IMU_DCM_KERNEL=jit", 1)):
        compile_s = (
            first[f"first replay, empty cache, {label} (CPU s)"]
            - first[f"second replay, same cache, {label} (CPU s)"]
        )
        checks += [
            (f"first - second replay (the compile), {label}, CPU s", compile_s, 4.0, "<="),
            (
                f"compile notices in a first run, {label}",
                first[f"compile notices, first run, {label}"],
                said_first,
                "==",
            ),
            (
                f"compile notices in a second run, {label}",
                first[f"compile notices, second run, {label}"],
                0,
                "==",
            ),
        ]
    print(f"\n{'start-up check':62s} {'measured':>8s}   target   met")
    out = []
    for name, value, target, op in checks:
        met = {"<=": value <= target, ">=": value >= target, "==": value == target}[op]
        print(f"{name:62s} {value:8.3g}   {op} {target:<5g} {'yes' if met else 'NO'}")
        out.append((name, value, target, met))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small inputs, 3 rounds (smoke run)")
    ap.add_argument("--rounds", type=int, default=7, help="timed rounds (default 7)")
    ap.add_argument(
        "--wall",
        action="store_true",
        help="time with the wall clock (default: CPU time of this process, which "
        "leaves out the time other processes hold the CPU)",
    )
    ap.add_argument(
        "--only",
        choices=("speed", "streaming", "startup"),
        help="one section: the throughput table, the streaming ratio alone, or start-up",
    )
    ap.add_argument(
        "--against",
        type=Path,
        metavar="TREE",
        help="with --only startup: also run each start-up case from TREE (another checkout, "
        "with its kernel built), interleaved, and give the ratio",
    )
    args = ap.parse_args(argv)
    if args.against is not None:
        if args.only != "startup" or not (args.against / "imu_dcm" / "__init__.py").is_file():
            ap.error("--against TREE needs --only startup and a checkout of imu_dcm at TREE")
        report_against(startup_against(args.against, 3 if args.quick else 7), args.against)
        return
    n_batch, n_loop, n_many = (
        (100_000, 2_000, 20_000) if args.quick else (1_000_000, 50_000, 200_000)
    )
    rounds = 3 if args.quick else max(5, args.rounds)
    clock = "wall time" if args.wall else "CPU time"
    print(
        f"imu_dcm core speed: {platform.python_implementation()} {platform.python_version()}, "
        f"numpy {np.__version__}, {platform.machine()}, one thread, {clock}, median of "
        f"{rounds} interleaved rounds; batch N = {n_batch:,}, per-sample loops N = "
        f"{n_loop:,}\n"
    )
    if args.only in (None, "speed"):
        report_speed(speed(n_batch, n_loop, n_many, rounds, wall=args.wall))
    if args.only == "streaming":
        report_streaming(speed(n_batch, n_loop, n_many, rounds, wall=args.wall, streaming=True))
    if args.only in (None, "startup"):
        runs = 3 if args.quick else 5
        report_startup(startup(runs), first_run(1 if args.quick else 3))
    if args.only is None:
        lookahead()


if __name__ == "__main__":
    main()
