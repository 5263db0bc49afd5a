"""``nail2nail distortion``: estimate the projector's radial distortion from a flat-plane capture.

Decodes every camera of the capture, estimates the optical centre and ρ by the thesis's method
(eq. 3.17–3.42, centre camera) and by the joint non-linear fit (all cameras), prints both, and
optionally writes the grid images of the thesis's Figures 19 (plain grid) and 20 (LUT-corrected
grid), drawn from the decoded projector coordinates.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from nail2nail._progress import Stages
from nail2nail._validation import as_int
from nail2nail.calibration.distortion import (
    PLANE_RMS_LIMIT_PX,
    ProjectorDistortion,
    check_plane,
    estimate_from_decoded,
    grid_from_decoded,
)
from nail2nail.io._atomic import atomic_directory, atomic_path
from nail2nail.io._json import dumps_json, write_json
from nail2nail.io.capture import read_capture
from nail2nail.scan.capture import decode_cameras
from nail2nail.simulation.rig import Rig

__all__ = ["add_parser", "run"]

def add_parser(sub) -> None:
    p = sub.add_parser(
        "distortion",
        help="estimate the projector's radial distortion (eq. 3.17-3.42) from a plane capture",
        description="Decode a capture of a flat plane under plain (not pre-distorted) fringe "
        "patterns, estimate the projector's optical centre and radial distortion ρ by the "
        "thesis's method and by a joint non-linear fit, and write the grid images of the "
        "thesis's Figures 19 and 20. A capture whose decoded points are not those of a flat "
        "plane (a smooth map of the camera pixels leaves more than "
        f"{PLANE_RMS_LIMIT_PX:g} projector px RMS) is refused before the fit.",
    )
    p.add_argument("capture_dir", type=Path, help="capture directory (capture.json + frames)")
    p.add_argument("--json", action="store_true", help="print machine-readable results")
    p.add_argument("--out", type=Path, help="directory for the grid images (PNG)")
    p.add_argument("--camera", help="camera for the thesis method (default: the middle one)")
    p.add_argument("--stride", type=int, default=2, help="pixel subsampling (default 2)")
    p.add_argument("--spacing", type=int, default=64, help="grid spacing, panel px (default 64)")
    p.add_argument("--line-width", type=int, default=None,
                   help="grid line width, panel px (default: about two camera pixels)")
    p.set_defaults(func=run)


def _load(capture_dir: Path):
    """Decoded maps, camera models and ground truth of a capture (if it records them)."""

    capture = read_capture(capture_dir, load=False)
    manifest = capture.manifest
    if manifest.get("predistortion") or manifest.get("predistorted"):
        raise ValueError(
            f"{capture_dir}: captured with pre-distorted patterns; estimate from plain patterns"
        )
    views, albedo = {}, {}
    for name, decoded in decode_cameras(capture, progress=True):
        if decoded.xp is None or decoded.yp is None:
            raise ValueError(f"{capture_dir}: the patterns must encode both xp and yp")
        views[name] = (decoded.xp, decoded.yp, decoded.mask)
        albedo[name] = decoded.albedo
    truth, models = None, {}
    if isinstance(manifest.get("rig"), dict):
        rig = Rig.from_capture(capture)
        models = dict(zip(rig.camera_names, rig.cameras, strict=True))
        truth = rig.projector_distortion
    assert capture.pattern_set is not None  # decode_cameras refused a capture without one
    return views, albedo, models, truth, capture.pattern_set.panel_size


def _write_png(path: Path, image: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")


def run(args: argparse.Namespace) -> int:
    # every option checked before anything is read or written
    for flag, value, minimum in (("--stride", args.stride, 1), ("--spacing", args.spacing, 2),
                                 ("--line-width", args.line_width, 1)):
        if value is not None:
            as_int(value, flag, minimum=minimum)
    step = Stages(prefix="distortion: ")  # stderr, a terminal only, not with --quiet
    views, albedo, models, truth, panel_size = _load(args.capture_dir)
    check_plane(views, args.capture_dir)  # seconds; the fit on anything else runs for long
    step("fit the projector distortion")
    report = estimate_from_decoded(views, primary=args.camera, cameras=models,
                                   stride=args.stride)
    result = report.to_dict(truth=truth)

    if args.out is not None:
        step("draw the grids")
        images = {}
        for name, (xp, yp, mask) in views.items():
            plain = grid_from_decoded(xp, yp, mask, panel_size=panel_size, spacing=args.spacing,
                                      width=args.line_width, background=albedo[name])
            corrected = grid_from_decoded(xp, yp, mask, panel_size=panel_size,
                                          spacing=args.spacing, width=args.line_width,
                                          center=report.fit.center, rho=report.fit.rho,
                                          background=albedo[name])
            for kind, image in (("distorted", plain), ("corrected", corrected)):
                images[f"grid_{kind}_{name}.png"] = image
        estimate = ProjectorDistortion(report.fit.center, report.fit.rho)
        # the directory as a whole: the old one or the new one, never a mix
        with atomic_directory(args.out, marker="projector_distortion.json") as tmp:
            for file, image in images.items():
                _write_png(tmp / file, image)
            write_json(tmp / "projector_distortion.json",
                       {"projector_distortion": estimate.to_dict()})
        result["written"] = [str(args.out / f)
                             for f in [*images, "projector_distortion.json"]]

    if args.json:
        print(dumps_json(result))
        return 0
    fit, thesis = report.fit, report.thesis
    print(f"non-linear (all cameras): center = ({fit.center[0]:.2f}, {fit.center[1]:.2f}) px "
          f"± ({fit.center_std_px[0]:.2f}, {fit.center_std_px[1]:.2f}), rho = {fit.rho:.6f} "
          f"± {fit.rho_std:.1e}, residual rms {fit.rms_px:.3f} px")
    if thesis is None:
        print(f"thesis method ({report.primary}): degenerate fit")
    else:
        print(f"thesis method ({report.primary}): center = ({thesis.center[0]:.2f}, "
              f"{thesis.center[1]:.2f}) px, rho = {thesis.rho:.6f}")
    for cam in report.cameras:
        th = "n/a" if cam.thesis is None else (
            f"({cam.thesis.center[0]:.1f}, {cam.thesis.center[1]:.1f}), {cam.thesis.rho:.6f}")
        print(f"  {cam.camera}: non-linear ({cam.fit.center[0]:.1f}, {cam.fit.center[1]:.1f}), "
              f"{cam.fit.rho:.6f}; thesis {th}")
    if truth is not None:
        t = result["truth"]
        line = (f"truth: center ({truth.center[0]:.1f}, {truth.center[1]:.1f}), rho "
                f"{truth.rho:.6f}; non-linear error {t['nonlinear']['center_error_px']:.2f} px, "
                f"{t['nonlinear']['rho_error_percent']:.2f} %")
        if t["thesis"] is not None:
            line += (f"; thesis error {t['thesis']['center_error_px']:.2f} px, "
                     f"{t['thesis']['rho_error_percent']:.2f} %")
        print(line)
    for path in result.get("written", []):
        print(f"wrote {path}")
    return 0
