"""The report's print section: the rolled-equivalent print and its geometric figures.

From the print directory (``print.json``, ``nail2nail unroll`` / ``process``): the print and
its binarised version, the size, area and resolution, the unrolling's distortion (length and
area scale), the ridge clarity per block and each camera's coverage of the print, with the
quality and coverage maps; for the demo also the comparison with the virtual finger's true
print and of the unrolling methods.
"""

from __future__ import annotations

from pathlib import Path

from nail2nail.io._json import read_json
from nail2nail.report._html import Section, image_html, note_html, table_html
from nail2nail.report._parts import CorruptPart, number, numbers, quoted, reading
from nail2nail.report._plot import fmt, percent
from nail2nail.report.inputs import ReportInputs

__all__ = ["MIN_CLARITY", "section"]

#: Median ridge clarity below which the print gets a warning (clean ridges ~0.9, noise ~0.1).
MIN_CLARITY = 0.5


def _stats(d: dict, key: str, scale: float = 100.0, unit: str = "%") -> str:
    return ", ".join(f"{k} {fmt(scale * v, '.2f')}{unit}" for k, v in d.items()
                     if number(v, f"{key}.{k}") is not None)


def _geometry_rows(meta: dict) -> list[list]:
    height, width = numbers(meta["shape"], "shape", 2, integer=True)
    ppi = number(meta["ppi"], "ppi")
    pitch = number(meta.get("pitch_mm"), "pitch_mm")
    if pitch is None and ppi:
        pitch = 25.4 / ppi
    rows = [["method", str(meta.get("method", ""))],
            ["size", f"{width:.0f} × {height:.0f} px at {fmt(ppi, 'g')} ppi "
                     f"({fmt(None if pitch is None else pitch * 1e3, '.1f')} µm per px)"]]
    if "print_size_mm" in meta:
        w, h = numbers(meta["print_size_mm"], "print_size_mm", 2)
        rows.append(["finger extent", f"{fmt(w, '.2f')} × {fmt(h, '.2f')} mm"])
    if "print_area_mm2" in meta:
        area = number(meta["print_area_mm2"], "print_area_mm2")
        rows.append(["print area", f"{fmt(area, '.1f')} mm²"])
    cyl = meta.get("flattening", {}).get("cylinder")
    if cyl:
        radius = number(cyl["radius_mm"], "flattening.cylinder.radius_mm")
        rows.append(["finger cylinder radius", f"{fmt(radius, '.2f')} mm"])
    dist = meta.get("distortion", {})
    if "length" in dist:
        rows.append(["length distortion |s − 1|", _stats(dist["length"], "distortion.length")])
    if "area" in dist:
        rows.append(["area distortion |a − 1|", _stats(dist["area"], "distortion.area")])
    q = meta.get("quality", {})
    if q:
        median = number(q.get("clarity_median"), "quality.clarity_median")
        p10 = number(q.get("clarity_p10"), "quality.clarity_p10")
        blocks = number(q.get("blocks", 0), "quality.blocks", integer=True)
        rows.append(["ridge clarity (median, p10)",
                     f"{fmt(median)}, {fmt(p10)} over {fmt(blocks, '.0f')} blocks"])
        period = number(q.get("ridge_period_mm_median"), "quality.ridge_period_mm_median")
        if period is not None:
            rows.append(["ridge period (median)", f"{fmt(1e3 * period, '.0f')} µm"])
    if "wsq_compression_ratio" in meta:
        ratio = number(meta["wsq_compression_ratio"], "wsq_compression_ratio")
        rows.append(["WSQ compression", f"{fmt(ratio, '.1f')} : 1"])
    return rows


def _methods(inputs: ReportInputs) -> str:
    assert inputs.print is not None  # the section is drawn only when there is a print
    path = inputs.print / "methods.json"
    if not path.is_file():
        return ""
    try:
        with reading(path):
            rows = _method_rows(read_json(path))
    except CorruptPart as exc:  # the rest of the print section without this table
        inputs.problems.append((exc.path, exc.reason))
        return ""
    if not rows:
        return ""
    return "<h3>Unrolling methods against the virtual finger's true print (demo)</h3>" + \
        table_html(rows, ["method", "displacement median µm", "displacement p95 µm",
                          "scale error median %", "ridge period ratio"])


def _method_cell(d: dict, key: str, factor: float, spec: str, where: str) -> str:
    if key not in d:
        return ""
    value = number(d[key], f"{where}.{key}")
    return fmt(None if value is None else factor * value, spec)


def _method_rows(methods: dict) -> list[list]:
    methods = methods.get("methods", methods)
    rows = []
    for name, m in methods.items():
        if not isinstance(m, dict):
            continue
        disp = m.get("displacement_mm", {})
        scale = m.get("scale_error", {})
        period = m.get("period_ratio", {})
        rows.append([name,
                     _method_cell(disp, "median", 1e3, ".0f", f"{name}.displacement_mm"),
                     _method_cell(disp, "p95", 1e3, ".0f", f"{name}.displacement_mm"),
                     _method_cell(scale, "median", 100, ".2f", f"{name}.scale_error"),
                     _method_cell(period, "median_ratio", 1, ".3f", f"{name}.period_ratio")])
    return rows


def section(inputs: ReportInputs) -> Section:
    """The print section of the report (``id="print"``)."""
    if inputs.print is None:
        return Section("print", "Print", note_html(
            f"No rolled-equivalent print under {inputs.root} (print/print.json: `nail2nail "
            "unroll`, or `process` without --no-unroll).", "missing"), status="missing")
    path = inputs.print / "print.json"
    with reading(path):
        meta = read_json(path)
        files = {k: _print_file(inputs.print, k, v) for k, v in meta.get("files", {}).items()}
        status, parts = "ok", []
        clarity = number(meta.get("quality", {}).get("clarity_median"), "quality.clarity_median")
        if clarity is not None and clarity < MIN_CLARITY:
            status = "warn"
            parts.append(note_html(f"Median ridge clarity {clarity:.2f} is below {MIN_CLARITY}: "
                                   "the ridges are faint or blurred on much of the print.",
                                   "warn"))
        geometry = table_html(_geometry_rows(meta), ["", "value"],
                              caption="Geometry and quality of the print (print.json)")
        coverage = meta.get("coverage", {})
        coverage_rows = [[name, percent(number(c.get("contributes_fraction"),
                                               f"coverage.{name}.contributes_fraction")),
                          percent(number(c.get("dominant_fraction"),
                                         f"coverage.{name}.dominant_fraction"))]
                         for name, c in coverage.items()]
    images = [(files.get("print"), "rolled-equivalent print (legacy: mirror of the pad seen "
               "from outside, tip up, ridges dark)"),
              (files.get("binary"), "binarised print")]
    parts.append('<div class="row">' + "".join(
        _image(inputs, p, caption, max_size=900, width=420) for p, caption in images
        if p is not None and p.is_file()) + "</div>")
    parts.append(geometry)
    if coverage_rows:
        parts.append(table_html(
            coverage_rows,
            ["camera", "% of the print it contributes to", "% where it dominates"],
            caption="Each camera's coverage of the print"))
    maps = [(files.get("quality"), "ridge clarity per block"),
            (files.get("coverage"), "coverage by camera"),
            (inputs.print / "print_vs_truth.png", "print against the virtual finger's truth"),
            (inputs.print / "distortion_maps.png", "distortion maps of the unrolling")]
    shown = [_image(inputs, p, caption, max_size=700) for p, caption in maps
             if p is not None and p.is_file()]
    if shown:
        parts.append("<h3>Maps</h3><div class=\"row\">" + "".join(shown) + "</div>")
    parts.append(_methods(inputs))
    return Section("print", "Print", "".join(parts), status=status)


def _print_file(directory: Path, key: str, name) -> Path:
    """A file named in ``print.json``'s ``files``: a plain name inside the print directory."""
    if not isinstance(name, str) or not name or Path(name).name != name or name in (".", ".."):
        raise ValueError(f"files.{key}: expected a file name in {directory}, got {quoted(name)}")
    return directory / name


def _image(inputs: ReportInputs, path: Path, caption: str, **kwargs) -> str:
    """An embedded image, or nothing (and the problem noted) when the file is not one."""
    try:
        with reading(path):
            return image_html(path, caption, **kwargs)
    except CorruptPart as exc:
        inputs.problems.append((exc.path, exc.reason))
        return ""
