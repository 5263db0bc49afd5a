"""Virtual scanner: rig, scenes, geometry ground truth and rendering (issue 3)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.calibration.files import RigCalibration
from nail2nail.simulation.render import camera_geometry, projector_radiance, render_frames
from nail2nail.simulation.rig import (
    Photometry,
    Rig,
    default_rig,
    ideal_calibration,
    load_rig,
    save_rig,
    scale_camera,
)
from nail2nail.simulation.scenes import make_scene

WHITE = np.full((1, 1040, 1280), 255, dtype=np.uint8)


@pytest.fixture(scope="module")
def rig_quarter():
    return default_rig(0.25)


# -- rig --------------------------------------------------------------------------------------
def test_default_rig_layout():
    rig = default_rig()
    assert rig.camera_names == ["cam0", "cam1", "cam2"]
    assert rig.projector.size == (1280, 1040)
    np.testing.assert_allclose(rig.projector.K[:2, 2], [640, 1000])
    assert rig.projector_distortion.to_dict() == {"center": [640.0, 1000.0], "rho": -0.004}
    for cam, az in zip(rig.cameras, (-45, 0, 45), strict=True):
        assert cam.size == (1024, 1280)
        c = cam.center
        assert np.degrees(np.arctan2(c[0], c[2])) == pytest.approx(az)
        # about 32 px/mm on the axis, +Y up the image
        a, b = cam.project(np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
        assert a[1] - b[1] == pytest.approx(32.0, rel=1e-3)
    # the baseline runs along the finger axis: projector above the cameras, same azimuth as cam1
    p = rig.projector.center
    assert abs(p[0]) < 1e-9 and p[1] > 50


def test_scale_keeps_field_of_view():
    full, half = default_rig(1.0), default_rig(0.5)
    xyz = np.array([[3.0, 5.0, 2.0], [-4.0, -10.0, 6.0]])
    for a, b in zip(full.cameras, half.cameras, strict=True):
        assert b.size == (512, 640)
        np.testing.assert_allclose((b.project(xyz) + 0.5) * 2 - 0.5, a.project(xyz), atol=1e-9)
    assert half.projector.size == full.projector.size


def test_rig_json_round_trip(tmp_path):
    rig = default_rig(0.5, projector_distortion="none")
    path = tmp_path / "rig.json"
    save_rig(path, rig)
    back = load_rig(path)
    assert back.to_dict() == json.loads(path.read_text())
    assert back.projector_distortion is None and back.scale == 0.5
    np.testing.assert_allclose(back.cameras[2].K, rig.cameras[2].K)


def test_rig_bad_input(tmp_path):
    with pytest.raises(ValueError, match="not a nail2nail rig"):
        Rig.from_dict({"format": "other"})
    with pytest.raises(ValueError, match="bit_depth"):
        Photometry(bit_depth=9)
    with pytest.raises(ValueError, match="projector_distortion"):
        default_rig(projector_distortion="barrel")
    with pytest.raises(ValueError, match="scale"):
        scale_camera(default_rig().cameras[0], -1.0)
    bad = tmp_path / "rig.json"
    bad.write_text("{")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_rig(bad)


def test_ideal_calibration_is_a_calibration_file(rig_quarter):
    calib = RigCalibration.from_dict(ideal_calibration(rig_quarter))
    assert [c.name for c in calib.cameras] == ["cam0", "cam1", "cam2"]
    xyz = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(calib.cameras[1].camera.project(xyz),
                               rig_quarter.cameras[1].project(xyz))
    assert calib.projector_distortion.rho == -0.004


@settings(max_examples=30, deadline=None)
@given(st.floats(0, 1279), st.floats(0, 1039))
def test_projector_ray_round_trip(x, y):
    rig = default_rig(0.25)
    origin, d = rig.projector_rays(np.array([[x, y]]))
    point = origin + 170.0 * d
    np.testing.assert_allclose(rig.panel_from_world(point), [[x, y]], atol=1e-8)


# -- geometry ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["target", "plane", "sphere", "finger", "coin"])
def test_geometry_round_trip(name, rig_quarter):
    """With noise off, each lit pixel's true panel coordinate maps back to that pixel."""
    rig = rig_quarter
    scene = make_scene(name, rig=rig)
    for i, cam in enumerate(rig.cameras):
        g = camera_geometry(rig, scene, i)
        rows, cols = np.nonzero(g.mask)
        assert rows.size > 1000
        # xyz lies on the pixel's ray
        np.testing.assert_allclose(cam.project(g.xyz[rows, cols]), np.column_stack([cols, rows]),
                                   atol=1e-6)
        # panel -> projector ray -> first surface hit -> camera
        origin, d = rig.projector_rays(np.column_stack([g.xp[rows, cols], g.yp[rows, cols]]))
        t = scene.intersect(origin, d)
        back = cam.project(origin + t[:, None] * d)
        err = np.hypot(back[:, 0] - cols, back[:, 1] - rows)
        assert err.max() <= 1e-6, f"{name} cam{i}: round trip {err.max():.2e} px"
        # ideal coordinates are the pinhole projection
        np.testing.assert_allclose(
            rig.projector.project(g.xyz[rows, cols]),
            np.column_stack([g.xp_ideal[rows, cols], g.yp_ideal[rows, cols]]), atol=1e-9)
        assert np.all(np.isnan(g.xp[~g.mask])) and np.all(np.isnan(g.xyz[~g.surface]))
        n = g.normal[rows, cols]
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)


def test_camera_distortion_round_trip():
    rig = default_rig(0.125, camera_distortion=(-0.2, 0.05, 0.0, 0.0, 0.0))
    scene = make_scene("sphere")
    g = camera_geometry(rig, scene, 0)
    rows, cols = np.nonzero(g.surface)
    back = rig.cameras[0].project(g.xyz[rows, cols])
    np.testing.assert_allclose(back, np.column_stack([cols, rows]), atol=1e-6)
    plain = camera_geometry(default_rig(0.125), scene, 0)
    assert g.surface.sum() != plain.surface.sum()  # the distortion changes what pixels see


def test_sphere_geometry_exact(rig_quarter):
    scene = make_scene("sphere")
    g = camera_geometry(rig_quarter, scene, 1)
    pts = g.xyz[g.surface]
    np.testing.assert_allclose(np.linalg.norm(pts - np.array(scene.center), axis=1), 10.0,
                               atol=1e-9)


def test_shadows_and_panel_limits(rig_quarter):
    """The side camera sees the cylinder beyond the projector's terminator: unlit there."""
    g = camera_geometry(rig_quarter, make_scene("target"), 0)
    theta = np.degrees(g.params["theta"])
    seen = g.surface
    assert np.any(seen & (theta < -95))
    assert not np.any(g.mask & (theta < -90))
    assert np.nanmin(g.xp) >= -0.5 and np.nanmax(g.yp) <= 1039.5


def test_plane_faces_projector(rig_quarter):
    scene = make_scene("plane", rig=rig_quarter)
    g = camera_geometry(rig_quarter, scene, 0)
    # the side cameras see the whole panel on the default plane (distortion estimation)
    assert np.nanmin(g.xp) < 5 and np.nanmax(g.xp) > 1274
    assert np.nanmin(g.yp) < 5 and np.nanmax(g.yp) > 1034
    custom = make_scene("plane", rig=rig_quarter, normal=(0.0, 0.0, 1.0))
    np.testing.assert_allclose(custom._n, [0, 0, 1])


def test_finger_shape(rig_quarter):
    scene = make_scene("finger")
    g = camera_geometry(rig_quarter, scene, 1)
    xyz = g.xyz[g.surface]
    width = np.ptp(xyz[:, 0])
    assert 16 <= width <= 20
    assert np.ptp(xyz[:, 1]) >= 25
    assert np.all(xyz[:, 2] > -1.0)  # nail side (-Z) hidden from the centre camera


def test_finger_relief_and_print_coordinates():
    scene = make_scene("finger")
    # pad centre: u = 0, v = y; arc length around the body
    u, v = scene.print_coordinates(np.array([[0.0, -3.0, scene.az], [scene.ax, -3.0, 0.0]]))
    assert u[0] == pytest.approx(0.0, abs=1e-9) and v[0] == pytest.approx(-3.0)
    quarter = np.trapezoid(np.hypot(scene.ax * np.cos(t := np.linspace(0, np.pi / 2, 20001)),
                                    scene.az * np.sin(t)), t)
    assert u[1] == pytest.approx(quarter, rel=1e-6)
    # relief: along the pad normal the surface sits h/2 * r off the base shape
    rays_o = np.array([0.0, -5.0, 50.0])
    ys = np.linspace(-10, 0, 200)
    dirs = np.tile([0.0, 0.0, -1.0], (200, 1))
    z = np.array([rays_o[2] - scene.intersect(rays_o + np.array([0, y + 5, 0]), dirs[:1])[0]
                  for y in ys])
    assert 0.02 <= np.ptp(z) <= 0.07  # 30-60 um peak to valley (plus sampling)
    r = scene.fingerprint.sample(np.zeros_like(ys), ys)
    np.testing.assert_allclose(z - scene.az, scene.relief_height / 2 * r, atol=2e-4)


# -- rendering --------------------------------------------------------------------------------
def test_render_noise_free_formula(rig_quarter):
    photometry = Photometry(noise=False, camera_blur_px=0.0, projector_blur_px=0.0)
    scene = make_scene("sphere")
    g = camera_geometry(rig_quarter, scene, 1)
    pattern = np.full((1, 1040, 1280), 128, dtype=np.uint8)
    frame = render_frames(g, pattern, photometry)[0]
    m = g.mask
    expected = g.albedo * photometry.projector_power * (
        photometry.ambient + g.irradiance * (128 / 255) ** 2.2)
    assert np.abs(frame[m].astype(float) - np.rint(expected[m] * 255)).max() <= 1
    assert np.all(frame[~g.surface] == 0)


@pytest.mark.parametrize("blur", [{"camera_blur_px": 6.0}, {"subsurface_mm": 0.3}])
def test_border_pixels_see_the_scene_beyond_the_sensor(rig_quarter, blur):
    """A lens integrates the light from beyond the sensor's edge too: the outer rows and columns
    of a camera equal the same pixels of a camera 6 px larger on each side (same optics), noise
    off. Blurring with the edge pixels repeated instead made them differ by 9 (camera blur)
    and 25 levels (subsurface spread)."""
    from dataclasses import replace

    photometry = Photometry(noise=False, **blur)
    big = rig_quarter.cameras[1]
    k = 6
    K = big.K.copy()
    K[0, 2] -= k
    K[1, 2] -= k
    small = replace(big, K=K, size=(big.size[0] - 2 * k, big.size[1] - 2 * k))
    scene = make_scene("finger", seed=3)
    cols = np.arange(1280)
    pattern = np.broadcast_to(np.rint(127.5 + 127 * np.cos(2 * np.pi * cols / 20)),
                              (1, 1040, 1280)).astype(np.uint8)
    frames = []
    for cam in (big, small):
        rig = replace(rig_quarter, cameras=[cam], camera_names=["cam"], photometry=photometry)
        frames.append(render_frames(camera_geometry(rig, scene, 0), pattern, photometry,
                                    scale=rig.scale)[0].astype(int))
    inner = frames[0][k:-k, k:-k]
    assert inner.shape == frames[1].shape
    assert np.abs(inner - frames[1]).max() <= 1  # the rays' rounding, at most a level


def test_projector_flicker_scales_each_frame_alike_for_every_camera(rig_quarter):
    """Frame k's projected light is (1 + flicker z_k) times the steady one, the ambient term
    not; the same factors for every camera; no flicker, no factor (frames byte-identical)."""
    from nail2nail.simulation.render import frame_flicker

    assert frame_flicker(Photometry(), 4, seed=1) is None
    steady = Photometry(noise=False, camera_blur_px=0.0, projector_blur_px=0.0, bit_depth=16)
    flickering = Photometry(noise=False, camera_blur_px=0.0, projector_blur_px=0.0,
                            bit_depth=16, projector_flicker=0.02)
    factors = frame_flicker(flickering, 3, seed=5)
    np.testing.assert_array_equal(factors, frame_flicker(flickering, 3, seed=5))
    assert factors.shape == (3,) and 0.002 < np.std(factors - 1) < 0.1
    pattern = np.full((3, 1040, 1280), 200, dtype=np.uint8)
    for camera in (0, 2):
        g = camera_geometry(rig_quarter, make_scene("sphere"), camera)
        a = render_frames(g, pattern, steady, seed=5, camera_index=camera).astype(float)
        b = render_frames(g, pattern, flickering, seed=5, camera_index=camera).astype(float)
        top = 65535
        ambient = (g.albedo * steady.projector_power * steady.ambient * top)[g.mask]
        for k in range(3):
            lit_a, lit_b = a[k][g.mask] - ambient, b[k][g.mask] - ambient
            bright = lit_a > 1000
            ratio = lit_b[bright] / lit_a[bright]
            assert np.median(ratio) == pytest.approx(factors[k], abs=2e-3)


def test_render_reproducible_and_bit_depth(rig_quarter):
    g = camera_geometry(rig_quarter, make_scene("sphere"), 2)
    a = render_frames(g, WHITE, rig_quarter.photometry, seed=3, camera_index=2)
    b = render_frames(g, WHITE, rig_quarter.photometry, seed=3, camera_index=2)
    c = render_frames(g, WHITE, rig_quarter.photometry, seed=4, camera_index=2)
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)
    twelve = Photometry(bit_depth=12)
    d = render_frames(g, WHITE, twelve, seed=3)
    assert d.dtype == np.uint16 and np.all(d % 16 == 0) and d.max() > 255 * 16


def test_render_any_pattern_sequence(rig_quarter):
    """Fringes along panel rows appear where the truth yp says they should."""
    photometry = Photometry(noise=False, camera_blur_px=0.0, projector_blur_px=0.0,
                            projector_gamma=1.0, ambient=0.0)
    g = camera_geometry(rig_quarter, make_scene("plane", rig=rig_quarter), 1)
    rows = np.arange(1040)
    stripes = (rows // 65) % 2 == 0
    pattern = np.where(stripes[:, None], 255, 0).astype(np.uint8)[None].repeat(1280, 2)
    frame = render_frames(g, pattern, photometry)[0]
    yp = g.yp[g.mask]
    inside = np.abs((yp + 0.5) / 65 - np.rint((yp + 0.5) / 65)) > 0.05
    bright = frame[g.mask] > 0.5 * frame[g.mask].max()
    expect = (np.floor((yp + 0.5) / 65) % 2) == 0
    assert np.mean(bright[inside] == expect[inside]) > 0.999


def test_render_bad_input(rig_quarter):
    g = camera_geometry(rig_quarter, make_scene("sphere"), 1)
    with pytest.raises(ValueError, match="does not match"):
        render_frames(g, np.zeros((1, 10, 10), np.uint8), rig_quarter.photometry)
    with pytest.raises(ValueError, match="n_frames"):
        render_frames(g, np.zeros((10, 10), np.uint8), rig_quarter.photometry)
    with pytest.raises(ValueError, match="2-D"):
        projector_radiance(np.zeros((2, 3, 4), np.uint8), rig_quarter.photometry)
    with pytest.raises(ValueError, match="camera_index"):
        camera_geometry(rig_quarter, make_scene("sphere"), 5)
    with pytest.raises(ValueError, match="scene"):
        make_scene("teapot")


def test_geometry_reused_under_other_patterns(rig_quarter, tmp_path):
    """simulate(geometry=...) renders the same frames as casting the rays again, and
    write_capture writes what simulate_capture writes."""
    from nail2nail.io.capture import read_capture
    from nail2nail.scan.patterns import PatternSet, make_patterns
    from nail2nail.simulation.capture import simulate, write_capture

    ps = PatternSet(x=[(1, 3), (8, 3)], y=[(1, 3), (8, 3)], panel_size=rig_quarter.panel_size)
    first = simulate("sphere", rig=rig_quarter, pattern_set=ps, seed=4)
    inverted = 255 - make_patterns(ps)
    again = simulate(first.scene, rig=rig_quarter, patterns=inverted, pattern_set=ps, seed=4)
    reused = simulate(first.scene, rig=rig_quarter, patterns=inverted, pattern_set=ps, seed=4,
                      geometry=first.geometry)
    for name in first.frames:
        np.testing.assert_array_equal(reused.frames[name], again.frames[name])
        assert not np.array_equal(reused.frames[name], first.frames[name])
    with pytest.raises(ValueError, match="no camera 'cam1'"):
        simulate(first.scene, rig=rig_quarter, pattern_set=ps, geometry={"cam0": None})
    write_capture(tmp_path / "cap", reused, seed=4, write_truth=False)
    capture = read_capture(tmp_path / "cap")
    np.testing.assert_array_equal(capture.load_frames("cam0", raw=True), reused.frames["cam0"])
