"""The thesis's legacy **mat5** scan format: ``<prefix>C.bmp``, ``I.bmp``, ``X.by`` … ``YP.by``.

Exactly what the appendix MATLAB code reads (thesis appendix, "Matlab Code for finding Error in
Merging of Scans")::

    c1 = imread([name 'C.bmp']);  [My, Nx, a] = size(c1);     % 24-bit RGB albedo
    i1 = imread([name 'I.bmp']);                             % intensity, i1(m, n) > 0 = valid
    fd = fopen([name 'X.by']); xw1 = fread(fd, 'float');     % little-endian float32
    xw1 = reshape(xw1, Nx, My)';                             % -> My x Nx, row-major on disk

Files
-----
``C.bmp``
    Albedo, 24-bit RGB BMP (grey: R = G = B = ``round(255 albedo)``), ``My x Nx``.
``I.bmp``
    Intensity, 8-bit grey BMP, ``round(255 intensity)`` clamped to ``[1, 255]`` on valid pixels and
    **0 on invalid pixels** (the validity mask of the legacy readers).
``X.by``, ``Y.by``, ``Z.by``, ``XP.by``, ``YP.by``
    World ``X, Y, Z`` (mm) and projector ``xp, yp`` (panel px): ``My * Nx`` little-endian
    ``float32``, row-major (row 0 first), no header. Invalid pixels hold **0** (the legacy readers
    expect numbers, and test ``I > 0``); valid pixels hold the values exactly (NaN stays NaN, e.g.
    ``xp`` of a scan decoded from ``y`` patterns only).

Round trip: :func:`read_mat5` returns the float32 arrays bit-exactly on valid pixels and NaN on
invalid ones; albedo and intensity come back quantised to 8 bits, and ``modulation`` (not stored)
as ``intensity / 2`` (``intensity = 2 B``, :class:`nail2nail.scan.results.Decoded`). Writing what
was read
reproduces the files byte for byte.
"""

from __future__ import annotations

import os
import struct
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

from nail2nail.io._atomic import atomic_path
from nail2nail.scan.results import Scan

__all__ = ["MAT5_SUFFIXES", "mat5_paths", "read_mat5", "write_mat5"]

MAT5_SUFFIXES = ("C.bmp", "I.bmp", "X.by", "Y.by", "Z.by", "XP.by", "YP.by")
_FLOAT = np.dtype("<f4")


def mat5_paths(prefix: str | os.PathLike) -> dict[str, Path]:
    """The seven file paths of a mat5 set, keyed by suffix (``"C.bmp"`` … ``"YP.by"``).

    Examples
    --------
    >>> mat5_paths("out/cam0")["XP.by"].as_posix()
    'out/cam0XP.by'
    """
    prefix = os.fspath(prefix)
    return {suffix: Path(prefix + suffix) for suffix in MAT5_SUFFIXES}


def _to_8bit(value) -> np.ndarray:
    """``round(255 value)`` as ``uint8``, ``value`` clipped to ``[0, 1]``, NaN as 0 (float64
    arithmetic: ``255 v`` of a float32 is exact, so the ties fall as they always have)."""
    scaled = np.multiply(value, 255.0, dtype=np.float64)
    np.fmax(scaled, 0.0, out=scaled)  # fmax/fmin drop NaN: 0
    np.fmin(scaled, 255.0, out=scaled)
    return np.rint(scaled, out=scaled).astype(np.uint8)


def _finite_pixels(xyz: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: all three coordinates finite (channel by channel: a reduction over a
    last axis of 3 is slow in numpy)."""
    finite = np.isfinite(xyz[..., 0])
    finite &= np.isfinite(xyz[..., 1])
    finite &= np.isfinite(xyz[..., 2])
    return finite


_PPM = int(96 * 39.3701 + 0.5)  # Pillow's default 96 dpi, in pixels per metre
_GREY_PALETTE = b"".join(bytes((i, i, i, 0)) for i in range(256))  # B, G, R, 0


def _write_bmp(path: Path, image: np.ndarray) -> None:
    """`image` ``(H, W)`` (8-bit grey, palette) or ``(H, W, 3)`` (24-bit RGB) ``uint8`` as an
    uncompressed BMP, byte for byte what Pillow writes (rows bottom-up, padded to 4 bytes,
    BGR), atomically; a single copy of the pixels, no Pillow image."""
    height, width = image.shape[:2]
    channels = 1 if image.ndim == 2 else 3
    stride = (width * channels + 3) & ~3
    palette = _GREY_PALETTE if channels == 1 else b""
    colors = len(palette) // 4
    offset = 14 + 40 + len(palette)
    header = struct.pack("<2sIII", b"BM", offset + stride * height, 0, offset)
    info = struct.pack("<IiiHHIIiiII", 40, width, height, 1, 8 * channels, 0, stride * height,
                       _PPM, _PPM, colors, colors)
    rows = np.zeros((height, stride), dtype=np.uint8)
    if channels == 1:
        rows[:, :width] = image[::-1]
    else:
        rows[:, : 3 * width].reshape(height, width, 3)[...] = image[::-1, :, ::-1]
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header + info + palette)
        rows.tofile(fh)


def _check_scan(scan) -> tuple[int, int]:
    if not isinstance(scan, Scan):
        raise TypeError(f"scan: expected a Scan, got {type(scan).__name__}")
    mask = np.asarray(scan.mask)
    if mask.ndim != 2 or mask.dtype != bool:
        raise ValueError(f"scan.mask: expected an (H, W) bool array, got {mask.dtype} {mask.shape}")
    shape = mask.shape
    for name in ("xp", "yp", "albedo", "intensity"):
        if np.shape(getattr(scan, name)) != shape:
            raise ValueError(f"scan.{name}: expected shape {shape}, got "
                             f"{np.shape(getattr(scan, name))}")
    if np.shape(scan.xyz) != (*shape, 3):
        raise ValueError(f"scan.xyz: expected shape {(*shape, 3)}, got {np.shape(scan.xyz)}")
    return shape


def write_mat5(prefix: str | os.PathLike, scan: Scan) -> list[Path]:
    """Write `scan` as a mat5 set ``<prefix>C.bmp`` … ``<prefix>YP.by`` (each file atomically).

    Parameters
    ----------
    prefix : path-like
        Path prefix, e.g. ``out/cam0`` for ``out/cam0C.bmp``; its directory is created.
    scan : Scan
        ``scan.mask`` decides validity (a valid pixel with non-finite ``xyz`` is written invalid).

    Returns
    -------
    list of Path
        The seven files, in :data:`MAT5_SUFFIXES` order.

    Raises
    ------
    TypeError, ValueError
        If `scan` is not a :class:`~nail2nail.scan.results.Scan` of consistent shapes.
    """
    _check_scan(scan)
    xyz = np.asarray(scan.xyz, dtype=np.float32)
    valid = np.asarray(scan.mask) & _finite_pixels(xyz)
    albedo = _to_8bit(scan.albedo)
    intensity = _to_8bit(scan.intensity)
    np.maximum(intensity, 1, out=intensity)
    intensity[~valid] = 0
    planes = {
        "X.by": xyz[..., 0], "Y.by": xyz[..., 1], "Z.by": xyz[..., 2],
        "XP.by": np.asarray(scan.xp, dtype=np.float32),
        "YP.by": np.asarray(scan.yp, dtype=np.float32),
    }
    paths = mat5_paths(prefix)
    paths["C.bmp"].parent.mkdir(parents=True, exist_ok=True)
    _write_bmp(paths["C.bmp"], np.broadcast_to(albedo[..., None], (*albedo.shape, 3)))
    _write_bmp(paths["I.bmp"], intensity)
    for suffix, plane in planes.items():
        data = np.where(valid, plane, np.float32(0.0)).astype(_FLOAT, copy=False)
        with atomic_path(paths[suffix]) as tmp, open(tmp, "wb") as fh:
            data.tofile(fh)
    return list(paths.values())


def _read_bmp(path: Path) -> np.ndarray:
    try:
        with warnings.catch_warnings(), Image.open(path) as image:
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            if image.format != "BMP":
                raise ValueError(f"{path}: expected a BMP image, got {image.format}")
            return np.asarray(image.convert("RGB") if image.mode not in ("L", "RGB") else image)
    except FileNotFoundError:
        raise
    except ValueError as exc:
        if str(exc).startswith(f"{path}: "):
            raise
        raise ValueError(f"{path}: not a readable BMP ({_short(exc)})") from exc
    except Exception as exc:  # Pillow raises OSError, SyntaxError, DecompressionBombError …
        raise ValueError(f"{path}: not a readable BMP ({_short(exc)})") from exc


def _short(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 120 else text[:117] + "..."


def read_mat5(prefix: str | os.PathLike, *, name: str | None = None) -> Scan:
    """Read a mat5 set written by :func:`write_mat5` (or by the thesis's software).

    Parameters
    ----------
    prefix : path-like
        Path prefix of the set (``out/cam0`` for ``out/cam0C.bmp``).
    name : str, optional
        Camera name of the returned scan; the prefix's file name by default.

    Returns
    -------
    Scan
        ``xyz``, ``xp``, ``yp`` float32 (NaN where ``I == 0``), ``albedo`` from the C image's first
        channel and ``intensity`` from the I image, both ``/ 255``; ``modulation = intensity / 2``;
        ``mask = I > 0``; ``camera_center = None``.

    Raises
    ------
    FileNotFoundError
        If a file of the set is missing.
    ValueError
        If a ``.by`` file does not hold ``Nx * My`` float32 (``Nx``, ``My`` from the C image).
    """
    paths = mat5_paths(prefix)
    color = _read_bmp(paths["C.bmp"])
    if color.ndim != 3:
        raise ValueError(f"{paths['C.bmp']}: expected a 24-bit RGB image, got shape {color.shape}")
    my, nx = color.shape[:2]  # [My, Nx, a] = size(c1)
    intensity = _read_bmp(paths["I.bmp"])
    if intensity.ndim == 3:
        intensity = intensity[..., 0]
    if intensity.shape != (my, nx):
        raise ValueError(f"{paths['I.bmp']}: expected {my} x {nx} pixels, got {intensity.shape}")
    mask = intensity > 0
    planes = {}
    for suffix in ("X.by", "Y.by", "Z.by", "XP.by", "YP.by"):
        raw = paths[suffix].read_bytes()
        if len(raw) != 4 * nx * my:
            raise ValueError(
                f"{paths[suffix]}: expected {nx} x {my} float32 ({4 * nx * my} bytes), "
                f"got {len(raw)} bytes"
            )
        plane = np.frombuffer(raw, dtype=_FLOAT).reshape(my, nx).astype(np.float32)
        plane[~mask] = np.nan
        planes[suffix] = plane
    intensity_f = intensity.astype(np.float32) / np.float32(255.0)
    return Scan(
        name=Path(os.fspath(prefix)).name if name is None else name,
        xyz=np.stack([planes["X.by"], planes["Y.by"], planes["Z.by"]], axis=-1),
        xp=planes["XP.by"],
        yp=planes["YP.by"],
        albedo=color[..., 0].astype(np.float32) / np.float32(255.0),
        intensity=intensity_f,
        modulation=intensity_f / np.float32(2.0),
        mask=mask,
    )
