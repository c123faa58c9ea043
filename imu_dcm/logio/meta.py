"""rosbag2 ``metadata.yaml``, both ways: read with bounds, and written (one form for every bag).

Reading: a ``metadata.yaml`` is a few kilobytes written by rosbag2 or rosbags. Scripts that fix
one up with PyYAML write YAML anchors and aliases wherever two entries share an object; those
are read, but the expansion is bounded before anything is built: the document may expand to at
most :data:`MAX_ALIAS_GROWTH` times the nodes written (at least :data:`MIN_ALIAS_NODES`), so an
alias bomb ("billion laughs") is refused in one line. A huge file, brackets nested too deep, a
document that is not UTF-8 or not the ``rosbag2_bagfile_information`` mapping raise
:class:`~imu_dcm.errors.LogError` instead of a traceback.

Writing: :func:`metadata_body` is the rosbag2 format version 9 body that the bag writer
(:mod:`imu_dcm.logio.writers`) and live's recorder both write; :func:`write_metadata` replaces a
bag's ``metadata.yaml`` whole (:func:`imu_dcm.outputs.write_text_atomic`).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from imu_dcm.errors import LogError

__all__ = [
    "MAX_ALIAS_GROWTH",
    "MAX_METADATA_BYTES",
    "MAX_NESTING",
    "MIN_ALIAS_NODES",
    "QOS_YAML",
    "TYPE_HASHES",
    "custom_data",
    "file_list",
    "load_metadata",
    "load_yaml",
    "metadata_body",
    "metadata_document",
    "read_custom_data",
    "topic_counts",
    "write_metadata",
    "yaml_str",
]


#: Largest metadata.yaml read (bytes); real ones are a few kB, one per topic ~0.5 kB.
MAX_METADATA_BYTES = 4 * 1024 * 1024
#: Deepest nesting of [ ] / { } accepted (rosbag2 writes 2-3 levels).
MAX_NESTING = 64
#: Aliases may expand a document to this many times the nodes written (PyYAML's shared QoS or
#: topic entries expand 2-4x; an alias bomb grows exponentially) ...
MAX_ALIAS_GROWTH = 10
#: ... or to this many nodes, whichever is more (a small file with a few shared entries).
MIN_ALIAS_NODES = 1000

#: REP 2011 type hashes (RIHS01) of the message types, as in rosbag2 metadata (Humble+ types).
TYPE_HASHES: dict[str, str] = {
    "sensor_msgs/msg/Imu": "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",  # noqa: E501
    "geometry_msgs/msg/QuaternionStamped": "RIHS01_381add86c6c3160644d228ca342182c7fd6c7fab11c7a85ad817a9cc22dbac6e",  # noqa: E501
    "geometry_msgs/msg/Vector3Stamped": "RIHS01_d4829622288cbb443886e7ea94ea5671a3b1be6bab4ad04224432a65f7d7887a",  # noqa: E501
}

#: ``offered_qos_profiles`` of every topic written (rosbag2's default: reliable, volatile,
#: keep last 10); also the MCAP channel metadata.
QOS_YAML = """- avoid_ros_namespace_conventions: false
  deadline:
    nsec: 854775807
    sec: 9223372036
  depth: 10
  durability: volatile
  history: keep_last
  lifespan:
    nsec: 854775807
    sec: 9223372036
  liveliness: automatic
  liveliness_lease_duration:
    nsec: 854775807
    sec: 9223372036
  reliability: reliable"""

# Words YAML 1.1 resolves to a bool or null when plain (PyYAML does; rosbag2's yaml-cpp too).
_YAML_WORDS = {"y", "n", "yes", "no", "true", "false", "on", "off", "null", "~"}


def _alias_refusal(expanded: int, written: int, where: Path, what: str) -> LogError:
    limit = max(MIN_ALIAS_NODES, MAX_ALIAS_GROWTH * written)
    return LogError(
        f"Expected a {what} without YAML aliases expanding it past {limit} nodes "
        f"({MAX_ALIAS_GROWTH}x the {written} written), got {expanded}+ nodes in {where}"
    )


def _check_aliases(events, where: Path, what: str) -> None:
    """Count the nodes the document expands to (aliases included) without expanding it.

    ``events`` are the parser's events. An anchored node's expanded size is known at its end;
    an alias adds that size. Refused as soon as the count passes the bound.
    """
    import yaml  # lazy: ~15 ms at import, a bag folder or EuRoC sensor file only

    sizes: dict[str, int] = {}
    stack: list[list] = []  # open collections: [anchor, expanded size so far]
    expanded = written = 0
    for ev in events:
        if isinstance(ev, yaml.AliasEvent):
            size = sizes.get(ev.anchor, 1)
        elif isinstance(ev, yaml.ScalarEvent):
            size = 1
            if ev.anchor:
                sizes[ev.anchor] = 1
        elif isinstance(ev, yaml.CollectionStartEvent):
            stack.append([ev.anchor, 1])
            written += 1
            expanded += 1
            continue
        elif isinstance(ev, yaml.CollectionEndEvent):
            anchor, size = stack.pop()
            if anchor:
                sizes[anchor] = size
            if stack:
                stack[-1][1] += size
            continue
        else:
            continue
        written += 1
        expanded += size
        if stack:
            stack[-1][1] += size
        if expanded > max(MIN_ALIAS_NODES, MAX_ALIAS_GROWTH * written):
            raise _alias_refusal(expanded, written, where, what)


def load_yaml(text: str, where: Path, what: str = "rosbag2 metadata.yaml") -> Any:
    """The YAML document ``text`` (from the file ``where``), aliases bounded (module doc).

    Raises
    ------
    LogError
        A syntax error, nesting too deep for the parser, or aliases expanding past the bound;
        the message names ``what`` and ``where``.
    """
    import yaml  # lazy, as in _check_aliases

    loader_cls = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    try:
        # Events first: aliases are counted before anything is built from them.
        _check_aliases(yaml.parse(text, Loader=loader_cls), where, what)
        return yaml.load(text, Loader=loader_cls)
    except yaml.YAMLError as exc:
        line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogError(
            f"Expected a YAML {what.split()[-1]}, got a syntax error in {where}: {line}"
        ) from None
    except RecursionError:
        raise LogError(f"Expected a {what}, got nesting too deep in {where}") from None
    except ValueError as exc:  # an integer of over 4300 digits (Python's conversion limit)
        line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogError(f"Expected a {what} of plain values, got in {where}: {line}") from None


def _check_nesting(raw: bytes, where: Path) -> None:
    """Refuse flow collections nested deeper than MAX_NESTING (YAML parsers recurse on them)."""
    b = np.frombuffer(raw, np.uint8)
    step = ((b == 0x5B) | (b == 0x7B)).astype(np.int32) - ((b == 0x5D) | (b == 0x7D))
    depth = int(np.cumsum(step).max()) if len(b) else 0
    if depth > MAX_NESTING:
        raise LogError(
            f"Expected a rosbag2 metadata.yaml, got brackets nested {depth} deep in {where}"
        )


def load_metadata(folder: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of ``folder/metadata.yaml``.

    Raises
    ------
    LogError
        The file is too big, not UTF-8, not YAML, uses aliases, or is not the expected mapping.
    """
    meta = folder / "metadata.yaml"
    try:
        size = meta.stat().st_size
        if size > MAX_METADATA_BYTES:
            raise LogError(
                f"Expected a metadata.yaml of at most {MAX_METADATA_BYTES} bytes, got "
                f"{size} bytes in {folder}"
            )
        raw = meta.read_bytes()
    except OSError as exc:
        raise LogError(
            f"Expected a readable metadata.yaml in {folder}, got {exc.strerror}"
        ) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise LogError(
            f"Expected a UTF-8 metadata.yaml, got a non-UTF-8 byte at {exc.start} in {meta}"
        ) from None
    _check_nesting(raw, meta)
    doc = load_yaml(text, meta)
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise LogError(
            f"Expected a rosbag2_bagfile_information mapping in {meta}, got "
            f"{type(doc).__name__ if not isinstance(doc, dict) else 'none'}"
        )
    return info


def custom_data(info: dict[str, Any]) -> dict[str, str]:
    """``custom_data`` as str -> str (empty when absent or not a mapping)."""
    data = info.get("custom_data")
    if not isinstance(data, dict):
        return {}
    return {str(k): str(v) for k, v in data.items()}


def topic_counts(info: dict[str, Any]) -> dict[str, int] | None:
    """Message count per topic from ``topics_with_message_count`` (None when unusable)."""
    out = {}
    try:
        for t in info.get("topics_with_message_count") or []:
            out[str(t["topic_metadata"]["name"])] = int(t["message_count"])
    except (KeyError, TypeError, ValueError):
        return None
    return out or None


def file_list(info: dict[str, Any], folder: Path) -> list[Path]:
    """The bag's storage files in recording order (``relative_file_paths``), checked."""
    rel = info.get("relative_file_paths")
    if not isinstance(rel, list) or not rel or not all(isinstance(x, str) for x in rel):
        raise LogError(
            f"Expected relative_file_paths (a list of file names) in "
            f"{folder / 'metadata.yaml'}, got {rel!r:.80}"
        )
    out = []
    for name in rel:
        p = folder / Path(name).name  # never outside the folder
        if p in out:
            raise LogError(
                f"Expected each bag file listed once in metadata.yaml, got {p.name} twice in "
                f"{folder}"
            )
        if not p.is_file():
            what = "a special file or folder" if p.exists() else "no such file"
            raise LogError(
                f"Expected the bag file {p.name} listed in metadata.yaml, got {what} in {folder}"
            )
        out.append(p)
    return out


def read_custom_data(path: str | Path) -> dict[str, str]:
    """``custom_data`` of a rosbag2 folder's ``metadata.yaml`` (empty dict when absent)."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    if not (folder / "metadata.yaml").is_file():
        return {}
    try:
        return custom_data(load_metadata(folder))
    except LogError:
        return {}


# ------------------------------------------------------------------------------- writing
def yaml_str(s: str) -> str:
    """A YAML scalar for ``s``: plain where YAML reads it back as the same string (a topic
    such as ``/imu/data``, a type such as ``sensor_msgs/msg/Imu``), else double-quoted (JSON
    string syntax is valid YAML)."""
    if re.fullmatch(r"[A-Za-z_/][A-Za-z0-9_/~]*", s) and s.lower() not in _YAML_WORDS:
        return s
    return json.dumps(s)


def metadata_body(
    mcap_name: str,
    topics: list[tuple[str, str, int]],
    start_ns: int,
    end_ns: int,
    custom_data: Mapping[str, str],
) -> str:
    """The rosbag2 ``metadata.yaml`` body (format version 9, MCAP storage), unindented.

    ``topics`` holds ``(name, type, message count)``; each type's REP 2011 hash comes from
    :data:`TYPE_HASHES` (an empty string for a type not listed, as rosbag2 writes for types
    without one). ``start_ns`` / ``end_ns`` are the first and last log times.
    """
    total = sum(n for _, _, n in topics)
    lines = ["compression_format: ''", "compression_mode: ''"]
    if custom_data:
        lines.append("custom_data:")
        lines += [f"  {json.dumps(k)}: {json.dumps(v)}" for k, v in custom_data.items()]
    else:
        lines.append("custom_data: {}")
    lines += [
        "duration:",
        f"  nanoseconds: {end_ns - start_ns}",
        "files:",
        "- duration:",
        f"    nanoseconds: {end_ns - start_ns}",
        f"  message_count: {total}",
        f"  path: {yaml_str(mcap_name)}",
        "  starting_time:",
        f"    nanoseconds_since_epoch: {start_ns}",
        f"message_count: {total}",
        "relative_file_paths:",
        f"- {yaml_str(mcap_name)}",
        "ros_distro: rosbags",
        "starting_time:",
        f"  nanoseconds_since_epoch: {start_ns}",
        "storage_identifier: mcap",
        "topics_with_message_count:",
    ]
    qos = "\n".join("    " + ln for ln in QOS_YAML.splitlines())
    for name, msgtype, count in topics:
        lines += [
            f"- message_count: {count}",
            "  topic_metadata:",
            f"    name: {yaml_str(name)}",
            "    offered_qos_profiles:",
            qos,
            "    serialization_format: cdr",
            f"    type: {yaml_str(msgtype)}",
            f"    type_description_hash: {yaml_str(TYPE_HASHES.get(msgtype, ''))}",
        ]
    lines.append("version: 9")
    return "\n".join(lines) + "\n"


def metadata_document(body: str) -> str:
    """The whole ``metadata.yaml``: ``body`` under ``rosbag2_bagfile_information``."""
    return "rosbag2_bagfile_information:\n" + "".join("  " + ln + "\n" for ln in body.splitlines())


def write_metadata(folder: Path, body: str) -> Path:
    """Replace ``folder/metadata.yaml`` whole with ``body`` (never half-written)."""
    # lazy: outputs is kept off the replay's import path (tests/test_replay_imports.py)
    from imu_dcm.outputs import write_text_atomic

    return write_text_atomic(folder / "metadata.yaml", metadata_document(body))
