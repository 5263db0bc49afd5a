"""JSON files: one atomic writer and one reader whose errors name the file."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from nail2nail._validation import file_kind
from nail2nail.io._atomic import atomic_path

__all__ = ["dumps_json", "json_ready", "read_json", "write_json"]


def json_ready(data: Any) -> Any:
    """`data` with NaN and infinities replaced by ``None`` and NumPy scalars/arrays made plain.

    JSON has no NaN or infinity (``json.dumps`` writes ``NaN``, which strict readers refuse):
    a value that is not a number is written as ``null``.

    Examples
    --------
    >>> json_ready({"a": float("nan"), "b": [1.5, float("inf")], "c": np.float32(2)})
    {'a': None, 'b': [1.5, None], 'c': 2.0}
    """
    if isinstance(data, dict):
        return {k: json_ready(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [json_ready(v) for v in data]
    if isinstance(data, np.ndarray):
        return json_ready(data.tolist())
    if isinstance(data, bool | np.bool_):
        return bool(data)
    if isinstance(data, np.integer):
        return int(data)
    if isinstance(data, float | np.floating):
        value = float(data)
        return value if math.isfinite(value) else None
    return data


def dumps_json(
    data: Any, *, indent: int | None = 2, default: Callable[[Any], Any] | None = None
) -> str:
    """`data` as strict JSON text: NaN and infinities written as ``null`` (:func:`json_ready`).

    Every ``--json`` print of the CLI and :func:`write_json` use it.

    Examples
    --------
    >>> dumps_json({"median": float("nan")}, indent=None)
    '{"median": null}'
    """
    wrapped = None if default is None else (lambda obj: json_ready(default(obj)))
    return json.dumps(json_ready(data), indent=indent, default=wrapped, allow_nan=False)


def write_json(
    path: str | os.PathLike, data: Any, *, default: Callable[[Any], Any] | None = None
) -> Path:
    """Write `data` as indented strict JSON (UTF-8, trailing newline), atomically.

    NaN and infinities are written as ``null`` (:func:`dumps_json`).

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
    text = dumps_json(data, indent=2, default=default) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def read_json(path: str | os.PathLike) -> Any:
    """Parse the JSON file `path`.

    Raises
    ------
    ValueError
        Naming the file, if it is not valid UTF-8 JSON or not a regular file.
    OSError
        If the file cannot be read (missing, permissions).
    """
    path = Path(path)
    # a FIFO or a device would block or stream: refused before it is opened
    if path.exists() and not path.is_file():
        raise ValueError(f"{path}: not a regular file ({file_kind(path.stat().st_mode)}); "
                         "expected a JSON file")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    except RecursionError as exc:
        raise ValueError(f"{path}: not valid JSON (nested too deeply)") from exc
