"""Helpers the subcommands share to speak of options as the command line names them."""

from __future__ import annotations

__all__ = ["as_option_error"]


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
