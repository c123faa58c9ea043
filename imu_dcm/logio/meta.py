"""rosbag2 ``metadata.yaml``, read with bounds: size, no aliases, the expected mapping.

A ``metadata.yaml`` is a few kilobytes written by rosbag2 or rosbags; it never uses YAML
aliases. An alias bomb ("billion laughs") or a huge file is refused before it is expanded, and a
document that is not UTF-8 or not the ``rosbag2_bagfile_information`` mapping raises
:class:`~imu_dcm.errors.LogError` instead of a traceback.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from imu_dcm.errors import LogError

#: Largest metadata.yaml read (bytes); real ones are a few kB, one per topic ~0.5 kB.
MAX_METADATA_BYTES = 4 * 1024 * 1024
#: Deepest nesting of [ ] / { } accepted (rosbag2 writes 2-3 levels).
MAX_NESTING = 64


def _yaml_load(text: str, where: Path) -> Any:
    import yaml

    loader_cls = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    try:
        # Events first: an alias is refused before anything is built from it.
        for event in yaml.parse(text, Loader=loader_cls):
            if isinstance(event, yaml.AliasEvent):
                raise LogError(
                    f"Expected a rosbag2 metadata.yaml without YAML aliases, got an "
                    f"alias in {where}"
                )
        return yaml.load(text, Loader=loader_cls)
    except yaml.YAMLError as exc:
        line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogError(
            f"Expected a YAML metadata.yaml, got a syntax error in {where}: {line}"
        ) from None
    except RecursionError:
        raise LogError(
            f"Expected a rosbag2 metadata.yaml, got nesting too deep in {where}"
        ) from None


def _check_nesting(raw: bytes, where: Path) -> None:
    """Refuse flow collections nested deeper than MAX_NESTING (YAML parsers recurse on them)."""
    import numpy as np

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
    doc = _yaml_load(text, meta)
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
        if not p.is_file():
            raise LogError(
                f"Expected the bag file {p.name} listed in metadata.yaml, got no such "
                f"file in {folder}"
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
