"""Two independent passes of one run side by side: one on a thread of its own, the other on the
caller's (standard library only).

A replay's passes over a whole log are compiled kernels and numpy loops, which release the GIL,
so two that need nothing of each other (the sampling check and the score, say) take the time of
the longer on two cores instead of the sum of both: on a 1 h log at 1 kHz the sampling check,
the score with no bias and the outcome (0.45-0.57 s) run beside the score and its evaluation
(0.69-0.77 s) (docs/benchmarks.md, "Long logs").

Each pass must be pure: it reads the arrays it is given, writes only arrays of its own and says
nothing (its lines are returned and said by the caller, in order, so the run says the same
lines in the same order as one pass after the other). Its errors are those of running the two
in order: the first pass's error when it fails, else the second's; an interrupt (Ctrl-C,
SIGTERM) goes up at once. The thread is a daemon and
ends with its pass (:meth:`Beside.result` joins it), so the process is left with its own
threads only (a replay's batch forks its workers only from a process of one thread).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

__all__ = ["Beside"]


class Beside:
    """``fn(*args)`` started on a thread of its own; :meth:`result` waits for it.

    >>> first = Beside(sum, [1, 2, 3])
    >>> second = max(4, 5)  # on the caller's thread meanwhile
    >>> first.result(), second
    (6, 5)
    """

    def __init__(self, fn: Callable, *args: Any) -> None:
        self._value: Any = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(fn, args), daemon=True)
        self._thread.name = f"imu_dcm-beside-{getattr(fn, '__name__', 'pass')}"
        self._thread.start()

    def _run(self, fn: Callable, args: tuple) -> None:
        try:
            self._value = fn(*args)
        except BaseException as exc:  # handed to the caller, who raises it as its own
            self._error = exc

    def result(self) -> Any:
        """The pass's value, once it has finished; raises what it raised."""
        self._thread.join()
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        return self._value

    def then(self, fn: Callable, *args: Any) -> tuple[Any, Any]:
        """``(this pass's value, fn(*args))``, ``fn`` run on the caller's thread meanwhile;
        raises as the two run in order would: this pass's error first (an interrupt in ``fn``
        at once)."""
        try:
            mine = fn(*args)
        except Exception:
            self.result()  # raises this pass's error, when it failed too
            raise
        # an interrupt (Ctrl-C, SIGTERM) goes up at once: the daemon thread ends with the process
        return self.result(), mine
