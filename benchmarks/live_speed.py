"""Live throughput, latency and CPU of ``python -m imu_dcm.live``, fed at a fixed rate per source.

``python -m benchmarks.live_speed [--rate 2000] [--duration 60] [--latency-rate 1000]
[--latency-duration 20] [--replay-rounds 3]``

What is measured (the live command runs as a child process, as a user runs it; the view is
``--rerun save:FILE.rrd`` so every batch goes through real rerun log calls):

* **Sustained rate**, per source (Foxglove WebSocket from a foxglove-sdk server in this process;
  UDP datagrams of one line each from this process; lines written to the child's stdin): a
  coning motion sampled at ``--rate`` Hz for ``--duration`` s, sent paced to the wall clock.
  Counted end to end: samples sent, samples the live run integrated, samples it dropped (any
  reason) and samples lost on the way (sent - integrated - dropped).
* **Latency** receive -> rerun log call of each sample, p50 / p99, from the live summary
  (``perf_counter`` at arrival to the ``send_columns`` batch holding it): at ``--rate`` with the
  default 50 ms reorder window and 50 ms view batches, and at ``--latency-rate`` with those
  defaults and with ``--reorder-window 0 --view-interval 10``. A sample is held until the window
  has passed in source time and then waits for the next batch: both add to the latency.
* **CPU** of the live process while receiving (``process_time``, all threads), per 1000
  samples/s, against ``imu_dcm.replay.replay`` on the same samples written as a bag (median of
  ``--replay-rounds`` runs, CPU time): replay CPU s per 1000 samples.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.timing import limit_threads_env

REPO = Path(__file__).resolve().parents[1]
T0_NS = 1_700_000_000 * 10**9


def coning(rate_hz: float, duration_s: float):
    """Stamps (int64 ns) and body rates (rad/s) of pure coning, half-angle 0.3 rad at 0.5 Hz."""
    import numpy as np

    n = int(rate_hz * duration_s)
    step = round(1e9 / rate_hz)
    t_ns = T0_NS + np.arange(n, dtype=np.int64) * step
    t = (t_ns - T0_NS) * 1e-9
    beta, om = 0.3, 2 * np.pi * 0.5
    w = om * np.stack(
        [
            -np.sin(beta) * np.sin(om * t),
            np.sin(beta) * np.cos(om * t),
            np.full_like(t, np.cos(beta) - 1.0),
        ],
        axis=1,
    )
    return t_ns, w


def lines_of(t_ns, w) -> list[bytes]:
    return [
        f"{t // 10**9}.{t % 10**9:09d},{a!r},{b!r},{c!r}".encode()
        for t, (a, b, c) in zip(t_ns.tolist(), w.tolist(), strict=False)
    ]


def paced(n: int, rate_hz: float):
    """Yield (lo, hi) index ranges due now, sleeping ~0.5 ms between checks."""
    start = time.perf_counter()
    sent = 0
    while sent < n:
        due = min(n, int((time.perf_counter() - start) * rate_hz) + 1)
        if due > sent:
            yield sent, due
            sent = due
        else:
            time.sleep(0.0005)


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


VIEW = {"mode": "save"}  # --rerun: "save" (an .rrd per run) or "off"


def run_live(
    source: str,
    feed,
    tmp: Path,
    window_ms: float = 50.0,
    stdin: bool = False,
    view_ms: float = 50.0,
) -> dict:
    """Start the live command on ``source``, call ``feed(proc)``, wait for its summary."""
    summary = tmp / f"summary_{time.monotonic_ns()}.json"
    rrd = tmp / f"view_{time.monotonic_ns()}.rrd"
    cmd = [
        sys.executable,
        "-m",
        "imu_dcm.live",
        source,
        "--bias",
        "none",
        "--rerun",
        f"save:{rrd}" if VIEW["mode"] == "save" else "off",
        "--summary-json",
        str(summary),
        "--no-status",
        "--quiet",
        "--idle-stop",
        "1.5",
        "--reorder-window",
        str(window_ms),
        "--view-interval",
        str(view_ms),
    ]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    errf = tmp / "live_stderr.txt"
    with open(errf, "wb") as err:
        proc = subprocess.Popen(
            cmd,
            stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=err,
            env=env,
        )
        try:
            feed(proc)
            proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    if proc.returncode != 0:
        raise RuntimeError(f"live exited {proc.returncode}: {errf.read_text()[-500:]}")
    out = json.loads(summary.read_text())
    rrd.unlink(missing_ok=True)
    return out


def wait_bound(proc, port: int) -> None:
    """Wait until the child has bound udp://127.0.0.1:port (binding it ourselves fails)."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return
        if proc.poll() is not None:
            raise RuntimeError("live exited before binding")
        time.sleep(0.05)
    raise TimeoutError("live did not bind the UDP port")


def feed_udp(t_ns, w, rate_hz: float, port: int):
    lines = lines_of(t_ns, w)

    def feed(proc):
        wait_bound(proc, port)
        time.sleep(0.5)
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for lo, hi in paced(len(lines), rate_hz):
            for line in lines[lo:hi]:
                s.sendto(line, ("127.0.0.1", port))
        s.close()

    return feed


def feed_stdin(t_ns, w, rate_hz: float):
    lines = lines_of(t_ns, w)

    def feed(proc):
        time.sleep(1.0)
        for lo, hi in paced(len(lines), rate_hz):
            proc.stdin.write(b"\n".join(lines[lo:hi]) + b"\n")
            proc.stdin.flush()
        proc.stdin.close()

    return feed


def feed_ws(t_ns, w, rate_hz: float, server_box: dict):
    import foxglove

    from imu_dcm.logio.writer import MSG_DEFINITIONS, cdr_messages, imu_doubles

    imu_type = "sensor_msgs/msg/Imu"
    payloads = [r.tobytes() for r in cdr_messages(t_ns, "imu", imu_doubles(w, None, None))]

    def feed(proc):
        ch = server_box["channel"]
        deadline = time.monotonic() + 30
        while not ch.has_sinks():
            if time.monotonic() > deadline or proc.poll() is not None:
                raise TimeoutError("live did not subscribe")
            time.sleep(0.01)
        time.sleep(0.5)
        log = ch.log
        for lo, hi in paced(len(payloads), rate_hz):
            for k in range(lo, hi):
                log(payloads[k], log_time=int(t_ns[k]))

    ctx = server_box["context"] = foxglove.Context()  # kept: its channels live with it
    server_box["channel"] = foxglove.Channel(
        "/imu/data",
        schema=foxglove.Schema(
            name=imu_type, encoding="ros2msg", data=MSG_DEFINITIONS[imu_type].encode()
        ),
        message_encoding="cdr",
        context=ctx,
    )
    server_box["server"] = foxglove.start_server(
        host="127.0.0.1", port=0, context=ctx, message_backlog_size=1 << 16
    )
    return feed


def sustain(
    kind: str,
    rate_hz: float,
    duration_s: float,
    tmp: Path,
    window_ms: float = 50.0,
    view_ms: float = 50.0,
):
    t_ns, w = coning(rate_hz, duration_s)
    if kind == "udp":
        port = free_port()
        s = run_live(
            f"udp://127.0.0.1:{port}",
            feed_udp(t_ns, w, rate_hz, port),
            tmp,
            window_ms,
            view_ms=view_ms,
        )
    elif kind == "stdin":
        s = run_live("-", feed_stdin(t_ns, w, rate_hz), tmp, window_ms, stdin=True, view_ms=view_ms)
    else:
        box: dict = {}
        feed = feed_ws(t_ns, w, rate_hz, box)
        try:
            s = run_live(
                f"ws://127.0.0.1:{box['server'].port}", feed, tmp, window_ms, view_ms=view_ms
            )
        finally:
            box["server"].stop()
    dropped = (
        s["dropped_nonfinite"] + s["dropped_duplicate"] + s["dropped_backward"] + s["malformed"]
    )
    return {
        "source": kind,
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "window_ms": window_ms,
        "view_ms": view_ms,
        "sent": len(t_ns),
        "integrated": s["samples"],
        "dropped": dropped,
        "lost": len(t_ns) - s["samples"] - dropped,
        "cpu_s": s["cpu_s"],
        "cpu_per_khz": s["cpu_s"] / duration_s / (rate_hz / 1000.0),
        "p50_ms": s["latency_p50_ms"],
        "p99_ms": s["latency_p99_ms"],
    }


def replay_cpu(rate_hz: float, duration_s: float, tmp: Path, rounds: int) -> float:
    """Median CPU s of imu_dcm.replay.replay on the same samples, per 1000 samples."""
    import statistics
    import warnings

    from imu_dcm.logio.writer import StampedSeries, write_bag
    from imu_dcm.replay import replay

    t_ns, w = coning(rate_hz, duration_s)
    bag = write_bag(tmp / "replay_bag", imu=StampedSeries(t_ns, w, "imu"))
    times = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        replay(bag, bias="none")  # warm-up
        for _ in range(rounds):
            c = time.process_time()
            replay(bag, bias="none")
            times.append(time.process_time() - c)
    return statistics.median(times) / len(t_ns) * 1000.0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.live_speed",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--rate", type=float, default=2000.0, help="sustained rate, Hz (default 2000)")
    p.add_argument("--duration", type=float, default=60.0, help="per source, s (default 60)")
    p.add_argument("--latency-rate", type=float, default=1000.0, help="Hz (default 1000)")
    p.add_argument("--latency-duration", type=float, default=20.0, help="s (default 20)")
    p.add_argument("--replay-rounds", type=int, default=3)
    p.add_argument("--sources", default="ws,udp,stdin")
    p.add_argument(
        "--rerun",
        choices=("save", "off"),
        default="save",
        help="the live view: streamed into an .rrd (default) or off (for the share "
        "of the view in the CPU time)",
    )
    p.add_argument("--no-latency", action="store_true", help="skip the latency rows")
    p.add_argument("--json", type=Path, help="also write the rows as JSON")
    args = p.parse_args(argv)
    limit_threads_env()
    VIEW["mode"] = args.rerun
    import platform

    import numpy as np

    rows = []
    with tempfile.TemporaryDirectory(prefix="live_speed_") as d:
        tmp = Path(d)
        for kind in args.sources.split(","):
            rows.append(sustain(kind, args.rate, args.duration, tmp))
        for window, view in () if args.no_latency else ((50.0, 50.0), (0.0, 10.0)):
            for kind in ("ws", "udp"):
                rows.append(
                    sustain(kind, args.latency_rate, args.latency_duration, tmp, window, view)
                )
        rep = replay_cpu(args.rate, args.duration, tmp, args.replay_rounds)
    print(
        f"imu_dcm live speed: CPython {platform.python_version()}, numpy {np.__version__}, "
        f"{platform.machine()}; live as a child process, view "
        f"{'--rerun save:FILE.rrd' if args.rerun == 'save' else '--rerun off'}, "
        f"bias none, magnus4"
    )
    print()
    head = (
        f"{'source':<7}{'rate Hz':>9}{'dur s':>7}{'window':>8}{'view':>7}{'sent':>9}"
        f"{'integrated':>11}"
        f"{'dropped':>9}{'lost':>6}{'CPU s':>8}{'CPU/kHz':>9}{'p50 ms':>8}{'p99 ms':>8}"
    )
    print(head)
    for r in rows:
        print(
            f"{r['source']:<7}{r['rate_hz']:>9.0f}{r['duration_s']:>7.0f}"
            f"{r['window_ms']:>6.0f}ms{r['view_ms']:>5.0f}ms{r['sent']:>9}{r['integrated']:>11}"
            f"{r['dropped']:>9}"
            f"{r['lost']:>6}{r['cpu_s']:>8.2f}{100 * r['cpu_per_khz']:>8.1f}%"
            f"{r['p50_ms']:>8.1f}{r['p99_ms']:>8.1f}"
        )
    print()
    live_k = [r["cpu_per_khz"] for r in rows if r["rate_hz"] == args.rate]
    print(
        f"CPU per 1000 samples/s: live {100 * min(live_k):.1f}-{100 * max(live_k):.1f} % of "
        f"a core (CPU s per 1000 samples: {min(live_k):.3f}-{max(live_k):.3f}); "
        f"replay on the same samples {rep:.4f} CPU s per 1000 samples "
        f"(live/replay {min(live_k) / rep:.0f}-{max(live_k) / rep:.0f}x)"
    )
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "replay_cpu_per_1000": rep}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
