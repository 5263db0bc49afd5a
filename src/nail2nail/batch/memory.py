"""How many captures fit in memory at once: a per-capture estimate and the default worker count.

The rule (README, "Batch processing on Dask"): one capture's job peaks at about
:data:`BASE_MB` (the interpreter, NumPy, SciPy, numba and their kernels) plus three float32
copies of all its frames (the frames read, the decoded phase planes and their working copies).
Measured with ``process.json``'s ``peak_rss_mb``: 556 MB for the simulated finger at scale 0.25
and at 0.5 (3 cameras, 24 frames of 256 × 320 and 512 × 640 px) in a fresh ``nail2nail
process``, 307 MB at scale 0.25 on a Dask worker, which the rule bounds at 668 and 870 MB; at
full scale (1280 × 1024) the rule gives 1.7 GB, against 868 MB measured for ``process`` in a
fresh process (README, "Speed"): the rule errs on the safe side. A local cluster of N workers
gives each ``total memory / N`` as its Dask memory limit, and the default N is the CPU count
capped so that N estimated captures fit in 80 % of the memory available now.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

from nail2nail.io.capture import projector_captures, read_capture

__all__ = ["BASE_MB", "capture_memory_mb", "check_memory_mb", "check_workers", "default_workers",
           "max_workers"]

BASE_MB = 600.0
COPIES = 3  # float32 copies of every frame held at the peak


def capture_memory_mb(capture: str | os.PathLike) -> float:
    """Estimated peak memory (MB) of processing the capture directory `capture`.

    Parameters
    ----------
    capture : path-like
        Capture directory (its ``capture.json`` is read, not the frames), or a capture of
        several projectors (``projectors.json``: the sum over its captures, as if their frames
        were held at once; they are scanned in turn, so this is an upper bound).

    Returns
    -------
    float
        ``BASE_MB + COPIES * 4 bytes * frames * height * width`` summed over the cameras of
        its ``capture.json``, MB.

    Raises
    ------
    ValueError
        The manifest is missing or inconsistent (naming the file).
    """

    layout = projector_captures(capture)
    pixels = 0
    for path in [capture] if layout is None else [p for _, p in layout]:
        manifest = read_capture(path, load=False).manifest
        n_frames = int(manifest.get("n_frames", 0))
        pixels += sum(int(c["size"][0]) * int(c["size"][1])
                      * (len(c.get("frames", [])) or n_frames) for c in manifest["cameras"])
    return BASE_MB + COPIES * 4 * pixels / 2**20


def max_workers() -> int:
    """The most local workers: the CPU count (each worker is a process running one capture,
    single-threaded, at a time: more workers than CPUs only share them, and each holds its
    interpreter and a capture's memory)."""
    return os.cpu_count() or 1


def check_workers(n_workers, n_captures: int, *, name: str = "n_workers") -> int:
    """`n_workers` checked against :func:`max_workers`, capped at `n_captures` (a worker
    beyond one per capture would stay idle).

    Raises
    ------
    TypeError
        `n_workers` is not an integer.
    ValueError
        `n_workers` is below 1 or above :func:`max_workers` (naming `name`).
    """
    if isinstance(n_workers, bool) or not isinstance(n_workers, int):
        raise TypeError(f"{name}: expected an integer, got {n_workers!r}")
    most = max_workers()
    if not 1 <= n_workers <= most:
        raise ValueError(f"{name}: expected at least 1 and at most {most} (the CPU count: each "
                         f"worker is a process running one capture at a time), got {n_workers}")
    return max(1, min(n_workers, n_captures))


def check_memory_mb(memory_mb, *, name: str = "memory_mb") -> float:
    """`memory_mb` as a finite float > 0 (MB of one capture's peak), else a ``ValueError``
    naming `name` and the value."""
    if isinstance(memory_mb, bool) or not isinstance(memory_mb, int | float):
        raise TypeError(f"{name}: expected a number of MB, got {memory_mb!r}")
    if not (math.isfinite(memory_mb) and memory_mb > 0):
        raise ValueError(f"{name}: expected a positive, finite number of MB, got {memory_mb:g}")
    return float(memory_mb)


def default_workers(captures: Sequence[str | os.PathLike], *,
                    memory_mb: float | None = None) -> int:
    """The default number of local workers for `captures`.

    Parameters
    ----------
    captures : sequence of path-like
        The capture directories (the largest estimate counts).
    memory_mb : float, optional
        Peak memory of one capture, MB (default :func:`capture_memory_mb` of the largest;
        a capture whose manifest cannot be read is left out here: its task reports it).

    Returns
    -------
    int
        ``min(CPU count, captures, 80 % of available memory // memory_mb)``, at least 1.

    Raises
    ------
    ValueError
        `memory_mb` is not a positive, finite number.
    """
    import psutil

    if memory_mb is not None:
        memory_mb = check_memory_mb(memory_mb)
    if memory_mb is None:
        estimates = []
        for c in captures:
            try:
                estimates.append(capture_memory_mb(c))
            except (OSError, ValueError, KeyError, TypeError):  # the task fails it, alone
                continue
        memory_mb = max(estimates, default=BASE_MB)
    available = psutil.virtual_memory().available / 2**20
    cpus = max_workers()
    fit = int(min(0.8 * available // memory_mb, cpus))  # a tiny memory_mb: no int(inf)
    return max(1, min(cpus, len(captures), fit))
