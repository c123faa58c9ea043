"""Record a live run as a ROS 2 bag (MCAP storage) as it goes: what was received + the estimate.

The bag folder (``metadata.yaml`` + ``<name>.mcap``, the layout of the project's other bags) is
written while the run lasts with ``mcap``'s streaming writer: every message is added as it is
handled, chunks (zstd) go to the file when full, and every ``FLUSH_S`` seconds the open chunk is
closed and written, the file flushed and ``metadata.yaml`` rewritten, so a crash loses at most
that much. :meth:`LiveRecorder.close` (on Ctrl-C, SIGTERM, a lost source or the end of input)
writes the summary and the footer: the bag reads back with the project's reader and ``rosbags``.

Topics: a WebSocket source's IMU and truth channels under their own topics, with the payloads
exactly as received and the schemas the server advertised; line sources as ``/imu/data``
(``sensor_msgs/msg/Imu``, rates in rad/s) and ``/ground_truth/orientation``
(``geometry_msgs/msg/QuaternionStamped``) when the lines carry a truth; the estimate as
``/estimate/orientation`` (QuaternionStamped, frame ``world``, stamped with the sample's source
stamp). MCAP log times are the wall clock when a message arrived (when the estimate was made),
as rosbag2 records them; header stamps are the source's.
"""

from __future__ import annotations

import os
import shutil
import time

import numpy as np
from mcap.writer import CompressionType, Writer
from numpy.typing import NDArray

from imu_dcm.live.events import Channel, Received
from imu_dcm.logio import meta
from imu_dcm.logio.writers import MSG_DEFINITIONS, cdr_messages, imu_doubles
from imu_dcm.outputs import check_output_dir, ensure_parent

__all__ = ["FLUSH_S", "LiveRecorder"]

#: Longest time a recorded message waits in memory before it is written to the file, s.
FLUSH_S = 1.0
_EST_TOPIC = "/estimate/orientation"
_QUAT_TYPE = "geometry_msgs/msg/QuaternionStamped"
_IMU_TYPE = "sensor_msgs/msg/Imu"


class LiveRecorder:
    """Streaming ROS 2 bag writer (see the module doc).

    Parameters
    ----------
    path : path-like
        Bag folder to create (missing parent folders are created).
    force : bool
        Replace an existing bag folder this project wrote (:func:`imu_dcm.outputs.is_own_bag`);
        anything else is refused with :class:`imu_dcm.outputs.OutputError`.
    custom_data : dict of str -> str
        Stored in ``metadata.yaml`` ``custom_data``.
    """

    def __init__(self, path, force: bool = False, custom_data: dict | None = None) -> None:
        out = check_output_dir(path, force=force, what="--record bag")
        ensure_parent(out, "--record bag")
        if out.exists():  # with force, a bag this project wrote (check_output_dir)
            shutil.rmtree(out)
        out.mkdir()
        self.path = out
        self.mcap_name = f"{out.name}.mcap"
        self.custom = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._file = open(out / self.mcap_name, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, chunk_size=256 * 1024, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="imu_dcm.live")
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[str, int] = {}  # kind -> channel id
        self._topics: dict[int, list] = {}  # channel id -> [topic, type, count]
        self._t_range = [None, None]
        self._last_flush = time.monotonic()
        self._closed = False
        self._channel("estimate", _EST_TOPIC, _QUAT_TYPE, "ros2msg", MSG_DEFINITIONS[_QUAT_TYPE])
        self._write_metadata()

    def _channel(self, kind: str, topic: str, type_name: str, encoding: str, text: str) -> int:
        key = (type_name, text)
        sid = self._schemas.get(key)
        if sid is None:
            sid = self._writer.register_schema(type_name, encoding, text.encode("utf-8"))
            self._schemas[key] = sid
        cid = self._writer.register_channel(
            topic, "cdr", sid, {"offered_qos_profiles": meta.QOS_YAML}
        )
        self._channels[kind] = cid
        self._topics[cid] = [topic, type_name, 0]
        return cid

    def add_channel(self, ch: Channel) -> None:
        """A picked source channel; WebSocket channels are recorded under their own topic."""
        if ch.kind in self._channels or not ch.name:
            return  # line sources: registered with the first data
        self._channel(ch.kind, ch.topic, ch.name, ch.encoding or "ros2msg", ch.text)

    def _write(self, cid: int, log_ns: NDArray, t_ns: NDArray, payloads) -> None:
        add = self._writer.add_message
        for lt, data in zip(log_ns.tolist(), payloads, strict=False):
            add(channel_id=cid, log_time=lt, data=data, publish_time=lt)
        info = self._topics[cid]
        info[2] += len(log_ns)
        if len(t_ns):
            lo, hi = int(np.min(log_ns)), int(np.max(log_ns))
            a, b = self._t_range
            self._t_range = [lo if a is None else min(a, lo), hi if b is None else max(b, hi)]

    def add_received(self, rec: Received) -> None:
        """Record a received batch (raw payloads as they came, or line samples as messages)."""
        if self._closed:
            return
        if rec.raw is not None:
            cid = self._channels.get(rec.kind)
            if cid is not None:
                self._write(cid, rec.wall_ns, rec.t_ns, rec.raw)
            return
        ok = (rec.t_ns >= 0) & (rec.t_ns < (2**31) * 10**9)
        t = rec.t_ns[ok]
        if not len(t):
            return
        if rec.kind == "imu":
            cid = self._channels.get("imu") or self._channel(
                "imu", "/imu/data", _IMU_TYPE, "ros2msg", MSG_DEFINITIONS[_IMU_TYPE]
            )
            rows = cdr_messages(t, "imu", imu_doubles(rec.values[ok], None, None))
        else:
            cid = self._channels.get("truth") or self._channel(
                "truth",
                "/ground_truth/orientation",
                _QUAT_TYPE,
                "ros2msg",
                MSG_DEFINITIONS[_QUAT_TYPE],
            )
            rows = cdr_messages(t, "world", rec.values[ok])
        self._write(cid, rec.wall_ns[ok], t, [r.tobytes() for r in rows])

    def add_estimate(self, t_ns: NDArray, q_w_b: NDArray) -> None:
        """Record estimates ``q_w_b`` (n, 4) ``[x, y, z, w]`` at source stamps ``t_ns``."""
        if self._closed:
            return
        ok = (t_ns >= 0) & (t_ns < (2**31) * 10**9) & np.all(np.isfinite(q_w_b), axis=1)
        if not ok.any():
            return
        rows = cdr_messages(t_ns[ok], "world", q_w_b[ok])
        wall = np.full(int(ok.sum()), time.time_ns(), np.int64)
        self._write(self._channels["estimate"], wall, t_ns[ok], [r.tobytes() for r in rows])

    def maybe_flush(self) -> None:
        """Write the open chunk and metadata when ``FLUSH_S`` has passed since the last time."""
        if not self._closed and time.monotonic() - self._last_flush >= FLUSH_S:
            self.flush()

    def flush(self) -> None:
        self._writer.flush()
        self._write_metadata()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Finish the MCAP (summary, footer) and write the final ``metadata.yaml``."""
        if self._closed:
            return
        self._closed = True
        self._writer.add_metadata("rosbag2", {"serialized_metadata": self._metadata_body()})
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        self._write_metadata()

    def _metadata_body(self) -> str:
        start, end = self._t_range
        start = start or 0
        topics = [(t, ty, n) for t, ty, n in self._topics.values()]
        return meta.metadata_body(self.mcap_name, topics, start, end or start, self.custom)

    def _write_metadata(self) -> None:
        meta.write_metadata(self.path, self._metadata_body())
