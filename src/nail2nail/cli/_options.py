"""Helpers the subcommands share to speak of options as the command line names them."""

from __future__ import annotations

import argparse

from nail2nail.merge.correspondence import PAIR_BY

__all__ = ["add_pair_by_option", "as_option_error"]


def as_option_error(exc: ValueError, names: dict[str, str]) -> ValueError:
    """`exc` with the library's name of an argument replaced by the command line's.

    Library checks name their argument (``frame: expected …``, ``rows, cols: …``); a user gave
    an option (``--frame``, ``--rows/--cols``). When the message starts with one of `names`'
    keys followed by ``": "``, that key is replaced by its value; otherwise `exc` is returned.
    """
    text = str(exc)
    for name, flag in names.items():
        if text.startswith(f"{name}: "):
            return type(exc)(flag + text[len(name):])
    return exc


def add_pair_by_option(p: argparse.ArgumentParser) -> None:
    """``--pair-by``: what pairs two cameras' pixels in the merge (``correspond``'s `pair_by`)."""
    p.add_argument("--pair-by", choices=PAIR_BY, default="auto",
                   help="what pairs two cameras' pixels: both projector coordinates (xpyp, the "
                   "thesis), or one and the surface along it (xp, yp); auto (default): the "
                   "one the scans were triangulated from when it is one (a stabilised moving "
                   "capture), else both")
