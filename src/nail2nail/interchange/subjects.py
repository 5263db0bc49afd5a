"""A batch's captures grouped by person: one ANSI/NIST-ITL transaction per subject.

``nail2nail batch … --subjects TABLE.csv`` reads a CSV table with the header
``capture,subject,finger_position`` (one row per capture: the capture directory's name, the
person, the finger's position) before the cluster starts, and after the batch writes
``OUT/transactions/<subject>.an2`` from the subject's job directories
(:func:`nail2nail.interchange.transaction.export_transaction`, default options).
"""

from __future__ import annotations

import csv
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from nail2nail._validation import as_name
from nail2nail.interchange.positions import FINGER_POSITIONS, check_position
from nail2nail.interchange.transaction import export_transaction

__all__ = ["SUBJECT_COLUMNS", "TRANSACTIONS_DIR", "export_subjects", "read_subject_table"]

#: The table's columns, in its header.
SUBJECT_COLUMNS = ("capture", "subject", "finger_position")
#: Where the transactions go, inside the batch's output directory.
TRANSACTIONS_DIR = "transactions"


def read_subject_table(path: str | os.PathLike, captures: Sequence[str | os.PathLike]
                       ) -> dict[str, list[tuple[str, int]]]:
    """Read and check the subjects table against the batch's captures.

    Parameters
    ----------
    path : path-like
        CSV file, header ``capture,subject,finger_position``.
    captures : sequence of path-like
        The batch's capture directories (their names are the table's ``capture``).

    Returns
    -------
    dict
        Subject → ``[(capture name, finger position)]`` in the table's order.

    Raises
    ------
    ValueError
        Naming the file and row: a missing file or column, a capture not in the batch or
        listed twice, a subject that is not a plain name, a position outside the standard's
        table or one finger twice for a subject; a capture named ``transactions``.
    """
    names = {Path(c).name for c in captures}
    if TRANSACTIONS_DIR in names:
        raise ValueError(f"{path}: a capture is named {TRANSACTIONS_DIR!r}, the directory of "
                         "the transactions in the output; rename it")
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
            header = tuple(rows[0].keys()) if rows else None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a UTF-8 CSV table ({exc.reason})") from exc
    except csv.Error as exc:
        raise ValueError(f"{path}: not a CSV table ({exc})") from exc
    if not rows:
        raise ValueError(f"{path}: no rows; expected the header {','.join(SUBJECT_COLUMNS)} "
                         "and one row per capture")
    missing = [c for c in SUBJECT_COLUMNS if c not in (header or ())]
    if missing:
        raise ValueError(f"{path}: no column {missing[0]!r}; expected the header "
                         f"{','.join(SUBJECT_COLUMNS)}")
    subjects: dict[str, list[tuple[str, int]]] = {}
    seen_captures: dict[str, int] = {}
    for number, row in enumerate(rows, start=2):  # the header is line 1
        where = f"{path}: line {number}"
        capture = (row.get("capture") or "").strip()
        if capture not in names:
            raise ValueError(f"{where}: capture {capture!r} is not one of the batch's "
                             f"captures ({len(names)} found)")
        if capture in seen_captures:
            raise ValueError(f"{where}: capture {capture!r} is listed twice (line "
                             f"{seen_captures[capture]})")
        seen_captures[capture] = number
        subject = as_name((row.get("subject") or "").strip(), f"{where}: subject")
        text = (row.get("finger_position") or "").strip()
        if not text.lstrip("-").isdigit():
            raise ValueError(f"{where}: finger_position: expected an integer code, got "
                             f"{text!r}")
        position = check_position(int(text), f"{where}: finger_position")
        taken = {p: c for c, p in subjects.get(subject, [])}
        if position in taken:
            raise ValueError(f"{where}: subject {subject!r} has finger position {position} "
                             f"({FINGER_POSITIONS[position]}) twice (captures "
                             f"{taken[position]!r} and {capture!r})")
        subjects.setdefault(subject, []).append((capture, position))
    return subjects


def export_subjects(subjects: dict[str, list[tuple[str, int]]], rows: Sequence[dict],
                    out: str | os.PathLike) -> list[str]:
    """Write one transaction per subject whose captures all succeeded; return their paths.

    A subject with a failed capture gets no transaction: one warning line on stderr
    (``nail2nail batch: warning: …``); the batch's exit status already says a capture failed.

    Raises
    ------
    ValueError
        After the other subjects' transactions are written, if one could not be (a print at
        a resolution a transaction does not take, …): the first subject, its reason and how
        many failed.
    """
    jobs = {row["capture"]: row for row in rows}
    written, errors = [], []
    for subject, entries in subjects.items():
        failed = [c for c, _ in entries if jobs.get(c, {}).get("status") not in ("done",
                                                                                  "skipped")]
        if failed:
            print(f"nail2nail batch: warning: subject {subject}: capture {failed[0]} failed; "
                  "no transaction written", file=sys.stderr)
            continue
        target = Path(out) / TRANSACTIONS_DIR / f"{subject}.an2"
        try:
            export_transaction([jobs[c]["out"] for c, _ in entries], target,
                               positions=[p for _, p in entries])
        except ValueError as exc:
            errors.append(f"subject {subject}: {exc}")
            continue
        written.append(os.fspath(target))
    if errors:
        raise ValueError(f"{errors[0]} ({len(errors)} of {len(subjects)} subjects' "
                         "transactions not written)")
    return written
