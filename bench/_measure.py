"""Shared by the benches: median wall times and peak memory (RSS) of a stage, a progress line."""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path


def log(message: str) -> None:
    """A progress line on stderr (the figures go to stdout)."""
    print(message, file=sys.stderr, flush=True)


def median_time(fn, repeats: int) -> tuple[float, object]:
    """Median wall time (s) of `repeats` calls of `fn`, and the last call's result."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def reset_peak() -> bool:
    """Reset this process's peak RSS (Linux ``clear_refs``); ``False`` where not possible."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def status_mb(key: str = "VmHWM") -> float | None:
    """A memory figure of this process from ``/proc/self/status``, MB (``VmHWM``: the peak RSS
    since the last :func:`reset_peak`; ``VmRSS``: now); ``None`` where not available."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(f"{key}:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None
