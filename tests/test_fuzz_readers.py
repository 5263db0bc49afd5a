"""Issue 10: property-based fuzzing (hypothesis) of every file reader.

Each reader starts from a valid file written by nail2nail's own writer; hypothesis mutates it
(binary files: bit flips, overwrites with boundary values, truncation, insertion, deletion;
JSON: dropped keys, wrong types, NaN/inf, huge and negative numbers, wrong nesting, unicode,
byte-order marks, truncation, deep nesting; points tables: cells, rows, columns, delimiters,
encodings) or builds a structurally odd file from scratch (PNG of every Pillow mode, PNG headers
with huge sizes and a valid CRC, npz of random arrays, PLY headers with odd counts and types).

The invariant (:func:`check_reader`): the reader returns an object that passes the target's
validity check, or raises ``ValueError``/``TypeError``/``OSError`` whose message names a file
of the case directory; never another exception, never a warning that names no file, never
more than a few seconds, never an ``open`` outside the case directory (a Python audit hook
records every ``open``).

``bench/fuzz_readers.py`` runs the same targets with ≥ 10⁵ cases in total.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import shutil
import struct
import sys
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from _robustness import Timeout, time_limit
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

import nail2nail
from nail2nail.calibration.files import RigCalibration, load_calibration
from nail2nail.io._json import read_json
from nail2nail.io._npz import read_npz
from nail2nail.io.capture import Capture, read_capture, read_frame, write_frame, write_manifest
from nail2nail.io.mat5 import MAT5_SUFFIXES, mat5_paths, read_mat5, write_mat5
from nail2nail.io.ply import PlyData, read_ply, write_ply
from nail2nail.io.points import REQUIRED_COLUMNS, PointsTable, read_points, thesis_table
from nail2nail.io.prints import read_print_image, write_print_image
from nail2nail.io.scans import load_scan_npz, load_scans, save_scans
from nail2nail.scan.patterns import Frequency, PatternSet
from nail2nail.scan.results import Scan
from nail2nail.simulation.rig import Rig, default_rig, load_rig, save_rig

# --------------------------------------------------------------------------------------------
# the invariant


class _Watch:
    """Records every ``open`` of a path outside the allowed roots while active."""

    active: Path | None = None
    outside: ClassVar[list[str]] = []
    installed = False
    allowed: tuple[str, ...] = ()


def _audit(event, args):
    if event != "open" or _Watch.active is None:
        return
    target = args[0]
    if target is None or isinstance(target, int):
        return
    try:
        path = os.path.realpath(os.fsdecode(target))
    except (TypeError, ValueError):
        return
    if not path.startswith(_Watch.allowed):
        _Watch.outside.append(path)


def _install_watch() -> None:
    if not _Watch.installed:
        package = os.path.realpath(os.path.dirname(nail2nail.__file__))
        prefixes = {os.path.realpath(p) for p in (sys.prefix, sys.base_prefix, sys.exec_prefix)}
        _Watch.allowed = (package, *sorted(prefixes), "/dev/", "/proc/", "/sys/")
        sys.addaudithook(_audit)
        _Watch.installed = True




def check_reader(read, root: Path, validate, *, seconds: float = 10.0) -> str | None:
    """Run ``read()`` on case directory `root`; ``None`` if the invariant holds, else why not."""
    root = Path(root)
    names = {str(root), os.path.realpath(root)}
    _install_watch()
    _Watch.outside = []
    _Watch.active = root
    saved_allowed = _Watch.allowed
    _Watch.allowed = (*saved_allowed, os.path.realpath(root) + os.sep)
    problem = None
    try:
        with warnings.catch_warnings(record=True) as caught, time_limit(seconds):
            warnings.simplefilter("always")
            try:
                result = read()
            except (ValueError, TypeError) as exc:
                if not any(n in str(exc) for n in names):
                    problem = f"{type(exc).__name__} not naming the file: {exc}"
            except OSError as exc:
                where = f"{exc} {exc.filename}"
                if not any(n in where for n in names):
                    problem = f"OSError not naming the file: {exc!r}"
            except Timeout:
                problem = f"no answer within {seconds} s"
            except Exception as exc:
                problem = f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
            else:
                try:
                    validate(result)
                except AssertionError as exc:
                    problem = f"returned an invalid object: {exc}"
        for w in caught:
            if not any(n in str(w.message) for n in names):
                problem = problem or f"warning not naming the file: {w.category.__name__}: " \
                                     f"{w.message}"
    finally:
        _Watch.active = None
        _Watch.allowed = saved_allowed
    if _Watch.outside:
        problem = problem or f"opened outside the directory: {_Watch.outside[:3]}"
    return problem


# --------------------------------------------------------------------------------------------
# mutations

_BOUNDARY_INTS = [0, 1, 0x7F, 0x80, 0xFF, 0x7FFF, 0x8000, 0xFFFF, 0x7FFFFFFF, 0x80000000,
                  0xFFFFFFFF]


@st.composite
def mutated_bytes(draw, original: bytes, max_ops: int = 4) -> bytes:
    """`original` after 1 … `max_ops` random byte-level edits."""
    buf = bytearray(original)
    for _ in range(draw(st.integers(1, max_ops))):
        n = len(buf)
        op = draw(st.sampled_from(["flip", "byte", "word", "truncate", "insert", "delete",
                                   "repeat"]))
        if op == "flip" and n:
            buf[draw(st.integers(0, n - 1))] ^= 1 << draw(st.integers(0, 7))
        elif op == "byte" and n:
            buf[draw(st.integers(0, n - 1))] = draw(st.sampled_from([0, 0x7F, 0x80, 0xFF])
                                                    | st.integers(0, 255))
        elif op == "word" and n >= 4:
            i = draw(st.integers(0, n - 4))
            value = draw(st.sampled_from(_BOUNDARY_INTS))
            buf[i:i + 4] = value.to_bytes(4, draw(st.sampled_from(["little", "big"])))
        elif op == "truncate":
            del buf[draw(st.integers(0, n)):]
        elif op == "insert":
            i = draw(st.integers(0, n))
            buf[i:i] = draw(st.binary(min_size=1, max_size=16))
        elif op == "delete" and n:
            i = draw(st.integers(0, n - 1))
            del buf[i:i + draw(st.integers(1, 16))]
        elif op == "repeat" and n:
            i = draw(st.integers(0, n - 1))
            j = min(n, i + draw(st.integers(1, 64)))
            buf[i:i] = buf[i:j] * draw(st.integers(1, 3))
    return bytes(buf)


_SPECIAL_NUMBERS = [float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 1e-320, 0, -1,
                    0.5, 2**31, 2**63, 2**64, -(2**63), 10**30, 1e6]
_SPECIAL_STRINGS = ["", " ", "..", "../secret", "/etc/passwd", "a/b", "a\\b", "C:x", "\x00",
                    "\u202e", "é", "\ufeff", "nan", "1", "cam0", "cam1", "dlt", "pinhole",
                    "x" * 200, "🙂"]
_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.sampled_from(_SPECIAL_NUMBERS),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.sampled_from(_SPECIAL_STRINGS),
)
_JSON_VALUES = st.recursive(
    _SCALARS,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                max_size=4),
    max_leaves=8,
)


def _locations(node, parent=None, key=None, out=None):
    """Every (parent, key) of the JSON tree, the root as (None, None)."""
    out = [] if out is None else out
    out.append((parent, key))
    if isinstance(node, dict):
        for k in list(node):
            _locations(node[k], node, k, out)
    elif isinstance(node, list):
        for i in range(len(node)):
            _locations(node[i], node, i, out)
    return out


@st.composite
def mutated_json_value(draw, original, max_ops: int = 3):
    """A deep copy of the JSON value `original` after 1 … `max_ops` structural edits."""
    root = [copy.deepcopy(original)]
    for _ in range(draw(st.integers(1, max_ops))):
        locs = _locations(root[0], root, 0)
        parent, key = draw(st.sampled_from(locs))
        value = parent[key]
        op = draw(st.sampled_from(["delete", "replace", "number", "string", "wrap", "unwrap",
                                   "empty", "add_key", "duplicate", "stringify"]))
        if op == "delete" and parent is not root:
            del parent[key]
        elif op == "replace":
            parent[key] = draw(_JSON_VALUES)
        elif op == "number":
            parent[key] = draw(st.sampled_from(_SPECIAL_NUMBERS) | st.integers(-(2**66), 2**66))
        elif op == "string":
            parent[key] = draw(st.sampled_from(_SPECIAL_STRINGS) | st.text(max_size=8))
        elif op == "wrap":
            parent[key] = draw(st.sampled_from([[value], {"value": value}]))
        elif op == "unwrap" and isinstance(value, list | dict) and value:
            parent[key] = next(iter(value.values())) if isinstance(value, dict) else value[0]
        elif op == "empty":
            parent[key] = type(value)() if isinstance(value, list | dict | str) else None
        elif op == "add_key" and isinstance(value, dict):
            value[draw(st.text(max_size=8))] = draw(_JSON_VALUES)
        elif op == "duplicate" and isinstance(value, list) and value:
            value.append(copy.deepcopy(value[draw(st.integers(0, len(value) - 1))]))
        elif op == "stringify":
            parent[key] = json.dumps(value, allow_nan=True)
    return root[0]


@st.composite
def mutated_json_text(draw, original) -> bytes:
    """JSON file bytes: `original` (a JSON value) structurally mutated, then maybe byte-mutated."""
    kind = draw(st.sampled_from(["structure"] * 6 + ["bytes", "bom", "empty", "deep", "latin1",
                                                      "utf16"]))
    if kind == "empty":
        return draw(st.sampled_from([b"", b" ", b"\n", b"null", b"[]", b"{}", b"0", b'""']))
    if kind == "deep":
        depth = draw(st.sampled_from([100, 1000, 10**5]))
        return draw(st.sampled_from([b"[" * depth + b"]" * depth, b'{"a":' * depth + b"1"
                                     + b"}" * depth]))
    value = original if kind != "structure" else draw(mutated_json_value(original))
    text = json.dumps(value, allow_nan=True, ensure_ascii=draw(st.booleans()),
                      indent=draw(st.sampled_from([None, 2])))
    if kind == "bom":
        return b"\xef\xbb\xbf" + text.encode("utf-8")
    if kind == "latin1":
        return (text + "é").encode("latin-1", "replace")
    if kind == "utf16":
        return text.encode("utf-16")
    data = text.encode("utf-8")
    if kind == "bytes":
        data = draw(mutated_bytes(data, max_ops=3))
    return data


# --------------------------------------------------------------------------------------------
# validity of what a reader returns


def _finite(a) -> bool:
    return bool(np.all(np.isfinite(np.asarray(a, dtype=np.float64))))


def valid_points(table):
    assert isinstance(table, PointsTable)
    n = len(table.columns["Xw"])
    assert n >= 1
    for c in REQUIRED_COLUMNS:
        assert table.columns[c].shape == (n,), c
        assert _finite(table.columns[c]), c
    assert len(table.labels) == n


def valid_scan(scan):
    assert isinstance(scan, Scan)
    mask = np.asarray(scan.mask)
    assert mask.ndim == 2 and mask.dtype == bool, (mask.dtype, mask.shape)
    for name in ("xp", "yp", "albedo", "intensity", "modulation"):
        assert np.shape(getattr(scan, name)) == mask.shape, name
        assert np.issubdtype(np.asarray(getattr(scan, name)).dtype, np.floating), name
    assert np.shape(scan.xyz) == (*mask.shape, 3)
    assert np.issubdtype(np.asarray(scan.xyz).dtype, np.floating)
    if scan.camera_center is not None:
        assert np.shape(scan.camera_center) == (3,)


def valid_scans(scans):
    assert isinstance(scans, list) and scans
    for scan in scans:
        valid_scan(scan)


def valid_capture(capture):
    assert isinstance(capture, Capture)
    for name in capture.camera_names:
        frames = capture.frames[name]
        assert frames.ndim == 3 and frames.dtype == np.float32
        assert frames.shape[0] == len(capture.camera(name)["frames"])
        assert np.all((frames >= 0) & (frames <= 1))
    if capture.pattern_set is not None:
        assert isinstance(capture.pattern_set, PatternSet)


def valid_calibration(calib):
    assert isinstance(calib, RigCalibration) and calib.cameras
    names = [c.name for c in calib.cameras]
    assert len(set(names)) == len(names)
    for cam in calib.cameras:
        for model in (cam.camera, cam.projector):
            if isinstance(model, np.ndarray):
                assert model.shape == (3, 4) and _finite(model)
            else:
                assert _finite(model.K) and _finite(model.R) and _finite(model.t)
                assert _finite(model.dist) and all(int(v) == v > 0 for v in model.size)


def valid_rig(rig):
    assert isinstance(rig, Rig)
    assert len(rig.camera_names) == len(rig.cameras) >= 1
    assert len(set(rig.camera_names)) == len(rig.camera_names)
    assert all(isinstance(n, str) for n in rig.camera_names)


def valid_npz(arrays):
    assert isinstance(arrays, dict)
    for value in arrays.values():
        assert isinstance(value, np.ndarray) and value.dtype != object


def valid_ply(ply):
    assert isinstance(ply, PlyData)
    n = len(ply.points)
    assert ply.points.shape == (n, 3) and ply.points.dtype == np.float32
    if ply.colors is not None:
        assert ply.colors.shape == (n, 3)
    if ply.normals is not None:
        assert ply.normals.shape == (n, 3)
    if ply.faces is not None:
        assert ply.faces.ndim == 2 and ply.faces.shape[1] == 3
        assert ply.faces.size == 0 or (ply.faces.min() >= 0 and ply.faces.max() < n)


def valid_frame(frame):
    assert isinstance(frame, np.ndarray) and frame.ndim == 2 and frame.dtype == np.float32
    assert frame.size and np.all((frame >= 0) & (frame <= 1))


def valid_print(result):
    image, ppi = result
    assert image.ndim == 2 and image.dtype == np.uint8 and image.size
    assert ppi is None or (math.isfinite(ppi) and 200 <= ppi <= 4000)


# --------------------------------------------------------------------------------------------
# valid starting files (small, written by nail2nail's writers)


def _small_scan(name="cam0", shape=(4, 5)) -> Scan:
    rng = np.random.default_rng(0)
    h, w = shape
    mask = rng.random(shape) > 0.3
    return Scan(name=name, xyz=rng.normal(size=(h, w, 3)).astype(np.float32),
                xp=rng.random(shape).astype(np.float32) * 100,
                yp=rng.random(shape).astype(np.float32) * 100,
                albedo=rng.random(shape).astype(np.float32),
                intensity=rng.random(shape).astype(np.float32),
                modulation=rng.random(shape).astype(np.float32), mask=mask,
                camera_center=np.array([0.0, 0.0, 150.0]))


def _png_bytes(array, **save) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG", **save)
    return buf.getvalue()


@dataclass
class Originals:
    """Valid files of every kind, as bytes or JSON values, built once per run."""

    base: Path
    points: bytes
    manifest: dict
    calibration: dict
    rig: dict
    scan_json: dict
    scan_npz: bytes
    mat5: dict
    ply_binary: bytes
    ply_ascii: bytes
    frame8: bytes
    frame12: bytes
    print_png: bytes
    print_wsq: bytes


def make_originals(base: Path) -> Originals:
    """Write one valid file of each kind under `base` with nail2nail's writers."""
    base.mkdir(parents=True, exist_ok=True)
    work = base / "originals"
    work.mkdir(exist_ok=True)
    from nail2nail.io.points import write_points

    table = thesis_table(0)
    table.columns = {k: v[:8] for k, v in table.columns.items()}
    table.labels = table.labels[:8]
    write_points(work / "points.tsv", table)
    rng = np.random.default_rng(1)
    frame = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    write_frame(work / "f8.png", frame)
    write_frame(work / "f12.png", (rng.integers(0, 4096, (6, 8)) << 4).astype(np.uint16))
    pattern = PatternSet(y=(Frequency(1, 3), Frequency(8, 3)))
    cap = work / "capture"
    frames = []
    for i in range(pattern.n_frames):
        frames.append(f"cam0/{i:03d}.png")
        write_frame(cap / frames[-1], rng.integers(0, 256, (6, 8), dtype=np.uint8))
    cams = [{"name": "cam0", "size": [8, 6], "frames": frames},
            {"name": "cam1", "size": [8, 6], "frames": frames}]
    write_manifest(cap, {"bit_depth": 8, "n_frames": pattern.n_frames,
                         "pattern_set": pattern.to_dict(), "cameras": cams})
    p = np.hstack([np.eye(3), np.ones((3, 1))]).tolist()
    calibration = {"format": "nail2nail-calibration", "version": 1,
                   "cameras": [{"name": "cam0", "camera": {"model": "dlt", "matrix": p,
                                                           "size": [8, 6]},
                                "projector": {"model": "dlt", "matrix": p}},
                               {"name": "cam1", "camera": default_rig(0.0625).cameras[1].to_dict(),
                                "projector": {"model": "dlt", "matrix": p}}],
                   "projector_distortion": {"center": [640, 1000], "rho": -0.004}}
    save_rig(work / "rig.json", default_rig(0.0625))
    scans = [_small_scan("cam0"), _small_scan("cam1")]
    manifest = save_scans(work / "scans", scans, mat5=False, ply=False)
    write_mat5(work / "mat5" / "cam0", scans[0])
    write_ply(work / "b.ply", rng.normal(size=(5, 3)), colors=rng.integers(0, 256, (5, 3)),
              normals=rng.normal(size=(5, 3)), faces=[[0, 1, 2], [2, 3, 4]])
    ascii_ply = (b"ply\nformat ascii 1.0\ncomment x\nelement vertex 4\nproperty float x\n"
                 b"property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n"
                 b"property uchar blue\nelement face 2\nproperty list uchar int vertex_indices\n"
                 b"end_header\n0 0 0 1 2 3\n1 0 0 4 5 6\n0 1 0 7 8 9\n1 1 1 10 11 12\n"
                 b"3 0 1 2\n3 1 2 3\n")
    write_print_image(work / "print.png", rng.integers(0, 256, (16, 16), dtype=np.uint8))
    write_print_image(work / "print.wsq", rng.integers(0, 256, (64, 64), dtype=np.uint8))
    # outside every case directory: what a confined reader must never open
    for name in ("secret.png", "secret.npz", "secret.json"):
        shutil.copy(work / {"secret.png": "f8.png", "secret.npz": "scans/cam0.npz",
                            "secret.json": "rig.json"}[name], base / name)
    return Originals(
        base=base,
        points=(work / "points.tsv").read_bytes(),
        manifest=read_json(cap / "capture.json"),
        calibration=calibration,
        rig=read_json(work / "rig.json"),
        scan_json=manifest,
        scan_npz=(work / "scans" / "cam0.npz").read_bytes(),
        mat5={s: p.read_bytes() for s, p in mat5_paths(work / "mat5" / "cam0").items()},
        ply_binary=(work / "b.ply").read_bytes(),
        ply_ascii=ascii_ply,
        frame8=(work / "f8.png").read_bytes(),
        frame12=(work / "f12.png").read_bytes(),
        print_png=(work / "print.png").read_bytes(),
        print_wsq=(work / "print.wsq").read_bytes(),
    )


# --------------------------------------------------------------------------------------------
# structured generators


@st.composite
def odd_png(draw) -> bytes:
    """A well-formed PNG of any Pillow mode and size, or one whose IHDR claims a huge size."""
    kind = draw(st.sampled_from(["mode", "mode", "huge"]))
    h, w = draw(st.integers(1, 9)), draw(st.integers(1, 9))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    if kind == "mode":
        mode = draw(st.sampled_from(["L", "LA", "RGB", "RGBA", "P", "1", "I;16", "u16hi"]))
        if mode in ("L", "P"):
            im = Image.fromarray(rng.integers(0, 256, (h, w), dtype=np.uint8))
            im = im.convert("P") if mode == "P" else im
        elif mode in ("LA", "RGB", "RGBA"):
            im = Image.fromarray(rng.integers(0, 256, (h, w, len(mode)), dtype=np.uint8))
        elif mode == "1":
            im = Image.fromarray(rng.random((h, w)) > 0.5)
        elif mode == "I;16":
            im = Image.fromarray(rng.integers(0, 65536, (h, w)).astype(np.uint16))
        elif mode == "u16hi":
            im = Image.fromarray((rng.integers(0, 256, (h, w)) << 8).astype(np.uint16))
        buf = io.BytesIO()
        im.save(buf, format="PNG")
        return buf.getvalue()
    data = bytearray(_png_bytes(rng.integers(0, 256, (h, w), dtype=np.uint8)))
    width = draw(st.sampled_from([0, 1, 2**16, 2**20, 2**31 - 1, 2**31, 2**32 - 1]))
    height = draw(st.sampled_from([0, 1, 2**16, 2**20, 2**31 - 1]))
    data[16:24] = struct.pack(">II", width, height)  # IHDR width, height
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])) & 0xFFFFFFFF)
    return bytes(data)


@st.composite
def odd_npz(draw) -> bytes:
    """An npz of random arrays (names of a scan file, odd dtypes and shapes, maybe pickled)."""
    names = draw(st.lists(st.sampled_from(["xyz", "xp", "yp", "albedo", "intensity",
                                           "modulation", "mask", "name", "camera_center",
                                           "other"]), min_size=0, max_size=10, unique=True))
    arrays = {}
    if draw(st.booleans()):  # a scan file with one array of another shape or dtype
        scan = _small_scan()
        arrays = {k: np.asarray(getattr(scan, k)) for k in ("xyz", "xp", "yp", "albedo",
                                                            "intensity", "modulation", "mask")}
        arrays["name"] = np.array("cam0")
        arrays["camera_center"] = np.asarray(scan.camera_center)
        names = draw(st.lists(st.sampled_from(sorted(arrays)), min_size=1, max_size=2))
    for name in names:
        dtype = draw(st.sampled_from(["f4", "f8", "i4", "bool", "U4", "c8", "u1", "V4", "O"]))
        shape = tuple(draw(st.lists(st.integers(0, 5), max_size=4)))
        if dtype == "O":
            value = np.empty(shape, dtype=object)
        elif dtype == "V4":
            value = np.zeros(shape, dtype="V4")
        else:
            value = np.zeros(shape, dtype=dtype)
        arrays[name] = value
    buf = io.BytesIO()
    (np.savez_compressed if draw(st.booleans()) else np.savez)(buf, **arrays)
    return buf.getvalue()


@st.composite
def odd_ply(draw, original: bytes) -> bytes:
    """A PLY whose header lines are edited (counts, types, formats, orders)."""
    head, sep, body = original.partition(b"end_header\n")
    lines = head.decode().splitlines()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(lines) - 1))
        words = lines[i].split() or ["comment"]
        op = draw(st.sampled_from(["count", "type", "format", "drop", "dup", "swap", "word"]))
        if op == "count" and words[0] == "element":
            words[2] = str(draw(st.sampled_from([-1, 0, 1, 3, 7, 10**6, 10**12, 2**63, 2**64]))
                           ) if draw(st.booleans()) else draw(st.sampled_from(["x", "1.5", ""]))
        elif op == "type" and words[0] == "property":
            j = draw(st.integers(0, len(words) - 1))
            words[j] = draw(st.sampled_from(["char", "uchar", "short", "int", "uint", "float",
                                             "double", "list", "int64", "bogus"]))
        elif op == "format" and words[0] == "format":
            words[1] = draw(st.sampled_from(["ascii", "binary_little_endian",
                                             "binary_big_endian", "binary", ""]))
        elif op == "drop":
            words = []
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "swap" and i + 1 < len(lines):
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
        elif op == "word":
            words = words[: draw(st.integers(0, len(words)))]
        if op not in ("dup", "swap"):
            lines[i] = " ".join(words)
    data = ("\n".join(lines) + "\n").encode() + sep + body
    if draw(st.booleans()):
        data = draw(mutated_bytes(data, max_ops=2))
    return data


@st.composite
def mutated_points(draw, original: bytes) -> bytes:
    """A points table with edited cells, rows, columns, delimiters and encodings."""
    rows = [line.split("\t") for line in original.decode().splitlines()]
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["cell", "cell", "drop_row", "drop_col", "dup_row",
                                   "extra_cell", "header", "comment"]))
        i = draw(st.integers(0, len(rows) - 1)) if rows else 0
        if op == "cell" and rows and rows[i]:
            j = draw(st.integers(0, len(rows[i]) - 1))
            rows[i][j] = draw(st.sampled_from(["nan", "inf", "-inf", "1e309", "", "abc", "0x10",
                                               "1,5", "１", "٣", "1_000", "-0", "1e-400",
                                               '"1"', "\u00a0", "Xw", "point"])
                              | st.text(max_size=6))
        elif op == "drop_row" and rows:
            del rows[i]
        elif op == "drop_col" and rows and rows[0]:
            j = draw(st.integers(0, len(rows[0]) - 1))
            for row in rows:
                if j < len(row):
                    del row[j]
        elif op == "dup_row" and rows:
            rows.insert(i, list(rows[i]))
        elif op == "extra_cell" and rows:
            rows[i].append(draw(st.text(max_size=4)))
        elif op == "header" and rows:
            rows[0] = draw(st.permutations(rows[0]))
        elif op == "comment" and rows:
            rows.insert(i, ["# " + draw(st.text(max_size=8))])
    delimiter = draw(st.sampled_from(["\t", ",", " ", ";", "\t\t"]))
    newline = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    text = newline.join(delimiter.join(r) for r in rows)
    encoding = draw(st.sampled_from(["utf-8", "utf-8", "utf-8-sig", "utf-16", "utf-16-le",
                                     "latin-1"]))
    data = text.encode(encoding, "replace")
    if draw(st.integers(0, 4)) == 0:
        data = draw(mutated_bytes(data, max_ops=2))
    return data


# --------------------------------------------------------------------------------------------
# targets: (originals, case directory, hypothesis data) -> failure text or None


def _write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def _json_bytes(draw, original) -> bytes:
    return draw(mutated_json_text(original))


def fuzz_points(o: Originals, root: Path, draw) -> str | None:
    path = _write(root / "points.tsv", draw(mutated_points(o.points)))
    return check_reader(lambda: read_points(path), root, valid_points)


def fuzz_manifest(o: Originals, root: Path, draw) -> str | None:
    src = o.base / "originals" / "capture"
    if not (root / "cam0").exists():
        shutil.copytree(src / "cam0", root / "cam0")
        os.symlink(o.base / "secret.png", root / "escape.png")
    original = copy.deepcopy(o.manifest)
    if draw(st.integers(0, 3)) == 0:  # a frame path that leads outside, or a missing frame
        cam = original["cameras"][draw(st.integers(0, 1))]
        cam["frames"][draw(st.integers(0, len(cam["frames"]) - 1))] = draw(st.sampled_from(
            ["../secret.png", str(o.base / "secret.png"), "escape.png", "cam0/../../secret.png",
             "cam0/missing.png", "cam0", "", "cam0/./000.png", "//secret.png"]))
    _write(root / "capture.json", _json_bytes(draw, original))
    return check_reader(lambda: read_capture(root), root, valid_capture)


def fuzz_calibration(o: Originals, root: Path, draw) -> str | None:
    path = _write(root / "calib.json", _json_bytes(draw, o.calibration))
    return check_reader(lambda: load_calibration(path), root, valid_calibration)


def fuzz_rig(o: Originals, root: Path, draw) -> str | None:
    path = _write(root / "rig.json", _json_bytes(draw, o.rig))
    return check_reader(lambda: load_rig(path), root, valid_rig)


def fuzz_scan_json(o: Originals, root: Path, draw) -> str | None:
    if not (root / "cam1.npz").exists():
        _write(root / "cam1.npz", (o.base / "originals" / "scans" / "cam1.npz").read_bytes())
        os.symlink(o.base / "secret.npz", root / "escape.npz")
    original = copy.deepcopy(o.scan_json)
    if draw(st.integers(0, 3)) == 0:
        original["cameras"][0]["npz"] = draw(st.sampled_from(
            ["../secret.npz", str(o.base / "secret.npz"), "escape.npz", "missing.npz",
             "cam1.npz", ".", "scan.json"]))
    npz = o.scan_npz
    what = draw(st.sampled_from(["json", "json", "npz", "odd_npz"]))
    if what == "npz":
        npz = draw(mutated_bytes(o.scan_npz))
    elif what == "odd_npz":
        npz = draw(odd_npz())
    _write(root / "cam0.npz", npz)
    text = _json_bytes(draw, original) if what == "json" else json.dumps(original).encode()
    _write(root / "scan.json", text)
    return check_reader(lambda: load_scans(root), root, valid_scans)


def fuzz_npz(o: Originals, root: Path, draw) -> str | None:
    data = draw(mutated_bytes(o.scan_npz) | odd_npz())
    path = _write(root / "x.npz", data)
    # the generic reader, then the scan reader itself (both layouts: whole arrays, packed)
    return (check_reader(lambda: read_npz(path, what="scan file"), root, valid_npz)
            or check_reader(lambda: load_scan_npz(path), root, valid_scan))


def fuzz_mat5(o: Originals, root: Path, draw) -> str | None:
    for suffix in MAT5_SUFFIXES:
        _write(root / f"cam0{suffix}", o.mat5[suffix])
    suffix = draw(st.sampled_from(MAT5_SUFFIXES))
    if draw(st.integers(0, 9)) == 0:
        (root / f"cam0{suffix}").unlink()
    else:
        _write(root / f"cam0{suffix}", draw(mutated_bytes(o.mat5[suffix])))
    return check_reader(lambda: read_mat5(root / "cam0"), root, valid_scan)


def fuzz_ply(o: Originals, root: Path, draw) -> str | None:
    original = draw(st.sampled_from([o.ply_binary, o.ply_ascii]))
    data = draw(mutated_bytes(original) | odd_ply(original))
    path = _write(root / "x.ply", data)
    return check_reader(lambda: read_ply(path), root, valid_ply)


def fuzz_frame(o: Originals, root: Path, draw) -> str | None:
    bit_depth = draw(st.sampled_from([8, 10, 12, 16]))
    original = o.frame8 if bit_depth == 8 else o.frame12
    data = draw(mutated_bytes(original) | odd_png())
    path = _write(root / "000.png", data)
    return check_reader(lambda: read_frame(path, bit_depth=bit_depth), root, valid_frame)


def fuzz_print(o: Originals, root: Path, draw) -> str | None:
    suffix, original = draw(st.sampled_from([(".png", o.print_png), (".wsq", o.print_wsq)]))
    data = draw(mutated_bytes(original) | odd_png())
    path = _write(root / f"print{suffix}", data)
    return check_reader(lambda: read_print_image(path), root, valid_print)


TARGETS = {
    "points": fuzz_points,
    "capture_json": fuzz_manifest,
    "calibration": fuzz_calibration,
    "rig": fuzz_rig,
    "scan_json_npz": fuzz_scan_json,
    "npz": fuzz_npz,
    "mat5": fuzz_mat5,
    "ply": fuzz_ply,
    "png_frame": fuzz_frame,
    "print_image": fuzz_print,
}


def run_target(name: str, originals: Originals, root: Path, *, max_examples: int,
               derandomize: bool, on_failure=None, seed: int | None = None) -> int:
    """Run target `name` for `max_examples` cases in case directory `root`; returns the count.

    `on_failure(problem)` is called for each case that breaks the invariant (default: fail).
    """
    fuzz = TARGETS[name]
    root.mkdir(parents=True, exist_ok=True)
    count = [0]

    @settings(max_examples=max_examples, deadline=None, derandomize=derandomize,
              database=None, suppress_health_check=list(HealthCheck), print_blob=False)
    @given(st.data())
    def case(data):
        count[0] += 1
        problem = fuzz(originals, root, data.draw)
        if problem is not None:
            if on_failure is None:
                raise AssertionError(f"{name}: {problem}")
            on_failure(problem)

    if seed is not None:
        from hypothesis import seed as hypothesis_seed

        case = hypothesis_seed(seed)(case)
    case()
    return count[0]


# --------------------------------------------------------------------------------------------
# the CI version: a few thousand cases, reproducible


@pytest.fixture(scope="module")
def originals(tmp_path_factory):
    return make_originals(tmp_path_factory.mktemp("fuzz"))


_CI_CASES = {"points": 300, "capture_json": 200, "calibration": 300, "rig": 250,
             "scan_json_npz": 250, "npz": 250, "mat5": 200, "ply": 300, "png_frame": 250,
             "print_image": 200}


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_reader_only_clean_errors(name, originals):
    root = originals.base / f"case_{name}"
    assert run_target(name, originals, root, max_examples=_CI_CASES[name],
                      derandomize=True) >= 1


# --------------------------------------------------------------------------------------------
# regression cases found by bench/fuzz_readers.py (10⁴ cases per reader; issue 10)


def _edit(path: str):
    """An edit of a JSON value at `path` ("a.0.b"): returns (value, new) -> edited copy."""

    def edit(value, new):
        value = copy.deepcopy(value)
        *keys, last = [int(k) if k.isdigit() else k for k in path.split(".")]
        node = value
        for k in keys:
            node = node[k]
        node[last] = new
        return value

    return edit


_P = [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]]

_CALIBRATION_CASES = {
    # RuntimeWarning "overflow encountered in multiply" (the rank message rounded 1e308 * 1e6)
    "dlt_1e308_rank_deficient": ("cameras.0.camera.matrix",
                                 [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 1.0],
                                  [0.0, 1e308, 1.0, 1.0]], "rank-deficient"),
    "dlt_1e308_column": ("cameras.0.camera.matrix",
                         [[1.0, 0.0, 1e308, 1.0], [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]],
                         "rank-deficient"),
    "dlt_1e308_scaled": ("cameras.0.camera.matrix", (np.array(_P) * 1e308).tolist(), None),
    # said "rank-deficient" (the rank is checked after the intrinsics' magnitudes now)
    "pinhole_K_1e308": ("cameras.1.camera.K", [[1e308, 0, 31.5], [0, 1e308, 39.5], [0, 0, 1]],
                        r"K: fx = 1e\+308 px"),
    "pinhole_t_1e308": ("cameras.1.camera.t", [1e308, -1e308, 1e308], None),
    # returned a pinhole model with t = -inf; LinAlgError "Singular matrix" (t[2] = -inf)
    "pinhole_t_inf": ("cameras.1.camera.t", [-math.inf, 3.175, 150.0], "t: contains NaN"),
    "pinhole_t_inf_z": ("cameras.1.camera.t", [0.0, 3.175, -math.inf], "t: contains NaN"),
    "pinhole_dist_nan": ("cameras.1.camera.dist", [math.nan, 0, 0, 0, 0], "dist"),
    "pinhole_size_fraction": ("cameras.1.camera.size", [64.5, 80], "size"),
    # numbers written as strings were parsed by np.asarray(..., dtype=float)
    "dlt_strings": ("cameras.0.camera.matrix",
                    [[1.0, "-1e+308", 0.0, 1.0], [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, "1.0"]],
                    "array of numbers"),
    "center_strings": ("projector_distortion.center", ["640", 1000], "center"),
    "rho_bool": ("projector_distortion.rho", True, "rho"),
}


@pytest.mark.parametrize("case", sorted(_CALIBRATION_CASES))
def test_calibration_regressions(case, originals, tmp_path):
    where, value, match = _CALIBRATION_CASES[case]
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(_edit(where)(originals.calibration, value), allow_nan=True))
    assert check_reader(lambda: load_calibration(path), tmp_path, valid_calibration) is None
    if match is not None:
        with pytest.raises(ValueError, match=match):
            load_calibration(path)


_PATTERN_CASES = {
    # OverflowError "cannot convert float infinity to integer" from int() in PatternSet
    "panel_size_inf": ("panel_size", [1280, -math.inf], "panel_size"),
    "levels_inf": ("levels", [-math.inf, 255], "levels"),
    "panel_size_fraction": ("panel_size", [1280.5, 1040], "panel_size"),
    "panel_size_strings": ("panel_size", ["1280", "1040"], "panel_size"),
    "gamma_inf": ("gamma", math.inf, "gamma"),
}


@pytest.mark.parametrize("case", sorted(_PATTERN_CASES))
def test_capture_pattern_set_regressions(case, originals, tmp_path):
    key, value, match = _PATTERN_CASES[case]
    shutil.copytree(originals.base / "originals" / "capture" / "cam0", tmp_path / "cam0")
    manifest = _edit(f"pattern_set.{key}")(originals.manifest, value)
    (tmp_path / "capture.json").write_text(json.dumps(manifest, allow_nan=True))
    assert check_reader(lambda: read_capture(tmp_path), tmp_path, valid_capture) is None
    with pytest.raises(ValueError, match=f"capture.json: pattern_set: {match}"):
        read_capture(tmp_path)


@pytest.mark.parametrize("value", [1e308, -1e200])
def test_rig_huge_rotation_entry(value, originals, tmp_path):
    """RuntimeWarning "overflow encountered in matmul" checking ``R @ R.T``."""
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(_edit("cameras.0.R.1.1")(originals.rig, value)))
    assert check_reader(lambda: load_rig(path), tmp_path, valid_rig) is None
    with pytest.raises(ValueError, match=r"rig\.json: .*not a rotation"):
        load_rig(path)
    calib = tmp_path / "calib.json"
    calib.write_text(json.dumps(_edit("cameras.1.camera.R.0.2")(originals.calibration, value)))
    assert check_reader(lambda: load_calibration(calib), tmp_path, valid_calibration) is None


def test_corrupt_wsq_neither_crashes_nor_prints(originals, tmp_path, capfd):
    """The WSQ decoder (C) crashed the bench with SIGSEGV (byte 581 of the original inverted)
    and printed ``ERROR : huffman_decode_data_mem …`` on file descriptor 2, lines beyond the
    CLI's one; it runs in a child process now and its lines go into the message."""
    messages = []
    for offset in range(203, 600, 42):
        data = bytearray(originals.print_wsq)
        data[offset] ^= 0xFF
        path = _write(tmp_path / f"print{offset}.wsq", bytes(data))
        with contextlib.suppress(ValueError), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            read_print_image(path)
            messages += [str(w.message) for w in caught]
            continue
        with pytest.raises(ValueError) as info:
            read_print_image(path)
        messages.append(str(info.value))
    assert capfd.readouterr().err == ""
    assert any("ERROR" in m and ".wsq" in m for m in messages), messages


def test_check_reader_catches_bad_behaviour(tmp_path):
    """The invariant itself: other exceptions, unnamed files and outside opens are caught."""
    outside = tmp_path / "outside.txt"
    outside.write_text("x")
    root = tmp_path / "case"
    root.mkdir()
    assert check_reader(lambda: {}["k"], root, lambda r: None).startswith("KeyError")
    assert "not naming" in check_reader(lambda: int("x"), root, lambda r: None)
    assert check_reader(lambda: outside.read_text(), root, lambda r: None).startswith("opened")
    assert check_reader(lambda: (root / "a").read_text(), root, lambda r: None) is None
    assert "invalid" in check_reader(lambda: 1, root, lambda r: (_ for _ in ()).throw(
        AssertionError("no")))
