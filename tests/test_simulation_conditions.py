"""The virtual scanner as many scanners: random conditions, sharp pixel grids, highlights,
subsurface spread, tapered and posed fingers (issue 22)."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.cli import main
from nail2nail.io.capture import read_capture
from nail2nail.scan.decoding import decode
from nail2nail.simulation.conditions import RANGES, Conditions, draw_conditions
from nail2nail.simulation.render import aperture_weights, camera_geometry, render_frames
from nail2nail.simulation.rig import Photometry, default_rig
from nail2nail.simulation.scenes import make_scene


@pytest.fixture(scope="module")
def rig_quarter():
    return default_rig(0.25)


# -- drawing conditions -----------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_conditions_are_drawn_within_their_ranges(seed):
    c = draw_conditions(seed)
    assert draw_conditions(seed) == c  # reproducible
    p, f = c.photometry, c.finger
    for key in ("projector_blur_px", "projector_gamma", "projector_power", "camera_blur_px",
                "ambient", "full_well", "read_noise", "specular", "specular_exponent",
                "subsurface_mm"):
        lo, hi = RANGES[key]
        assert lo - 1e-3 <= p[key] <= hi + 1e-3, key
    if p["projector_fill_factor"] is not None:
        lo, hi = RANGES["projector_fill_factor"]
        assert lo - 1e-3 <= p["projector_fill_factor"] <= hi + 1e-3
    lo, hi = RANGES["section_ratio"]
    assert lo - 1e-3 <= f["az"] / f["ax"] <= hi + 1e-3
    assert all(abs(a) <= 10.001 for a in f["rotation_deg"])
    Photometry(**p)  # valid
    json.dumps(c.to_dict())  # JSON-ready


def test_conditions_differ_between_seeds_and_override_ranges():
    a, b = draw_conditions(1), draw_conditions(2)
    assert a.photometry != b.photometry and a.finger != b.finger
    c = draw_conditions(1, {"projector_gamma": (2.2,), "tilt_deg": (5.0,)})
    assert c.photometry["projector_gamma"] == 2.2 and c.finger["rotation_deg"][0] == 5.0
    with pytest.raises(ValueError, match="unknown key"):
        draw_conditions(1, {"gamma": (2.0, 2.4)})


def test_conditions_build_the_rig_and_the_finger():
    c = draw_conditions(7)
    rig = c.rig(0.25)
    assert rig.cameras[0].size == default_rig(0.25).cameras[0].size
    for key, value in c.photometry.items():
        assert getattr(rig.photometry, key) == value
    finger = make_scene("finger", rig=rig, seed=7, **c.finger_options())
    assert finger.taper == c.finger["taper"] and finger.pattern == c.finger["pattern"]
    image = np.full((60, 50), 255, np.uint8)
    options = Conditions(7, c.photometry, c.finger).finger_options(print_image=image)
    assert "pattern" not in options and options["print_image"] is image


def test_photometry_refuses_bad_optics():
    with pytest.raises(ValueError, match="projector_fill_factor"):
        Photometry(projector_fill_factor=0.0)
    with pytest.raises(ValueError, match="projector_fill_factor"):
        Photometry(projector_fill_factor=1.5)
    with pytest.raises(ValueError, match="specular"):
        Photometry(specular=-0.1)
    with pytest.raises(ValueError, match="subsurface_mm"):
        Photometry(subsurface_mm=-1.0)


# -- a sharp pixel grid -----------------------------------------------------------------------
def test_aperture_weights_of_a_sharp_grid():
    """Weights over the panel pixels: a box of side √fill per pixel, normalised to the pixel's
    mean radiance, blurred by the defocus and the camera pixel's footprint."""
    rig = default_rig(0.25)
    g = camera_geometry(rig, make_scene("plane", rig=rig), 1)
    K, _, _, wx, wy = aperture_weights(g, Photometry(projector_fill_factor=0.64,
                                                     projector_blur_px=0.3))
    assert wx.shape == wy.shape == (int(g.mask.sum()), 2 * K + 1)
    # a uniform panel row sums to 1 on average over pixel phases (energy kept; gaps dark)
    assert np.mean(wx.sum(axis=1)) == pytest.approx(1.0, abs=0.02)
    assert np.all(wx >= 0) and np.all(wy >= 0)


def test_sharp_grid_decodes_the_panel_coordinate(rig_quarter):
    """A plane under the default patterns through sharp apertures decodes to the true panel
    coordinate within a few hundredths of a pixel, and the grid's dark gaps show in a
    uniform frame's brightness (a projector's screen-door pattern), which the soft model
    does not have."""
    from nail2nail.scan.patterns import default_pattern_set, make_patterns

    scene = make_scene("plane", rig=rig_quarter)
    g = camera_geometry(rig_quarter, scene, 1)
    ps = default_pattern_set()
    patterns = make_patterns(ps)
    sharp = Photometry(projector_fill_factor=0.5, projector_blur_px=0.0, camera_blur_px=0.0,
                       noise=False, bit_depth=12)
    frames = render_frames(g, patterns, sharp, scale=0.25)
    d = decode(frames, ps)
    ok = d.mask & g.mask
    err = d.xp[ok] - g.xp[ok]
    assert ok.mean() > 0.5 * g.mask.mean()
    assert np.median(np.abs(err)) < 0.05
    white = np.full((1, 1040, 1280), 255, np.uint8)
    soft = Photometry(noise=False, camera_blur_px=0.0, bit_depth=12)
    # at a quarter of the resolution a camera pixel covers 3 panel pixels: the grid averages
    # out in a 1/4 rig; at full resolution (one panel pixel a camera pixel) it shows
    full = default_rig(1.0)
    gf = camera_geometry(full, make_scene("plane", rig=full), 1)
    win = (slice(500, 540), slice(620, 660))
    tiles = [render_frames(gf, white, p)[0][win].astype(float) for p in (sharp, soft)]
    assert np.std(tiles[0]) > 3 * np.std(tiles[1])


def test_specular_and_subsurface(rig_quarter):
    scene = make_scene("sphere")
    shiny = camera_geometry(default_rig(0.25, photometry=Photometry(
        specular=0.3, reference_distance_mm=176.5)), scene, 1)
    assert shiny.specular.max() > 0.05 and np.all(shiny.specular[~shiny.mask] == 0)
    dull = camera_geometry(rig_quarter, scene, 1)
    assert np.all(dull.specular == 0)
    # the spread of light in the skin lowers the fine fringes' contrast
    x = np.arange(1280)
    fringes = np.stack([np.tile(np.uint8(127.5 + 127 * np.cos(2 * np.pi * x / 20 - k)),
                                (1040, 1)) for k in (0, 2.1, 4.2)])
    contrast = []
    for mm in (0.0, 0.15):
        p = Photometry(subsurface_mm=mm, noise=False, camera_blur_px=0.0, bit_depth=16)
        f = render_frames(dull, fringes, p, scale=0.25).astype(float)
        contrast.append(np.median((f.max(0) - f.min(0))[dull.mask]))
    assert contrast[1] < 0.7 * contrast[0]


# -- finger shape and pose --------------------------------------------------------------------
def test_posed_finger_keeps_its_skin_coordinates():
    """A rotated and shifted finger: the world surface points map to the same (u, v) as the
    upright finger's; its normals are rotated with it."""
    upright = make_scene("finger", seed=3, print_image=None)
    posed = make_scene("finger", seed=3, rotation_deg=(8.0, -6.0, 9.0), offset_mm=(1.0, -0.5,
                                                                                   0.7))
    rng = np.random.default_rng(0)
    origin = np.array([0.0, -3.0, 60.0])  # rays from one point, as a camera's
    target = np.column_stack([rng.uniform(-3, 3, 50), rng.uniform(-10, 5, 50), np.zeros(50)])
    d = (target - origin) / np.linalg.norm(target - origin, axis=1)[:, None]
    t = upright.intersect(origin, d)
    hit = np.isfinite(t)
    assert hit.sum() > 40
    pts = origin + t[hit, None] * d[hit]
    world = pts @ posed._R.T + posed._t
    u0, v0 = upright.print_coordinates(pts)
    u1, v1 = posed.print_coordinates(world)
    np.testing.assert_allclose(u1, u0, atol=1e-9)
    np.testing.assert_allclose(v1, v0, atol=1e-9)
    # the posed finger's rays, moved with it, hit the same skin
    t2 = posed.intersect(origin @ posed._R.T + posed._t, d[hit] @ posed._R.T)
    np.testing.assert_allclose(t2, t[hit], atol=1e-6)
    n0 = upright.surface(pts).normal
    n1 = posed.surface(world).normal
    np.testing.assert_allclose(n1, n0 @ posed._R.T, atol=1e-6)


def test_tapered_finger_widens_below_the_cap():
    finger = make_scene("finger", taper=0.01)
    for y, k in ((finger.y0, 1.0), (finger.y0 - 10, 1.1), (finger.y0 - 40, 1.3)):
        o = np.array([0.0, y, 40.0])
        t = finger.intersect(o, np.array([[0.0, 0.0, -1.0]]))[0]
        assert 40.0 - t == pytest.approx(finger.az * k, abs=0.05)
    with pytest.raises(ValueError, match="taper"):
        make_scene("finger", taper=-0.01)
    with pytest.raises(ValueError, match="rotation_deg"):
        make_scene("finger", rotation_deg=(1.0, 2.0))


@functools.lru_cache(maxsize=1)
def _widest_print():
    return make_scene("finger", taper=0.02).fingerprint


@settings(max_examples=40, deadline=None)
@given(taper=st.floats(0.002, 0.02), below=st.floats(0.05, 3.0),
       azimuth=st.floats(-60.0, 60.0), elevation=st.floats(15.0, 60.0))
def test_tapered_finger_is_hit_first_from_above_the_cap(taper, below, azimuth, elevation):
    """A ray from above the cap's base (a projector above the cameras) to the body just below
    it hits the body there: its first hit is the point. The march's outer shell once left out
    the rays entering the tapered body's grown cylinder through the plane of the cap's base,
    so their march began past the skin and the simulator printed a false shadow band across
    the finger below the cap."""
    # the print of the most tapered finger (the widest) serves every taper: growing one per
    # taper cost a second each, and the ridges do not change the march being tested
    finger = make_scene("finger", taper=taper, fingerprint=_widest_print())
    a = np.radians(azimuth)
    y = finger.y0 - below
    k = 1 + taper * below
    # a point of the body (without the ridges, whose height the march finds) facing the ray
    point = np.array([finger.ax * k * np.sin(a), y, finger.az * k * np.cos(a)])
    e = np.radians(elevation)
    toward = np.array([np.sin(a) * np.cos(e), np.sin(e), np.cos(a) * np.cos(e)])
    origin = point + 150.0 * toward
    t = finger.intersect(origin, -toward[None])[0]
    assert t == pytest.approx(150.0, abs=2 * finger._hmax + 0.01)


def test_cli_simulate_conditions(tmp_path, capsys):
    out = tmp_path / "cap"
    assert main(["simulate", "--scene", "finger", "--conditions", "5", "--scale", "0.125",
                 "--out", str(out), "--json", "--no-truth"]) == 0
    summary = json.loads(capsys.readouterr().out)
    drawn = draw_conditions(5)
    assert summary["conditions"] == json.loads(json.dumps(drawn.to_dict()))
    manifest = json.loads((out / "capture.json").read_text())
    assert manifest["rig"]["photometry"]["projector_gamma"] == drawn.photometry["projector_gamma"]
    assert manifest["scene"]["taper"] == drawn.finger["taper"]
    assert read_capture(out, load=False).camera_names == ["cam0", "cam1", "cam2"]
    assert main(["simulate", "--scene", "sphere", "--conditions", "5", "--out",
                 str(tmp_path / "x")]) == 2
    assert "--conditions" in capsys.readouterr().err
