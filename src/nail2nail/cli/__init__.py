"""Command-line interface: a thin layer over the library (see ``nail2nail --help``)."""

from nail2nail.cli._main import main

__all__ = ["main"]
