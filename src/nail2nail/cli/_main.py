"""Entry point: parses arguments and dispatches to one module per subcommand.

Each subcommand lives in ``cli/_<name>.py`` with ``add_parser(subparsers)`` registering it and
setting ``func``; errors from the library (``ValueError``, ``TypeError``, ``OSError``) become one
line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# Subcommand modules, in pipeline order.
COMMANDS = [
    "calibrate",
    "crosscheck",
    "simulate",
    "patterns",
    "scan",
    "distortion",
    "merge",
    "unroll",
    "demo",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nail2nail",
        description="Touchless 3D fingerprint capture: calibrate, simulate, scan, merge, unroll.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"nail2nail.cli._{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"nail2nail.cli._{name}":
                raise
            continue  # subcommand not built yet
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, TypeError, OSError, KeyError) as exc:
        print(f"nail2nail {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
