"""The report's first section: did this scan work, in a few numbers.

Valid pixels per camera, the merge error per pair against the thesis's 0.05 mm, the super
scan's size, the print's size and ridge clarity, the time of every stage and the peak memory
(``process``), and what the report looked for and did not find.
"""

from __future__ import annotations

from nail2nail.io._json import read_json
from nail2nail.report._html import Section, escape, note_html, table_html
from nail2nail.report.inputs import ReportInputs
from nail2nail.report.merge import above_threshold
from nail2nail.report.prints import MIN_CLARITY

__all__ = ["section"]


def _kpi(value: str, label: str) -> str:
    return f'<div class="kpi"><b>{escape(value)}</b><span>{escape(label)}</span></div>'


def section(inputs: ReportInputs) -> Section:
    """The overview section (``id="overview"``)."""
    summary, kpis, warnings = inputs.summary, [], []
    if inputs.scans is not None:
        for cam in read_json(inputs.scans / "scan.json").get("cameras", []):
            h, w = cam["shape"]
            share = 100 * cam["valid_pixels"] / (h * w)
            kpis.append(_kpi(f"{cam['valid_pixels']:,}",
                             f"{cam['name']}: valid pixels ({share:.0f}% of the image)"))
    if inputs.merge is not None:
        merged = read_json(inputs.merge / "merge.json")
        for key, m in merged.get("merge", {}).items():
            median = m["distance_mm"].get("median")
            if median is None:  # no matched pixels: no statistics
                kpis.append(_kpi("—", f"merge {key}: no matched pixels"))
                warnings.append(f"merge {key}: no matched pixels")
                continue
            kpis.append(_kpi(f"{1e3 * median:.1f} µm", f"merge {key}: median error"))
            if above_threshold(m["distance_mm"]):
                warnings.append(f"merge {key}: median error {1e3 * median:.0f} µm")
        sup = merged.get("super_scan")
        if sup:
            kpis.append(_kpi(f"{sup['vertices']:,}", "super scan vertices"))
    if inputs.print is not None:
        meta = read_json(inputs.print / "print.json")
        kpis.append(_kpi(f"{meta['shape'][1]} × {meta['shape'][0]}",
                         f"print px at {meta['ppi']:g} ppi"))
        clarity = meta.get("quality", {}).get("clarity_median")
        if clarity is not None:
            kpis.append(_kpi(f"{clarity:.2f}", "print ridge clarity (median, 1 = clean)"))
            if clarity < MIN_CLARITY:
                warnings.append(f"print ridge clarity {clarity:.2f}")
    seconds = summary.get("seconds") if inputs.kind == "process" else None
    if seconds:
        kpis.append(_kpi(f"{seconds.get('total', sum(seconds.values())):.1f} s", "whole job"))
    if summary.get("peak_rss_mb"):
        kpis.append(_kpi(f"{summary['peak_rss_mb']:.0f} MB", "peak memory"))
    parts = ["<div>" + "".join(kpis) + "</div>"]
    if warnings:
        parts.append(note_html("Look at: " + "; ".join(warnings) + ".", "warn"))
    rows = [[k, v] for k, v in (("capture", inputs.capture), ("calibration", inputs.calibration),
                               ("scans", inputs.scans), ("merge", inputs.merge),
                               ("print", inputs.print)) if v is not None]
    parts.append(table_html([[k, str(v)] for k, v in rows], ["part", "read from"]))
    if seconds:
        parts.append(table_html([[k, f"{v:.2f}"] for k, v in seconds.items()],
                                ["stage", "seconds"], caption="Wall time per stage"))
    options = summary.get("options")
    if options:
        parts.append(table_html([[k, str(v)] for k, v in options.items()], ["option", "value"],
                                caption="Options of the job"))
    parts.extend(note_html(n, "missing") for n in inputs.notes)
    status = "warn" if warnings or inputs.notes else "ok"
    return Section("overview", "Overview", "".join(parts), status=status)
