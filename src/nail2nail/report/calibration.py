"""The report's calibration section: per-camera geometry and reprojection residuals.

The geometry of every camera and of the projector (focal lengths, principal point, image size,
lens distortion, optical centre in the world, triangulation angle, baseline) from the
calibration JSON; the camera and projector reprojection residuals of the points tables
``{stem}_points_{camera}.tsv`` that ``nail2nail calibrate`` (and ``demo``) write beside it.
"""

from __future__ import annotations

import numpy as np

from nail2nail.calibration.camera_models import Pinhole, pinhole_from_dlt, project_dlt
from nail2nail.calibration.files import load_calibration
from nail2nail.io.points import read_points
from nail2nail.report._html import Section, figure_html, note_html, table_html
from nail2nail.report._parts import CorruptPart, reading
from nail2nail.report._plot import fmt, new_figure
from nail2nail.report.inputs import ReportInputs, projector_panel
from nail2nail.scan.triangulation import _panel_of_points

__all__ = ["section"]

ID, TITLE = "calibration", "Calibration"


def _pinhole(model, size):
    """A :class:`~nail2nail.calibration.camera_models.Pinhole` of a pinhole or DLT model."""

    return model if isinstance(model, Pinhole) else pinhole_from_dlt(model, size=size)


def _axis(model) -> np.ndarray:
    """Optical axis (3,) of a pinhole model in the world frame (its camera frame's z)."""
    return model.R[2]


def _geometry_table(calib, panel: tuple[int, int]) -> str:
    rows = []
    for cam in calib.cameras:
        camera = _pinhole(cam.camera, cam.size or (1024, 1280))
        projector = _pinhole(cam.projector, panel)
        angle = np.degrees(np.arccos(np.clip(_axis(camera) @ _axis(projector), -1, 1)))
        baseline = np.linalg.norm(camera.center - projector.center)
        for what, m in ((cam.name, camera), (f"{cam.name}: projector", projector)):
            rows.append([what, fmt(m.K[0, 0], ".1f"), fmt(m.K[1, 1], ".1f"),
                         f"({m.K[0, 2]:.1f}, {m.K[1, 2]:.1f})", f"{m.size[0]} × {m.size[1]}",
                         ", ".join(f"{v:.3g}" for v in m.dist),
                         "(" + ", ".join(f"{v:.1f}" for v in m.center) + ")",
                         fmt(np.linalg.norm(m.center), ".1f"), fmt(angle, ".2f"),
                         fmt(baseline, ".1f")])
    return table_html(rows, ["model", "fx px", "fy px", "principal point px", "size",
                             "k1, k2, p1, p2, k3", "centre (world mm)", "distance to origin mm",
                             "camera–projector angle °", "baseline mm"],
                      caption="Per camera: the camera and the projector calibrated with it "
                              "(DLT models decomposed into K, R, t).")


def residuals(calib, camera: str, table) -> tuple[np.ndarray, np.ndarray]:
    """Camera and projector reprojection residuals of a points table.

    Returns
    -------
    camera_xy, projector_xy : (n_points, 2) float64
        Projection minus observation, px (camera pixels; projector panel pixels through the
        radial model).
    """

    cam = calib.camera(camera)
    xyz = table.xyz_world
    model = cam.camera
    cam_xy = model.project(xyz) if hasattr(model, "project") else project_dlt(model, xyz)
    proj_xy = _panel_of_points(cam.projector, calib.projector_distortion, xyz)
    return cam_xy - table.xy_camera, proj_xy - table.xy_projector


def section(inputs: ReportInputs) -> Section:
    """The calibration section of the report of `inputs` (``inputs.calibration``)."""

    if inputs.calibration is None:
        return Section(ID, TITLE, note_html(
            "No calibration: the summary names no calibration JSON that is still there.",
            "missing"), status="missing")
    path = inputs.calibration
    with reading(path):
        calib = load_calibration(path, allow_mirrored=True)
        body = [note_html(f"{path}"), _geometry_table(calib, projector_panel(inputs))]
        if calib.projector_distortion:
            d = calib.projector_distortion
            body.append(note_html(f"Projector radial distortion in the model: centre "
                                  f"({d.center[0]:.2f}, {d.center[1]:.2f}) px, "
                                  f"ρ = {d.rho:.6f}."))
    rows, found = [], {}
    for cam in calib.cameras:
        tsv = path.parent / f"{path.stem}_points_{cam.name}.tsv"
        if tsv.is_file():
            try:  # the residuals of the other cameras without this table
                with reading(tsv):
                    table = read_points(tsv)
                    found[cam.name] = (*residuals(calib, cam.name, table), table.xy_camera)
            except CorruptPart as exc:
                inputs.problems.append((exc.path, exc.reason))
    body.append("<h3>Residuals</h3>")
    status = "ok"
    if not found:
        body.append(note_html(f"No points tables ({path.stem}_points_CAMERA.tsv beside the "
                              "calibration): `nail2nail calibrate` writes them.", "missing"))
        return Section(ID, TITLE, "".join(body), status=status)
    for name, (rc, rp, _) in found.items():
        nc, npj = np.hypot(*rc.T), np.hypot(*rp.T)
        rows.append([name, fmt(len(nc)), *(fmt(f(v), ".3f") for v in (nc, npj)
                                           for f in (lambda a: np.sqrt(np.nanmean(a**2)),
                                                     np.nanmedian, np.nanmax))])
        if np.nanmax(nc) > 5 or np.nanmax(npj) > 5:
            status = "warn"
            body.append(note_html(f"Camera {name}: reprojection residuals above 5 px.", "warn"))
    body.append(table_html(rows, ["camera", "points", "camera RMS px", "camera median px",
                                  "camera max px", "projector RMS px", "projector median px",
                                  "projector max px"]))
    body.append(_residual_figure(calib, found))
    return Section(ID, TITLE, "".join(body), status=status)


def _residual_figure(calib, found: dict) -> str:
    fig = new_figure(2.6 * len(found) + 2.6, 3.2)
    axes = fig.subplots(1, len(found) + 1, squeeze=False)[0]
    biggest = max(float(np.nanmax(np.hypot(*rc.T))) for rc, _, _ in found.values())
    size0 = calib.cameras[0].size or (1024, 1280)
    gain = 0.05 * max(size0) / biggest if biggest > 0 else 1.0  # largest arrow: 5 % of image
    for ax, (name, (rc, _, xy)) in zip(axes, found.items(), strict=False):
        size = calib.camera(name).size or (1024, 1280)
        ax.quiver(xy[:, 0], xy[:, 1], gain * rc[:, 0], gain * rc[:, 1], angles="xy",
                  scale_units="xy", scale=1, width=0.004, color="#d62728")
        ax.set_xlim(-0.5, size[0] - 0.5)
        ax.set_ylim(size[1] - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=10)
        ax.tick_params(labelsize=7)
    hist = axes[-1]
    for name, (rc, rp, _) in found.items():
        hist.hist(np.hypot(*rc.T), bins=30, histtype="step", label=f"{name} camera")
        hist.hist(np.hypot(*rp.T), bins=30, histtype="step", ls="--", label=f"{name} projector")
    hist.set_xlabel("residual px")
    hist.legend(fontsize=6)
    return figure_html(fig, f"Camera residual vectors over each image, magnified {gain:.3g}×; "
                            "histogram of the camera and projector residuals.")
