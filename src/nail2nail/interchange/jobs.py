"""One finger's print and what is known of its capture, read from a job directory.

A job directory is what ``nail2nail process`` (or a ``batch`` job) writes: ``print/print.json``
and ``print/print.png`` beside ``process.json``; the print directory of ``nail2nail unroll``
(``print.json`` at its top) is read too. :func:`read_job` takes the print (the lossless PNG:
the transaction's WSQ or JPEG 2000 is encoded from it), its resolution, its quality figure and
the capture's description.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nail2nail import __version__
from nail2nail._validation import confined_path
from nail2nail.io._json import read_json
from nail2nail.io.prints import read_print_image
from nail2nail.io.rolled import ROLLED_FORMAT

__all__ = ["FingerPrint", "find_print_dir", "read_job"]


@dataclass(frozen=True)
class FingerPrint:
    """A rolled-equivalent print and its capture, ready for a Type-14 record.

    Attributes
    ----------
    image : (H, W) uint8
        The print, legacy convention (ridges dark), lossless.
    ppi : float
        Its resolution (``print.json`` ``ppi``).
    quality : int or None
        Ridge clarity median × 100, rounded (``print.json`` ``quality.clarity_median``), or
        ``None`` when the print has none.
    capture_date : str
        ``YYYYMMDD``: the local date ``process.json`` (else ``print.json``) was written, the
        day the job ran (``capture.json`` records no date).
    created_by : str or None
        The capture's writer (``capture.json`` ``created_by``) when the capture is still there.
    comment : str
        The description written in field 14.020.
    source : str
        The job directory, as given.
    """

    image: np.ndarray
    ppi: float
    quality: int | None
    capture_date: str
    created_by: str | None
    comment: str
    source: str


def find_print_dir(job_dir: str | os.PathLike) -> Path:
    """The print directory of a job (``JOB/print``) or of ``unroll`` (``JOB`` itself).

    Raises
    ------
    ValueError
        Naming `job_dir`: missing, not a directory, or holding no ``print.json``.
    """
    job = Path(job_dir)
    if not job.exists():
        raise ValueError(f"{job_dir}: no such job directory")
    if not job.is_dir():
        raise ValueError(f"{job_dir}: not a directory; expected a job directory of "
                         "`nail2nail process` or `batch`")
    for candidate in (job / "print", job):
        if (candidate / "print.json").is_file():
            return candidate
    raise ValueError(f"{job_dir}: not a job directory: no print/print.json (run `nail2nail "
                     "process` on the capture first)")


def _capture_writer(job: Path) -> str | None:
    """``created_by`` of the job's capture, if ``process.json`` names one still readable."""
    try:
        summary = read_json(job / "process.json")
        capture = Path(summary["capture"])
        manifest = read_json(capture / "capture.json")
    except (OSError, ValueError, KeyError, TypeError):
        return None
    writer = manifest.get("created_by") if isinstance(manifest, dict) else None
    return writer if isinstance(writer, str) and writer.strip() else None


def read_job(job_dir: str | os.PathLike) -> FingerPrint:
    """Read the print of a job directory and what is known of its capture.

    Parameters
    ----------
    job_dir : path-like
        A ``process`` or ``batch`` job directory (or an ``unroll`` print directory).

    Returns
    -------
    FingerPrint

    Raises
    ------
    ValueError
        Naming the directory or file: no job there, a ``print.json`` of another format, or an
        unreadable print image.
    """
    print_dir = find_print_dir(job_dir)
    meta_path = print_dir / "print.json"
    meta = read_json(meta_path)
    if not isinstance(meta, dict) or meta.get("format") != ROLLED_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise ValueError(f"{meta_path}: expected format {ROLLED_FORMAT!r}, got {got!r}")
    files = meta.get("files")
    name = files.get("print", "print.png") if isinstance(files, dict) else "print.png"
    image_path = confined_path(print_dir, name, f"{meta_path}: files")
    image, file_ppi = read_print_image(image_path)
    ppi = meta.get("ppi", file_ppi)
    if isinstance(ppi, bool) or not isinstance(ppi, (int, float)) or not ppi > 0:
        raise ValueError(f"{meta_path}: ppi: expected a positive number, got {ppi!r}")
    quality = None
    figures = meta.get("quality")
    clarity = figures.get("clarity_median") if isinstance(figures, dict) else None
    if isinstance(clarity, (int, float)) and not isinstance(clarity, bool) and math.isfinite(
            clarity):
        quality = round(100 * min(max(float(clarity), 0.0), 1.0))
    job = Path(job_dir)
    stamp = job / "process.json" if (job / "process.json").is_file() else meta_path
    capture_date = time.strftime("%Y%m%d", time.localtime(stamp.stat().st_mtime))
    writer = _capture_writer(job)
    method = meta.get("method") if isinstance(meta.get("method"), str) else "unknown"
    cameras = meta.get("cameras")
    n_cameras = len(cameras) if isinstance(cameras, list) else 0
    comment = (f"contactless 3D structured-light capture ({writer or 'capture unknown'}, "
               f"{n_cameras} cameras) unrolled ({method}) by nail2nail {__version__}")
    return FingerPrint(image=image, ppi=float(ppi), quality=quality,
                       capture_date=capture_date, created_by=writer, comment=comment,
                       source=os.fspath(job_dir))
