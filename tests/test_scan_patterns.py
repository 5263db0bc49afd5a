"""Tests for nail2nail.scan.patterns: the pattern spec, the phase rule, rendering, the grid."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nail2nail.scan.patterns import (
    Frequency,
    PatternSet,
    default_pattern_set,
    frame_table,
    grid_pattern,
    make_patterns,
    pattern_phase,
)


def test_default_pattern_set_has_24_frames_in_both_directions():
    ps = default_pattern_set()
    assert ps.n_frames == 24
    assert ps.directions == ("x", "y")
    assert ps.panel_size == (1280, 1040)
    assert min(f.periods for f in ps.x) == 1.0
    assert max(f.periods for f in ps.y) == 64.0


def test_frame_table_order_and_shifts():
    ps = PatternSet(x=[(1, 3), (16, 4)], y=[(1, 3)], shift_sign=-1, phase_offset=0.5)
    table = frame_table(ps)
    assert [t.direction for t in table] == ["x"] * 7 + ["y"] * 3
    assert [t.periods for t in table[:7]] == [1.0] * 3 + [16.0] * 4
    assert [t.step for t in table] == [0, 1, 2, 0, 1, 2, 3, 0, 1, 2]
    assert [t.index for t in table] == list(range(10))
    np.testing.assert_allclose(table[4].shift, -2 * np.pi / 4 + 0.5)


def test_make_patterns_follows_phase_rule():
    # docs/conventions.md: phi = 2 pi n (u + 1/2) / size,
    # frame k shows 1/2 + 1/2 cos(phi - 2 pi k / N)
    ps = PatternSet(x=[(1, 3), (8, 4)], y=[(1, 3)], panel_size=(64, 40))
    frames = make_patterns(ps)
    assert frames.shape == (10, 40, 64) and frames.dtype == np.uint8
    u = np.arange(64)
    expected = 0.5 + 0.5 * np.cos(2 * np.pi * 8 * (u + 0.5) / 64 - 2 * np.pi * 1 / 4)
    np.testing.assert_array_equal(frames[4, 7], np.rint(255 * expected).astype(np.uint8))
    # x patterns are constant down columns, y patterns constant along rows
    assert np.all(frames[:7] == frames[:7, :1, :])
    v = np.arange(40)
    expected_y = 0.5 + 0.5 * np.cos(2 * np.pi * (v + 0.5) / 40 - 2 * np.pi * 2 / 3)
    np.testing.assert_array_equal(frames[9, :, 3], np.rint(255 * expected_y).astype(np.uint8))


def test_pattern_phase_is_pi_at_panel_centre():
    ps = default_pattern_set()
    assert pattern_phase(ps, "y", 1, 519.5) == pytest.approx(np.pi)
    assert pattern_phase(ps, "x", 64, -0.5) == pytest.approx(0.0)


def test_gamma_and_levels():
    linear = PatternSet(x=[(1, 3)], panel_size=(32, 2), levels=(10, 200))
    frames = make_patterns(linear)
    assert frames.min() >= 10 and frames.max() <= 200
    pre = make_patterns(PatternSet(x=[(1, 3)], panel_size=(32, 2), gamma=2.2))
    # the projector applies v ** 2.2 to the sent value: the result is the linear sinusoid
    sent = pre.astype(float) / 255
    ideal = make_patterns(PatternSet(x=[(1, 3)], panel_size=(32, 2))).astype(float) / 255
    np.testing.assert_allclose(sent**2.2, ideal, atol=0.02)


@settings(max_examples=25, deadline=None)
@given(
    x=st.lists(st.tuples(st.sampled_from([0.5, 1, 4, 16, 33.5]), st.integers(3, 9)), max_size=3),
    y=st.lists(st.tuples(st.sampled_from([1, 2, 7]), st.integers(3, 5)), max_size=2),
    sign=st.sampled_from([1, -1]),
    offset=st.floats(-3, 3),
    gamma=st.one_of(st.none(), st.floats(0.5, 3)),
)
def test_json_round_trip(x, y, sign, offset, gamma):
    if not x and not y:
        x = [(1, 3)]
    if x and min(p for p, _ in x) > 1:
        x = [*x, (1, 3)]
    if y and min(p for p, _ in y) > 1:
        y = [*y, (1, 4)]
    ps = PatternSet(x=x, y=y, shift_sign=sign, phase_offset=offset, gamma=gamma)
    again = PatternSet.from_json(json.dumps(ps.to_dict()))
    assert again == ps
    assert again.n_frames == sum(s for _, s in x) + sum(s for _, s in y)


def test_other_system_spec_three_step_with_cue():
    ps = PatternSet.from_dict({"y": [{"periods": 16, "steps": 3}, {"periods": 1, "steps": 3}],
                               "shift_sign": -1, "directions": ["y"]})
    assert ps.n_frames == 6 and ps.x == () and ps.directions == ("y",)
    assert [t.periods for t in frame_table(ps)] == [16.0] * 3 + [1.0] * 3


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({}, ValueError, "at least one of x and y"),
        ({"x": [(8, 3)]}, ValueError, "coarsest frequency must have at most 1 period"),
        ({"x": [(1, 2)]}, ValueError, "at least 3 phase steps"),
        ({"x": [(1, 3.5)]}, TypeError, "steps: expected an integer"),
        ({"x": [(-1, 3)]}, ValueError, "periods: expected > 0"),
        ({"x": [(1, 3)], "shift_sign": 2}, ValueError, "shift_sign"),
        ({"x": [(1, 3)], "levels": (200, 100)}, ValueError, "levels"),
        ({"x": [(1, 3)], "gamma": -1.0}, ValueError, "gamma"),
        ({"x": [(1, 3)], "directions": ("x", "y")}, ValueError, "directions"),
        ({"x": [(1, 3)], "panel_size": (0, 10)}, ValueError, "panel_size"),
        ({"x": "13"}, TypeError, "x: expected a list"),
    ],
)
def test_bad_pattern_sets(kwargs, error, match):
    with pytest.raises(error, match=match):
        PatternSet(**kwargs)


def test_from_dict_rejects_unknown_keys_and_format():
    with pytest.raises(ValueError, match="unknown key"):
        PatternSet.from_dict({"x": [[1, 3]], "colour": "red"})
    with pytest.raises(ValueError, match="format"):
        PatternSet.from_dict({"format": "other", "x": [[1, 3]]})
    with pytest.raises(ValueError, match="invalid JSON"):
        PatternSet.from_json("{")
    with pytest.raises(TypeError, match="PatternSet"):
        make_patterns({"x": [[1, 3]]})


def test_frequency_is_normalised():
    assert Frequency(np.int64(8), np.int64(4)) == Frequency(8.0, 4)


def test_grid_pattern():
    grid = grid_pattern(panel_size=(1280, 1040), spacing=64, width=2)
    assert grid.shape == (1040, 1280) and grid.dtype == np.uint8
    assert grid[520, 641] == 255 and grid[521, 641] == 255 and grid[519, 600] == 0
    cols = np.flatnonzero(grid[10] == 255)
    assert set(np.diff(cols)) <= {1, 63}
    with pytest.raises(ValueError, match="spacing"):
        grid_pattern(spacing=2, width=2)
    with pytest.raises(ValueError, match="foreground"):
        grid_pattern(foreground=300)


def test_cli_patterns(tmp_path, capsys):
    import argparse

    from PIL import Image

    from nail2nail.cli import _patterns

    def main(argv):  # the subcommand alone (other subcommands may be mid-work)
        parser = argparse.ArgumentParser()
        _patterns.add_parser(parser.add_subparsers())
        args = parser.parse_args(argv)
        return args.func(args)

    spec = PatternSet(x=[(1, 3), (4, 4)], panel_size=(32, 8), gamma=2.2)
    (tmp_path / "spec.json").write_text(spec.to_json())
    out = tmp_path / "out"
    assert main(["patterns", "--spec", str(tmp_path / "spec.json"), "--out", str(out),
                 "--grid", "--grid-spacing", "8", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_frames"] == 7 and summary["grid"] == "grid.png"
    manifest = json.loads((out / "patterns.json").read_text())
    assert PatternSet.from_dict(manifest["pattern_set"]) == spec
    assert manifest["frames"][5]["periods"] == 4.0 and manifest["frames"][5]["step"] == 2
    with Image.open(out / "pattern_005.png") as im:
        assert im.mode == "L" and im.size == (32, 8)
        np.testing.assert_array_equal(np.asarray(im), make_patterns(spec)[5])
    (tmp_path / "bad.json").write_text('{"x": [[8, 3]]}')
    with pytest.raises(ValueError, match=r"bad\.json: x: the coarsest frequency"):
        main(["patterns", "--spec", str(tmp_path / "bad.json"), "--out", str(out)])
