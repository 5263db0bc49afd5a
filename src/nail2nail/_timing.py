"""Wall time of the steps of a computation: the one clock behind every ``timings`` and
``seconds`` the library reports (``SuperScan.timings``, ``RolledPrint.timings``,
``merge.json`` and ``process.json`` seconds, ``scan_capture(timings=)``)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["StepClock"]


class StepClock:
    """Adds the wall time since the last lap to a named step (seconds, ``time.perf_counter``).

    ``clock("step")`` ends a lap and charges it to ``step``; ``clock.restart()`` drops the time
    since the last lap (work that belongs to no step); ``with clock.stage("step"):`` charges
    the block alone. Steps keep the order they were first charged in; a step charged again
    accumulates.

    Examples
    --------
    >>> clock = StepClock()
    >>> clock("read"); clock("decode"); clock("read")
    >>> list(clock.seconds)
    ['read', 'decode']
    >>> with clock.stage("write"):
    ...     pass
    >>> sorted(clock.rounded())
    ['decode', 'read', 'total', 'write']
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.last = time.perf_counter()

    def __call__(self, step: str) -> None:
        now = time.perf_counter()
        self.seconds[step] = self.seconds.get(step, 0.0) + now - self.last
        self.last = now

    def restart(self) -> None:
        """Start the next lap now."""
        self.last = time.perf_counter()

    @contextmanager
    def stage(self, step: str) -> Iterator[None]:
        """Charge the block's wall time (and only it) to `step`, also when it raises."""
        self.restart()
        try:
            yield
        finally:
            self(step)

    def rounded(self, digits: int = 3) -> dict[str, float]:
        """The seconds per step and their ``total``, rounded."""
        out = {k: round(v, digits) for k, v in self.seconds.items()}
        out["total"] = round(sum(self.seconds.values()), digits)
        return out
