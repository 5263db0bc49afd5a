"""Content hash of a batch task's inputs: the capture's files, the calibration, the options and
the nail2nail version.

A capture whose output holds the same hash (``OUT/<capture>/batch.json``) is skipped by
:func:`nail2nail.batch.process_batch`; any changed byte, renamed file, changed option or another
release of nail2nail redoes it.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from nail2nail import __version__

__all__ = ["inputs_hash"]

_CHUNK = 1 << 20


def _update_with_file(digest, path: Path) -> None:
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)


def _file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    _update_with_file(digest, path)
    return digest.hexdigest()


def _value(value):
    """JSON stand-in of an option value that JSON cannot hold."""
    import numpy as np

    if isinstance(value, np.ndarray):  # all of it: repr() elides large arrays
        array = np.ascontiguousarray(value)
        return {"dtype": array.dtype.str, "shape": list(array.shape),
                "sha256": hashlib.sha256(array.tobytes()).hexdigest()}
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return repr(value)


def _canonical(options: dict) -> dict:
    """`options` with each mask file replaced by its path and content hash."""
    masks = options.get("masks")
    if not masks:
        return options
    files = {}
    for camera, mask in masks.items():
        if isinstance(mask, (str, os.PathLike)):
            path = Path(mask)
            if not path.is_file():
                raise ValueError(f"{path}: mask file of camera {camera!r} not found")
            mask = {"path": os.fspath(path), "sha256": _file_sha256(path)}
        files[camera] = mask
    return {**options, "masks": files}


def inputs_hash(capture: str | os.PathLike, calibration: str | os.PathLike,
                options: dict | None = None) -> str:
    """SHA-256 of every file under `capture` (relative path and content), of `calibration`'s
    content, of `options` (as sorted JSON) and of ``nail2nail.__version__``; hex string.

    Parameters
    ----------
    capture : path-like
        Capture directory (or a capture of several projectors: every file under it); hidden
        files (names starting with ``.``) are ignored.
    calibration : path-like
        Calibration JSON file; for a capture of several projectors, it stands for one per
        projector (:func:`nail2nail.process.calibration_files`), each hashed in turn.
    options : dict, optional
        The processing options (JSON-serialisable values, else their ``repr``); NumPy arrays
        count by their dtype, shape and bytes, and the files of ``options["masks"]``
        (``{camera: path or array}``) by their content.

    Returns
    -------
    str
        64 hexadecimal digits.

    Raises
    ------
    ValueError
        `capture` is not a directory or a calibration file is missing.
    """
    from nail2nail.process import calibration_files

    capture, calibration = Path(capture), Path(calibration)
    if not capture.is_dir():
        raise ValueError(f"{capture}: not a capture directory")
    calibrations = calibration_files(calibration, capture)
    digest = hashlib.sha256()
    files = sorted(p for p in capture.rglob("*") if p.is_file()
                   and not any(part.startswith(".") for part in p.relative_to(capture).parts))
    for path in files:
        # the name and size first, so that moving bytes between files changes the hash
        digest.update(f"{path.relative_to(capture).as_posix()}\0{path.stat().st_size}\0"
                      .encode())
        _update_with_file(digest, path)
    for path in calibrations:
        digest.update(b"\0calibration\0")
        _update_with_file(digest, path)
    digest.update(b"\0options\0")
    digest.update(json.dumps(_canonical(options or {}), sort_keys=True, default=_value)
                  .encode())
    digest.update(f"\0nail2nail {__version__}".encode())
    return digest.hexdigest()
