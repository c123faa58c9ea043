"""Clean recorded gyro samples before integration: what no gyro can produce is dropped, counted
and reported with its time, so one bad byte costs one sample, never the answer.

Rules, in order (all on the rates in rad/s, in file order until the sort):

1. **Non-finite** rates (NaN, Inf) are dropped.
2. **Implausible** rates are dropped: a component above :data:`MAX_RATE_RAD_S` (10⁴ rad/s,
   far above any MEMS full scale, ±4000 °/s = 70 rad/s, even read as deg/s), and isolated
   spikes: a sample whose ``|ω|`` exceeds :data:`SPIKE_RATIO` times both the log's 99.9th
   percentile of ``|ω|`` and every neighbour within :data:`SPIKE_NEIGHBOURS` samples (and
   1 rad/s). A flipped exponent bit gives such a sample; real motion never does (the six BROAD
   trials peak at 1.84, the tapping trial).
3. **Wild stamps** are dropped: a stamp further than :data:`WILD_STAMP_STEPS` median steps from
   the median of its :data:`WILD_STAMP_WINDOW` file-order neighbours (one stamp glitched a day
   ahead costs that sample, not every later one). A monotone sequence, gaps included, is never
   affected: the median of a sorted window is its centre. At either end of the file the window
   is the nearest full one, so fewer than 5 samples cut off by a gap of that size there count
   as wild too.
4. The rest is **sorted by stamp** (stable): messages slightly out of file order keep their
   place in time.
5. **Exact duplicates** (same stamp, same rate) are dropped; a repeated stamp with a different
   rate keeps the first sample (counted as a stamp conflict).
6. **Gaps** over :data:`imu_dcm.integrator.batch.GAP_FACTOR` median steps are listed (not dropped).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import median, percentile, row_finite, row_norm
from imu_dcm.errors import Diagnostics, GapWarning, ImuDcmWarning, say
from imu_dcm.gyro.rates import MAX_RATE_RAD_S, implausible_rates
from imu_dcm.gyro.rates import deg_evidence as _deg_evidence  # noqa: F401 - replay.core's
from imu_dcm.integrator.batch import find_gaps, gap_message

__all__ = [
    "MAX_RATE_RAD_S",
    "SPIKE_RATIO",
    "CleanedImu",
    "clean_imu",
]

#: An isolated sample this many times above the log's 99.9th percentile and its neighbours is
#: a spike.
SPIKE_RATIO = 8.0
#: Neighbours on each side compared with a candidate spike.
SPIKE_NEIGHBOURS = 2
#: Spikes below this rate (rad/s) are left alone: they cannot spoil the attitude.
SPIKE_FLOOR_RAD_S = 1.0
#: File-order window (samples) whose median stamp a wild stamp is compared with.
WILD_STAMP_WINDOW = 9
#: A stamp this many median steps from its window's median is wild.
WILD_STAMP_STEPS = 1000


@dataclass(slots=True, frozen=True)
class CleanedImu:
    """Gyro samples after cleaning, sorted by stamp, with the counts of what was dropped.

    ``t_ns`` int64 (N,) strictly increasing; ``omega_b`` float64 (N, 3) finite, rad/s;
    ``index`` int64 (N,) position of each kept sample in the input, or ``slice(0, N)`` when
    every sample was kept in its place (indexing with it then gives a view); gaps as (time s
    since the first kept sample, length s); ``implausible_t_s`` the times of the implausible
    samples (s since the first kept sample); ``messages`` its warnings, one line each (said as
    they were found, or added to the caller's diagnostics).
    """

    t_ns: NDArray[np.int64]
    omega_b: NDArray[np.float64]
    index: NDArray[np.int64] | slice
    dropped_nonfinite: int
    dropped_implausible: int
    dropped_wild_stamp: int
    dropped_duplicate: int
    dropped_stamp_conflict: int
    sorted_out_of_order: int
    gaps: tuple[tuple[float, float], ...]
    implausible_t_s: tuple[float, ...]
    messages: tuple[str, ...] = ()

    @property
    def dropped_nonincreasing(self) -> int:
        """Samples dropped for their stamp: wild, duplicate or conflicting."""
        return self.dropped_wild_stamp + self.dropped_duplicate + self.dropped_stamp_conflict


def _wild_stamps(t: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Stamps far from the median of their file-order window (see the module rules).

    Only samples whose window holds a suspicious step (not positive, or longer than the limit)
    and the first and last windows can deviate: elsewhere the window is sorted and its median
    is the sample itself. So only those are computed (a good log costs two windows).
    """
    n, w = len(t), WILD_STAMP_WINDOW
    if n < w:
        return np.zeros(n, dtype=bool)
    step = np.diff(t)
    up = step > 0
    positive = step if up.all() else step[up]  # the usual log: no copy
    if len(positive) == 0:
        return np.zeros(n, dtype=bool)
    limit = WILD_STAMP_STEPS * median(positive)
    half = w // 2
    odd = np.flatnonzero((step <= 0) | (step > limit))
    near = (odd[:, None] + np.arange(-half + 1, half + 1)).ravel()  # windows holding a step
    hit = np.zeros(n, dtype=bool)  # the candidates, each once, in order (np.unique without
    hit[:w] = hit[n - w :] = True  # the masked-array import it costs)
    hit[near[(near >= 0) & (near < n)]] = True
    cand = np.flatnonzero(hit)
    start = np.clip(cand - half, 0, n - w)  # at the ends: the nearest full window
    wild = np.zeros(n, dtype=bool)
    for s in range(0, len(cand), 1 << 16):  # bounded memory: a block of windows at a time
        c, st = cand[s : s + (1 << 16)], start[s : s + (1 << 16)]
        med = np.median(t[st[:, None] + np.arange(w)], axis=1)
        wild[c] = np.abs(t[c] - med) > limit
    return wild


def _spikes(w: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Isolated samples far above both the log's 99.9th percentile and their neighbours."""
    n, k = len(w), SPIKE_NEIGHBOURS
    spike = np.zeros(n, dtype=bool)
    if n < 2 * k + 1:
        return spike
    norm = row_norm(w)
    level = max(SPIKE_RATIO * percentile(norm, 99.9), SPIKE_FLOOR_RAD_S)
    cand = np.flatnonzero(norm > level)  # rare: a good log has none
    if len(cand):
        around = np.concatenate([np.arange(-k, 0), np.arange(1, k + 1)])
        j = cand[:, None] + around
        near = np.where((j >= 0) & (j < n), norm[np.clip(j, 0, n - 1)], 0.0).max(axis=1)
        spike[cand] = norm[cand] > SPIKE_RATIO * near
    return spike


def _times(t: NDArray[np.int64], t0: int, limit: int = 5) -> str:
    shown = ", ".join(f"{(x - t0) * 1e-9:.3f} s" for x in t[:limit])
    return shown + (f" and {len(t) - limit} more" if len(t) > limit else "")


def clean_imu(
    t_ns: ArrayLike,
    omega_b: ArrayLike,
    topic: str = "IMU",
    *,
    diagnostics: Diagnostics | None = None,
) -> CleanedImu:
    """Apply the cleaning rules of this module to gyro samples in file order.

    Parameters
    ----------
    t_ns : array_like, int64 (N,)
        Stamps, ns, in file order.
    omega_b : array_like, (N, 3)
        Body rates, rad/s, body axes.
    topic : str
        Named in the warnings.
    diagnostics : Diagnostics, optional
        Where the warnings go instead of being warned.

    Returns
    -------
    CleanedImu

    Warns
    -----
    ImuDcmWarning
        One line per rule that dropped or sorted samples, with counts and first times (s since
        the first kept sample).
    GapWarning
        The gaps, with their times.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    w = w_in = np.asarray(omega_b, dtype=float)
    index = None  # each kept row's place in the input; None while every row is kept, in order

    def drop(mask: NDArray[np.bool_]) -> None:  # copies only when something goes
        nonlocal t, w, index
        if mask.any():
            keep = ~mask
            t, w, index = t[keep], w[keep], np.flatnonzero(keep) if index is None else index[keep]

    nonfinite = ~row_finite(w)
    n_bad = int(nonfinite.sum())
    drop(nonfinite)

    huge = implausible_rates(w)  # the rule live applies too
    bad_t = [t[huge]]
    drop(huge)

    wild = _wild_stamps(t)
    n_wild = int(wild.sum())
    wild_t = t[wild]
    drop(wild)

    t, w, index, n_sorted, n_dup, n_conf = _sort_and_dedupe(t, w, index)
    spike = _spikes(w)
    bad_t.append(t[spike])
    drop(spike)
    bad = np.sort(np.concatenate(bad_t))
    t0 = int(t[0]) if len(t) else (int(bad[0]) if len(bad) else 0)

    counts = (n_bad, bad, n_dup, n_conf, n_wild, wild_t, n_sorted)
    messages, gaps = _report(topic, t, t0, counts, diagnostics)
    if index is None:  # every sample kept, in place
        index = slice(0, len(w_in))
    return CleanedImu(
        t,
        w,
        index,
        n_bad,
        len(bad),
        n_wild,
        n_dup,
        n_conf,
        n_sorted,
        gaps,
        tuple(float((x - t0) * 1e-9) for x in bad),
        tuple(messages),
    )


def _sort_and_dedupe(t, w, index):
    """Sort by stamp (stable) and drop repeated stamps (rules 4 and 5).

    Returns (t, w, index, samples sorted out of file order, exact duplicates, conflicts).
    """
    step = np.diff(t)
    n_sorted = 0
    if np.any(step < 0):
        before = np.maximum.accumulate(np.concatenate([t[:1], t[:-1]]))
        n_sorted = int(np.count_nonzero(t < before))  # stamps earlier than one already seen
        order = np.argsort(t, kind="stable")
        t, w = t[order], w[order]
        index = order if index is None else index[order]
        step = np.diff(t)
    same = np.concatenate([[False], step == 0])
    if not same.any():
        return t, w, index, n_sorted, 0, 0
    # a repeat of the previous stamp: an exact duplicate of the first sample at that stamp?
    first = np.maximum.accumulate(np.where(~same, np.arange(len(t)), 0))
    dup = same & np.all(w == w[first], axis=1)
    n_dup = int(dup.sum())
    keep = ~same
    index = np.flatnonzero(keep) if index is None else index[keep]
    return t[keep], w[keep], index, n_sorted, n_dup, int(same.sum()) - n_dup


def _report(topic, t, t0, counts, diagnostics: Diagnostics | None):
    """The cleaning's warnings, one line per rule that acted (said and returned), and gaps."""
    n_bad, bad, n_dup, n_conf, n_wild, wild_t, n_sorted = counts
    messages: list[str] = []

    def warn(msg: str, cat: type[Warning] = ImuDcmWarning) -> None:
        messages.append(f"{topic}: {msg}")
        say(diagnostics, messages[-1], cat, stacklevel=4)

    if n_bad:
        warn(f"dropped {n_bad} samples with NaN/Inf rates")
    if len(bad):
        warn(
            f"dropped {len(bad)} implausible samples (a rate over {MAX_RATE_RAD_S:.0e} rad/s or "
            f"an isolated spike over {SPIKE_RATIO:.0f}x the log's 99.9th percentile) at "
            f"{_times(bad, t0)}"
        )
    if n_wild or n_dup or n_conf:
        parts = []
        if n_dup:
            parts.append(f"{n_dup} exact duplicates")
        if n_conf:
            parts.append(f"{n_conf} repeated stamps with another rate")
        if n_wild:
            parts.append(f"{n_wild} wild stamps far from their neighbours at {_times(wild_t, t0)}")
        warn(
            f"dropped {n_wild + n_dup + n_conf} samples with duplicate or backward stamps "
            f"({'; '.join(parts)})"
        )
    if n_sorted:
        warn(f"sorted {n_sorted} samples that were out of file order by their stamps")
    gaps = find_gaps((t - t[0]) * 1e-9) if len(t) else ()
    if gaps:
        warn(gap_message(gaps), GapWarning)
    return tuple(messages), gaps
