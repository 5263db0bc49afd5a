"""Unrolling: the nail-to-nail 3D finger flattened into a rolled-equivalent 2D print.

capture → decode → reconstruct → merge → **unroll** → report. The stage takes every camera's
scan of a finger, measures the ridges as relief (plus albedo) on each camera's grid, flattens
the skin into the print plane (cylinder, fitted sphere, or distance-preserving ARAP on a mesh
of the scan), blends the cameras across their overlaps and renders a 500-ppi print in the legacy
convention (mirror of the pad view, fingertip up, ridges dark), with its binarised version,
mask, quality and distortion figures.

Modules, in data order: :mod:`~nail2nail.unroll.fringes` (the scanner's phase-locked error,
taken out of each camera's signals), :mod:`~nail2nail.unroll.ridges` (ridge signal per camera:
relief and albedo), :mod:`~nail2nail.unroll.flatten` (flattening maps and their distortion),
:mod:`~nail2nail.unroll.render` (print grid, blending, grey and binary prints),
:mod:`~nail2nail.unroll.mixing` (relief and albedo weighed by their clarity, the clarity mask),
:mod:`~nail2nail.unroll.quality` (ridge period and clarity),
:mod:`~nail2nail.unroll.rolled` (:func:`unroll_scans`), :mod:`~nail2nail.unroll.accuracy`
(comparison with the true skin coordinates).
"""

from nail2nail.unroll.flatten import METHODS, fit_flattening, map_distortion
from nail2nail.unroll.mixing import clarity_map, mix_layers
from nail2nail.unroll.rolled import (
    DEFAULT_LENGTH_MM,
    DEFAULT_METHOD,
    FLOOR_FRACTION,
    MAX_LENGTH_MM,
    MAX_PPI,
    MAX_SHARPEN,
    MIN_CLARITY,
    MIN_LENGTH_MM,
    MIN_PPI,
    SHARPEN,
    RolledPrint,
    check_print_size,
    image_up_direction,
    unroll_scans,
)

__all__ = [
    "DEFAULT_LENGTH_MM",
    "DEFAULT_METHOD",
    "FLOOR_FRACTION",
    "MAX_LENGTH_MM",
    "MAX_PPI",
    "MAX_SHARPEN",
    "METHODS",
    "MIN_CLARITY",
    "MIN_LENGTH_MM",
    "MIN_PPI",
    "SHARPEN",
    "RolledPrint",
    "check_print_size",
    "clarity_map",
    "fit_flattening",
    "image_up_direction",
    "map_distortion",
    "mix_layers",
    "unroll_scans",
]
