"""The report's projector distortion section: the radial model's estimate and its effect.

From ``projector_distortion.json`` (``demo``'s ``distortion/``: the non-linear fit with its
standard deviations and RMS, the thesis method beside it) or else the calibration's
``projector_distortion`` ``{center, rho}``. The figure draws a regular panel grid as the
projector shows it under the radial model (thesis eq. 3.15–3.16,
:mod:`nail2nail.calibration.distortion`)
and the LUT-corrected grid, the displacement magnified; a second plot gives the radial
displacement against the radius from the optical centre.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from nail2nail.calibration.distortion import grid_from_decoded, ideal_from_panel
from nail2nail.io._json import read_json
from nail2nail.io.capture import read_capture
from nail2nail.report._html import Section, figure_html, image_html, note_html, table_html
from nail2nail.report._parts import number, numbers, quoted, reading
from nail2nail.report._plot import fmt, new_figure
from nail2nail.report.inputs import ReportInputs, projector_panel
from nail2nail.scan.decoding import decode
from nail2nail.scan.patterns import PatternSet

__all__ = ["section"]

ID, TITLE = "distortion", "Projector distortion"

#: Grid spacing of the figure, panel px.
SPACING = 64


def _estimate(inputs: ReportInputs) -> tuple[dict | None, str]:
    """``({"center", "rho", …}, source)`` of the distortion estimate, or ``(None, why)``."""

    if inputs.distortion is not None:
        with reading(inputs.distortion):
            data = read_json(inputs.distortion)
            if "center_px" in data and "rho" in data:
                return _checked({**data, "center": data["center_px"]},
                                "center_px"), str(inputs.distortion)
    if inputs.calibration is not None:
        with reading(inputs.calibration):
            dist = read_json(inputs.calibration).get("projector_distortion")
            if isinstance(dist, dict) and {"center", "rho"} <= set(dist):
                return (_checked(dist, "projector_distortion.center", "projector_distortion."),
                        f"{inputs.calibration} (projector_distortion)")
    return None, ("No projector distortion: no distortion/projector_distortion.json and no "
                  "projector_distortion in the calibration.")


def _checked(est: dict, center_key: str, prefix: str = "") -> dict:
    """`est` with its numbers checked (``ValueError`` naming the key of one that is not)."""
    for key, values in ((center_key, numbers(est["center"], center_key, 2)),
                        (f"{prefix}rho", [number(est["rho"], f"{prefix}rho")])):
        if not all(v is not None and np.isfinite(v) for v in values):
            raise ValueError(f"{key}: expected finite numbers, got {quoted(values)}")
    std = est.get("center_std_px")
    if std is not None:
        numbers(std, "center_std_px", 2)
    for key in ("rho_std", "rms_px"):
        number(est.get(key), key)
    thesis = est.get("thesis")
    if isinstance(thesis, dict) and "center_px" in thesis:
        numbers(thesis["center_px"], "thesis.center_px", 2)
        number(thesis.get("rho"), "thesis.rho")
    return est


def section(inputs: ReportInputs) -> Section:
    """The projector distortion section of the report of `inputs`."""
    est, source = _estimate(inputs)
    if est is None:
        return Section(ID, TITLE, note_html(source, "missing"), status="missing")
    center, rho = np.asarray(est["center"], float), float(est["rho"])
    std = est.get("center_std_px") or [None, None]
    rows = [["non-linear fit" if "center_px" in est else "calibration model",
             fmt(center[0], ".2f"), fmt(center[1], ".2f"), f"{rho:.6f}",
             fmt(std[0], ".3f"), fmt(std[1], ".3f"), fmt(est.get("rho_std"), ".2e"),
             fmt(est.get("rms_px"), ".3f")]]
    thesis = est.get("thesis")
    if isinstance(thesis, dict) and "center_px" in thesis:
        rows.append(["thesis method", fmt(thesis["center_px"][0], ".2f"),
                     fmt(thesis["center_px"][1], ".2f"), fmt(thesis.get("rho"), ".6f"),
                     "—", "—", "—", "—"])
    body = [note_html(source),
            table_html(rows, ["estimate", "centre x px", "centre y px", "ρ", "std x px",
                              "std y px", "std ρ", "fit RMS px"]),
            _grid_figure(center, rho, projector_panel(inputs))]
    plane = inputs.root / "captures" / "plane"
    if (plane / "capture.json").is_file():
        body.append(_plane_grids(plane, est.get("primary_camera"), center, rho))
    return Section(ID, TITLE, "".join(body))


def _plane_grids(plane, camera: str | None, center: np.ndarray, rho: float) -> str:
    """The thesis's Figures 19 and 20 drawn from the decoded plane capture (one camera):
    the plain grid as projected, and the grid of the ideal coordinates (LUT-corrected)."""

    try:
        capture = read_capture(plane, load=False)
        names = capture.camera_names
        name = camera if camera in names else names[len(names) // 2]
        decoded = decode(capture.load_frames(name, raw=True), cast(PatternSet, capture.pattern_set),
                         full_scale=2**capture.bit_depth - 1, method="numba")
    except (ValueError, TypeError) as exc:
        return note_html(f"{plane}: the plane capture cannot be decoded ({exc}).", "warn")
    if decoded.xp is None or decoded.yp is None:
        return ""
    assert capture.pattern_set is not None  # decode refused a capture without one
    panel = capture.pattern_set.panel_size
    images = [grid_from_decoded(decoded.xp, decoded.yp, decoded.mask, panel_size=panel,
                                spacing=SPACING, background=decoded.albedo),
              grid_from_decoded(decoded.xp, decoded.yp, decoded.mask, panel_size=panel,
                                spacing=SPACING, background=decoded.albedo, center=center,
                                rho=rho)]
    return ('<div class="row">'
            + image_html(images[0], f"{name}: the plain {SPACING}-px grid on the plane, from "
                                    "the decoded coordinates (thesis Figure 19)", max_size=400)
            + image_html(images[1], f"{name}: the LUT-corrected grid (ideal coordinates of the "
                                    "estimate; thesis Figure 20)", max_size=400)
            + "</div>")


def _grid_figure(center: np.ndarray, rho: float, panel: tuple[int, int]) -> str:
    """A panel grid (`panel` ``(W, H)`` px) as shown under the radial model, and corrected;
    radial displacement."""

    width, height = panel
    fig = new_figure(9.0, 3.6)
    grid_ax, radial_ax = fig.subplots(1, 2, width_ratios=[1.6, 1])
    # where the rays of panel grid points land, in ideal (pinhole) coordinates
    xs = np.arange(width // 2 % SPACING, width, SPACING, dtype=float)
    ys = np.arange(height // 2 % SPACING, height, SPACING, dtype=float)
    corners = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [-0.5, height - 0.5],
                        [width - 0.5, height - 0.5]])
    biggest = np.nanmax(np.hypot(*(ideal_from_panel(corners, center, rho) - corners).T))
    gain = max(1.0, round(0.05 * width / biggest)) if biggest > 0 else 1.0
    lines = [np.column_stack([np.full(100, x), np.linspace(-0.5, height - 0.5, 100)])
             for x in xs]
    lines += [np.column_stack([np.linspace(-0.5, width - 0.5, 100), np.full(100, y)])
              for y in ys]
    for i, line in enumerate(lines):
        shown = line + gain * (ideal_from_panel(line, center, rho) - line)
        grid_ax.plot(*shown.T, color="#d62728", lw=0.8, label="plain patterns" if i == 0 else None)
        grid_ax.plot(*line.T, color="#2a62c9", lw=0.6, ls="--",
                     label="LUT-corrected" if i == 0 else None)
    grid_ax.plot(*center, "k+", ms=10, mew=2, label="optical centre")
    grid_ax.set_xlim(-0.1 * width, 1.1 * width)
    grid_ax.set_ylim(1.1 * height, -0.1 * height)
    grid_ax.set_aspect("equal")
    grid_ax.legend(fontsize=7, loc="lower right")
    grid_ax.set_title(f"{SPACING}-px panel grid, displacement × {gain:g}", fontsize=10)
    r = np.linspace(0, np.hypot(*np.max(np.abs(corners - center), axis=0)), 200)
    shift = np.hypot(*(ideal_from_panel(center + np.column_stack([r, 0 * r]), center, rho)
                       - center).T) - r
    radial_ax.plot(r, shift, color="#d62728")
    radial_ax.set_xlabel("radius from the centre, panel px")
    radial_ax.set_ylabel("radial displacement px")
    radial_ax.grid(alpha=0.3)
    return figure_html(fig, f"Left: a regular grid of the panel (every {SPACING} px) where a "
                            f"pinhole projector would put it under the radial model (red, plain "
                            f"patterns; displacement magnified {gain:g}×) and with the "
                            "look-up-table correction (blue, the ideal grid); + the optical "
                            "centre. Right: displacement ρ³ r³ against the radius r "
                            "(eq. 3.34).")
