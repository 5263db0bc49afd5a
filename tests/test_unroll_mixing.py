"""The ridge signal apart from the scanner: clarity maps, relief and albedo weighed by their
clarity, skin without ridges left out of the print (issue 22)."""

from __future__ import annotations

import numpy as np
import pytest

from nail2nail.unroll.mixing import clarity_map, gate_mask, mix_layers
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
    assert np.median(info["correlation"]) < -0.2
    # relief alone: returned as it is
    alone, info = mix_layers(relief, None, mask, PITCH)
    np.testing.assert_allclose(alone, relief.astype(np.float32))
    assert info["albedo_share"] == 0.0


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
