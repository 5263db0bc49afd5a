"""JSON files: one atomic writer and one reader whose errors name the file."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ._atomic import atomic_path

__all__ = ["read_json", "write_json"]


def write_json(
    path: str | os.PathLike, data: Any, *, default: Callable[[Any], Any] | None = None
) -> Path:
    """Write `data` as indented JSON (UTF-8, trailing newline), atomically.

    Parameters
    ----------
    path : path-like
        Target file; its directory is created if needed.
    data : JSON-serialisable object
    default : callable, optional
        Passed to :func:`json.dumps` for objects it cannot serialise (e.g. ``float``).

    Returns
    -------
    Path
        `path`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "a.json"
    >>> read_json(write_json(target, {"a": [1, 2]}))
    {'a': [1, 2]}
    """
    path = Path(path)
    text = json.dumps(data, indent=2, default=default) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def read_json(path: str | os.PathLike) -> Any:
    """Parse the JSON file `path`.

    Raises
    ------
    ValueError
        Naming the file, if it is not valid UTF-8 JSON.
    OSError
        If the file cannot be read (missing, permissions).
    """
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
