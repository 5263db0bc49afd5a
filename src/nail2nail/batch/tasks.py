"""One batch task: the whole job for one capture on a Dask worker, never raising.

:func:`run_capture` is what each worker runs. It returns a record (a dict) in every case: an
ordinary error (a corrupt frame, a bad capture) is caught and becomes a ``"failed"`` record, so
that Dask does not retry it pointlessly; only the loss of the worker itself (killed, out of
memory) makes the scheduler run the task again elsewhere.
"""

from __future__ import annotations

import glob
import os
import shutil
import time
from pathlib import Path
from typing import Any, cast

from nail2nail._validation import describe_error
from nail2nail.batch.hashing import inputs_hash
from nail2nail.io._atomic import OutputRefusedError
from nail2nail.io._json import read_json, write_json
from nail2nail.process import process_capture
from nail2nail.report import write_report

__all__ = ["BATCH_JSON", "bad_input", "clean_stale", "run_capture"]

BATCH_JSON = "batch.json"  # the hash record, inside the job directory


def bad_input(exc: BaseException) -> bool:
    """Whether `exc` is an error of the capture's own content, repeated without running again
    while the inputs are unchanged.

    The project's validation errors (``ValueError``, naming the file: a truncated frame, an
    inconsistent manifest), but not :class:`nail2nail.io._atomic.OutputRefusedError` (the
    output path, which the user may clear) nor any other exception (file system, memory,
    internal errors), which are run again on the next call.
    """

    return isinstance(exc, ValueError) and not isinstance(exc, OutputRefusedError)


def clean_stale(out: str | os.PathLike, name: str) -> list[Path]:
    """Remove what an interrupted job for `name` may have left beside ``OUT/<name>``.

    Parameters
    ----------
    out : path-like
        The batch's output directory.
    name : str
        The capture's name (matched literally, not as a pattern).

    Returns
    -------
    list of Path
        The temporary ``.NAME.tmp-*`` and ``.NAME.old-*`` directories of
        :func:`nail2nail.io._atomic.atomic_directory` that were removed.

    Notes
    -----
    Call it only while no task for `name` runs (before submitting, after all have ended).
    """
    out = Path(out)
    name = glob.escape(name)
    stale = [*out.glob(f".{name}.tmp-*"), *out.glob(f".{name}.old-*")]
    for path in stale:
        shutil.rmtree(path, ignore_errors=True)
    return stale


def _write_report(job: Path, points: int) -> None:

    write_report(job, max_points=points)  # atomic, inside the job directory


def _recorded_hash(marker: Path) -> str | None:
    """The hash that the job directory's marker records; ``None`` if unreadable (redo)."""

    try:
        record = read_json(marker)
    except (OSError, ValueError):
        return None
    return record.get("hash") if isinstance(record, dict) else None


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except ValueError:  # not on a Dask worker (called directly)
        return "local"


def run_capture(capture: str, calibration: str, out: str, options: dict,
                failed: dict | None = None, report_points: int | None = None) -> dict:
    """Process one capture into `out` unless its output is complete and its inputs unchanged,
    or it failed before on the same inputs.

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
    failed : dict, optional
        An earlier run's failure for this capture, ``{"hash", "error", "bad_input"}`` (a row
        of ``OUT/batch.json``): if it was a bad-input error and the inputs hash is the same,
        the job is not run again (it would fail the same way) and the record repeats that
        error, with ``ran`` false. Other failures (a file system error, a lost worker, an
        internal error) are always retried.
    report_points : int, optional
        Also write ``OUT/<name>/report.html`` (:func:`nail2nail.report.write_report`, this
        many viewer points). Not part of the inputs hash: a current job without its report
        gets the report alone (``done``), and an existing report is kept.

    Returns
    -------
    dict
        ``{"capture", "out", "status": "done" | "skipped" | "failed", "error", "bad_input",
        "hash", "ran", "worker", "wall_seconds"}``; ``error`` is one line, ``None`` unless
        failed; ``bad_input``: the error is the capture's own (:func:`bad_input`);
        ``ran``: whether the job ran in this call (false when skipped, or its earlier failure
        was repeated).
    """

    start = time.perf_counter()
    record: dict[str, Any] = {"capture": str(capture), "out": str(out), "status": "failed",
                              "error": None,
              "bad_input": False, "hash": None, "ran": False, "worker": _worker_name()}
    job = Path(out)
    try:
        record["hash"] = digest = inputs_hash(capture, calibration, options)
        marker = job / BATCH_JSON
        current = ((job / "process.json").is_file() and marker.is_file()
                   and _recorded_hash(marker) == digest)
        wants_report = report_points is not None and not (job / "report.html").is_file()
        if current and not wants_report:
            record["status"] = "skipped"
        elif current:  # the job is current, its report missing: the report alone
            record["ran"] = True
            _write_report(job, cast(int, report_points))  # wants_report: not None
            record["status"] = "done"
        elif failed and failed.get("bad_input") and failed.get("hash") == digest:
            record["error"] = failed["error"]  # the same inputs fail the same way
            record["bad_input"] = True
        else:
            record["ran"] = True
            process_capture(capture, calibration, job, **options)
            if report_points is not None:
                _write_report(job, report_points)
            # after the job directory is in place: killed in between, the job is redone
            write_json(marker, {"hash": digest, "capture": str(capture),
                                "calibration": str(calibration)})  # atomic
            record["status"] = "done"
    except Exception as exc:  # isolate the capture: its error is its record
        record["error"] = f"{type(exc).__name__}: {describe_error(exc)}"
        record["bad_input"] = bad_input(exc)
    record["wall_seconds"] = round(time.perf_counter() - start, 3)
    return record
