"""Progress on stderr: one helper for every long step of the library and the command line.

Progress bars (:func:`progress_bar`, tqdm) and stage lines (:class:`Stages`) go to
``sys.stderr`` only, so that they never mix with the ``--json`` output on stdout. They are shown
only when stderr is a terminal and the caller asked for them, and never inside :func:`quiet`
(the command line's ``--quiet``), which also silences the informational lines of :func:`info`.
Errors and warnings are not affected.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import time
from collections.abc import Iterable, Iterator

__all__ = ["Stages", "info", "is_quiet", "progress_bar", "progress_enabled", "quiet",
           "stderr_is_terminal"]

_QUIET: contextvars.ContextVar[bool] = contextvars.ContextVar("nail2nail_quiet", default=False)


def stderr_is_terminal() -> bool:
    """Whether ``sys.stderr`` (as it is now) is an interactive terminal."""
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # None, a closed stream, an object without isatty
        return False


def is_quiet() -> bool:
    """Whether progress and informational lines are silenced (:func:`quiet`)."""
    return _QUIET.get()


@contextlib.contextmanager
def quiet(enabled: bool = True) -> Iterator[None]:
    """Silence progress bars, stage lines and :func:`info` lines inside the block."""
    token = _QUIET.set(bool(enabled))
    try:
        yield
    finally:
        _QUIET.reset(token)


def progress_enabled(requested: bool = True) -> bool:
    """Whether progress is shown: `requested`, not :func:`quiet`, and stderr a terminal."""
    return bool(requested) and not is_quiet() and stderr_is_terminal()


def progress_bar(iterable: Iterable | None = None, *, desc: str, unit: str = "it",
                 total: int | None = None, enabled: bool = True, leave: bool = True):
    """A tqdm progress bar on stderr, disabled unless :func:`progress_enabled` (`enabled`).

    Parameters
    ----------
    iterable : iterable, optional
        What to iterate over; without it, advance the bar with ``bar.update()`` (`total`
        steps) and close it (or use it as a context manager).
    desc : str
        Label, e.g. ``"scan"``.
    unit : str
        What one step is, e.g. ``"camera"``.
    total : int, optional
        Number of steps (default ``len(iterable)`` when it has one).
    enabled : bool
        The caller's wish (a library function's ``progress`` argument).
    leave : bool
        Keep the finished bar on the terminal.

    Returns
    -------
    tqdm.tqdm
        Iterable like `iterable`; a disabled bar writes nothing.
    """
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, unit=unit, total=total, file=sys.stderr, leave=leave,
                disable=not progress_enabled(enabled), dynamic_ncols=True)


def info(text: str) -> None:
    """One informational line on stderr, unless :func:`quiet` (errors and warnings are not
    informational: print them directly)."""
    if not is_quiet():
        print(text, file=sys.stderr, flush=True)


class Stages:
    """Numbered stage lines on stderr with the elapsed time: ``[ 3/16]   12.4s  message``.

    Shown when `enabled` and not :func:`quiet`; with ``terminal_only`` (the default) only when
    stderr is a terminal, like a progress bar, so that an error read from a file or pipe is
    its one line.

    Parameters
    ----------
    n_stages : int
        Number of stages announced (0: no count).
    enabled : bool
        The caller's wish.
    prefix : str
        Put before each line, e.g. ``"process: "``.
    terminal_only : bool
        Print only when stderr is a terminal.
    """

    def __init__(self, n_stages: int = 0, *, enabled: bool = True, prefix: str = "",
                 terminal_only: bool = True):
        self.n_stages, self.enabled, self.prefix = n_stages, enabled, prefix
        self.terminal_only = terminal_only
        self.stage = 0
        self.start = time.perf_counter()

    def __call__(self, message: str) -> None:
        """Announce the next stage."""
        self.stage += 1
        if not self.enabled or is_quiet() or (self.terminal_only and not stderr_is_terminal()):
            return
        elapsed = time.perf_counter() - self.start
        count = f"[{self.stage:2d}/{self.n_stages}] " if self.n_stages else ""
        print(f"{self.prefix}{count}{elapsed:6.1f}s  {message}", file=sys.stderr, flush=True)
