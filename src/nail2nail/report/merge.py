"""The report's merge section: the merge error per camera pair (thesis chapter four).

Per pair: the statistics of ``merge.json`` (pairs kept, distance median … max in µm, the share
below the thesis's 0.05 mm, the pairs rejected and why), a heat map of the error over the
parent camera's image and its histogram, drawn from the pair's mapping file
(``merge_P-C_mapping.npz``) where it was written, else the PNG figures the merge wrote. Then
the super scan's bookkeeping (vertices, each camera's share, points removed) and, for the
demo, the comparison of calibration configurations.
"""

from __future__ import annotations

import numpy as np

from nail2nail.io._json import read_json
from nail2nail.report._html import Section, escape, figure_html, image_html, note_html, table_html
from nail2nail.report._parts import CorruptPart, number, quoted, reading
from nail2nail.report._plot import fmt, percent
from nail2nail.report.inputs import ReportInputs

__all__ = ["THRESHOLD_MM", "above_threshold", "section"]

#: The thesis's threshold on the merge error (0.05 mm, chapter four).
THRESHOLD_MM = 0.05


def _um(value_mm, key: str = "distance_mm") -> str:
    value = number(value_mm, key)
    return "—" if value is None else fmt(1e3 * value, ".2f")


def _count(value, key: str) -> str:
    return fmt(number(value, key, integer=True), ".0f")


def above_threshold(distance_mm: dict) -> bool:
    """Whether a pair's median merge error is above the thesis's threshold (``False`` when
    the pair had no matches: its statistics are ``null``)."""
    median = number(distance_mm.get("median"), "distance_mm.median")
    return median is not None and median > THRESHOLD_MM


#: What paired two cameras' pixels (``merge.json`` → ``pair_by``), as the table says it.
PAIRINGS = {"xpyp": "xp, yp", "xp": "xp + surface", "yp": "yp + surface",
            "pixel": "same pixel"}


def _pair_rows(merge: dict) -> list[list]:
    rows = []
    for key, m in merge.items():
        d = m["distance_mm"]
        rejected = m.get("rejected", {})
        where = f"merge.{key}.distance_mm"
        pair_by = m.get("pair_by", "xpyp")  # merges written before it: the thesis's pairing
        if pair_by not in PAIRINGS:
            raise ValueError(f"merge.{key}.pair_by: expected one of {', '.join(PAIRINGS)}, got "
                             f"{quoted(pair_by)}")
        rows.append([
            key, m.get("parent", ""), m.get("child", ""), PAIRINGS[pair_by],
            f"{number(m['pairs'], f'merge.{key}.pairs', integer=True):,.0f}",
            *(_um(d[k] if k in ("median", "mean", "p95", "max") else d.get(k), f"{where}.{k}")
              for k in ("median", "mean", "rms", "p90", "p95", "max")),
            percent(number(d.get("frac_below_0_05"), f"{where}.frac_below_0_05"), ".2f"),
            ", ".join(f"{k} {v}" for k, v in rejected.items() if v) or "none",
        ])
    return rows


def _heatmap_figure(mapping_path, key: str, parent: str, child: str):
    """Heat map of the error over the parent image and its histogram (one figure)."""
    from matplotlib.figure import Figure

    with np.load(mapping_path, allow_pickle=False) as data:
        shape = data["mapping"].shape[:2]
        rc = np.asarray(data["parent_rc"])
        error = data["distance_mm"].astype(float) * 1e3
    if (rc.ndim != 2 or rc.shape[1:] != (2,) or len(rc) != len(error)
            or not np.issubdtype(rc.dtype, np.integer)):
        raise ValueError("parent_rc: expected (n, 2) pixel indices, one per distance_mm")
    if len(rc) and (rc.min() < 0 or np.any(rc.max(axis=0) >= shape)):
        raise ValueError(f"parent_rc: pixel indices outside the {shape} image")
    image = np.full(shape, np.nan)
    image[rc[:, 0], rc[:, 1]] = error
    error = error[np.isfinite(error)]  # a NaN is a hole in the map, not a histogram entry
    top = float(np.percentile(error, 99)) if error.size else 1.0
    fig = Figure(figsize=(10, 4.2), dpi=90)
    ax, hist = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.1, 1]})
    # the finger's rows and columns only: the rest of the image is background
    rows, cols = np.nonzero(np.isfinite(image))
    if rows.size:
        image = image[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
        extent = (cols.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5, rows.min() - 0.5)
    else:
        extent = None
    shown = ax.imshow(image, cmap="viridis", vmin=0, vmax=top, interpolation="nearest",
                      extent=extent)
    fig.colorbar(shown, ax=ax, label="merge error (µm)", shrink=0.85)
    ax.set_title(f"{key}: error over {parent}'s image (px)", fontsize=10)
    ax.set_xlabel("column")
    ax.set_ylabel("row")
    if error.size:
        hist.hist(error, bins=80, range=(0, max(top, 1e-3)), color="#3b528b")
        for value, label, style in ((np.median(error), "median", "-"),
                                    (np.percentile(error, 95), "p95", "--")):
            hist.axvline(value, color="#d62728", ls=style, lw=1,
                         label=f"{label} {value:.1f} µm")
        hist.legend(fontsize=8)
    hist.set_xlabel("merge error (µm)")
    hist.set_ylabel("pairs")
    hist.set_title(f"{key}: {error.size:,} pairs ({parent} → {child})", fontsize=10)
    fig.tight_layout()
    return fig


def _super_scan(info: dict) -> str:
    cams = info.get("cameras", {})
    rejected = info.get("points_rejected", {})
    dups = info.get("duplicates_removed", {})
    where = "super_scan.cameras"
    rows = [[name, _count(c.get("owned", 0), f"{where}.{name}.owned"),
             _count(c.get("fused", 0), f"{where}.{name}.fused"),
             _count(dups.get(name, 0), f"super_scan.duplicates_removed.{name}"),
             ", ".join(f"{k} {v}" for k, v in rejected.get(name, {}).items()) or "none"]
            for name, c in cams.items()]
    priority = " > ".join(map(str, info.get("priority", [])))
    head = (f"<p>{_count(info.get('vertices', 0), 'super_scan.vertices')} vertices, "
            f"{_count(info.get('faces', 0), 'super_scan.faces')} triangles; "
            f"priority {escape(priority)}; frame {escape(str(info.get('frame', 'world')))}.</p>")
    return head + table_html(rows, ["camera", "points owned", "fused with a partner",
                                    "duplicates removed", "points rejected"],
                             caption="Each camera's share of the super scan")


def _comparison(summary: dict) -> str:
    comparison = summary.get("comparison") or {}
    rows = []
    for config, objects in comparison.items():
        for obj, pairs in objects.items():
            for key, m in pairs.items():
                d = m["distance_mm"]
                rows.append([config, obj, key, _count(m["pairs"], f"comparison.{key}.pairs"),
                             _um(d["median"]), _um(d["p95"]), _um(d["max"]),
                             percent(d.get("frac_below_0_05"), ".1f")])
    if not rows:
        return ""
    return "<h3>Calibration configurations compared (demo)</h3>" + table_html(
        rows, ["configuration", "object", "pair", "pairs", "median µm", "p95 µm", "max µm",
               "% < 50 µm"],
        caption="The merge error of every configuration the demo ran (README, issue 5)")


def section(inputs: ReportInputs) -> Section:
    """The merge section of the report."""
    if inputs.merge is None:
        return Section("merge", "Merge", note_html(
            f"No merge: no merge.json under {inputs.root} (nail2nail merge or process "
            "writes it).", "missing"), status="missing")
    path = inputs.merge / "merge.json"
    with reading(path):
        summary = read_json(path)
        merge = summary.get("merge", {})
        status = "ok"
        parts = []
        worst = [k for k, m in merge.items() if above_threshold(m["distance_mm"])]
        if worst:
            status = "warn"
            parts.append(note_html(
                f"Median merge error above the thesis's {1e3 * THRESHOLD_MM:.0f} µm for "
                f"{', '.join(worst)}: the cameras disagree (calibration, distortion or motion).",
                "warn"))
        parts.append(table_html(
            _pair_rows(merge),
            ["pair", "parent", "child", "paired by", "pairs", "median µm", "mean µm", "RMS µm",
             "p90 µm", "p95 µm", "max µm", "% < 50 µm", "rejected"],
            caption="Merge error per camera pair: 3D distance between a parent pixel's point "
            "and the child's point at the same projector coordinates (thesis chapter four); "
            "paired by one coordinate (scans triangulated from it), at the child's point of "
            "that coordinate nearest the parent's"))
        for key in merge:
            if not isinstance(key, str) or not key or set(key) & set("/\\:") or ".." in key:
                raise ValueError(f"merge: a camera pair named {quoted(key)}, not a plain name")
        super_scan = (["<h3>Super scan</h3>" + _super_scan(summary["super_scan"])]
                      if "super_scan" in summary else [])
    for key, m in merge.items():
        parts.append(_pair_figures(inputs, key, m))
    parts += super_scan
    if inputs.kind == "demo":
        with reading(inputs.summary_path or inputs.root):
            parts.append(_comparison(inputs.summary))
    return Section("merge", "Merge", "".join(parts), status=status)


def _pair_figures(inputs: ReportInputs, key: str, m: dict) -> str:
    """The heat map and histogram of a pair, from its mapping file, else its PNG figures;
    nothing (the problem noted) when the file cannot be read."""
    assert inputs.merge is not None
    mapping = inputs.merge / f"merge_{key}_mapping.npz"
    try:
        if mapping.is_file():
            with reading(mapping):
                return figure_html(_heatmap_figure(mapping, key, str(m.get("parent", "parent")),
                                                   str(m.get("child", "child"))))
        shown = []
        for p in (inputs.merge / f"merge_{key}_{kind}.png" for kind in ("heatmap", "histogram")):
            if p.is_file():
                with reading(p):
                    shown.append(image_html(p, p.name, max_size=640))
    except CorruptPart as exc:
        inputs.problems.append((exc.path, exc.reason))
        return ""
    return ('<div class="row">' + "".join(shown) + "</div>" if shown else note_html(
        f"{key}: neither the mapping file nor the figures were written.", "missing"))
