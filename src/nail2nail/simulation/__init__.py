"""The virtual scanner: rig, scenes, rendering and capture writing (``docs/capture-format.md``).

Modules: :mod:`.rig` (cameras, projector, photometry), :mod:`.projectors` (rigs of several
projectors: layouts, and the rolled print's skin they light), :mod:`.scenes` (target, finger, plane,
sphere, coin, calibration board), :mod:`.fingerprint` (synthetic prints), :mod:`.conditions`
(random optics, light, skin and finger per seed: many scanners, not one), :mod:`.render`
(per-camera geometry and frames), :mod:`.capture` (in-memory simulation and capture
directories), :mod:`.board_poses` (board poses in front of a rig, board capture series).
"""

from nail2nail.simulation.board_poses import board_poses, simulate_board_captures
from nail2nail.simulation.capture import (
    SimulatedCapture,
    load_pattern_dir,
    simulate,
    simulate_capture,
    write_capture,
)
from nail2nail.simulation.conditions import RANGES, Conditions, draw_conditions
from nail2nail.simulation.projectors import LAYOUTS, projector_rigs, rolled_coverage
from nail2nail.simulation.render import (
    CameraGeometry,
    camera_geometry,
    projector_radiance,
    render_frames,
)
from nail2nail.simulation.rig import (
    Photometry,
    Rig,
    default_rig,
    ideal_calibration,
    load_rig,
    save_rig,
)
from nail2nail.simulation.scenes import SCENES, BoardScene, Scene, make_scene

__all__ = [
    "LAYOUTS",
    "RANGES",
    "SCENES",
    "BoardScene",
    "CameraGeometry",
    "Conditions",
    "Photometry",
    "Rig",
    "Scene",
    "SimulatedCapture",
    "board_poses",
    "camera_geometry",
    "default_rig",
    "draw_conditions",
    "ideal_calibration",
    "load_pattern_dir",
    "load_rig",
    "make_scene",
    "projector_radiance",
    "projector_rigs",
    "render_frames",
    "rolled_coverage",
    "save_rig",
    "simulate",
    "simulate_board_captures",
    "simulate_capture",
    "write_capture",
]
