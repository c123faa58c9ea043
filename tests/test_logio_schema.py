"""The ``.msg`` fast path of :mod:`imu_dcm.logio.ros.schema` against rosbags' parser as the oracle.

Plain ``.msg`` texts (the schemas ROS 2 and ROS 1 recorders store) are read without importing
rosbags; whatever the fast path takes must come out exactly as rosbags reads it, and whatever
it does not know (quotes, annotations, a malformed line) it must leave to rosbags, so that a
schema rosbags refuses is still refused with rosbags' words.
"""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from imu_dcm.errors import LogError
from imu_dcm.logio.ros.collect import Conn
from imu_dcm.logio.ros.schema import _convert, _msg_types, _with_time, definitions


def _rosbags(text: str, root: str):
    """rosbags' field lists, or None when rosbags refuses the text."""
    try:
        return _convert(get_types_from_msg(text, root))
    except Exception:
        return None


def _agrees(text: str, root: str) -> None:
    """The fast path reads ``text`` as rosbags does, or defers to it (None)."""
    got = _msg_types(text, root)
    if got is None:
        return
    want = _rosbags(text, root)
    assert want is not None, f"the fast path took a text rosbags refuses:\n{text}"
    assert _with_time(got) == want


@pytest.mark.parametrize(
    ("store", "version"),
    [(Stores.ROS2_HUMBLE, 2), (Stores.ROS1_NOETIC, 1)],
    ids=["ros2 humble", "ros1 noetic"],
)
def test_every_stock_message_reads_as_rosbags_reads_it(store, version):
    ts = get_typestore(store)
    read = 0
    for name in sorted(ts.fielddefs):
        text, _ = ts.generate_msgdef(name, ros_version=version)
        got = _msg_types(text, name)
        assert got is not None, name  # the stock definitions are all plain .msg
        assert _with_time(got) == _rosbags(text, name), name
        read += 1
    assert read > 100


def test_the_forms_a_hand_written_msg_takes():
    text = "\n".join(
        [
            "# a comment, then a blank line",
            "",
            "Header header  # trailing comment",
            "  time stamp2",
            "duration\tspan",
            "int32 LIMIT = 5",
            "uint8 MODE_A=1  # a constant",
            "float64 x 0.5",
            "float64[] xs",
            "float64[<=4] bounded",
            "float32[3] triple",
            "string<=10 label",
            "string[] names",
            "Vector3 relative",
            "geometry_msgs/Quaternion q",
            "other_pkg/msg/Thing[2] things",
            "=" * 80,
            "MSG: my_pkg/Vector3",
            "float64 x",
            "=" * 80,
            "MSG: std_msgs/Header",
            "uint32 seq",
            "time stamp",
            "string frame_id",
        ]
    )
    got = _msg_types(text, "my_pkg/msg/Sample")
    assert got is not None
    assert _with_time(got) == _rosbags(text, "my_pkg/msg/Sample")
    fields = {f.name: f for f in got["my_pkg/msg/Sample"]}
    assert fields["relative"].base == "my_pkg/msg/Vector3"  # resolved in the owner's package
    assert fields["q"].base == "geometry_msgs/msg/Quaternion"
    assert fields["header"].base == "std_msgs/msg/Header"
    assert fields["stamp2"].base == "builtin_interfaces/msg/Time"
    assert (fields["triple"].array, fields["triple"].count) == ("fixed", 3)
    assert fields["bounded"].array == "seq" and fields["label"].base == "string"
    assert "LIMIT" not in fields and "MODE_A" not in fields


@pytest.mark.parametrize(
    "line",
    [
        'string NAME="a # b"',  # quotes: rosbags reads them
        "@verbatim (language=comment)",  # annotations
        "float64 x0.5",  # no space before a default
        "int32 X=",  # a constant without a value
        "Foo/Bar x",  # a package name rosbags does not accept
        "float64[+3] x",
        "wstring<=5 w",
        "=" * 79,
        "int32/Foo x",  # rosbags takes the base type, then fails
        "int32 FOO_=1",
        "a" * 300 + "! x",  # long odd tokens: no regex may backtrack for ever on them
        "int32 " + "A" * 300 + "!=1",
        "pkg_/" + "B" * 300 + "_ x",
    ],
)
def test_what_the_fast_path_does_not_know_goes_to_rosbags(line):
    text = f"float64 a\n{line}\nfloat64 b\n"
    assert _msg_types(text, "p/msg/M") is None or _rosbags(text, "p/msg/M") is not None
    _agrees(text, "p/msg/M")


@pytest.mark.parametrize(
    "root", ["sensor_msgs/msg/Imu", "geometry_msgs/msg/QuaternionStamped", "nav_msgs/msg/Odometry"]
)
@pytest.mark.parametrize("version", [1, 2])
def test_mutated_schemas_read_as_rosbags_reads_them_or_defer(root, version):
    text, _ = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef(root, version)
    rng = np.random.default_rng(5)
    alphabet = "abcXYZ019_/[]<=#@ \t\n'\"=.-"
    taken = 0
    for _ in range(500):
        chars = list(text)
        for _ in range(int(rng.integers(1, 4))):
            k = int(rng.integers(len(chars)))
            op = rng.integers(3)
            if op == 0:
                del chars[k]
            elif op == 1:
                chars.insert(k, alphabet[int(rng.integers(len(alphabet)))])
            else:
                chars[k] = alphabet[int(rng.integers(len(alphabet)))]
        mutated = "".join(chars)
        taken += _msg_types(mutated, root) is not None
        _agrees(mutated, root)
    assert taken >= 25  # the fast path was tried on many (a mutated comment or name ...)


def test_a_schema_rosbags_refuses_is_refused_in_one_line():
    conn = Conn(1, "/imu", "sensor_msgs/msg/Imu", "cdr", "ros2msg", "float64 x0.5\n")
    with pytest.raises(LogError, match="/imu"):
        definitions(conn)
