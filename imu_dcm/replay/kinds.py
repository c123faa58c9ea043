"""The kinds of truth a score is against, as ``info``, the replay and the batch table say them.

An attitude truth is an *independent reference* (motion capture, a simulator's attitude) or *the
vehicle's own estimate* (PX4's or ArduPilot's EKF, odometry, the IMU's own orientation: the
reader marks these with ``TruthSeries.estimate_of``); a channel with *positions only* cannot
score an attitude; a replay without truth scores against *none*. Errors against different kinds
are never averaged together.
"""

from __future__ import annotations

INDEPENDENT = "independent reference"
ESTIMATE = "the vehicle's own estimate"
POSITIONS = "positions only"
NO_TRUTH = "none"
#: The order kinds are listed in.
KINDS = (INDEPENDENT, ESTIMATE, NO_TRUTH)


def truth_kind(estimate_of: str | None) -> str:
    """:data:`INDEPENDENT` for ``""``, :data:`ESTIMATE` for who estimated it, :data:`NO_TRUTH`
    for None (no truth)."""
    if estimate_of is None:
        return NO_TRUTH
    return ESTIMATE if estimate_of else INDEPENDENT
