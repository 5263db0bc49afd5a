"""Reading ``.npz`` files: every failure (missing, truncated, corrupt, pickled) names the file."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

__all__ = ["read_npz"]


def read_npz(
    path: str | os.PathLike, *, required: Iterable[str] = (), what: str = "npz file"
) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at `path`, read now (no pickles).

    Parameters
    ----------
    path : path-like
    required : iterable of str
        Array names that must be present.
    what : str
        What the file is, for messages (``"scan file"``).

    Raises
    ------
    ValueError
        Naming the file: missing, not a zip archive, truncated, corrupt, holding objects that
        need pickle, or lacking a `required` array.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: {what} missing")
    try:
        fh = open(path, "rb")  # ours to close, whatever np.load raises
    except OSError as exc:
        raise ValueError(f"{path}: cannot read {what} ({exc.strerror or exc})") from exc
    try:
        with fh:
            if fh.read(4) not in (b"PK\x03\x04", b"PK\x05\x06"):
                raise ValueError(f"{path}: not a valid {what} (not an .npz archive)")
            fh.seek(0)
            with np.load(fh, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
    except ValueError as exc:
        if str(exc).startswith(f"{path}: "):
            raise
        raise ValueError(f"{path}: not a valid {what} ({_short(exc)})") from exc
    except Exception as exc:
        raise ValueError(f"{path}: not a valid {what} ({_short(exc)})") from exc
    missing = [k for k in required if k not in arrays]
    if missing:
        raise ValueError(f"{path}: {what} lacks array(s) {', '.join(missing)}")
    return arrays


def _short(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 120 else text[:117] + "..."
