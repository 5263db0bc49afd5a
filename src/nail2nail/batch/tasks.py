"""One batch task: the whole job for one capture on a Dask worker, never raising.

:func:`run_capture` is what each worker runs. It returns a record (a dict) in every case: an
ordinary error (a corrupt frame, a bad capture) is caught and becomes a ``"failed"`` record, so
that Dask does not retry it pointlessly; only the loss of the worker itself (killed, out of
memory) makes the scheduler run the task again elsewhere.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

from .hashing import inputs_hash

__all__ = ["BATCH_JSON", "clean_stale", "run_capture"]

BATCH_JSON = "batch.json"  # the hash record, inside the job directory


def clean_stale(out: str | os.PathLike, name: str) -> list[Path]:
    """Remove what an interrupted job for `name` may have left beside ``OUT/<name>``: the
    temporary ``.NAME.tmp-*`` and ``.NAME.old-*`` directories of
    :func:`nail2nail.io._atomic.atomic_directory`. Return the paths removed.

    Call it only while no task for `name` runs (before submitting, after all have ended).
    """
    out = Path(out)
    stale = [*out.glob(f".{name}.tmp-*"), *out.glob(f".{name}.old-*")]
    for path in stale:
        shutil.rmtree(path, ignore_errors=True)
    return stale


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except ValueError:  # not on a Dask worker (called directly)
        return "local"


def run_capture(capture: str, calibration: str, out: str, options: dict) -> dict:
    """Process one capture into `out` unless its output is complete and its inputs unchanged.

    Parameters
    ----------
    capture : str
        Capture directory.
    calibration : str
        Calibration JSON file.
    out : str
        The job directory, ``OUT/<capture name>``.
    options : dict
        Keyword arguments of :func:`nail2nail.process.process_capture`.

    Returns
    -------
    dict
        ``{"capture", "out", "status": "done" | "skipped" | "failed", "error", "hash",
        "worker", "wall_seconds"}``; ``error`` is one line, ``None`` unless failed.
    """
    from .._validation import describe_error
    from ..io._json import read_json, write_json
    from ..process import process_capture

    start = time.perf_counter()
    record = {"capture": str(capture), "out": str(out), "status": "failed", "error": None,
              "hash": None, "worker": _worker_name()}
    job = Path(out)
    try:
        record["hash"] = digest = inputs_hash(capture, calibration, options)
        done = job / "process.json"
        marker = job / BATCH_JSON
        if done.is_file() and marker.is_file() and read_json(marker).get("hash") == digest:
            record["status"] = "skipped"
        else:
            process_capture(capture, calibration, job, **options)
            # after the job directory is in place: killed in between, the job is redone
            write_json(marker, {"hash": digest, "capture": str(capture),
                                "calibration": str(calibration)})  # atomic
            record["status"] = "done"
    except Exception as exc:  # isolate the capture: its error is its record
        record["error"] = f"{type(exc).__name__}: {describe_error(exc)}"
    record["wall_seconds"] = round(time.perf_counter() - start, 3)
    return record
