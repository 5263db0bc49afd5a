"""A decoder's input: frame values as intensities, the stack checked against its pattern set.

Shared by the NumPy decoders (:mod:`~nail2nail.scan.decoding`) and the fused kernel
(:mod:`~nail2nail.scan.kernels`), so that both refuse the same input with the same message.
"""

from __future__ import annotations

import numpy as np

from nail2nail.scan.patterns import PatternSet, frame_labels

__all__ = [
    "CUE_MODULATION",
    "DECODE_DEFAULTS",
    "ERODE",
    "MAX_ERODE",
    "MIN_ALBEDO",
    "MIN_MODULATION",
    "SATURATION",
    "UNWRAP_TOLERANCE",
    "frame_intensities",
    "normalize_frames",
]

# The decoders' default options (decoding.decode, kernels.decode_fast, capture.scan_capture).
MIN_MODULATION = 0.03  #: the finest fringe's amplitude ``B`` below which a pixel is dropped
CUE_MODULATION = None  #: the same for the coarser, unwrap-only fringes (None: MIN_MODULATION)
MIN_ALBEDO = 0.02  #: mean intensity below which a pixel is in shadow
SATURATION = 254.5 / 255.0  #: a frame value at or above this fraction of full scale saturates
UNWRAP_TOLERANCE = float(np.pi / 2)  #: unwrapping residual above which a pixel is dropped, rad
ERODE = 1  #: pixels within this distance of an invalid pixel are dropped (EDGE)
#: The largest ``erode`` accepted, px: the smallest camera accepted is 64 px on a side
#: (simulated cameras; docs/conventions.md), which any larger value empties; the decoder holds
#: ``2 erode + 1`` rows of every map at once, so an unbounded value exhausts memory.
MAX_ERODE = 64

#: The options above by keyword, as ``process.json`` and the report name them.
DECODE_DEFAULTS: dict[str, float | int | None] = {
    "min_modulation": MIN_MODULATION, "cue_modulation": CUE_MODULATION,
    "min_albedo": MIN_ALBEDO, "saturation": SATURATION, "unwrap_tolerance": UNWRAP_TOLERANCE,
    "erode": ERODE,
}


# ------------------------------------------------------------------------------------------------
# Input checks
# ------------------------------------------------------------------------------------------------
def _full_scale(dtype: np.dtype) -> float:
    if dtype == np.uint8:
        return 255.0
    if dtype == np.uint16:
        return 65535.0
    if np.issubdtype(dtype, np.floating):
        return 1.0
    raise TypeError(f"frames: expected uint8, uint16 or float frames, got dtype {dtype}")


def _check_frames(frames, pattern_set: PatternSet) -> np.ndarray:
    if not isinstance(pattern_set, PatternSet):
        raise TypeError(f"pattern_set: expected a PatternSet, got {type(pattern_set).__name__}")
    if isinstance(frames, (list, tuple)):
        frames = np.stack([np.asarray(f) for f in frames])
    frames = np.asarray(frames)
    _full_scale(frames.dtype)
    if frames.ndim != 3:
        raise ValueError(f"frames: expected shape (n_frames, H, W), got {frames.shape}")
    if frames.shape[0] != pattern_set.n_frames:
        expected = "; ".join(f"{i}: {label}" for i, label in enumerate(frame_labels(pattern_set)))
        raise ValueError(
            f"frames: the pattern set has {pattern_set.n_frames} frames, got {frames.shape[0]} "
            f"(the frames it expects, in order: {expected})"
        )
    return frames


def normalize_frames(frames) -> np.ndarray:
    """Frames as ``float32`` in ``[0, 1]`` of full scale.

    ``uint8`` is divided by 255, ``uint16`` (left-aligned 10/12/16-bit) by 65535; float input is
    taken as already normalised.

    Examples
    --------
    >>> normalize_frames(np.array([0, 51, 255], np.uint8)).tolist()
    [0.0, 0.20000000298023224, 1.0]
    """
    frames = np.asarray(frames)
    scale = _full_scale(frames.dtype)
    out = frames.astype(np.float32)
    if scale != 1.0:
        out /= np.float32(scale)
    return out


def _check_erode(erode) -> int:
    if (isinstance(erode, bool) or not isinstance(erode, (int, np.integer))
            or not 0 <= erode <= MAX_ERODE):
        raise ValueError(f"erode: expected an integer in 0..{MAX_ERODE} (pixels), got {erode!r}")
    return int(erode)


def _check_scale(full_scale) -> float | None:
    if full_scale is None:
        return None
    if isinstance(full_scale, bool) or not 0 < float(full_scale) < np.inf:
        raise ValueError(f"full_scale: expected a positive number or None, got {full_scale!r}")
    return float(full_scale)


def _check_modulation(value, name: str) -> float | None:
    """A modulation threshold: a finite number >= 0 (``None`` allowed for `cue_modulation`)."""
    if value is None and name == "cue_modulation":
        return None
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.number))
            or not 0 <= float(value) < np.inf):
        raise ValueError(f"{name}: expected a finite number >= 0"
                         f"{' or None' if name == 'cue_modulation' else ''}, got {value!r}")
    return float(value)


def _check_gradient(max_gradient) -> float | None:
    if max_gradient is None:
        return None
    if not max_gradient > 0:
        raise ValueError(f"max_gradient: expected a positive number or None, got {max_gradient!r}")
    return float(max_gradient)


def frame_intensities(values, bit_depth: int = 8) -> np.ndarray:
    """Frame values of `bit_depth` bits (``raw=True`` of :func:`~nail2nail.io.capture.read_frame`)
    as ``float32``.

    ``values / (2**bit_depth - 1)`` in ``[0, 1]``, exactly what
    :func:`~nail2nail.io.capture.read_frame` returns; any
    shape (a frame, a stack, a band of rows of a stack).

    Examples
    --------
    >>> frame_intensities(np.array([0, 51, 255], np.uint8)).tolist()
    [0.0, 0.20000000298023224, 1.0]
    """
    return np.asarray(values).astype(np.float32) / np.float32(2**bit_depth - 1)
