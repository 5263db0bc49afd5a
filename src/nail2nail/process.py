"""The whole job for one capture: frames → scans → merge → super scan → rolled-equivalent print.

:func:`process_capture` is what ``nail2nail process CAPTURE --calib rig.json --out OUT`` runs:
the stages of ``scan``, ``merge`` and ``unroll`` in one process, without writing and reading
the scans in between, with the wall time of every stage and the peak memory in the summary
(``OUT/process.json``). Each stage is the library function the stand-alone command calls
(:func:`nail2nail.scan.capture.scan_capture`, :func:`nail2nail.merge.write_merge`,
:func:`nail2nail.unroll.unroll_scans`), so both paths give the same files.

Output directory (written as a whole, :func:`nail2nail.io._atomic.atomic_directory`)::

    OUT/process.json    summary: options, per-stage seconds, peak RSS, merge figures, print
    OUT/scans/          the scan directory (``nail2nail scan``; .npz, mat5 and PLY on request)
    OUT/merge/          merge.json, the mapping files, super.ply and the super mat5 (figures
                        with ``figures=True``)
    OUT/print/          the rolled-equivalent print (``nail2nail unroll``), unless ``unroll=False``

A capture of a rig of several projectors (a directory with ``projectors.json``,
``docs/projectors.md``) is processed as a whole: each projector's capture scanned with its own
calibration (``rig_<capture>.json`` beside the ``rig.json`` given, as ``nail2nail calibrate``
writes them, or a list), every scan into ``OUT/scans`` (named ``<camera>-p<k>``, each with its
projector and camera index), merged and fused together and unrolled from all of them.
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from nail2nail._progress import Stages
from nail2nail._timing import StepClock
from nail2nail.calibration.files import load_calibration
from nail2nail.frames import frame_transform
from nail2nail.io._atomic import atomic_directory, check_output_directory, relocate_paths
from nail2nail.io._json import write_json
from nail2nail.io.capture import projector_captures, read_capture
from nail2nail.io.rolled import ROLLED_LENGTH_MM, write_rolled_print
from nail2nail.io.scans import save_scans
from nail2nail.merge.correspondence import check_pair_by
from nail2nail.merge.report import parse_pairs, write_merge
from nail2nail.scan.capture import MAX_GRADIENT, motion_summary, scan_capture
from nail2nail.unroll import DEFAULT_METHOD, METHODS, check_print_size, unroll_scans

__all__ = ["calibration_files", "peak_rss_mb", "process_capture"]


def peak_rss_mb() -> float | None:
    """Peak resident memory of this process so far, MB (``None`` where not measurable).

    ``ru_maxrss`` is in kilobytes on Linux, bytes on macOS; Windows has no ``resource``.
    """
    try:
        import resource
    except ImportError:  # pragma: no cover - Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (2**20 if sys.platform == "darwin" else 2**10)


def process_capture(
    capture,
    calibration,
    out: str | os.PathLike,
    *,
    use: str = "xpyp",
    max_gradient: float | None = MAX_GRADIENT,
    min_modulation: float = 0.03,
    allow_mirrored: bool = False,
    pairs=None,
    pair_by: str = "auto",
    figures: bool = False,
    mat5: bool = False,
    ply: bool = False,
    seamless_mesh: bool = False,
    unroll: bool = True,
    method: str | None = None,
    ppi: float = 500.0,
    tip_direction=None,
    length_mm: float | None = ROLLED_LENGTH_MM,
    ridge_options: dict | None = None,
    wsq: bool = True,
    progress: bool = False,
    calibration_name: str = "calibration",
    frame: str = "world",
    masks=None,
    decode_options: dict | None = None,
) -> dict:
    """Scan, merge, fuse and unroll one capture; write everything under `out`.

    Parameters
    ----------
    capture : Capture or path-like
        A capture (:func:`nail2nail.io.capture.read_capture`, ``load=False`` saves memory) or
        its directory; or the directory of a capture of several projectors
        (``projectors.json``).
    calibration : RigCalibration or path-like, or a sequence of them
        The rig's calibration, or its JSON file. For a capture of several projectors, one per
        projector in ``projectors.json``'s order, or one path ``DIR/NAME.json`` standing for
        ``DIR/NAME_<capture>.json`` of each (what ``nail2nail calibrate`` writes).
    out : path-like
        Output directory, replaced as a whole once the job is complete; a non-empty directory
        without ``process.json`` is refused before any work.
    use, max_gradient, min_modulation, allow_mirrored
        Scanning options (:func:`nail2nail.scan.capture.scan_capture`).
    pairs : list of (int, int) or str, optional
        Camera pairs of the merge report, as scan indices or as ``"0-1,1-2"``
        (:func:`nail2nail.merge.parse_pairs`); default the neighbours, ``0-1, 1-2, …`` (with
        several projectors, the neighbouring cameras of each projector and the neighbouring
        projectors of each camera).
    pair_by : {"auto", "xpyp", "xp", "yp"}
        What pairs two cameras' pixels in the merge (:func:`nail2nail.merge.correspond`).
    figures : bool
        Write the merge figures (off by default: the job's own output is the data).
    mat5 : bool
        Also write the legacy mat5 sets: each camera's into ``OUT/scans``, the super mat5 into
        ``OUT/merge`` (about 95 MB each for three 1280 × 1024 cameras).
    ply : bool
        Also write each camera's PLY point cloud into ``OUT/scans`` (the super scan's
        ``OUT/merge/super.ply`` is always written).
    seamless_mesh : bool
        Mesh ``OUT/merge/super.ply`` as one seamless surface
        (:func:`nail2nail.merge.write_merge`'s `seamless_mesh`; about 10 s more for a
        full-resolution finger).
    unroll : bool
        Unroll the finger into the rolled-equivalent print (``OUT/print``).
    method, ppi, tip_direction, length_mm, wsq
        Unroll options (:func:`nail2nail.unroll.unroll_scans`, `length_mm` None: all the
        skin that was seen;
        :func:`nail2nail.io.rolled.write_rolled_print`); `method` defaults to
        :data:`nail2nail.unroll.DEFAULT_METHOD`.
    ridge_options : dict, optional
        ``mix`` and ``min_clarity`` of :func:`nail2nail.unroll.unroll_scans` (the ridge
        signal's blend and the clarity mask); their defaults otherwise.
    progress : bool
        One line per stage and progress bars (scan, merge) on stderr; a terminal only, and
        not inside :func:`nail2nail._progress.quiet`.
    calibration_name : str
        How errors name the calibration (its file, when given as an object).
    frame : str
        Frame of the points written (``OUT/scans``, the super scan in ``OUT/merge``):
        ``"world"`` or a camera's name (:func:`nail2nail.frames.frame_transform`); everything
        is computed in the world frame. Recorded with ``T_frame_world`` in ``process.json``.
    masks : mapping of str to (H, W) bool array or path-like, optional
        User validity masks by camera (:func:`nail2nail.scan.capture.scan_capture`).
    decode_options : dict, optional
        Further decoder thresholds (``min_albedo``, ``saturation``, ``unwrap_tolerance``,
        ``erode`` …: :func:`nail2nail.scan.decoding.decode`), recorded in ``process.json``.

    Returns
    -------
    dict
        The content of ``OUT/process.json``: ``{"capture", "calibration", "out", "options",
        "seconds": {stage: s, …, "total"}, "scan_seconds": {"read_frames", "decode", "motion"},
        "merge_seconds": {"correspond", "fuse", "write", "figures"},
        "peak_rss_mb", "cameras": {name: valid pixels}, "merge": {pair: statistics},
        "super_scan", "print"}``. Stages: ``scan`` (reading the frames, decoding,
        triangulating; ``scan_seconds`` splits it), ``write_scans``, ``merge``
        (correspondence, super scan and their files; ``merge_seconds`` splits it),
        ``unroll``, ``write_print``.

    Raises
    ------
    ValueError
        Bad input, naming the file (the capture, the calibration) and the problem; `out`
        holds its earlier content then.
    """

    method = DEFAULT_METHOD if method is None else method
    if unroll and method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    check_print_size(ppi, length_mm)  # the unroll's bounds, before the scan and merge run
    check_pair_by(pair_by)
    out = check_output_directory(out, marker="process.json")
    times = StepClock()

    say = Stages(enabled=progress, prefix="process: ")  # stderr, a terminal only, not quiet

    layout = (projector_captures(capture) if isinstance(capture, (str, os.PathLike))
              else None)
    captures: list[tuple[str | None, Any]]
    calibrations: list[tuple[str, Any]]
    if layout is None:
        captures = [(None, capture)]
        calibrations = [(calibration_name, calibration)]
    else:
        captures = list(layout)
        calibrations = _projector_calibrations(calibration, [n for n, _ in layout], capture)
    loaded: list[tuple[str, Any]] = []
    for name, calib in calibrations:
        if isinstance(calib, (str, os.PathLike)):
            name, calib = str(calib), load_calibration(calib, allow_mirrored=allow_mirrored)
        loaded.append((name, calib))
    transform = frame_transform(loaded[0][1], frame)  # the cameras are the projectors' own

    say("scan")
    scan_parts: dict[str, float] = {}
    scans, projectors, cameras = [], [], []
    camera_index: dict[str, int] = {}
    with times.stage("scan"):
        for k, ((_, source), (name, calib)) in enumerate(zip(captures, loaded, strict=True)):
            opened = (read_capture(source, load=False)
                      if isinstance(source, (str, os.PathLike)) else source)
            parts: dict[str, float] = {}
            mine = scan_capture(opened, calib, use=use, max_gradient=max_gradient,
                                min_modulation=min_modulation, allow_mirrored=allow_mirrored,
                                calibration_name=name, timings=parts, masks=masks,
                                progress=progress, **(decode_options or {}))
            for key, value in parts.items():
                scan_parts[key] = scan_parts.get(key, 0.0) + value
            for scan in mine:  # cameras matched by name across the projectors
                cameras.append(camera_index.setdefault(str(scan.name), len(camera_index)))
                projectors.append(k)
                scans.append(scan if layout is None
                             else replace(scan, name=f"{scan.name}-p{k}"))
    capture_path = capture if layout is not None else opened.path
    several = layout is not None
    if len(scans) < 2:
        raise ValueError(f"{capture_path}: need at least two cameras to merge, got "
                         f"{len(scans)}")
    if isinstance(pairs, str):
        pairs = parse_pairs(pairs, len(scans))
    elif pairs is None and not several:
        pairs = parse_pairs(None, len(scans))
    summary: dict = {
        "capture": str(capture_path),
        "calibration": loaded[0][0] if not several else [n for n, _ in loaded],
        **({"projectors": [n for n, _ in captures]} if several else {}),
        "out": str(out),
        "frame": frame,
        "T_frame_world": transform.tolist(),
        "options": {"use": use, "max_gradient": max_gradient, "min_modulation": min_modulation,
                    **(decode_options or {}),
                    "masks": {k: (str(v) if isinstance(v, (str, os.PathLike)) else "array")
                              for k, v in (masks or {}).items()},
                    "pair_by": pair_by, "figures": figures, "unroll": unroll,
                    **({"method": method, "ppi": ppi, "length_mm": length_mm,
                        **(ridge_options or {})} if unroll else {})},
        "cameras": {s.name: int(s.mask.sum()) for s in scans},
        "motion": motion_summary(scans),
    }
    with atomic_directory(out, marker="process.json") as tmp:
        say("write the scans")
        with times.stage("write_scans"):
            save_scans(tmp / "scans", scans, mat5=mat5, ply=ply,
                       extra={"capture": str(capture_path),
                              "calibration": summary["calibration"]},
                       frame=frame, transform=transform,
                       projectors=projectors if several else None,
                       cameras=cameras if several else None)
        say("merge and fuse the super scan")
        with times.stage("merge"):
            merged = write_merge(scans, tmp / "merge", pairs=pairs, pair_by=pair_by,
                                 figures=figures,
                                 super_scan=True, mat5=mat5, frame=frame,
                                 seamless_mesh=seamless_mesh,
                                 transform=transform, progress=progress,
                                 final_dir=out / "merge",  # the job directory once renamed
                                 projectors=projectors if several else None,
                                 cameras=cameras if several else None)
        summary["merge"] = {key: {k: v[k] for k in ("kind", "pair_by", "pairs", "distance_mm",
                                                 "rejected")
                                  if k in v}
                            for key, v in merged["merge"].items()}
        summary["super_scan"] = {k: v for k, v in merged["super_scan"].items()
                                 if k != "files"}
        if unroll:

            say(f"unroll ({method})")
            with times.stage("unroll"):
                rolled = unroll_scans(scans, method=method, ppi=ppi,
                                      tip_direction=tip_direction, length_mm=length_mm,
                                      **(ridge_options or {}))
            del scans  # the print alone from here on
            with times.stage("write_print"):
                meta = write_rolled_print(tmp / "print", rolled, wsq=wsq)
            summary["print"] = {k: meta[k] for k in ("method", "shape", "ppi", "print_size_mm",
                                                       "print_area_mm2", "files") if k in meta}
        summary["seconds"] = times.rounded()
        summary["scan_seconds"] = {k: round(v, 3) for k, v in scan_parts.items()}
        summary["merge_seconds"] = merged["seconds"]
        summary["peak_rss_mb"] = _round(peak_rss_mb())
        summary = relocate_paths(summary, str(tmp), str(out))
        write_json(tmp / "process.json", summary)
    say(f"done in {summary['seconds']['total']:.2f} s -> {out}")
    return summary


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 1)


def calibration_files(calibration: str | os.PathLike, capture: str | os.PathLike) -> list[Path]:
    """The calibration file(s) that `calibration` names for `capture`.

    Parameters
    ----------
    calibration : path-like
        A calibration file ``DIR/STEM.SUFFIX``.
    capture : path-like
        A capture directory, or a capture of several projectors (``projectors.json``).

    Returns
    -------
    list of Path
        ``[calibration]`` for a capture of one projector; for a capture of several,
        ``DIR/STEM_<capture>.SUFFIX`` of each projector, in ``projectors.json``'s order (what
        ``nail2nail calibrate`` and ``calibrate-board`` write).

    Raises
    ------
    ValueError
        Naming the file that is missing (and what `calibration` stands for), or a bad
        ``projectors.json``.
    """
    path = Path(calibration)
    layout = projector_captures(capture)
    if layout is None:
        if not path.is_file():
            raise ValueError(f"{path}: calibration file not found")
        return [path]
    names = [n for n, _ in layout]
    files = [path.with_name(f"{path.stem}_{n}{path.suffix or '.json'}") for n in names]
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise ValueError(f"{capture}: a capture of {len(names)} projectors ({', '.join(names)}) "
                         f"is scanned with one calibration per projector; {missing[0]} not "
                         f"found (--calib {path} stands for {', '.join(f.name for f in files)}, "
                         "as `nail2nail calibrate` writes them)")
    return files


def _projector_calibrations(calibration, names: list[str], capture) -> list[tuple[str, Any]]:
    """``[(name for errors, RigCalibration or path)]`` per projector of a capture of several:
    a sequence as given, or a path ``DIR/STEM.SUFFIX`` for ``DIR/STEM_<name>.SUFFIX`` each."""
    if isinstance(calibration, (str, os.PathLike)):
        return [(str(f), f) for f in calibration_files(calibration, capture)]
    if isinstance(calibration, (list, tuple)):
        if len(calibration) != len(names):
            raise ValueError(f"calibration: {len(calibration)} given for a capture of "
                             f"{len(names)} projectors ({', '.join(names)})")
        return [(str(c) if isinstance(c, (str, os.PathLike)) else f"calibration of {n}", c)
                for n, c in zip(names, calibration, strict=True)]
    raise ValueError(f"{capture}: a capture of {len(names)} projectors needs one calibration "
                     "per projector (a list, or the path of rig.json standing for "
                     "rig_<capture>.json)")
