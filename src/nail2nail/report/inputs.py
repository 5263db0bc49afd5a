"""What the report is made of: the files of one nail2nail output directory, found by name.

Four kinds of directory are recognised, by the summary file they hold:

========== ============================ ===================================================
kind       marker                       layout
========== ============================ ===================================================
process    ``process.json``             ``nail2nail process``: ``scans/``, ``merge/``,
                                        ``print/``; capture and calibration named in the
                                        summary (read where they are, when they still exist)
demo       ``summary.json``             ``nail2nail demo``: the finger of the best
                                        configuration (``scans/best/finger``,
                                        ``merge/best/finger``), ``print/``, ``calib/``,
                                        ``distortion/``, ``captures/``
scans      ``scan.json``                ``nail2nail scan``; ``merge/`` beside it if present
merge      ``merge.json``               ``nail2nail merge``
========== ============================ ===================================================
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from nail2nail.io._json import read_json
from nail2nail.report._parts import CorruptPart, quoted, reading
from nail2nail.scan.patterns import PANEL_SIZE

__all__ = ["ReportInputs", "find_inputs", "projector_panel"]


@dataclass
class ReportInputs:
    """Paths of the parts of one output directory (``None``: not there).

    Attributes
    ----------
    root : Path
        The output directory.
    kind : str
        ``"process"``, ``"demo"``, ``"scans"`` or ``"merge"``.
    summary : dict
        The directory's summary file (``process.json``, ``summary.json``, ``scan.json`` or
        ``merge.json``).
    capture : Path or None
        The capture directory (``capture.json``) the scans were decoded from.
    calibration : Path or None
        The calibration JSON the scans were reconstructed with.
    scans, merge, print : Path or None
        The scan directory (``scan.json``), merge directory (``merge.json``) and print
        directory (``print.json``).
    distortion : Path or None
        ``projector_distortion.json`` of a distortion estimate (demo).
    comparison : dict
        Demo only: merge directories of the other calibration configurations,
        ``{"before/target": Path, …}``.
    notes : list of str
        What was looked for and not found (shown in the report).
    summary_path : Path or None
        The summary file :attr:`summary` was read from.
    problems : list of (str, str)
        Files that are there but cannot be used (not JSON, truncated, values of the wrong
        kind) and why, as ``(file, problem)``: filled as the sections are drawn, each noted in
        the sections that read the file and warned about once
        (:mod:`nail2nail.report._parts`).
    """

    root: Path
    kind: str
    summary: dict
    capture: Path | None = None
    calibration: Path | None = None
    scans: Path | None = None
    merge: Path | None = None
    print: Path | None = None
    distortion: Path | None = None
    comparison: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    summary_path: Path | None = None
    problems: list = field(default_factory=list)


def _dir_with(path: Path, marker: str) -> Path | None:
    return path if (path / marker).is_file() else None


def _read_summary(path: Path, problems: list) -> dict:
    """The summary file as a dict; ``{}`` (and the problem in `problems`) when it cannot be
    read or is not a JSON object: the parts found by their place are still reported."""
    try:
        with reading(path):
            summary = read_json(path)
            if not isinstance(summary, dict):
                raise ValueError(f"expected a JSON object, got {type(summary).__name__}")
    except CorruptPart as exc:
        problems.append((exc.path, exc.reason))
        return {}
    return summary


def _named(summary: dict, key: str, root: Path, marker: str, what: str, notes: list,
           problems: list, summary_path: Path) -> Path | None:
    """A path named in a summary, if it still exists (as given, or relative to `root`)."""
    value = summary.get(key)
    if not value:
        return None
    if not isinstance(value, str):
        problems.append((str(summary_path), f"{key}: expected a path, got {quoted(value)}"))
        return None
    for candidate in (Path(value), root / value, root.parent / value):
        target = candidate / marker if marker else candidate
        if target.is_file():
            return candidate
    notes.append(f"the {what} {value} named in the summary is not there any more")
    return None


def find_inputs(out_dir: str | os.PathLike) -> ReportInputs:
    """The parts of a nail2nail output directory, for :func:`nail2nail.report.build_report`.

    Parameters
    ----------
    out_dir : path-like
        Output of ``nail2nail process``, ``nail2nail demo``, ``nail2nail scan`` or
        ``nail2nail merge``.

    Returns
    -------
    ReportInputs

    Raises
    ------
    ValueError
        `out_dir` is not a directory, or holds none of the summary files above. A summary
        file that cannot be read is recorded in ``problems`` (and read as ``{}``).
    """
    root = Path(out_dir)
    if not root.is_dir():
        raise ValueError(f"{root}: not a directory")
    notes: list[str] = []
    problems: list[tuple[str, str]] = []
    if (root / "process.json").is_file():
        path = root / "process.json"
        summary = _read_summary(path, problems)
        inputs = ReportInputs(root, "process", summary,
                              scans=_dir_with(root / "scans", "scan.json"),
                              merge=_dir_with(root / "merge", "merge.json"),
                              print=_dir_with(root / "print", "print.json"))
        projectors = summary.get("projectors")
        if isinstance(projectors, list) and projectors and isinstance(
                summary.get("calibration"), list) and summary["calibration"]:
            # a rig of several projectors: the first projector's capture and calibration
            # stand for the rig in their sections (the cameras are the same in each)
            first = {**summary, "capture": str(Path(str(summary.get("capture", ""))) /
                                               str(projectors[0])),
                     "calibration": summary["calibration"][0]}
            listed = ", ".join(map(str, projectors))
            notes.append(f"a rig of {len(projectors)} projectors ({listed}): the capture and "
                         f"calibration sections show {projectors[0]}'s")
        else:
            first = summary
        inputs.capture = _named(first, "capture", root, "capture.json", "capture", notes,
                                problems, path)
        inputs.calibration = _named(first, "calibration", root, "", "calibration", notes,
                                    problems, path)
    elif (root / "summary.json").is_file():
        path = root / "summary.json"
        summary = _read_summary(path, problems)
        inputs = ReportInputs(root, "demo", summary,
                              scans=_dir_with(root / "scans" / "best" / "finger", "scan.json"),
                              merge=_dir_with(root / "merge" / "best" / "finger", "merge.json"),
                              print=_dir_with(root / "print", "print.json"))
        inputs.capture = _dir_with(root / "captures" / "finger", "capture.json")
        best = root / "calib" / "rig_best.json"
        inputs.calibration = best if best.is_file() else None
        dist = root / "distortion" / "projector_distortion.json"
        inputs.distortion = dist if dist.is_file() else None
        inputs.comparison = {
            f"{m.parent.parent.name}/{m.parent.name}": m.parent
            for m in sorted((root / "merge").glob("*/*/merge.json"))
        }
    elif (root / "scan.json").is_file():
        path = root / "scan.json"
        summary = _read_summary(path, problems)
        inputs = ReportInputs(root, "scans", summary, scans=root,
                              merge=_dir_with(root / "merge", "merge.json"))
        inputs.capture = _named(summary, "capture", root, "capture.json", "capture", notes,
                                problems, path)
        inputs.calibration = _named(summary, "calibration", root, "", "calibration", notes,
                                    problems, path)
    elif (root / "merge.json").is_file():
        path = root / "merge.json"
        summary = _read_summary(path, problems)
        inputs = ReportInputs(root, "merge", summary, merge=root)
    else:
        raise ValueError(
            f"{root}: not a nail2nail output directory (no process.json, summary.json, "
            "scan.json or merge.json in it)")
    inputs.notes = notes
    inputs.summary_path = path
    inputs.problems = problems
    return inputs


def projector_panel(inputs: ReportInputs) -> tuple[int, int]:
    """The projector panel ``(W, H)`` px: the capture manifest's ``projector.size``, else
    the thesis's :data:`nail2nail.scan.patterns.PANEL_SIZE` (no capture, or a manifest without
    it)."""

    if inputs.capture is not None:
        try:
            size = read_json(inputs.capture / "capture.json").get("projector", {}).get("size")
            width, height = (int(v) for v in size)
        except (OSError, ValueError, TypeError, AttributeError):  # the capture section says
            return PANEL_SIZE
        if width > 0 and height > 0:
            return width, height
    return PANEL_SIZE
