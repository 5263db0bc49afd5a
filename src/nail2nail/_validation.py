"""Shared input checks: one place that turns bad input into a clear error."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

__all__ = [
    "as_float_array",
    "as_int",
    "as_matrix",
    "as_name",
    "as_points",
    "check_format",
    "check_unique",
    "confined_path",
    "describe_error",
    "file_kind",
    "one_line",
]


def as_float_array(value, name: str, *, dtype=np.float64) -> np.ndarray:
    """Return `value` as a floating-point array, or raise a `TypeError` naming `name`."""
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged input
        raise TypeError(f"{name}: expected a numeric array, got {type(value).__name__}") from exc
    if not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise TypeError(f"{name}: expected a numeric array, got dtype {array.dtype}")
    if np.issubdtype(array.dtype, np.floating) and dtype is None:
        return array
    return array.astype(dtype if dtype is not None else np.float64, copy=False)


def as_points(
    value, name: str, dim: int, *, min_points: int = 0, finite: bool = True
) -> np.ndarray:
    """Return `value` as an ``(N, dim)`` float64 array.

    Raises
    ------
    ValueError
        If the shape is not ``(N, dim)``, there are fewer than `min_points` rows, or
        (with `finite`) any value is NaN or infinite.
    """
    array = as_float_array(value, name)
    if array.ndim != 2 or array.shape[1] != dim:
        raise ValueError(f"{name}: expected shape (N, {dim}), got {array.shape}")
    if array.shape[0] < min_points:
        raise ValueError(f"{name}: need at least {min_points} points, got {array.shape[0]}")
    if finite and not np.all(np.isfinite(array)):
        bad = np.flatnonzero(~np.all(np.isfinite(array), axis=1))
        raise ValueError(
            f"{name}: {bad.size} point(s) contain NaN or infinity (first at index {bad[0]})"
        )
    return array


def as_matrix(value, name: str, shape: tuple[int, int]) -> np.ndarray:
    """Return `value` as a finite float64 array of exactly `shape`."""
    array = as_float_array(value, name)
    if array.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: contains NaN or infinity")
    return array


def as_int(value, name: str, *, minimum: int) -> int:
    """Return `value` as a Python ``int`` ≥ `minimum` (``bool`` is refused).

    Raises
    ------
    TypeError
        If `value` is not an integer.
    ValueError
        If it is below `minimum`.
    """
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise TypeError(f"{name}: expected an integer, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name}: expected an integer ≥ {minimum}, got {value}")
    return int(value)


def as_int_pair(value, name: str, what: str, *, minimum: int | None = None,
                error: type[Exception] = ValueError) -> tuple[int, int]:
    """Two integers (integral floats such as ``1280.0`` accepted), each ≥ `minimum` if given.

    Refused with `error` naming `name` and `what` (e.g. ``"(width, height)"``): strings,
    booleans, fractions, NaN and infinities (``int(inf)`` would raise an ``OverflowError``,
    ``int(1.5)`` would truncate silently).

    Examples
    --------
    >>> as_int_pair([1280.0, 1024], "size", "(width, height)")
    (1280, 1024)
    """
    try:
        a, b = value
    except (TypeError, ValueError) as exc:
        raise error(f"{name}: expected {what}, got {value!r}") from exc
    out = []
    for v in (a, b):
        if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating) or (
                not isinstance(v, int | np.integer) and not (np.isfinite(v) and v == int(v))
        ) or (minimum is not None and v < minimum):
            kind = "integers" if minimum is None else f"integers >= {minimum}"
            raise error(f"{name}: expected {what} as {kind}, got {value!r}")
        out.append(int(v))
    return out[0], out[1]


def check_format(data, *, fmt: str, where: str, versions: tuple[int, ...] = (1,)) -> dict:
    """Check that the parsed file `data` is an object of format `fmt` and a known version.

    Raises
    ------
    ValueError
        Naming `where` (the file): not an object, another ``format``, or a ``version`` missing
        or not one of `versions` (``bool`` and strings are refused, ``"1"`` included).
    """
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a JSON object, got {type(data).__name__}")
    if data.get("format") != fmt:
        raise ValueError(f"{where}: not a {fmt.replace('-', ' ', 1)} file (format is "
                         f"{data.get('format')!r})")
    if "version" not in data:
        raise ValueError(f"{where}: no 'version' (this nail2nail reads version(s) "
                         f"{', '.join(map(str, versions))})")
    version = data["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version not in versions:
        raise ValueError(f"{where}: unknown version {version!r} (this nail2nail reads "
                         f"version(s) {', '.join(map(str, versions))})")
    return data


_FORBIDDEN_IN_NAMES = ("/", "\\", ":", "\0")


def as_name(value, where: str) -> str:
    """Return `value` if it is a plain name: usable as a file name, never as a path.

    A name is a non-empty string of at most 100 characters with no ``/``, ``\\``, ``:``,
    control characters or surrounding spaces, and is not ``.`` or ``..``; names come from files
    and become file names in output directories, so they must not climb out of them.

    Raises
    ------
    ValueError
        Naming `where`, if it is not.
    """
    if not isinstance(value, str):
        raise ValueError(f"{where}: expected a name (a string), got {type(value).__name__}")
    bad = (
        not value
        or value in (".", "..")
        or len(value) > 100
        or value != value.strip()
        or any(c in value for c in _FORBIDDEN_IN_NAMES)
        or any(ord(c) < 32 or ord(c) == 127 for c in value)
    )
    if bad:
        raise ValueError(f"{where}: {value!r} is not a plain name (non-empty, no '/', '\\', "
                         "':', '..' or control characters)")
    return value


def check_unique(names, where: str) -> None:
    """Raise a ``ValueError`` naming `where` and the first repeated name, if any."""
    seen: set = set()
    for name in names:
        if name in seen:
            raise ValueError(f"{where}: two cameras are named {name!r}; names must be unique")
        seen.add(name)


def confined_path(directory: str | os.PathLike, relative, where: str) -> Path:
    """``directory / relative``, refused unless it stays inside `directory`.

    `relative` must be a relative path (a string) whose resolved location (symbolic links
    followed) lies inside the resolved `directory`: files named by a manifest are read from the
    manifest's directory and nowhere else.

    Raises
    ------
    ValueError
        Naming `where`: not a string, empty, absolute, or leading outside `directory`.
    """
    if not isinstance(relative, str) or not relative or "\0" in relative:
        raise ValueError(f"{where}: expected a relative file path, got {relative!r}")
    if os.path.isabs(relative) or Path(relative).is_absolute() or relative.startswith("\\"):
        raise ValueError(f"{where}: {relative!r} is an absolute path; files must lie inside "
                         f"{directory}")
    base = Path(directory)
    target = base / relative
    try:
        inside = target.resolve().is_relative_to(base.resolve())
    except (OSError, RuntimeError) as exc:  # symlink loop
        raise ValueError(f"{where}: cannot resolve {relative!r} ({exc})") from exc
    if not inside:
        raise ValueError(f"{where}: {relative!r} leads outside {directory}")
    return target


def one_line(text) -> str:
    """`text` (or an exception's message) on one line: its lines joined by ``"; "``."""
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


def describe_error(exc: BaseException) -> str:
    """The user's words for a bad-input exception, on one line.

    A ``KeyError`` of a bare key (``KeyError('npz')``) becomes "an input file lacks the required
    entry 'npz'"; an ``OSError`` becomes "FILE: reason"; anything else its message.
    """
    if isinstance(exc, KeyError):
        key = exc.args[0] if exc.args else None
        if isinstance(key, str) and " " in key.strip():
            return one_line(key)  # already a sentence ("capture has no camera 'x' …")
        return f"an input file lacks the required entry {key!r}"
    if isinstance(exc, OSError) and exc.strerror:
        where = exc.filename if exc.filename is not None else ""
        if exc.filename2 is not None:
            where = f"{where} -> {exc.filename2}"
        text = exc.strerror[:1].lower() + exc.strerror[1:]
        return f"{where}: {text}" if where else text
    return one_line(exc) or type(exc).__name__


def file_kind(mode: int) -> str:
    """What a ``st_mode`` that is not a regular file is, for messages: ``"a directory"``,
    ``"a FIFO, a named pipe"``, ``"a character device"``, … (a FIFO or a device given as an input
    file would block or stream: readers refuse them before opening, from ``os.stat``)."""
    for test, kind in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO, a named pipe"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a plain file"
