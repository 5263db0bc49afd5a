"""The report's capture section: frame thumbnails, decode quality maps and coverage per camera.

Three parts:

* **Frames**: up to six evenly spaced frames of every camera, as thumbnails labelled with the
  frame index and what the pattern set projects in it (``nail2nail.scan.patterns.frame_table``).
* **Decode quality**: every camera's fringe amplitude (modulation) map with its threshold, and
  a map of why each pixel is or is not in the scan: valid; outside the user's mask; decoded but
  rejected by the decoder's checks (saturation, unwrapping, outside the panel, edge, steep, no
  3D point); fringe amplitude below ``min_modulation``; no signal (mean intensity below
  ``min_albedo``). With the capture at hand its frames are decoded again
  (:func:`nail2nail.scan.decoding.decode`, the fused kernel, the scan's options: about a second per
  full-resolution camera) for the decoder's exact per-pixel reasons; otherwise the classes are
  derived from the scan's stored arrays, and the caption says so.
* **Coverage**: valid pixels per camera (of the image and of its lit pixels) and each camera's
  share of the super scan (``merge.json``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from nail2nail.io._json import read_json
from nail2nail.io.capture import read_capture, read_frame
from nail2nail.io.masks import read_mask
from nail2nail.io.scans import load_scans
from nail2nail.report._html import Section, escape, figure_html, image_html, note_html, table_html
from nail2nail.report._parts import CorruptPart, number, quoted, reading
from nail2nail.report._plot import decimate, extent, fmt, new_figure
from nail2nail.report.inputs import ReportInputs
from nail2nail.scan.capture import MAX_GRADIENT, MIN_KEPT_FRACTION, kept_fraction
from nail2nail.scan.inputs import DECODE_DEFAULTS
from nail2nail.scan.patterns import frame_labels
from nail2nail.scan.results import LOW_MODULATION as LOW_MODULATION_BIT
from nail2nail.scan.results import REASON_NAMES, Reason
from nail2nail.scan.results import SHADOW as SHADOW_BIT

__all__ = ["section"]

ID, TITLE = "capture", "Capture"

#: Thumbnails per camera (evenly spaced over its frames) and their longest side, px.
N_THUMBNAILS = 6
THUMBNAIL_PX = 200
#: Longest side of a map as drawn (decimated by an integer stride), px.
MAP_PX = 320

#: Pixel classes of the validity map, in priority order (a pixel takes the first that holds).
CLASSES = ("valid", "outside the user mask", "decoded, rejected by the checks",
           "below the modulation threshold", "no signal")
COLORS = ("#2ca02c", "#9467bd", "#d62728", "#ff9f1c", "#d9d9d9")
VALID, USER_MASK, REJECTED, LOW_MODULATION, NO_SIGNAL = range(5)


def section(inputs: ReportInputs) -> Section:
    """The capture section of the report of `inputs`.

    Parameters
    ----------
    inputs : ReportInputs
        The output directory's parts: ``inputs.capture`` (frames; decoded again for the
        per-pixel reasons), ``inputs.scans`` (the quality maps and coverage),
        ``inputs.merge`` (the super scan's share per camera).

    Returns
    -------
    Section
        ``status`` ``"missing"`` when neither the capture nor the scans are there, ``"warn"``
        when a camera keeps few of its lit pixels (less than
        :data:`nail2nail.scan.capture.MIN_KEPT_FRACTION`) or the capture cannot be read.
    """

    options = _scan_options(inputs)
    status, body = "ok", []
    capture, capture_note = _open_capture(inputs)
    if capture is None and inputs.scans is None:
        looked = capture_note or "no capture"
        return Section(ID, TITLE, note_html(
            f"No capture and no scans: {looked}; no scans/scan.json either.", "missing"),
            status="missing")
    body.append("<h3>Frames</h3>")
    if capture is None:
        body.append(note_html(capture_note, "missing"))
    else:
        body.append(_thumbnails(capture, inputs.problems))
    if inputs.scans is None:
        body.append(note_html(f"No scans: {inputs.root / 'scans' / 'scan.json'} not found; no "
                              "decode quality maps or coverage.", "missing"))
        return Section(ID, TITLE, "".join(body), status=status)
    with reading(inputs.scans / "scan.json"):
        scans = load_scans(inputs.scans, frame="stored")
        classes, counts, exact = _pixel_classes(scans, options)
        body.append("<h3>Decode quality</h3>")
        body.append(_modulation_figure(scans, options["min_modulation"]))
        body.append(_validity_figure(scans, classes, options, exact))
    if counts is not None:
        body.append(_reason_table(scans, counts))
    body.append("<h3>Coverage</h3>")
    coverage, warnings = _coverage(scans, inputs, options["min_modulation"])
    body.append(coverage)
    motion, moving = _motion(scans)
    if motion:
        body.append("<h3>Motion</h3>")
        body.append(motion)
        warnings += moving
    if capture is not None and capture_note:  # readable manifest, unreadable frames
        warnings.insert(0, capture_note)
    if warnings:
        status = "warn"
        body[1:1] = [note_html(w, "warn") for w in warnings]
    return Section(ID, TITLE, "".join(body), status=status)


# ------------------------------------------------------------------------------------------------
# Inputs
# ------------------------------------------------------------------------------------------------
def _scan_options(inputs: ReportInputs) -> dict:
    """The decoder's options the scans were made with: ``process.json``'s ``options``, else
    the defaults of :func:`nail2nail.scan.capture.scan_capture` (what ``demo`` and ``scan`` use
    unless told otherwise)."""
    options: dict[str, Any] = {**DECODE_DEFAULTS, "max_gradient": MAX_GRADIENT, "masks": {}}
    given = inputs.summary.get("options") if inputs.kind == "process" else None
    if isinstance(given, dict):
        try:  # values of the wrong kind: the defaults, and a note
            with reading(inputs.summary_path or inputs.root):
                for k in (*DECODE_DEFAULTS, "max_gradient"):
                    if k in given:
                        number(given[k], f"options.{k}")
                if not isinstance(given.get("masks", {}), (dict, type(None))):
                    raise ValueError(f"options.masks: expected an object, got "
                                     f"{quoted(given['masks'])}")
        except CorruptPart as exc:
            inputs.problems.append((exc.path, exc.reason))
        else:
            options.update({k: given[k] for k in (*DECODE_DEFAULTS, "max_gradient", "masks")
                            if k in given})
    if options["min_modulation"] is None:
        options["min_modulation"] = 0.0
    return options


def _open_capture(inputs: ReportInputs):
    """``(Capture or None, note)``: the capture read without its frames, or why not."""

    if inputs.capture is None:
        named = inputs.summary.get("capture")
        if inputs.kind == "demo":
            where = inputs.root / "captures" / "finger" / "capture.json"
            return None, f"No capture: {where} not found."
        if named:
            return None, (f"No capture: {named}/capture.json, named in the summary, is not "
                          "there any more; frames not shown, maps from the stored scans.")
        return None, "No capture: the summary names none (capture.json)."
    try:
        with reading(inputs.capture / "capture.json"):
            return read_capture(inputs.capture, load=False), ""
    except CorruptPart as exc:
        inputs.problems.append((exc.path, exc.reason))
        return None, f"The capture cannot be read: {exc}"


def _frame_labels(capture) -> list[str]:
    """What every frame shows, from the capture's pattern set (or its pattern files)."""

    n_frames = len(capture.manifest["cameras"][0]["frames"])
    if capture.pattern_set is None:
        files = (capture.manifest.get("patterns") or {}).get("files") or []
        return [str(f) for f in files] if len(files) == n_frames else [""] * n_frames
    labels = frame_labels(capture.pattern_set)
    return labels if len(labels) == n_frames else [""] * n_frames


def _thumbnails(capture, problems: list) -> str:
    """Up to :data:`N_THUMBNAILS` evenly spaced frames of every camera; a frame that cannot
    be read is a note (and a problem in `problems`)."""

    labels = _frame_labels(capture)
    bit_depth = capture.bit_depth
    rows = []
    for cam in capture.manifest["cameras"]:
        files = cam["frames"]
        picks = np.unique(np.linspace(0, len(files) - 1, min(N_THUMBNAILS, len(files)))
                          .round().astype(int))
        figures = []
        for i in picks:
            try:
                with reading(capture.path / files[i]):
                    values = read_frame(capture.path / files[i], bit_depth=bit_depth, raw=True)
            except CorruptPart as exc:
                problems.append((exc.path, exc.reason))
                figures.append(note_html(str(exc), "warn"))
                continue
            if bit_depth > 8:  # right-aligned values: their top 8 bits
                values = (values >> (bit_depth - 8)).astype(np.uint8)
            caption = f"frame {i}" + (f" · {labels[i]}" if labels[i] else "")
            figures.append(image_html(decimate(values, 2 * THUMBNAIL_PX), caption,
                                      max_size=THUMBNAIL_PX))
        rows.append(f"<p><b>{escape(cam['name'])}</b> ({len(files)} frames, {bit_depth}-bit)"
                    f"</p><div class=\"row\">{''.join(figures)}</div>")
    return "".join(rows)


# ------------------------------------------------------------------------------------------------
# Decode quality
# ------------------------------------------------------------------------------------------------
def _user_masks(scans, options) -> dict:
    """The user masks the scans were cut with, by camera (files that are still there)."""

    masks = {}
    for scan in scans:
        path = (options.get("masks") or {}).get(scan.name)
        if path and path != "array":
            try:
                masks[scan.name] = read_mask(path, shape=scan.shape)
            except (ValueError, OSError):
                pass
    return masks


def _pixel_classes(scans, options):
    """Per camera, the validity class of every pixel (:data:`CLASSES`).

    Returns
    -------
    classes : dict of str to (H, W) uint8
    counts : dict of str to dict, or None
        Pixels per :class:`~nail2nail.scan.results.Reason` bit and ``"outside the user
        mask"``, when every scan carries its reasons (``Scan.reason``, stored by the scan).
    exact : bool
        Whether the classes come from the scans' reasons (else from the stored arrays, for
        scan files that do not store them).
    """
    exact = all(scan.reason is not None for scan in scans)
    masks = {} if exact else _user_masks(scans, options)
    classes, counts = {}, {} if exact else None
    for scan in scans:
        valid = np.asarray(scan.mask, bool)
        out = np.full(scan.shape, REJECTED, np.uint8)
        if exact:
            reason = scan.reason
            out[reason & LOW_MODULATION_BIT != 0] = LOW_MODULATION
            out[reason & SHADOW_BIT != 0] = NO_SIGNAL
            cut = (reason == 0) & ~valid  # kept by the decoder and the triangulation
            counts[scan.name] = {
                **{REASON_NAMES[bit]: int(np.count_nonzero(reason & bit)) for bit in Reason},
                "outside the user mask": int(np.count_nonzero(cut)),
            }
        else:  # from the stored arrays: the decoder's first two checks, the rest lumped
            user = masks.get(scan.name)
            modulation = np.nan_to_num(scan.modulation, nan=0.0)
            out[modulation < options["min_modulation"]] = LOW_MODULATION
            out[~(np.nan_to_num(scan.albedo, nan=0.0) >= options["min_albedo"])] = NO_SIGNAL
            cut = (out == REJECTED) & ~user if user is not None else None
        if cut is not None and np.any(cut):
            out[cut] = USER_MASK
        out[valid] = VALID
        classes[scan.name] = out
    return classes, counts, exact


def _map_axes(fig, n: int):
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    return axes


def _modulation_figure(scans, threshold: float) -> str:
    """Fringe amplitude maps, one colour scale for all cameras, the threshold on the bar."""
    fig = new_figure(2.4 * len(scans) + 1.0, 3.6)
    axes = _map_axes(fig, len(scans))
    shown = [decimate(np.nan_to_num(s.modulation, nan=0.0), MAP_PX) for s in scans]
    top = max(float(np.percentile(np.concatenate([m.ravel() for m in shown]), 99.5)),
              2 * threshold, 1e-3)
    for ax, scan, image in zip(axes, scans, shown, strict=True):
        im = ax.imshow(image, cmap="viridis", vmin=0, vmax=top, extent=extent(scan.shape),
                       interpolation="nearest")
        ax.set_title(scan.name, fontsize=10)
    bar = fig.colorbar(im, ax=list(axes), shrink=0.85)
    bar.set_label("fringe amplitude B (full scale 1)", fontsize=9)
    bar.ax.axhline(threshold, color="#d62728", lw=2)
    return figure_html(fig, f"Modulation: the finest fringe's amplitude B per camera pixel; the "
                            f"red line on the colour bar is the threshold min_modulation = "
                            f"{threshold:g}.")


def _validity_figure(scans, classes: dict, options: dict, exact: bool) -> str:
    """Map of the validity class of every pixel, with a legend."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    fig = new_figure(2.4 * len(scans) + 0.4, 4.0)
    axes = _map_axes(fig, len(scans))
    cmap = ListedColormap(COLORS)
    for ax, scan in zip(axes, scans, strict=True):
        ax.imshow(decimate(classes[scan.name], MAP_PX), cmap=cmap, vmin=-0.5,
                  vmax=len(COLORS) - 0.5, extent=extent(scan.shape), interpolation="nearest")
        ax.set_title(scan.name, fontsize=10)
    fig.legend([Patch(color=c) for c in COLORS], CLASSES, loc="outside lower center", ncol=3,
               fontsize=8, frameon=False)
    how = ("from the decoder's per-pixel reasons, stored with the scans" if exact else
           f"derived from the stored arrays (the scan files do not store the reasons): no "
           f"signal = mean intensity below min_albedo {options['min_albedo']:g}, below the "
           f"threshold = amplitude below "
           f"min_modulation {options['min_modulation']:g}; the decoder's other rejections "
           "(saturation, unwrapping, outside the panel, edge, steep, no 3D point) are not told "
           "apart")
    return figure_html(fig, f"Validity: why each pixel is in the scan or not, {how}.")


def _reason_table(scans, counts: dict) -> str:
    names = [*REASON_NAMES.values(), "outside the user mask"]
    rows = [[name, *(fmt(counts[s.name][name]) for s in scans)] for name in names]
    return table_html(rows, ["decoder reason", *(s.name for s in scans)],
                      caption="Pixels per decoder reason (a pixel can have several).")


# ------------------------------------------------------------------------------------------------
# Coverage
# ------------------------------------------------------------------------------------------------
def _super_scan_cameras(inputs: ReportInputs) -> dict:
    """``merge.json``'s ``super_scan.cameras`` (``{name: {"owned", "fused"}}``), or {}."""

    if inputs.merge is None:
        return {}
    try:
        with reading(inputs.merge / "merge.json"):
            cams = read_json(inputs.merge / "merge.json").get("super_scan", {}).get("cameras", {})
            if not isinstance(cams, dict):
                raise ValueError(f"super_scan.cameras: expected an object, got {quoted(cams)}")
            for name, c in cams.items():
                for k in ("owned", "fused"):
                    number(c.get(k), f"super_scan.cameras.{name}.{k}", integer=True)
    except CorruptPart as exc:  # the coverage without the super scan's shares
        inputs.problems.append((exc.path, exc.reason))
        return {}
    return cams


def _coverage(scans, inputs: ReportInputs, min_modulation: float) -> tuple[str, list[str]]:
    """The coverage table and bar chart; warnings for cameras that keep few lit pixels."""

    share = _super_scan_cameras(inputs)
    owned_total = sum(int(c.get("owned", 0)) for c in share.values() if isinstance(c, dict))
    rows, warnings, stats = [], [], []
    for scan in scans:
        valid, lit = kept_fraction(scan, min_modulation)
        n_pixels = scan.mask.size
        cam: dict = share[scan.name] if isinstance(share.get(scan.name), dict) else {}
        owned = cam.get("owned")
        part = 100 * owned / owned_total if owned is not None and owned_total else None
        stats.append((scan.name, valid, lit, part))
        rows.append([scan.name, f"{scan.shape[1]} × {scan.shape[0]}", fmt(lit), fmt(valid),
                     fmt(100 * valid / n_pixels, ".1f"),
                     fmt(100 * valid / lit if lit else None, ".1f"),
                     fmt(owned), fmt(part, ".1f"), fmt(cam.get("fused"))])
        if valid == 0 or (lit and valid < MIN_KEPT_FRACTION * lit):
            warnings.append(f"Camera {scan.name} keeps {valid} of its {lit} lit pixels "
                            f"({100 * valid / max(lit, 1):.1f} %, less than "
                            f"{100 * MIN_KEPT_FRACTION:.0f} %): look at its validity map.")
    header = ["camera", "image (W × H)", "lit pixels", "valid pixels", "% of image",
              "% of lit", "super-scan points", "share of super scan %", "fused"]
    caption = (f"Lit: fringe amplitude ≥ min_modulation {min_modulation:g}. Super scan "
               "(merge.json): the points each camera contributes (owned) and of them those "
               "fused with another camera's." if share else
               f"Lit: fringe amplitude ≥ min_modulation {min_modulation:g}. No merge.json: no "
               "super-scan shares.")
    return table_html(rows, header, caption=caption) + _coverage_figure(stats), warnings


def _number(value) -> float | None:
    """A finite number from a JSON value, else None (scan.json may be edited by hand)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if np.isfinite(value) else None


def _motion(scans) -> tuple[str, list[str]]:
    """The motion the frames show per camera (``scan.json`` → ``motion``), and warnings."""
    rows, warnings = [], []
    for scan in scans:
        m = scan.motion if isinstance(scan.motion, dict) else None
        if not m or "motion_mm" not in m:
            continue
        mm = _number(m.get("motion_mm"))
        shifts = []
        groups = m.get("groups")
        for g in groups if isinstance(groups, list) else []:
            xy = g.get("shift_px") if isinstance(g, dict) else None
            if isinstance(xy, list) and len(xy) == 2:
                shifts.append(f"{g.get('label')}: ({fmt(_number(xy[0]), '.2f')}, "
                              f"{fmt(_number(xy[1]), '.2f')})")
        comp = m.get("compensation")
        comp_groups = comp.get("groups") if isinstance(comp, dict) else None
        comp_groups = comp_groups if isinstance(comp_groups, list) else []
        comp_text = ", ".join(f"{g.get('label')} {fmt(_number(g.get('offset_rms_rad')), '.3f')}"
                              " rad" for g in comp_groups if isinstance(g, dict)) or "—"
        threshold = _number(m.get("threshold_mm"))
        moving = mm is not None and threshold is not None and mm > threshold
        rows.append([scan.name, fmt(None if mm is None else 1000 * mm, ".1f"),
                     fmt(_number(m.get("max_spread_px")), ".2f"), ", ".join(shifts) or "—",
                     comp_text, "moving" if moving else "still"])
        if moving:
            assert mm is not None and threshold is not None
            warnings.append(f"Camera {scan.name} saw the finger move by {1000 * mm:.0f} µm "
                            f"during the capture (above {1000 * threshold:.0f} µm): its scan "
                            "carries errors of about that size.")
    if not rows:
        return "", []
    header = ["camera", "motion µm", "largest spread px", "groups' shifts (dx, dy) px",
              "compensated (offsets' RMS)", "verdict"]
    caption = ("Each phase-shift group's mean frame (the scene without fringes) registered "
               "against the first group's; the motion is the largest distance between two "
               "groups' shifts, over the image or any of 3 × 3 regions (docs/motion.md).")
    return table_html(rows, header, caption=caption), warnings


def _coverage_figure(stats) -> str:
    names = [s[0] for s in stats]
    x = np.arange(len(names))
    has_share = any(s[3] is not None for s in stats)
    fig = new_figure(7.0 if has_share else 4.0, 2.8)
    axes = fig.subplots(1, 2 if has_share else 1, squeeze=False)[0]
    ax = axes[0]
    ax.bar(x - 0.2, [s[2] for s in stats], 0.4, label="lit", color="#9ecae1")
    ax.bar(x + 0.2, [s[1] for s in stats], 0.4, label="valid", color="#2ca02c")
    ax.set_xticks(x, names)
    ax.set_ylabel("pixels")
    ax.legend(fontsize=8)
    ax.set_title("pixels per camera", fontsize=10)
    if has_share:
        ax = axes[1]
        ax.bar(x, [s[3] or 0 for s in stats], 0.6, color="#2a62c9")
        ax.set_xticks(x, names)
        ax.set_ylabel("%")
        ax.set_title("share of the super scan", fontsize=10)
    return figure_html(fig, "Coverage per camera.")
