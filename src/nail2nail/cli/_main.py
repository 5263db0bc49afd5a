"""Entry point: parses arguments and dispatches to one module per subcommand.

Each subcommand lives in ``cli/_<name>.py`` with ``add_parser(subparsers)`` registering it and
setting ``func``. Exit codes (``docs/conventions.md``, "Errors"): 0 success; 2 bad input
(``ValueError``, ``TypeError``, ``OSError``, ``KeyError`` from the library, and argparse's usage
errors), one line on stderr naming the file or argument; 130 interrupted (Ctrl-C); 1 any other
exception, an internal error, one line asking for a report. No traceback unless the environment
variable ``NAIL2NAIL_DEBUG`` is set to a non-empty value other than ``0``. ``-q``/``--quiet``
(before or after the subcommand) silences progress (``nail2nail._progress``) and informational
lines on stderr.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
import warnings

from nail2nail._progress import is_quiet, quiet
from nail2nail._validation import describe_error, one_line
from nail2nail.cli import (
    _batch,
    _calibrate,
    _calibrate_board,
    _crosscheck,
    _demo,
    _distortion,
    _export_mesh,
    _export_nist,
    _import_calibration,
    _merge,
    _patterns,
    _print_target,
    _process,
    _report,
    _scan,
    _simulate,
    _unroll,
)

__all__ = ["EXIT_BAD_INPUT", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "build_parser", "main"]

EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 1
EXIT_INTERRUPTED = 130
QUIET_HELP = ("no progress bars or stage lines on stderr (shown only when stderr is a terminal) "
              "and no informational lines; errors and warnings are still printed")

# Subcommand modules, in pipeline order.
COMMANDS = (
    _calibrate,
    _calibrate_board,
    _import_calibration,
    _crosscheck,
    _simulate,
    _print_target,
    _patterns,
    _scan,
    _distortion,
    _merge,
    _export_mesh,
    _unroll,
    _report,
    _process,
    _batch,
    _export_nist,
    _demo,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nail2nail",
        description="Touchless 3D fingerprint capture: calibrate, simulate, scan, merge, unroll.",
        epilog="Exit codes: 0 success, 2 bad input, 130 interrupted, 1 internal error. "
        "NAIL2NAIL_DEBUG=1 prints the traceback of an error.",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.add_parser(sub)
    for p in sub.choices.values():  # also after the subcommand; SUPPRESS keeps a leading -q
        p.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                       help=QUIET_HELP)
    return parser


def _check_option_values(argv: list[str]) -> None:
    """Refuse ``--option=--``: argparse (Python < 3.12) gives the option the empty list ``[]``
    for it, not converted by its type, which would reach the command as its value."""
    for arg in argv:
        if arg == "--":  # positionals from here on
            return
        if arg.startswith("--") and arg.endswith("=--"):
            raise ValueError(f"{arg[:-3]}: expected a value, got '--'")


def _debug() -> bool:
    return os.environ.get("NAIL2NAIL_DEBUG", "") not in ("", "0")


def _run_with_warnings(args: argparse.Namespace, command: str) -> int:
    """Run the command; the library's warnings (e.g. a camera that keeps few of its lit
    pixels, a camera pair that keeps few pairs) become one line each on stderr."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        try:
            return int(args.func(args) or 0)
        finally:
            for w in caught:
                kind = "" if issubclass(w.category, UserWarning) else f"{w.category.__name__}: "
                print(f"{command}: warning: {kind}{one_line(w.message)}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run the command line `argv` (default ``sys.argv[1:]``) and return the exit code."""
    command = "nail2nail"
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        command = f"nail2nail {args.command}"
        _check_option_values(sys.argv[1:] if argv is None else argv)
        with quiet(args.quiet or is_quiet()):  # a caller's quiet() holds too
            return _run_with_warnings(args, command)
    except KeyboardInterrupt:
        if _debug():
            traceback.print_exc()
        print(f"{command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, TypeError, OSError, KeyError) as exc:
        if _debug():
            traceback.print_exc()
        print(f"{command}: error: {describe_error(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:
        if _debug():
            traceback.print_exc()
        print(
            f"{command}: internal error: {type(exc).__name__}: {one_line(exc)} "
            "(a bug: please report it with the command line and the traceback; "
            "NAIL2NAIL_DEBUG=1 shows the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
