"""The ridge signal apart from the scanner: clarity maps, relief and albedo weighed by their
clarity, skin without ridges left out of the print (issue 22)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.unroll.mixing import (
    clarity_map,
    deshade_albedo,
    gate_mask,
    mix_layers,
    riesz_transform,
)
from nail2nail.unroll.render import to_gray
from nail2nail.unroll.ridges import local_normalize

PITCH = 25.4 / 500  # mm per print pixel at 500 ppi


def ridges(shape=(200, 200), period_mm=0.5, angle=0.3, phase=0.0):
    r, c = np.mgrid[: shape[0], : shape[1]] * PITCH
    k = 2 * np.pi / period_mm
    return np.cos(k * (np.cos(angle) * c + np.sin(angle) * r) + phase)


def test_clarity_map_tells_ridges_from_noise_and_shading():
    rng = np.random.default_rng(0)
    mask = np.ones((200, 200), bool)
    clean = clarity_map(ridges(), mask, PITCH)
    noise = clarity_map(rng.standard_normal((200, 200)), mask, PITCH)
    r, c = np.mgrid[:200, :200] * PITCH
    # shading and the bands of a smooth surface's bias: a few mm, not ridges
    shading = clarity_map(0.5 * r + np.cos(2 * np.pi * c / 3.0), mask, PITCH)
    assert np.nanmin(clean) > 0.8
    assert np.nanmedian(noise) < 0.35
    assert np.nanmedian(shading) < 0.35
    # off the mask: NaN; a mask too small for a block: NaN everywhere
    small = np.zeros((200, 200), bool)
    small[:10, :10] = True
    assert np.isnan(clarity_map(ridges(), small, PITCH)).all()


def test_mix_layers_weighs_the_clearer_signal_and_finds_the_albedo_sign():
    """Relief drowned in noise, albedo clean but of opposite sign (furrows brighter): the mix
    follows the ridges better than either weighting alone would."""
    rng = np.random.default_rng(1)
    truth = ridges()
    mask = np.ones(truth.shape, bool)
    relief = truth + 2.0 * rng.standard_normal(truth.shape)
    albedo = -truth + 0.2 * rng.standard_normal(truth.shape)
    mixed, info = mix_layers(relief, albedo, mask, PITCH)
    corr = np.corrcoef(mixed.ravel(), truth.ravel())[0, 1]
    assert corr > 0.95
    assert corr > np.corrcoef(relief.ravel(), truth.ravel())[0, 1] + 0.3
    assert info["albedo_share"] > 0.8
    assert info["albedo_polarity"] == -1
    assert np.median(info["correlation"]) < -0.2
    # deshaded: the same polarity; the correlation is then the deshaded albedo's, which
    # deshading gave the relief's sign
    _, deshaded = mix_layers(relief, albedo, mask, PITCH, deshade=True)
    assert deshaded["albedo_polarity"] == -1
    assert np.median(deshaded["correlation"]) > 0.2
    # relief alone: returned as it is
    alone, info = mix_layers(relief, None, mask, PITCH)
    np.testing.assert_allclose(alone, relief.astype(np.float32))
    assert info["albedo_share"] == 0.0


def test_mix_layers_keeps_one_polarity_where_the_relief_phase_drifts():
    """The relief's ridge phase drifts by 0.75 π across the patch (as light scattered under
    the skin biases it), so its local correlation with the albedo turns negative on the
    right. A sign taken there flips the albedo and prints the ridges inverted (and a seam);
    the print's one polarity keeps them."""
    rng = np.random.default_rng(3)
    shape = (200, 300)
    truth = ridges(shape, angle=0.0)
    _, c = np.mgrid[: shape[0], : shape[1]]
    drift = 0.75 * np.pi * c / shape[1]
    relief = ridges(shape, angle=0.0, phase=drift) + 0.3 * rng.standard_normal(shape)
    albedo = truth + 0.1 * rng.standard_normal(shape)
    mask = np.ones(shape, bool)
    right = np.s_[:, 240:]
    # (deshading would bring the albedo to the relief's drifting phase instead, tested below)
    mixed, info = mix_layers(relief, albedo, mask, PITCH)
    assert info["albedo_polarity"] == 1
    assert np.median(info["correlation"][right]) < -0.2
    assert np.corrcoef(mixed[right].ravel(), truth[right].ravel())[0, 1] > 0.9
    local, _ = mix_layers(relief, albedo, mask, PITCH, polarity="local")
    assert np.corrcoef(local[right].ravel(), truth[right].ravel())[0, 1] < 0
    # a negative polarity (furrows brighter) is found over the whole print as well
    _, info = mix_layers(relief, -albedo, mask, PITCH)
    assert info["albedo_polarity"] == -1
    with pytest.raises(ValueError, match="polarity"):
        mix_layers(relief, albedo, mask, PITCH, polarity="per-pixel")


def _corr(a, b) -> float:
    return float(np.corrcoef(np.ravel(a), np.ravel(b))[0, 1])


@settings(max_examples=20, deadline=None)
@given(angle=st.floats(0, np.pi), period=st.floats(0.4, 0.7), phase=st.floats(0, 2 * np.pi))
def test_riesz_transform_of_ridges_is_their_quadrature(angle, period, phase):
    """``R cos(ω·x + φ) = (ω/|ω|) sin(ω·x + φ)`` for any orientation (away from the grid's
    edges, where the zero padding cuts the pattern)."""
    shape = (160, 160)
    r, c = np.mgrid[: shape[0], : shape[1]] * PITCH
    k = 2 * np.pi / period
    arg = k * (np.sin(angle) * r + np.cos(angle) * c) + phase
    rows, cols = riesz_transform(np.cos(arg), np.ones(shape, bool))
    inner = np.s_[40:-40, 40:-40]
    for comp, direction in ((rows, np.sin(angle)), (cols, np.cos(angle))):
        np.testing.assert_allclose(comp[inner], direction * np.sin(arg)[inner], atol=0.08)


def shaded_albedo(shape=(240, 300), contrast=0.4, slope=1.0, seed=4):
    """Ridges (a whorl-like curved pattern), their relief with noise, and an albedo of
    reflectance contrast `contrast` plus the shading of the ridges' slopes along a light
    direction that turns across the patch (as around a finger), ``slope`` × the shading of
    unit-height sinusoidal ridges."""
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[: shape[0], : shape[1]] * PITCH
    k = 2 * np.pi / 0.5
    arg = k * np.hypot(r - 3.0, c - 4.0)  # rings: every orientation occurs
    truth = np.cos(arg)
    relief = truth + 0.5 * rng.standard_normal(shape)
    # the light's tangential direction turns from −x to +x across the patch
    lx = np.linspace(-1.0, 1.0, shape[1])[None, :] * np.ones(shape)
    ly = 0.3 * np.ones(shape)
    grad_r, grad_c = np.gradient(truth, PITCH)
    shading = -(ly * grad_r + lx * grad_c) / k  # ∂h/∂l of unit ridges, about ±1
    albedo = contrast * truth + slope * shading + 0.05 * rng.standard_normal(shape)
    return truth, relief, albedo


def test_deshade_albedo_brings_a_shaded_albedo_into_the_ridges_phase():
    """Shading as large as 2.5 × the reflectance contrast turns the albedo's ridges by up to
    68° and its sign with the light across the patch; deshaded, it follows the ridges (and
    the mix of relief and albedo with it)."""
    truth, relief, albedo = shaded_albedo()
    mask = np.ones(truth.shape, bool)
    out, info = deshade_albedo(relief, albedo, mask, PITCH)
    inner = np.s_[30:-30, 30:-30]
    assert _corr(albedo[inner], truth[inner]) < 0.7
    assert _corr(out[inner], truth[inner]) > 0.9
    assert info["polarity"] == 1
    assert info["relief_correlation"][1] > info["relief_correlation"][0] + 0.2
    mixed, mixing = mix_layers(relief, albedo, mask, PITCH, deshade=True)
    plain, _ = mix_layers(relief, albedo, mask, PITCH)
    assert mixing["shading"]["correction_rms"] > 0.5
    assert _corr(mixed[inner], truth[inner]) > _corr(plain[inner], truth[inner]) + 0.1
    # furrows brighter: the polarity is found, the deshaded albedo positive on the crests
    out, info = deshade_albedo(relief, -albedo, mask, PITCH)
    assert info["polarity"] == -1
    assert _corr(out[inner], truth[inner]) > 0.9


def test_deshade_albedo_leaves_an_unshaded_albedo_alone():
    """No shading (a diffuse light, or ridges lit along their length): the correction is
    small, the albedo's ridges and local RMS are kept."""
    truth, relief, albedo = shaded_albedo(slope=0.0)
    mask = np.ones(truth.shape, bool)
    out, info = deshade_albedo(relief, albedo, mask, PITCH)
    inner = np.s_[30:-30, 30:-30]
    assert info["correction_rms"] < 0.1
    assert _corr(out[inner], albedo[inner]) > 0.99
    assert np.std(out[inner]) == pytest.approx(np.std(albedo[inner]), rel=0.05)
    # NaN off the mask; a mask of a few pixels: returned as given
    mask[:, :100] = False
    out, _ = deshade_albedo(relief, albedo, mask, PITCH)
    assert np.isnan(out[:, :100]).all() and np.isfinite(out[:, 100:]).all()
    tiny = np.zeros_like(mask)
    tiny[0, :5] = True
    out, info = deshade_albedo(relief, albedo, tiny, PITCH)
    np.testing.assert_allclose(out[tiny], albedo[tiny].astype(np.float32))
    assert info["correction_rms"] == 0.0


def test_gate_mask_keeps_the_ridged_piece():
    clarity = np.full((100, 100), 0.9)
    clarity[:, 60:] = 0.1  # no ridges
    clarity[5:8, 80:83] = 0.9  # a speck that passes: too small, dropped
    mask = np.ones((100, 100), bool)
    kept = gate_mask(clarity, mask, min_clarity=0.3, min_area_px=50)
    assert kept[:, :60].all() and not kept[:, 60:].any()


def test_rms_floor_keeps_a_flat_patch_faint():
    """Ridges on one half, a few µm of noise on the other: normalised without a floor, the
    noise prints at full contrast; with it, faintly."""
    rng = np.random.default_rng(2)
    v = 0.02 * ridges((120, 240))
    v[:, 120:] = 0.001 * rng.standard_normal((120, 120))
    valid = np.ones(v.shape, bool)
    plain = local_normalize(v, valid, 20.0, reduce=2)
    floored = local_normalize(v, valid, 20.0, reduce=2, floor_fraction=0.35)
    assert np.std(plain[:, 150:]) > 0.8
    # the floor: 0.35 × the ridges' RMS, 0.02 / √2; the noise's 0.001 prints at 0.2 of it
    assert np.std(floored[:, 150:]) == pytest.approx(0.001 / (0.35 * 0.02 / np.sqrt(2)),
                                                     rel=0.1)
    assert np.std(floored[:, :90]) == pytest.approx(np.std(plain[:, :90]), rel=0.05)
    gray = to_gray(v, valid, sigma_px=20.0, reduce=2, floor_fraction=0.35)
    assert np.std(gray[:, 150:]) < 0.25 * np.std(gray[:, :90])


# -- end to end: skin without ridges, and a scanner's periodic phase error ------------------
#: the condition of the virtual scanner a patch finger is scanned under: drawn from a seed no
#: tuning used (a sharp pixel grid, specular highlights, subsurface spread, a posed finger,
#: shallow ridges of 33 µm), or None for the default optics
PATCH_CONDITIONS = (None, 1000)


@pytest.fixture(scope="module", params=PATCH_CONDITIONS)
def patch_finger(request):
    """A virtual finger (half resolution) wearing a 9 × 12 mm patch of ridges, flat skin
    around it; its scans, which camera pixels see the patch and which the flat skin, each
    pixel's distance from the patch (mm), and the condition."""
    from nail2nail.calibration.files import RigCalibration
    from nail2nail.io.capture import Capture
    from nail2nail.scan.capture import scan_capture
    from nail2nail.simulation.capture import simulate
    from nail2nail.simulation.conditions import draw_conditions
    from nail2nail.simulation.rig import default_rig, ideal_calibration
    from nail2nail.simulation.scenes import make_scene

    rows, cols = np.mgrid[:236, :177]  # 12 × 9 mm at 500 ppi
    image = np.uint8(127.5 + 127 * np.cos(2 * np.pi * (rows + 0.2 * cols) * PITCH / 0.5))
    if request.param is None:
        rig = default_rig(0.5)
        scene = make_scene("finger", rig=rig, seed=1, print_image=image)
    else:
        condition = draw_conditions(request.param)
        rig = condition.rig(0.5)
        scene = make_scene("finger", rig=rig, seed=1,
                           **condition.finger_options(print_image=image))
    sim = simulate(scene, rig=rig, seed=1)
    names = list(sim.frames)
    capture = Capture(path=None, manifest={"cameras": [{"name": n} for n in names],
                                           "bit_depth": 8},
                      pattern_set=sim.pattern_set,
                      frames={n: sim.frames[n].astype(np.float32) / np.float32(255)
                              for n in names})
    scans = scan_capture(capture, RigCalibration.from_dict(ideal_calibration(rig)))
    uv = [(sim.geometry[s.name].params["u"], sim.geometry[s.name].params["v"]) for s in scans]
    u0, v0 = scene.pad_center
    # distance of each camera pixel's skin from the patch (4.5 × 6 mm half sides), mm
    away = [np.maximum(np.abs(u - u0) - 4.5, np.abs(v - v0) - 6.0) for u, v in uv]
    inside = [a < -0.5 for a in away]
    # 1 mm out: the amplitude's 1 mm window reaches about as far into the flat skin (a rim of
    # faint skin stays around the ridges)
    outside = [a > 1.0 for a in away]
    return scans, inside, outside, away, request.param


@pytest.mark.parametrize("error_um", [0.0, 3.0])
def test_skin_without_ridges_is_left_out_never_striped(patch_finger, error_um):
    """The flat skin around a patch of ridges is left out of the print, the ridges kept; also
    when the scanner adds a periodic error of a few µm along the normal, with the fringes'
    period (20 projector px), which a print normalised without a floor or a clarity mask
    printed as stripes at full contrast."""
    import copy

    from nail2nail.unroll import unroll_scans

    scans, inside, outside, _, _ = patch_finger
    if error_um:
        scans = copy.deepcopy(scans)
        for s in scans:
            toward = np.asarray(s.camera_center, np.float32) - s.xyz
            toward /= np.linalg.norm(toward, axis=-1, keepdims=True)
            wave = np.float32(error_um * 1e-3) * np.sin(2 * np.pi * s.xp / 20.0)
            s.xyz += toward * wave[..., None]
    rolled = unroll_scans(scans, length_mm=None)
    ungated = unroll_scans(scans, length_mm=None, min_clarity=None)  # the same grid
    # the fixed blend of earlier versions, without the phase-locked fit either
    before = unroll_scans(scans, length_mm=None, mix=False, min_clarity=None, sharpen=0.0,
                          ridge_options={"fringe_harmonics": 0})
    # the flat skin away from the print's outer rim (1.5 mm: there the 1 mm windows of the
    # normalisations are cut by the edge, and only grazing views saw the skin; the rim is
    # measured below, not required)
    import scipy.ndimage as ndi

    interior = ndi.distance_transform_edt(ungated.mask) * PITCH > 1.5
    flat = _landing(rolled, scans, outside) & interior
    ridged = _landing(rolled, scans, inside)
    assert flat.sum() > 20000 and ridged.sum() > 20000
    kept_flat = rolled.mask[flat].mean()
    assert kept_flat < 0.01, kept_flat
    assert rolled.mask[ridged].mean() > 0.9
    # the earlier fixed blend printed all the flat skin, and the error as clear stripes
    flat_before = _landing(before, scans, outside) \
        & (ndi.distance_transform_edt(before.mask) * PITCH > 1.5)
    assert before.mask[flat_before].mean() > 0.95
    if error_um:
        qb = clarity_map(before.image, before.mask, PITCH)
        assert np.nanmedian(qb[flat_before]) > 0.5


def _landing(rolled, scans, select):
    """The print pixels that the selected camera pixels land on."""
    hits = np.zeros(rolled.mask.shape, bool)
    for scan, sel in zip(scans, select, strict=True):
        ok = sel & scan.mask
        r, c = rolled.pixel_of(np.asarray(scan.xyz, np.float64)[ok])
        r, c = np.rint(r).astype(int), np.rint(c).astype(int)
        keep = (r >= 0) & (r < hits.shape[0]) & (c >= 0) & (c < hits.shape[1])
        hits[r[keep], c[keep]] = True
    return hits


def test_cli_refuses_a_bad_clarity_before_reading(tmp_path, capsys):
    from nail2nail.cli import main

    for value in ("1.5", "-0.1", "nan"):
        assert main(["unroll", str(tmp_path / "missing"), "--out", str(tmp_path / "o"),
                     "--min-clarity", value]) == 2
        err = capsys.readouterr().err
        assert "--min-clarity" in err and "missing" not in err
    assert not (tmp_path / "o").exists()
    for value in ("-1", "11", "nan", "inf"):
        assert main(["unroll", str(tmp_path / "missing"), "--out", str(tmp_path / "o"),
                     "--sharpen", value]) == 2
        err = capsys.readouterr().err
        assert "--sharpen" in err and "missing" not in err
        assert main(["process", str(tmp_path / "missing"), "--calib", str(tmp_path / "c.json"),
                     "--out", str(tmp_path / "o"), "--sharpen", value]) == 2
        assert "--sharpen" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    # --length and --full-length are one choice
    with pytest.raises(SystemExit):
        main(["unroll", str(tmp_path), "--out", str(tmp_path / "o"), "--length", "20",
              "--full-length"])
