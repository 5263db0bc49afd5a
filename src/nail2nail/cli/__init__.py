"""Command-line interface: a thin layer over the library (see ``nail2nail --help``).

:func:`main` is the console entry point (``pyproject.toml``, ``[project.scripts]``). It imports
the subcommands (:mod:`nail2nail.cli._main`, and through them NumPy, SciPy, Numba …: most of a
second) inside its own Ctrl-C handling, so that an interrupt while they load is one line
``nail2nail: interrupted`` and exit code 130, as an interrupt later is, not a traceback.
"""

import os
import sys

__all__ = ["main"]

#: Exit code of an interrupted command (``nail2nail.cli._main.EXIT_INTERRUPTED``, not imported
#: here: that import is what an early Ctrl-C interrupts).
EXIT_INTERRUPTED = 130


def main(argv: list[str] | None = None) -> int:
    """Run the command line `argv` (default ``sys.argv[1:]``) and return the exit code
    (:func:`nail2nail.cli._main.main`)."""
    try:
        from nail2nail.cli._main import main as run
    except KeyboardInterrupt:
        if os.environ.get("NAIL2NAIL_DEBUG", "") not in ("", "0"):
            import traceback

            traceback.print_exc()
        print("nail2nail: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return run(argv)
