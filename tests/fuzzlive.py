"""Fuzz harness for the live sources: seeded bad messages among known good samples, and one
bounded run of ``python -m imu_dcm.live`` per case (a subprocess: its real exit code, stdout and
stderr).

The good samples are a constant 90 deg/s spin about z at 200 Hz (stamps k * 5 ms), so every
method integrates them exactly, over any step: the final attitude is the rotation by
90 deg/s * ``final_t_s`` about z, whatever was dropped. A bad message with a stamp takes a
half-step stamp (k + 1/2) * 5 ms, so it can never make a good sample a duplicate.
"""

from __future__ import annotations

import builtins
import dataclasses
import decimal
import json
import math
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RATE_HZ, SPIN_DEG_S = 200, 90.0
STEP_S = 1.0 / RATE_HZ
#: A case's run ends 0.4 s after its last sample (--idle-stop) and is killed after this long.
RUN_TIMEOUT_S = 30.0
IDLE_STOP_S = 0.4
#: Every Python exception class name (builtins and decimal's): none may reach the user.
EXCEPTION_NAMES = sorted(
    {
        n
        for n in dir(builtins)
        if isinstance(getattr(builtins, n), type)
        and issubclass(getattr(builtins, n), Exception)
        and not issubclass(getattr(builtins, n), Warning)
    }
    | {
        n
        for n in dir(decimal)
        if isinstance(getattr(decimal, n), type)
        and issubclass(getattr(decimal, n), ArithmeticError)
    }
)
_EXC_RE = re.compile(r"\b(" + "|".join(EXCEPTION_NAMES) + r")\b|Traceback")


def good_t(k: int) -> str:
    return f"{k * STEP_S:.3f}"


def bad_t(k: int) -> str:
    return f"{(k + 0.5) * STEP_S:.4f}"


def good_line(k: int, fmt: str) -> bytes:
    if fmt == "csv":
        return f"{good_t(k)},0,0,{SPIN_DEG_S!r}".encode()
    return json.dumps({"t_s": float(good_t(k)), "omega_b": [0, 0, SPIN_DEG_S]}).encode()


def garbage(rng: np.random.Generator, lo: int, hi: int) -> bytes:
    while True:
        b = bytes(rng.integers(0, 256, int(rng.integers(lo, hi)), dtype=np.uint8))
        b = b.replace(b"\n", b"").replace(b"\r", b"")
        if b.strip():
            return b


def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


#: Line damage by class: each a function (rng, k, fmt, udp) -> bytes, one bad line (no line
#: end) to sit between good samples k and k + 1.
def _truncated(rng, k, fmt, udp):
    g = good_line(k, fmt).decode()
    if fmt == "csv":  # cut before the last comma: three fields at most, never a valid sample
        return g[: int(rng.integers(1, g.rindex(",")))].encode()
    return g[: int(rng.integers(1, len(g)))].encode()


def _huge(rng, k, fmt, udp):
    v = ["1e30", "-3e38", "1.7e308", "1e400", "9" * 400, "-" + "9" * 5000][int(rng.integers(6))]
    if fmt == "csv":
        return f"{bad_t(k)},0,{v},0".encode()
    return ('{"t_s": ' + bad_t(k) + ', "omega_b": [0, ' + v + ", 0]}").encode()


def _nonfinite(rng, k, fmt, udp):
    if fmt == "csv":
        v = ["nan", "inf", "-inf", "NaN", "-nan", "Infinity"][int(rng.integers(6))]
        return f"{bad_t(k)},{v},0,0".encode()
    v = ["NaN", "Infinity", "-Infinity"][int(rng.integers(3))]
    return ('{"t_s": ' + bad_t(k) + ', "omega_b": [0, 0, ' + v + "]}").encode()


def _wrong_type(rng, k, fmt, udp):
    t = bad_t(k)
    options = [
        {"t_s": True, "omega_b": [0, 0, 1]},
        {"t_s": [float(t)], "omega_b": [0, 0, 1]},
        {"t_s": None, "omega_b": [0, 0, 1]},
        {"t_s": {"s": 1}, "omega_b": [0, 0, 1]},
        {"t_ns": 1.5e9, "omega_b": [0, 0, 1]},
        {"t_ns": "5", "omega_b": [0, 0, 1]},
        {"t_s": float(t), "omega_b": "0,0,1"},
        {"t_s": float(t), "omega_b": {"x": 0}},
        {"t_s": float(t), "omega_b": [0, 0]},
        {"t_s": float(t), "omega_b": [True, 0, 0]},
        {"t_s": float(t), "omega_b": ["a", 0, 0]},
        {"t_s": float(t), "omega_b": [None, 0, 0]},
        {"t_s": float(t), "omega_b": [[0], 0, 0]},
        {"t_s": float(t), "gx": 0},
        {"t_s": float(t), "omega_b": [0, 0, 1], "q_w_b": "identity"},
        {"t_s": float(t), "omega_b": [0, 0, 1], "q_w_b": [0, 0, 0, None]},
        [float(t), 0, 0, 1],
        "a string",
        42,
    ]
    return json.dumps(options[int(rng.integers(len(options)))]).encode()


def _deep(rng, k, fmt, udp):
    depth = int(rng.integers(1000, 30_000))  # under 64 KiB: parsed, not dropped for its length
    where = int(rng.integers(3))
    if where == 0:
        return ('{"t_s": ' + bad_t(k) + ', "omega_b": ' + _nested(depth) + "}").encode()
    if where == 1:
        return ('{"t_s": ' + bad_t(k) + ', "x": ' + _nested(depth) + "}").encode()
    return ("{" + '"a": {' * (depth // 8) + "}" * (depth // 8) + "}").encode()


def _stamp(rng, k, fmt, udp):
    if fmt == "csv":
        v = ["-0.5", "9.3e18", "1e999999999", "-1e-3", "1e999990", "0x10"]
        return f"{v[int(rng.integers(len(v)))]},0,0,1".encode()
    v = [
        '"t_s": -1',
        '"t_s": 1e300',
        '"t_s": "1e999999999"',
        '"t_s": 1e999',
        f'"t_ns": {2**63}',
        f'"t_ns": {2**70}',
        '"t_ns": -5',
        '"t_ns": 1' + "0" * 5000,
    ]
    return ("{" + v[int(rng.integers(len(v)))] + ', "omega_b": [0, 0, 1]}').encode()


def _oversize(rng, k, fmt, udp):
    # stdin: past the 64 KiB a line may hold; UDP: a datagram near the 64 KiB UDP limit
    n = int(rng.integers(40_000, 65_000)) if udp else int(rng.integers(65_537, 200_000))
    if rng.integers(2):
        return f"{bad_t(k)},0,0,".encode() + b"9" * n
    return b"1," * (n // 2)


def _garbage_line(rng, k, fmt, udp):
    return garbage(rng, 1, 300)


LINE_DAMAGE = {
    "garbage": _garbage_line,
    "truncated": _truncated,
    "huge": _huge,
    "nonfinite": _nonfinite,
    "wrong_type": _wrong_type,
    "deep": _deep,
    "stamp": _stamp,
    "oversize": _oversize,
}


@dataclasses.dataclass(frozen=True)
class LineCase:
    """A stream of ``n_good`` good lines with ``bad`` lines after the good lines ``after``."""

    name: str
    fmt: str
    n_good: int
    bad: tuple[bytes, ...]
    after: tuple[int, ...]

    def lines(self) -> list[bytes]:
        by_k: dict[int, list[bytes]] = {}
        for k, b in zip(self.after, self.bad, strict=True):
            by_k.setdefault(k, []).append(b)
        out = []
        for k in range(self.n_good):
            out.append(good_line(k, self.fmt))
            out += by_k.get(k, [])
        return out


def line_cases(rng: np.random.Generator, per_class: int, n_good: int, udp: bool) -> list[LineCase]:
    """``per_class`` cases of each damage class, 1 to 4 bad lines each at random places (never
    before the first good line: a first line may be a header)."""
    cases = []
    for cls, make in LINE_DAMAGE.items():
        for i in range(per_class):
            fmt = "json" if cls in ("wrong_type", "deep") else ("csv", "json")[int(rng.integers(2))]
            n_bad = int(rng.integers(1, 5))
            after = tuple(sorted(int(a) for a in rng.integers(0, n_good - 1, n_bad)))
            bad = tuple(make(rng, k, fmt, udp) for k in after)
            cases.append(LineCase(f"{cls}-{i}-{fmt}", fmt, n_good, bad, after))
    return cases


# ------------------------------------------------------------------------------------- runs
@dataclasses.dataclass
class Run:
    rc: int | None
    stdout: str
    stderr: str
    summary: dict | None
    hang: bool
    nan_in_json: bool = False


def live_argv(source: str, summary: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "imu_dcm.live",
        source,
        "--rerun",
        "off",
        "--no-status",
        "--gyro-units",
        "deg/s",
        "--bias",
        "none",
        "--idle-stop",
        str(IDLE_STOP_S),
        "--give-up",
        "3",
        "--summary-json",
        str(summary),
        *extra,
    ]


def _reject_constant(name):
    raise ValueError(name)


def finish(proc: subprocess.Popen, summary: Path, stdin: bytes | None = None) -> Run:
    """Wait for ``proc`` (feeding ``stdin``) up to :data:`RUN_TIMEOUT_S`; read its summary."""
    hang = False
    try:
        out, err = proc.communicate(stdin, timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        hang = True
    s, nan = None, False
    if summary.exists():
        text = summary.read_text()
        try:
            s = json.loads(text, parse_constant=_reject_constant)
        except ValueError:
            nan, s = True, json.loads(text)
    return Run(
        proc.returncode, out.decode(errors="replace"), err.decode(errors="replace"), s, hang, nan
    )


def start(argv: list[str], stdin: bool = False) -> subprocess.Popen:
    return subprocess.Popen(
        argv,
        stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def send_datagrams(
    port: int, datagrams: list[bytes], pause_every: int = 20, pause_s: float = 0.004
) -> None:
    """One datagram each, paced (``pause_s`` every ``pause_every``) so loopback rarely drops."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for i, d in enumerate(datagrams):
            tx.sendto(d, ("127.0.0.1", port))
            if i % pause_every == pause_every - 1:
                time.sleep(pause_s)


def violations(
    run: Run, *, expect_samples: bool, rate_z_rad_s: float = math.radians(SPIN_DEG_S)
) -> list[str]:
    """The rules every live case keeps, whatever the source (the good samples turn the body
    at ``rate_z_rad_s`` about its z axis, FLU)."""
    v = []
    if run.hang:
        return [f"hang (> {RUN_TIMEOUT_S:g} s)"]
    m = _EXC_RE.search(run.stdout + run.stderr)
    if m:
        v.append(f"{m.group(0)} in the output")
    if run.rc not in (0, 1, 2):
        v.append(f"exit {run.rc}")
    elif expect_samples and run.rc != 0:
        v.append(f"exit {run.rc} with good samples sent")
    if run.summary is None:
        v.append("no --summary-json")
    if run.nan_in_json:
        v.append("NaN or Infinity in the JSON")
    if run.summary is not None and run.rc == 0:
        s = run.summary
        q = np.array(s["final_q_w_b"], dtype=float)
        if not np.all(np.isfinite(q)):
            v.append("a non-finite attitude")
        else:
            # the exact spin: the angle about z is 90 deg/s times the time integrated
            want = rate_z_rad_s * s["final_t_s"]
            err = abs(2 * math.atan2(q[2], q[3]) - want)
            if err > 1e-9 or abs(q[0]) + abs(q[1]) > 1e-12:
                v.append(f"final attitude off by {math.degrees(err):.3g} deg")
    if v:
        v.append(f"stderr {run.stderr.strip()[-300:]!r}")
    return v


def bad_counted(s: dict) -> int:
    return s["malformed"] + s["dropped_nonfinite"] + s["dropped_implausible"]
