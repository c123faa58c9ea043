"""A seeded, bounded fuzz campaign: nothing a user feeds in crashes, hangs, destroys or loses more
than it must.

Inputs: an 8 s slice of the shipped trial ``replay/broad_07_undisturbed_fast_rotation_B``
re-written as a small bag (zstd chunks of ~160 kB, so damage can hit one chunk of several) and a
``data_synth`` coning log (lz4 chunks). Damage classes, one test each: truncation at every
record boundary and at random offsets; byte flips in the file; byte flips inside decompressed
chunks re-packed with a valid CRC; lying length and size fields (and decompression bombs);
corrupt schemas; corrupt ``metadata.yaml`` (alias bomb, non-mapping, non-UTF-8); one hostile
message in a JSON IMU channel (stamps 1e300, 2^70, Infinity; 100 000-deep nesting); special files
as input; hostile output paths (inside the input, FIFOs, device nodes made in a temporary folder,
read-only folders), for replay and also for live (`--record`, `--summary-json`, `--rerun save:`)
and batch (`--table`); a corrupted record (byte flips, truncations) in each container beside
MCAP: a PX4 ULog, an ArduPilot DataFlash log, a EuRoC folder and a split bag whose
metadata.yaml holds YAML aliases (``tests/fuzz_containers.py``).

Each case names the fix it exercises (``Case.fix``); a failing class lists its cases by fix.
The reader is imported in one line (``fuzzlib._run_case``): repoint it when the reader moves.

Every case runs through the command line (``python -m imu_dcm.replay LOG --rerun off``, called
in-process in a long-lived worker) and, for damaged logs, through the library (the log reader
and :func:`imu_dcm.replay.replay`). For every case (:func:`fuzzlib.judge`):

* exit 0 (stderr: warnings only) or exit 2 with exactly one error line; the library raises only
  :class:`imu_dcm.errors.ImuDcmError` subclasses; no traceback;
* no hang (``fuzzlib.CASE_TIMEOUT_S``); peak memory below ``fuzzlib.MEMORY_LIMIT_BYTES``;
* input bytes unchanged (hashed before and after); on exit 2 no output left behind;
* no more IMU samples lost than the damaged chunks held (a log with intact chunks is not
  refused), and a loss is warned about.

The random offsets and bytes come from ``numpy.random.default_rng(SEED)``.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import struct
from collections import defaultdict
from pathlib import Path

import fuzz_containers
import fuzzlib
import numpy as np
import pytest
from conftest import REPO_ROOT
from fuzzlib import OP, Base, Case, chunk_record, without_summary

pytestmark = pytest.mark.slow

SEED = 20261201
BROAD = REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B"
SLICE_S = 8.0
RANDOM_TRUNCATIONS = 8
RANDOM_FLIPS = 16
CLASSES = (
    "truncation",
    "flip",
    "repacked_flip",
    "lying_size",
    "schema",
    "metadata",
    "json_message",
    "special_input",
    "output_path",
    "output_onto",
    "container_record",
)
#: The two largest classes run the CLI (which calls replay() in-process: an exception other than
#: ImuDcmError escapes it too) and the reader; the others also call replay() directly.
BULK_KINDS = ("cli", "read_log")
JSON_N, JSON_RATE_HZ, JSON_PER_CHUNK, JSON_HOSTILE_AT = 400, 200.0, 40, 150


# ------------------------------------------------------------------------------- inputs
def _bag(d: Path, base: Base, mcap: bytes | None = None, meta: bytes | None = None) -> Path:
    """A copy of ``base`` under ``d/in/bag``, with its .mcap or metadata.yaml replaced."""
    bag = d / "in" / base.folder.name
    shutil.copytree(base.folder, bag)
    if mcap is not None:
        (bag / base.mcap.name).write_bytes(mcap)
    if meta is not None:
        (bag / "metadata.yaml").write_bytes(meta)
    return bag


def _with(base: Base, mcap: bytes | None = None, meta: bytes | None = None):
    def make(d: Path):
        return _bag(d, base, mcap, meta), []

    return make


def _patch(buf: bytes, at: int, new: bytes) -> bytes:
    return buf[:at] + new + buf[at + len(new) :]


def _lost_after(base: Base, offset: int) -> int:
    """IMU samples in chunks not wholly before ``offset`` (a truncation there loses them)."""
    return sum(c.count(base.imu_channel) for c in base.chunks if c.rec.end > offset)


# -------------------------------------------------------------------------------- classes
def truncation_cases(base: Base, rng: np.random.Generator) -> list[Case]:
    buf = base.bytes
    cuts = {r.start for r in base.records} | {len(buf) - 8, 4}
    cuts |= {int(x) for x in rng.integers(9, len(buf) - 1, RANDOM_TRUNCATIONS)}
    out = []
    for x in sorted(cuts):
        rec = next((r.name for r in base.records if r.start == x), "random")
        out.append(
            Case(
                "truncation",
                f"at{x}-{rec}",
                base.name,
                _with(base, buf[:x]),
                lost=_lost_after(base, x),
                kinds=BULK_KINDS,
                fix="reader: keep whole chunks before the cut",
            )
        )
    return out


def flip_cases(base: Base, rng: np.random.Generator) -> list[Case]:
    buf = base.bytes
    first_data = next(r.start for r in base.records if r.op not in (OP["header"],))
    targets = {int(x): "random" for x in rng.integers(0, len(buf), RANDOM_FLIPS)}
    for k, c in enumerate(base.chunks):  # one flip in every chunk's compressed bytes
        targets[c.data_at + int(rng.integers(0, c.data_len))] = f"chunk{k}-data"
    c = base.chunks[len(base.chunks) // 2]
    targets[c.size_at + 8] = "chunk-crc"
    targets[c.size_at + 12] = "chunk-compression"
    for r in base.records:
        if r.op in (OP["chunk_index"], OP["statistics"], OP["data_end"], OP["footer"]):
            targets.setdefault(r.body + 1, r.name)
    out = []
    for x, what in sorted(targets.items()):
        k = base.chunk_at(x)
        lost = None if x < first_data else base.lost_in(k) if k is not None else 0
        flipped = _patch(buf, x, bytes([buf[x] ^ int(rng.integers(1, 256))]))
        out.append(
            Case(
                "flip",
                f"at{x}-{what}",
                base.name,
                _with(base, flipped),
                lost=lost,
                kinds=BULK_KINDS,
                fix="reader: skip the damaged chunk, go on with the next",
            )
        )
    return out


def _repack(base: Base, k: int, raw: bytes, **kw) -> bytes:
    c = base.chunks[k]
    t0, t1 = struct.unpack_from("<QQ", base.bytes, c.rec.body)
    idx = base.records.index(c.rec)
    return without_summary(base.bytes, {idx: chunk_record(t0, t1, raw, c.compression, **kw)})


def repacked_flip_cases(base: Base, rng: np.random.Generator) -> list[Case]:
    out = [
        Case(
            "repacked_flip",
            "no-summary-undamaged",
            base.name,
            _with(base, without_summary(base.bytes)),
            lost=0,
            fix="reader: summary-less MCAP",
        )
    ]
    for k in range(len(base.chunks)):
        c = base.chunks[k]
        imu = [(s, e) for ch, s, e in c.messages if ch == base.imu_channel]
        s, e = imu[int(rng.integers(0, len(imu)))]
        # message record: op u8, len u64, channel u16, seq u32, log u64, pub u64, then CDR:
        # encapsulation 4, stamp sec 4 + nanosec 4, frame_id ...; angular_velocity near the end
        spots = {
            "msg-length": s + 8,
            "msg-channel": s + 9,
            "log-time": s + 22,
            "stamp-sec": s + 31 + 7,
            "payload": int(rng.integers(s + 35, e)),
            "rate-exponent": e - 48 - 72 - 8 * int(rng.integers(0, 3)) - 1,
        }
        what = list(spots)[k % len(spots)]
        at = spots[what]
        raw = bytearray(c.raw)
        raw[at] ^= 0x7F if what == "rate-exponent" else int(rng.integers(1, 256))
        out.append(
            Case(
                "repacked_flip",
                f"chunk{k}-{what}",
                base.name,
                _with(base, _repack(base, k, bytes(raw))),
                lost=base.lost_in(k),
                fix="replay: implausible samples/stamps cost one sample (issue §5)",
            )
        )
    return out


def _bomb(compression: str, size: int) -> bytes:
    """``size`` zero bytes compressed (streamed: never held whole here)."""
    if compression == "zstd":
        import zstandard

        cobj = zstandard.ZstdCompressor(level=1).compressobj()
        block = bytes(1 << 20)
        parts = [cobj.compress(block) for _ in range(size >> 20)]
        return b"".join(parts) + cobj.flush()
    import lz4.frame

    with lz4.frame.LZ4FrameCompressor() as comp:
        block = bytes(1 << 20)
        parts = [comp.begin()] + [comp.compress(block) for _ in range(size >> 20)]
        return b"".join(parts) + comp.flush()


def lying_size_cases(base: Base, rng: np.random.Generator) -> list[Case]:
    buf = base.bytes
    out = []
    k = len(base.chunks) // 2
    c = base.chunks[k]
    lost = base.lost_in(k)

    def u64(v):
        return struct.pack("<Q", v)

    lies = {
        "record-length-max": (c.rec.start + 1, u64(2**64 - 1)),
        "record-length-2^63": (c.rec.start + 1, u64(2**63)),
        "record-length-0": (c.rec.start + 1, u64(0)),
        "record-length-short": (c.rec.start + 1, u64(c.rec.end - c.rec.body - 1)),
        "uncompressed-size-0": (c.size_at, u64(0)),
        "uncompressed-size-short": (c.size_at, u64(len(c.raw) - 1)),
        "uncompressed-size-long": (c.size_at, u64(len(c.raw) + 1)),
        "uncompressed-size-2.2GB": (c.size_at, u64(2_200_000_000)),
        "uncompressed-size-2^63": (c.size_at, u64(2**63)),
        "uncompressed-size-max": (c.size_at, u64(2**64 - 1)),
        "data-length-max": (c.data_at - 8, u64(2**64 - 1)),
        "data-length-short": (c.data_at - 8, u64(c.data_len - 1)),
        "compression-length-max": (c.size_at + 12, struct.pack("<I", 2**32 - 1)),
    }
    for r in base.records:
        if (
            r.op == OP["chunk_index"]
            and struct.unpack_from("<Q", buf, r.body + 16)[0] == c.rec.start
        ):
            lies["index-chunk-offset-past-end"] = (r.body + 16, u64(len(buf) * 2))
            lies["index-chunk-length-max"] = (r.body + 24, u64(2**64 - 1))
        if r.op == OP["message_index"] and "message-index-length-max" not in lies:
            lies["message-index-length-max"] = (r.start + 1, u64(2**63 - 1))
        if r.op == OP["footer"]:
            lies["footer-summary-start-past-end"] = (r.body, u64(len(buf) * 3))
            lies["footer-summary-start-in-header"] = (r.body, u64(9))
        if r.op == OP["statistics"]:
            lies["statistics-message-count-max"] = (r.body, u64(2**64 - 1))
    index_lies = ("index-", "message-index", "footer-", "statistics-")
    for name, (at, new) in lies.items():
        out.append(
            Case(
                "lying_size",
                name,
                base.name,
                _with(base, _patch(buf, at, new)),
                lost=0 if name.startswith(index_lies) else lost,
                fix="reader: bound sizes by the file, skip the chunk",
            )
        )
    # A message record inside a chunk claiming to run past the chunk (re-packed, valid CRC).
    s = next(s for ch, s, e in c.messages if ch == base.imu_channel)
    raw = _patch(c.raw, s + 1, u64(2**63 - 1))
    out.append(
        Case(
            "lying_size",
            "inner-message-length",
            base.name,
            _with(base, _repack(base, k, raw)),
            lost=lost,
            fix="reader: bound records",
        )
    )
    # Decompression bombs on the last chunk's place: 1 GiB of zeros claiming 1000 bytes, and the
    # same truthfully declared (nothing of it is replayed: it holds no IMU message).
    t0, t1 = struct.unpack_from("<QQ", buf, base.chunks[-1].rec.body)
    data = _bomb(c.compression or "zstd", 1 << 30)
    for name, declared in (("bomb-declared-1000", 1000), ("bomb-declared-truthfully", 1 << 30)):
        rec = chunk_record(
            t0, t1, b"", c.compression or "zstd", declared_size=declared, crc=0, data=data
        )
        out.append(
            Case(
                "lying_size",
                name,
                base.name,
                _with(base, without_summary(buf, insert=rec)),
                lost=0,
                fix="reader: never inflate past the declared size; bound it by the file",
            )
        )
    return out


def _schema_variant(base: Base, hook):
    """The base with ``hook(name, encoding, data)`` applied to the schema records inside its
    chunks (re-packed with a valid CRC; summary dropped, so the chunks' copies are the only)."""
    buf = base.bytes
    replace = {}
    for _k, c in enumerate(base.chunks):
        parts, changed = [], False
        for op, s, e in fuzzlib.inner_records(c.raw):
            rec = c.raw[s:e]
            if op == OP["schema"]:
                (sid,) = struct.unpack_from("<H", rec, 9)
                fields, p = [], 11
                for width in ("<I", "<I", "<I"):
                    (n,) = struct.unpack_from(width, rec, p)
                    fields.append(rec[p + 4 : p + 4 + n])
                    p += 4 + n
                name, enc, data = hook(fields[0].decode(), fields[1].decode(), fields[2])
                if (name, enc, data) != (fields[0].decode(), fields[1].decode(), fields[2]):
                    changed = True
                    body = struct.pack("<H", sid) + b"".join(
                        struct.pack("<I", len(x)) + x for x in (name.encode(), enc.encode(), data)
                    )
                    rec = struct.pack("<BQ", OP["schema"], len(body)) + body
            parts.append(rec)
        if changed:
            t0, t1 = struct.unpack_from("<QQ", buf, c.rec.body)
            replace[base.records.index(c.rec)] = chunk_record(
                t0, t1, b"".join(parts), c.compression
            )
    return _with(base, without_summary(buf, replace))


def schema_cases(base: Base, rng: np.random.Generator) -> list[Case]:
    imu = "sensor_msgs/msg/Imu"

    def nested(depth):
        lines = [f"pkg/msg/T{i} a" for i in range(1, 2)]
        for i in range(1, depth):
            lines.append("=" * 80 + f"\nMSG: pkg/msg/T{i}\npkg/msg/T{i + 1} a")
        lines.append("=" * 80 + f"\nMSG: pkg/msg/T{depth}\nfloat64 x")
        return "\n".join(lines).encode()

    variants = {
        "non-utf8": lambda n, e, d: (n, e, b"\xff\xfe\xfd" + d),
        "empty": lambda n, e, d: (n, e, b""),
        "garbage": lambda n, e, d: (n, e, b"%% not a message definition {[(\n" * 3),
        "bad-field-type": lambda n, e, d: (n, e, d.replace(b"float64[9]", b"float64[9", 1)),
        "bad-resource-name": lambda n, e, d: (
            n,
            e,
            d.replace(b"MSG: std_msgs/Header", b"MSG: 9bad-name//Header", 1),
        ),
        "self-recursive": lambda n, e, d: (
            n,
            e,
            d.replace(
                b"MSG: geometry_msgs/Vector3\n",
                b"MSG: geometry_msgs/Vector3\ngeometry_msgs/Vector3 again\n",
                1,
            ),
        ),
        "nested-3000": lambda n, e, d: (n, e, nested(3000)),
        "unbounded-covariance": lambda n, e, d: (
            n,
            e,
            d.replace(b"float64[9] orientation_covariance", b"float64[] orientation_covariance", 1),
        ),
        "encoding-unknown": lambda n, e, d: (n, "no-such-encoding", d),
        "encoding-ros1msg": lambda n, e, d: (n, "ros1msg", d),
        "name-empty": lambda n, e, d: ("", e, d),
        "name-long": lambda n, e, d: ("x/msg/" + "y" * 100_000, e, d),
    }
    out = []
    for name, fn in variants.items():

        def hook(n, e, d, fn=fn):
            return fn(n, e, d) if n == imu else (n, e, d)

        out.append(
            Case(
                "schema",
                name,
                base.name,
                _schema_variant(base, hook),
                lost=None,
                fix="reader: schema errors are LogError (decode, parse, depth)",
            )
        )
    return out


def metadata_cases(base: Base, rng: np.random.Generator) -> list[Case]:
    laughs = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, 10):
        laughs.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    good = base.folder.joinpath("metadata.yaml").read_bytes()
    variants = {
        "alias-bomb": (
            "rosbag2_bagfile_information:\n  custom_data:\n"
            + "".join(f"    {ln}\n" for ln in laughs)
        ).encode(),
        "alias-bomb-top": "\n".join(laughs).encode() + b"\n",
        "list": b"- 1\n- 2\n",
        "scalar": b"just a string\n",
        "null": b"~\n",
        "empty": b"",
        "non-utf8": b"rosbag2_bagfile_information:\n  custom_data:\n    k: \xff\xfe\xfa\n",
        "binary": bytes(rng.integers(0, 256, 4096, dtype=np.uint8)),
        "info-list": b"rosbag2_bagfile_information: [1, 2]\n",
        "custom-data-list": b"rosbag2_bagfile_information:\n  custom_data: [a, b]\n",
        "custom-data-nested": b"rosbag2_bagfile_information:\n  custom_data:\n    k: {a: [1]}\n",
        "deep-nesting": b"[" * 100_000 + b"]" * 100_000,
        "bad-yaml": b"rosbag2_bagfile_information:\n\t- : :\n  ][\n",
        "missing-file": good.replace(base.mcap.name.encode(), b"missing.mcap"),
        "large": b"# pad\n" * 2_000_000 + good,
    }
    return [
        Case(
            "metadata",
            name,
            base.name,
            _with(base, meta=text),
            lost=None,
            fix="reader: bounded YAML parse, mapping check, UTF-8 errors as LogError",
        )
        for name, text in variants.items()
    ]


def _json_payloads() -> tuple[list[bytes], list[int]]:
    """A JSON IMU channel: 2 s at 200 Hz of a rotation about a wandering axis."""
    t_ns = [1_700_000_000_000_000_000 + round(k * 1e9 / JSON_RATE_HZ) for k in range(JSON_N)]
    out = []
    for k, t in enumerate(t_ns):
        w = (0.3 * np.sin(0.05 * k), 0.2, 0.5 * np.cos(0.03 * k))
        out.append(
            json.dumps(
                {
                    "header": {
                        "stamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                        "frame_id": "imu",
                    },
                    "angular_velocity": dict(zip("xyz", w, strict=False)),
                }
            ).encode()
        )
    return out, t_ns


def json_cases(base: Base) -> list[Case]:
    """One hostile message (index 150, chunk 3) among 400 good ones of a JSON IMU channel."""
    good, t_ns = _json_payloads()
    j = JSON_HOSTILE_AT
    head = b'{"header": {"stamp": '
    rate = b', "angular_velocity": {"x": 0.1, "y": 0.2, "z": 0.3}}'
    stamp = b'{"sec": 1700000000, "nanosec": 0}'

    def with_stamp(st: bytes) -> bytes:
        return head + st + b"}" + rate

    def with_x(x: bytes) -> bytes:
        return head + stamp + b'}, "angular_velocity": {"x": ' + x + b', "y": 0, "z": 0}}'

    hostile = {
        "stamp-sec-1e300": with_stamp(b'{"sec": 1e300, "nanosec": 0}'),
        "stamp-sec-2^70": with_stamp(b'{"sec": %d, "nanosec": 0}' % 2**70),
        "stamp-sec-Infinity": with_stamp(b'{"sec": Infinity, "nanosec": 0}'),
        "stamp-sec-NaN": with_stamp(b'{"sec": NaN, "nanosec": 0}'),
        "stamp-sec-string": with_stamp(b'{"sec": "soon", "nanosec": 0}'),
        "stamp-sec-negative": with_stamp(b'{"sec": -5, "nanosec": 0}'),
        "stamp-nanosec-10^30": with_stamp(b'{"sec": 1700000000, "nanosec": %d}' % 10**30),
        "stamp-list": with_stamp(b"[1, 2]"),
        "rate-string": with_x(b'"fast"'),
        "rate-null": with_x(b"null"),
        "rate-1e400": with_x(b"1e400"),
        "rate-int-10^400": with_x(b"1" + b"0" * 400),
        "rate-nesting-100000": with_x(b"[" * 100_000 + b"]" * 100_000),
        "message-nesting-100000": b"[" * 100_000 + b"]" * 100_000,
        "message-list": b"[1, 2, 3]",
        "invalid-json": b'{"angular_velocity": ',
        "non-utf8": b"\xff\xfe{}",
        "frame-id-5MB": head + stamp + b', "frame_id": "' + b"a" * 5_000_000 + b'"}' + rate,
    }
    out = []
    for name, payload in hostile.items():
        msgs = list(good)
        msgs[j] = payload
        mcap = fuzzlib.json_log(msgs, t_ns, JSON_PER_CHUNK)
        out.append(
            Case(
                "json_message",
                name,
                base.name,
                _with(base, mcap),
                lost=base.lost_in(j // JSON_PER_CHUNK),
                fix="reader: a bad JSON message costs itself (bounded parse, checked stamp range)",
            )
        )
    return out


def _mknod(path: Path, minor: int) -> bool:
    """A character device like /dev/null (3), /dev/zero (5), /dev/full (7), made in a temporary
    folder (never a real /dev node); False where the system does not allow it."""
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, minor))
        return True
    except OSError:
        return False


def special_input_cases(base: Base) -> list[Case]:
    def fifo_log(d):
        os.mkfifo(d / "in" / "log.mcap")
        return d / "in" / "log.mcap", []

    def fifo_in_bag(d):
        bag = _bag(d, base)
        (bag / base.mcap.name).unlink()
        os.mkfifo(bag / base.mcap.name)
        return bag, []

    def zero_log(d):
        p = d / "in" / "zero.mcap"
        if not _mknod(p, 5):
            p.write_bytes(b"")
        return p, []

    def zero_in_bag(d):
        bag = _bag(d, base)
        (bag / base.mcap.name).unlink()
        if not _mknod(bag / base.mcap.name, 5):
            (bag / base.mcap.name).write_bytes(b"")
        return bag, []

    def empty_dir(d):
        (d / "in" / "empty").mkdir()
        return d / "in" / "empty", []

    def missing(d):
        return d / "in" / "nothing-here", []

    def link_loop(d):
        (d / "in" / "a").symlink_to(d / "in" / "b")
        (d / "in" / "b").symlink_to(d / "in" / "a")
        return d / "in" / "a", []

    def metadata_fifo(d):
        bag = _bag(d, base)
        (bag / "metadata.yaml").unlink()
        os.mkfifo(bag / "metadata.yaml")
        return bag, []

    makers = {
        "fifo-log": fifo_log,
        "fifo-in-bag": fifo_in_bag,
        "zero-device-log": zero_log,
        "zero-device-in-bag": zero_in_bag,
        "empty-folder": empty_dir,
        "missing": missing,
        "symlink-loop": link_loop,
        "metadata-fifo": metadata_fifo,
    }
    return [
        Case(
            "special_input",
            name,
            base.name,
            make,
            lost=None,
            fix="reader: regular files and folders only",
        )
        for name, make in makers.items()
    ]


def _file(p: Path) -> Path:
    """A regular file at ``p`` (so that ``p / "x"`` can never be created)."""
    p.write_bytes(b"x")
    return p


def output_path_cases(base: Base) -> list[Case]:
    """Hostile outputs for the CLI; every one must be refused (exit 2) and change nothing."""

    def case(name, extra, refuse=True, fix="replay CLI: shared output-safety helper"):
        def make(d):
            bag = _bag(d, base)
            return bag, extra(d, bag)

        return Case(
            "output_path", name, base.name, make, lost=None, kinds=("cli",), refuse=refuse, fix=fix
        )

    def dev(minor):
        def extra(d, bag):
            p = d / "out" / f"dev{minor}"
            if not _mknod(p, minor):
                os.mkfifo(p)
            return ["--summary-json", str(p)]

        return extra

    def fifo(flag, force=False):
        def extra(d, bag):
            os.mkfifo(d / "out" / "fifo")
            return [flag, str(d / "out" / "fifo"), *(["--force"] if force else [])]

        return extra

    def readonly(d, bag):
        (d / "out" / "ro").mkdir()
        os.chmod(d / "out" / "ro", 0o555)
        return ["--summary-json", str(d / "out" / "ro" / "s.json")]

    def link_to_input(d, bag):
        (d / "out" / "link.json").symlink_to(bag / base.mcap.name)
        return ["--summary-json", str(d / "out" / "link.json")]

    def link_dir_to_input(d, bag):
        (d / "out" / "est").symlink_to(bag)
        return ["--out", str(d / "out" / "est"), "--force"]

    def parent_is_file(d, bag):
        (d / "out" / "file").write_bytes(b"x")
        return ["--summary-json", str(d / "out" / "file" / "s.json")]

    return [
        case(
            "summary-json-is-input-mcap", lambda d, b: ["--summary-json", str(b / base.mcap.name)]
        ),
        case("summary-json-is-metadata", lambda d, b: ["--summary-json", str(b / "metadata.yaml")]),
        case("summary-json-is-input-folder", lambda d, b: ["--summary-json", str(b)]),
        case("summary-json-symlink-to-input", link_to_input),
        case("out-is-input", lambda d, b: ["--out", str(b), "--force"]),
        case("out-holds-input", lambda d, b: ["--out", str(b.parent), "--force"]),
        case("out-symlink-to-input", link_dir_to_input),
        case("summary-json-fifo", fifo("--summary-json")),
        case("out-fifo-force", fifo("--out", force=True)),
        # a character device is a stream: /dev/null takes the JSON (exit 0), /dev/full refuses
        # it at the write (ENOSPC, exit 2); either way the device stays a device
        case("summary-json-null-device", dev(3), refuse=False, fix="outputs: streams direct"),
        case("summary-json-full-device", dev(7)),
        case("summary-json-folder", lambda d, b: ["--summary-json", str(d / "out")]),
        case("summary-json-parent-is-file", parent_is_file),
        # root writes into a read-only folder: then exit 0 is right too
        case("summary-json-read-only-folder", readonly, refuse=os.geteuid() != 0),
        case(
            "rerun-bad-with-outputs",
            lambda d, b: ["--rerun", "bogus", "--out", str(d / "out" / "est")],
            fix="replay CLI: validate every option before any output",
        ),
        case(
            "rerun-save-unwritable",
            lambda d, b: [
                "--rerun",
                f"save:{_file(d / 'out' / 'file') / 'x' / 'v.rrd'}",
                "--summary-json",
                str(d / "out" / "s.json"),
            ],
            fix="replay CLI: check --rerun save: before any output",
        ),
    ]


def live_batch_output_cases(base: Base) -> list[Case]:
    """Hostile outputs for ``live`` (--record, --summary-json, --rerun save:) and ``batch``
    (--table): each refused (exit 2) before anything is read or written, nothing changed."""

    def case(kind, name, extra, fix):
        def make(d):
            return _bag(d, base), extra(d)

        return Case("output_path", f"{kind}-{name}", base.name, make, None, (kind,), True, fix)

    def notes(d):
        (d / "out" / "rec").mkdir()
        (d / "out" / "rec" / "notes.txt").write_text("mine\n")
        return d / "out" / "rec"

    def bag_copy(d):
        shutil.copytree(base.folder, d / "out" / "copy")
        (d / "out" / "copy" / "ATTRIBUTION.md").write_text("theirs\n")
        return d / "out" / "copy"

    def fifo(d, name="fifo"):
        os.mkfifo(d / "out" / name)
        return d / "out" / name

    def folder(d, name):
        (d / "out" / name).mkdir()
        (d / "out" / name / "notes.txt").write_text("mine\n")
        return d / "out" / name

    def link_to_folder(d):
        (d / "out" / "real").mkdir()
        (d / "out" / "link").symlink_to(d / "out" / "real")
        return d / "out" / "link"

    rec, force = "--record", "--force"
    live_fix = "live CLI: imu_dcm.outputs before the source opens"
    batch_fix = "batch CLI: imu_dcm.outputs for --table"
    return [
        case("live", "record-foreign-folder", lambda d: [rec, str(notes(d)), force], live_fix),
        case("live", "record-bag-copy", lambda d: [rec, str(bag_copy(d)), force], live_fix),
        case("live", "record-fifo", lambda d: [rec, str(fifo(d)), force], live_fix),
        case("live", "record-symlink", lambda d: [rec, str(link_to_folder(d)), force], live_fix),
        case("live", "record-no-force", lambda d: [rec, str(link_to_folder(d) / "..")], live_fix),
        case(
            "live",
            "record-parent-is-file",
            lambda d: [rec, str(_file(d / "out" / "file") / "rec")],
            live_fix,
        ),
        case("live", "summary-json-fifo", lambda d: ["--summary-json", str(fifo(d))], live_fix),
        # (a character device is a stream, written at stop: the CLI's device cases cover it)
        case("live", "summary-json-folder", lambda d: ["--summary-json", str(d / "out")], live_fix),
        case(
            "live",
            "rerun-save-parent-is-file",
            lambda d: ["--rerun", f"save:{_file(d / 'out' / 'file') / 'v.rrd'}"],
            live_fix,
        ),
        case("batch", "table-fifo", lambda d: ["--table", str(fifo(d, "t.csv"))], batch_fix),
        case("batch", "table-folder", lambda d: ["--table", str(folder(d, "t.csv"))], batch_fix),
        case(
            "batch",
            "table-parent-is-file",
            lambda d: ["--table", str(_file(d / "out" / "file") / "t.csv")],
            batch_fix,
        ),
        case(
            "batch",
            "table-in-input-folder",
            lambda d: ["--table", str(d / "in" / base.folder.name / "t.csv")],
            batch_fix,
        ),
        case(
            "batch",
            "table-not-a-table",
            lambda d: ["--table", str(_file(d / "out" / "t.csv"))],
            batch_fix,
        ),
        case(
            "batch",
            "table-not-ours-force",
            lambda d: ["--table", str(_file(d / "out" / "t.csv")), "--force"],
            batch_fix,
        ),
    ]


#: Every output a user names, by command: (name, how it is asked for, the file it writes, under
#: ``out/``). The file is made foreign, a link, or the input before the run.
_ONTO_OUTPUTS = {
    "cli": [
        ("summary-json", lambda f: ["--summary-json", str(f)], "s.json"),
        ("export-tum-estimate", lambda f: ["--export-tum", str(f.parent)], "tum/estimate.tum"),
        ("export-tum-truth", lambda f: ["--export-tum", str(f.parent)], "tum/truth.tum"),
        ("rerun-save", lambda f: ["--rerun", f"save:{f}"], "v.rrd"),
    ],
    "live": [
        ("summary-json", lambda f: ["--summary-json", str(f)], "s.json"),
        ("rerun-save", lambda f: ["--rerun", f"save:{f}"], "v.rrd"),
    ],
    "batch": [
        ("table", lambda f: ["--table", str(f)], "t.csv"),
        ("table-md", lambda f: ["--table", str(f.with_suffix(".csv"))], "t.md"),
        ("table-png", lambda f: ["--table", str(f.with_suffix(".csv"))], "t.png"),
        ("table-curves", lambda f: ["--table", str(f.parent / "t.csv")], "t.curves.jsonl"),
        ("chart", lambda f: ["--table", str(f.parent / "t.csv"), "--chart", str(f)], "c.png"),
    ],
}
_USER_BYTES = b"a user's file: not imu_dcm's\n"


def output_onto_cases(base: Base) -> list[Case]:
    """Every output onto a file this tool did not write (with and without ``--force``), a
    symbolic link (to a user's file, or to nothing), and an input (a hard link to the log, the
    file on standard input): each refused (exit 2, one line), nothing under ``out/`` or ``in/``
    changed, nothing created."""
    import importlib.util

    has_chart = importlib.util.find_spec("matplotlib") is not None

    def foreign(d, f):
        f.write_bytes(_USER_BYTES)

    def link(d, f):
        (d / "out" / "mine.txt").write_bytes(_USER_BYTES)
        f.symlink_to(d / "out" / "mine.txt")

    def dangling(d, f):
        f.symlink_to(d / "out" / "nothing-here")

    def hard_link(d, f):
        os.link(d / "in" / base.folder.name / base.mcap.name, f)

    targets = {
        "foreign": (foreign, []),
        "foreign-force": (foreign, ["--force"]),
        "symlink-to-user-file": (link, []),
        "symlink-dangling": (dangling, []),
        "hard-link-to-input": (hard_link, []),
        "stdin-file": (None, []),  # the output is the file standard input reads
    }
    cases = []
    for kind, outputs in _ONTO_OUTPUTS.items():
        for out_name, argv, rel in outputs:
            if rel.endswith(".png") and not has_chart:
                continue
            for target, (prepare, extra) in targets.items():
                if kind == "live" and target == "hard-link-to-input":
                    continue  # live's input is its stream (stdin-file is its file input)

                def make(d, argv=argv, rel=rel, prepare=prepare, extra=extra, target=target):
                    bag = _bag(d, base)
                    f = d / "out" / rel
                    f.parent.mkdir(parents=True, exist_ok=True)
                    if prepare is not None:
                        prepare(d, f)
                        return bag, [*argv(f), *extra]
                    named = d / "in" / rel  # an input outside the bag folder, on stdin
                    named.parent.mkdir(parents=True, exist_ok=True)
                    named.write_text("0,0,0,0.1\n")
                    return bag, [*argv(named), *extra, f"--stdin={named}"]

                cases.append(
                    Case(
                        "output_onto",
                        f"{kind}-{out_name}-{target}",
                        base.name,
                        make,
                        None,
                        (kind,),
                        True,
                        "outputs: claim_output (ours or new, no link to a file, never an input)",
                    )
                )
    return cases


# -------------------------------------------------------------------------------- campaign
def _bases(tmp: Path) -> dict[str, Base]:
    from data_synth.cli import main as synth_main

    start = 1_700_000_000_000_000_000
    (mcap,) = BROAD.glob("*.mcap")
    broad = fuzzlib.rewrite_bag(
        mcap,
        tmp / "broad07",
        t_end_ns=start + int(SLICE_S * 1e9),
        chunk_size=160_000,
        compression="zstd",
        source="broad 07 slice",
    )
    assert (
        synth_main(
            [
                "coning",
                "--rate",
                "200",
                "--duration",
                "3",
                "--gyro-noise-density",
                "1e-3",
                "--gyro-bias=0.01,-0.02,0.005",
                "--out",
                str(tmp / "synth-src"),
            ]
        )
        == 0
    )
    (src,) = (tmp / "synth-src").glob("*.mcap")
    synth = fuzzlib.rewrite_bag(
        src,
        tmp / "coning",
        t_end_ns=None,
        chunk_size=48_000,
        compression="lz4",
        source="data_synth coning",
    )
    (tmp / "json").mkdir()
    (tmp / "json" / "json.mcap").write_bytes(fuzzlib.json_log(*_json_payloads(), JSON_PER_CHUNK))
    return {
        "broad07": fuzzlib.load_base("broad07", broad),
        "coning": fuzzlib.load_base("coning", synth),
        "json": fuzzlib.load_base("json", tmp / "json", imu_topic="/imu/json"),
    }


class Campaign:
    """Runs each class's cases once, on first request, in a pool of two warm workers."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.bases = _bases(tmp / "bases")
        rng = np.random.default_rng(SEED)
        self.cases: dict[str, list[Case]] = defaultdict(list)
        for base in (self.bases["broad07"], self.bases["coning"]):
            for gen in (
                truncation_cases,
                flip_cases,
                repacked_flip_cases,
                lying_size_cases,
                schema_cases,
                metadata_cases,
            ):
                for c in gen(base, rng):
                    self.cases[c.cls].append(c)
        self.cases["json_message"] = json_cases(self.bases["json"])
        self.cases["special_input"] = special_input_cases(self.bases["broad07"])
        self.cases["output_path"] = output_path_cases(self.bases["broad07"])
        self.cases["output_path"] += live_batch_output_cases(self.bases["broad07"])
        self.cases["output_onto"] = output_onto_cases(self.bases["broad07"])
        broad = self.bases["broad07"]
        self.pool = fuzzlib.Pool(
            REPO_ROOT, n=2, warmup={"kind": "replay", "path": str(broad.folder)}
        )
        clean = [Case("clean", "clean", b.name, _with(b), lost=None) for b in self.bases.values()]
        self.clean = self.pool.run(
            [(c, k) for c in clean for k in c.kinds], tmp / "clean", self.bases
        )
        for v in self.clean:  # the floor of each rule: what the clean log gives
            self.bases[v.case.base].clean[v.kind] = v.result.get("samples")
        self._containers(tmp)
        self._done: dict[str, list[fuzzlib.Verdict]] = {}

    def _containers(self, tmp: Path) -> None:
        """The ULog, DataFlash, EuRoC and split-bag bases (tests/fuzz_containers.py), their
        clean runs (the floor of each rule) and their damaged-record cases."""
        self.other = fuzz_containers.bases(tmp / "containers")
        clean = [
            Case("clean", "clean", b.name, fuzz_containers._copy_with(b, b.mcap.read_bytes()), None)
            for b in self.other.values()
        ]
        jobs = [(c, k) for c in clean for k in fuzz_containers.KINDS]
        self.other_clean = self.pool.run(jobs, tmp / "clean-containers", self.other)
        for v in self.other_clean:
            self.other[v.case.base].clean[v.kind] = v.result.get("samples")
        rng = np.random.default_rng(SEED + 27)
        self.cases["container_record"] = fuzz_containers.container_cases(self.other, rng)

    def verdicts(self, cls: str) -> list[fuzzlib.Verdict]:
        if cls not in self._done:
            jobs = [(c, k) for c in self.cases[cls] for k in c.kinds]
            bases = {**self.bases, **self.other} if cls == "container_record" else self.bases
            self._done[cls] = self.pool.run(jobs, self.tmp / cls, bases)
        return self._done[cls]

    def close(self) -> None:
        self.pool.close()


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    c = Campaign(tmp_path_factory.mktemp("fuzz"))
    yield c
    c.close()


def test_clean_logs_replay_with_all_samples(campaign):
    # The harness's own baseline: undamaged inputs pass every rule and keep every sample.
    bad = [v.line() for v in campaign.clean if v.violations]
    assert not bad, "\n".join(bad)
    for b in campaign.bases.values():
        assert b.clean["read_log"] == b.imu_total, b.name
        assert len(b.chunks) >= 5, b.name  # damage can hit one chunk of several
        assert b.clean["cli"] == b.clean["replay"], b.name
        assert b.clean["replay"] > 0.99 * b.imu_total, b.name


def test_clean_containers_read_every_sample(campaign):
    bad = [v.line() for v in campaign.other_clean if v.violations]
    assert not bad, "\n".join(bad)
    for b in campaign.other.values():
        assert b.clean["read_log"] == fuzz_containers.N, b.name
        assert b.clean["cli"] > 0.99 * fuzz_containers.N, b.name


@pytest.mark.parametrize("cls", CLASSES)
def test_fuzz_class(campaign, cls):
    verdicts = campaign.verdicts(cls)
    assert len(verdicts) >= 8, f"{cls}: only {len(verdicts)} cases ran"
    bad = [v for v in verdicts if v.violations]
    by_fix = defaultdict(list)
    for v in bad:
        by_fix[v.case.fix].append(f"{v.case.base}/{v.case.name}[{v.kind}]")
    fixes = "\n".join(
        f"  needs {fix}: {len(ids)} runs, e.g. {', '.join(ids[:3])}" for fix, ids in by_fix.items()
    )
    report = "\n".join(v.line() for v in bad)
    print(_class_counts(cls, len(campaign.cases[cls]), verdicts))  # shown with pytest -s
    assert not bad, f"{len(bad)} of {len(verdicts)} {cls} runs broke a rule\n{fixes}\n{report}"


def _counts(verdicts: list[fuzzlib.Verdict]) -> dict[str, int]:
    """What a campaign found, by rule: runs, tracebacks, hangs, inputs modified, files replaced
    (a user's file, a link's target, a special file), silent results (exit 0 where only a
    refusal is safe), and runs breaking any rule."""
    found = defaultdict(int)
    found["runs"] = len(verdicts)
    for v in verdicts:
        text = " ".join(v.violations)
        found["tracebacks"] += "traceback" in text
        found["hangs"] += "hang" in text
        found["inputs modified"] += "input changed" in text
        found["files replaced"] += "replaced or removed" in text or "left behind or" in text
        found["silent results"] += "exit 0 where" in text
        found["broken"] += bool(v.violations)
    return dict(found)


def test_every_output_onto_a_foreign_file_a_link_and_an_input_is_refused(campaign, capsys):
    verdicts = campaign.verdicts("output_onto")
    counts = _counts(verdicts)
    with capsys.disabled():
        print(f"\noutput_onto: {counts}")
    kinds = {v.kind for v in verdicts}
    assert kinds == {"cli", "live", "batch"} and counts["runs"] >= 50, counts
    assert counts["broken"] == 0, counts


def _class_counts(cls: str, n_cases: int, verdicts: list[fuzzlib.Verdict]) -> str:
    """One line of the class's counts: cases, runs, and runs breaking each kind of rule."""
    kinds = {
        "tracebacks": ("traceback", "raised "),
        "hangs": ("hang",),
        "inputs modified": ("input changed",),
        "silent results": ("without a warning", "expected >="),
    }
    got = {
        k: sum(any(m in x for x in v.violations for m in marks) for v in verdicts)
        for k, marks in kinds.items()
    }
    said = ", ".join(f"{n} {k}" for k, n in got.items())
    return f"{cls}: {n_cases} cases, {len(verdicts)} runs; {said}"
