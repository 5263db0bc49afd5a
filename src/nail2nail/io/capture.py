"""Capture directories: ``capture.json`` plus PNG frames per camera (``docs/capture-format.md``).

A capture is what the scanner (real or virtual) records for one scan::

    DIR/capture.json        manifest (format "nail2nail-capture", version 1)
    DIR/cam0/000.png …      frames of camera cam0, in projection order
    DIR/cam1/…, DIR/cam2/…
    DIR/truth/…             ground truth (virtual scanner only)

Frames are 8-bit grey PNGs, or 16-bit PNGs holding 10/12/16-bit values left-aligned. In memory
(:func:`read_capture`) intensities are ``float32`` in ``[0, 1]``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from ._atomic import atomic_path
from ._json import read_json, write_json

__all__ = [
    "CAPTURE_FORMAT",
    "Capture",
    "read_capture",
    "read_frame",
    "read_truth",
    "write_frame",
    "write_manifest",
]

CAPTURE_FORMAT = "nail2nail-capture"
MANIFEST = "capture.json"


@dataclass
class Capture:
    """A capture read from disk.

    Attributes
    ----------
    path : Path
        The capture directory.
    manifest : dict
        The parsed ``capture.json``.
    pattern_set : PatternSet or None
        The projected pattern set, if the manifest names one.
    frames : dict of str to (n_frames, H, W) float32
        Frames per camera name, intensities in ``[0, 1]`` (empty if read with ``load=False``).
    """

    path: Path
    manifest: dict
    pattern_set: object = None
    frames: dict = field(default_factory=dict)

    @property
    def camera_names(self) -> list[str]:
        """Camera names, in manifest order."""
        return [c["name"] for c in self.manifest["cameras"]]

    @property
    def bit_depth(self) -> int:
        """Bits per pixel of the frames (manifest ``bit_depth``, 8 by default)."""
        return int(self.manifest.get("bit_depth", 8))

    def camera(self, name: str) -> dict:
        """The manifest entry of camera `name`."""
        for cam in self.manifest["cameras"]:
            if cam["name"] == name:
                return cam
        raise KeyError(f"capture has no camera {name!r} (has {self.camera_names})")

    def load_frames(self, name: str) -> np.ndarray:
        """Read (and cache) the frames of camera `name`: ``(n_frames, H, W) float32``."""
        if name not in self.frames:
            files = self.camera(name)["frames"]
            self.frames[name] = np.stack(
                [read_frame(self.path / f, bit_depth=self.bit_depth) for f in files]
            )
        return self.frames[name]

    def rig(self):
        """The rig stored in the manifest (virtual scanner), as a ``simulation.rig.Rig``."""
        if "rig" not in self.manifest:
            raise KeyError(f"{self.path}: the manifest holds no rig")
        from ..simulation.rig import Rig

        return Rig.from_dict(self.manifest["rig"], where=f"{self.path / MANIFEST}: rig")


def read_frame(path: str | os.PathLike, *, bit_depth: int = 8) -> np.ndarray:
    """One frame as ``(H, W) float32`` in ``[0, 1]`` (16-bit PNGs: left-aligned `bit_depth`)."""
    path = Path(path)
    try:
        with Image.open(path) as im:
            raw = np.asarray(im)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read frame ({exc})") from exc
    if raw.ndim != 2:
        raise ValueError(f"{path}: expected a grey image, got shape {raw.shape}")
    if raw.dtype == np.uint8:
        return raw.astype(np.float32) / np.float32(255)
    values = raw.astype(np.uint32) >> (16 - bit_depth)
    return values.astype(np.float32) / np.float32(2**bit_depth - 1)


def write_frame(path: str | os.PathLike, frame: np.ndarray, *, compress_level: int = 1) -> None:
    """Write one frame (uint8, or uint16 left-aligned) as PNG, atomically."""
    frame = np.asarray(frame)
    if frame.ndim != 2 or frame.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"frame: expected a 2-D uint8/uint16 image, got {frame.dtype} "
                         f"{frame.shape}")
    image = Image.fromarray(frame)
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG", compress_level=compress_level)


def write_manifest(directory: str | os.PathLike, manifest: dict) -> Path:
    """Write ``capture.json`` (atomically; write it last: its presence marks a complete capture).

    Required keys: ``cameras`` (list of ``{"name", "size", "frames"}``) and ``n_frames``;
    ``format``/``version`` are filled in.
    """
    directory = Path(directory)
    _check_manifest(manifest, where="manifest")
    data = {"format": CAPTURE_FORMAT, "version": 1, **manifest}
    path = directory / MANIFEST
    return write_json(path, data)


def _check_manifest(data, *, where: str) -> None:
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a JSON object")
    cams = data.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise ValueError(f"{where}: 'cameras' must be a non-empty list")
    n = data.get("n_frames")
    for i, cam in enumerate(cams):
        if not isinstance(cam, dict) or not {"name", "frames"} <= set(cam):
            raise ValueError(f"{where}: cameras[{i}] needs 'name' and 'frames'")
        if n is not None and len(cam["frames"]) != n:
            raise ValueError(
                f"{where}: cameras[{i}] lists {len(cam['frames'])} frames, n_frames is {n}"
            )


def read_capture(path: str | os.PathLike, *, load: bool = True) -> Capture:
    """Read a capture directory.

    Parameters
    ----------
    path : path-like
        The directory holding ``capture.json``.
    load : bool
        Read every camera's frames now (``True``) or on demand with
        :meth:`Capture.load_frames`.

    Returns
    -------
    Capture

    Raises
    ------
    ValueError
        Naming the file: missing or invalid manifest, missing frames.
    """
    path = Path(path)
    manifest_path = path / MANIFEST
    if not manifest_path.is_file():
        raise ValueError(f"{path}: not a capture directory (no {MANIFEST})")
    manifest = read_json(manifest_path)
    if not isinstance(manifest, dict) or manifest.get("format") != CAPTURE_FORMAT:
        raise ValueError(f"{manifest_path}: not a nail2nail capture (format != "
                         f"{CAPTURE_FORMAT!r})")
    _check_manifest(manifest, where=str(manifest_path))
    for cam in manifest["cameras"]:
        missing = [f for f in cam["frames"] if not (path / f).is_file()]
        if missing:
            raise ValueError(f"{path}: camera {cam['name']}: {len(missing)} frame file(s) "
                             f"missing (first {missing[0]})")
    pattern_set = None
    if manifest.get("pattern_set") is not None:
        from ..patterns import PatternSet

        pattern_set = PatternSet.from_dict(manifest["pattern_set"])
    capture = Capture(path=path, manifest=manifest, pattern_set=pattern_set)
    if load:
        for name in capture.camera_names:
            capture.load_frames(name)
    return capture


def read_truth(path: str | os.PathLike, camera: str) -> dict[str, np.ndarray]:
    """Ground-truth arrays of one camera of a simulated capture (``truth/<camera>.npz``)."""
    file = Path(path) / "truth" / f"{camera}.npz"
    if not file.is_file():
        raise ValueError(f"{path}: no ground truth for camera {camera!r} ({file} missing)")
    with np.load(file) as data:
        return {k: data[k] for k in data.files}
