"""Issue 11, fast I/O: frames decoded in threads straight into the stack, the packed scan npz
(layout 2) and the layout-1 files written before it, write_npz's compression, the numpy mat5
BMP and scan PLY writers against their Pillow / write_ply references, atomic writes.

No timings here: ``bench/io.py`` measures.
"""

from __future__ import annotations

import io
import json
import os
import warnings
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from nail2nail.io import capture as capture_module
from nail2nail.io._atomic import write_npz
from nail2nail.io.capture import read_capture, write_frame, write_manifest
from nail2nail.io.mat5 import mat5_paths, read_mat5, write_mat5
from nail2nail.io.ply import read_ply, write_ply, write_scan_ply
from nail2nail.io.scans import (
    SCAN_NPZ_LAYOUT,
    load_scan_npz,
    load_scans,
    save_scan_npz,
    save_scans,
)
from nail2nail.scan.inputs import frame_intensities
from nail2nail.scan.results import Scan

ARRAYS = ("xyz", "xp", "yp", "albedo", "intensity", "modulation", "mask")
QUIET_NAN = np.array([0x7FC00000], np.uint32).view(np.float32)[0]  # np.nan
X86_NAN = np.array([0xFFC00000], np.uint32).view(np.float32)[0]  # what 0/0 gives on x86
PAYLOAD_NAN = np.array([0x7FC12345], np.uint32).view(np.float32)[0]


# --------------------------------------------------------------------------------------------
# helpers


def make_scan(shape=(9, 11), *, seed=0, name="cam0", dtype=np.float32, nan=QUIET_NAN,
              background=0.0, center=True) -> Scan:
    """A scan as the pipeline makes them: NaN (`nan`) outside the mask for xyz, xp, yp; 0 for
    intensity; `background` outside for albedo and modulation."""
    rng = np.random.default_rng(seed)
    h, w = shape
    mask = rng.random(shape) > 0.6
    xyz = rng.normal(0, 10, (h, w, 3)).astype(dtype)
    xp = rng.uniform(0, 1280, shape).astype(dtype)
    yp = rng.uniform(0, 1040, shape).astype(dtype)
    for a in (xyz, xp, yp):
        a[~mask] = dtype(nan)
    albedo = rng.random(shape).astype(dtype)
    modulation = rng.uniform(0, 0.5, shape).astype(dtype)
    intensity = np.where(mask, 2 * modulation, 0).astype(dtype)
    if background is not None:
        albedo[~mask] = background
        modulation[~mask] = background
    return Scan(name=name, xyz=xyz, xp=xp, yp=yp, albedo=albedo, intensity=intensity,
                modulation=modulation, mask=mask,
                camera_center=np.array([1.0, 2.0, 150.0]) if center else None)


def assert_same_scan(a: Scan, b: Scan) -> None:
    """Bit for bit: dtypes, shapes and bytes (NaN payloads and positions included)."""
    assert a.name == b.name
    for key in ARRAYS:
        x, y = np.asarray(getattr(a, key)), np.asarray(getattr(b, key))
        assert x.dtype == y.dtype and x.shape == y.shape, key
        assert x.tobytes() == y.tobytes(), key
    if a.camera_center is None:
        assert b.camera_center is None
    else:
        assert np.array_equal(a.camera_center, b.camera_center)


def save_layout1(path, scan: Scan) -> None:
    """The scan npz as written before issue 11 (``save_scan_npz`` at layout 1)."""
    arrays = {k: getattr(scan, k) for k in ARRAYS}
    if scan.camera_center is not None:
        arrays["camera_center"] = np.asarray(scan.camera_center, dtype=float)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, name=np.array(scan.name), **arrays)


def npz_members(path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def rewrite(path, members: dict) -> None:
    buf = io.BytesIO()
    np.savez(buf, **members)
    path.write_bytes(buf.getvalue())


# --------------------------------------------------------------------------------------------
# frames


def _capture(tmp_path, frames, *, bit_depth=8, size=True, name="cap"):
    root = tmp_path / name
    files = []
    for i, frame in enumerate(frames):
        files.append(f"cam0/{i:03d}.png")
        write_frame(root / files[-1], frame)
    cam = {"name": "cam0", "frames": files}
    if size:
        cam["size"] = [int(frames[0].shape[1]), int(frames[0].shape[0])]
    write_manifest(root, {"bit_depth": bit_depth, "n_frames": len(frames), "cameras": [cam]})
    return root


def _plain_stack(root, n):
    return np.stack([np.asarray(Image.open(root / f"cam0/{i:03d}.png")) for i in range(n)])


@pytest.mark.parametrize("bit_depth", [8, 10, 12, 16])
@pytest.mark.parametrize("size", [True, False])
def test_load_frames_equals_plain_pil(tmp_path, bit_depth, size):
    rng = np.random.default_rng(bit_depth)
    n, shape = 7, (13, 17)
    if bit_depth == 8:
        frames = [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(n)]
    else:
        frames = [(rng.integers(0, 2**bit_depth, shape) << (16 - bit_depth)).astype(np.uint16)
                  for _ in range(n)]
    root = _capture(tmp_path, frames, bit_depth=bit_depth, size=size)
    plain = _plain_stack(root, n)
    want = plain >> (16 - bit_depth) if bit_depth > 8 else plain
    capture = read_capture(root, load=False)
    raw = capture.load_frames("cam0", raw=True)
    assert raw.dtype == (np.uint8 if bit_depth == 8 else np.uint16)
    assert raw.shape == (n, *shape) and np.array_equal(raw, want)
    floats = capture.load_frames("cam0")
    assert floats.dtype == np.float32
    assert floats.tobytes() == frame_intensities(want, bit_depth).tobytes()
    assert capture.frame_shape("cam0") == shape


def test_load_frames_fallback_and_one_thread_agree(tmp_path, monkeypatch):
    """The fast path (decoding into the stack, threads) gives what np.asarray in one thread
    gives."""
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 256, (9, 6), dtype=np.uint8) for _ in range(5)]
    root = _capture(tmp_path, frames)
    fast = read_capture(root, load=False).load_frames("cam0", raw=True)
    monkeypatch.setattr(capture_module, "_decode_into", lambda im, out: False)
    monkeypatch.setattr(capture_module.os, "cpu_count", lambda: 1)
    slow = read_capture(root, load=False).load_frames("cam0", raw=True)
    assert np.array_equal(fast, slow) and np.array_equal(fast, np.stack(frames))


def test_first_bad_frame_in_order_is_raised(tmp_path):
    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 256, (8, 6), dtype=np.uint8) for _ in range(8)]
    root = _capture(tmp_path, frames)
    write_frame(root / "cam0/005.png", np.zeros((7, 6), np.uint8))  # wrong size
    capture = read_capture(root, load=False)
    with pytest.raises(ValueError, match=r"005.png: frame is 6 x 7 px.*6 x 8"):
        capture.load_frames("cam0", raw=True)
    data = (root / "cam0/002.png").read_bytes()
    (root / "cam0/002.png").write_bytes(data[: len(data) // 2])  # truncated: earlier
    for raw in (True, False):
        with pytest.raises(ValueError, match=r"002.png: cannot read frame"):
            capture.load_frames("cam0", raw=raw)


@pytest.mark.parametrize("bad", ["rgb", "16bit", "right_aligned"])
def test_bad_frame_checks_kept_in_threads(tmp_path, bad):
    rng = np.random.default_rng(3)
    bit_depth = 8 if bad != "right_aligned" else 12
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    frames = [(rng.integers(0, 200, (6, 5)) << (0 if bit_depth == 8 else 4)).astype(dtype)
              for _ in range(4)]
    root = _capture(tmp_path, frames, bit_depth=bit_depth)
    target = root / "cam0/003.png"
    if bad == "rgb":
        Image.fromarray(np.zeros((6, 5, 3), np.uint8)).save(target)
        match = "expected a single-channel grey image"
    elif bad == "16bit":
        write_frame(target, np.zeros((6, 5), np.uint16))
        match = "a 16-bit image, but the capture's bit_depth is 8"
    else:
        write_frame(target, np.full((6, 5), 3, np.uint16))
        match = "left-aligned"
    with pytest.raises(ValueError, match=rf"003.png: .*{match}"):
        read_capture(root, load=False).load_frames("cam0", raw=True)


def test_decompression_bomb_in_threads_and_filters_restored(tmp_path, monkeypatch):
    frames = [np.zeros((40, 30), np.uint8) for _ in range(4)]
    root = _capture(tmp_path, frames)
    before = list(warnings.filters)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # 1200 px: a warning, made an error
    with pytest.raises(ValueError, match=r"000.png: cannot read frame \(Image size"):
        read_capture(root, load=False).load_frames("cam0", raw=True)
    assert warnings.filters == before


@pytest.mark.parametrize("size", [[8, 2**63], [2**40, 2**40], [100000, 100000], [7, 6]])
def test_manifest_size_checked_before_the_stack_is_made(tmp_path, size):
    """Regression (fuzz, capture_json): a manifest size far from the frames' was allocated
    before any frame was read (numpy: 'Maximum allowed dimension exceeded', or gigabytes)."""
    frames = [np.zeros((6, 8), np.uint8)] * 3
    root = _capture(tmp_path, frames)
    manifest = json.loads((root / "capture.json").read_text())
    manifest["cameras"][0]["size"] = size
    (root / "capture.json").write_text(json.dumps(manifest))
    capture = read_capture(root, load=False)
    for raw in (True, False):
        with pytest.raises(ValueError, match=rf"000.png: frame is 8 x 6 px \(W x H\), but camera "
                                             rf"cam0's size in .*capture.json is {size[0]} x"):
            capture.load_frames("cam0", raw=raw)
    with pytest.raises(ValueError, match=r"000.png: frame is 8 x 6 px"):
        capture.frame_shape("cam0")


def test_frames_of_another_size_without_manifest_size(tmp_path):
    frames = [np.zeros((8, 6), np.uint8)] * 3
    root = _capture(tmp_path, frames, size=False)
    write_frame(root / "cam0/002.png", np.zeros((8, 7), np.uint8))
    with pytest.raises(ValueError, match=r"002.png: frame is 7 x 8 px.*first frame is 6 x 8"):
        read_capture(root, load=False).load_frames("cam0", raw=True)


# --------------------------------------------------------------------------------------------
# write_npz


@pytest.mark.parametrize("compress, method", [
    (True, zipfile.ZIP_DEFLATED), (False, zipfile.ZIP_STORED), (0, zipfile.ZIP_STORED),
    (1, zipfile.ZIP_DEFLATED), (9, zipfile.ZIP_DEFLATED),
])
def test_write_npz_compression(tmp_path, compress, method):
    arrays = {"a": np.arange(1000.0), "b": np.array("x"), "c": np.zeros((3, 0), bool)}
    path = write_npz(tmp_path / "f.npz", arrays, compress=compress)
    got = npz_members(path)
    assert got.keys() == arrays.keys()
    for k, v in arrays.items():
        assert got[k].dtype == v.dtype and np.array_equal(got[k], v)
    with zipfile.ZipFile(path) as z:
        assert {i.compress_type for i in z.infolist()} == {method}


def test_write_npz_per_array_levels(tmp_path):
    path = write_npz(tmp_path / "f.npz", {"a": np.zeros(100), "b": np.zeros(100)},
                     compress={"b": 1})
    with zipfile.ZipFile(path) as z:
        kinds = {i.filename: i.compress_type for i in z.infolist()}
    assert kinds == {"a.npy": zipfile.ZIP_STORED, "b.npy": zipfile.ZIP_DEFLATED}


@pytest.mark.parametrize("compress", [10, -1, 1.5, "yes", None])
def test_write_npz_bad_compress(tmp_path, compress):
    with pytest.raises(ValueError, match="compress"):
        write_npz(tmp_path / "f.npz", {"a": np.zeros(2)}, compress=compress)
    assert not any(tmp_path.iterdir())


def test_write_npz_atomic_on_failure(tmp_path):
    path = tmp_path / "f.npz"
    write_npz(path, {"a": np.arange(3)})
    before = path.read_bytes()
    with pytest.raises(ValueError, match="pickle"):
        write_npz(path, {"a": np.zeros(10), "b": np.array([{1: 2}], dtype=object)},
                  compress=False)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.npz"]  # no temporary left


# --------------------------------------------------------------------------------------------
# scan npz: packed layout, old layout


def test_scan_npz_packed_layout(tmp_path):
    scan = make_scan((20, 30), nan=X86_NAN)
    save_scan_npz(tmp_path / "s.npz", scan)
    members = npz_members(tmp_path / "s.npz")
    assert int(members["layout"]) == SCAN_NPZ_LAYOUT
    assert members["shape"].tolist() == [20, 30]
    n = int(scan.mask.sum())
    assert members["xyz.values"].shape == (n, 3) and members["xp.values"].shape == (n,)
    assert "xyz.where" not in members  # the mask's pixels
    assert members["xyz.fill"].view(np.uint32).tolist() == [0xFFC00000] * 3
    for key in ARRAYS:
        assert key not in members
    with zipfile.ZipFile(tmp_path / "s.npz") as z:
        kinds = {i.filename: i.compress_type for i in z.infolist()}
    assert kinds["xyz.values.npy"] == zipfile.ZIP_STORED
    assert kinds["mask.bits.npy"] == zipfile.ZIP_DEFLATED
    assert_same_scan(scan, load_scan_npz(tmp_path / "s.npz"))


def test_scan_npz_dense_arrays_stay_whole(tmp_path):
    """A noisy background (no fill to speak of) and a full mask: arrays stored whole."""
    scan = make_scan((12, 10), background=None)
    save_scan_npz(tmp_path / "s.npz", scan)
    members = npz_members(tmp_path / "s.npz")
    assert "albedo" in members and "xyz.values" in members
    assert_same_scan(scan, load_scan_npz(tmp_path / "s.npz"))
    full = make_scan((6, 7), seed=1)
    full.mask[...] = True
    save_scan_npz(tmp_path / "f.npz", full)
    assert "xyz" in npz_members(tmp_path / "f.npz")
    assert_same_scan(full, load_scan_npz(tmp_path / "f.npz"))


@pytest.mark.parametrize("compress", [True, 1])
def test_scan_npz_compressed(tmp_path, compress):
    scan = make_scan((15, 9), seed=4)
    save_scan_npz(tmp_path / "s.npz", scan, compress=compress)
    with zipfile.ZipFile(tmp_path / "s.npz") as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED}
    assert_same_scan(scan, load_scan_npz(tmp_path / "s.npz"))


@st.composite
def scans(draw) -> Scan:
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    dtype = draw(st.sampled_from([np.float32, np.float64, np.float16]))
    mask = rng.random((h, w)) < draw(st.floats(0.0, 1.0))
    fills = [np.nan, 0.0, -0.0, 1.0, np.inf]
    if dtype == np.float32:
        fills += [X86_NAN, PAYLOAD_NAN]

    def array(shape):
        a = rng.normal(size=shape).astype(dtype)
        if draw(st.booleans()):  # the pipeline's pattern: one value outside the mask
            a[~mask] = draw(st.sampled_from(fills))
        if draw(st.booleans()):  # and NaN or fill values inside it too
            a[rng.random(shape[:2]) < 0.2] = draw(st.sampled_from(fills))
        return a

    return Scan(name=draw(st.sampled_from(["cam0", "c"])), xyz=array((h, w, 3)),
                xp=array((h, w)), yp=array((h, w)), albedo=array((h, w)),
                intensity=array((h, w)), modulation=array((h, w)), mask=mask,
                camera_center=draw(st.sampled_from([None, np.array([0.5, -1.0, 2.0])])))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                   HealthCheck.function_scoped_fixture])
@given(scan=scans(), compress=st.sampled_from([False, True]))
def test_scan_npz_round_trip_bit_for_bit(tmp_path, scan, compress):
    save_scan_npz(tmp_path / "s.npz", scan, compress=compress)
    assert_same_scan(scan, load_scan_npz(tmp_path / "s.npz"))
    save_layout1(tmp_path / "old.npz", scan)
    assert_same_scan(scan, load_scan_npz(tmp_path / "old.npz"))


def test_old_layout_scan_directory_still_read(tmp_path):
    """A scan directory written before issue 11 (layout-1 npz, no ``layout`` member)."""
    scans = [make_scan((10, 8), seed=i, name=f"cam{i}") for i in range(3)]
    manifest = save_scans(tmp_path / "s", scans, mat5=False, ply=False)
    for scan in scans:
        save_layout1(tmp_path / "s" / f"{scan.name}.npz", scan)
    assert "layout" not in npz_members(tmp_path / "s" / "cam0.npz")
    assert [c["name"] for c in manifest["cameras"]] == ["cam0", "cam1", "cam2"]
    for a, b in zip(scans, load_scans(tmp_path / "s"), strict=True):
        assert_same_scan(a, b)


def _packed(tmp_path):
    scan = make_scan((10, 12), seed=5)
    save_scan_npz(tmp_path / "s.npz", scan)
    return npz_members(tmp_path / "s.npz")


@pytest.mark.parametrize("edit, match", [
    (lambda m: m.update(layout=np.array(3)), "layout 3 is not 1 or 2"),
    (lambda m: m.update(layout=np.array([2, 2])), "layout int64 \\(2,\\)"),
    (lambda m: m.pop("shape"), "shape must be 2 positive integers"),
    (lambda m: m.update(shape=np.array([10, -12])), "shape must be"),
    (lambda m: m.update(shape=np.array([2**40, 2**40])), "shape must be"),
    (lambda m: m.update(shape=np.array([10.0, 12.0])), "shape must be"),
    (lambda m: m.update({"mask.bits": m["mask.bits"][:-1]}), "mask.bits must be 15 bytes"),
    (lambda m: m.update({"mask.bits": m["mask.bits"].astype(np.int16)}), "mask.bits must be"),
    (lambda m: m.pop("mask.bits"), "lacks array\\(s\\) mask"),
    (lambda m: m.pop("xp.values"), "lacks array\\(s\\) xp"),
    (lambda m: m.pop("xp.fill"), "xp.values must be .* no fill"),
    (lambda m: m.update({"xp.values": m["xp.values"][1:]}), "xp.values holds .* the mask"),
    (lambda m: m.update({"xp.fill": m["xp.fill"].astype(np.float64)}), "xp.values must be"),
    (lambda m: m.update({"xp.values": m["xp.values"].astype(np.int32)}), "xp.values must be"),
    (lambda m: m.update({"xp.values": m["xp.values"].astype(np.longdouble),
                         "xp.fill": m["xp.fill"].astype(np.longdouble)}), "float16/32/64"),
    (lambda m: m.update({"xyz.values": m["xyz.values"][:, :2]}), "xyz.values must be"),
    (lambda m: m.update({"xp.values": np.float32(1.0)}), "xp.values must be"),
    (lambda m: m.update({"xyz.values": m["xyz.values"][None]}), "xyz.values must be"),
    (lambda m: m.update({"xyz.fill": m["xyz.fill"][0]}), "xyz.values must be"),
    (lambda m: m.update({"albedo.where": m["mask.bits"][:3]}), "albedo.where must be"),
    (lambda m: m.update({"albedo.where": np.zeros_like(m["mask.bits"])}), "albedo.values holds"),
])
def test_bad_packed_scan_names_file(tmp_path, edit, match):
    members = _packed(tmp_path)
    members["albedo.where"] = members["mask.bits"]  # where present (here the mask's pixels)
    edit(members)
    rewrite(tmp_path / "bad.npz", members)
    with pytest.raises(ValueError, match=rf"bad.npz: .*{match}"):
        load_scan_npz(tmp_path / "bad.npz")


@st.composite
def odd_members(draw):
    """A packed scan file with one or two members replaced by odd arrays, or dropped."""
    edits = draw(st.lists(st.tuples(
        st.sampled_from(["layout", "shape", "mask.bits", "xyz.values", "xyz.fill", "xp.values",
                         "xp.fill", "albedo.where", "mask", "xyz", "name"]),
        st.sampled_from(["drop", "f4", "f8", "i8", "u1", "bool", "U3", "c8", "f2"]),
        st.lists(st.integers(0, 20), max_size=3)), min_size=1, max_size=2))
    return edits


@settings(max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=odd_members())
def test_odd_packed_members_refused_or_read(tmp_path, edits):
    members = _packed(tmp_path)
    for name, dtype, shape in edits:
        if dtype == "drop":
            members.pop(name, None)
        else:
            members[name] = np.ones(tuple(shape), dtype=dtype)
    path = tmp_path / "odd.npz"
    rewrite(path, members)
    try:
        scan = load_scan_npz(path)
    except ValueError as exc:
        assert str(exc).startswith(f"{path}: "), exc
        return
    shape = scan.mask.shape
    assert scan.mask.dtype == bool and scan.xyz.shape == (*shape, 3)
    for key in ARRAYS[1:-1]:
        assert getattr(scan, key).shape == shape
        assert np.issubdtype(getattr(scan, key).dtype, np.floating)


# --------------------------------------------------------------------------------------------
# scan directory: npz, mat5, PLY


def _bmp_by_pillow(path, image):
    Image.fromarray(image).save(path, "BMP")


def _to_8bit_reference(value):  # the mat5 writer's formula before issue 11
    value = np.nan_to_num(np.asarray(value, dtype=np.float64), nan=0.0)
    return np.rint(np.clip(value, 0.0, 1.0) * 255.0).astype(np.uint8)


@pytest.mark.parametrize("shape", [(1, 1), (3, 5), (4, 6), (7, 9), (2, 13)])
def test_mat5_files_as_pillow_wrote_them(tmp_path, shape):
    """Byte for byte the files of the Pillow-based writer (row padding, palette, header)."""
    scan = make_scan(shape, seed=sum(shape), background=None)
    scan.albedo.flat[0] = np.nan
    scan.albedo.flat[-1] = 1.7
    scan.intensity.flat[-1] = -np.inf
    write_mat5(tmp_path / "cam0", scan)
    paths = mat5_paths(tmp_path / "cam0")
    xyz = scan.xyz
    valid = scan.mask & np.all(np.isfinite(xyz), axis=-1)
    albedo = _to_8bit_reference(scan.albedo)
    intensity = np.where(valid, np.maximum(_to_8bit_reference(scan.intensity), 1), 0)
    _bmp_by_pillow(tmp_path / "C.bmp", np.repeat(albedo[..., None], 3, axis=-1))
    _bmp_by_pillow(tmp_path / "I.bmp", intensity.astype(np.uint8))
    assert paths["C.bmp"].read_bytes() == (tmp_path / "C.bmp").read_bytes()
    assert paths["I.bmp"].read_bytes() == (tmp_path / "I.bmp").read_bytes()
    for suffix, plane in (("X.by", xyz[..., 0]), ("Z.by", xyz[..., 2]), ("YP.by", scan.yp)):
        want = np.where(valid, plane, np.float32(0)).astype("<f4").tobytes()
        assert paths[suffix].read_bytes() == want
    back = read_mat5(tmp_path / "cam0")
    assert np.array_equal(back.mask, valid)
    assert np.array_equal(back.xyz[valid], xyz[valid])


def test_scan_ply_as_write_ply_wrote_it(tmp_path):
    scan = make_scan((9, 7), seed=6, background=None)
    scan.xyz[0, 0, 1] = np.inf  # a masked pixel with an infinite coordinate is dropped
    scan.mask[0, 0] = True
    scan.albedo[scan.mask] = np.linspace(-0.5, 1.5, int(scan.mask.sum()))
    scan.albedo.flat[np.flatnonzero(scan.mask)[3]] = np.nan
    write_scan_ply(tmp_path / "new.ply", scan)
    valid = scan.mask & np.all(np.isfinite(scan.xyz), axis=-1)
    grey = _to_8bit_reference(scan.albedo[valid])
    write_ply(tmp_path / "ref.ply", scan.xyz[valid], colors=np.repeat(grey[:, None], 3, 1),
              comments=[f"nail2nail scan {scan.name}"])
    assert (tmp_path / "new.ply").read_bytes() == (tmp_path / "ref.ply").read_bytes()
    ply = read_ply(tmp_path / "new.ply")
    assert np.array_equal(ply.points, scan.xyz[valid]) and np.array_equal(ply.colors[:, 0], grey)


def test_scan_ply_float64_and_empty(tmp_path):
    scan = make_scan((4, 5), seed=7, dtype=np.float64)
    write_scan_ply(tmp_path / "a.ply", scan)
    assert np.array_equal(read_ply(tmp_path / "a.ply").points,
                          scan.xyz[scan.mask].astype(np.float32))
    scan.mask[...] = False
    write_scan_ply(tmp_path / "b.ply", scan)
    assert read_ply(tmp_path / "b.ply").points.shape == (0, 3)


def test_save_scans_round_trip(tmp_path):
    scans = [make_scan((10, 8), seed=i, name=f"cam{i}", nan=X86_NAN) for i in range(3)]
    manifest = save_scans(tmp_path / "s", scans, extra={"capture": "x"})
    assert [c["name"] for c in manifest["cameras"]] == ["cam0", "cam1", "cam2"]
    assert manifest["capture"] == "x"
    for scan, entry, back in zip(scans, manifest["cameras"], load_scans(tmp_path / "s"),
                                 strict=True):
        assert entry["valid_pixels"] == int(scan.mask.sum())
        assert_same_scan(scan, back)
        assert (tmp_path / "s" / entry["ply"]).is_file()
        assert np.array_equal(read_mat5(tmp_path / "s" / entry["mat5"]).mask, scan.mask)
    want = {"scan.json"} | {f"{s.name}{suffix}" for s in scans for suffix in (
        ".npz", ".ply", *mat5_paths("").keys())}
    assert {p.name for p in (tmp_path / "s").iterdir()} == want  # no temporary files left
    assert sorted(os.listdir(tmp_path)) == ["s"]


def test_save_scans_first_error_in_order_and_nothing_written(tmp_path):
    scans = [make_scan((6, 5), seed=i, name=f"cam{i}") for i in range(4)]
    scans[2].xp = scans[2].xp[:, :3]  # mat5 refuses
    scans[3].xyz = scans[3].xyz[:2]  # so does it, later in order
    with pytest.raises(ValueError, match=r"scan.xp: expected shape \(6, 5\)"):
        save_scans(tmp_path / "s", scans, ply=False)
    assert not (tmp_path / "s").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".s.")]


def test_save_scans_replaces_earlier_directory_whole(tmp_path):
    out = tmp_path / "s"
    save_scans(out, [make_scan((5, 5), name="cam0")], mat5=False)
    save_scans(out, [make_scan((5, 5), seed=1, name="cam1")], mat5=False, ply=False)
    assert sorted(p.name for p in out.iterdir()) == ["cam1.npz", "scan.json"]
    assert sorted(os.listdir(tmp_path)) == ["s"]
