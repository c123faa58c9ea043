"""Live CPU and latency of ``python -m imu_dcm.live`` per source and view setting, fed at a rate.

``python -m benchmarks.live_speed [--rate 1000] [--duration 20] [--sources ws,udp,stdin]
[--latency-duration 20] [--replay-rounds 3] [--ws-clients]``; ``--fast [--fast-rate 100000]
[--fast-duration 10]`` for the fast rows only; ``--soak`` for the memory of a long run
(:mod:`benchmarks.live_soak`).

What is measured (the live command runs as a child process, as a user runs it):

* **CPU per 1000 samples/s**, per source (Foxglove WebSocket from a foxglove-sdk server in this
  process; UDP datagrams of one line each from this process; lines written to the child's
  stdin) and per view setting (``--rerun off``, and ``--rerun save:FILE.rrd``, where every
  batch goes through real rerun log calls): a coning motion sampled at ``--rate`` Hz for
  ``--duration`` s, sent paced to the wall clock, with live's defaults: a 50 ms reorder window,
  and a wake-up every 50 ms with the view (its batches), every 250 ms without. CPU is the live
  process's ``process_time`` while receiving (all threads), over the duration, per 1000
  samples/s: a fraction of one core. Counted end to end:
  samples sent, integrated, dropped (any reason) and lost on the way. Targets at 1 kHz: at most
  5 % of a core without the view, 10 % with it.
* **Latency** receive -> view log call of each sample, p50 / p99, from the live summary
  (``perf_counter`` at arrival to the ``send_columns`` batch holding it), in every row above
  and in rows with ``--reorder-window 0 --view-interval 10`` (view on) over WebSocket and UDP.
  Target there: p99 at most 20 ms.
* **Replay** (:func:`imu_dcm.replay.replay`) CPU on the same samples written as a bag (median
  of ``--replay-rounds`` runs), per 1000 samples, for scale.
* With ``--ws-clients``: the WebSocket client alone, each in a child process receiving
  ``--rate`` messages/s for ``--duration`` s from the same server: ``websockets.sync.client``
  (a reader thread hands each frame over; one ``recv`` per message, batches of 5 ms as the live
  source used it) against :class:`imu_dcm.live.sources.websocket.WsConnection` (under the
  source thread's own socket loop: websockets' Sans-I/O protocol for the handshake and control
  frames, the data frames split by the client; one ``recv`` per wake-up).
* **This machine's wake-up**: the CPU of one parse of 50 sample lines run again at once, and
  run after 50 ms asleep as live's loop runs it. Where a sleeping process's caches and
  page tables go cold (a shared or nested virtual machine), the second is many times the first;
  live's CPU, made of such wake-ups, rises and falls with it.
* **Fast rows** (``--fast``): UDP at 100 000 samples/s for 10 s, one, 10 and 100 lines a
  datagram, the view off: samples sent, integrated, lost (and of those, counted by the system
  as dropped), the loop's final read cadence and live's CPU as a fraction of one core. Target:
  0 lost, within 40 % of a core.
* The report's first line gives the machine's cores and its load average at start and end (the
  CPU figures rise with the load of other jobs: measure before and after one after the other).
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
    view_ms: float | None = None,
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
        *([] if view_ms is None else ["--view-interval", str(view_ms)]),
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
    deadline = time.monotonic() + 120  # a fresh numba cache compiles first
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


def feed_udp(t_ns, w, rate_hz: float, port: int, per_datagram: int = 1):
    """Datagrams of ``per_datagram`` lines each, paced to ``rate_hz`` samples/s."""
    lines = lines_of(t_ns, w)
    grams = [b"\n".join(lines[k : k + per_datagram]) for k in range(0, len(lines), per_datagram)]

    def feed(proc):
        wait_bound(proc, port)
        time.sleep(0.5)
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        send, to = s.sendto, ("127.0.0.1", port)
        for lo, hi in paced(len(grams), rate_hz / per_datagram):
            for gram in grams[lo:hi]:
                send(gram, to)
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

    from imu_dcm.logio.writers import MSG_DEFINITIONS, cdr_messages, imu_doubles

    imu_type = "sensor_msgs/msg/Imu"
    payloads = [r.tobytes() for r in cdr_messages(t_ns, "imu", imu_doubles(w, None, None))]

    def feed(proc):
        ch = server_box["channel"]
        deadline = time.monotonic() + 120  # a fresh numba cache compiles first
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
    view_ms: float | None = None,
    per_datagram: int = 1,
):
    t_ns, w = coning(rate_hz, duration_s)
    if kind == "udp":
        port = free_port()
        s = run_live(
            f"udp://127.0.0.1:{port}",
            feed_udp(t_ns, w, rate_hz, port, per_datagram),
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
        "view_ms": view_ms or (50.0 if VIEW["mode"] == "save" else 250.0),  # live's defaults
        "sent": len(t_ns),
        "integrated": s["samples"],
        "dropped": dropped,
        "lost": len(t_ns) - s["samples"] - dropped,
        "cpu_s": s["cpu_s"],
        "cpu_per_khz": s["cpu_s"] / duration_s / (rate_hz / 1000.0),
        "p50_ms": s["latency_p50_ms"],
        "p99_ms": s["latency_p99_ms"],
        "lines_per_datagram": per_datagram,
        "lost_by_system": s["lost_by_system"],
        "read_ms": 1e3 * (s.get("read_interval_s") or 0.0),
    }


def fast_rows(args, tmp: Path) -> list[dict]:
    """UDP at ``--fast-rate`` samples/s, 1, 10 and 100 lines a datagram, the view off."""
    VIEW["mode"] = "off"
    return [
        sustain("udp", args.fast_rate, args.fast_duration, tmp, per_datagram=k)
        for k in (1, 10, 100)
    ]


def report_fast(rows: list[dict]) -> None:
    print(
        f"{'source':<7}{'lines/dgram':>12}{'rate Hz':>9}{'dur s':>7}{'sent':>9}"
        f"{'integrated':>11}{'lost':>6}{'by system':>10}{'read every':>11}{'CPU s':>7}"
        f"{'% of a core':>12}"
    )
    for r in rows:
        print(
            f"{'udp':<7}{r['lines_per_datagram']:>12}{r['rate_hz']:>9.0f}{r['duration_s']:>7.0f}"
            f"{r['sent']:>9}{r['integrated']:>11}{r['lost']:>6}{r['lost_by_system']:>10}"
            f"{r['read_ms']:>9.0f}ms{r['cpu_s']:>7.2f}{100 * r['cpu_s'] / r['duration_s']:>11.1f}%"
        )


def replay_cpu(rate_hz: float, duration_s: float, tmp: Path, rounds: int) -> float:
    """Median CPU s of imu_dcm.replay.replay on the same samples, per 1000 samples."""
    import statistics
    import warnings

    from imu_dcm.logio.writers import StampedSeries, write_bag
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


WS_CLIENT = r"""
import json, sys, time
url, which, n, batch_s = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
SUB = ("foxglove.websocket.v1", "foxglove.sdk.v1")
if which == "sync":
    from websockets.sync.client import connect
    import contextlib
    stack = contextlib.ExitStack()
    ws = stack.enter_context(
        connect(url, subprotocols=list(SUB), max_size=None, compression=None, proxy=None)
    )
    close = stack.close
    def batch():
        out = [ws.recv(timeout=30)]
        t_end = time.perf_counter() + batch_s
        while (left := t_end - time.perf_counter()) > 0:
            try:
                out.append(ws.recv(timeout=left))
            except TimeoutError:
                break
        return out
else:
    from imu_dcm.live.sources.websocket import WsConnection
    ws = WsConnection(url, SUB)
    close = ws.close
    def batch():
        out = ws.recv_messages(30)
        time.sleep(batch_s)
        return out + ws.recv_messages(0)
got, cpu0 = 0, None
while got < n:
    for m in batch():
        if isinstance(m, str):
            msg = json.loads(m)
            if msg.get("op") == "advertise":
                cid = msg["channels"][0]["id"]
                sub = {"op": "subscribe", "subscriptions": [{"id": 1, "channelId": cid}]}
                ws.send(json.dumps(sub))
        else:
            if cpu0 is None:
                cpu0 = time.process_time()
            got += 1
print(time.process_time() - cpu0, flush=True)
close()  # the closing handshake (the server logs a reset otherwise)
"""


def ws_client_cpu(which: str, rate_hz: float, duration_s: float) -> float:
    """CPU s of one WebSocket client (``sync`` or ``sansio``) receiving every message."""
    t_ns, w = coning(rate_hz, duration_s)
    box: dict = {}
    feed = feed_ws(t_ns, w, rate_hz, box)
    url = f"ws://127.0.0.1:{box['server'].port}"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-c", WS_CLIENT, url, which, str(len(t_ns)), "0.005"]
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, env=env)
        feed(proc)
        out, _ = proc.communicate(timeout=60)
    finally:
        box["server"].stop()
    return float(out.decode().strip().splitlines()[-1])


def wake_cost(rounds: int = 20) -> tuple[float, float]:
    """The machine's price of a wake-up, measured here: the CPU (ms, medians) of one parse of
    50 plain sample lines run back to back, and run after 50 ms asleep, as live's loop runs it.
    On a machine whose caches and page tables go cold while a process sleeps (a shared or
    nested virtual machine), the second is many times the first, and live's CPU with it."""
    import numpy as np

    from imu_dcm.live.lines import parse_csv_blob

    t_ns, w = coning(1000.0, 0.05)
    blob = b"\n".join(lines_of(t_ns, w))
    warm, cold = [], []
    for _ in range(rounds):
        time.sleep(0.05)
        for out in (cold, warm):  # the first after the sleep, then the same again at once
            c = time.thread_time()
            parse_csv_blob(blob)
            out.append(time.thread_time() - c)
    return 1e3 * float(np.median(warm)), 1e3 * float(np.median(cold))


def measure(args, tmp: Path) -> list[dict]:
    """The rows: each source with the view off and on, then the low-latency setting."""
    rows = []
    for kind in args.sources.split(","):
        for view in ("off", "save"):
            VIEW["mode"] = view
            rows.append({**sustain(kind, args.rate, args.duration, tmp), "view": view})
    VIEW["mode"] = "save"
    for kind in () if args.no_latency else ("ws", "udp"):
        r = sustain(kind, args.rate, args.latency_duration, tmp, 0.0, 10.0)
        rows.append({**r, "view": "save"})
    return rows


def report(rows: list[dict], rep: float, clients: dict, wake: tuple[float, float]) -> None:
    head = (
        f"{'source':<7}{'view':>5}{'rate Hz':>9}{'dur s':>7}{'window':>8}{'every':>7}{'sent':>8}"
        f"{'integrated':>11}{'dropped':>8}{'lost':>6}{'CPU s':>7}{'CPU/kHz':>9}"
        f"{'p50 ms':>8}{'p99 ms':>8}"
    )
    print(head)
    for r in rows:
        print(
            f"{r['source']:<7}{r['view']:>5}{r['rate_hz']:>9.0f}{r['duration_s']:>7.0f}"
            f"{r['window_ms']:>6.0f}ms{r['view_ms']:>5.0f}ms{r['sent']:>8}{r['integrated']:>11}"
            f"{r['dropped']:>8}{r['lost']:>6}{r['cpu_s']:>7.2f}{100 * r['cpu_per_khz']:>8.1f}%"
            f"{r['p50_ms']:>8.1f}{r['p99_ms']:>8.1f}"
        )
    print()
    for view in ("off", "save"):
        k = [r["cpu_per_khz"] for r in rows if r["view"] == view and r["window_ms"] == 50.0]
        if k:
            print(
                f"CPU per 1000 samples/s, view {view}: {100 * min(k):.1f}-{100 * max(k):.1f} % "
                f"of a core (replay on the same samples: {100 * rep:.2f} %)"
            )
    for which, cpu in clients.items():
        print(f"WebSocket client {which}: {cpu:.2f} CPU s")
    print(
        f"This machine's wake-up: one parse of 50 lines costs {wake[0]:.3f} ms of CPU run again "
        f"at once and {wake[1]:.3f} ms after 50 ms asleep ({wake[1] / wake[0]:.0f}x)"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.live_speed",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--rate", type=float, default=1000.0, help="samples/s (default 1000)")
    p.add_argument("--duration", type=float, default=20.0, help="per row, s (default 20)")
    p.add_argument("--latency-duration", type=float, default=20.0, help="s (default 20)")
    p.add_argument("--replay-rounds", type=int, default=3)
    p.add_argument("--sources", default="ws,udp,stdin")
    p.add_argument("--no-latency", action="store_true", help="skip the low-latency rows")
    p.add_argument("--ws-clients", action="store_true", help="also the two WebSocket clients")
    p.add_argument("--json", type=Path, help="also write the rows as JSON")
    p.add_argument(
        "--fast",
        action="store_true",
        help="only the fast rows: UDP at --fast-rate, 1, 10 and 100 lines a datagram, view off",
    )
    p.add_argument("--fast-rate", type=float, default=100_000.0, help="samples/s (100000)")
    p.add_argument("--fast-duration", type=float, default=10.0, help="s (default 10)")
    p.add_argument(
        "--soak",
        action="store_true",
        help="the memory of a long run instead: python -m benchmarks.live_soak's defaults",
    )
    args = p.parse_args(argv)
    if args.soak:  # its own module (which uses this one's helpers), as a user runs it
        return subprocess.call([sys.executable, "-m", "benchmarks.live_soak"], cwd=REPO)
    limit_threads_env()
    if args.fast:
        with tempfile.TemporaryDirectory(prefix="live_speed_") as d:
            rows = fast_rows(args, Path(d))
        print(
            f"imu_dcm live speed, fast rows: {os.cpu_count()} cores, load average "
            f"{os.getloadavg()[0]:.1f} at the end; live as a child process, bias none, magnus4"
        )
        report_fast(rows)
        return 0
    import platform

    import numpy as np

    load_before = os.getloadavg()
    wake = wake_cost()
    with tempfile.TemporaryDirectory(prefix="live_speed_") as d:
        tmp = Path(d)
        rows = measure(args, tmp)
        rep = replay_cpu(args.rate, args.duration, tmp, args.replay_rounds)
    clients = {}
    if args.ws_clients:
        for which in ("sync", "sansio"):
            clients[which] = ws_client_cpu(which, args.rate, args.duration)
    load = "/".join(f"{a:.1f}" for a in (load_before[0], os.getloadavg()[0]))
    print(
        f"imu_dcm live speed: CPython {platform.python_version()}, numpy {np.__version__}, "
        f"{platform.machine()}, {os.cpu_count()} cores, load average {load} (start/end); live as "
        f"a child process, bias none, magnus4"
    )
    print()
    report(rows, rep, clients, wake)
    if args.json:
        out = {
            "rows": rows,
            "replay_cpu_per_1000": rep,
            "ws_clients_cpu_s": clients,
            "load_average": [load_before[0], os.getloadavg()[0]],
            "wake_parse_ms": {"warm": wake[0], "after_50ms_asleep": wake[1]},
        }
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
