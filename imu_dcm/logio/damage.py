"""The damaged parts a reader skipped, said in one line and warned once (every container)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from imu_dcm.errors import Diagnostics, ImuDcmWarning, say
from imu_dcm.logio.types import Damage

__all__ = ["damage_summary", "warn_damage"]


def damage_summary(damage: Sequence[Damage]) -> str:
    """One line for the damaged parts skipped: the first one, and the messages lost in all."""
    lost = [d.messages_lost for d in damage]
    n_lost = "an unknown number of" if None in lost else str(sum(lost))
    first = damage[0]
    more = f" (and {len(damage) - 1} more)" if len(damage) > 1 else ""
    where = [f"file offset {first.offset}"] if first.offset >= 0 else []
    if first.t_start_ns is not None and first.t_end_ns is not None:
        where.append(f"log time {first.t_start_ns}..{first.t_end_ns} ns")
    at = f" ({', '.join(where)})" if where else ""
    return (
        f"{first.what}{at}{more}; {n_lost} messages of the read channels lost in "
        f"{len(damage)} damaged part{'s' if len(damage) > 1 else ''}"
    )


def warn_damage(
    path: Path,
    damage: Sequence[Damage],
    stacklevel: int = 3,
    diagnostics: Diagnostics | None = None,
) -> str | None:
    """Warn once that ``path`` is truncated or corrupt (once the log is known to be usable, so
    that an error is the only line otherwise), or add it to ``diagnostics``; returns the
    summary, or None without damage."""
    if not damage:
        return None
    summary = damage_summary(damage)
    said = f"{path.name} is truncated or corrupt: {summary}"
    say(diagnostics, said, ImuDcmWarning, stacklevel=stacklevel + 1)
    return summary
