"""Scan directories: what ``nail2nail scan`` writes and ``nail2nail merge`` reads.

Layout (``docs/capture-format.md``)::

    SCAN_DIR/scan.json      manifest: cameras, their files, valid pixel counts
    SCAN_DIR/cam0.npz       every array of a :class:`~nail2nail.reconstruction.Scan`
    SCAN_DIR/cam0C.bmp …    the legacy mat5 set of the camera (C, I, X, Y, Z, XP, YP)
    SCAN_DIR/cam0.ply       binary PLY point cloud with albedo as colour
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._validation import as_name, check_format, check_unique, confined_path
from ..reconstruction import Scan
from ._atomic import atomic_directory, write_npz
from ._json import read_json, write_json
from ._npz import read_npz

__all__ = ["SCAN_FORMAT", "load_scan_npz", "load_scans", "save_scan_npz", "save_scans"]

SCAN_FORMAT = "nail2nail-scan"
_ARRAYS = ("xyz", "xp", "yp", "albedo", "intensity", "modulation", "mask")


def save_scan_npz(path: str | os.PathLike, scan: Scan) -> None:
    """Write every array of `scan` to one ``.npz`` (atomically)."""
    arrays = {name: getattr(scan, name) for name in _ARRAYS}
    if scan.camera_center is not None:
        arrays["camera_center"] = np.asarray(scan.camera_center, dtype=float)
    write_npz(path, {"name": np.array(scan.name), **arrays})


def load_scan_npz(path: str | os.PathLike) -> Scan:
    """Read a scan written by :func:`save_scan_npz`; ``ValueError`` naming the file if bad."""
    path = Path(path)
    data = read_npz(path, required=_ARRAYS, what="scan file")
    arrays = {k: data[k] for k in _ARRAYS}
    center = data.get("camera_center")
    name = str(data["name"]) if "name" in data else path.stem
    mask = arrays["mask"]
    if mask.ndim != 2 or mask.dtype != bool:
        raise ValueError(f"{path}: mask must be an (H, W) bool array, got {mask.dtype} "
                         f"{mask.shape}")
    shape = mask.shape
    for key in _ARRAYS[:-1]:
        want = (*shape, 3) if key == "xyz" else shape
        if arrays[key].shape != want or not np.issubdtype(arrays[key].dtype, np.floating):
            raise ValueError(f"{path}: {key} must be a float array of shape {want} (mask "
                             f"{shape}), got {arrays[key].dtype} {arrays[key].shape}")
    if center is not None and (center.shape != (3,)
                               or not np.issubdtype(center.dtype, np.floating)):
        raise ValueError(f"{path}: camera_center must be 3 floats, got {center.dtype} "
                         f"{center.shape}")
    if "name" in data and (data["name"].shape != () or data["name"].dtype.kind != "U"):
        raise ValueError(f"{path}: name must be a string, got {data['name'].dtype} "
                         f"{data['name'].shape}")
    return Scan(name=name, camera_center=center, **arrays)


def save_scans(
    out_dir: str | os.PathLike, scans: list[Scan], *, mat5: bool = True, ply: bool = True,
    extra: dict | None = None,
) -> dict:
    """Write a scan directory and return its manifest (also written as ``scan.json``).

    The directory is written as a whole (:func:`nail2nail.io._atomic.atomic_directory`): an
    earlier scan directory there is replaced only once the new one is complete; a non-empty
    directory without ``scan.json`` is refused.
    """
    out = Path(out_dir)
    for i, scan in enumerate(scans):
        as_name(scan.name, f"scans[{i}].name")
    check_unique([scan.name for scan in scans], "scans")
    with atomic_directory(out, marker="scan.json") as tmp:
        return _write_scans(tmp, scans, mat5=mat5, ply=ply, extra=extra)


def _write_scans(out: Path, scans: list[Scan], *, mat5: bool, ply: bool, extra) -> dict:
    cameras = []
    for scan in scans:
        entry = {"name": scan.name, "npz": f"{scan.name}.npz",
                 "valid_pixels": int(scan.mask.sum()), "shape": list(scan.shape)}
        save_scan_npz(out / entry["npz"], scan)
        if mat5:
            from .mat5 import write_mat5

            write_mat5(out / scan.name, scan)
            entry["mat5"] = scan.name
        if ply:
            from .ply import write_scan_ply

            write_scan_ply(out / f"{scan.name}.ply", scan)
            entry["ply"] = f"{scan.name}.ply"
        if scan.camera_center is not None:
            entry["camera_center"] = np.asarray(scan.camera_center).tolist()
        cameras.append(entry)
    manifest = {"format": SCAN_FORMAT, "version": 1, "cameras": cameras, **(extra or {})}
    write_json(out / "scan.json", manifest)
    return manifest


def load_scans(scan_dir: str | os.PathLike) -> list[Scan]:
    """Read every camera's scan of a scan directory, in manifest order.

    Raises
    ------
    ValueError
        Naming the file: no or bad ``scan.json`` (format, version, camera entries, names not
        plain or not unique, an ``npz`` path leading outside `scan_dir`), or a bad ``.npz``.
    """
    scan_dir = Path(scan_dir)
    manifest_path = scan_dir / "scan.json"
    if not manifest_path.is_file():
        raise ValueError(f"{scan_dir}: not a scan directory (no scan.json)")
    manifest = check_format(read_json(manifest_path), fmt=SCAN_FORMAT, where=str(manifest_path))
    cams = manifest.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise ValueError(f"{manifest_path}: 'cameras' must be a non-empty list")
    files = []
    for i, cam in enumerate(cams):
        where = f"{manifest_path}: cameras[{i}]"
        if not isinstance(cam, dict) or not {"name", "npz"} <= set(cam):
            raise ValueError(f"{where} needs 'name' and 'npz'")
        as_name(cam["name"], f"{where}.name")
        files.append(confined_path(scan_dir, cam["npz"], f"{where}.npz"))
    check_unique([cam["name"] for cam in cams], str(manifest_path))
    return [load_scan_npz(file) for file in files]
