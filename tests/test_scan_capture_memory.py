"""Issue 10: a scan's memory stays bounded (one camera's integer frames; the NumPy reference in
bands of rows), and the banded reference scan is the whole-image one. Peak RSS at 4x the default
size: bench/scan_memory.py. The fused kernel against the reference: tests/test_scan_kernels.py."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture, read_frame, write_frame
from nail2nail.scan import capture as scanning
from nail2nail.scan import triangulation as reconstruction
from nail2nail.scan.capture import camera_center, gradient_limit, scan_capture, scan_frames
from nail2nail.scan.decoding import decode
from nail2nail.scan.inputs import frame_intensities
from nail2nail.scan.phase_shift import wrapped_phase
from nail2nail.scan.triangulation import _reconstruct_rows, band_rows, reconstruct_image
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import default_rig, ideal_calibration

SCALE = 0.25  # 256 x 320 cameras


@pytest.fixture(scope="module")
def finger(tmp_path_factory):
    """A finger capture at scale 0.25 with the thesis's projector distortion, and its ideal
    calibration (which compensates the distortion in the model)."""
    root = tmp_path_factory.mktemp("mem")
    rig = default_rig(SCALE)
    simulate_capture(root / "cap", "finger", rig=rig, seed=2, write_truth=False)
    calibration = RigCalibration.from_dict(ideal_calibration(rig))
    assert calibration.projector_distortion is not None
    return root / "cap", calibration


def whole_image_scan(frames, pattern_set, camera, *, projector_distortion, use, **options):
    """The unbanded reference: decode and triangulate the whole image at once."""
    decoded = decode(frames, pattern_set, **options)
    nan = np.full(decoded.shape, np.nan, np.float32)
    xp = decoded.xp if decoded.xp is not None else nan
    yp = decoded.yp if decoded.yp is not None else nan
    xyz = _reconstruct_rows(camera.camera, camera.projector, xp, yp, 0,
                            projector_distortion=projector_distortion, use=use)
    mask = decoded.mask & np.all(np.isfinite(xyz), axis=-1)
    xyz[~mask] = np.nan
    return dict(xyz=xyz.astype(np.float32), mask=mask, albedo=decoded.albedo,
                modulation=decoded.modulation, xp=np.where(mask, xp, np.nan),
                yp=np.where(mask, yp, np.nan),
                intensity=np.where(mask, decoded.intensity, 0).astype(np.float32))


def assert_same_scan(scan, ref):
    np.testing.assert_array_equal(scan.mask, ref["mask"])
    assert scan.mask.sum() > 500
    np.testing.assert_array_equal(np.isnan(scan.xyz), np.isnan(ref["xyz"]))
    np.testing.assert_allclose(scan.xyz, ref["xyz"], rtol=0, atol=1e-6)  # mm
    for key in ("xp", "yp", "albedo", "modulation", "intensity"):
        np.testing.assert_array_equal(getattr(scan, key), ref[key], err_msg=key)
        assert getattr(scan, key).dtype == np.float32


@pytest.mark.parametrize(("erode", "max_gradient", "use", "band"), [
    (1, 8.0, "xpyp", 1),  # the scan's defaults at this scale, one row a band
    (1, 8.0, "xpyp", 7),
    (0, None, "yp", 3),
    (2, None, "xpyp", 2),
    (2, 8.0, "xp", 5),
    (0, 2.0, "xpyp", 4),  # many steep pixels
])
def test_banded_scan_frames_equals_whole_image(finger, monkeypatch, erode, max_gradient, use,
                                               band):
    cap, calibration = finger
    capture = read_capture(cap, load=False)
    frames = capture.load_frames("cam1")
    camera = calibration.camera("cam1")
    options = dict(erode=erode, max_gradient=max_gradient)
    ref = whole_image_scan(frames, capture.pattern_set, camera,
                           projector_distortion=calibration.projector_distortion, use=use,
                           **options)
    monkeypatch.setattr(scanning, "BAND_PIXELS", band * frames.shape[2])
    monkeypatch.setattr(reconstruction, "BAND_PIXELS", 2 * frames.shape[2])
    scan = scan_frames(frames, capture.pattern_set, camera,
                       projector_distortion=calibration.projector_distortion, use=use,
                       method="numpy", **options)
    assert_same_scan(scan, ref)
    np.testing.assert_array_equal(scan.camera_center, camera_center(camera.camera))


def test_scan_capture_reads_integer_frames_and_caches_none(finger, monkeypatch):
    """Issue 10: scan_capture holds one camera's 8-bit frames at a time and decodes them band
    by band (the NumPy reference); the result is the whole-image scan of the float frames."""
    cap, calibration = finger
    monkeypatch.setattr(scanning, "BAND_PIXELS", 5 * 256)
    capture = read_capture(cap, load=False)
    scan_capture(capture, calibration)  # the fused kernel: caches none either
    assert capture.frames == {}
    scans = scan_capture(capture, calibration, method="numpy")
    assert capture.frames == {}
    preloaded = read_capture(cap)  # float frames cached: used as they are
    for scan, name in zip(scans, capture.camera_names, strict=True):
        frames = preloaded.frames[name]
        ref = whole_image_scan(frames, capture.pattern_set, calibration.camera(name),
                               projector_distortion=calibration.projector_distortion,
                               use="xpyp", max_gradient=gradient_limit(2.0, frames.shape))
        assert_same_scan(scan, ref)
    for scan, again in zip(scans, scan_capture(preloaded, calibration, method="numpy"),
                           strict=True):
        np.testing.assert_array_equal(scan.xyz, again.xyz)


@pytest.mark.parametrize("method", ["numba", "numpy"])
def test_scan_capture_memory_is_bounded_by_the_band(finger, monkeypatch, method):
    """Traced allocations stay near outputs + one camera's 8-bit frames; unbanded, the float64
    triangulation temporaries alone took ~0.6 kB per pixel (48 MB here). (The fused kernel's
    per-row temporaries are numba's, not traced: bench/scan_memory.py measures its RSS.)"""
    cap, calibration = finger
    capture = read_capture(cap, load=False)
    width, height = capture.camera("cam0")["size"]
    monkeypatch.setattr(scanning, "BAND_PIXELS", 16 * width)
    monkeypatch.setattr(reconstruction, "BAND_PIXELS", 16 * width)
    scan_capture(capture, calibration, method=method)  # imports, caches outside the measurement
    tracemalloc.start()
    try:
        scans = scan_capture(capture, calibration, method=method)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    pixels = width * height
    outputs = len(scans) * pixels * (12 + 5 * 4 + 1)  # xyz, five float32 images, mask
    frames = capture.pattern_set.n_frames * pixels  # uint8
    assert peak < outputs + frames + 10e6, (peak, outputs, frames)


@pytest.mark.parametrize("band", [1, 3, 1000])
def test_reconstruct_image_bands_are_the_whole_image(finger, monkeypatch, band):
    _, calibration = finger
    camera = calibration.camera("cam0")
    rng = np.random.default_rng(0)
    xp = rng.uniform(0, 1280, (37, 23))
    yp = rng.uniform(0, 800, (37, 23))
    xp[3, 4] = np.nan
    for use in ("xpyp", "yp", "xp"):
        ref = _reconstruct_rows(camera.camera, camera.projector, xp, yp, 0,
                                projector_distortion=calibration.projector_distortion, use=use)
        monkeypatch.setattr(reconstruction, "BAND_PIXELS", band * 23)
        got = reconstruct_image(camera.camera, camera.projector, xp.astype(np.float32),
                                yp.astype(np.float32),
                                projector_distortion=calibration.projector_distortion, use=use)
        ref32 = _reconstruct_rows(camera.camera, camera.projector, xp.astype(np.float32),
                                  yp.astype(np.float32), 0,
                                  projector_distortion=calibration.projector_distortion, use=use)
        assert got.dtype == np.float64 and got.shape == (37, 23, 3)
        np.testing.assert_array_equal(got, ref32)
        np.testing.assert_allclose(got, ref, atol=1e-3)  # float32 projector coordinates
        assert np.isnan(got[3, 4]).all()  # the distortion model needs both coordinates


def test_band_rows():
    assert band_rows(2048) == reconstruction.BAND_PIXELS // 2048
    assert band_rows(10, 25) == 2
    assert band_rows(10**9) == 1


@pytest.mark.parametrize("bit_depth", [8, 10, 12, 16])
def test_raw_frames_are_the_float_frames(tmp_path, bit_depth):
    rng = np.random.default_rng(bit_depth)
    values = rng.integers(0, 2**bit_depth, (5, 7))
    if bit_depth == 8:
        stored = values.astype(np.uint8)
    else:
        stored = (values.astype(np.uint16) << (16 - bit_depth)).astype(np.uint16)
    write_frame(tmp_path / "f.png", stored)
    raw = read_frame(tmp_path / "f.png", bit_depth=bit_depth, raw=True)
    assert raw.dtype == (np.uint8 if bit_depth == 8 else np.uint16)
    np.testing.assert_array_equal(raw, values)
    np.testing.assert_array_equal(frame_intensities(raw, bit_depth),
                                  read_frame(tmp_path / "f.png", bit_depth=bit_depth))


def test_load_frames_raw_is_not_cached(finger):
    cap, _ = finger
    capture = read_capture(cap, load=False)
    raw = capture.load_frames("cam2", raw=True)
    assert raw.dtype == np.uint8 and capture.frames == {}
    assert capture.frame_shape("cam2") == raw.shape[1:] and capture.frames == {}
    np.testing.assert_array_equal(frame_intensities(raw, 8), capture.load_frames("cam2"))
    assert list(capture.frames) == ["cam2"]


@pytest.mark.parametrize("steps", [3, 4, 6])
def test_wrapped_phase_of_a_band_is_that_of_the_whole_image(steps):
    """A BLAS dot product fused multiply-adds depending on the array size: bands of rows differed
    from the whole image in the last bit (issue 10); the frame-by-frame sum does not."""
    rng = np.random.default_rng(steps)
    frames = rng.integers(0, 256, (steps, 300, 61)).astype(np.float32) / np.float32(255)
    shifts = 2 * np.pi * np.arange(steps) / steps
    whole = wrapped_phase(frames, shifts)
    for rows in (1, 7, 160):
        for got, ref in zip(zip(*(wrapped_phase(frames[:, a:a + rows], shifts)
                                  for a in range(0, 300, rows)), strict=True), whole,
                            strict=True):
            np.testing.assert_array_equal(np.concatenate(got), ref)
