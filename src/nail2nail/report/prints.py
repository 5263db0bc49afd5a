"""The report's print section: the rolled-equivalent print and its geometric figures.

From the print directory (``print.json``, ``nail2nail unroll`` / ``process``): the print and
its binarised version, the size, area and resolution, the unrolling's distortion (length and
area scale), the ridge clarity per block and each camera's coverage of the print, with the
quality and coverage maps; for the demo also the comparison with the virtual finger's true
print and of the unrolling methods.
"""

from __future__ import annotations

from nail2nail.io._json import read_json
from nail2nail.report._html import Section, image_html, note_html, table_html
from nail2nail.report._plot import fmt, percent
from nail2nail.report.inputs import ReportInputs

__all__ = ["MIN_CLARITY", "section"]

#: Median ridge clarity below which the print gets a warning (clean ridges ~0.9, noise ~0.1).
MIN_CLARITY = 0.5


def _stats(d: dict, scale: float = 100.0, unit: str = "%") -> str:
    return ", ".join(f"{k} {scale * v:.2f}{unit}" for k, v in d.items()
                     if isinstance(v, (int, float)))


def _geometry_rows(meta: dict) -> list[list]:
    rows = [["method", meta.get("method", "")],
            ["size", f"{meta['shape'][1]} × {meta['shape'][0]} px at {meta['ppi']:g} ppi "
                     f"({meta.get('pitch_mm', 25.4 / meta['ppi']) * 1e3:.1f} µm per px)"]]
    if "print_size_mm" in meta:
        w, h = meta["print_size_mm"]
        rows.append(["finger extent", f"{w:.2f} × {h:.2f} mm"])
    if "print_area_mm2" in meta:
        rows.append(["print area", f"{meta['print_area_mm2']:.1f} mm²"])
    cyl = meta.get("flattening", {}).get("cylinder")
    if cyl:
        rows.append(["finger cylinder radius", f"{cyl['radius_mm']:.2f} mm"])
    dist = meta.get("distortion", {})
    if "length" in dist:
        rows.append(["length distortion |s − 1|", _stats(dist["length"])])
    if "area" in dist:
        rows.append(["area distortion |a − 1|", _stats(dist["area"])])
    q = meta.get("quality", {})
    if q:
        rows.append(["ridge clarity (median, p10)",
                     f"{fmt(q.get('clarity_median'))}, {fmt(q.get('clarity_p10'))} over "
                     f"{q.get('blocks', 0)} blocks"])
        period = q.get("ridge_period_mm_median")
        if period is not None:
            rows.append(["ridge period (median)", f"{fmt(1e3 * period, '.0f')} µm"])
    if "wsq_compression_ratio" in meta:
        rows.append(["WSQ compression", f"{meta['wsq_compression_ratio']:.1f} : 1"])
    return rows


def _methods(inputs: ReportInputs) -> str:
    assert inputs.print is not None  # the section is drawn only when there is a print
    path = inputs.print / "methods.json"
    if not path.is_file():
        return ""
    methods = read_json(path)
    methods = methods.get("methods", methods)
    rows = []
    for name, m in methods.items():
        if not isinstance(m, dict):
            continue
        disp = m.get("displacement_mm", {})
        scale = m.get("scale_error", {})
        period = m.get("period_ratio", {})
        rows.append([name, f"{1e3 * disp['median']:.0f}" if "median" in disp else "",
                     f"{1e3 * disp['p95']:.0f}" if "p95" in disp else "",
                     f"{100 * scale['median']:.2f}" if "median" in scale else "",
                     f"{period['median_ratio']:.3f}" if "median_ratio" in period else ""])
    if not rows:
        return ""
    return "<h3>Unrolling methods against the virtual finger's true print (demo)</h3>" + \
        table_html(rows, ["method", "displacement median µm", "displacement p95 µm",
                          "scale error median %", "ridge period ratio"])


def section(inputs: ReportInputs) -> Section:
    """The print section of the report (``id="print"``)."""
    if inputs.print is None:
        return Section("print", "Print", note_html(
            f"No rolled-equivalent print under {inputs.root} (print/print.json: `nail2nail "
            "unroll`, or `process` without --no-unroll).", "missing"), status="missing")
    meta = read_json(inputs.print / "print.json")
    files = {k: inputs.print / v for k, v in meta.get("files", {}).items()}
    status, parts = "ok", []
    clarity = meta.get("quality", {}).get("clarity_median")
    if clarity is not None and clarity < MIN_CLARITY:
        status = "warn"
        parts.append(note_html(f"Median ridge clarity {clarity:.2f} is below {MIN_CLARITY}: "
                               "the ridges are faint or blurred on much of the print.", "warn"))
    images = [(files.get("print"), "rolled-equivalent print (legacy: mirror of the pad seen "
               "from outside, tip up, ridges dark)"),
              (files.get("binary"), "binarised print")]
    parts.append('<div class="row">' + "".join(
        image_html(p, caption, max_size=900, width=420) for p, caption in images
        if p is not None and p.is_file()) + "</div>")
    parts.append(table_html(_geometry_rows(meta), ["", "value"],
                            caption="Geometry and quality of the print (print.json)"))
    coverage = meta.get("coverage", {})
    if coverage:
        parts.append(table_html(
            [[name, percent(c.get("contributes_fraction")), percent(c.get("dominant_fraction"))]
             for name, c in coverage.items()],
            ["camera", "% of the print it contributes to", "% where it dominates"],
            caption="Each camera's coverage of the print"))
    maps = [(files.get("quality"), "ridge clarity per block"),
            (files.get("coverage"), "coverage by camera"),
            (inputs.print / "print_vs_truth.png", "print against the virtual finger's truth"),
            (inputs.print / "distortion_maps.png", "distortion maps of the unrolling")]
    shown = [image_html(p, caption, max_size=700) for p, caption in maps
             if p is not None and p.is_file()]
    if shown:
        parts.append("<h3>Maps</h3><div class=\"row\">" + "".join(shown) + "</div>")
    parts.append(_methods(inputs))
    return Section("print", "Print", "".join(parts), status=status)
