"""Shared by the benches: render the virtual scenes a calibration bench needs, once."""

from __future__ import annotations

from pathlib import Path

from nail2nail.scan.patterns import default_pattern_set, make_patterns
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import default_rig


def render_scenes(work: Path, scale: float, scenes=("plane", "target", "finger")) -> None:
    """Render each scene into ``work/SCENE`` (thesis projector distortion, default patterns,
    seed 0; truth for the finger) unless a capture is already there."""
    rig = default_rig(scale, projector_distortion="thesis")
    pattern_set = default_pattern_set()
    patterns = make_patterns(pattern_set)
    for scene in scenes:
        if not (Path(work) / scene / "capture.json").exists():
            simulate_capture(Path(work) / scene, scene, rig=rig, patterns=patterns,
                             pattern_set=pattern_set, seed=0, write_truth=scene == "finger")
