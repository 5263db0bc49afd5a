"""Gray codes and the panel profiles of code bit planes and shifted lines.

The binary-reflected Gray code of a stripe index and its inverse, the number of bit planes for a
number of stripes, and the 0/1 profile along the panel of one bit plane (:func:`code_profile`)
or one shifted line pattern (:func:`line_profile`), which
:func:`~nail2nail.scan.patterns.make_patterns`
renders and :mod:`~nail2nail.scan.gray` decodes.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "code_profile",
    "gray_from_index",
    "index_from_gray",
    "line_profile",
    "n_code_bits",
]


def gray_from_index(index) -> np.ndarray:
    """Binary-reflected Gray code ``g = i XOR (i >> 1)`` of non-negative integers.

    Examples
    --------
    >>> gray_from_index(np.arange(8)).tolist()
    [0, 1, 3, 2, 6, 7, 5, 4]
    """
    index = np.asarray(index, dtype=np.int64)
    return index ^ (index >> 1)


def index_from_gray(code) -> np.ndarray:
    """Inverse of :func:`gray_from_index` (prefix XOR of the bits), int64.

    Examples
    --------
    >>> index_from_gray([0, 1, 3, 2, 6, 7, 5, 4]).tolist()
    [0, 1, 2, 3, 4, 5, 6, 7]
    """
    value = np.asarray(code, dtype=np.int64).copy()
    shift = 1
    while shift < 63:
        value ^= value >> shift
        shift *= 2
    return value


def n_code_bits(n_stripes: float) -> int:
    """Bits of a Gray code numbering ``ceil(n_stripes)`` stripes (at least 1).

    Examples
    --------
    >>> n_code_bits(64), n_code_bits(65), n_code_bits(16.25), n_code_bits(1)
    (6, 7, 5, 1)
    """
    return max(1, math.ceil(math.log2(max(math.ceil(n_stripes - 1e-9), 1))))


def code_profile(u, origin: float, width: float, n_bits: int, bit: int) -> np.ndarray:
    """Value (0 or 1) of Gray-code bit plane `bit` at panel coordinates `u`.

    Parameters
    ----------
    u : (...) float
        Panel pixel-centre coordinates, px.
    origin : float
        Panel coordinate where stripe 0 starts (``phase_origin``).
    width : float
        Stripe width ``T``, panel px.
    n_bits : int
        Bits of the code.
    bit : int
        ``0 … n_bits - 1``: most significant first; ``n_bits``: the complementary bit (the
        least significant bit of the ``n_bits + 1``-bit code of stripes ``T / 2`` wide).

    Returns
    -------
    (...) uint8

    Examples
    --------
    >>> u = np.arange(8)
    >>> [code_profile(u, -0.5, 2, 2, b).tolist() for b in range(3)]
    [[0, 0, 0, 0, 1, 1, 1, 1], [0, 0, 1, 1, 1, 1, 0, 0], [0, 1, 1, 0, 0, 1, 1, 0]]
    """
    s = np.asarray(u, dtype=np.float64) - origin
    if bit == n_bits:
        half = np.clip(np.floor(2.0 * s / width), 0, 2 ** (n_bits + 1) - 1).astype(np.int64)
        return (gray_from_index(half) & 1).astype(np.uint8)
    if not 0 <= bit < n_bits:
        raise ValueError(f"bit: expected 0 … {n_bits}, got {bit}")
    stripe = np.clip(np.floor(s / width), 0, 2**n_bits - 1).astype(np.int64)
    return ((gray_from_index(stripe) >> (n_bits - 1 - bit)) & 1).astype(np.uint8)


def line_profile(u, origin: float, spacing: int, shift: int) -> np.ndarray:
    """Line frame `shift` of a line-shift sequence: 1 where ``(u - ceil(origin)) mod spacing``
    equals `shift`, else 0 (uint8), at integer panel coordinates `u`.

    Examples
    --------
    >>> line_profile(np.arange(8), -0.5, 4, 1).tolist()
    [0, 1, 0, 0, 0, 1, 0, 0]
    """
    u = np.asarray(u, dtype=np.int64)
    return (np.mod(u - math.ceil(origin), spacing) == shift).astype(np.uint8)

