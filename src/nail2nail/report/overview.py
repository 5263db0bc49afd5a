"""The report's first section: did this scan work, in a few numbers.

Valid pixels per camera, the merge error per pair against the thesis's 0.05 mm, the super
scan's size, the print's size and ridge clarity, the time of every stage and the peak memory
(``process``), and what the report looked for and did not find.
"""

from __future__ import annotations

from nail2nail.io._json import read_json
from nail2nail.report._html import Section, escape, note_html, table_html
from nail2nail.report._parts import CorruptPart, number, numbers, quoted, reading
from nail2nail.report._plot import fmt
from nail2nail.report.inputs import ReportInputs
from nail2nail.report.merge import above_threshold
from nail2nail.report.prints import MIN_CLARITY

__all__ = ["section"]


def _kpi(value: str, label: str) -> str:
    return f'<div class="kpi"><b>{escape(value)}</b><span>{escape(label)}</span></div>'


def _scan_kpis(inputs: ReportInputs, kpis: list) -> None:
    assert inputs.scans is not None
    with reading(inputs.scans / "scan.json"):
        for cam in read_json(inputs.scans / "scan.json").get("cameras", []):
            h, w = numbers(cam["shape"], "cameras[].shape", 2, integer=True)
            valid = number(cam["valid_pixels"], "cameras[].valid_pixels", integer=True)
            share = 100 * valid / (h * w) if valid is not None and h and w else None
            kpis.append(_kpi(fmt(int(valid)) if valid is not None else "—",
                             f"{cam['name']}: valid pixels ({fmt(share, '.0f')}% of the image)"))


def _merge_kpis(inputs: ReportInputs, kpis: list, warnings: list) -> None:
    assert inputs.merge is not None
    with reading(inputs.merge / "merge.json"):
        merged = read_json(inputs.merge / "merge.json")
        for key, m in merged.get("merge", {}).items():
            median = number(m["distance_mm"].get("median"), f"merge.{key}.distance_mm.median")
            if median is None:  # no matched pixels: no statistics
                kpis.append(_kpi("—", f"merge {key}: no matched pixels"))
                warnings.append(f"merge {key}: no matched pixels")
                continue
            kpis.append(_kpi(f"{fmt(1e3 * median, '.1f')} µm", f"merge {key}: median error"))
            if above_threshold(m["distance_mm"]):
                warnings.append(f"merge {key}: median error {1e3 * median:.0f} µm")
        sup = merged.get("super_scan")
        if sup:
            vertices = number(sup["vertices"], "super_scan.vertices", integer=True)
            kpis.append(_kpi(fmt(None if vertices is None else int(vertices)),
                             "super scan vertices"))


def _print_kpis(inputs: ReportInputs, kpis: list, warnings: list) -> None:
    assert inputs.print is not None
    with reading(inputs.print / "print.json"):
        meta = read_json(inputs.print / "print.json")
        h, w = numbers(meta["shape"], "shape", 2, integer=True)
        ppi = number(meta["ppi"], "ppi")
        kpis.append(_kpi(f"{fmt(w, '.0f')} × {fmt(h, '.0f')}",
                         f"print px at {fmt(ppi, 'g')} ppi"))
        clarity = number(meta.get("quality", {}).get("clarity_median"), "quality.clarity_median")
        if clarity is not None:
            kpis.append(_kpi(fmt(clarity, ".2f"), "print ridge clarity (median, 1 = clean)"))
            if clarity < MIN_CLARITY:
                warnings.append(f"print ridge clarity {clarity:.2f}")


def section(inputs: ReportInputs) -> Section:
    """The overview section (``id="overview"``); a part that cannot be read leaves out its
    figures (the section's notes name it)."""
    summary = inputs.summary
    kpis: list[str] = []
    warnings: list[str] = []
    for part, kpi in ((inputs.scans, lambda: _scan_kpis(inputs, kpis)),
                      (inputs.merge, lambda: _merge_kpis(inputs, kpis, warnings)),
                      (inputs.print, lambda: _print_kpis(inputs, kpis, warnings))):
        if part is not None:
            try:
                kpi()
            except CorruptPart as exc:
                inputs.problems.append((exc.path, exc.reason))
    seconds, options = None, None
    try:  # the summary's figures; without them when it holds values of the wrong kind
        with reading(inputs.summary_path or inputs.root):
            given = summary.get("seconds") if inputs.kind == "process" else None
            if given:
                seconds = {str(k): number(v, f"seconds.{k}") for k, v in given.items()}
                total = seconds.get("total", sum(v for v in seconds.values() if v is not None))
                kpis.append(_kpi(f"{fmt(total, '.1f')} s", "whole job"))
            peak = number(summary.get("peak_rss_mb"), "peak_rss_mb")
            if peak:
                kpis.append(_kpi(f"{fmt(peak, '.0f')} MB", "peak memory"))
            options = summary.get("options")
            if options and not isinstance(options, dict):
                raise ValueError(f"options: expected an object, got {quoted(options)}")
    except CorruptPart as exc:
        inputs.problems.append((exc.path, exc.reason))
        seconds, options = None, None
    parts = ["<div>" + "".join(kpis) + "</div>"]
    if warnings:
        parts.append(note_html("Look at: " + "; ".join(warnings) + ".", "warn"))
    rows = [[k, v] for k, v in (("capture", inputs.capture), ("calibration", inputs.calibration),
                               ("scans", inputs.scans), ("merge", inputs.merge),
                               ("print", inputs.print)) if v is not None]
    parts.append(table_html([[k, str(v)] for k, v in rows], ["part", "read from"]))
    if seconds:
        parts.append(table_html([[k, fmt(v, ".2f")] for k, v in seconds.items()],
                                ["stage", "seconds"], caption="Wall time per stage"))
    if options:
        parts.append(table_html([[k, str(v)] for k, v in options.items()], ["option", "value"],
                                caption="Options of the job"))
    parts.extend(note_html(n, "missing") for n in inputs.notes)
    status = "warn" if warnings or inputs.notes else "ok"
    return Section("overview", "Overview", "".join(parts), status=status)
