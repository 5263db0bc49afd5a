"""Scan directories: what ``nail2nail scan`` writes and ``nail2nail merge`` reads.

Layout (``docs/capture-format.md``)::

    SCAN_DIR/scan.json      manifest: cameras, their files, valid pixel counts
    SCAN_DIR/cam0.npz       every array of a :class:`~nail2nail.scan.results.Scan`
    SCAN_DIR/cam0C.bmp …    the legacy mat5 set of the camera (C, I, X, Y, Z, XP, YP)
    SCAN_DIR/cam0.ply       binary PLY point cloud with albedo as colour

The points are written in the frame named in ``scan.json`` (``"frame"``: ``"world"`` or a
camera's name, with the 4×4 ``"T_frame_world"``; :mod:`nail2nail.frames`); :func:`load_scans`
returns them in the world frame (or as stored, ``frame="stored"``).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from nail2nail._validation import as_name, check_format, check_unique, confined_path
from nail2nail.frames import WORLD, _check_transform, invert_transform, scan_in_frame
from nail2nail.io._atomic import atomic_directory, write_npz
from nail2nail.io._json import read_json, write_json
from nail2nail.io._npz import read_npz
from nail2nail.io.mat5 import write_mat5
from nail2nail.io.ply import write_scan_ply
from nail2nail.scan.results import Scan
from nail2nail.scan.triangulation import USES

__all__ = ["SCAN_FORMAT", "load_scan_dirs", "load_scan_npz", "load_scans", "read_scan_frame",
           "save_scan_npz", "save_scans"]

SCAN_FORMAT = "nail2nail-scan"
_ARRAYS = ("xyz", "xp", "yp", "albedo", "intensity", "modulation", "mask")
SCAN_NPZ_LAYOUT = 2  # 1: every array whole (before issue 11); 2: packed (docs/capture-format.md)
_PACK_FILL = 0.25  # an array is packed when at least this share of its pixels hold its fill


def save_scan_npz(path: str | os.PathLike, scan: Scan, *, compress: bool | int = False) -> None:
    """Write every array of `scan` to one ``.npz`` (atomically), in the packed layout.

    An array is stored as the values of the pixels that do not hold its *fill* (the value of
    its first pixel outside ``scan.mask``: NaN for ``xyz``, ``xp``, ``yp``), the fill, and
    which pixels those are (``scan.mask``'s pixels unless stored), when at least a quarter of
    its pixels hold the fill; whole otherwise. :func:`load_scan_npz` restores every array bit
    for bit (NaN payloads included). ``docs/capture-format.md``, "Scan directory".

    Parameters
    ----------
    path : path-like
        The ``.npz`` file.
    scan : Scan
    compress : bool or int
        zlib level for every array (:func:`nail2nail.io._atomic.write_npz`); by default
        (``False``) only the pixel bits are compressed (level 1), the float values are stored:
        zlib shrinks them by some 20 % in some 20 times the time (``bench/io.py``).
    """
    mask = np.asarray(scan.mask)
    arrays = {"layout": np.array(SCAN_NPZ_LAYOUT), "name": np.array(scan.name)}
    if mask.ndim == 2 and mask.dtype == bool:
        arrays["shape"] = np.array(mask.shape, dtype=np.int64)
        arrays["mask.bits"] = np.packbits(mask, axis=None)
        for key in _ARRAYS[:-1]:
            arrays.update(_pack(key, np.asarray(getattr(scan, key)), mask))
    else:  # left to the reader to refuse, as before
        arrays.update({key: getattr(scan, key) for key in _ARRAYS})
    for key in ("camera_center", "projector_center"):
        if getattr(scan, key) is not None:
            arrays[key] = np.asarray(getattr(scan, key), dtype=float)
    if scan.reason is not None:
        arrays["reason"] = np.asarray(scan.reason)
    levels: bool | int | dict[str, int] = compress
    if not compress:  # the float values stored; the pixel bits shrink 20 times in no time
        levels = {key: 1 for key in arrays if key.endswith((".bits", ".where"))
                  or key == "reason"}
    write_npz(path, arrays, compress=levels)


def _pack(key: str, value: np.ndarray, mask: np.ndarray) -> dict[str, np.ndarray]:
    """`value` as ``{key: value}`` or ``{key.values, key.fill[, key.where]}`` (packed)."""
    tail = (3,) if key == "xyz" else ()
    if (value.shape != (*mask.shape, *tail) or value.dtype.kind != "f"
            or value.itemsize not in (2, 4, 8) or value.size == 0 or mask.all()):
        return {key: value}
    value = np.ascontiguousarray(value)
    first = np.unravel_index(int(np.argmin(mask)), mask.shape)  # first pixel outside the mask
    fill = np.array(value[first])
    bits = value.view(f"u{value.itemsize}")
    fill_bits = fill.view(bits.dtype)
    if tail:
        held = bits[..., 0] != fill_bits[0]
        for channel in range(1, tail[0]):
            held |= bits[..., channel] != fill_bits[channel]
    else:
        held = bits != fill_bits
    n_held = int(np.count_nonzero(held))
    if mask.size - n_held < _PACK_FILL * mask.size:
        return {key: value}
    packed = {f"{key}.values": _pixels(value, tail)[held].view(value.dtype).reshape(-1, *tail),
              f"{key}.fill": fill}
    if not np.array_equal(held, mask):
        packed[f"{key}.where"] = np.packbits(held, axis=None)
    return packed


def load_scan_npz(path: str | os.PathLike) -> Scan:
    """Read a scan written by :func:`save_scan_npz` (either layout); ``ValueError`` naming the
    file if bad."""
    path = Path(path)
    data = read_npz(path, what="scan file")
    layout = data.get("layout")
    if layout is not None and (layout.shape != () or layout.dtype.kind not in "iu"
                               or int(layout) not in (1, SCAN_NPZ_LAYOUT)):
        raise ValueError(f"{path}: scan file layout {_describe(layout)} is not 1 or "
                         f"{SCAN_NPZ_LAYOUT} (written by a newer nail2nail?)")
    missing = [k for k in _ARRAYS if k not in data and f"{k}.values" not in data
               and f"{k}.bits" not in data]
    if missing:
        raise ValueError(f"{path}: scan file lacks array(s) {', '.join(missing)}")
    if "mask" in data:
        mask = data["mask"]
    else:
        mask = _bits(data, "mask", _shape(data, path), path)
    if mask.ndim != 2 or mask.dtype != bool:
        raise ValueError(f"{path}: mask must be an (H, W) bool array, got {mask.dtype} "
                         f"{mask.shape}")
    arrays: dict[str, Any] = {key: _unpack(data, key, mask, path) for key in _ARRAYS[:-1]}
    arrays["mask"] = mask
    center = data.get("camera_center")
    projector = data.get("projector_center")
    name = str(data["name"]) if "name" in data else path.stem
    shape = mask.shape
    for key in _ARRAYS[:-1]:
        want = (*shape, 3) if key == "xyz" else shape
        if arrays[key].shape != want or not np.issubdtype(arrays[key].dtype, np.floating):
            raise ValueError(f"{path}: {key} must be a float array of shape {want} (mask "
                             f"{shape}), got {arrays[key].dtype} {arrays[key].shape}")
    for key, value in (("camera_center", center), ("projector_center", projector)):
        if value is not None and (value.shape != (3,)
                                  or not np.issubdtype(value.dtype, np.floating)):
            raise ValueError(f"{path}: {key} must be 3 floats, got {value.dtype} "
                             f"{value.shape}")
    if "name" in data and (data["name"].shape != () or data["name"].dtype.kind != "U"):
        raise ValueError(f"{path}: name must be a string, got {data['name'].dtype} "
                         f"{data['name'].shape}")
    reason = data.get("reason")
    if reason is not None and (reason.shape != shape or reason.dtype != np.uint8):
        raise ValueError(f"{path}: reason must be a uint8 array of shape {shape} (mask "
                         f"{shape}), got {reason.dtype} {reason.shape}")
    return Scan(name=name, camera_center=center, projector_center=projector,
                reason=reason, **arrays)


def _describe(array: np.ndarray) -> str:
    return f"{array.dtype} {array.shape}" if array.size != 1 else repr(array.item())


def _shape(data: dict, path: Path) -> tuple[int, int]:
    shape = data.get("shape")
    if (shape is None or shape.shape != (2,) or shape.dtype.kind not in "iu"
            or not all(0 < int(v) < 2**31 for v in shape)):
        raise ValueError(f"{path}: shape must be 2 positive integers (H, W), got "
                         f"{'nothing' if shape is None else _describe(shape)}")
    return int(shape[0]), int(shape[1])


def _bits(data: dict, key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    """The (H, W) bool array packed as ``key.bits`` (or ``key.where``) by ``np.packbits``."""
    name = f"{key}.bits" if key == "mask" else f"{key}.where"
    bits = data[name]
    n = shape[0] * shape[1]
    if bits.dtype != np.uint8 or bits.shape != (-(-n // 8),):
        raise ValueError(f"{path}: {name} must be {-(-n // 8)} bytes (uint8) for "
                         f"{shape[0]} x {shape[1]} pixels, got {bits.dtype} {bits.shape}")
    return np.unpackbits(bits, count=n).view(bool).reshape(shape)


def _unpack(data: dict, key: str, mask: np.ndarray, path: Path) -> np.ndarray:
    if key in data:
        return data[key]
    values, fill = data.get(f"{key}.values"), data.get(f"{key}.fill")
    tail = (3,) if key == "xyz" else ()
    if (values is None or fill is None or values.dtype.kind != "f"
            or values.itemsize not in (2, 4, 8) or fill.dtype != values.dtype
            or values.ndim != 1 + len(tail) or values.shape[1:] != tail or fill.shape != tail):
        got = "nothing" if values is None else f"{values.dtype} {values.shape}"
        has = "no fill" if fill is None else f"fill {fill.dtype} {fill.shape}"
        want = "(n, 3)" if tail else "(n,)"
        raise ValueError(f"{path}: {key}.values must be a float16/32/64 array {want} with a "
                         f"fill of its dtype and shape {tail}, got {got}, {has}")
    held = _bits(data, key, mask.shape, path) if f"{key}.where" in data else mask
    n_held = int(np.count_nonzero(held))
    if values.shape[0] != n_held:
        raise ValueError(f"{path}: {key}.values holds {values.shape[0]} pixels, but "
                         f"{'its where' if held is not mask else 'the mask'} marks {n_held}")
    array = np.empty((*mask.shape, *tail), dtype=values.dtype)
    ints = array.view(f"u{array.itemsize}")
    fill_bits = np.ascontiguousarray(fill).view(ints.dtype).reshape(-1)
    if np.all(fill_bits == fill_bits[0]):  # as integers: the fill's bits, NaN payloads too
        ints.fill(fill_bits[0])
    else:
        _pixels(array, tail)[...] = _pixels(np.ascontiguousarray(fill), tail)
    _pixels(array, tail)[held] = _pixels(np.ascontiguousarray(values), tail)
    return array


def _pixels(array: np.ndarray, tail: tuple[int, ...]) -> np.ndarray:
    """A C-contiguous array of `tail`-shaped pixels as one item per pixel (``V{size}``): numpy
    gathers and scatters ``(H, W, 3)`` arrays through a boolean mask ten times faster so."""
    if not tail:
        return array
    size = int(np.prod(tail)) * array.itemsize
    return array.view(np.dtype((np.void, size))).reshape(array.shape[: -len(tail)])


def save_scans(
    out_dir: str | os.PathLike, scans: list[Scan], *, mat5: bool = True, ply: bool = True,
    extra: dict | None = None, compress: bool | int = False, frame: str = "world",
    transform=None, projectors=None, cameras=None,
) -> dict:
    """Write a scan directory and return its manifest (also written as ``scan.json``).

    `scans` are in the world frame; with `transform` (``T_frame_world``, 4×4, from
    :func:`nail2nail.frames.frame_transform`) their points and camera centres are written in
    the frame named `frame` (the ``.npz``, mat5 and PLY files alike), and ``scan.json``
    records ``"frame"`` and ``"T_frame_world"`` (the identity for the world frame), from which
    :func:`load_scans` maps them back.

    The directory is written as a whole (:func:`nail2nail.io._atomic.atomic_directory`): an
    earlier scan directory there is replaced only once the new one is complete; a non-empty
    directory without ``scan.json`` is refused. The scans are written in threads, one scan
    each (numpy and file writes release the GIL); `compress` as for :func:`save_scan_npz`.

    A rig of several projectors writes all its scans into one directory: `projectors` and
    `cameras` (lists of int, one per scan, as :func:`nail2nail.merge.fusion.fuse_scans` takes
    them) are recorded per camera entry (``"projector_index"``, ``"camera_index"``) and
    :func:`load_scan_dirs` returns them.
    """
    out = Path(out_dir)
    for i, scan in enumerate(scans):
        as_name(scan.name, f"scans[{i}].name")
    check_unique([scan.name for scan in scans], "scans")
    if (projectors is None) != (cameras is None):
        raise ValueError("projectors, cameras: give both or neither")
    if projectors is not None and not (len(projectors) == len(cameras) == len(scans)):
        raise ValueError(f"projectors, cameras: one each per scan ({len(scans)})")

    if not isinstance(frame, str) or not frame:
        raise ValueError(f"frame: expected 'world' or a camera name, got {frame!r}")
    T = np.eye(4) if transform is None else _check_transform(transform)
    if frame == WORLD and not np.array_equal(T, np.eye(4)):
        raise ValueError("transform: the world frame's transform is the identity")
    if frame != WORLD and transform is None:
        raise ValueError(f"frame {frame!r}: its transform T_frame_world is needed")
    scans = [scan_in_frame(scan, T) for scan in scans]
    extra = {**(extra or {}), "frame": frame, "T_frame_world": T.tolist()}
    index = None if projectors is None else {
        scan.name: (int(k), int(i)) for scan, k, i in zip(scans, projectors, cameras,
                                                          strict=True)}
    with atomic_directory(out, marker="scan.json") as tmp:
        return _write_scans(tmp, scans, mat5=mat5, ply=ply, extra=extra, compress=compress,
                            index=index)


def _write_scans(out: Path, scans: list[Scan], *, mat5: bool, ply: bool, extra,
                 compress: bool | int, index: dict | None = None) -> dict:
    def write(scan: Scan) -> dict:
        entry: dict[str, Any] = {"name": scan.name, "npz": f"{scan.name}.npz",
                 "valid_pixels": int(np.count_nonzero(scan.mask)), "shape": list(scan.shape)}
        if index is not None:
            entry["projector_index"], entry["camera_index"] = index[scan.name]
        save_scan_npz(out / entry["npz"], scan, compress=compress)
        if mat5:

            write_mat5(out / scan.name, scan)
            entry["mat5"] = scan.name
        if ply:

            write_scan_ply(out / f"{scan.name}.ply", scan)
            entry["ply"] = f"{scan.name}.ply"
        for key in ("camera_center", "projector_center"):
            if getattr(scan, key) is not None:
                entry[key] = np.asarray(getattr(scan, key)).tolist()
        if scan.motion is not None:
            entry["motion"] = scan.motion
        if scan.fringe_periods:
            entry["fringe_periods_px"] = dict(scan.fringe_periods)
        if scan.triangulated_from is not None:
            entry["triangulated_from"] = scan.triangulated_from
        return entry

    cameras = _map_in_threads(write, scans)
    manifest = {"format": SCAN_FORMAT, "version": 1, "cameras": cameras, **(extra or {})}
    write_json(out / "scan.json", manifest)
    return manifest


def _fringe_periods(value, where: str) -> dict | None:
    """A manifest's ``fringe_periods_px`` (absent: None, as in scans written before it)."""
    if value is None:
        return None
    if (not isinstance(value, dict) or not set(value) <= {"x", "y"}
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) and v > 0 for v in value.values())):
        raise ValueError(f"{where}.fringe_periods_px: expected {{'x': T, 'y': T}} with periods "
                         f"> 0 in panel px, got {value!r}")
    return {k: float(v) for k, v in value.items()}


def _triangulated_from(value, where: str) -> str | None:
    """A manifest's ``triangulated_from`` (absent: None, as in scans written before it)."""
    if value is None or value in USES:
        return value
    raise ValueError(f"{where}.triangulated_from: expected 'xpyp', 'xp' or 'yp', got {value!r}")


def _map_in_threads(task, items: list) -> list:
    """``[task(item) for item in items]`` in up to ``os.cpu_count()`` threads; the error of the
    first failing item (in order) is raised, the items not started are dropped."""
    workers = min(os.cpu_count() or 1, len(items))
    if workers <= 1:
        return [task(item) for item in items]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(task, items))  # map yields in order, cancels the rest on error


def _read_manifest(scan_dir: Path) -> tuple[Path, dict]:
    manifest_path = scan_dir / "scan.json"
    if not manifest_path.is_file():
        raise ValueError(f"{scan_dir}: not a scan directory (no scan.json)")
    return manifest_path, check_format(read_json(manifest_path), fmt=SCAN_FORMAT,
                                       where=str(manifest_path))


def _manifest_frame(manifest: dict, where: str) -> tuple[str, np.ndarray]:
    """``(frame, T_frame_world)`` of a manifest (``"world"`` and the identity when absent:
    scan directories written before issue 12)."""

    frame = manifest.get("frame", WORLD)
    if not isinstance(frame, str) or not frame:
        raise ValueError(f"{where}: 'frame' must be 'world' or a camera name, got {frame!r}")
    T = manifest.get("T_frame_world")
    if T is None:
        if frame != WORLD:
            raise ValueError(f"{where}: the points are in frame {frame!r} but 'T_frame_world' "
                             "is missing: they cannot be mapped to the world frame")
        return frame, np.eye(4)
    try:
        T = _check_transform(np.asarray(T, dtype=float))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: 'T_frame_world' must be a rigid 4x4 transform ({exc})") \
            from exc
    if frame == WORLD and not np.array_equal(T, np.eye(4)):
        raise ValueError(f"{where}: frame 'world' with a 'T_frame_world' that is not the "
                         "identity")
    return frame, T


def read_scan_frame(scan_dir: str | os.PathLike) -> tuple[str, np.ndarray]:
    """The frame a scan directory's points are written in and its ``T_frame_world`` (4×4).

    ``("world", identity)`` for a directory written before frames were recorded.

    Raises
    ------
    ValueError
        Naming ``scan.json``: no manifest, a bad ``frame`` or ``T_frame_world`` (not a rigid
        transform; missing for a frame other than the world).
    """
    manifest_path, manifest = _read_manifest(Path(scan_dir))
    return _manifest_frame(manifest, str(manifest_path))


def load_scans(scan_dir: str | os.PathLike, *, frame: str = "world") -> list[Scan]:
    """Read every camera's scan of a scan directory, in manifest order.

    Parameters
    ----------
    scan_dir : path-like
    frame : {"world", "stored"}
        ``"world"``: the points (and camera centres) mapped back to the world frame with the
        manifest's ``T_frame_world`` (:func:`read_scan_frame`; nothing to do for scans written
        in the world frame), which ``merge`` and ``unroll`` compute in. ``"stored"``: as
        written.

    Raises
    ------
    ValueError
        Naming the file: no or bad ``scan.json`` (format, version, camera entries, names not
        plain or not unique, an ``npz`` path leading outside `scan_dir`, a bad ``frame`` or
        ``T_frame_world``), or a bad ``.npz``.
    """

    if frame not in ("world", "stored"):
        raise ValueError(f"frame: expected 'world' or 'stored', got {frame!r}")
    scan_dir = Path(scan_dir)
    manifest_path, manifest = _read_manifest(scan_dir)
    _, T = _manifest_frame(manifest, str(manifest_path))
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
    scans = _map_in_threads(load_scan_npz, files)
    for i, (scan, cam) in enumerate(zip(scans, cams, strict=True)):
        # what the frames said of motion, as written (a dict; anything else is not ours)
        scan.motion = cam.get("motion") if isinstance(cam.get("motion"), dict) else None
        scan.fringe_periods = _fringe_periods(cam.get("fringe_periods_px"),
                                              f"{manifest_path}: cameras[{i}]")
        scan.triangulated_from = _triangulated_from(cam.get("triangulated_from"),
                                                    f"{manifest_path}: cameras[{i}]")
    if frame == "stored":
        return scans
    world_from_frame = invert_transform(T)
    return [scan_in_frame(scan, world_from_frame) for scan in scans]


def load_scan_dirs(scan_dirs) -> tuple[list[Scan], list[int] | None, list[int] | None]:
    """The scans of one scan directory, or of one per projector of a rig of several.

    Parameters
    ----------
    scan_dirs : sequence of path-like
        One scan directory (a one-projector rig, or every scan of a rig of several as
        ``nail2nail process`` writes them: :func:`save_scans` with `projectors`), or one per
        projector (``nail2nail scan`` of each projector's capture, in projector order),
        written in one world frame.

    Returns
    -------
    scans : list of Scan
        In the world frame (:func:`load_scans`); with several directories renamed
        ``<camera>-p<k>`` (``k`` the directory's index), directory by directory.
    projectors, cameras : list of int or None
        Per scan, its directory's index and its camera's (cameras matched by name across the
        directories, numbered in order of first appearance); for one directory, those it
        records, else None. As :func:`nail2nail.merge.fusion.fuse_scans` takes them.

    Raises
    ------
    ValueError
        Naming the directory: one given twice, or a camera whose image size differs between
        directories; and every error of :func:`load_scans`.
    """
    dirs = [Path(d) for d in scan_dirs]
    if not dirs:
        raise ValueError("scan_dirs: expected at least one scan directory")
    if len(dirs) == 1:
        return (*_one_dir(dirs[0]),)
    resolved = [d.resolve() for d in dirs]
    for k, d in enumerate(resolved):
        if d in resolved[:k]:
            raise ValueError(f"{dirs[k]}: given twice")
    scans: list[Scan] = []
    projectors: list[int] = []
    cameras: list[int] = []
    index: dict[str, int] = {}
    size: dict[str, tuple] = {}
    for k, d in enumerate(dirs):
        for scan in load_scans(d):
            name = str(scan.name)
            shape = tuple(np.shape(scan.mask))
            if name in size and size[name] != shape:
                raise ValueError(f"{d}: camera {name!r} is {shape[1]}x{shape[0]} px, "
                                 f"{size[name][1]}x{size[name][0]} in the directories before")
            size.setdefault(name, shape)
            cameras.append(index.setdefault(name, len(index)))
            projectors.append(k)
            scans.append(replace(scan, name=f"{name}-p{k}"))
    return scans, projectors, cameras


def _one_dir(scan_dir: Path) -> tuple[list[Scan], list[int] | None, list[int] | None]:
    """:func:`load_scan_dirs` of one directory: its scans, and the projector and camera index
    of each where ``scan.json`` records them (every entry, or none)."""
    scans = load_scans(scan_dir)
    _, manifest = _read_manifest(scan_dir)
    cams = manifest["cameras"]
    have = [("projector_index" in c, "camera_index" in c) for c in cams]
    if not any(a or b for a, b in have):
        return scans, None, None
    if not all(a and b for a, b in have):
        raise ValueError(f"{scan_dir / 'scan.json'}: projector_index and camera_index must be "
                         "given for every camera or for none")
    lists: dict[str, list[int]] = {"projector_index": [], "camera_index": []}
    for i, c in enumerate(cams):
        for key, values in lists.items():
            v = c[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{scan_dir / 'scan.json'}: cameras[{i}].{key} must be a "
                                 f"non-negative integer, got {v!r}")
            values.append(v)
    return scans, lists["projector_index"], lists["camera_index"]
