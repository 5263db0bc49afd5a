"""Decoder thresholds per frequency (issue 12): ``cue_modulation`` for the coarser, unwrap-only
frequencies, identical in the NumPy reference and the fused kernel."""

from __future__ import annotations

import numpy as np
import pytest

from nail2nail.calibration.files import RigCalibration
from nail2nail.io.capture import read_capture
from nail2nail.scan.capture import scan_capture
from nail2nail.scan.decoding import decode
from nail2nail.scan.kernels import decode_fast
from nail2nail.scan.patterns import PatternSet, frame_table, make_patterns
from nail2nail.scan.results import LOW_MODULATION
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import default_rig, ideal_calibration

PS = PatternSet(x=[(1, 3), (8, 4), (64, 6)], y=[(1, 4), (13, 3)], panel_size=(640, 48))


def _weak_cues(amplitude: float) -> np.ndarray:
    """The panel images as float frames, the coarser frequencies' amplitude scaled to
    `amplitude` (the finest keep 0.5)."""
    frames = make_patterns(PS).astype(np.float32) / 255
    for t in frame_table(PS):
        finest = max(f.periods for f in PS.frequencies(t.direction))
        if t.periods != finest:
            frames[t.index] = 0.5 + (amplitude / 0.5) * (frames[t.index] - 0.5)
    return frames


@pytest.mark.parametrize("method", ["numpy", "numba"])
def test_weak_cues_pass_with_a_lower_cue_threshold(method):
    frames = _weak_cues(0.02)
    options = dict(saturation=1.01, erode=0, method=method)
    default = decode(frames, PS, **options)
    assert (default.reason == LOW_MODULATION).all()  # 0.02 < min_modulation 0.03
    d = decode(frames, PS, cue_modulation=0.01, **options)
    assert d.mask.all()
    assert np.abs(d.xp - np.arange(640)).max() < 0.01
    assert np.abs(d.yp - np.arange(48)[:, None]).max() < 0.01
    # the finest frequency keeps min_modulation
    strict = decode(frames, PS, cue_modulation=0.01, min_modulation=0.6, **options)
    assert (strict.reason == LOW_MODULATION).all()


def test_both_methods_agree_pixel_for_pixel():
    """Amplitudes of the cues on either side of the threshold: the same reasons and
    coordinates in the reference and the kernel."""
    frames = _weak_cues(0.02)
    ramp = np.linspace(0.3, 1.7, 640, dtype=np.float32)  # cue amplitude 0.006 … 0.034
    for t in frame_table(PS):
        if t.periods < max(f.periods for f in PS.frequencies(t.direction)):
            frames[t.index] = 0.5 + ramp * (frames[t.index] - 0.5)
    valid = {}
    for cue in (None, 0.02, 0.015, 0.0):
        ref = decode(frames, PS, cue_modulation=cue, saturation=1.01)
        fast = decode_fast(frames, PS, cue_modulation=cue, saturation=1.01)
        np.testing.assert_array_equal(ref.reason, fast.reason)
        assert np.nanmax(np.abs(ref.xp - fast.xp)) < 1e-4
        valid[cue] = ref.mask.mean()
    assert valid[None] < valid[0.02] < valid[0.015] < valid[0.0] == 1.0


def test_none_is_min_modulation_everywhere():
    frames = _weak_cues(0.04)
    for min_modulation in (0.03, 0.05):
        for method in ("numpy", "numba"):
            a = decode(frames, PS, min_modulation=min_modulation, saturation=1.01, method=method)
            b = decode(frames, PS, min_modulation=min_modulation, cue_modulation=min_modulation,
                       saturation=1.01, method=method)
            np.testing.assert_array_equal(a.reason, b.reason)


@pytest.mark.parametrize("bad", [-0.1, float("nan"), "0.1", True])
def test_bad_cue_modulation(bad):
    frames = _weak_cues(0.2)
    for method in ("numpy", "numba"):
        with pytest.raises(ValueError, match="cue_modulation: expected a finite number >= 0"):
            decode(frames, PS, cue_modulation=bad, method=method)


def test_scan_capture_cue_modulation_both_methods(tmp_path):
    """scan_capture passes cue_modulation to the decoder of either method, with the same
    result; a lower cue threshold keeps at least the pixels of the default."""
    rig = default_rig(0.25, projector_distortion="none")
    simulate_capture(tmp_path / "cap", "finger", rig=rig, seed=2, write_truth=False)
    capture = read_capture(tmp_path / "cap", load=False)
    calib = RigCalibration.from_dict(ideal_calibration(rig))
    kept = {}
    for cue in (None, 0.01, 0.2):
        fast = scan_capture(capture, calib, cue_modulation=cue, min_modulation=0.05)
        ref = scan_capture(capture, calib, cue_modulation=cue, min_modulation=0.05,
                           method="numpy")
        for f, r in zip(fast, ref, strict=True):
            assert np.count_nonzero(f.mask != r.mask) <= 2  # pixels within rounding only
            both = f.mask & r.mask
            assert np.abs(f.xyz - r.xyz)[both].max() <= 1e-4
        kept[cue] = [int(s.mask.sum()) for s in fast]
    assert all(a >= b for a, b in zip(kept[0.01], kept[None], strict=True))
    assert all(a < b for a, b in zip(kept[0.2], kept[None], strict=True))
