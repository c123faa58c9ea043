"""rosbag2 storage other than one plain MCAP: sqlite3 files, split bags, compressed bags.

* sqlite3 (``.db3``, Humble's default): read with :mod:`sqlite3` opened read-only and immutable
  (the input is never touched), only the kept topics, in insertion (file) order. Definitions come
  from the ``message_definitions`` table when the bag has one (Iron and later), else from
  rosbags' type store.
* split bags: every file listed in ``metadata.yaml`` is read in order and channels of one topic
  are merged across files.
* ``file`` compression: each ``.zstd`` file is decompressed, streaming and bounded, into a
  temporary file first. ``message`` compression: each kept payload is decompressed, bounded.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from imu_dcm.errors import LogError
from imu_dcm.logio import meta
from imu_dcm.logio.containers.mcap import McapSource, size_bound
from imu_dcm.logio.meta import topic_counts
from imu_dcm.logio.paths import MCAP_MAGIC, check_regular
from imu_dcm.logio.ros.collect import Collected, Conn, Payloads, Sink, join_any
from imu_dcm.logio.ros.read import RosSource
from imu_dcm.logio.source import ProgressCallback
from imu_dcm.logio.types import Damage

if TYPE_CHECKING:
    import sqlite3

__all__ = [
    "MAX_MESSAGE_BYTES",
    "SQLITE_MAGIC",
    "STORAGES",
    "ZSTD_MAGIC",
    "Rosbag2Folder",
    "SqliteSource",
    "ZstdFile",
    "decompress_file",
    "decompress_messages",
    "is_bag_folder",
    "open_folder",
    "storage_source",
]


#: Largest single decompressed message of a message-compressed bag (bytes).
MAX_MESSAGE_BYTES = 256 << 20
SQLITE_MAGIC = b"SQLite format 3\x00"
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
#: rosbag2 storage plugins read, by ``storage_identifier``.
STORAGES = ("mcap", "sqlite3")


class SqliteSource(RosSource):
    """One rosbag2 sqlite3 file."""

    kind = "ros2 sqlite3"

    def __init__(
        self,
        path: Path,
        progress: ProgressCallback | None = None,
        counts: dict[str, int] | None = None,
    ):
        self.path = path
        self.progress = progress
        self.counts = counts  # message count per topic from metadata.yaml (saves a table scan)

    def collect(self, sink: Sink) -> Collected:
        import sqlite3  # lazy: ~1.3 ms at import, a sqlite3 bag only (an MCAP replay needs none)

        uri = f"file:{self.path.resolve().as_posix()}?mode=ro&immutable=1"
        try:
            db = sqlite3.connect(uri, uri=True)
        except sqlite3.Error as exc:
            raise LogError(f"Expected a readable sqlite3 bag, got {exc} in {self.path}") from None
        try:
            return self._read(db, sink)
        except sqlite3.DatabaseError as exc:
            raise LogError(
                f"Expected a rosbag2 sqlite3 database, got {str(exc).rstrip('.')} in "
                f"{self.path}; `sqlite3 {self.path.name} .recover | sqlite3 fixed.db3` "
                f"may rescue it"
            ) from None
        finally:
            db.close()

    def _read(self, db: sqlite3.Connection, sink: Sink) -> Collected:
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if not {"topics", "messages"} <= tables:
            raise LogError(
                f"Expected a rosbag2 sqlite3 database (tables topics, messages), got "
                f"{', '.join(sorted(tables)) or 'no tables'} in {self.path}"
            )
        defs: dict[str, tuple[str, str]] = {}
        if "message_definitions" in tables:
            for typ, enc, text in db.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            ):
                if text:
                    defs[typ] = (enc, text)
        topics = list(
            db.execute("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
        )
        if self.counts is not None and all(str(t[1]) in self.counts for t in topics):
            counts = {t[0]: self.counts[str(t[1])] for t in topics}
        else:
            counts = dict(db.execute("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id"))
        conns = []
        for tid, name, typ, fmt in topics:
            enc, text = defs.get(typ, ("", ""))
            conns.append(
                Conn(int(tid), str(name), str(typ), str(fmt), enc, text, int(counts.get(tid, 0)))
            )
        kept = [c.id for c in conns if sink.wants(c)]
        if kept:
            marks = ",".join("?" * len(kept))
            rows = db.execute(
                f"SELECT topic_id, timestamp, data FROM messages "
                f"WHERE topic_id IN ({marks}) ORDER BY id",
                kept,
            )
            total = max(sum(c.count or 0 for c in conns if c.id in kept), 1)
            done = 0
            while batch := rows.fetchmany(20_000):
                # file-order key: the row's place in id order (one column less to fetch)
                ids = np.arange(done, done + len(batch), dtype=np.int64)
                done += len(batch)
                if self.progress is not None:
                    self.progress(min(done / total, 1.0))
                tids, stamps, datas = zip(*batch, strict=False)
                tids = np.array(tids, np.int64)
                for tid in np.unique(tids).tolist():
                    sel = np.flatnonzero(tids == tid)
                    rs = datas if len(sel) == len(datas) else [datas[i] for i in sel.tolist()]
                    lens = np.fromiter(map(len, rs), np.int64, len(rs))
                    starts = np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64)
                    sink.add(
                        tid,
                        Payloads(
                            np.frombuffer(b"".join(rs), np.uint8),
                            starts,
                            lens,
                            np.array(stamps, np.int64)[sel],
                            ids[sel],
                        ),
                    )
        payloads = sink.finish()
        return Collected(self.kind, conns, payloads, [])


def decompress_messages(p: Payloads, where: str, damage: list[Damage]) -> Payloads:
    """zstd-decompress every payload (a ``message``-compressed bag), each bounded."""
    import zstandard  # lazy: ~3 ms at import, a compressed bag only

    dec = zstandard.ZstdDecompressor()
    out = bytearray()
    starts, lens, keep = [], [], []
    for i in range(len(p)):
        data = p.payload(i)
        try:
            size = zstandard.frame_content_size(data)
            cap = min(MAX_MESSAGE_BYTES, size_bound(len(data)))
            if size > cap:
                raise ValueError(f"declares {size} bytes")
            m = dec.decompress(data, max_output_size=cap)
        except (zstandard.ZstdError, ValueError) as exc:
            damage.append(
                Damage(
                    -1,
                    f"{where}: message {i} does not decompress ({exc})",
                    int(p.log_time[i]),
                    int(p.log_time[i]),
                    1,
                )
            )
            continue
        starts.append(len(out))
        lens.append(len(m))
        keep.append(i)
        out += m
    k = np.asarray(keep, np.int64)
    return Payloads(
        np.frombuffer(bytes(out), np.uint8),
        np.asarray(starts, np.int64),
        np.asarray(lens, np.int64),
        p.log_time[k],
        p.order[k],
    )


def decompress_file(src: Path, dst_dir: Path) -> Path:
    """Stream-decompress ``src`` (``.zstd``) into ``dst_dir``, at most size_bound(src) bytes."""
    import zstandard  # lazy, as in decompress_messages

    dst = dst_dir / src.name.removesuffix(".zstd")
    cap = (
        size_bound(src.stat().st_size)
        if src.stat().st_size < (1 << 21)
        else (1024 * src.stat().st_size)
    )
    written = 0
    try:
        with open(src, "rb") as fin, open(dst, "wb") as fout:
            reader = zstandard.ZstdDecompressor().stream_reader(fin)
            while block := reader.read(1 << 20):
                written += len(block)
                if written > cap:
                    raise LogError(
                        f"Expected {src.name} to decompress to at most {cap} bytes, "
                        f"got more (refused)"
                    )
                fout.write(block)
    except zstandard.ZstdError as exc:
        raise LogError(f"Expected a zstd-compressed bag file, got {exc} in {src}") from None
    return dst


class Rosbag2Folder(RosSource):
    """A rosbag2 folder: ``metadata.yaml`` and one or more storage files."""

    def __init__(
        self,
        folder: Path,
        info: dict,
        files: list[Path],
        progress: ProgressCallback | None = None,
    ):
        self.folder = self.path = folder
        self.info = info
        self.files = files
        self.progress = progress
        self.storage = str(info.get("storage_identifier") or "")
        mode = str(info.get("compression_mode") or "").lower()
        self.mode = "" if mode == "none" else mode
        fmt = str(info.get("compression_format") or "")
        if self.mode and fmt != "zstd":
            raise LogError(
                f"Expected compression format zstd in {folder / 'metadata.yaml'}, got "
                f"{fmt!r}; `ros2 bag convert` can rewrite it uncompressed"
            )
        if self.mode not in ("", "file", "message"):
            raise LogError(
                f"Expected compression_mode file, message or none, got {mode!r} in "
                f"{folder / 'metadata.yaml'}"
            )

    @property
    def kind(self) -> str:
        parts = [f"ros2 {self.storage}"]
        if len(self.files) > 1:
            parts.append(f"split in {len(self.files)} files")
        if self.mode:
            parts.append(f"{self.mode}-compressed")
        return ", ".join(parts)

    def collect(self, sink: Sink) -> Collected:
        merged: dict[tuple, Conn] = {}
        parts: dict[int, list] = {}
        damage: list[Damage] = []
        with tempfile.TemporaryDirectory(prefix="imu_dcm_bag_") as tmp:
            for k, path in enumerate(self.files):
                if self.mode == "file":
                    path = decompress_file(path, Path(tmp))
                src = storage_source(path, self.storage)
                if isinstance(src, SqliteSource) and len(self.files) == 1:
                    src.counts = topic_counts(self.info)
                name = self.files[k].name
                transform = None
                if self.mode == "message":

                    def transform(p, name=name):
                        return decompress_messages(p, name, damage)

                got = src.collect(Sink(sink.plan, transform))
                for d in got.damage:
                    damage.append(
                        Damage(
                            d.offset,
                            f"{self.files[k].name}: {d.what}",
                            d.t_start_ns,
                            d.t_end_ns,
                            d.messages_lost,
                        )
                    )
                for c in got.conns:
                    key = (c.topic, c.msgtype, c.encoding)
                    g = merged.get(key)
                    if g is None:
                        g = merged[key] = Conn(
                            len(merged) + 1,
                            c.topic,
                            c.msgtype,
                            c.encoding,
                            c.schema_encoding,
                            c.schema_text,
                            0,
                        )
                    g.count = (g.count or 0) + (c.count or 0)
                    p = got.payloads.get(c.id)
                    if p is not None and len(p):
                        p.order = p.order + (k << 56)
                        parts.setdefault(g.id, []).append(p)
                if self.mode == "file":
                    path.unlink()
                if self.progress is not None:
                    self.progress((k + 1) / len(self.files))
            shutil.rmtree(tmp, ignore_errors=True)
        payloads = {c: join_any(p) for c, p in parts.items()}
        return Collected(self.kind, list(merged.values()), payloads, damage)


# ------------------------------------------------------------------ opening, by storage or bytes
def storage_source(path: Path, storage: str, progress: ProgressCallback | None = None) -> RosSource:
    """The source reading one storage file of a rosbag2 bag, by its ``storage_identifier``."""
    if storage == "sqlite3":
        return SqliteSource(path, progress)
    return McapSource(path, progress)


class ZstdFile(RosSource):
    """A single ``.zstd``-compressed storage file (MCAP or sqlite3), decompressed into a
    temporary folder first (bounded, see :func:`decompress_file`)."""

    kind = "zstd-compressed file"

    def __init__(self, path: Path, progress: ProgressCallback | None = None):
        self.path = path
        self.progress = progress

    def collect(self, sink: Sink) -> Collected:
        with tempfile.TemporaryDirectory(prefix="imu_dcm_bag_") as tmp:
            inner = decompress_file(self.path, Path(tmp))
            with open(inner, "rb") as f:
                head = f.read(len(SQLITE_MAGIC))
            if head.startswith(SQLITE_MAGIC):
                src: RosSource = SqliteSource(inner, self.progress)
            elif head.startswith(MCAP_MAGIC):
                src = McapSource(inner, self.progress)
            else:
                raise LogError(
                    f"Expected an MCAP or sqlite3 file inside {self.path}, got a file "
                    f"starting {head[:8]!r}"
                )
            got = src.collect(sink)
            self.kind = got.kind = f"{src.kind}, file-compressed"
            return got


def is_bag_folder(path: Path, head: bytes) -> bool:
    """A rosbag2 folder: a folder holding ``metadata.yaml``."""
    return not head and path.is_dir() and (path / "metadata.yaml").is_file()


def open_folder(folder: Path, progress: ProgressCallback | None = None) -> RosSource:
    """The source of a rosbag2 folder: its one plain storage file, or the whole folder.

    Raises
    ------
    LogError
        ``metadata.yaml`` is unreadable, names a storage other than mcap or sqlite3, lists
        files that are missing or not regular files.
    """
    info = meta.load_metadata(folder)
    storage = str(info.get("storage_identifier") or "")
    if storage not in STORAGES:
        raise LogError(
            f"Expected rosbag2 storage mcap or sqlite3, got {storage!r} in "
            f"{folder / 'metadata.yaml'}; `ros2 bag convert -i {folder.name} -o out.yaml` "
            f"with storage_id mcap rewrites it"
        )
    files = meta.file_list(info, folder)
    for f in files:
        check_regular(f)
    mode = str(info.get("compression_mode") or "").lower()
    if len(files) == 1 and mode in ("", "none"):
        src = storage_source(files[0], storage, progress)
        src.kind = f"ros2 {storage}"
        if isinstance(src, SqliteSource):
            src.counts = topic_counts(info)
    else:
        src = Rosbag2Folder(folder, info, files, progress)
    src.custom_data = meta.custom_data(info)
    return src
