"""The whole pipeline (``nail2nail demo``) at reduced scale: issues 5 and 6 end to end.

Thesis projector distortion in the virtual scanner; the demo estimates and corrects it, and
the merge error of the finger must reach the targets of issue 6.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nail2nail.calibration.distortion import THESIS_CENTER, THESIS_RHO
from nail2nail.cli import main


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    import contextlib
    import io

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert main(["demo", "--out", str(out), "--scale", "0.5", "--json"]) == 0
    return json.loads(buffer.getvalue()), out


def test_distortion_estimate(demo):
    """Issue 5: centre within 5 px and ρ within 2 % of the truth."""
    result, _ = demo
    d = result["distortion"]
    assert np.hypot(*(np.array(d["center_px"]) - THESIS_CENTER)) < 5
    assert abs(d["rho"] - THESIS_RHO) < 0.02 * abs(THESIS_RHO)


def test_merge_error_targets(demo):
    """Issue 6: finger, cameras 0↔1 and 1↔2, median ≤ 10 µm and p95 ≤ 25 µm."""
    result, _ = demo
    for pair in ("0-1", "1-2"):
        d = result["merge"][pair]["distance_mm"]
        assert result["merge"][pair]["pairs"] > 10_000
        assert d["median"] <= 0.010, (pair, d)
        assert d["p95"] <= 0.025, (pair, d)


@pytest.mark.parametrize("obj", ["target", "finger"])
def test_correction_improves_merge_five_fold(demo, obj):
    """Issue 5: the merge median drops at least 5× from before correction to the best."""
    result, _ = demo
    comparison = result["comparison"]
    for pair in ("0-1", "1-2"):
        before = comparison["before"][obj][pair]["distance_mm"]["median"]
        lut = comparison["thesis_lut"][obj][pair]["distance_mm"]["median"]
        model = comparison["model_dlt"][obj][pair]["distance_mm"]["median"]
        best = comparison["best"][obj][pair]["distance_mm"]["median"]
        assert best * 5 <= before, (obj, pair, before, best)
        assert lut < before and model < before  # both corrections help with the thesis's DLT


def test_outputs_exist(demo):
    result, out = demo
    assert result["thesis"]["yp"]["pairs"] == 24
    assert result["outputs"]
    for path in result["outputs"]:
        assert Path(path).exists(), path
    assert (out / "summary.json").exists()
    assert result["super_scan"]["vertices"] > 100_000
