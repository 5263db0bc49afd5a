"""Scan: a capture's frames to one 3D scan per camera (capture → decode → reconstruct).

Modules, in the order the data flows through them:

- :mod:`~nail2nail.scan.codes`: Gray codes and the panel profiles of code bit planes;
- :mod:`~nail2nail.scan.patterns`: what the projector shows (:class:`PatternSet`, the frame
  table, the panel images);
- :mod:`~nail2nail.scan.inputs`: a decoder's input, frame values as intensities, checked
  against the pattern set;
- :mod:`~nail2nail.scan.results`: what decoding hands on: the :class:`Reason` flags,
  :class:`Decoded`, :class:`Scan`, the neighbourhood checks;
- :mod:`~nail2nail.scan.phase_shift`: wrapped phase and temporal unwrapping (multi-frequency
  PMP, thesis chapter two);
- :mod:`~nail2nail.scan.gray`: the Gray-code schemes' decoding;
- :mod:`~nail2nail.scan.decoding`: :func:`decode`, the NumPy reference decoder of any scheme;
- :mod:`~nail2nail.scan.rays`: the compiled per-pixel triangulation on the camera ray;
- :mod:`~nail2nail.scan.triangulation`: world points from camera pixels and projector
  coordinates (thesis eq. 3.12–3.14), the per-calibration tables;
- :mod:`~nail2nail.scan.kernels`: :func:`decode_fast`, decoding, checks and triangulation
  fused in one numba pass;
- :mod:`~nail2nail.scan.motion`: did the finger move while the frames were shown? (the
  frame groups' DC images registered against each other);
- :mod:`~nail2nail.scan.stabilise`: a moving finger's frames resampled so that every pixel
  shows one point of skin (its motion measured from the skin's texture, or from the other
  cameras' through one rigid motion);
- :mod:`~nail2nail.scan.capture`: :func:`scan_capture`, a capture and its calibration to a
  :class:`Scan` per camera.

The cameras' and projector's models that the triangulation reads are in
:mod:`nail2nail.calibration` (:mod:`~nail2nail.calibration.camera_models`,
:mod:`~nail2nail.calibration.distortion`, :mod:`~nail2nail.calibration.files`).
"""

from nail2nail.scan.capture import decode_cameras, scan_capture, scan_frames
from nail2nail.scan.decoding import decode
from nail2nail.scan.kernels import decode_fast
from nail2nail.scan.patterns import PatternSet, default_pattern_set, make_patterns
from nail2nail.scan.results import Decoded, Reason, Scan
from nail2nail.scan.triangulation import (
    RayTable,
    TriangulationTable,
    ray_table,
    reconstruct_image,
    reconstruct_points,
    reconstruct_points_lsq,
    triangulation_table,
)

__all__ = [
    "Decoded",
    "PatternSet",
    "RayTable",
    "Reason",
    "Scan",
    "TriangulationTable",
    "decode",
    "decode_cameras",
    "decode_fast",
    "default_pattern_set",
    "make_patterns",
    "ray_table",
    "reconstruct_image",
    "reconstruct_points",
    "reconstruct_points_lsq",
    "scan_capture",
    "scan_frames",
    "triangulation_table",
]
