"""Accuracy of the planar-board calibration (issue 12) against the virtual scanner's truth.

Renders (once) `--poses` captures of a board (:func:`nail2nail.simulation.board_poses
.simulate_board_captures`, the default rig with the thesis's projector distortion) and a finger
at the given scale, then calibrates with :func:`nail2nail.calibration.observe.board_views` and
:func:`nail2nail.calibration.board.calibrate_board` for each projector model and prints:

- the board features' detection error (camera px) and the local homographies' projector points'
  error (panel px) against the truth (RMS per coordinate, largest);
- the RMS reprojection errors of the fit per camera and of the projector;
- per device (cameras, projector): focal length error (%), principal point error (px), and the
  error of its pose relative to cam0 (rotation °, translation mm);
- the finger scanned with the calibration against the true surface (distance along the true
  normal, µm): in the truth's world frame through the true cam0 pose (the calibration's world
  is cam0's frame as calibrated: cam0's own pose error shows), and after the one rigid motion of
  all cameras' scans together that fits them best (the calibration's shape error); the same for
  the simulator's true calibration (the decoding's share).

The peer in the same run: OpenCV on the same detected points, as a structured-light system
calibrates with it (SLStudio's way): ``cv2.calibrateCamera`` per camera and for the projector
(on the projector points averaged over the cameras), then ``cv2.stereoCalibrate`` with the
intrinsics fixed for each camera–projector pair and each camera against cam0 (the poses both
saw), the same distortion terms (cameras k1, k2; projector all five); its reprojection RMS and
the same errors against the truth, and the finger scanned with it.

Usage: ``python bench/board_calibration.py [WORK_DIR] [--scale S] [--poses N] [--board KIND]``
(captures reused when WORK_DIR has them; about 5 minutes at full scale with 8 poses on two
cores, mostly rendering).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from nail2nail.calibration.board import (
    MIN_FEATURES,
    calibrate_board,
    calibrate_device,
    projector_points_by_pose,
)
from nail2nail.calibration.boards import BOARD_KINDS, default_board
from nail2nail.calibration.camera_models import Pinhole
from nail2nail.calibration.files import CameraCalibration, RigCalibration
from nail2nail.calibration.observe import board_views
from nail2nail.io.capture import read_capture, read_truth
from nail2nail.scan.capture import scan_capture
from nail2nail.simulation.board_poses import simulate_board_captures
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import Rig, default_rig, ideal_calibration


def render(work: Path, *, scale: float, n_poses: int, kind: str) -> list[Path]:
    rig = default_rig(scale)
    poses_dir = work / f"{kind}-{n_poses}"
    if not (poses_dir / "poses.json").exists():
        t0 = time.perf_counter()
        simulate_board_captures(poses_dir, n_poses, board=default_board(kind), rig=rig, seed=0)
        print(f"rendered {n_poses} {kind} poses in {time.perf_counter() - t0:.0f} s")
    if not (work / "finger" / "capture.json").exists():
        t0 = time.perf_counter()
        simulate_capture(work / "finger", "finger", rig=rig, seed=3)
        print(f"rendered the finger in {time.perf_counter() - t0:.0f} s")
    return sorted(p for p in poses_dir.iterdir() if p.is_dir())


def measurement_errors(captures, poses, board, rig) -> None:
    obj = board.object_points()
    cam_err, proj_err = [], []
    for v in captures.views:
        scene = json.loads((poses[v.pose] / "capture.json").read_text())["scene"]
        xyz = obj[v.ids] @ np.array(scene["R_world_board"]).T + np.array(scene["t_world_board"])
        cam_err.append(v.xy_camera - rig.cameras[rig.camera_names.index(v.camera)].project(xyz))
        proj_err.append(v.xy_projector - rig.panel_from_world(xyz))
    for what, err in (("detection (camera px)", cam_err), ("projector points (panel px)",
                                                           proj_err)):
        err = np.concatenate(err)
        ok = np.all(np.isfinite(err), axis=1)
        print(f"  {what}: RMS x {np.sqrt(np.mean(err[ok, 0] ** 2)):.4f}, y "
              f"{np.sqrt(np.mean(err[ok, 1] ** 2)):.4f}, largest {np.abs(err[ok]).max():.3f}, "
              f"none {int((~ok).sum())} of {len(ok)}")


def device_errors(result, rig) -> None:
    T0 = np.eye(4)
    T0[:3, :3], T0[:3, 3] = rig.cameras[0].R, rig.cameras[0].t
    pairs = [*zip(result.camera_names, result.cameras, rig.cameras, strict=True),
             ("projector", result.projector, rig.projector)]
    print(f"  {'device':>9} {'focal %':>8} {'pp px':>13} {'rot °':>7} {'t mm':>7}")
    for name, est, true in pairs:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = true.R, true.t
        rel = T @ np.linalg.inv(T0)
        focal = 100 * np.max(np.abs(np.diag(est.K)[:2] / np.diag(true.K)[:2] - 1))
        pp = est.K[:2, 2] - true.K[:2, 2]
        rot = np.degrees(np.linalg.norm(Rotation.from_matrix(est.R @ rel[:3, :3].T).as_rotvec()))
        dt = np.linalg.norm(est.t - rel[:3, 3])
        print(f"  {name:>9} {focal:8.4f} {pp[0]:6.2f},{pp[1]:6.2f} {rot:7.4f} {dt:7.4f}")


class OpenCVRig:
    """OpenCV's calibration of the rig, in the shape :func:`device_errors` reads."""

    def __init__(self, cameras: dict, projector: Pinhole, rms: dict) -> None:
        self.camera_names = list(cameras)
        self.cameras = list(cameras.values())
        self.projector = projector
        self.rms = rms

    def rig_calibration(self) -> RigCalibration:
        return RigCalibration(cameras=[CameraCalibration(n, c, self.projector, size=c.size)
                                       for n, c in zip(self.camera_names, self.cameras,
                                                       strict=True)])


def opencv_peer(captures, board) -> OpenCVRig:
    """cv2.calibrateCamera per device, then cv2.stereoCalibrate (intrinsics fixed) for the
    projector and every camera against cam0: poses in cam0's frame."""
    import cv2

    obj = board.object_points().astype(np.float32)
    names = list(captures.camera_sizes)
    by = {n: {v.pose: v for v in captures.views if v.camera == n} for n in names}
    models = {}
    for n in names:
        vs = list(by[n].values())
        models[n], _, _ = calibrate_device([obj[v.ids] for v in vs], [v.xy_camera for v in vs],
                                           captures.camera_sizes[n], name=n, distortion="radial")
    # the projector's points of a pose: averaged over the cameras that measured them
    proj = projector_points_by_pose(captures.views, sorted({v.pose for v in captures.views}))
    projector, _, _ = calibrate_device([obj[i] for i, _ in proj.values()],
                                       [xy for _, xy in proj.values()], captures.projector_size,
                                       name="projector", distortion="full")
    flags = cv2.CALIB_FIX_INTRINSIC
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)

    def stereo(a_pts: dict, b_pts: dict, a: Pinhole, b: Pinhole, size) -> tuple:
        o, pa, pb = [], [], []
        for pose in sorted(set(a_pts) & set(b_pts)):
            ia, xa = a_pts[pose]
            ib, xb = b_pts[pose]
            common, ka, kb = np.intersect1d(ia, ib, return_indices=True)
            if len(common) >= MIN_FEATURES:
                o.append(obj[common].reshape(-1, 1, 3))
                pa.append(xa[ka].astype(np.float32).reshape(-1, 1, 2))
                pb.append(xb[kb].astype(np.float32).reshape(-1, 1, 2))
        rms, *_, R, t, _, _ = cv2.stereoCalibrate(
            o, pa, pb, a.K, a.dist, b.K, b.dist, tuple(int(v) for v in size), flags=flags,
            criteria=crit)
        return float(rms), R, np.ravel(t)

    cam_pts = {n: {p: (v.ids, v.xy_camera) for p, v in by[n].items()} for n in names}
    rms, cameras = {}, {}
    for n in names:
        if n == names[0]:
            R, t = np.eye(3), np.zeros(3)
        else:
            rms[f"{names[0]}-{n}"], R, t = stereo(cam_pts[names[0]], cam_pts[n], models[names[0]],
                                                  models[n], captures.camera_sizes[names[0]])
        cameras[n] = Pinhole(K=models[n].K, R=R, t=t, dist=models[n].dist, size=models[n].size)
    rms[f"{names[0]}-projector"], R, t = stereo(cam_pts[names[0]], proj, models[names[0]],
                                                projector, captures.camera_sizes[names[0]])
    proj_model = Pinhole(K=projector.K, R=R, t=t, dist=projector.dist, size=projector.size)
    return OpenCVRig(cameras, proj_model, rms)


def finger_errors(calib, rig, finger: Path, *, in_cam0: bool = True) -> None:
    scans = scan_capture(read_capture(finger, load=False), calib)
    R0, t0 = (rig.cameras[0].R, rig.cameras[0].t) if in_cam0 else (np.eye(3), np.zeros(3))
    data = []
    for scan in scans:
        truth = read_truth(finger, scan.name)
        ok = scan.mask & truth["mask"]
        data.append(((scan.xyz[ok].astype(float) - t0) @ R0, truth["xyz"][ok].astype(float),
                     truth["normal"][ok].astype(float)))
    p, q, n = (np.concatenate(a) for a in zip(*data, strict=True))
    R, t = np.eye(3), np.zeros(3)
    for _ in range(5):  # point-to-plane rigid fit, linearised and iterated
        pt = p @ R.T + t
        step = np.linalg.lstsq(np.concatenate([np.cross(pt, n), n], axis=1),
                               np.sum((q - pt) * n, axis=1), rcond=None)[0]
        dR = Rotation.from_rotvec(step[:3]).as_matrix()
        R, t = dR @ R, dR @ t + step[3:]
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec()))
    print(f"  finger (µm along the true normal; rigid motion {angle:.4f}°, "
          f"{1000 * np.linalg.norm(t):.1f} µm):")
    for scan, (pc, qc, nc) in zip(scans, data, strict=True):
        raw = 1000 * np.sum((pc - qc) * nc, axis=1)
        fit = 1000 * np.sum((pc @ R.T + t - qc) * nc, axis=1)
        print(f"    {scan.name}: {len(raw)} points, in the true world frame RMS "
              f"{np.sqrt(np.mean(raw**2)):.2f} (mean {raw.mean():.2f}); after the rigid motion "
              f"RMS {np.sqrt(np.mean(fit**2)):.2f} (mean {fit.mean():.2f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("work", nargs="?", type=Path, help="directory for the captures")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--poses", type=int, default=8)
    parser.add_argument("--board", choices=BOARD_KINDS, default="circles")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="board-bench-"))
    work = work / f"scale-{args.scale:g}"
    print(f"captures in {work}")
    poses = render(work, scale=args.scale, n_poses=args.poses, kind=args.board)
    rig = Rig.from_capture(read_capture(poses[0], load=False))
    board = default_board(args.board)
    t0 = time.perf_counter()
    captures = board_views(poses, board)
    print(f"board views: {len(captures.views)} ({len(captures.refused)} refused) in "
          f"{time.perf_counter() - t0:.1f} s")
    measurement_errors(captures, poses, board, rig)
    for model in ("thesis", "opencv"):
        t0 = time.perf_counter()
        result = calibrate_board(captures.views, board.object_points(), captures.camera_sizes,
                                 projector_size=captures.projector_size, projector_model=model)
        print(f"projector model {model}: fitted in {time.perf_counter() - t0:.1f} s; RMS "
              + ", ".join(f"{k} {v:.4f}" for k, v in result.camera_rms_px.items())
              + f", projector {result.projector_rms_px:.4f} px; {result.points_dropped} "
              f"points dropped; distortion {result.projector_distortion}")
        device_errors(result, rig)
        finger_errors(result.rig_calibration(), rig, work / "finger")
    t0 = time.perf_counter()
    peer = opencv_peer(captures, board)
    print(f"OpenCV (calibrateCamera + stereoCalibrate, intrinsics fixed): in "
          f"{time.perf_counter() - t0:.1f} s; stereo RMS "
          + ", ".join(f"{k} {v:.4f}" for k, v in peer.rms.items()) + " px")
    device_errors(peer, rig)
    finger_errors(peer.rig_calibration(), rig, work / "finger")
    print("the simulator's true calibration (decoding noise only):")
    truth = RigCalibration.from_dict(ideal_calibration(rig))
    finger_errors(truth, rig, work / "finger", in_cam0=False)


if __name__ == "__main__":
    main()
