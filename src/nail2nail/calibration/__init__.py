"""Calibration of the cameras and the projector.

Submodules
----------
:mod:`.dlt`
    Least-squares (DLT) projection matrices per camera and per projector (thesis eq. 3.1–3.11),
    the point-table calibration and the cross-check of two tables.
:mod:`.observe`
    Board views from pose captures: detection, decoding, the projector's board points.
:mod:`.target`
    Joint refinement of pinhole cameras and one shared projector on the thesis's machined
    cylinder target (:mod:`nail2nail.markers`).
:mod:`.board`
    Cameras and projector from a flat board in several poses: Zhang's method per device, the
    projector's board points through local homographies (Moreno & Taubin 2012), a joint bundle
    adjustment.

Every public name is re-exported here (``from nail2nail.calibration import X``); the private
helpers that tests use are reachable as before.
"""

from .board import (
    BoardCalibration,
    BoardView,
    calibrate_board,
    calibrate_device,
)
from .dlt import METHODS as METHODS
from .dlt import MIN_POINTS as MIN_POINTS
from .dlt import (
    CalibrationReport,
    CrossCheck,
    calibrate_points,
    check_calibration_points,
    crosscheck,
    fit_projection_matrix,
    reprojection_errors,
)
from .observe import BoardCaptures, board_views, projector_points
from .target import (
    JointCalibration,
    TargetObservations,
    calibrate_from_observations,
    calibrate_rig_joint,
)
from .target import _mark_centroids as _mark_centroids
from .target import _mark_quadrature as _mark_quadrature
from .target import _ray_cylinder as _ray_cylinder

__all__ = [
    "BoardCalibration",
    "BoardCaptures",
    "BoardView",
    "CalibrationReport",
    "CrossCheck",
    "JointCalibration",
    "TargetObservations",
    "board_views",
    "calibrate_board",
    "calibrate_device",
    "calibrate_from_observations",
    "calibrate_points",
    "calibrate_rig_joint",
    "check_calibration_points",
    "crosscheck",
    "fit_projection_matrix",
    "projector_points",
    "reprojection_errors",
]
