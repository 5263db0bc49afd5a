"""Synthetic fingerprints (SFinGe-like growth), prints from images and the finger's rolled print."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.simulation.fingerprint import (
    PATTERN_FREQUENCIES,
    PATTERNS,
    Fingerprint,
    arch_orientation,
    find_minutiae,
    generate_fingerprint,
    orientation_field,
    pattern_for_seed,
)
from nail2nail.simulation.scenes import Finger, make_scene


@pytest.fixture(scope="module")
def small_print():
    return generate_fingerprint(u_range=(-6, 6), v_range=(-6, 6), cores=[(0, 1)],
                                deltas=[(-3, -4)], ridge_period=0.46, seed=1)


def local_periods(ridges, pitch, *, win=128, step=96):
    """Ridge period (mm) in windows: peak of the zero-padded, Hann-windowed 2D spectrum."""
    h, w = ridges.shape
    hann = np.hanning(win)[:, None] * np.hanning(win)[None, :]
    n = 512
    f = np.fft.fftfreq(n, pitch)
    radius = np.hypot(f[:, None], f[None, :])
    periods = []
    for r in range(0, h - win + 1, step):
        for c in range(0, w - win + 1, step):
            patch = ridges[r : r + win, c : c + win].astype(float)
            spec = np.abs(np.fft.fft2((patch - patch.mean()) * hann, (n, n))) ** 2
            spec[radius < 1.0] = 0  # below 1 cycle/mm: not ridges
            periods.append(1 / radius.flat[np.argmax(spec)])
    return np.array(periods)


# -- orientation models ---------------------------------------------------------------------
def _turn(theta):
    return np.sum(np.angle(np.exp(2j * np.diff(theta)))) / 2


def test_orientation_field_singularities():
    # around a core the orientation turns by +pi, around a delta by -pi
    t = np.linspace(0, 2 * np.pi, 721)
    for point, sign in (((0.0, 0.0), 1), ((0.0, -5.0), -1)):
        u, v = point[0] + 0.5 * np.cos(t), point[1] + 0.5 * np.sin(t)
        theta = orientation_field(u, v, cores=[(0, 0)], deltas=[(0, -5)])
        assert _turn(theta) == pytest.approx(sign * np.pi, abs=1e-6)


@settings(max_examples=30, deadline=None)
@given(n_cores=st.integers(0, 2), n_deltas=st.integers(0, 2),
       points=st.lists(st.tuples(st.floats(-8, 8), st.floats(-8, 8)), min_size=4, max_size=4),
       theta_inf=st.floats(-0.5, 0.5))
def test_orientation_field_winding_property(n_cores, n_deltas, points, theta_inf):
    # a loop around all singular points turns by pi (cores - deltas); values in [0, pi)
    cores, deltas = points[:n_cores], points[2 : 2 + n_deltas]
    t = np.linspace(0, 2 * np.pi, 4001)
    u, v = 30 * np.cos(t), 30 * np.sin(t)
    theta = orientation_field(u, v, cores=cores, deltas=deltas, theta_inf=theta_inf)
    assert np.all((theta >= 0) & (theta < np.pi))
    assert _turn(theta) == pytest.approx(np.pi * (n_cores - n_deltas), abs=1e-6)


def test_arch_orientation_smooth_without_singularities():
    t = np.linspace(0, 2 * np.pi, 2001)
    theta = arch_orientation(6 * np.cos(t), 6 * np.sin(t), center=(0, 0))
    assert _turn(theta) == pytest.approx(0, abs=1e-6)
    # ridges rise towards the centre from the left and fall to the right
    assert 0 < arch_orientation(-3.0, 2.0, center=(0, 0)) < np.pi / 2
    assert np.pi / 2 < arch_orientation(3.0, 2.0, center=(0, 0)) < np.pi


# -- pattern classes --------------------------------------------------------------------------
def test_pattern_for_seed_frequencies_and_variety():
    assert set(pattern_for_seed(s) for s in range(10)) == set(PATTERNS)
    counts = {p: 0 for p in PATTERNS}
    for s in range(20000):
        counts[pattern_for_seed(s)] += 1
    for p in PATTERNS:
        assert counts[p] / 20000 == pytest.approx(PATTERN_FREQUENCIES[p], abs=0.005)
    assert sum(PATTERN_FREQUENCIES.values()) == pytest.approx(1.0)


@pytest.mark.parametrize(("pattern", "n_cores", "n_deltas"), [
    ("arch", 0, 0), ("tented_arch", 1, 1), ("left_loop", 1, 1), ("right_loop", 1, 1),
    ("whorl", 2, 2)])
def test_pattern_singular_points(pattern, n_cores, n_deltas):
    center = (0.5, 3.0)
    fp = generate_fingerprint(u_range=(-1, 1), v_range=(-1, 1), center=center, pattern=pattern,
                              seed=3, iterations=1)
    assert fp.pattern == pattern and fp.describe()["pattern"] == pattern
    assert fp.cores.shape == (n_cores, 2) and fp.deltas.shape == (n_deltas, 2)
    if n_cores:
        mid = fp.cores.mean(axis=0)
        assert np.all(np.abs(mid - center) <= 1.5 + 1e-9)
        assert np.all(fp.deltas[:, 1] < mid[1] - 1.5)
    if pattern == "left_loop":  # delta at the image right: smaller u (columns run to -u)
        assert fp.deltas[0, 0] < fp.cores[0, 0] - 4
    if pattern == "right_loop":
        assert fp.deltas[0, 0] > fp.cores[0, 0] + 4


def test_seeds_give_different_fingers():
    prints = [generate_fingerprint(u_range=(-2, 2), v_range=(-2, 2), seed=s, iterations=1)
              for s in range(10)]
    assert len({fp.pattern for fp in prints}) == 5
    cores = [tuple(fp.cores[0].round(3)) for fp in prints if len(fp.cores)]
    assert len(set(cores)) == len(cores)
    periods = {round(fp.ridge_period, 4) for fp in prints}
    assert len(periods) == 10 and all(0.45 <= p <= 0.50 for p in periods)


# -- growth -----------------------------------------------------------------------------------
def test_ridge_period_and_range(small_print):
    fp = small_print
    assert fp.ppi == pytest.approx(500)
    assert fp.ridges.dtype == np.float32
    assert fp.ridges.min() >= -1 and fp.ridges.max() <= 1
    periods = local_periods(fp.ridges, fp.pitch)
    assert np.median(periods) == pytest.approx(0.46, rel=0.05)


def test_ridge_period_measured_in_local_windows():
    # issue 9: the period measured on the image (FFT peak in 6.5 mm windows) is realistic
    fp = generate_fingerprint(u_range=(-10, 10), v_range=(-8, 12), center=(0, 3), seed=4)
    assert 0.45 <= fp.ridge_period <= 0.50
    periods = local_periods(fp.ridges, fp.pitch)
    assert np.median(periods) == pytest.approx(fp.ridge_period, rel=0.04)
    assert np.mean((periods > 0.40) & (periods < 0.58)) >= 0.9


def test_no_seams_in_the_ridge_field(small_print):
    # the ridge profile is the same everywhere: local RMS and smoothness carry no block
    # structure (no jumps between neighbouring pixels beyond a ridge flank's slope)
    r = small_print.ridges.astype(float)
    step = np.abs(np.diff(r, axis=1)).max(), np.abs(np.diff(r, axis=0)).max()
    period_px = 0.46 / small_print.pitch
    assert max(step) < 2 * np.pi / period_px * 2.5  # a sine of amplitude ~1.3 at most
    col_energy = np.mean(r**2, axis=0)[20:-20]
    row_energy = np.mean(r**2, axis=1)[20:-20]
    assert col_energy.std() < 0.1 and row_energy.std() < 0.1


def test_minutiae_found_and_reproducible(small_print):
    fp = small_print
    assert len(fp.minutiae) >= 5
    assert set(np.unique(fp.minutiae[:, 4])) <= {1.0, 3.0}
    col, row = fp.pixel_from_uv(fp.minutiae[:, 0], fp.minutiae[:, 1])
    np.testing.assert_allclose(np.column_stack([col, row]), fp.minutiae[:, 2:4], atol=1e-9)
    again = generate_fingerprint(u_range=(-6, 6), v_range=(-6, 6), cores=[(0, 1)],
                                 deltas=[(-3, -4)], ridge_period=0.46, seed=1)
    np.testing.assert_array_equal(again.ridges, fp.ridges)
    other = generate_fingerprint(u_range=(-6, 6), v_range=(-6, 6), cores=[(0, 1)],
                                 deltas=[(-3, -4)], ridge_period=0.46, seed=2)
    assert np.any(other.ridges != fp.ridges)


def test_minutiae_density_realistic():
    fp = generate_fingerprint(u_range=(-10, 10), v_range=(-8, 12), center=(0, 3), seed=0)
    u, v = fp.minutiae[:, 0], fp.minutiae[:, 1]
    inner = (np.abs(u) < 8) & (np.abs(v - 2) < 8)
    density = inner.sum() / 16**2
    assert 0.18 <= density <= 0.5


def test_find_minutiae_on_a_drawn_ridge():
    image = -np.ones((60, 60))
    image[28:32, 10:40] = 1.0  # one ridge: two endings
    image[20:40, 38:42] = 1.0  # joined to a vertical one: a T-junction, i.e. a bifurcation
    found = find_minutiae(image, border_px=2, min_distance_px=3)
    kinds = sorted(found[:, 2].tolist())
    assert kinds.count(1.0) == 3 and kinds.count(3.0) == 1
    ending = found[(found[:, 2] == 1) & (found[:, 0] < 20)]
    assert ending.shape[0] == 1 and 9 <= ending[0, 0] <= 13 and 28 <= ending[0, 1] <= 31


def test_sample_matches_grid(small_print):
    fp = small_print
    rows, cols = np.array([10, 100, 200]), np.array([5, 150, 230])
    u, v = fp.uv_from_pixel(cols, rows)
    np.testing.assert_allclose(fp.sample(u, v), fp.ridges[rows, cols], atol=1e-5)


def test_legacy_grid_orientation(small_print):
    # legacy convention: column 0 is the largest u, row 0 the largest v
    fp = small_print
    assert fp.u0 == 6 and fp.v0 == 6
    u, v = fp.uv_from_pixel(np.array([0, 10]), np.array([0, 10]))
    assert u[1] < u[0] and v[1] < v[0]
    geometry = fp.describe()
    assert geometry["col_direction"] == "-u" and geometry["row_direction"] == "-v"
    assert geometry["u_of_col0_mm"] == 6 and geometry["v_of_row0_mm"] == 6


@settings(max_examples=50, deadline=None)
@given(u=st.floats(-20, 20), v=st.floats(-20, 20), ppi=st.floats(250, 1000),
       cu=st.floats(-3, 3), cv=st.floats(-3, 8))
def test_pixel_uv_round_trip(u, v, ppi, cu, cv):
    fp = Fingerprint.from_image(np.zeros((7, 9), np.uint8), ppi=ppi, center_uv=(cu, cv),
                                normalize=False)
    col, row = fp.pixel_from_uv(u, v)
    u2, v2 = fp.uv_from_pixel(col, row)
    assert u2 == pytest.approx(u, abs=1e-9) and v2 == pytest.approx(v, abs=1e-9)
    # mirror: one pixel to the right is one pitch towards -u; the centre pixel is center_uv
    assert fp.uv_from_pixel(col + 1, row)[0] == pytest.approx(u - 25.4 / ppi, abs=1e-9)
    uc, vc = fp.uv_from_pixel(4, 3)
    assert uc == pytest.approx(cu, abs=1e-9) and vc == pytest.approx(cv, abs=1e-9)


def test_generate_bad_input():
    with pytest.raises(ValueError, match="ridge_period"):
        generate_fingerprint(ridge_period=5.0)
    with pytest.raises(ValueError, match="u_range"):
        generate_fingerprint(u_range=(3, 1))
    with pytest.raises(ValueError, match="pattern"):
        generate_fingerprint(pattern="double_loop")
    with pytest.raises(ValueError, match="ppi"):
        generate_fingerprint(ppi=0)


# -- prints from images -----------------------------------------------------------------------
def _stripes(h=41, w=61, period_px=9):
    rows = np.arange(h)[:, None] + 0 * np.arange(w)[None, :]
    return np.rint(127.5 + 127.5 * np.cos(2 * np.pi * rows / period_px)).astype(np.uint8)


def test_from_image_values_and_outside():
    image = _stripes()
    fp = Fingerprint.from_image(image, ppi=500, center_uv=(1.0, 2.0), normalize=False)
    assert fp.pattern == "image" and fp.outside == "flat" and len(fp.minutiae) == 0
    np.testing.assert_array_equal(fp.image, image)
    np.testing.assert_allclose(fp.ridges, (127.5 - image) / 127.5, atol=1e-6)
    rows, cols = np.array([0, 7, 20, 40]), np.array([0, 30, 11, 60])
    u, v = fp.uv_from_pixel(cols, rows)
    np.testing.assert_allclose(fp.sample(u, v), fp.ridges[rows, cols], atol=1e-5)
    # beyond the image the skin is flat
    far = fp.sample(np.array([1.0, 1.0 + 5, 1.0 - 5]), np.array([2.0 + 5, 2.0, 2.0]))
    np.testing.assert_allclose(far, 0.0, atol=1e-12)


def test_from_image_normalised_contrast():
    faint = (96 + (_stripes().astype(int) // 8)).astype(np.uint8)  # weak ink
    fp = Fingerprint.from_image(faint, ppi=500, normalize=True)
    inner = fp.ridges[10:-10, 10:-10]
    assert inner.max() > 0.9 and inner.min() < -0.9
    # ridges (dark) still positive
    dark = faint[10:-10, 10:-10] < np.median(faint)
    assert np.mean(inner[dark] > 0) > 0.95
    blank = Fingerprint.from_image(np.full((30, 30), 250, np.uint8))
    np.testing.assert_allclose(blank.ridges, 0.0, atol=1e-6)


@pytest.mark.parametrize(("image", "match"), [
    (np.zeros((5, 5), np.uint16), "uint8"),
    (np.zeros((5, 5, 3), np.uint8), "shape"),
    (np.zeros((0, 5), np.uint8), "shape"),
])
def test_from_image_bad_input(image, match):
    with pytest.raises(ValueError, match=match):
        Fingerprint.from_image(image)
    with pytest.raises(ValueError, match="ppi"):
        Fingerprint.from_image(np.zeros((5, 5), np.uint8), ppi=-1)


# -- the finger --------------------------------------------------------------------------------
def test_rolled_print():
    scene = make_scene("finger")
    image, mask = scene.rolled_print()
    fp = scene.fingerprint
    assert image.shape == mask.shape and image.dtype == np.uint8
    assert fp.ppi == pytest.approx(500)
    assert np.all(image[~mask] == 255)
    # the tip: above y0 + meridian length nothing maps onto the finger
    _, v = scene.uv_from_legacy_pixel(0, np.arange(image.shape[0]))
    assert not np.any(mask[v > scene.y0 + scene._m[-1] + 0.1])
    assert np.all(mask[(v < scene.y0 - 1) & (v > scene.v_tip - 24)][:, image.shape[1] // 2])
    # ridges dark: the ink of ridge crests
    r0, r1, c0, c1 = scene._box
    crest = (fp.ridges[r0:r1, c0:c1] > 0.9) & mask
    assert image[crest].mean() < 60
    assert len(fp.minutiae) > 50 and len(scene.rolled_print_minutiae()) > 50
    assert np.linalg.norm(fp.cores.mean(axis=0) - scene.pad_center) <= 1.5 * np.sqrt(2)


def test_ridge_envelope_pad_and_back():
    # friction-ridge skin on the palmar side only: the envelope is 1 on the pad, 0 on the back
    scene = make_scene("finger")
    phi = np.radians([0.0, 60.0, -100.0, 115.0, 150.0, 180.0, -130.0])
    for y in (-10.0, 0.0, 5.0):
        xyz = np.column_stack([scene.ax * np.sin(phi), np.full(len(phi), y),
                               scene.az * np.cos(phi)])
        u, v = scene.print_coordinates(xyz)
        np.testing.assert_array_equal(scene.ridge_envelope(u, v), [1, 1, 1, 0, 0, 0, 0])
        # no relief and no albedo contrast on the back, ridges on the pad
        albedo = scene.surface(xyz).albedo
        np.testing.assert_allclose(albedo[3:], scene.skin_albedo, atol=1e-12)
        np.testing.assert_allclose(scene.implicit(xyz)[3:], 0.0, atol=1e-6)
        assert np.abs(scene.implicit(xyz)[:3]).max() > 1e-4
    # the fall: ridge_edge_mm of arc before the nail edge, on the cap at the same angle
    s_edge = np.interp(np.radians(110.0), scene._phi, scene._s)
    e = scene.ridge_envelope(np.array([s_edge - 1.0, s_edge - 0.5, s_edge]), np.zeros(3))
    np.testing.assert_allclose(e, [1.0, 0.5, 0.0], atol=1e-12)
    psi = np.radians(60.0)
    v_cap = scene.y0 + np.interp(psi, scene._psi, scene._m)
    e = scene.ridge_envelope(np.cos(psi) * np.array([s_edge - 1.0, s_edge + 0.1]), v_cap)
    np.testing.assert_allclose(e, [1.0, 0.0], atol=1e-9)
    assert scene.ridge_envelope(0.0, scene.v_tip) == 1.0  # the apex
    # all round, or a print from an image: no envelope
    assert np.all(Finger(ridge_arc_deg=180).ridge_envelope(np.array([0.0, 24.0]), 0.0) == 1)


def test_rolled_print_extent_and_size():
    # the truth print: nail edge to nail edge (|phi| <= 110 deg), tip to 25 mm below it, cut
    # to its bounding box plus 1 mm, 500 ppi
    scene = make_scene("finger")
    image, mask = scene.rolled_print()
    pitch = scene.fingerprint.pitch
    arc = np.interp(np.radians(110.0), scene._phi, scene._s)
    assert image.shape[1] == pytest.approx((2 * arc + 2) / pitch, abs=3)
    assert image.shape[0] == pytest.approx((25 + 2) / pitch, abs=3)
    geometry = scene.rolled_print_geometry()
    assert geometry["shape"] == list(image.shape)
    assert geometry["ridge_arc_deg"] == 110 and geometry["rolled_length_mm"] == 25
    assert geometry["rolled_extent"]["u_max_mm"] == pytest.approx(arc, abs=1e-6)
    u, v = scene.uv_from_legacy_pixel(np.arange(image.shape[1])[None, :],
                                      np.arange(image.shape[0])[:, None])
    assert (u[0, 0], v[0, 0]) == (geometry["u_of_col0_mm"], geometry["v_of_row0_mm"])
    # about 1 mm margins all round, white
    assert u[0, 0] == pytest.approx(arc + 1, abs=pitch) and u[0, -1] == pytest.approx(-arc - 1,
                                                                                        abs=pitch)
    assert v[0, 0] == pytest.approx(scene.v_tip + 1, abs=pitch)
    assert v[-1, 0] == pytest.approx(scene.v_tip - 26, abs=pitch)
    assert not mask[:, :15].any() and not mask[:, -15:].any() and not mask[-15:].any()
    assert np.all(image[:, :15] == 255) and np.all(image[-15:] == 255)
    # mask: the rolled extent; inked where the envelope is 1 (ridges span the grey range)
    np.testing.assert_array_equal(mask, scene.rolled_extent(u, v))
    body = (np.abs(u) < arc - 1.5) & (v < scene.y0) & (v > scene.v_tip - 23)
    assert mask[body].all() and image[body].min() < 20 and image[body].max() > 235
    # a longer or narrower print
    longer = Finger(rolled_length_mm=30, ridge_arc_deg=90)
    shape = longer.rolled_print()[0].shape
    assert shape[0] == pytest.approx(32 / pitch, abs=3)
    assert shape[1] == pytest.approx((2 * np.interp(np.pi / 2, scene._phi, scene._s) + 2) / pitch,
                                     abs=3)


def test_legacy_print_pixel_hits_the_truth_pixel():
    # a skin point inside the rolled extent: print coordinates -> legacy pixel of the truth
    # print -> the ink of the ridge field at that point
    scene = make_scene("finger")
    image, mask = scene.rolled_print()
    phi = np.radians(np.linspace(-95, 95, 23))
    y = np.linspace(-5.0, 5.0, 23)
    xyz = np.column_stack([scene.ax * np.sin(phi), y, scene.az * np.cos(phi)])
    u, v = scene.print_coordinates(xyz)
    col, row = scene.legacy_print_pixel(u, v)
    assert scene.rolled_extent(u, v).all()
    ci, ri = np.rint(col).astype(int), np.rint(row).astype(int)
    assert np.all(mask[ri, ci])
    # the pixel centre's skin point is within half a pixel, and its ink is the ridge field
    uc, vc = scene.uv_from_legacy_pixel(ci, ri)
    pitch = scene.fingerprint.pitch
    assert np.all(np.abs(uc - u) <= pitch / 2 + 1e-9) and np.all(np.abs(vc - v) <= pitch / 2 + 1e-9)
    expected = np.rint(127.5 - 127.5 * scene.fingerprint.sample(uc, vc))
    np.testing.assert_allclose(image[ri, ci], expected, atol=2)
    # between pixel centres: the print interpolated at (col, row) is the surface's ridge
    # field at the point (dark = ridge crest = raised relief)
    printed = ndi.map_coordinates(image.astype(float), [row, col], order=1)
    relief = (scene._base_distance(xyz) - scene.implicit(xyz)) / scene._hmax
    np.testing.assert_allclose(printed, 127.5 - 127.5 * relief, atol=15)


def test_finger_bad_skin_parameters():
    for kwargs, match in (({"ridge_arc_deg": 0}, "ridge_arc_deg"),
                          ({"ridge_edge_mm": 0}, "ridge_edge_mm"),
                          ({"rolled_length_mm": -1}, "rolled_length_mm"),
                          ({"rolled_length_mm": np.inf}, "rolled_length_mm")):
        with pytest.raises(ValueError, match=match):
            Finger(**kwargs)


def test_rolled_print_is_the_mirror_of_the_pad_view():
    # issue 9: legacy convention. A point on the +X side of the finger (u > 0) lands left of
    # the print centre, a point nearer the tip (larger Y) higher up.
    scene = make_scene("finger")
    xyz = np.array([[3.0, 0.0, scene.az * np.sqrt(1 - (3.0 / scene.ax) ** 2)],
                    [-3.0, 0.0, scene.az * np.sqrt(1 - (3.0 / scene.ax) ** 2)],
                    [0.0, 4.0, scene.az]])
    u, v = scene.print_coordinates(xyz)
    col, row = scene.legacy_print_pixel(u, v)
    assert col[0] < col[1] and row[2] < row[0]
    mid = (scene.rolled_print()[0].shape[1] - 1) / 2
    assert col[0] < mid < col[1]
    u2, v2 = scene.uv_from_legacy_pixel(col, row)
    np.testing.assert_allclose(np.column_stack([u2, v2]), np.column_stack([u, v]), atol=1e-9)


def test_finger_pattern_option():
    scene = Finger(pattern="whorl", seed=5)
    assert scene.fingerprint.pattern == "whorl"
    assert scene.to_dict()["fingerprint"]["pattern"] == "whorl"


def test_finger_wears_an_image_print():
    # issue 9: a real print on the finger, true scale, image centre on the pad centre
    image = _stripes(201, 151, period_px=23)
    image[:5, :5] = 0
    scene = make_scene("finger", print_image=image, print_ppi=500)
    fp = scene.fingerprint
    rolled, mask = scene.rolled_print()
    np.testing.assert_array_equal(rolled, image)
    assert mask.all()
    uc, vc = scene.uv_from_legacy_pixel(75, 100)
    assert (uc, vc) == pytest.approx(scene.pad_center)
    # surface points: print coordinates -> legacy pixel -> the image value there
    cols, rows = np.array([10, 75, 140, 30]), np.array([20, 100, 180, 150])
    u, v = scene.uv_from_legacy_pixel(cols, rows)
    on_body = v <= scene.y0
    phi = np.interp(u, scene._s, scene._phi)
    xyz = np.column_stack([scene.ax * np.sin(phi), v, scene.az * np.cos(phi)])[on_body]
    pu, pv = scene.print_coordinates(xyz)
    pc, pr = scene.legacy_print_pixel(pu, pv)
    np.testing.assert_allclose(pc, cols[on_body], atol=1e-3)
    np.testing.assert_allclose(pr, rows[on_body], atol=1e-9)
    sampled = fp.sample(pu, pv)
    expected = fp.ridges[rows[on_body], cols[on_body]]
    np.testing.assert_allclose(sampled, expected, atol=0.05)
    # albedo follows the image: dark pixels (ridges) brighter skin
    albedo = scene.surface(xyz).albedo
    assert np.all(np.sign(albedo - scene.skin_albedo) == np.sign(np.round(expected, 3)))


def test_print_cache_between_processes(tmp_path, monkeypatch):
    """$NAIL2NAIL_FINGERPRINT_CACHE: a print grown once is read back identical (its relief
    upsampled again the same), keyed by its parameters; a damaged entry is grown again."""
    from nail2nail.simulation import scenes

    monkeypatch.setenv(scenes.PRINT_CACHE_ENV, str(tmp_path))
    args = ((-3.0, 3.0), (-3.0, 3.0), (0.0, 0.0), 5, "whorl")
    scenes._cached_fingerprint.cache_clear()
    grown = scenes._cached_fingerprint(*args)
    files = list(tmp_path.glob("print-*.npz"))
    assert len(files) == 1
    scenes._cached_fingerprint.cache_clear()
    read = scenes._cached_fingerprint(*args)
    assert read is not grown
    for key in ("ridges", "orientation", "minutiae", "cores", "deltas", "_fine"):
        np.testing.assert_array_equal(getattr(read, key), getattr(grown, key), err_msg=key)
    for key in ("u0", "v0", "pitch", "pattern", "seed", "ridge_period", "_pad"):
        assert getattr(read, key) == getattr(grown, key), key
    uv = np.array([[0.3, -1.2], [1.7, 0.4]])
    np.testing.assert_array_equal(read.sample(*uv.T), grown.sample(*uv.T))
    scenes._cached_fingerprint.cache_clear()
    scenes._cached_fingerprint((-3.0, 3.0), (-3.0, 3.0), (0.0, 0.0), 6, "whorl")
    assert len(list(tmp_path.glob("print-*.npz"))) == 2  # another seed, another entry
    files[0].write_bytes(b"not an npz")
    scenes._cached_fingerprint.cache_clear()
    again = scenes._cached_fingerprint(*args)
    np.testing.assert_array_equal(again.ridges, grown.ridges)
    scenes._cached_fingerprint.cache_clear()
