"""The compiled field walk against rosbags, an independent CDR and ROS 1 implementation.

Messages of one layout with every kind of step the walk follows (strings of any length,
sequences of 1-, 2-, 4- and 8-byte values, fixed arrays, signed and unsigned integers of every
width, float32 and float64, nested messages) are serialised by rosbags and decoded by
:func:`imu_dcm.logio.ros.cdr.decode`; every wanted value must equal what was serialised, as
rosbags' own deserialiser (:func:`~imu_dcm.logio.ros.cdr.decode_slow`) reads it too.
"""

from __future__ import annotations

import numpy as np
import pytest

from imu_dcm.logio.ros.cdr import Scratch, decode, decode_slow
from imu_dcm.logio.ros.collect import Conn, Payloads
from imu_dcm.logio.ros.schema import definitions, typestore_for

ROOT = "acme_msgs/msg/Probe"
SECTION = "\n" + "=" * 80 + "\nMSG: "
SCHEMA = (
    "std_msgs/Header header\nuint8[] blob\nfloat32 f\nint16 s\nstring name\n"
    "int16[] shorts\nacme_msgs/Inner inner\nfloat64[3] arr\nint8 k\nuint32[] words\n"
    "float64 last\nuint64 big\nint32 neg\n"
    + SECTION + "acme_msgs/Inner\nbool flag\nfloat64[] seq\ngeometry_msgs/Vector3 v\n"
    + SECTION + "geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
    + SECTION + "std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
    + SECTION + "builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
)  # fmt: skip
WANT = {
    "header.stamp.sec": ("i8", 1),
    "header.stamp.nanosec": ("i8", 1),
    "f": ("f8", 1),
    "s": ("i8", 1),
    "inner.flag": ("i8", 1),
    "inner.v.x": ("f8", 1),
    "inner.v.y": ("f8", 1),
    "inner.v.z": ("f8", 1),
    "arr": ("f8", 2),  # the first two of three
    "k": ("i8", 1),
    "last": ("f8", 1),
    "big": ("u8", 1),
    "neg": ("i8", 1),
}


def _conn(encoding: str) -> Conn:
    return Conn(1, "/probe", ROOT, encoding, "ros2msg", SCHEMA)


def _messages(store, n: int, rng) -> list:
    def t(name):
        return store.types[name]

    out = []
    for i in range(n):
        stamp = t("builtin_interfaces/msg/Time")(sec=int(rng.integers(-(2**31), 2**31)), nanosec=i)
        inner = t("acme_msgs/msg/Inner")(
            flag=bool(i % 2),
            seq=rng.normal(size=int(rng.integers(0, 4))),
            v=t("geometry_msgs/msg/Vector3")(*rng.normal(size=3)),
        )
        out.append(
            t(ROOT)(
                header=t("std_msgs/msg/Header")(
                    stamp=stamp, frame_id="f" * int(rng.integers(0, 12))
                ),
                blob=rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8),
                f=np.float32(rng.normal()),
                s=int(rng.integers(-(2**15), 2**15)),
                name="n" * int(rng.integers(0, 7)),
                shorts=rng.integers(-5, 5, int(rng.integers(0, 5)), dtype=np.int16),
                inner=inner,
                arr=rng.normal(size=3),
                k=int(rng.integers(-128, 128)),
                words=rng.integers(0, 2**32, int(rng.integers(0, 4)), dtype=np.uint32),
                last=float(rng.normal()),
                big=int(rng.integers(0, 2**63)) * 2 + 1,
                neg=int(rng.integers(-(2**31), 0)),
            )
        )
    return out


def _expected(msg) -> dict:
    return {
        "header.stamp.sec": msg.header.stamp.sec,
        "header.stamp.nanosec": msg.header.stamp.nanosec,
        "f": float(np.float32(msg.f)),
        "s": msg.s,
        "inner.flag": int(msg.inner.flag),
        "inner.v.x": msg.inner.v.x,
        "inner.v.y": msg.inner.v.y,
        "inner.v.z": msg.inner.v.z,
        "arr": msg.arr[:2],
        "k": msg.k,
        "last": msg.last,
        "big": msg.big,
        "neg": msg.neg,
    }


def _payloads(blobs: list[bytes]) -> Payloads:
    lengths = np.array([len(b) for b in blobs], np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    n = len(blobs)
    buf = np.frombuffer(b"".join(blobs), np.uint8)
    return Payloads(buf, starts, lengths, np.zeros(n, np.int64), np.arange(n, dtype=np.int64))


@pytest.mark.parametrize("encoding", ["cdr", "ros1"])
def test_every_kind_of_step_reads_what_rosbags_wrote(encoding):
    conn = _conn(encoding)
    store, root = typestore_for(conn)
    msgs = _messages(store, 300, np.random.default_rng(7))
    if encoding == "cdr":
        blobs = [bytes(store.serialize_cdr(m, root)) for m in msgs]
    else:
        blobs = [bytes(store.serialize_ros1(m, root)) for m in msgs]
    raw = _payloads(blobs)
    defs, root = definitions(conn)
    scratch = Scratch()
    out, good = decode(conn, defs, root, raw, WANT, scratch)
    assert good.all()
    slow, slow_good = decode_slow(conn, raw, WANT)
    assert slow_good.all()
    for path, (dtype, count) in WANT.items():
        want = np.array([_expected(m)[path] for m in msgs], dtype=dtype)
        assert out[path].dtype == np.dtype(dtype)
        assert out[path].shape == ((300, count) if count > 1 else (300,))
        np.testing.assert_array_equal(out[path], want, err_msg=path)
        np.testing.assert_array_equal(slow[path], out[path], err_msg=path)
    # a second batch through the same scratch: the first one's leaves are views of it
    again, _ = decode(conn, defs, root, _payloads(blobs[:10]), WANT, scratch)
    np.testing.assert_array_equal(again["last"], [m.last for m in msgs[:10]])


def test_a_short_or_big_endian_message_costs_only_itself():
    conn = _conn("cdr")
    store, root = typestore_for(conn)
    msgs = _messages(store, 40, np.random.default_rng(8))
    blobs = [bytes(store.serialize_cdr(m, root)) for m in msgs]
    blobs[5] = blobs[5][:30]  # cut inside the layout: no value to give
    blobs[9] = blobs[9][:3]  # not even the encapsulation header
    blobs[17] = bytes(store.serialize_cdr(msgs[17], root, little_endian=False))
    defs, root = definitions(conn)
    out, good = decode(conn, defs, root, _payloads(blobs), WANT, Scratch())
    np.testing.assert_array_equal(np.flatnonzero(~good), [5, 9])
    assert np.isnan(out["last"][[5, 9]]).all() and (out["neg"][[5, 9]] == 0).all()
    keep = np.flatnonzero(good)  # the big-endian one read by rosbags, every other one walked
    np.testing.assert_array_equal(out["last"][keep], [msgs[i].last for i in keep])
    np.testing.assert_array_equal(out["neg"][keep], [msgs[i].neg for i in keep])
    np.testing.assert_array_equal(out["arr"][keep], [msgs[i].arr[:2] for i in keep])


def test_an_all_big_endian_batch_is_read_by_rosbags():
    conn = _conn("cdr")
    store, root = typestore_for(conn)
    msgs = _messages(store, 12, np.random.default_rng(9))
    blobs = [bytes(store.serialize_cdr(m, root, little_endian=False)) for m in msgs]
    defs, root = definitions(conn)
    out, good = decode(conn, defs, root, _payloads(blobs), WANT)
    assert good.all()
    np.testing.assert_array_equal(out["inner.v.y"], [m.inner.v.y for m in msgs])
    np.testing.assert_array_equal(out["big"], np.array([m.big for m in msgs], np.uint64))


def test_the_walk_refuses_a_table_it_would_misread():
    from imu_dcm._kernels.calls import walk_fields

    buf = np.zeros(64, np.uint8)
    start, length = np.array([0], np.int64), np.array([64], np.int64)
    out, good = np.zeros((1, 2), np.uint64), np.zeros(1, bool)
    for row in ([0, 3, 1, 0, 0, 1], [0, 8, 2, 0, 1, 2], [0, 8, 1, 0, 0, 2], [1, 8, 0, 0, 0, 1]):
        with pytest.raises(TypeError, match="Expected steps"):
            walk_fields(buf, start, length, True, np.array([row], np.int64), out, good)
    # a message outside the buffer is not read: it is not good
    ok = np.array([[0, 8, 1, 0, 0, 1]], np.int64)
    assert walk_fields(buf, np.array([40], np.int64), length, False, ok, out, good) == 1
    assert not good[0]
    buf[8:16] = np.frombuffer(np.float64(2.5).tobytes(), np.uint8)
    assert (
        walk_fields(buf, np.array([8], np.int64), np.array([8], np.int64), False, ok, out, good)
        == 0
    )
    assert good[0] and out[0, :1].view(np.float64)[0] == 2.5
