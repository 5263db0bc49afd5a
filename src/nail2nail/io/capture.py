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
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from nail2nail._validation import as_name, check_format, check_unique, confined_path, describe_error
from nail2nail.io._atomic import atomic_path
from nail2nail.io._json import read_json, write_json
from nail2nail.io._npz import read_npz
from nail2nail.scan.inputs import frame_intensities
from nail2nail.scan.patterns import PatternSet

if TYPE_CHECKING:
    from PIL import ImageFile

__all__ = [
    "CAPTURE_FORMAT",
    "Capture",
    "frame_intensities",
    "projector_captures",
    "read_capture",
    "read_frame",
    "read_truth",
    "write_frame",
    "write_manifest",
]

CAPTURE_FORMAT = "nail2nail-capture"
BIT_DEPTHS = (8, 10, 12, 16)
MANIFEST = "capture.json"
#: The file that makes a directory a capture of several projectors (``docs/projectors.md``).
PROJECTORS = "projectors.json"


def projector_captures(source) -> list[tuple[str, Path]] | None:
    """The captures of a rig of several projectors, one per projector, from ``projectors.json``.

    Parameters
    ----------
    source : path-like
        A directory; a capture of several projectors holds ``projectors.json`` (``{"captures":
        [{"capture": "p0", ...}, ...]}``, as ``nail2nail simulate --projectors`` writes it)
        and one capture directory per projector beside it.

    Returns
    -------
    list of (str, Path) or None
        ``(name, directory)`` per projector, in the file's order; None when `source` holds no
        ``projectors.json`` (a capture of one projector).

    Raises
    ------
    ValueError
        Naming the file: not a layout, no capture or a repeated one, a name that is not a
        directory inside `source`.
    """
    source = Path(source)
    path = source / PROJECTORS
    if not path.is_file():
        return None
    try:
        layout = read_json(path)
        entries = [str(c["capture"]) for c in layout["captures"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a projector layout (expected \"captures\": "
                         f"[{{\"capture\": DIR, ...}}, ...]): {exc}") from exc
    if len(entries) < 1 or len(set(entries)) != len(entries):
        raise ValueError(f"{path}: \"captures\" must name one or more distinct directories, "
                         f"got {entries}")
    out = []
    for name in entries:
        if Path(name).name != name or name in (".", ".."):
            raise ValueError(f"{path}: capture {name!r} is not a directory name inside "
                             f"{source}")
        out.append((name, source / name))
    return out


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
    pattern_set: PatternSet | None = None
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

    def load_frames(self, name: str, *, raw: bool = False) -> np.ndarray:
        """Read (and cache) the frames of camera `name`: ``(n_frames, H, W) float32``.

        With ``raw=True`` the frames' integer values are returned instead, not cached and
        without a float copy: ``uint8`` for ``bit_depth`` 8, ``uint16`` (right-aligned, ``0 …
        2**bit_depth - 1``) otherwise, a quarter (8-bit) or half of the float stack's memory;
        :func:`frame_intensities` turns any part of them into the float frames, bit for bit.
        Frames already cached as floats are read again from disk. The frames are decoded in
        ``min(os.cpu_count(), n_frames)`` threads (Pillow's PNG decoder releases the GIL), each
        straight into the returned stack; the first bad frame, in frame order, raises.

        Raises
        ------
        ValueError
            Naming the frame file: unreadable, not grey, its pixel values not of the manifest's
            ``bit_depth``, or its size not the camera's ``size`` (or, without one, not the size
            of the camera's first frame).
        """
        if raw:
            return self._read_stack(name, raw=True)
        if name not in self.frames:
            self.frames[name] = self._read_stack(name, raw=False)
        return self.frames[name]

    def frame_shape(self, name: str) -> tuple[int, int]:
        """``(H, W)`` of camera `name`'s frames: of its cached frames, or of its first frame on
        disk (read and checked as by :meth:`load_frames`; the others are not read)."""
        if name in self.frames:
            return tuple(self.frames[name].shape[1:])
        return self._read_stack(name, raw=True, first_only=True).shape[1:]

    def _read_stack(self, name: str, *, raw: bool, first_only: bool = False) -> np.ndarray:
        cam = self.camera(name)
        files = [self.path / f for f in (cam["frames"][:1] if first_only else cam["frames"])]
        size = cam.get("size")
        bit_depth = self.bit_depth
        # set here, for every decoding thread (catch_warnings is not thread-safe)
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            first = None
            if size is not None:
                shape = (int(size[1]), int(size[0]))
                said = f"camera {name}'s size in {self.path / MANIFEST} is"
                if _header_shape(files[0]) != shape:  # the stack is not made of a bad size
                    first = _read_values(files[0], bit_depth)  # raises if unreadable
            else:
                first = _read_values(files[0], bit_depth)
                shape = first.shape
                said = f"camera {name}'s first frame is"
            if first is not None and first.shape != shape:
                raise ValueError(f"{files[0]}: frame is {first.shape[1]} x {first.shape[0]} px "
                                 f"(W x H), but {said} {shape[1]} x {shape[0]}")
            dtype = (np.uint8 if bit_depth == 8 else np.dtype("<u2")) if raw else np.float32
            stack = np.empty((len(files), *shape), dtype=dtype)
            scale = np.float32(2**bit_depth - 1)

            def load(i: int) -> None:
                target = stack[i]
                if i == 0 and first is not None:
                    values = first
                else:
                    values = _read_values(files[i], bit_depth, out=target if raw else None)
                if values is target:
                    return
                if values.shape != shape:
                    raise ValueError(f"{files[i]}: frame is {values.shape[1]} x "
                                     f"{values.shape[0]} px (W x H), but {said} {shape[1]} x "
                                     f"{shape[0]}")
                if raw:
                    target[...] = values
                else:  # frame_intensities, bit for bit, without a temporary float frame
                    np.divide(values, scale, out=target, dtype=np.float32)

            _run_in_order(load, len(files))
        return stack


def read_frame(path: str | os.PathLike, *, bit_depth: int = 8, raw: bool = False) -> np.ndarray:
    """One frame as ``(H, W) float32`` in ``[0, 1]``.

    `bit_depth` 8 wants an 8-bit grey PNG; 10, 12 and 16 want a 16-bit grey PNG holding the
    values left-aligned (``v << (16 - bit_depth)``, ``docs/capture-format.md``). With
    ``raw=True`` the values themselves: ``(H, W) uint8`` for 8 bits, ``uint16`` right-aligned
    (``0 … 2**bit_depth - 1``) otherwise; :func:`frame_intensities` makes the floats of them.

    Raises
    ------
    ValueError
        Naming the file: unreadable, truncated or corrupt; not single-channel grey (palette,
        colour, alpha, bilevel, float); or pixel values that are not `bit_depth`-bit values
        stored as the format says (a 16-bit PNG under ``bit_depth`` 8, an 8-bit PNG under 10,
        12 or 16, or low bits set under 10 or 12: values right-aligned, not left-aligned).
    """
    path = Path(path)
    if isinstance(bit_depth, bool) or bit_depth not in BIT_DEPTHS:
        raise ValueError(f"bit_depth: expected one of {BIT_DEPTHS}, got {bit_depth!r}")
    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        values = _read_values(path, bit_depth)
    return values if raw else frame_intensities(values, bit_depth)


def _read_values(path: Path, bit_depth: int, *, out: np.ndarray | None = None) -> np.ndarray:
    """The checked values of one frame (:func:`read_frame` with ``raw=True``).

    With `out` (``(H, W) uint8`` for `bit_depth` 8, little-endian ``uint16`` otherwise) a PNG
    of that size and type is decoded straight into `out`, which is returned; any other file is
    decoded into a new array (`out` untouched, the caller compares sizes). No warning filters
    are set here (the caller's apply; they are process-wide, not per thread).
    """
    try:
        with Image.open(path) as im:
            mode = im.mode
            image = out if out is not None and _decode_into(im, out) else np.asarray(im)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read frame ({_short(exc)})") from exc
    if mode not in ("L", "I;16", "I;16L", "I;16B", "I") or image.ndim != 2:
        raise ValueError(f"{path}: expected a single-channel grey image (8- or 16-bit), got "
                         f"PIL mode {mode} with shape {image.shape}")
    if mode == "I":  # a 16-bit PNG opened as 32-bit integers
        if image.size and (image.min() < 0 or image.max() > 65535):
            raise ValueError(f"{path}: pixel values outside 0 … 65535")
        image = image.astype(np.uint16)
    if bit_depth == 8:
        if image.dtype != np.uint8:
            raise ValueError(f"{path}: a 16-bit image, but the capture's bit_depth is 8 "
                             "(8-bit frames are 8-bit PNGs)")
        return image
    if image.dtype != np.uint16:
        raise ValueError(f"{path}: an 8-bit image, but the capture's bit_depth is {bit_depth} "
                         "(stored in 16-bit PNGs, left-aligned)")
    shift = 16 - bit_depth
    if shift and np.any(image & np.uint16((1 << shift) - 1)):
        raise ValueError(
            f"{path}: {bit_depth}-bit values must be stored left-aligned (value << {shift}) "
            f"but the low {shift} bits are set (largest raw value {int(image.max())}; "
            f"right-aligned values, or a deeper image than bit_depth {bit_depth}?)"
        )
    if image is out:
        return np.right_shift(out, np.uint16(shift), out=out)
    return image >> np.uint16(shift)


def _header_shape(path: Path) -> tuple[int, int] | None:
    """``(H, W)`` of an image file from its header alone; ``None`` if it cannot be opened."""
    try:
        with Image.open(path) as im:
            return im.size[1], im.size[0]
    except Exception:
        return None


_DIRECT_MODES = {np.dtype(np.uint8): "L", np.dtype("<u2"): "I;16"}


def _decode_into(im: ImageFile.ImageFile, out: np.ndarray) -> bool:
    """Decode the opened PNG `im` into `out`'s memory if its mode and size fit; say if done.

    Pillow decodes into the image memory it finds on the image (``ImageFile.load``), here one
    mapped onto `out` (``Image.frombuffer``): no image memory of Pillow's own and no copies
    (``np.asarray`` copies twice). Anything unusual falls back to ``np.asarray`` (``False``).
    """
    mode = _DIRECT_MODES.get(out.dtype)
    if (mode is None or im.mode != mode or im.format != "PNG" or len(im.tile) != 1
            or out.shape != (im.size[1], im.size[0]) or not out.flags.c_contiguous
            or not out.flags.writeable):
        return False
    memory = Image.frombuffer(mode, im.size, out, "raw", mode, 0, 1).im
    im.im = memory
    im.load()
    return im.im is memory and im.mode == mode


def _run_in_order(task, n: int) -> None:
    """``task(i)`` for ``i < n`` in threads; re-raise the error of the first failing ``i``."""
    workers = min(os.cpu_count() or 1, n)
    if workers <= 1:
        for i in range(n):
            task(i)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(task, i) for i in range(n)]
        try:
            for future in futures:
                future.result()
        finally:
            for future in futures:
                future.cancel()


def _short(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 120 else text[:117] + "..."


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
    bit_depth = data.get("bit_depth", 8)
    if isinstance(bit_depth, bool) or bit_depth not in BIT_DEPTHS:
        raise ValueError(f"{where}: bit_depth {bit_depth!r} is not one of {BIT_DEPTHS}")
    cams = data.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise ValueError(f"{where}: 'cameras' must be a non-empty list")
    n = data.get("n_frames")
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise ValueError(f"{where}: n_frames must be a positive integer, got {n!r}")
    for i, cam in enumerate(cams):
        if not isinstance(cam, dict) or not {"name", "frames"} <= set(cam):
            raise ValueError(f"{where}: cameras[{i}] needs 'name' and 'frames'")
        as_name(cam["name"], f"{where}: cameras[{i}].name")
        frames = cam["frames"]
        if not isinstance(frames, list) or not frames or not all(
            isinstance(f, str) for f in frames
        ):
            raise ValueError(f"{where}: cameras[{i}].frames must be a non-empty list of paths")
        if n is not None and len(frames) != n:
            raise ValueError(
                f"{where}: cameras[{i}] lists {len(frames)} frames, n_frames is {n}"
            )
        size = cam.get("size")
        if size is not None and not (
            isinstance(size, list) and len(size) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
        ):
            raise ValueError(f"{where}: cameras[{i}].size must be [W, H] in pixels, got "
                             f"{size!r}")
    check_unique([cam["name"] for cam in cams], where)


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
    check_format(manifest, fmt=CAPTURE_FORMAT, where=str(manifest_path))
    _check_manifest(manifest, where=str(manifest_path))
    for i, cam in enumerate(manifest["cameras"]):
        for f in cam["frames"]:
            confined_path(path, f, f"{manifest_path}: cameras[{i}].frames")
        missing = [f for f in cam["frames"] if not (path / f).is_file()]
        if missing:
            raise ValueError(f"{path}: camera {cam['name']}: {len(missing)} frame file(s) "
                             f"missing (first {missing[0]})")
    pattern_set = None
    if manifest.get("pattern_set") is not None:

        try:
            pattern_set = PatternSet.from_dict(manifest["pattern_set"])
        except (ValueError, TypeError, KeyError, OverflowError) as exc:
            raise ValueError(f"{manifest_path}: pattern_set: {describe_error(exc)}") from exc
        # said here, naming the file and the camera, rather than by the decoder ("frames: the
        # pattern set has 24 frames, got 23") that every command reaches later
        for cam in manifest["cameras"]:
            if len(cam["frames"]) != pattern_set.n_frames:
                raise ValueError(
                    f"{manifest_path}: camera {cam['name']!r} lists {len(cam['frames'])} "
                    f"frames, its pattern_set projects {pattern_set.n_frames} (one frame per "
                    "projected image, in order: nail2nail.scan.patterns.frame_table)")
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
    return read_npz(file, what="ground-truth file")
