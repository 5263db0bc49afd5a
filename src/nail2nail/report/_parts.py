"""Corrupt parts of an output directory: each section of the report stands on its own.

A file the report reads may be truncated, not JSON, or hold values of the wrong kind (a string
or NaN where a number belongs, a list where a table belongs). The section that reads it says so
in a note, naming the file and the problem; the other sections are drawn, and ``nail2nail
report`` prints one warning line per such file (exit 0). :func:`reading` turns what a corrupt
file raises as it is read, or as its values are used, into :class:`CorruptPart`, which names
the file; :func:`number` names the key of a value that is not a number.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from nail2nail._validation import describe_error
from nail2nail.report._html import note_html

__all__ = ["CORRUPT", "CorruptPart", "number", "numbers", "problem_notes", "quoted", "reading"]

#: What reading a corrupt file, or using its values, raises: the readers' ``ValueError`` /
#: ``OSError``, and ``TypeError``, ``KeyError``, ``IndexError``, ``AttributeError``,
#: ``ArithmeticError`` from values of the wrong kind (``"abc"`` as a size, a list as a table).
CORRUPT = (ValueError, TypeError, KeyError, IndexError, AttributeError, ArithmeticError,
           OSError)

#: Longest repr of a bad value quoted in a note or warning (the file may hold megabytes).
MAX_QUOTED = 60


class CorruptPart(ValueError):
    """A file of the output directory that the report cannot use.

    Attributes
    ----------
    path : str
        The file (or, when the problem cannot be pinned on one file, the section's inputs).
    reason : str
        What is wrong with it, on one line.
    """

    def __init__(self, path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


def _reason(path: str, exc: BaseException) -> str:
    text = describe_error(exc)
    if isinstance(exc, (TypeError, AttributeError, IndexError)):
        text = f"a value of the wrong kind ({type(exc).__name__}: {text})"
    for prefix in (f"{path}: ", f"{Path(path).name}: "):  # readers name the file: not twice
        if text.startswith(prefix):
            return text[len(prefix):]
    return text


@contextmanager
def reading(path) -> Iterator[None]:
    """Attribute what goes wrong inside the block to the file `path` (:class:`CorruptPart`)."""
    try:
        yield
    except CorruptPart:
        raise
    except CORRUPT as exc:
        raise CorruptPart(path, _reason(str(path), exc)) from exc


def quoted(value) -> str:
    """``repr(value)``, cut to :data:`MAX_QUOTED` characters."""
    text = repr(value)
    return text if len(text) <= MAX_QUOTED else text[:MAX_QUOTED - 1] + "…"


def number(value, key: str, *, integer: bool = False) -> float | None:
    """`value` of entry `key` as a float (NaN and infinities kept: shown as "—"), ``None`` for
    ``None``; else ``ValueError`` naming the key and the value. `integer`: whole numbers only
    (sizes, counts)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{key}: expected a number, got {quoted(value)}")
    if integer and not (math.isfinite(value) and float(value).is_integer()):
        raise ValueError(f"{key}: expected a whole number, got {quoted(value)}")
    return float(value)


def numbers(value, key: str, n: int, *, integer: bool = False) -> list[float]:
    """`value` of entry `key` as a list of `n` numbers (:func:`number`; no ``None``)."""
    out = []
    for v in value if isinstance(value, (list, tuple)) and len(value) == n else [None]:
        x = number(v, key, integer=integer)
        if x is None:
            raise ValueError(f"{key}: expected {n} numbers, got {quoted(value)}")
        out.append(x)
    return out


def problem_notes(problems, what: str = "what it holds is not shown") -> str:
    """Warning notes, one per ``(file, problem)`` of `problems` (repeats once), each ending
    with `what`."""
    return "".join(note_html(f"{path}: {reason}; {what}.", "warn")
                   for path, reason in dict.fromkeys(problems))
