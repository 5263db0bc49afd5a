"""The batch results table: one row per capture, from the task records and the job's files.

:func:`result_row` completes a task record with what ``OUT/<capture>/process.json`` and
``print/print.json`` hold; :func:`write_results` writes ``OUT/batch.json`` (the rows as a list)
and ``OUT/batch.csv`` (the same, nested fields flattened), each atomically.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

from nail2nail.io._atomic import atomic_path
from nail2nail.io._json import read_json, write_json

__all__ = ["TABLE_CSV", "TABLE_JSON", "read_results", "result_row", "write_results"]

TABLE_JSON, TABLE_CSV = "batch.json", "batch.csv"  # in OUT, beside the job directories


def result_row(record: dict, *, attempts: int = 1) -> dict:
    """A results row from a task record (:func:`nail2nail.batch.tasks.run_capture`).

    Parameters
    ----------
    record : dict
        The task's record.
    attempts : int
        How many times the task ran (1 + the workers lost while it ran).

    Returns
    -------
    dict
        ``{"capture", "status", "error", "bad_input", "seconds": {stage: s},
        "merge_median_um": {pair: µm}, "valid_pixels": {camera: n}, "super_vertices",
        "clarity_median", "motion_um", "peak_rss_mb",
        "ran", "worker", "attempts", "task_seconds", "hash", "out"}`` (``ran``: the job ran in
        this batch, not skipped nor an earlier failure repeated; ``task_seconds``: the task's
        wall time on its worker, hashing included; ``hash``: the inputs hash, ``None`` if it
        could not be computed); the job's figures are ``None``/empty when it failed.
    """

    row = {"capture": Path(record["capture"]).name, "status": record["status"],
           "error": record["error"], "bad_input": bool(record.get("bad_input", False)),
           "seconds": {}, "merge_median_um": {}, "valid_pixels": {},
           "super_vertices": None, "clarity_median": None, "motion_um": None,
           "peak_rss_mb": None,
           "ran": bool(record.get("ran", False)), "worker": record.get("worker"),
           "attempts": int(attempts), "task_seconds": record.get("wall_seconds"),
           "hash": record.get("hash"), "out": record["out"]}
    job = Path(record["out"])
    if record["status"] == "failed" or not (job / "process.json").is_file():
        return row
    summary = read_json(job / "process.json")
    row["seconds"] = dict(summary.get("seconds", {}))
    row["merge_median_um"] = {pair: round(1e3 * m["distance_mm"]["median"], 3)
                              for pair, m in summary.get("merge", {}).items()
                              if m["distance_mm"].get("median") is not None}
    row["valid_pixels"] = dict(summary.get("cameras", {}))
    row["super_vertices"] = summary.get("super_scan", {}).get("vertices")
    row["peak_rss_mb"] = summary.get("peak_rss_mb")
    motion = summary.get("motion")
    if isinstance(motion, dict) and isinstance(motion.get("motion_mm"), (int, float)):
        row["motion_um"] = round(1e3 * motion["motion_mm"], 1)  # docs/motion.md
    if (job / "print" / "print.json").is_file():
        quality = read_json(job / "print" / "print.json").get("quality", {})
        row["clarity_median"] = quality.get("clarity_median")
    return row


def _flat(row: dict) -> dict:
    flat = {}
    for key, value in row.items():
        if isinstance(value, dict):
            prefix = {"seconds": "seconds", "merge_median_um": "merge_median_um",
                      "valid_pixels": "valid_pixels"}[key]
            flat.update({f"{prefix}_{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    return flat


def write_results(out: str | os.PathLike, rows: list[dict]) -> tuple[Path, Path]:
    """Write `rows` as ``OUT/batch.json`` and ``OUT/batch.csv`` (atomically); return both paths.

    The CSV has one column per scalar field and per stage, pair and camera
    (``seconds_scan``, ``merge_median_um_0-1``, ``valid_pixels_cam0`` …), in order of first
    appearance; a capture without a value has an empty cell.
    """

    out = Path(out)
    json_path, csv_path = out / TABLE_JSON, out / TABLE_CSV
    write_json(json_path, rows)
    flat = [_flat(r) for r in rows]
    columns = list(dict.fromkeys(k for r in flat for k in r))
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(flat)
    with atomic_path(csv_path) as tmp:
        tmp.write_text(text.getvalue(), encoding="utf-8")
    return json_path, csv_path


def read_results(out: str | os.PathLike) -> list[dict]:
    """The rows of an earlier ``OUT/batch.json``; ``[]`` when there is none, or it is not a
    list of rows (unreadable, or not this command's): nothing to resume from."""

    try:
        rows = read_json(Path(out) / TABLE_JSON)
    except (OSError, ValueError):
        return []
    return [r for r in rows if isinstance(r, dict)] if isinstance(rows, list) else []
