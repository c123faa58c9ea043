"""The integrator kernel's state: one float64 array of named fields, and the codes of a push.

What carries across samples (the attitude, the last four rates and their stamps, the sample
count, the method) lives in one small array that the compiled kernel updates in place
(:mod:`imu_dcm._kernels.calls`). Its fields are defined once, by the ``_STATE.field`` calls
below; each offset is a plain int, which the compiler folds in as a constant, so named fields
cost nothing per sample. No numba here: the checked calls, the streaming integrator and the
compiled code all read the same layout.
"""

from __future__ import annotations

import numpy as np

from imu_dcm.integrator.methods import Method


class _Layout:
    """Named fields of the flat float64 state array, laid out in the order they are defined:
    each :meth:`field` call returns its offset."""

    def __init__(self) -> None:
        self.size = 0
        self.fields: dict[str, tuple[int, int, str]] = {}

    def field(self, name: str, width: int, meaning: str) -> int:
        offset = self.size
        self.fields[name] = (offset, width, meaning)
        self.size += width
        return offset


_STATE = _Layout()
Q = _STATE.field("q", 4, "attitude at the last committed sample, [x, y, z, w]")
Q0 = _STATE.field("q0", 4, "attitude at the first sample (rotvec_sum adds to it)")
PHI_SUM = _STATE.field("phi_sum", 3, "rotvec_sum: sum of dt_j omega_j so far, rad")
W = _STATE.field("omega", 12, "the last four rates, oldest first (rate r at W + 3 r), rad/s")
T = _STATE.field("t", 4, "their stamps, s")
N = _STATE.field("n", 1, "samples received")
METHOD = _STATE.field("method", 1, "the Method code")
ROWS = _STATE.field("rows", 8, "two rows of four: the attitudes push() or close() commit")
CLOSED = _STATE.field("closed", 1, "1 once close() has run: push() refuses samples")
STATE_SIZE = _STATE.size
#: ``name -> (offset, width, meaning)`` of every state field, in layout order.
STATE_FIELDS = _STATE.fields

#: ``Method.MAGNUS4`` as a plain int (the compiled loops pass it to the increment as a constant).
MAGNUS4 = int(Method.MAGNUS4)

# -- codes returned by push --------------------------------------------------------------------
OK, NOT_FINITE, NOT_INCREASING, MAYBE_GAP, IS_CLOSED = 0, 1, 2, 3, 4


def feed_entry(method: int, emit_phi: bool) -> str:
    """Name of the compiled loop over samples for ``method`` (rows: attitudes, or ``φ`` when
    ``emit_phi``)."""
    return f"feed_{method}_{int(emit_phi)}"


def push_entry(method: int) -> str:
    """Name of the compiled per-sample push for ``method``."""
    return f"push_{method}"


def new_state(q0: np.ndarray, method: int) -> np.ndarray:
    """A fresh state: attitude ``q0`` (unit ``[x, y, z, w]``), no sample yet."""
    state = np.zeros(STATE_SIZE)
    state[Q : Q + 4] = q0
    state[Q0 : Q0 + 4] = q0
    state[METHOD] = method
    return state


def state_fields(state: np.ndarray) -> dict[str, np.ndarray]:
    """Every named field of ``state`` as a view (writing to one writes the state)."""
    return {name: state[o : o + w] for name, (o, w, _) in STATE_FIELDS.items()}
