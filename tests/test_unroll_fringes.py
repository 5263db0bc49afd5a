"""The scanner's phase-locked error taken out of a camera's signals (issue 22)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from nail2nail.scan.patterns import (
    default_pattern_set,
    fringe_periods,
    gray_code_pattern_set,
    gray_line_pattern_set,
    gray_phase_pattern_set,
)
from nail2nail.unroll.fringes import fringe_basis, remove_phase_locked

H, W = 240, 320


def _coords(rng, tilt: float):
    """Projector coordinates of a camera looking at a curved surface: a smooth, slightly
    non-linear map of the pixel grid (about 1.3 panel px per camera px)."""
    r, c = np.mgrid[:H, :W].astype(np.float64)
    xp = 300 + 1.3 * c + tilt * r + 2e-4 * (c - W / 2) ** 2
    yp = 200 + 1.2 * r - tilt * c + 1e-4 * (r - H / 2) ** 2
    return {"x": xp.astype(np.float32), "y": yp.astype(np.float32)}, r, c


def _ridges(r, c, rng):
    """Ridge-like relief, µm: sinusoids of 7–10 px period (half the fringes', as on skin)
    whose orientation turns over the
    image (ridges are not locked to the projector's phase)."""
    theta = 0.8 * np.sin(r / 90) + 0.6 * np.cos(c / 70) + rng.uniform(0, np.pi)
    period = 8.5 + 1.5 * np.sin((r + c) / 150)
    phase = 2 * np.pi * (c * np.cos(theta) + r * np.sin(theta)) / period
    return 10.0 * np.cos(phase)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), tilt=st.floats(-0.2, 0.2),
       amplitude=st.floats(2.0, 5.0))
def test_a_known_phase_locked_error_is_taken_out(seed, tilt, amplitude):
    """A fringe-locked error of known harmonics, its amplitude varying linearly over the image,
    2.4–6 µm RMS under ridges of 7 µm RMS: most of it is taken out (40 seeds measured 6–30 %
    of it left, median 11 %: the halves' agreement weighs each harmonic down by what the ridges
    lend it by chance)."""
    rng = np.random.default_rng(seed)
    coords, r, c = _coords(rng, tilt)
    periods = {"x": 20.0, "y": 16.25}
    phase = 2 * np.pi * coords["x"] / periods["x"]
    scale = 1 + 0.3 * (c / W - 0.5)  # the sensitivity changes across the image
    error = amplitude * scale * (np.cos(phase + rng.uniform(0, 6.3))
                                 + 0.5 * np.sin(2 * phase + rng.uniform(0, 6.3))
                                 + 0.3 * np.cos(2 * np.pi * coords["y"] / periods["y"])
                                 + 0.2 * np.sin(2 * np.pi * coords["x"]))  # the pixel grid
    skin = _ridges(r, c, rng) + rng.normal(0, 2.0, (H, W))
    valid = np.ones((H, W), bool)
    valid[:30, :50] = False
    out, info = remove_phase_locked((skin + error)[..., None], valid, coords, periods)
    assert info["terms"] == 20 and info["gains"]["x/1"][0] > 0.8
    left = out[valid, 0] - skin[valid]
    assert np.sqrt(np.mean(left**2)) < 0.4 * np.sqrt(np.mean(error[valid] ** 2))
    # off the valid pixels nothing changes
    np.testing.assert_array_equal(out[~valid, 0], (skin + error)[~valid].astype(np.float32))


def test_an_error_alone_is_taken_out_whole():
    rng = np.random.default_rng(1)
    coords, _, c = _coords(rng, 0.1)
    periods = {"x": 20.0, "y": 16.25}
    error = (1 + 0.3 * (c / W - 0.5)) * np.cos(2 * np.pi * coords["x"] / periods["x"] + 1)
    out, info = remove_phase_locked(error[..., None], np.ones((H, W), bool), coords, periods)
    assert np.sqrt(np.mean(out**2)) < 1e-4
    assert info["gains"]["x/1"] == [1.0]


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), tilt=st.floats(-0.2, 0.2))
def test_ridges_without_a_phase_locked_error_are_hardly_changed(seed, tilt):
    """Without a phase-locked error the fit takes little of the ridges: these synthetic ridges
    run at the fringes' second harmonic, coherent over the whole image, the worst case for a
    fit of 60 terms, which took 3–8 % of their RMS; weighed by the halves' agreement, 30 seeds
    measured 0.1–5.4 % (median 0.9 %) on 76,800 pixels (a camera's scan has 5–15 times as many,
    and ridges that turn)."""
    rng = np.random.default_rng(seed)
    coords, r, c = _coords(rng, tilt)
    skin = _ridges(r, c, rng) + rng.normal(0, 2.0, (H, W))
    valid = np.ones((H, W), bool)
    out, info = remove_phase_locked(skin[..., None], valid, coords, {"x": 20.0, "y": 16.25})
    change = out[..., 0] - skin
    assert np.sqrt(np.mean(change**2)) < 0.08 * np.sqrt(np.mean(skin**2))
    assert info["removed_rms"][0] == pytest.approx(np.sqrt(np.mean(change**2)), rel=0.05,
                                                   abs=1e-4)


def test_nothing_to_fit_leaves_the_signals():
    coords = {"x": np.full((8, 8), np.nan, np.float32), "y": np.full((8, 8), np.nan, np.float32)}
    values = np.arange(64, dtype=np.float32).reshape(8, 8, 1)
    for periods, harmonics in (({"x": 20.0}, 4), ({}, 4), ({"x": 20.0}, 0)):
        out, info = remove_phase_locked(values, np.ones((8, 8), bool), coords, periods,
                                        harmonics=harmonics)
        np.testing.assert_array_equal(out, values)
        assert info["terms"] == 0
    with pytest.raises(ValueError, match="harmonics"):
        remove_phase_locked(values, np.ones((8, 8), bool), coords, {"x": 20.0}, harmonics=-1)


def test_basis_is_periodic_in_the_fringe_and_the_pixel():
    u = np.array([3.25, 23.25, 3.25 + 20 * 1000], np.float32)
    basis = dict(fringe_basis({"x": u}, {"x": 20.0}, harmonics=2))
    assert list(basis) == ["cos x/1", "sin x/1", "cos x/2", "sin x/2", "cos x/pixel",
                           "sin x/pixel"]
    for b in basis.values():
        np.testing.assert_allclose(b, b[0], atol=2e-3)  # float32 coordinates of 20,003 px


def test_fringe_periods_of_each_scheme():
    assert fringe_periods(default_pattern_set()) == {"x": 20.0, "y": 16.25}
    assert fringe_periods(gray_phase_pattern_set(periods=32)) == {"x": 40.0, "y": 32.5}
    assert fringe_periods(gray_line_pattern_set(spacing=8)) == {"x": 8.0, "y": 8.0}
    assert fringe_periods(gray_code_pattern_set()) == {}


def test_scan_files_carry_the_fringe_periods(tmp_path):
    from nail2nail.io.scans import load_scans, save_scans
    from nail2nail.scan.results import Scan

    nan = np.full((4, 5), np.nan, np.float32)
    xyz = np.zeros((4, 5, 3), np.float32)
    mask = np.ones((4, 5), bool)
    scan = Scan(name="cam0", xyz=xyz, xp=nan, yp=nan, albedo=nan, intensity=nan,
                modulation=nan, mask=mask, fringe_periods={"x": 20.0, "y": 16.25})
    save_scans(tmp_path / "s", [scan])
    assert load_scans(tmp_path / "s")[0].fringe_periods == {"x": 20.0, "y": 16.25}
    manifest = json.loads((tmp_path / "s" / "scan.json").read_text())
    for bad in ({"x": -1}, {"z": 20.0}, [20.0], {"x": "20"}, {"x": float("inf")}):
        manifest["cameras"][0]["fringe_periods_px"] = bad
        (tmp_path / "s" / "scan.json").write_text(json.dumps(manifest))
        with pytest.raises(ValueError, match=r"scan.json: cameras\[0\].fringe_periods_px"):
            load_scans(tmp_path / "s")
    del manifest["cameras"][0]["fringe_periods_px"]  # a scan written before: None
    (tmp_path / "s" / "scan.json").write_text(json.dumps(manifest))
    assert load_scans(tmp_path / "s")[0].fringe_periods is None


def test_cli_unroll_records_the_fit_and_turns_it_off(tmp_path, capsys):
    """``unroll`` records what the fit took out per camera (``print.json`` →
    ``quality.fringes``); ``--no-fringe-fit`` leaves it out."""
    from nail2nail.calibration.files import RigCalibration, save_calibration
    from nail2nail.cli import main
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.simulation.rig import default_rig, ideal_calibration

    rig = default_rig(0.25, projector_distortion="none")
    simulate_capture(tmp_path / "finger", "finger", rig=rig, seed=4, write_truth=False)
    save_calibration(tmp_path / "rig.json", RigCalibration.from_dict(ideal_calibration(rig)))
    assert main(["-q", "scan", str(tmp_path / "finger"), "--calib", str(tmp_path / "rig.json"),
                 "--out", str(tmp_path / "scan"), "--no-mat5", "--no-ply"]) == 0
    manifest = json.loads((tmp_path / "scan" / "scan.json").read_text())
    assert all(c["fringe_periods_px"] == {"x": 20.0, "y": 16.25} for c in manifest["cameras"])
    for name, extra in (("fit", []), ("off", ["--no-fringe-fit"]), ("plain", ["--sharpen", "0"]),
                        ("deshaded", ["--deshade"])):
        assert main(["-q", "unroll", str(tmp_path / "scan"), "--out", str(tmp_path / name),
                     *extra]) == 0
    capsys.readouterr()
    fit = json.loads((tmp_path / "fit" / "print.json").read_text())["quality"]["fringes"]
    off = json.loads((tmp_path / "off" / "print.json").read_text())["quality"]["fringes"]
    assert sorted(fit) == ["cam0", "cam1", "cam2"] and off is None
    assert all(v["terms"] == 20 and v["relief_um"] >= 0 for v in fit.values())
    # the grey print's unsharp mask is recorded; the clarity mask is measured before it, so
    # the print without it has the same mask
    sharp = json.loads((tmp_path / "fit" / "print.json").read_text())["quality"]["sharpening"]
    plain = json.loads((tmp_path / "plain" / "print.json").read_text())["quality"]["sharpening"]
    assert sharp == {"amount": 2.0, "sigma_mm": 0.075} and plain is None
    masks = [np.asarray(Image.open(tmp_path / n / "print_mask.png")) for n in ("fit", "plain")]
    np.testing.assert_array_equal(masks[0], masks[1])
    # --deshade records its shading fit (quality.mixing.shading); off by default
    mixing = json.loads((tmp_path / "deshaded" / "print.json").read_text())["quality"]["mixing"]
    plain = json.loads((tmp_path / "fit" / "print.json").read_text())["quality"]["mixing"]
    assert mixing["shading"]["degree"] == 1 and mixing["shading"]["polarity"] in (1, -1)
    assert 0 <= mixing["shading"]["correction_rms"] <= 3.0
    assert plain["shading"] is None
