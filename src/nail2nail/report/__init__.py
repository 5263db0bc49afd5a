"""The scan report: one self-contained HTML page for an output directory (issue 13).

``nail2nail report OUT_DIR`` (and ``--report`` on ``process``; ``demo`` writes one by default)
builds ``OUT_DIR/report.html`` from the files the pipeline wrote there
(:func:`~nail2nail.report.inputs.find_inputs`): the capture (frame thumbnails, decode quality
and coverage), the calibration (per-camera geometry and residuals), the projector distortion,
the merge (heat maps, histograms and statistics per camera pair), an interactive 3D viewer of
the super scan (plotly.js, WebGL) and the rolled-equivalent print. Every image and script is
embedded: the page opens offline, from ``file://``, and weighs a few MB to a few tens of MB
(plotly.js's 3D bundle, ``report/vendor/``, is 1.7 MB of it; the 3D viewer's two levels of
detail most of the rest).

The page's JavaScript contract, for scripts and tests: ``<div id="viewer">`` holds the WebGL
canvas, and ``window.nail2nailReport`` is
``{ready, rotate(degrees), colorBy(name), show(what)}``: ``ready`` a promise resolved once the
3D view has drawn, ``rotate`` turns the view about the finger axis, ``colorBy`` recolours it
by ``"albedo"``, ``"camera"`` or ``"error"``, ``show`` switches to ``"mesh"``, ``"points"`` or
``"detail"``; each returns a promise resolved after the redraw.
"""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path

from nail2nail import __version__
from nail2nail._progress import Stages
from nail2nail._validation import describe_error
from nail2nail.io._atomic import atomic_path
from nail2nail.report import calibration, capture, distortion, merge, overview, prints, viewer
from nail2nail.report._html import Section, page_html
from nail2nail.report._parts import CORRUPT, CorruptPart, problem_notes
from nail2nail.report.inputs import ReportInputs, find_inputs

__all__ = ["ReportInputs", "build_report", "find_inputs", "write_report"]


def build_report(out_dir: str | os.PathLike, *, max_points: int = 60_000,
                 progress: bool = False) -> str:
    """The HTML report of a nail2nail output directory, as a string.

    Parameters
    ----------
    out_dir : path-like
        Output directory of ``process``, ``demo``, ``scan`` or ``merge``
        (:func:`~nail2nail.report.inputs.find_inputs`).
    max_points : int
        Most super-scan vertices sent to the 3D viewer (decimated by vertex clustering above;
        the PLY in the directory keeps every point).
    progress : bool
        Stage lines on stderr (a terminal only, not under :func:`nail2nail._progress.quiet`).

    Returns
    -------
    str
        The page.

    Raises
    ------
    ValueError
        `out_dir` is not an output directory.

    Warns
    -----
    UserWarning
        Once per file that is there but cannot be used (not JSON, truncated, values of the
        wrong kind), naming it and the problem: the sections that read it say so in a note,
        the others are drawn (:mod:`nail2nail.report._parts`).
    """
    import matplotlib

    inputs = find_inputs(out_dir)
    say = Stages(enabled=progress, prefix="report: ")
    sections = []
    # names from the input files (cameras, pairs) are drawn as they are: a "$" is not maths
    with matplotlib.rc_context({"text.parse_math": False}):
        for (sid, title), module in SECTIONS:
            say(title.lower() if sid != "view3d" else title)
            sections.append(_section(inputs, sid, title, module, max_points))
    for path, reason in dict.fromkeys(inputs.problems):
        warnings.warn(f"{path}: {reason}; the report says so in its section and shows the "
                      "rest", UserWarning, stacklevel=2)

    title = f"nail2nail scan report: {inputs.root.resolve().name}"
    subtitle = (f"{inputs.kind} directory {inputs.root.resolve()} · written "
                f"{time.strftime('%Y-%m-%d %H:%M')} by nail2nail {__version__}")
    return page_html(title, subtitle, sections, head_scripts=viewer.libraries(),
                     footer="Self-contained page: every image and script is embedded; it "
                     "needs no network. Units: mm and µm in the world frame of the scan, "
                     "pixels with (0, 0) the centre of the top-left pixel (docs/conventions.md).")


#: The sections, in page order: ``((id, title), module)``.
SECTIONS = ((("overview", "Overview"), overview), (("capture", "Capture"), capture),
            (("calibration", "Calibration"), calibration),
            (("distortion", "Projector distortion"), distortion), (("merge", "Merge"), merge),
            (("view3d", "3D viewer"), viewer), (("print", "Print"), prints))


def _section_inputs(sid: str, inputs: ReportInputs) -> str:
    """The files a section reads, for a problem that no single one of them is blamed for."""
    parts = {"overview": [inputs.summary_path, inputs.scans, inputs.merge, inputs.print],
             "capture": [inputs.capture, inputs.scans, inputs.summary_path],
             "calibration": [inputs.calibration],
             "distortion": [inputs.distortion, inputs.calibration],
             "merge": [inputs.merge, inputs.summary_path], "view3d": [inputs.merge, inputs.scans],
             "print": [inputs.print]}[sid]
    return ", ".join(str(p) for p in parts if p is not None) or str(inputs.root)


def _section(inputs: ReportInputs, sid: str, title: str, module, max_points: int) -> Section:
    """One section; the files it could not use are noted at its top (a section that cannot be
    drawn at all is that note)."""
    start = 0 if sid == "overview" else len(inputs.problems)  # overview: the summary's too
    try:
        try:
            if module is viewer:
                section = viewer.section(inputs, max_points=max_points)
            else:
                section = module.section(inputs)
        except CORRUPT as exc:
            if isinstance(exc, CorruptPart):
                raise
            raise CorruptPart(f"the {title.lower()} section's inputs "
                              f"({_section_inputs(sid, inputs)})",
                              f"{type(exc).__name__}: {describe_error(exc)}") from exc
    except CorruptPart as exc:
        inputs.problems.append((exc.path, exc.reason))
        body = problem_notes(inputs.problems[start:], "the section is not drawn")
        scripts = [viewer.STUB_JS] if module is viewer else []
        return Section(sid, title, body, status="warn", scripts=scripts)
    if len(inputs.problems) > start:
        section.body = problem_notes(inputs.problems[start:]) + section.body
        section.status = "warn"
    return section


def write_report(out_dir: str | os.PathLike, path: str | os.PathLike | None = None, *,
                 max_points: int = 60_000, progress: bool = False) -> Path:
    """Write :func:`build_report` of `out_dir` to `path` (default ``out_dir/report.html``).

    The file is written under a temporary name and renamed: a failed report leaves no partial
    file and keeps an earlier one.

    Returns
    -------
    Path
        The report written.
    """

    path = Path(out_dir) / "report.html" if path is None else Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a directory; give the report's file name")
    existing = next(p for p in (path.parent, *path.parent.parents) if p.exists() or p == p.parent)
    if not existing.is_dir():  # said now, before the report is built (missing ones are made)
        raise ValueError(f"{path}: cannot write the report there: {existing} is not a "
                         "directory")
    if path.exists() and not path.is_file():
        raise ValueError(f"{path}: not a regular file (a FIFO or a device); give the "
                         "report's file name")
    text = build_report(out_dir, max_points=max_points, progress=progress)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path
