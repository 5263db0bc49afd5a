"""Tests of nail2nail.merge: projector-space correspondence and merge error (thesis ch. 4)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).parent))
from _synthetic import synthetic_scans

from nail2nail._interpolate import bilinear
from nail2nail.merge import (
    DROP_REASONS,
    REJECT_REASONS,
    correspond,
    incidence_cosine,
    merge_statistics,
    nearest_bruteforce,
    nearest_kdtree,
    refine_subpixel,
    restrict_pairs,
    sample_pixels,
    valid_mask,
)
from nail2nail.scan.results import Scan

SIZE = (96, 120)  # (width, height): reduced resolution, 0.27 mm per pixel at the finger


@pytest.fixture(scope="module")
def clean():
    return synthetic_scans(size=SIZE)


@pytest.fixture(scope="module")
def noisy():
    return synthetic_scans(size=SIZE, noise_px=0.05, seed=3)


def _flat_scan(name="flat", shape=(20, 24), *, dx=0.0, dz=0.0):
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float32)
    xyz = np.stack([cc * 0.1, rr * 0.1, 0 * rr + dz], -1).astype(np.float32)
    one = np.ones(shape, np.float32)
    return Scan(name, xyz, (1.3 * cc + 0.2 * rr + dx).astype(np.float32),
                (0.1 * cc + 1.1 * rr).astype(np.float32), one, one, one, one > 0)


# -- ground truth ----------------------------------------------------------------------------
def test_zero_noise_merge_error_is_interpolation_only(clean):
    m = correspond(clean[0], clean[1])
    stats = m.statistics()
    assert m.n_pairs > 2000
    assert stats["distance_mm"]["median"] < 0.002  # sub-micron-ish at 0.27 mm pixels
    assert stats["distance_mm"]["frac_below_0_05"] == 1.0
    assert np.all(m.residual_px < 1e-3)


def test_known_shift_gives_known_merge_error(clean):
    shifted = replace(clean[1], xyz=clean[1].xyz + np.float32([0.05, 0, 0]))
    m = correspond(clean[0], shifted)
    d = m.distance_mm
    assert np.median(d) == pytest.approx(0.05, abs=0.002)
    assert m.statistics()["squared_mm2"]["median"] == pytest.approx(0.0025, abs=2e-4)


def test_noise_sets_the_merge_error(noisy):
    # 0.05 px decoding noise in both scans, ≈ 0.031 mm per projector px at the finger:
    # a 2-D Gaussian offset of σ ≈ 0.05·√2·0.031 mm has median ≈ 1.18 σ ≈ 2.6 µm.
    m = correspond(noisy[0], noisy[1])
    median = m.statistics()["distance_mm"]["median"]
    assert 0.001 < median < 0.006


def test_counts_add_up_and_overlap_is_decided(clean):
    m = correspond(clean[0], clean[2])
    assert m.n_sampled == m.n_pairs + sum(m.dropped.values())
    assert set(m.dropped) == set(DROP_REASONS)
    assert m.dropped["parent_border"] > 0 and m.dropped["child_border"] > 0
    # every kept pair is a true correspondence (exact geometry)
    assert m.distance_mm.max() < 0.02


def test_region_the_child_never_saw_is_dropped(clean):
    child = clean[1]
    mask = child.mask.copy()
    mask[:, : SIZE[0] // 2] = False  # the child lost its left half
    cut = replace(child, mask=mask)
    full = correspond(clean[0], child)
    half = correspond(clean[0], cut)
    assert half.n_pairs < full.n_pairs
    assert half.distance_mm.max() < 0.02  # no false pairs from nearest neighbours at the cut
    assert half.dropped["child_border"] > full.dropped["child_border"]


def test_projector_discontinuity_is_not_interpolated_across():
    parent = _flat_scan()
    # a depth step: the child's columns 12.. see the parent's columns 17.. (1 mm higher), and
    # never 12..16
    xyz = parent.xyz.copy()
    xyz[:, 17:, 2] += 1.0
    parent = replace(parent, xyz=xyz)
    arrays = {k: getattr(parent, k).copy() for k in ("xyz", "xp", "yp", "mask")}
    for a in arrays.values():
        a[:, 12:19] = a[:, 17:24]
    arrays["mask"][:, 19:] = False
    child = replace(parent, name="stepped", **arrays)
    m = correspond(parent, child)
    assert m.n_pairs > 0
    assert m.distance_mm.max() < 1e-5  # no point invented inside the step
    lenient = correspond(parent, child, max_jump_px=100.0, outlier_mm=None)
    assert lenient.distance_mm.max() > 0.05  # what interpolating across the step would do
    # the outlier test catches those invented points even so
    caught = correspond(parent, child, max_jump_px=100.0)
    assert caught.distance_mm.max() < 1e-5
    assert caught.dropped["outlier"] > 0
    assert caught.rejected.distance_mm.min() > 0.05


def test_residual_above_decoding_noise_is_dropped(clean):
    m = correspond(clean[0], clean[1], refine=False)  # nearest pixel only: residual ~ px size
    assert m.dropped["residual"] > 0.9 * (m.n_sampled - m.dropped["parent_border"]
                                          - m.dropped["child_border"])
    assert np.all(m.residual_px <= 0.5)


def test_refine_false_is_the_appendix_nearest_pixel(clean):
    m = correspond(clean[0], clean[1], refine=False, max_residual_px=50.0)
    np.testing.assert_array_equal(m.child_rc, m.child_nearest.astype(float))
    assert np.median(m.distance_mm) > 0.02  # whole-pixel matching is coarse


def test_stride_subsamples(clean):
    full = correspond(clean[0], clean[1])
    five = correspond(clean[0], clean[1], stride=5)
    assert np.all(five.parent_rc % 5 == 0)
    assert 0.02 * full.n_pairs < five.n_pairs < 0.06 * full.n_pairs
    assert five.stride == 5


# -- fast paths against references ------------------------------------------------------------
def test_kdtree_matches_bruteforce(noisy):
    rows, cols = sample_pixels(valid_mask(noisy[0]), stride=3)
    b = nearest_bruteforce(noisy[0], noisy[1], rows, cols)
    k = nearest_kdtree(noisy[0], noisy[1], rows, cols, workers=1)
    np.testing.assert_array_equal(b[0], k[0])
    np.testing.assert_array_equal(b[1], k[1])
    np.testing.assert_allclose(b[2], k[2], rtol=1e-9, atol=1e-12)


def test_correspond_methods_agree(noisy):
    a = correspond(noisy[0], noisy[1], stride=4)
    b = correspond(noisy[0], noisy[1], stride=4, method="bruteforce")
    np.testing.assert_array_equal(a.parent_rc, b.parent_rc)
    np.testing.assert_allclose(a.xyz_child, b.xyz_child)
    assert a.dropped == b.dropped


def test_compiled_refinement_matches_numpy_reference(noisy):
    m = correspond(noisy[0], noisy[1], stride=2)
    child = noisy[1]
    rows, cols = m.parent_rc.T
    nr, nc = m.child_nearest.T
    tx = noisy[0].xp[rows, cols].astype(float)
    ty = noisy[0].yp[rows, cols].astype(float)
    r, c, res = refine_subpixel(child.xp, child.yp, tx, ty, nr, nc)
    np.testing.assert_allclose(m.child_rc[:, 0], r, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m.child_rc[:, 1], c, rtol=0, atol=1e-9)
    np.testing.assert_allclose(m.residual_px, res, rtol=1e-6, atol=1e-9)
    xyz = bilinear(child.xyz.astype(float), r, c)[0]
    np.testing.assert_allclose(m.xyz_child, xyz, rtol=0, atol=1e-9)


def test_refinement_nan_neighbourhood_is_reported():
    xp = np.tile(np.arange(5.0), (5, 1))
    yp = xp.T.copy()
    xp[2, 3] = np.nan
    r, c, res = refine_subpixel(xp, yp, [2.2], [2.1], [2], [2])
    assert np.isnan(r[0]) and np.isnan(c[0]) and np.isnan(res[0])


@settings(max_examples=40, deadline=None)
@given(
    a=st.floats(0.5, 2.0), b=st.floats(-0.4, 0.4), c=st.floats(-0.4, 0.4), d=st.floats(0.5, 2.0),
    dr=st.floats(-0.5, 0.5), dc=st.floats(-0.5, 0.5),
)
def test_refinement_is_exact_for_affine_maps(a, b, c, d, dr, dc):
    rr, cc = np.mgrid[0:7, 0:7].astype(float)
    xp, yp = a * cc + b * rr + 3.0, c * cc + d * rr - 1.0
    tr, tc = 3 + dr, 3 + dc
    r, cl, res = refine_subpixel(xp, yp, [a * tc + b * tr + 3.0], [c * tc + d * tr - 1.0],
                                 [3], [3])
    assert r[0] == pytest.approx(tr, abs=1e-9)
    assert cl[0] == pytest.approx(tc, abs=1e-9)
    assert res[0] < 1e-9


# -- outputs -------------------------------------------------------------------------------
def test_mapping_matrix_and_distance_image(clean):
    m = correspond(clean[0], clean[1], stride=3)
    mapping = m.mapping
    assert mapping.shape == (*clean[0].shape, 2) and mapping.dtype == np.int32
    paired = (mapping >= 0).all(-1)
    assert paired.sum() == m.n_pairs
    assert np.all(mapping[~paired] == -1)
    np.testing.assert_array_equal(mapping[tuple(m.parent_rc.T)], m.child_nearest)
    img = m.distance_image()
    assert img.dtype == np.float32
    np.testing.assert_array_equal(np.isfinite(img), paired)


def test_merge_statistics_values():
    s = merge_statistics([0.0, 0.01, 0.02, 0.03, 0.2])
    d = s["distance_mm"]
    assert d["median"] == pytest.approx(0.02)
    assert d["mean"] == pytest.approx(0.052)
    assert d["max"] == pytest.approx(0.2)
    assert d["frac_below_0_05"] == pytest.approx(0.8)
    assert d["p95"] == pytest.approx(0.166)  # linear interpolation at rank 3.8
    assert s["squared_mm2"]["max"] == pytest.approx(0.04)
    empty = merge_statistics([])
    assert np.isnan(empty["distance_mm"]["median"]) and empty["distance_mm"]["frac_below_0_05"] == 0


def test_sample_pixels_skips_invalid():
    mask = np.ones((6, 6), bool)
    mask[0, 0] = False
    rows, cols = sample_pixels(mask, stride=3)
    assert list(zip(rows.tolist(), cols.tolist(), strict=True)) == [(0, 3), (3, 0), (3, 3)]


# -- bad input -------------------------------------------------------------------------------
def test_bad_inputs_name_the_argument(clean):
    a, b = clean[0], clean[1]
    with pytest.raises(TypeError, match=r"parent: expected a nail2nail\.scan\.results\.Scan"):
        correspond(np.zeros((3, 3)), b)
    with pytest.raises(ValueError, match="stride: expected an integer ≥ 1"):
        correspond(a, b, stride=0)
    with pytest.raises(TypeError, match="stride: expected an integer"):
        correspond(a, b, stride=2.5)
    with pytest.raises(ValueError, match="border_px"):
        correspond(a, b, border_px=0)
    with pytest.raises(ValueError, match="max_residual_px"):
        correspond(a, b, max_residual_px=-1)
    with pytest.raises(ValueError, match="method"):
        correspond(a, b, method="octree")
    with pytest.raises(ValueError, match=r"child.xp: expected shape"):
        correspond(a, replace(b, xp=b.xp[:-1]))
    with pytest.raises(ValueError, match="no valid pixels"):
        correspond(a, replace(b, mask=np.zeros_like(b.mask)))
    with pytest.raises(ValueError, match="distance_mm"):
        merge_statistics([0.1, np.nan])


# -- command line ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scan_dir(tmp_path_factory):
    from nail2nail.io.scans import save_scans

    out = tmp_path_factory.mktemp("scan")
    save_scans(out, synthetic_scans(size=(64, 80), noise_px=0.05), mat5=False, ply=False)
    return out


def test_cli_merge_json(scan_dir, tmp_path, capsys):
    import json

    from nail2nail.cli._main import main

    out = tmp_path / "merged"
    assert main(["merge", str(scan_dir), "--out", str(out), "--stride", "2", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["merge"]) == {"0-1", "1-2"}
    for key, m in summary["merge"].items():
        assert m["pairs"] > 100 and m["stride"] == 2
        assert {"median", "p95", "max", "frac_below_0_05"} <= set(m["distance_mm"])
        assert m["distance_mm"]["median"] < 0.02
        assert m["sampled"] == m["pairs"] + sum(m["dropped"].values())
        for path in m["files"].values():
            assert Path(path).exists(), key
    mapping = np.load(summary["merge"]["0-1"]["files"]["mapping"])["mapping"]
    assert mapping.shape == (80, 64, 2)
    sup = summary["super_scan"]
    assert sup["vertices"] > 0 and Path(sup["files"]["ply"]).exists()
    assert Path(sup["files"]["mat5"] + "X.by").exists()
    assert all(Path(p).exists() for p in summary["outputs"])
    assert json.loads((out / "merge.json").read_text())["merge"]["0-1"]["pairs"] == \
        summary["merge"]["0-1"]["pairs"]


def test_cli_merge_text_and_pairs(scan_dir, tmp_path, capsys):
    from nail2nail.cli._main import main

    args = ["merge", str(scan_dir), "--out", str(tmp_path / "m"), "--pairs", "2-0",
            "--no-figures", "--no-super"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "2-0" in text and "median" in text
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == [
        "merge.json", "merge_2-0_mapping.npz"]


def test_cli_merge_figures_on_and_off(scan_dir, tmp_path):
    from nail2nail.cli._main import main

    base = ["merge", str(scan_dir), "--pairs", "0-1", "--stride", "2", "--no-super"]
    assert main([*base, "--out", str(tmp_path / "on"), "--figures"]) == 0
    assert sorted(p.name for p in (tmp_path / "on").glob("*.png")) == [
        f"merge_0-1_{k}.png" for k in ("heatmap", "histogram", "marked", "points3d")]
    assert main([*base, "--out", str(tmp_path / "off"), "--no-figures"]) == 0
    assert not list((tmp_path / "off").glob("*.png"))


@pytest.mark.parametrize(("extra", "message"), [
    (["--pairs", "0-7"], "must name two different cameras"),
    (["--pairs", "0:1"], "expected PARENT-CHILD"),
    (["--stride", "0"], "stride: expected an integer ≥ 1"),
])
def test_cli_merge_errors(scan_dir, tmp_path, capsys, extra, message):
    from nail2nail.cli._main import main

    assert main(["merge", str(scan_dir), "--out", str(tmp_path / "x"), *extra]) == 2
    assert message in capsys.readouterr().err


def test_cli_merge_not_a_scan_dir(tmp_path, capsys):
    from nail2nail.cli._main import main

    assert main(["merge", str(tmp_path), "--out", str(tmp_path / "x")]) == 2
    assert "not a scan directory" in capsys.readouterr().err


def test_write_merge_rejects_bad_pairs(tmp_path):
    from _synthetic import synthetic_scans

    from nail2nail.merge.report import write_merge

    scans = synthetic_scans(size=(32, 40))
    for pairs in ([(0, 5)], [(1, 1)]):
        with pytest.raises(ValueError, match="pairs"):
            write_merge(scans, tmp_path / "out", pairs=pairs, figures=False, super_scan=False)
    assert not (tmp_path / "out").exists()


def test_write_merge_without_data_files(noisy, tmp_path):
    """data=False: merge.json (and figures) only, with the same figures as a full merge."""
    from nail2nail.merge.report import write_merge

    full = write_merge(noisy, tmp_path / "full", stride=3, figures=False)
    lean = write_merge(noisy, tmp_path / "lean", stride=3, figures=False, data=False)
    assert sorted(p.name for p in (tmp_path / "lean").iterdir()) == ["merge.json"]
    assert lean["outputs"] == [str(tmp_path / "lean" / "merge.json")]
    for key, stats in full["merge"].items():
        assert lean["merge"][key]["files"] == {}
        assert lean["merge"][key]["distance_mm"] == stats["distance_mm"]
    assert lean["super_scan"]["vertices"] == full["super_scan"]["vertices"]
    assert lean["super_scan"]["files"] == {}


# -- one search, several readers (issue 27) ---------------------------------------------------
def _same_pairs(a, b):
    for key in ("parent_rc", "child_nearest", "child_rc", "xyz_parent", "xyz_child",
                "residual_px"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)


@settings(max_examples=25, deadline=None)
@given(border=st.integers(1, 4), stride=st.integers(1, 4), hole=st.integers(0, 30),
       outlier=st.booleans())
def test_restrict_pairs_is_the_narrower_search(noisy, border, stride, hole, outlier):
    """Narrowing a 1-px-border, stride-1 search gives what the narrower search finds: the same
    pairs, the same drops per reason, the same view-angle and modulation rejections (the local
    outlier test, run on a different set of pairs, is left out of the exact comparison)."""
    parent, child = noisy[0], noisy[1]
    if hole:  # a hole in the child's valid region: pixels lost to the child's border
        mask = child.mask.copy()
        mask[40:40 + hole // 2, 30:30 + hole] = False
        child = replace(child, mask=mask)
    options = {"outlier_mm": 0.025 if outlier else None}
    wide = correspond(parent, child, border_px=1, **options)
    narrow = restrict_pairs(wide, parent, child, border_px=border, stride=stride)
    direct = correspond(parent, child, border_px=border, stride=stride, **options)
    assert narrow.n_sampled == direct.n_sampled and narrow.stride == stride
    if not outlier:
        assert narrow.dropped == direct.dropped
        _same_pairs(narrow, direct)
        _same_pairs(narrow.rejected, direct.rejected)
        np.testing.assert_array_equal(narrow.rejected.reason, direct.rejected.reason)
    else:  # only the outlier verdicts may differ
        for key in ("parent_border", "child_border", "residual", "view_angle", "incidence",
                    "modulation"):
            assert narrow.dropped[key] == direct.dropped[key], key
        a, b = narrow.all_pairs(), direct.all_pairs()
        assert {tuple(x) for x in a.parent_rc} == {tuple(x) for x in b.parent_rc}
    assert sum(narrow.dropped.values()) + narrow.n_pairs == narrow.n_sampled


def test_restrict_pairs_refuses_what_it_cannot_narrow(noisy):
    wide = correspond(noisy[0], noisy[1], border_px=1, stride=2)
    with pytest.raises(ValueError, match="stride 1"):
        restrict_pairs(wide, noisy[0], noisy[1], border_px=2)
    wide = correspond(noisy[0], noisy[1], border_px=1)
    small = replace(noisy[1], **{k: getattr(noisy[1], k)[:-1] for k in (
        "xyz", "xp", "yp", "albedo", "intensity", "modulation", "mask")})
    with pytest.raises(ValueError, match="child: shape"):
        restrict_pairs(wide, noisy[0], small, border_px=2)


def test_write_merge_reads_the_fusions_pairs(noisy, tmp_path):
    """With the super scan, the merge statistics come from the fusion's single search; they
    equal a search of their own up to the outlier test's verdicts on a handful of pairs."""
    from nail2nail.merge.report import write_merge

    one = write_merge(noisy, tmp_path / "one", figures=False, data=False)
    own = write_merge(noisy, tmp_path / "own", figures=False, data=False, super_scan=False)
    for key, stats in own["merge"].items():
        got = one["merge"][key]
        for reason in ("parent_border", "child_border", "residual", "view_angle",
                       "incidence", "modulation"):
            assert got["dropped"][reason] == stats["dropped"][reason], (key, reason)
        assert got["before_rejection"]["pairs"] == stats["before_rejection"]["pairs"]
        assert abs(got["pairs"] - stats["pairs"]) <= 0.002 * stats["pairs"] + 2
        assert got["distance_mm"]["median"] == pytest.approx(stats["distance_mm"]["median"],
                                                             rel=0.01)


# -- issue 9: rejection of unreliable pairs --------------------------------------------------
def _corrupt_edge(scan, *, band_px=3, offset_mm=0.2):
    """`scan` with the points within `band_px` of its mask edge pushed off the surface."""
    import scipy.ndimage

    inner = scipy.ndimage.binary_erosion(scan.mask, iterations=band_px)
    band = scan.mask & ~inner
    xyz = scan.xyz.copy()
    xyz[band, 2] += np.float32(offset_mm)
    return replace(scan, xyz=xyz), band


def test_issue9_corrupted_mask_edge_pairs_are_rejected(noisy):
    child, _ = _corrupt_edge(noisy[1])
    plain = correspond(noisy[0], child, max_view_angle_deg=None, max_incidence_deg=None,
                       min_relative_modulation=None, outlier_mm=None)
    assert plain.rejected is None and plain.dropped["outlier"] == 0
    assert plain.distance_mm.max() > 0.1  # the corrupted points are paired without the tests
    m = correspond(noisy[0], child)
    # every pair more than the outlier floor (25 µm) off its neighbours is rejected
    assert m.distance_mm.max() < 0.035
    assert m.n_pairs > 0.8 * plain.n_pairs
    assert REJECT_REASONS == ("view_angle", "incidence", "modulation", "outlier")
    assert m.rejected.n_pairs == sum(m.dropped[k] for k in REJECT_REASONS)
    assert set(m.rejected.reason) <= set(REJECT_REASONS)
    assert m.dropped["outlier"] > 0
    # nothing is hidden: the statistics before rejection hold every pair found
    stats = m.statistics()
    assert stats["before_rejection"]["pairs"] == plain.n_pairs
    assert stats["before_rejection"]["distance_mm"]["max"] == pytest.approx(
        plain.distance_mm.max())
    assert stats["rejected"] == {k: m.dropped[k] for k in REJECT_REASONS}
    assert m.n_sampled == m.n_pairs + sum(m.dropped.values())


def test_issue9_rejection_tests_by_reason(clean):
    # grazing views: the cylinder's silhouette seen by the side cameras
    off = {"max_view_angle_deg": None, "max_incidence_deg": None,
           "min_relative_modulation": None, "outlier_mm": None}
    wide = correspond(clean[0], clean[1], **off)
    m = correspond(clean[0], clean[1], **{**off, "max_view_angle_deg": 60.0})
    assert m.dropped["view_angle"] > 0 and m.dropped["modulation"] == 0
    assert m.n_pairs + m.dropped["view_angle"] == wide.n_pairs
    # grazing light: the projector lights the cylinder's sides at a glancing angle
    m = correspond(clean[0], clean[1], **{**off, "max_incidence_deg": 50.0})
    assert m.dropped["incidence"] > 0 and m.dropped["view_angle"] == 0
    assert m.n_pairs + m.dropped["incidence"] == wide.n_pairs
    angle = np.degrees(np.arccos(incidence_cosine(clean[0], smooth_px=2.0)))
    r, c = m.parent_rc.T
    assert angle[r, c].max() < 50.0 + 1.0  # bilinear in the child, nearest here
    # a stripe of weak fringes (a tenth of the modulation) in the child
    stripe = (np.arange(SIZE[0]) >= 40) & (np.arange(SIZE[0]) < 50)
    weak = replace(clean[1], modulation=clean[1].modulation * np.where(
        stripe, 0.1, 1.0).astype(np.float32))
    m = correspond(clean[0], weak, max_view_angle_deg=None, max_incidence_deg=None,
                   outlier_mm=None)
    assert m.dropped["modulation"] > 0
    assert m.n_pairs + m.dropped["modulation"] == wide.n_pairs
    col = m.child_rc[:, 1]
    assert not np.any((col >= 40) & (col <= 49))  # none in the stripe (bilinear at its rim)
    with pytest.raises(ValueError, match="max_view_angle_deg"):
        correspond(clean[0], clean[1], max_view_angle_deg=120)
    with pytest.raises(ValueError, match="max_incidence_deg"):
        correspond(clean[0], clean[1], max_incidence_deg=0)
    with pytest.raises(ValueError, match="projector_center"):
        incidence_cosine(replace(clean[0], projector_center=None))
    with pytest.raises(ValueError, match="outlier_mm"):
        correspond(clean[0], clean[1], outlier_mm=-1)


def test_issue9_local_outliers_follow_a_smooth_offset():
    from nail2nail.merge import local_outliers

    rows, cols = np.divmod(np.arange(64 * 64), 64)
    d = 0.005 + 0.05 * cols / 64  # a calibration-like ramp, 5 to 55 µm
    d[[100, 2000, 4000]] += 0.1
    out = local_outliers(rows, cols, d, block_px=16)
    assert np.flatnonzero(out).tolist() == [100, 2000, 4000]


# -- issue 25: scans triangulated from one projector coordinate -------------------------------
def _one_coordinate(scans, used="yp"):
    return [replace(s, triangulated_from=used) for s in scans]


def test_pairing_by_one_coordinate_ignores_the_other_coordinates_error(clean):
    """A child whose xp is off by 0.6 panel px (decoded at another time: a moving finger's
    stabilised scan, triangulated from yp) but whose points are right: the thesis's pairing
    by (xp, yp) reads the xp error as a tangential distance; pairing by yp and the surface
    finds the parent's point on the child's surface."""
    parent, child = _one_coordinate(clean[:2])
    child = replace(child, xp=(child.xp + np.float32(0.6)).astype(np.float32))
    thesis = correspond(parent, child, pair_by="xpyp", outlier_mm=None)
    by_yp = correspond(parent, child, outlier_mm=None)  # auto: both scans say yp
    assert thesis.pair_by == "xpyp" and by_yp.pair_by == "yp"
    assert by_yp.statistics()["pair_by"] == "yp"
    # 0.6 px at ≈ 0.031 mm per panel px at the finger (the fixture's sampling): ≈ 18 µm
    assert np.median(thesis.distance_mm) > 0.015
    # the still pair's own figure (the bilinear interpolation's, about 1 µm here)
    still = np.median(correspond(*clean[:2], outlier_mm=None).distance_mm)
    assert np.median(by_yp.distance_mm) == pytest.approx(still, abs=2e-4)
    assert np.all(by_yp.residual_px < 1e-6)  # the yp residual alone, solved
    assert by_yp.n_pairs >= 0.95 * thesis.n_pairs


def test_pairing_by_one_coordinate_keeps_the_surfaces_distance(clean):
    """Points of the child moved 30 µm along its normal: pairing by yp and the surface still
    measures (nearly) the 30 µm, it only leaves out the distance along the other coordinate."""
    from nail2nail.merge import grid_normals

    parent, child = _one_coordinate(clean[:2])
    normals = grid_normals(child.xyz, camera_center=child.camera_center)
    moved = replace(child, xyz=(child.xyz + np.float32(0.03) * normals).astype(np.float32))
    d = correspond(parent, moved, outlier_mm=None).distance_mm
    assert np.median(d) == pytest.approx(0.03, abs=0.0015)
    # and on the still scans pairing by one coordinate agrees with the thesis's pairing
    both = correspond(*clean[:2], outlier_mm=None).distance_mm
    one = correspond(parent, child, outlier_mm=None).distance_mm
    assert np.median(one) <= np.median(both) + 1e-4


@pytest.mark.parametrize("used, other, pair_by, expected", [
    ("yp", "yp", "auto", "yp"), ("xp", "xp", "auto", "xp"), ("yp", "xp", "auto", "xpyp"),
    ("xpyp", "xpyp", "auto", "xpyp"), (None, "yp", "auto", "xpyp"), (None, None, "auto", "xpyp"),
    ("yp", "yp", "xpyp", "xpyp"), (None, None, "xp", "xp"),
])
def test_pairing_coordinates(clean, used, other, pair_by, expected):
    from nail2nail.merge import pairing_coordinates

    a = replace(clean[0], triangulated_from=used)
    b = replace(clean[1], triangulated_from=other)
    assert pairing_coordinates(a, b, pair_by) == expected


def test_pairing_refuses_an_unknown_coordinate(clean, tmp_path):
    from nail2nail.merge.report import write_merge

    with pytest.raises(ValueError, match="pair_by: expected 'auto', 'xpyp', 'xp' or 'yp'"):
        correspond(clean[0], clean[1], pair_by="zp")
    with pytest.raises(ValueError, match="pair_by"):
        write_merge(clean, tmp_path / "m", pair_by="both")
    assert not (tmp_path / "m").exists()


def test_write_merge_and_cli_name_the_pairing(scan_dir, tmp_path, capsys):
    import json

    from nail2nail.cli._main import main
    from nail2nail.io.scans import load_scans, save_scans

    scans = _one_coordinate(load_scans(scan_dir))
    save_scans(tmp_path / "scan", scans, mat5=False, ply=False)
    assert [s.triangulated_from for s in load_scans(tmp_path / "scan")] == ["yp"] * 3
    assert main(["merge", str(tmp_path / "scan"), "--out", str(tmp_path / "m"), "--json",
                 "--no-figures"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert {m["pair_by"] for m in summary["merge"].values()} == {"yp"}
    assert main(["merge", str(tmp_path / "scan"), "--out", str(tmp_path / "t"), "--json",
                 "--no-figures", "--pair-by", "xpyp"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert {m["pair_by"] for m in summary["merge"].values()} == {"xpyp"}
    with pytest.raises(SystemExit):
        main(["merge", str(tmp_path / "scan"), "--out", str(tmp_path / "u"), "--pair-by", "z"])
    assert "invalid choice: 'z'" in capsys.readouterr().err
    assert not (tmp_path / "u").exists()


def test_scan_json_refuses_a_bad_triangulation_record(scan_dir, tmp_path):
    import json
    import shutil

    from nail2nail.io.scans import load_scans

    bad = tmp_path / "scan"
    shutil.copytree(scan_dir, bad)
    manifest = json.loads((bad / "scan.json").read_text())
    manifest["cameras"][1]["triangulated_from"] = "zp"
    (bad / "scan.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=r"scan\.json: cameras\[1\]\.triangulated_from"):
        load_scans(bad)


@settings(max_examples=15, deadline=None)
@given(offset=st.floats(-1.0, 1.0), tilt=st.floats(-0.01, 0.01),
       used=st.sampled_from(["xp", "yp"]))
def test_pairing_by_one_coordinate_is_blind_to_the_others_error(clean, offset, tilt, used):
    """Any smooth error of the coordinate not triangulated from (an offset and a tilt across
    the image, panel px) leaves the merge error of one-coordinate pairing where the still
    scans have it."""
    other = "xp" if used == "yp" else "yp"
    parent, child = _one_coordinate(clean[:2], used)
    cols = np.arange(child.shape[1], dtype=np.float32)
    wrong = getattr(child, other) + np.float32(offset) + np.float32(tilt) * cols
    child = replace(child, **{other: wrong.astype(np.float32)})
    m = correspond(parent, child, outlier_mm=None)
    still = correspond(*_one_coordinate(clean[:2], used), outlier_mm=None)
    assert m.pair_by == used
    assert m.n_pairs >= 0.95 * still.n_pairs
    assert np.median(m.distance_mm) == pytest.approx(np.median(still.distance_mm), abs=3e-4)
