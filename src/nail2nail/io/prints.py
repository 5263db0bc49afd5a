"""Fingerprint images: 8-bit grayscale PNG (or any Pillow format) and FBI WSQ, with their ppi.

Prints are ``(H, W) uint8`` arrays, ridges dark on light, in the legacy convention
(``docs/conventions.md``, "Rolled prints"). The resolution is read from a PNG's ``pHYs`` chunk
(Pillow's ``info["dpi"]``) or from the ``PPI`` line of a WSQ file's ``NIST_COM`` comment.

WSQ is encoded and decoded by NIST's NBIS codec as the pinned ``wsq`` package builds it; both
run in a child process (:func:`encode_wsq`, :func:`decode_wsq`): the decoder can crash on
corrupt files, and both print their errors on stderr, which then go into the error's message.
"""

from __future__ import annotations

import os
import re
import signal
import stat
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

from nail2nail._validation import file_kind
from nail2nail.io._atomic import atomic_path

__all__ = [
    "JPEG2000_RATIO",
    "WSQ_BITRATE",
    "WSQ_BITRATE_RANGE",
    "WSQ_MIN_SIDE",
    "decode_jpeg2000",
    "decode_wsq",
    "encode_jpeg2000",
    "encode_wsq",
    "read_print_image",
    "write_print_image",
    "wsq_shape",
]

# a resolution outside this range is taken as "unknown" (e.g. 72 or 96 dpi written by
# tools that know nothing of the scan)
_PPI_RANGE = (200.0, 4000.0)

#: WSQ bit rate by default, bits per pixel: the FBI's target for 500 ppi tenprints (the WSQ
#: specification; NBIS documents 0.75 as "around 15 : 1" on card scans). The ratio it gives
#: depends on the image: 12.2 : 1 on the demo print (README, "Interchange"), whose white margin
#: compresses well; 8 / 0.75 = 10.7 : 1 if every pixel cost the target rate.
WSQ_BITRATE = 0.75
#: Bit rates accepted, bits per pixel: below 0.1 (about 80 : 1) the ridges are gone; above 4
#: (2 : 1) a lossless PNG is about as small and exact, and NBIS's encoder, whose output buffer
#: is the raw image's size, fails on small prints.
WSQ_BITRATE_RANGE = (0.1, 4.0)
#: Smallest side of a WSQ image, px: NBIS's encoder overflows its output buffer on 16 x 16
#: images at 0.75 bpp (its tables alone take about 600 bytes); 64 px is 3.3 mm at 500 ppi,
#: far less than any print.
WSQ_MIN_SIDE = 64
#: JPEG 2000 compression ratio of nail2nail's 1000 ppi prints (irreversible 9/7 wavelet, one
#: quality layer at this rate, OpenJPEG through Pillow): the rate WSQ aims at for 500 ppi.
#: Conformance to NIST SP 500-289's 1000 ppi profile (a certified codec) is not claimed.
JPEG2000_RATIO = 15.0


def _wsq_ppi(data: bytes) -> float | None:
    """PPI of a WSQ file from its NIST_COM comment (``None`` if absent or ``-1``)."""
    pos = 2  # after the SOI marker FFA0
    while pos + 4 <= len(data):
        marker = data[pos : pos + 2]
        if marker in (b"\xff\xa2", b"\xff\xa1") or marker[:1] != b"\xff":
            break  # start of frame (or end / garbage): no more header segments
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker == b"\xff\xa8":
            text = data[pos + 4 : pos + 2 + length].decode("latin-1")
            if text.startswith("NIST_COM"):
                match = re.search(r"^PPI\s+(-?\d+(?:\.\d+)?)\s*$", text, re.MULTILINE)
                if match and float(match.group(1)) > 0:
                    return float(match.group(1))
        pos += 2 + length
    return None


def read_print_image(path: str | os.PathLike) -> tuple[np.ndarray, float | None]:
    """Read a fingerprint image as 8-bit grey, with its resolution if the file records it.

    Grayscale 8-bit images are returned unchanged; colour (RGB, RGBA, palette) and 1-bit
    images are converted to grey with Pillow's ``convert("L")`` (ITU-R 601 luma); 16-bit and
    floating-point images are refused (convert them to 8-bit first, e.g. ``value >> 8``).

    Parameters
    ----------
    path : path-like
        PNG (or another format Pillow reads) or WSQ (``wsq`` plugin).

    Returns
    -------
    image : (H, W) uint8
    ppi : float or None
        PNG: ``info["dpi"]`` rounded to 0.1 (PNG stores pixels per metre); WSQ: the
        ``NIST_COM`` ``PPI``; ``None`` when absent, or (with a warning) outside 200–4000.

    Raises
    ------
    ValueError
        Naming the file: missing, not an image, empty, or 16-bit / floating point.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "print.png"
    >>> _ = write_print_image(path, np.full((4, 6), 200, np.uint8), ppi=500)
    >>> image, ppi = read_print_image(path)
    >>> image.shape, image.dtype.name, ppi
    ((4, 6), 'uint8', 500.0)
    """
    import wsq  # noqa: F401  (registers the WSQ plugin with Pillow)

    path = Path(path)
    try:
        mode = path.stat().st_mode
    except OSError:
        raise ValueError(f"{path}: no such print image file") from None
    if not stat.S_ISREG(mode):  # a FIFO or a device would block or stream: refused unopened
        raise ValueError(f"{path}: {file_kind(mode)}, expected a PNG or WSQ print image file")
    data = path.read_bytes()
    if not data:
        raise ValueError(f"{path}: empty file, expected a PNG or WSQ print image")
    if data[:2] == b"\xff\xa0":  # WSQ: decoded in a child process (see _decode_wsq)
        image, fmt, info = _decode_wsq(path, label=path), "WSQ", {}
        size = image.shape[::-1]
    else:
        try:
            with warnings.catch_warnings(), Image.open(path) as im:
                warnings.simplefilter("error", Image.DecompressionBombWarning)
                im.load()
                mode, size, info = im.mode, im.size, dict(im.info)
                if mode in ("I", "I;16", "I;16B", "I;16L", "I;16N", "F"):
                    raise ValueError(f"{path}: {mode} ({'16-bit' if 'I' in mode else 'float'}) "
                                     "image; expected 8-bit grayscale (convert first, e.g. "
                                     "value >> 8)")
                image = np.asarray(im if mode == "L" else im.convert("L"))
                fmt = im.format
        except ValueError as exc:
            if str(exc).startswith(f"{path}: "):
                raise
            raise ValueError(f"{path}: not a readable image ({_short(exc)})") from exc
        except Exception as exc:  # Pillow raises many types on corrupt data
            raise ValueError(f"{path}: not a readable image ({_short(exc)})") from exc
    if image.size == 0 or 0 in size:
        raise ValueError(f"{path}: empty image ({size[0]}x{size[1]})")
    if fmt == "WSQ":
        ppi = _wsq_ppi(data)
    else:
        dpi = info.get("dpi")
        ppi = round(float(dpi[0]), 1) if dpi else None
    if ppi is not None and not _PPI_RANGE[0] <= ppi <= _PPI_RANGE[1]:
        warnings.warn(f"{path}: recorded resolution {ppi} ppi is implausible for a print; "
                      "ignored", stacklevel=2)
        ppi = None
    return np.ascontiguousarray(image, dtype=np.uint8), ppi


_WSQ_CHILD = r"""
import sys, warnings
from PIL import Image
import wsq  # registers the WSQ plugin
warnings.simplefilter("error", Image.DecompressionBombWarning)
with Image.open(sys.argv[1]) as im:
    im.load()
    im = im if im.mode == "L" else im.convert("L")
    sys.stdout.buffer.write(b"%d %d\n" % im.size + im.tobytes())
"""


def _decode_wsq(path: Path, *, timeout: float = 60.0, label=None) -> np.ndarray:
    """A WSQ file's pixels ``(H, W) uint8``, decoded by the NBIS decoder in a child process.

    The decoder (C, package ``wsq``) crashes the process (SIGSEGV) on some corrupt files and
    prints ``ERROR : …`` lines on stderr for others (found by ``bench/fuzz_readers.py``); in a
    child, a crash is a ``ValueError`` naming the file (or `label`) and the decoder's lines go
    into the message, not onto the terminal (about 0.1 s per file).
    """
    path, shown = Path(path), path if label is None else label
    try:
        proc = subprocess.run([sys.executable, "-c", _WSQ_CHILD, os.fspath(path)],
                              capture_output=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired as exc:
        raise ValueError(f"{shown}: not a readable image (the WSQ decoder took over "
                         f"{timeout:g} s)") from exc
    lines = [" ".join(line.split())[:160]
             for line in proc.stderr.decode("utf-8", "replace").splitlines() if line.strip()]
    native = [line for line in lines if line.startswith("ERROR")]
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        said = f"; {native[0]}" if native else ""
        raise ValueError(f"{shown}: not a readable image (the WSQ decoder crashed: {name}{said})")
    if proc.returncode != 0:
        said = lines[-1] if lines else f"exit status {proc.returncode}"
        said += f"; {native[0]}" if native and native[0] != said else ""
        raise ValueError(f"{shown}: not a readable image ({said})")
    header, _, pixels = proc.stdout.partition(b"\n")
    try:
        width, height = (int(v) for v in header.split())
    except ValueError as exc:
        raise ValueError(f"{shown}: not a readable image (WSQ decoder output)") from exc
    image = np.frombuffer(pixels, dtype=np.uint8)
    if image.size != width * height:
        raise ValueError(f"{shown}: not a readable image (WSQ decoder output)")
    if native:
        warnings.warn(f"{shown}: the WSQ decoder reported {native[0]!r} ({len(native)} "
                      "message(s)); the image may be damaged", stacklevel=3)
    return image.reshape(height, width).copy()


def _short(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 120 else text[:117] + "..."


_WSQ_ENCODE_CHILD = r"""
import ctypes, sys
import _wsq  # the NBIS codec of the wsq package: its exported wsq_encode_mem
height, width, ppi = (int(v) for v in sys.argv[1:4])
bitrate = float(sys.argv[4])
pixels = sys.stdin.buffer.read()
assert len(pixels) == width * height
encode = ctypes.CDLL(_wsq.__file__).wsq_encode_mem
encode.restype = ctypes.c_int
encode.argtypes = [ctypes.POINTER(ctypes.POINTER(ctypes.c_ubyte)), ctypes.POINTER(ctypes.c_int),
                   ctypes.c_float, ctypes.c_char_p, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                   ctypes.c_int, ctypes.c_char_p]
out, size = ctypes.POINTER(ctypes.c_ubyte)(), ctypes.c_int(0)
status = encode(ctypes.byref(out), ctypes.byref(size), bitrate, pixels, width, height, 8, ppi, None)
if status != 0:
    sys.stderr.write("WSQ encoder status %d\n" % status)
    sys.exit(3)
sys.stdout.buffer.write(ctypes.string_at(out, size.value))  # the process ends: no free()
"""


def _check_bitrate(bitrate) -> float:
    if isinstance(bitrate, bool) or not isinstance(bitrate, (int, float, np.floating)):
        raise TypeError(f"bitrate: expected a number of bits per pixel, got "
                        f"{type(bitrate).__name__}")
    low, high = WSQ_BITRATE_RANGE
    if not low <= float(bitrate) <= high:
        raise ValueError(f"bitrate: expected {low:g}..{high:g} bits per pixel, got {bitrate}")
    return float(bitrate)


def _check_print(image) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 2 or image.size == 0:
        raise ValueError(f"image: expected a non-empty (H, W) uint8 array, got {image.dtype} "
                         f"{image.shape}")
    return np.ascontiguousarray(image)


def encode_wsq(image, *, bitrate: float = WSQ_BITRATE, timeout: float = 60.0) -> bytes:
    """Compress a 500 ppi print with FBI WSQ at `bitrate` bits per pixel; return the file's bytes.

    NBIS's ``wsq_encode_mem`` (the encoder of the ``wsq`` package, whose Pillow plugin fixes
    the rate at 0.75) runs in a child process: its errors are a ``ValueError``, not a line of C
    on stderr. At 0.75 the bytes are those of the plugin. The file's ``NIST_COM`` records
    ``PPI 500`` and the requested rate (``WSQ_BITRATE``).

    Parameters
    ----------
    image : (H, W) uint8
        At least ``WSQ_MIN_SIDE`` (64) pixels on each side.
    bitrate : float
        Target bits per pixel, ``WSQ_BITRATE_RANGE`` (0.1–4): it sets the quantisation. The
        achieved rate is below it, the more so the more blank paper the image holds (0.639
        for 0.75 on the demo print, about 0.53 on a real print with 40 % blank).

    Returns
    -------
    bytes
        The WSQ file.

    Raises
    ------
    ValueError
        `image` not a non-empty 2-D uint8 array or smaller than 64 px on a side, `bitrate`
        outside 0.1–4, or the encoder failed (its message included).
    TypeError
        If `bitrate` is not a number.

    Examples
    --------
    >>> rows = np.arange(96)[:, None] + np.zeros((1, 80))
    >>> image = (127.5 + 100 * np.cos(2 * np.pi * rows / 9)).astype(np.uint8)
    >>> data = encode_wsq(image, bitrate=0.75)
    >>> data[:2], wsq_shape(data)
    (b'\\xff\\xa0', (96, 80))
    """
    image = _check_print(image)
    bitrate = _check_bitrate(bitrate)
    height, width = image.shape
    if min(height, width) < WSQ_MIN_SIDE:
        raise ValueError(f"image: WSQ needs at least {WSQ_MIN_SIDE} px on each side, got "
                         f"{height} x {width}")
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _WSQ_ENCODE_CHILD, str(height), str(width), "500",
             repr(bitrate)],
            input=image.tobytes(), capture_output=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired as exc:
        raise ValueError(f"the WSQ encoder took over {timeout:g} s on a {height} x {width} "
                         "image") from exc
    if proc.returncode != 0 or proc.stdout[:2] != b"\xff\xa0":
        lines = [" ".join(line.split())[:160] for line in
                 proc.stderr.decode("utf-8", "replace").splitlines() if line.strip()]
        said = "; ".join(lines[-2:]) or f"exit status {proc.returncode}"
        raise ValueError(f"the WSQ encoder failed on a {height} x {width} image at {bitrate:g} "
                         f"bits per pixel ({said})")
    return proc.stdout


def decode_wsq(data: bytes, *, name: str = "WSQ data") -> np.ndarray:
    """Decode WSQ bytes to ``(H, W) uint8`` with NBIS, in a child process (see
    :func:`read_print_image`); errors are a ``ValueError`` naming `name`."""
    import tempfile

    if not isinstance(data, (bytes, bytearray)):
        raise TypeError(f"{name}: expected bytes, got {type(data).__name__}")
    if bytes(data[:2]) != b"\xff\xa0":
        raise ValueError(f"{name}: not WSQ data (no start-of-image marker FFA0)")
    with tempfile.TemporaryDirectory(prefix="nail2nail-wsq-") as tmp:
        path = Path(tmp) / "image.wsq"
        path.write_bytes(bytes(data))
        return _decode_wsq(path, label=name)


def wsq_shape(data: bytes) -> tuple[int, int]:
    """``(height, width)`` from a WSQ file's frame header, without decoding it.

    Raises
    ------
    ValueError
        If `data` is not WSQ or has no frame header.
    """
    data = bytes(data)
    if data[:2] != b"\xff\xa0":
        raise ValueError("not WSQ data (no start-of-image marker FFA0)")
    pos = 2
    while pos + 4 <= len(data):
        marker = data[pos: pos + 2]
        if marker == b"\xff\xa2":  # start of frame: length (2), black, white, height, width
            if pos + 10 > len(data):
                break
            return (int.from_bytes(data[pos + 6: pos + 8], "big"),
                    int.from_bytes(data[pos + 8: pos + 10], "big"))
        if marker[:1] != b"\xff" or marker == b"\xff\xa1":
            break
        pos += 2 + int.from_bytes(data[pos + 2: pos + 4], "big")
    raise ValueError("not WSQ data (no frame header FFA2)")


def encode_jpeg2000(image, *, ratio: float = JPEG2000_RATIO) -> bytes:
    """Compress a print ``(H, W) uint8`` as a lossy JPEG 2000 file (JP2) at `ratio` : 1.

    Raises
    ------
    ValueError
        If `image` is not a non-empty 2-D uint8 array or `ratio` is not above 1.
    """
    import io

    image = _check_print(image)
    if not float(ratio) > 1.0:
        raise ValueError(f"ratio: expected a compression ratio above 1, got {ratio}")
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG2000", irreversible=True,
                                quality_mode="rates", quality_layers=[float(ratio)])
    return buffer.getvalue()


def decode_jpeg2000(data: bytes, *, name: str = "JPEG 2000 data") -> np.ndarray:
    """Decode JPEG 2000 bytes to ``(H, W) uint8``; errors are a ``ValueError`` naming `name`."""
    import io

    try:
        with warnings.catch_warnings(), Image.open(io.BytesIO(bytes(data))) as im:
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            if im.format != "JPEG2000":
                raise ValueError(f"{im.format} image")
            im.load()
            if im.mode != "L":
                raise ValueError(f"{im.mode} image, expected 8-bit grey")
            return np.array(im, dtype=np.uint8)
    except Exception as exc:  # Pillow raises many types on corrupt data
        raise ValueError(f"{name}: not a readable JPEG 2000 image ({_short(exc)})") from exc


def write_print_image(path: str | os.PathLike, image, *, ppi: float = 500.0,
                      bitrate: float = WSQ_BITRATE) -> Path:
    """Write a print ``(H, W) uint8`` as PNG (with its dpi) or WSQ (by suffix), atomically.

    WSQ (``.wsq``, lossy, at `bitrate` bits per pixel: :func:`encode_wsq`) is the FBI's
    format for 500 ppi prints and records ``PPI 500``, so it is refused for another `ppi`.

    Raises
    ------
    ValueError
        If `image` is not a non-empty 2-D uint8 array, WSQ is asked for at another ppi, or
        (WSQ) as :func:`encode_wsq`.
    """
    path = Path(path)
    image = _check_print(image)
    is_wsq = path.suffix.lower() == ".wsq"
    if is_wsq and abs(ppi - 500.0) > 1e-6:
        raise ValueError(f"{path}: the WSQ writer records 500 ppi only, got ppi={ppi}")
    if is_wsq:
        try:
            data = encode_wsq(image, bitrate=bitrate)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
    else:
        with atomic_path(path) as tmp:
            Image.fromarray(image).save(tmp, format="PNG", dpi=(float(ppi), float(ppi)))
    return path
