"""Fuzz harness: damaged logs, hostile paths, and a worker process that runs each case bounded.

The harness knows nothing about how the reader works. It builds small valid logs (a slice of a
shipped BROAD trial, a data_synth scene), damages them at the byte level (its own MCAP record
walker below, after the MCAP specification: magic, then records ``opcode u8, length u64, body``),
and runs every case in a long-lived worker process (:func:`worker_main`) that

* calls the replay command line in-process (``main(argv)``, stderr captured) or the library
  (:data:`read_log`, :func:`imu_dcm.replay.replay`);
* stops a case after ``timeout_s`` (SIGALRM, then the parent kills the worker);
* measures the peak resident memory of the case (``VmHWM`` reset through ``/proc/self/clear_refs``)
  under an address-space limit, so a bomb cannot take the machine down.

The parent (:class:`Pool`) hashes the input before and after, snapshots the output folder, and
turns each result into a list of violated rules (:func:`judge`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import os
import queue
import select
import signal
import stat
import struct
import subprocess
import sys
import threading
import time
import traceback
import zlib
from collections.abc import Callable
from pathlib import Path

from loopback import free_udp_port

MAGIC = b"\x89MCAP0\r\n"
OP = {
    "header": 0x01,
    "footer": 0x02,
    "schema": 0x03,
    "channel": 0x04,
    "message": 0x05,
    "chunk": 0x06,
    "message_index": 0x07,
    "chunk_index": 0x08,
    "statistics": 0x0B,
    "metadata": 0x0C,
    "metadata_index": 0x0D,
    "summary_offset": 0x0E,
    "data_end": 0x0F,
}
OP_NAME = {v: k for k, v in OP.items()}
PROG_PREFIX = "imu-dcm-replay: "
#: The command-line kinds: ``cli`` (one replay), ``live`` and ``batch`` (hostile outputs), with
#: the prefix of their stderr lines.
CLI_KINDS = {"cli": PROG_PREFIX, "live": "imu-dcm-live: ", "batch": "imu-dcm-replay batch: "}
#: Peak resident memory a case may add over the worker's baseline (the logs are < 1 MB).
MEMORY_LIMIT_BYTES = 512 * 2**20
#: Address space the worker may add after its imports: a bomb gets MemoryError, not the machine.
ADDRESS_SPACE_HEADROOM = 3 * 2**29
#: A case runs in well under a second (0.05-0.2 s measured on a loaded 2-core machine).
CASE_TIMEOUT_S = 8.0


# ------------------------------------------------------------------------------ MCAP bytes
@dataclasses.dataclass(frozen=True)
class Rec:
    """A top-level record: opcode, file offsets of its start, body and end."""

    op: int
    start: int
    body: int
    end: int

    @property
    def name(self) -> str:
        return OP_NAME.get(self.op, f"0x{self.op:02x}")


@dataclasses.dataclass(frozen=True)
class ChunkInfo:
    """A chunk record: where its fields sit in the file, and its decompressed records."""

    rec: Rec
    size_at: int  # file offset of uncompressed_size (u64); the CRC (u32) follows it
    compression: str
    data_at: int  # file offset of the compressed bytes (after their u64 length at data_at - 8)
    data_len: int
    raw: bytes  # decompressed records
    messages: tuple[tuple[int, int, int], ...]  # (channel id, offset in raw, record end in raw)

    def count(self, channel_id: int) -> int:
        return sum(1 for c, _, _ in self.messages if c == channel_id)


def walk(buf: bytes) -> list[Rec]:
    """Top-level records of a valid MCAP file, the footer last."""
    assert buf[:8] == MAGIC
    out, pos = [], 8
    while pos + 9 <= len(buf):
        op, length = struct.unpack_from("<BQ", buf, pos)
        rec = Rec(op, pos, pos + 9, pos + 9 + length)
        out.append(rec)
        pos = rec.end
        if op == OP["footer"]:
            break
    return out


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    return bytes(data)


def compress(compression: str, raw: bytes) -> bytes:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdCompressor().compress(raw)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.compress(raw)
    return bytes(raw)


def inner_records(raw: bytes) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of the records inside a decompressed chunk."""
    out, pos = [], 0
    while pos + 9 <= len(raw):
        op, length = struct.unpack_from("<BQ", raw, pos)
        out.append((op, pos, pos + 9 + length))
        pos += 9 + length
    return out


def chunk_info(buf: bytes, rec: Rec) -> ChunkInfo:
    p = rec.body + 16
    size_at = p
    size, _crc = struct.unpack_from("<QI", buf, p)
    p += 12
    (clen,) = struct.unpack_from("<I", buf, p)
    compression = buf[p + 4 : p + 4 + clen].decode()
    p += 4 + clen
    (dlen,) = struct.unpack_from("<Q", buf, p)
    raw = _decompress(compression, buf[p + 8 : p + 8 + dlen], size)
    msgs = tuple(
        (struct.unpack_from("<H", raw, s + 9)[0], s, e)
        for op, s, e in inner_records(raw)
        if op == OP["message"]
    )
    return ChunkInfo(rec, size_at, compression, p + 8, dlen, raw, msgs)


def chunk_record(
    start_ns: int,
    end_ns: int,
    raw: bytes,
    compression: str,
    declared_size: int | None = None,
    crc: int | None = None,
    data: bytes | None = None,
) -> bytes:
    """A chunk record holding ``raw`` (compressed here unless ``data`` is given)."""
    data = compress(compression, raw) if data is None else data
    body = (
        struct.pack(
            "<QQQI",
            start_ns,
            end_ns,
            len(raw) if declared_size is None else declared_size,
            zlib.crc32(raw) if crc is None else crc,
        )
        + struct.pack("<I", len(compression))
        + compression.encode()
        + struct.pack("<Q", len(data))
        + data
    )
    return struct.pack("<BQ", OP["chunk"], len(body)) + body


def without_summary(
    buf: bytes, replace: dict[int, bytes] | None = None, insert: bytes = b""
) -> bytes:
    """The file rebuilt as a data section only (summary dropped, footer zeroed): records
    ``replace``d by index, ``insert`` placed before DataEnd. Valid MCAP (a streamed file)."""
    replace = replace or {}
    recs = walk(buf)
    parts = [MAGIC]
    for i, r in enumerate(recs):
        if r.op == OP["data_end"]:
            parts.append(insert)
            parts.append(buf[r.start : r.end])
            break
        parts.append(replace.get(i, buf[r.start : r.end]))
    footer = struct.pack("<QQI", 0, 0, 0)
    parts.append(struct.pack("<BQ", OP["footer"], len(footer)) + footer + MAGIC)
    return b"".join(parts)


def _str(x: str | bytes) -> bytes:
    b = x.encode() if isinstance(x, str) else x
    return struct.pack("<I", len(b)) + b


def _record(op: str, body: bytes) -> bytes:
    return struct.pack("<BQ", OP[op], len(body)) + body


def json_log(
    payloads: list[bytes], t_ns: list[int], per_chunk: int = 40, topic: str = "/imu/json"
) -> bytes:
    """An MCAP file of one schema-less JSON channel, ``per_chunk`` messages to a zstd chunk
    (so message j sits in chunk j // per_chunk); data section only."""
    parts = [MAGIC, _record("header", _str("") + _str("fuzzlib"))]
    channel = _record(
        "channel", struct.pack("<HH", 1, 0) + _str(topic) + _str("json") + struct.pack("<I", 0)
    )
    for a in range(0, len(payloads), per_chunk):
        recs = [channel] if a == 0 else []
        for j in range(a, min(a + per_chunk, len(payloads))):
            recs.append(
                _record("message", struct.pack("<HIQQ", 1, j, t_ns[j], t_ns[j]) + payloads[j])
            )
        parts.append(
            chunk_record(
                t_ns[a], t_ns[min(a + per_chunk, len(payloads)) - 1], b"".join(recs), "zstd"
            )
        )
    parts.append(_record("data_end", struct.pack("<I", 0)))
    parts.append(_record("footer", struct.pack("<QQI", 0, 0, 0)) + MAGIC)
    return b"".join(parts)


# -------------------------------------------------------------------------------- base logs
@dataclasses.dataclass
class Base:
    """A small valid bag folder and what the harness knows about it."""

    name: str
    folder: Path
    mcap: Path
    imu_channel: int
    imu_total: int  # IMU messages in the file
    chunks: list[ChunkInfo]
    records: list[Rec]
    clean: dict = dataclasses.field(default_factory=dict)  # kind -> samples on the clean log

    @property
    def bytes(self) -> bytes:
        return self.mcap.read_bytes()

    def lost_in(self, *chunk_indexes: int) -> int:
        return sum(self.chunks[k].count(self.imu_channel) for k in set(chunk_indexes))

    def chunk_at(self, offset: int) -> int | None:
        """Index of the chunk whose record holds file ``offset``, else None."""
        for k, c in enumerate(self.chunks):
            if c.rec.start <= offset < c.rec.end:
                return k
        return None


METADATA = """rosbag2_bagfile_information:
  version: 5
  storage_identifier: mcap
  relative_file_paths:
  - {name}.mcap
  duration:
    nanoseconds: {duration}
  starting_time:
    nanoseconds_since_epoch: {start}
  message_count: {count}
  compression_format: ''
  compression_mode: ''
  topics_with_message_count: []
  custom_data:
    fuzz.source: {source}
"""


def rewrite_bag(
    src_mcap: Path,
    dst: Path,
    *,
    t_end_ns: int | None,
    chunk_size: int,
    compression: str,
    source: str,
    schema_hook: Callable | None = None,
) -> Path:
    """Copy the messages of ``src_mcap`` up to ``t_end_ns`` (log time) into a new bag folder
    ``dst`` with small chunks (so damage can hit one chunk of several). ``schema_hook(name,
    encoding, data) -> (name, encoding, data)`` may rewrite the schemas."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    ctype = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "": CompressionType.NONE}[
        compression
    ]
    dst.mkdir(parents=True)
    out = dst / f"{dst.name}.mcap"
    count, first, last = 0, None, None
    with open(src_mcap, "rb") as f, open(out, "wb") as g:
        reader = make_reader(f)
        w = Writer(g, chunk_size=chunk_size, compression=ctype)
        w.start(profile="ros2", library="fuzzlib")
        schema_ids, channel_ids = {}, {}
        for schema, channel, msg in reader.iter_messages(ending_at=t_end_ns, log_time_order=False):
            if schema.id not in schema_ids:
                fields = (schema.name, schema.encoding, schema.data)
                schema_ids[schema.id] = w.register_schema(*(schema_hook or _same)(*fields))
            if channel.id not in channel_ids:
                channel_ids[channel.id] = w.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schema_ids[schema.id],
                    dict(channel.metadata),
                )
            w.add_message(
                channel_ids[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence
            )
            count += 1
            first = msg.log_time if first is None else min(first, msg.log_time)
            last = msg.log_time if last is None else max(last, msg.log_time)
        w.finish()
    (dst / "metadata.yaml").write_text(
        METADATA.format(
            name=dst.name, duration=last - first, start=first, count=count, source=source
        )
    )
    return dst


def _same(*fields):
    return fields


def load_base(name: str, folder: Path, imu_topic: str = "/imu/data") -> Base:
    (mcap,) = folder.glob("*.mcap")
    buf = mcap.read_bytes()
    recs = walk(buf)
    chunks = [chunk_info(buf, r) for r in recs if r.op == OP["chunk"]]
    imu_channel = None
    for c in chunks:
        for op, s, _e in inner_records(c.raw):
            if op == OP["channel"]:
                cid, _sid, tlen = struct.unpack_from("<HHI", c.raw, s + 9)
                if c.raw[s + 17 : s + 17 + tlen].decode() == imu_topic:
                    imu_channel = cid
    assert imu_channel is not None, "no IMU channel record inside the chunks"
    total = sum(c.count(imu_channel) for c in chunks)
    return Base(name, folder, mcap, imu_channel, total, chunks, recs)


# -------------------------------------------------------------------------------- snapshots
def snapshot(root: Path) -> dict[str, tuple]:
    """Every node under ``root`` (not following links): type, and bytes' hash for files.
    Special files are never opened."""
    out: dict[str, tuple] = {}
    if not (root.exists() or root.is_symlink()):
        return out
    nodes = [root]
    if root.is_dir() and not root.is_symlink():
        for dirpath, dirnames, filenames in os.walk(root):
            nodes += [Path(dirpath) / n for n in dirnames + filenames]
    for p in nodes:
        st = p.lstat()
        key = str(p.relative_to(root))
        if stat.S_ISLNK(st.st_mode):
            out[key] = ("link", os.readlink(p))
        elif stat.S_ISREG(st.st_mode):
            out[key] = ("file", hashlib.sha256(p.read_bytes()).hexdigest())
        elif stat.S_ISDIR(st.st_mode):
            out[key] = ("dir",)
        else:
            out[key] = ("special", stat.S_IFMT(st.st_mode), st.st_rdev)
    return out


# ------------------------------------------------------------------------------------- cases
@dataclasses.dataclass
class Case:
    """One fuzz case.

    ``make(d)`` writes the input under ``d / "in"`` (and any pre-existing output nodes under
    ``d / "out"``) and returns ``(log_path, extra_argv)``. ``lost``: IMU samples the damage may
    cost (None: any, an exit 2 is fine). ``refuse``: only exit 2 is right (hostile outputs).
    ``kinds``: what runs it (``cli``, ``read_log``, ``replay``; ``live`` and ``batch`` for
    hostile outputs). ``fix``: what it exercises.
    """

    cls: str
    name: str
    base: str
    make: Callable[[Path], tuple[Path, list[str]]]
    lost: int | None
    kinds: tuple[str, ...] = ("cli", "read_log", "replay")
    refuse: bool = False
    fix: str = ""

    @property
    def id(self) -> str:
        return f"{self.cls}/{self.base}/{self.name}"


@dataclasses.dataclass
class Verdict:
    case: Case
    kind: str
    result: dict
    violations: list[str]

    def line(self) -> str:
        r = self.result
        got = f"exit {r.get('rc')}" if self.kind in CLI_KINDS else f"{r.get('exc_type') or 'ok'}"
        msg = (r.get("stderr") or r.get("exc_msg") or "").strip().splitlines()
        tail = f" | {msg[-1][:160]}" if msg else ""
        return f"{self.case.id} [{self.kind}] {got}: {'; '.join(self.violations)}{tail}"


def judge(
    case: Case,
    kind: str,
    r: dict,
    base: Base | None,
    before_in: dict,
    after_in: dict,
    before_out: dict,
    after_out: dict,
    summary: Path | None,
) -> list[str]:
    """The rules every case must keep (see tests/test_fuzz.py)."""
    v: list[str] = []
    if r.get("hang"):
        return [f"hang (> {CASE_TIMEOUT_S:g} s)"] + (
            ["input changed"] if before_in != after_in else []
        )
    if r.get("peak_bytes", 0) > MEMORY_LIMIT_BYTES:
        v.append(f"memory {r['peak_bytes'] / 2**20:.0f} MiB > {MEMORY_LIMIT_BYTES / 2**20:.0f}")
    if r.get("escaped"):
        v.append(f"traceback ({r['exc_type']})")
    changed = sorted(k for k in before_in if after_in.get(k) != before_in[k])
    if changed:
        v.append(f"input changed: {changed[:3]}")
    replaced = sorted(
        k for k, node in before_out.items() if node[0] == "special" and after_out.get(k) != node
    )
    if replaced:
        v.append(f"special file replaced or removed: {replaced}")
    files = sorted(
        k for k, node in before_out.items() if node[0] == "file" and after_out.get(k) != node
    )
    if files:
        v.append(f"file replaced or removed: {files[:3]}")
    samples = None
    if kind in CLI_KINDS:
        prefix = CLI_KINDS[kind]
        rc, err = r.get("rc"), r.get("stderr", "")
        lines = [ln for ln in err.splitlines() if ln.strip()]
        if "Traceback" in err:
            v.append("traceback on stderr")
        if rc == 2:
            if len(lines) != 1 or not lines[0].startswith(prefix + "error:"):
                v.append(f"exit 2 with {len(lines)} stderr lines (expected one error line)")
            if after_out != before_out:
                extra = sorted(set(after_out) - set(before_out)) or sorted(
                    k for k in before_out if after_out.get(k) != before_out[k]
                )
                v.append(f"output left behind or changed on exit 2: {extra[:3]}")
        elif rc == 0:
            bad = [ln for ln in lines if not ln.startswith(prefix + "warning:")]
            if bad:
                v.append(f"exit 0 with non-warning stderr: {bad[0][:80]!r}")
            if case.refuse:
                v.append("exit 0 where only a refusal is safe")
            if summary is not None:
                samples = r.get("samples")
                if samples is None:
                    v.append("exit 0 without a readable --summary-json")
        elif case.refuse and not r.get("escaped"):
            v.append(f"exit {rc} where only a refusal (exit 2) is safe")
        elif not r.get("escaped"):
            v.append(f"exit {rc} (expected 0 or 2)")
        ok = rc == 0
    else:
        if r.get("escaped"):
            pass
        elif r.get("exc_type") and not r.get("is_imu_dcm_error"):
            v.append(f"raised {r['exc_type']} (not an ImuDcmError)")
        ok = not r.get("exc_type")
        samples = r.get("samples") if ok else None
        if ok and r.get("nonfinite_score"):
            v.append("a non-finite estimate was scored")
    if base is not None and case.lost is not None:
        floor = (base.clean.get(kind) or base.imu_total) - case.lost
        if ok and samples is not None and samples < floor:
            v.append(f"kept {samples} samples, expected >= {floor} (damage held {case.lost})")
        warned = (
            r.get("reported")
            if kind != "cli"
            else any(
                ln.startswith(PROG_PREFIX + "warning:") for ln in r.get("stderr", "").splitlines()
            )
        )
        if ok and samples is not None and samples < (base.clean.get(kind) or 0) and not warned:
            v.append(
                "samples lost without a warning"
                + (" or a damage record" if kind == "read_log" else "")
            )
        if not ok and not r.get("hang") and floor > 0:
            v.append(f"refused a log with {floor} intact IMU samples")
    return v


# ------------------------------------------------------------------------------------ worker
def _vm(field: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    return 0


class _Hang(BaseException):
    """Raised by SIGALRM inside a case that runs too long."""


@contextlib.contextmanager
def stdin_from(path: str | None):
    """fd 0 reads ``path`` for the block (the worker's requests wait in ``sys.stdin``'s buffer
    and on the saved fd, restored after)."""
    if path is None:
        yield
        return
    saved = os.dup(0)
    fd = os.open(path, os.O_RDONLY)
    try:
        os.dup2(fd, 0)
        yield
    finally:
        os.dup2(saved, 0)
        os.close(saved)
        os.close(fd)


def _run_case(op: dict) -> dict:
    # The one import line of the reader: repoint when the reader moves (imu_dcm.logio).
    import warnings

    from imu_dcm.errors import ImuDcmError
    from imu_dcm.logio import read_log
    from imu_dcm.replay import replay
    from imu_dcm.replay.__main__ import main as replay_main

    kind = op["kind"]
    r: dict = {}
    out, err = io.StringIO(), io.StringIO()
    try:
        with (
            stdin_from(op.get("stdin")),
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            warnings.catch_warnings(record=True) as caught,
        ):
            warnings.simplefilter("always")
            if kind in CLI_KINDS:
                from imu_dcm.live.__main__ import main as live_main

                run_main = live_main if kind == "live" else replay_main
                try:
                    r["rc"] = run_main(list(op["argv"]))
                except SystemExit as exc:
                    r["rc"] = exc.code if isinstance(exc.code, int) else 2
            elif kind == "read_log":
                data = read_log(op["path"])
                r["samples"] = len(data.imu.t_ns)
                r["reported"] = bool(
                    getattr(data, "damage", ()) or getattr(data, "stopped_at", None)
                )
            else:
                res = replay(op["path"])
                r["samples"] = len(res.t_ns)
                s = res.summary
                rms = (
                    s.get("rms_error_deg")
                    if isinstance(s, dict)
                    else getattr(s, "rms_error_deg", None)
                )
                r["nonfinite_score"] = rms is not None and not (
                    float(rms) == float(rms) and abs(float(rms)) < 1e300
                )
            r["reported"] = r.get("reported", False) or bool(caught)
    except _Hang:
        r["hang"] = True
    except ImuDcmError as exc:
        r.update(exc_type=type(exc).__name__, exc_msg=str(exc)[:300], is_imu_dcm_error=True)
    except BaseException as exc:
        r.update(
            exc_type=type(exc).__name__,
            exc_msg=str(exc)[:300],
            escaped=True,
            traceback=traceback.format_exc()[-2000:],
            is_imu_dcm_error=False,
        )
    r["stdout"], r["stderr"] = out.getvalue()[-2000:], err.getvalue()[: 1 << 20]
    return r


def worker_main() -> None:
    """Serve cases: one JSON request per line on stdin, one JSON answer per line on fd 3's dup."""
    import resource

    proto = os.fdopen(os.dup(1), "w")
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)  # stray prints of C code never corrupt the protocol
    import imu_dcm.replay.__main__  # noqa: F401 - imports before the address-space limit

    _run_case({"kind": "read_log", "path": "/nonexistent"})
    limit = _vm("VmSize") + ADDRESS_SPACE_HEADROOM
    resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))

    def on_alarm(signum, frame):
        raise _Hang

    signal.signal(signal.SIGALRM, on_alarm)
    for line in sys.stdin:
        op = json.loads(line)
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")  # reset the peak RSS (VmHWM) to the current RSS
        except OSError:
            pass
        rss0 = _vm("VmRSS")
        t0 = time.monotonic()
        signal.setitimer(signal.ITIMER_REAL, float(op.get("timeout", CASE_TIMEOUT_S)))
        try:
            r = _run_case(op)
        except _Hang:
            r = {"hang": True}
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        r["elapsed_s"] = time.monotonic() - t0
        r["peak_bytes"] = max(0, _vm("VmHWM") - rss0)
        proto.write(json.dumps(r) + "\n")
        proto.flush()


class Worker:
    """A worker subprocess (started and killed only by this object, by its own pid)."""

    def __init__(self, repo: Path):
        env = dict(
            os.environ,
            PYTHONPATH=os.pathsep.join([str(repo), str(repo / "tests")]),
            OMP_NUM_THREADS="1",
            OPENBLAS_NUM_THREADS="1",
            MKL_NUM_THREADS="1",
            NUMBA_NUM_THREADS="1",
            MALLOC_ARENA_MAX="2",
            PYTHONWARNINGS="ignore",
        )
        self.proc = subprocess.Popen(
            [sys.executable, "-c", "import fuzzlib; fuzzlib.worker_main()"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=env,
            cwd=str(repo),
            text=True,
        )

    def ask(self, op: dict, timeout_s: float) -> dict:
        """Send one case; the answer, or ``{"hang": True}`` after killing a stuck worker."""
        self.proc.stdin.write(json.dumps(op) + "\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        line = self.proc.stdout.readline() if ready else ""
        if not line:
            self.close()
            return {"hang": True, "killed": True}
        return json.loads(line)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            with contextlib.suppress(OSError):
                pipe.close()  # closed here, not left to the garbage collector mid-test

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None


class Pool:
    """``n`` long-lived workers fed from one queue of (case, kind) jobs; a worker killed after
    a hang is replaced (and warmed up: imports and numba compilation are not timed)."""

    def __init__(self, repo: Path, n: int = 2, warmup: dict | None = None):
        self.repo, self.warmup = repo, warmup
        self.workers: list[Worker | None] = [None] * n
        self._start(range(n))

    def _start(self, slots) -> None:
        def start(k):
            w = Worker(self.repo)
            if self.warmup:
                w.ask(self.warmup, 300.0)
            self.workers[k] = w

        threads = [threading.Thread(target=start, args=(k,)) for k in slots]
        for t in threads:
            t.start()
        for t in threads:
            t.join()

    def run(
        self, jobs: list[tuple[Case, str]], workdir: Path, bases: dict[str, Base]
    ) -> list[Verdict]:
        q: queue.Queue = queue.Queue()
        for i, job in enumerate(jobs):
            q.put((i, job))
        verdicts: list[Verdict | None] = [None] * len(jobs)

        def serve(slot: int) -> None:
            while True:
                try:
                    i, (case, kind) = q.get_nowait()
                except queue.Empty:
                    return
                w = self.workers[slot]
                if w is None or not w.alive:
                    if w is not None:
                        w.close()
                    self._start([slot])
                    w = self.workers[slot]
                verdicts[i] = run_one(w, case, kind, workdir / f"c{i}", bases.get(case.base))

        threads = [threading.Thread(target=serve, args=(k,)) for k in range(len(self.workers))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return [v for v in verdicts if v is not None]

    def close(self) -> None:
        for w in self.workers:
            if w is not None:
                w.close()


def run_one(w: Worker, case: Case, kind: str, d: Path, base: Base | None) -> Verdict:
    (d / "in").mkdir(parents=True)
    (d / "out").mkdir()
    log, extra = case.make(d)
    stdin = [a[len("--stdin=") :] for a in extra if a.startswith("--stdin=")]
    extra = [a for a in extra if not a.startswith("--stdin=")]
    summary = d / "out" / "summary.json"
    before_in, before_out = snapshot(d / "in"), snapshot(d / "out")
    if kind == "cli":
        argv = [str(log), "--rerun", "off", "--quiet", *extra]
        if "--summary-json" not in extra:
            argv += ["--summary-json", str(summary)]
        op = {"kind": "cli", "argv": argv}
    elif kind == "live":  # a source that never sends: every refusal comes before it opens
        argv = [f"udp://127.0.0.1:{free_udp_port()}", "--rerun", "off", "--no-status"]
        op = {"kind": kind, "argv": [*argv, "--idle-stop", "0.5", "--quiet", *extra]}
    elif kind == "batch":
        op = {"kind": kind, "argv": ["batch", str(log), "--jobs", "1", "--quiet", *extra]}
    else:
        op = {"kind": kind, "path": str(log)}
    op["timeout"] = CASE_TIMEOUT_S
    if stdin:  # the case's file on the worker's standard input (``cmd < FILE``)
        op["stdin"] = stdin[0]
    r = w.ask(op, CASE_TIMEOUT_S + 20.0)
    if kind == "cli" and r.get("rc") == 0 and "--summary-json" not in extra:
        with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
            r["samples"] = int(json.loads(summary.read_text())["samples"])  # as the CLI counted
    after_in, after_out = snapshot(d / "in"), snapshot(d / "out")
    v = judge(
        case,
        kind,
        r,
        base,
        before_in,
        after_in,
        before_out,
        after_out,
        summary if kind == "cli" and "--summary-json" not in extra else None,
    )
    _rmtree(d)
    return Verdict(case, kind, r, v)


def _rmtree(d: Path) -> None:
    """Remove a case folder, read-only folders included (never follows links)."""
    for dirpath, dirnames, _filenames in os.walk(d, topdown=True):
        os.chmod(dirpath, 0o755)
        for n in dirnames:
            p = Path(dirpath) / n
            if not p.is_symlink():
                os.chmod(p, 0o755)
    import shutil

    shutil.rmtree(d, ignore_errors=True)


if __name__ == "__main__":
    worker_main()
