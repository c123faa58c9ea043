"""Write ROS 2 bags (MCAP storage) of IMU rates, quaternions and vectors, fast and atomically.

The output is a rosbag2 folder in the layout of recorded ROS 2 logs: ``metadata.yaml``
(rosbag2 format version 9) and one ``<folder name>.mcap`` file with profile ``ros2``, CDR
messages (:mod:`imu_dcm.logio.writers.messages`), their ``ros2msg`` definitions embedded as
schemas, zstd chunks, and the rosbag2 metadata record (:mod:`imu_dcm.logio.writers.mcap`).
Readable by the project's reader, by ``mcap`` + ``mcap-ros2-support`` and by ``rosbags``.
``metadata.yaml`` is written by :mod:`imu_dcm.logio.meta` (the one module that reads and
writes it).

Header stamps come from ``t_ns`` (int64 ns since the Unix epoch); MCAP ``log_time`` and
``publish_time`` equal the header stamp unless a series gives its own ``log_t_ns`` (to build
logs whose receive times differ from their stamps). Messages are written in log-time order
across topics.

Output safety (:mod:`imu_dcm.outputs`): the bag never replaces an input, a folder holding one,
or a special file; ``force`` replaces only a bag this package wrote (its MCAP header names the
library ``imu_dcm.bag_writer``, the writer's name before it moved into :mod:`imu_dcm.logio`:
bags written then stay replaceable).
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.logio.meta import TYPE_HASHES, metadata_body, metadata_document
from imu_dcm.logio.writers.mcap import OWN_LIBRARY, Encoded, Written, write_mcap
from imu_dcm.logio.writers.messages import MSG_DEFINITIONS, cdr_messages, imu_doubles
from imu_dcm.outputs import OutputError, check_output_dir, ensure_parent

__all__ = [
    "MSG_DEFINITIONS",
    "BagBlock",
    "OWN_LIBRARY",
    "TYPE_HASHES",
    "StampedSeries",
    "cdr_messages",
    "imu_doubles",
    "write_bag",
    "write_bag_blocks",
]

_MAX_T_NS = (2**31) * 10**9  # header.stamp.sec is an int32


@dataclass(frozen=True)
class StampedSeries:
    """Stamped samples for one topic.

    Attributes
    ----------
    t_ns : ndarray of int64, shape (N,)
        Header stamps, ns since the Unix epoch (>= 0); also the MCAP log and publish times.
    values : ndarray of float64, shape (N, k)
        Samples: ``k = 3`` for rates (rad/s, body axes) and vectors, ``k = 4`` for quaternions
        ``[x, y, z, w]``.
    frame_id : str
        ``header.frame_id`` (e.g. ``"imu"``, ``"world"``).
    log_t_ns : ndarray of int64, shape (N,), optional
        MCAP log (receive) times when they differ from the header stamps (default: equal).
        Messages are written in log-time order, so header stamps may then be out of file order.
    """

    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    frame_id: str
    log_t_ns: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns)
        if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
            raise InputError(
                f"Expected `t_ns` an int64 array of shape (N,), got {t.dtype} of shape {t.shape}"
            )
        v = np.asarray(self.values, dtype=np.float64)
        if v.ndim != 2 or v.shape[0] != t.shape[0]:
            raise InputError(f"Expected `values` of shape (N={t.shape[0]}, k), got {v.shape}")
        if not isinstance(self.frame_id, str) or "\0" in self.frame_id:
            raise InputError(f"Expected `frame_id` a str without NUL, got {self.frame_id!r}")
        try:  # a ROS string is UTF-8: a lone surrogate has no encoding
            self.frame_id.encode("utf-8")
        except UnicodeEncodeError:
            raise InputError(
                f"Expected `frame_id` text that UTF-8 can encode, got {self.frame_id!r}"
            ) from None
        object.__setattr__(self, "t_ns", t.astype(np.int64, copy=False))
        object.__setattr__(self, "values", v)
        if self.log_t_ns is not None:
            lt = np.asarray(self.log_t_ns)
            if lt.shape != t.shape or not np.issubdtype(lt.dtype, np.integer):
                raise InputError(
                    f"Expected `log_t_ns` an int64 array of shape {t.shape}, got "
                    f"{lt.dtype} of shape {lt.shape}"
                )
            object.__setattr__(self, "log_t_ns", lt.astype(np.int64, copy=False))

    @property
    def file_t_ns(self) -> NDArray[np.int64]:
        """The MCAP log times: ``log_t_ns`` when given, else the header stamps."""
        return self.t_ns if self.log_t_ns is None else self.log_t_ns


def _check_series(name: str, s: StampedSeries, k: int) -> None:
    if not isinstance(s, StampedSeries):
        raise InputError(f"Expected {name} a StampedSeries, got {type(s).__name__}")
    if s.values.shape[1] != k:
        raise InputError(f"Expected {name} values of shape (N, {k}), got {s.values.shape}")
    if s.t_ns.size == 0:
        raise InputError(f"Expected {name} to hold at least one sample, got none")
    for label, t in (("t_ns", s.t_ns), ("log_t_ns", s.file_t_ns)):
        bad = np.flatnonzero((t < 0) | (t >= _MAX_T_NS))
        if bad.size:
            raise InputError(
                f"Expected {name} stamps in [0, 2^31 s) ns, got {label}[{bad[0]}] "
                f"= {int(t[bad[0]])}"
            )
    finite = np.isfinite(s.values).all(axis=1)
    if not finite.all():
        i = int(np.argmin(finite))
        raise InputError(f"Expected {name} finite values, got row {i} = {s.values[i].tolist()}")


#: (topic, msgtype, series, rows -> the float64 after each of those messages' headers)
_Topic = tuple[str, str, StampedSeries, Callable[[NDArray[np.int64]], NDArray[np.float64]]]


def _imu_topic(
    imu: StampedSeries, imu_topic: str, accel: ArrayLike | None, cov: ArrayLike | None
) -> _Topic:
    """The IMU topic's row, its acceleration and gyro covariance checked."""
    _check_series(f"imu ({imu_topic})", imu, 3)
    a = None
    if accel is not None:
        a = np.asarray(accel, dtype=float)
        if a.shape != imu.values.shape or not np.all(np.isfinite(a)):
            raise InputError(
                f"Expected finite imu_linear_acceleration of shape "
                f"{imu.values.shape}, got {a.shape}"
            )
    c = None
    if cov is not None:
        c = np.asarray(cov, dtype=float)
        if c.shape != (3, 3):
            raise InputError(
                f"Expected imu_angular_velocity_covariance of shape (3, 3), got {c.shape}"
            )

    def doubles(rows: NDArray[np.int64]) -> NDArray[np.float64]:
        return imu_doubles(imu.values[rows], None if a is None else a[rows], c)

    return (imu_topic, "sensor_msgs/msg/Imu", imu, doubles)


def _check_topic_names(topics: list[_Topic]) -> None:
    if not topics:
        raise InputError("Expected at least one of imu, quaternions, vectors, got none")
    names = [t[0] for t in topics]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"Expected distinct topic names, got {dup} more than once")
    for name in names:
        if not name.startswith("/"):
            raise InputError(f"Expected topic names starting with '/', got {name!r}")


def _encoded(topic: str, msgtype: str, s: StampedSeries, doubles) -> Encoded:
    """A topic's channel, its CDR payloads built for the rows each chunk asks for."""
    width = doubles(np.zeros(1, np.int64)).shape[1]
    size = cdr_messages(np.zeros(1, np.int64), s.frame_id, np.zeros((1, width))).shape[1]

    def payloads(rows: NDArray[np.int64]) -> NDArray[np.uint8]:
        return cdr_messages(s.t_ns[rows], s.frame_id, doubles(rows))

    return Encoded(topic, msgtype, s.file_t_ns, size, payloads)


def _write_into(
    folder: Path, name: str, blocks: Iterable[list[_Topic]], custom: dict[str, str]
) -> None:
    """``<name>.mcap`` and ``metadata.yaml`` of the bag, written into ``folder`` a block of
    topics at a time."""
    mcap_name = f"{name}.mcap"
    names: list[tuple[str, str]] = []

    def encoded():
        for topics in blocks:
            names[:] = [(t[0], t[1]) for t in topics]
            yield [_encoded(*t) for t in topics]

    def body(w: Written) -> str:
        counts = [(n, ty, c) for (n, ty), c in zip(names, w.counts, strict=True)]
        return metadata_body(mcap_name, counts, w.t_min_ns, w.t_max_ns, custom)

    with open(folder / mcap_name, "wb") as f:
        w = write_mcap(f, encoded(), lambda w: {"serialized_metadata": body(w)})
    (folder / "metadata.yaml").write_text(metadata_document(body(w)), encoding="utf-8")


def _swap_in(tmp: Path, out: Path) -> None:
    """Rename the finished ``tmp`` to ``out``; an existing ``out`` (our own bag) is replaced."""
    if out.exists():  # force, and it is our own bag: swap in, then remove the old one
        old = out.parent / f".{out.name}.old-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        os.rename(out, old)
        os.rename(tmp, out)
        shutil.rmtree(old)
    else:
        os.rename(tmp, out)


def _write_atomic(
    out: Path, blocks: Iterable[list[_Topic]], custom: dict, inputs: tuple, force: bool
) -> None:
    """Write the bag under a temporary sibling name, then swap it in (whole or not at all)."""
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        ensure_parent(out, "output bag")  # e.g. --out out/top in a fresh checkout
        tmp.mkdir()
    except OSError as exc:
        raise OutputError(
            f"Expected to create the output bag {str(out)!r}, got "
            f"{type(exc).__name__}: {exc.strerror}"
        ) from None
    try:
        _write_into(tmp, out.name, blocks, custom)
        check_output_dir(out, inputs, force=force, what="output bag")  # unchanged meanwhile
        _swap_in(tmp, out)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(
            f"Expected to write the output bag {str(out)!r}, got "
            f"{type(exc).__name__}: {exc.strerror or exc}"
        ) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_bag(
    out_dir: str | os.PathLike,
    *,
    imu: StampedSeries | None = None,
    quaternions: Mapping[str, StampedSeries] | None = None,
    vectors: Mapping[str, StampedSeries] | None = None,
    imu_topic: str = "/imu/data",
    imu_linear_acceleration: ArrayLike | None = None,
    imu_angular_velocity_covariance: ArrayLike | None = None,
    custom_data: Mapping[str, str] | None = None,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write a rosbag2 folder (MCAP storage) atomically.

    Parameters
    ----------
    out_dir : path
        Bag folder to create; it appears whole or not at all (written under a temporary sibling
        name, renamed at the end).
    imu : StampedSeries, optional
        Gyro rates ``omega_b`` (N, 3), rad/s, body axes, on ``imu_topic`` as
        ``sensor_msgs/msg/Imu``.
    quaternions : dict of topic -> StampedSeries, optional
        ``geometry_msgs/msg/QuaternionStamped`` topics, values (N, 4) ``[x, y, z, w]``.
    vectors : dict of topic -> StampedSeries, optional
        ``geometry_msgs/msg/Vector3Stamped`` topics, values (N, 3).
    imu_topic : str
        Topic of the IMU messages.
    imu_linear_acceleration : array_like, shape (N, 3), optional
        Specific force, m/s², body axes, aligned with ``imu``; ``None``: not measured
        (``linear_acceleration_covariance[0] = -1``).
    imu_angular_velocity_covariance : array_like, shape (3, 3), optional
        ``angular_velocity_covariance``, (rad/s)²; ``None``: zeros (unknown).
    custom_data : dict of str -> str, optional
        Recorded in ``metadata.yaml`` ``custom_data`` (and in the MCAP's rosbag2 record).
    force : bool
        Replace an existing ``out_dir``, only if it is a bag this function wrote
        (:func:`imu_dcm.outputs.is_own_bag`).
    inputs : iterable of path
        Paths that must survive: ``out_dir`` may not be, hold or lie inside any of them.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    LogError
        (:class:`imu_dcm.outputs.OutputError`) If ``out_dir`` exists and ``force`` is false,
        exists and is not a bag written here, is or holds an input, is a special file, its
        parent folder is missing or read-only, or writing fails.
    InputError
        For a malformed series (shape, non-finite value, stamp out of range), no topics at all,
        a duplicated topic, or a non-string ``custom_data`` entry.
    """
    inputs = tuple(inputs)
    out, custom = _checked_out(out_dir, inputs, force, custom_data)
    block = BagBlock(imu, quaternions or {}, vectors or {}, imu_linear_acceleration)
    topics = _block_topics(block, imu_topic, imu_angular_velocity_covariance)
    _write_atomic(out, [topics], custom, inputs, force)
    return out


def _checked_out(out_dir, inputs: tuple, force: bool, custom_data) -> tuple[Path, dict]:
    """The output folder (:func:`imu_dcm.outputs.check_output_dir`) and the custom data,
    checked."""
    out = check_output_dir(out_dir, inputs, force=force, what="output bag")
    custom = dict(custom_data or {})
    for k, v in custom.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise InputError(f"Expected custom_data str -> str, got {k!r}: {type(v).__name__}")
    return out, custom


@dataclass(frozen=True)
class BagBlock:
    """One block of a bag written by :func:`write_bag_blocks`: the arguments of
    :func:`write_bag` of the same names, for a stretch of the log."""

    imu: StampedSeries | None = None
    quaternions: Mapping[str, StampedSeries] = field(default_factory=dict)
    vectors: Mapping[str, StampedSeries] = field(default_factory=dict)
    imu_linear_acceleration: ArrayLike | None = None


def _block_topics(block: BagBlock, imu_topic: str, cov: ArrayLike | None) -> list[_Topic]:
    """The topics of one block, each series checked."""
    topics: list[_Topic] = []
    if block.imu is not None:
        topics.append(_imu_topic(block.imu, imu_topic, block.imu_linear_acceleration, cov))
    for name, s in dict(block.quaternions).items():
        _check_series(f"quaternions[{name!r}]", s, 4)
        topics.append((name, "geometry_msgs/msg/QuaternionStamped", s, s.values.__getitem__))
    for name, s in dict(block.vectors).items():
        _check_series(f"vectors[{name!r}]", s, 3)
        topics.append((name, "geometry_msgs/msg/Vector3Stamped", s, s.values.__getitem__))
    _check_topic_names(topics)
    return topics


def write_bag_blocks(
    out_dir: str | os.PathLike,
    blocks: Iterable[BagBlock],
    *,
    imu_topic: str = "/imu/data",
    imu_angular_velocity_covariance: ArrayLike | None = None,
    custom_data: Mapping[str, str] | None = None,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """:func:`write_bag`, a block of the log at a time: a log of any length in the memory of
    one block.

    ``blocks`` yields :class:`BagBlock` s in log-time order (each block's stamps at or after
    the block before's), every block with the same topics; each is encoded, compressed and
    written before the next is asked for. The other arguments are :func:`write_bag`'s. The bag
    appears whole or not at all: a block that fails its checks (:func:`write_bag`'s, plus
    order and topics) removes what was written and raises :class:`InputError`.
    """
    inputs = tuple(inputs)
    out, custom = _checked_out(out_dir, inputs, force, custom_data)
    cov = imu_angular_velocity_covariance
    _write_atomic(out, (_block_topics(b, imu_topic, cov) for b in blocks), custom, inputs, force)
    return out
