"""rosbag2 ``metadata.yaml``, both ways: the one writer (bag writer and live recorder) reads back
through two independent YAML parsers; anchors and aliases are read with their expansion bounded;
an alias bomb is refused in one line."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from conftest import raises_naming
from rosbags.rosbag2 import Reader as Rosbag2Reader
from ruamel.yaml import YAML  # a dependency of rosbags: a YAML parser independent of PyYAML

from imu_dcm.errors import LogError
from imu_dcm.logio import meta, read_log
from imu_dcm.logio.writers import StampedSeries, write_bag

T0_NS = 1_700_000_000_000_000_000

# Names a topic or type may have, with the ones YAML would read as something else when plain.
NAMES = [
    "/imu/data",
    "/a_b/c~d",
    "sensor_msgs/msg/Imu",
    "123",
    "1e3",
    "yes",
    "No",
    "~",
    "null",
    "",
    "a: b",
    "- x",
    "#x",
    "'q'",
    '"dq"',
    "/ünï/cödé",
    "tab\there",
    "line\nbreak",
]


@pytest.mark.parametrize("name", NAMES)
def test_yaml_str_reads_back_as_the_same_string(name):
    doc = f"k: {meta.yaml_str(name)}\n"
    assert yaml.safe_load(doc) == {"k": name}
    assert YAML(typ="safe").load(doc) == {"k": name}


def test_metadata_body_hash_and_quoting():
    body = meta.metadata_body(
        "x.mcap",
        [("/imu/data", "sensor_msgs/msg/Imu", 3), ("/odd topic", "vendor_msgs/msg/Odd", 2)],
        10,
        25,
        {"k": 'it\'s "q"'},
    )
    info = YAML(typ="safe").load(meta.metadata_document(body))["rosbag2_bagfile_information"]
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert set(topics) == {"/imu/data", "/odd topic"}
    imu = topics["/imu/data"]["topic_metadata"]
    assert imu["type_description_hash"] == meta.TYPE_HASHES["sensor_msgs/msg/Imu"]
    # a type without a known hash: an empty string (not the text "''" or a missing key)
    assert topics["/odd topic"]["topic_metadata"]["type_description_hash"] == ""
    assert info["message_count"] == 5 and info["duration"]["nanoseconds"] == 15
    assert info["custom_data"] == {"k": 'it\'s "q"'}
    assert "/imu/data\n" in body  # a plain topic name stays plain, as rosbag2 writes it


def _write_half(folder, name, t_ns, w, q):
    return write_bag(
        folder / name,
        imu=StampedSeries(t_ns, w, "imu"),
        quaternions={"/truth": StampedSeries(t_ns, q, "world")},
    )


@pytest.fixture
def split_bag(tmp_path):
    """A split bag (two MCAP files) whose metadata.yaml PyYAML dumped with anchors and aliases."""
    rng = np.random.default_rng(5)
    n = 400
    t_ns = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    w = rng.normal(size=(n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[0] = [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]
    bag = tmp_path / "split"
    bag.mkdir()
    halves = [slice(0, n // 2), slice(n // 2, n)]
    for k, s in enumerate(halves):
        part = _write_half(tmp_path, f"part{k}", t_ns[s], w[s], q[s])
        (part / f"part{k}.mcap").rename(bag / f"split_{k}.mcap")
    info = YAML(typ="safe").load((part / "metadata.yaml").read_text())
    info = info["rosbag2_bagfile_information"]
    shared_qos = info["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"]
    shared_start = {"nanoseconds_since_epoch": int(t_ns[0])}
    for t in info["topics_with_message_count"]:
        t["topic_metadata"]["offered_qos_profiles"] = shared_qos  # one object, twice
        t["message_count"] = n
    info["relative_file_paths"] = ["split_0.mcap", "split_1.mcap"]
    info["files"] = [
        {"path": f"split_{k}.mcap", "starting_time": shared_start, "message_count": n}
        for k in range(2)
    ]
    info["starting_time"] = shared_start
    info["message_count"] = 2 * n
    text = yaml.dump({"rosbag2_bagfile_information": info})
    (bag / "metadata.yaml").write_text(text)
    return bag, t_ns, w, q, text


def test_split_bag_with_aliases_reads_whole(split_bag):
    bag, t_ns, w, q, text = split_bag
    assert "&id001" in text and "*id001" in text  # PyYAML did write anchors and aliases
    log = read_log(bag)
    np.testing.assert_array_equal(log.imu.t_ns, t_ns)
    np.testing.assert_array_equal(log.imu.omega_b, w)
    np.testing.assert_array_equal(log.truth.q_w_b, q)
    assert log.container == "ros2 mcap, split in 2 files"
    with Rosbag2Reader(bag) as other:  # an independent reader agrees on the bag
        assert other.message_count == 2 * len(t_ns)


def _laughs(levels: int, width: int = 10) -> bytes:
    lines = ["rosbag2_bagfile_information:", "  custom_data:"]
    lines.append("    a0: &a0 [" + ", ".join(["lol"] * width) + "]")
    for i in range(1, levels):
        lines.append(f"    a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return ("\n".join(lines) + "\n").encode()


@pytest.mark.parametrize("levels", [3, 9, 30])
def test_alias_bomb_is_refused_in_one_line(tmp_path, levels):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_bytes(_laughs(levels))
    with raises_naming(LogError, "YAML aliases", 1000, str(bag / "metadata.yaml")) as info:
        meta.load_metadata(bag)
    assert "\n" not in str(info.value)


def test_alias_bound_is_the_documented_growth(tmp_path):
    # One shared list of k scalars referenced r times: expanded = written + r * k. Just under the
    # bound it is read (and expands to the same mapping as without aliases); just over, refused.
    bag = tmp_path / "bag"
    bag.mkdir()

    def doc(k: int, r: int) -> str:
        refs = "".join(f"    r{i}: *s\n" for i in range(r))
        items = ", ".join(f"v{j}" for j in range(k))
        return f"rosbag2_bagfile_information:\n  custom_data:\n    s: &s [{items}]\n{refs}"

    # written: info map, custom map, keys (1 + r), the list and its k items, r aliases
    k = 200
    for r, ok in ((4, True), (60, False)):
        text = doc(k, r)
        written = 2 + (1 + r) + (1 + k) + r + 1  # + the top-level key
        expanded = written + r * k
        assert (expanded <= max(meta.MIN_ALIAS_NODES, meta.MAX_ALIAS_GROWTH * written)) == ok
        (bag / "metadata.yaml").write_text(text)
        if ok:
            info = meta.load_metadata(bag)
            assert info["custom_data"]["r3"] == [f"v{j}" for j in range(k)]
        else:
            with pytest.raises(LogError, match="without YAML aliases"):
                meta.load_metadata(bag)


def test_an_integer_past_pythons_digit_limit_is_one_line(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  message_count: "
        + "9" * 5000
        + "\n"
    )
    with raises_naming(LogError, str(bag / "metadata.yaml"), 5000) as info:
        meta.load_metadata(bag)
    assert "\n" not in str(info.value)


def test_a_file_listed_twice_through_an_alias_is_refused(split_bag):
    """relative_file_paths naming split_0.mcap twice (an alias to one list item, or written
    out): the reader read it twice, doubling every message."""
    bag, *_ = split_bag
    info = YAML(typ="safe").load((bag / "metadata.yaml").read_text())
    info["rosbag2_bagfile_information"]["relative_file_paths"] = ["split_0.mcap"] * 2
    (bag / "metadata.yaml").write_text(yaml.dump(info))
    with raises_naming(LogError, "metadata.yaml", "split_0.mcap twice", str(bag)):
        read_log(bag)
