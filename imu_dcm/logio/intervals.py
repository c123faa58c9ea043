"""Intervals a log declares in its metadata (BROAD's movement phases), as stamp spans.

A rosbag2 ``metadata.yaml`` may carry, in ``custom_data``, a key ending in
``intervals_stamp_ns`` whose value is a JSON list of ``[t_start_ns, t_end_ns]`` pairs of header
stamps (inclusive), e.g. BROAD's ``broad.movement_intervals_stamp_ns``. The name before the suffix
(``broad.movement``) names the intervals. Nothing here is tuned to one dataset: any key of that
form is read, and a value that is not such a list is refused in one line.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from imu_dcm.errors import LogError

__all__ = ["SUFFIX", "Declared", "declared_intervals"]


SUFFIX = "intervals_stamp_ns"


@dataclass(frozen=True, slots=True)
class Declared:
    """Intervals declared under one metadata key.

    Attributes
    ----------
    key : str — the ``custom_data`` key (``broad.movement_intervals_stamp_ns``).
    name : str — what they are, from the key (``broad.movement``).
    spans_ns : tuple of (t_start_ns, t_end_ns) — header stamps, ns, inclusive, in order.
    """

    key: str
    name: str
    spans_ns: tuple[tuple[int, int], ...]


def _spans(key: str, text: str) -> tuple[tuple[int, int], ...]:
    try:
        raw = json.loads(text)
        spans = tuple((int(a), int(b)) for a, b in raw)
    except (ValueError, TypeError) as exc:
        raise LogError(
            f"Expected a JSON list of [t_start_ns, t_end_ns] pairs in metadata {key}, got "
            f"{text[:60]!r} ({type(exc).__name__})"
        ) from None
    bad = next(((a, b) for a, b in spans if b < a), None)
    if bad is not None:
        raise LogError(f"Expected t_start_ns <= t_end_ns in metadata {key}, got {list(bad)}")
    return spans


def declared_intervals(custom_data: dict[str, str]) -> tuple[Declared, ...]:
    """Every interval list ``custom_data`` declares (keys ending in :data:`SUFFIX`), by key.

    Raises
    ------
    LogError
        A value that is not a JSON list of ``[start, end]`` stamp pairs with start <= end.
    """
    out = []
    for key in sorted(custom_data):
        if key.endswith(SUFFIX):
            name = key[: -len(SUFFIX)].rstrip("._") or key
            out.append(Declared(key, name, _spans(key, custom_data[key])))
    return tuple(out)
