"""Live memory over a long run: ``python -m benchmarks.live_soak [--rate 10000] [--duration 600]
[--source stdin|udp]`` (also ``python -m benchmarks.live_speed --soak``).

The live command runs as a child process, as a user runs it (``--rerun off``, ``--bias auto``,
magnus4), fed a coning motion (:func:`benchmarks.live_speed.coning`, made one second at a time,
so the generator holds one second) at ``--rate`` samples/s for ``--duration`` s, paced to the
wall clock, as CSV lines on its stdin (or datagrams of ``--lines`` lines over UDP). The child's
memory is read from ``/proc/PID/status`` every ``--every`` s: its resident set (``VmRSS``) and
its peak (``VmHWM``). Reported: the peak after the first ``--warm`` s (the start: numba, the
kernel and the first buffers are in) and at the end, their difference (the growth; target:
under 50 MB for 10 minutes at 10 kHz) and the growth per sample. Linux only (``/proc``).
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

from benchmarks.live_speed import REPO, T0_NS, free_port, wait_bound
from benchmarks.timing import limit_threads_env


def _memory_kb(pid: int) -> tuple[int, int]:
    """(VmRSS, VmHWM) of process ``pid``, kB."""
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            fields[key] = int(value.split()[0])
    return fields["VmRSS"], fields["VmHWM"]


def _second(k: int, rate_hz: float) -> list[bytes]:
    """The lines of second ``k`` of a coning motion (half-angle 0.3 rad at 0.5 Hz)."""
    import numpy as np

    n = int(rate_hz)
    step = round(1e9 / rate_hz)
    t_ns = T0_NS + (k * n + np.arange(n, dtype=np.int64)) * step
    t = (t_ns - T0_NS) * 1e-9
    beta, om = 0.3, 2 * np.pi * 0.5
    w = om * np.stack(
        [-np.sin(beta) * np.sin(om * t), np.sin(beta) * np.cos(om * t), np.full_like(t, -0.04)],
        axis=1,
    )
    return [
        f"{a // 10**9}.{a % 10**9:09d},{x:.9g},{y:.9g},{z:.9g}".encode()
        for a, (x, y, z) in zip(t_ns.tolist(), w.tolist(), strict=True)
    ]


def soak(rate_hz: float, duration_s: float, source: str, lines: int, every_s: float, warm_s: float):
    """Run the child, feed it, sample its memory; returns the report's figures."""
    tmp = Path(tempfile.mkdtemp(prefix="live_soak_"))
    summary = tmp / "summary.json"
    port = free_port()
    where = "-" if source == "stdin" else f"udp://127.0.0.1:{port}"
    cmd = [sys.executable, "-m", "imu_dcm.live", where, "--rerun", "off", "--bias", "auto"]
    cmd += ["--summary-json", str(summary), "--no-status", "--quiet", "--idle-stop", "2"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        cmd,
        stdin=subprocess.PIPE if source == "stdin" else subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    samples: list[tuple[float, int, int]] = []  # (s since the feed started, rss, hwm) kB
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        if source == "udp":
            wait_bound(proc, port)
        time.sleep(1.0)
        start = time.perf_counter()
        next_mem = start
        for k in range(int(duration_s)):
            block = _second(k, rate_hz)
            per = int(rate_hz) // 100  # sent 100 times a second
            for j in range(100):
                due = start + k + j / 100
                while (wait := due - time.perf_counter()) > 0:
                    time.sleep(min(wait, 0.005))
                part = block[j * per : (j + 1) * per]
                if source == "stdin":
                    proc.stdin.write(b"\n".join(part) + b"\n")
                    proc.stdin.flush()
                else:
                    for i in range(0, len(part), lines):
                        sock.sendto(b"\n".join(part[i : i + lines]), ("127.0.0.1", port))
            if time.perf_counter() >= next_mem:
                samples.append((time.perf_counter() - start, *_memory_kb(proc.pid)))
                next_mem += every_s
        samples.append((time.perf_counter() - start, *_memory_kb(proc.pid)))
        if source == "stdin":
            proc.stdin.close()
        proc.wait(timeout=120)
    finally:
        sock.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    s = json.loads(summary.read_text())
    summary.unlink()
    tmp.rmdir()
    start_hwm = next(h for t, _, h in samples if t >= warm_s)
    end_hwm = samples[-1][2]
    n = int(rate_hz) * int(duration_s)
    return {
        "source": source,
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "sent": n,
        "integrated": s["samples"],
        "start_hwm_mb": start_hwm / 1024,
        "end_hwm_mb": end_hwm / 1024,
        "growth_mb": (end_hwm - start_hwm) / 1024,
        "bytes_per_sample": (end_hwm - start_hwm) * 1024 / max(1, n - int(warm_s * rate_hz)),
        "rss_mb": [(round(t), round(r / 1024, 1)) for t, r, _ in samples],
        "cpu_s": s["cpu_s"],
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.live_soak", description=__doc__)
    p.add_argument("--rate", type=float, default=10_000.0, help="samples/s (default 10000)")
    p.add_argument("--duration", type=float, default=600.0, help="s (default 600)")
    p.add_argument("--source", choices=("stdin", "udp"), default="stdin")
    p.add_argument("--lines", type=int, default=10, help="udp: lines a datagram (default 10)")
    p.add_argument("--every", type=float, default=10.0, help="memory read every S s (10)")
    p.add_argument("--warm", type=float, default=30.0, help="the start's peak after S s (30)")
    args = p.parse_args(argv)
    limit_threads_env()
    r = soak(args.rate, args.duration, args.source, args.lines, args.every, args.warm)
    print(
        f"imu_dcm live soak: {r['source']}, {r['rate_hz']:.0f} samples/s for "
        f"{r['duration_s']:.0f} s, load average {os.getloadavg()[0]:.1f} at the end"
    )
    print(f"sent {r['sent']}, integrated {r['integrated']}, live CPU {r['cpu_s']:.1f} s")
    print(
        f"peak RSS after {args.warm:.0f} s: {r['start_hwm_mb']:.1f} MB; at the end: "
        f"{r['end_hwm_mb']:.1f} MB; growth {r['growth_mb']:.1f} MB "
        f"({r['bytes_per_sample']:.2f} bytes a sample; target: under 50 MB)"
    )
    print("RSS (s, MB): " + ", ".join(f"{t}: {m}" for t, m in r["rss_mb"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
