"""The fused decoding kernel: decode, unwrap, check and triangulate in one numba pass.

:func:`decode_fast` (``method="numba"``) is the fast path, the one ``nail2nail scan`` runs:
one numba kernel, parallel over chunks of rows, reads the frames as stored (uint8, uint16,
float32), decodes, unwraps, runs the neighbourhood checks and triangulates in one pass, holding
only per-row temporaries besides the frames and the outputs; given a
:class:`~nail2nail.scan.triangulation.RayTable` it triangulates on the camera rays in float64
(:mod:`~nail2nail.scan.rays`), compensating the projector's distortion model and lens as
:func:`~nail2nail.scan.triangulation.reconstruct_image` does; given a
:class:`~nail2nail.scan.triangulation.TriangulationTable` it uses the rational form of thesis
eq. 3.12–3.14. Precision against the NumPy reference (:func:`~nail2nail.scan.decoding.decode`;
``tests/test_scan_kernels.py``, virtual finger, every option): the same mask (no pixel differs; at
most a pixel within rounding of a threshold could), ``xp``, ``yp`` within one float32 step
(6.1e-5 px below 1024 px, 1.2e-4 px above; the kernel's arctangent is exact to 1.5e-7 rad),
points within 1e-6 mm of the float64 reference triangulation of the same coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numba
import numpy as np

from nail2nail.scan.inputs import (
    CUE_MODULATION,
    ERODE,
    MIN_ALBEDO,
    MIN_MODULATION,
    SATURATION,
    UNWRAP_TOLERANCE,
    _check_erode,
    _check_frames,
    _check_gradient,
    _check_modulation,
    _check_scale,
    _full_scale,
)
from nail2nail.scan.patterns import PatternSet
from nail2nail.scan.phase_shift import TWO_PI
from nail2nail.scan.rays import _CACHE, _FAST, _RAY_SIZE, _ideal_panel, _pack_ray, _ray_points
from nail2nail.scan.results import Decoded, Reason
from nail2nail.scan.triangulation import RayTable

__all__ = [
    "decode_fast",
    "planar_table",
]

# The Reason bits as the kernels' uint8 constants (numba reads module globals as constants).
_LOW_MODULATION = np.uint8(Reason.LOW_MODULATION)
_SATURATED = np.uint8(Reason.SATURATED)
_SHADOW = np.uint8(Reason.SHADOW)
_UNWRAP_ERROR = np.uint8(Reason.UNWRAP_ERROR)
_OUT_OF_PANEL = np.uint8(Reason.OUT_OF_PANEL)
_EDGE = np.uint8(Reason.EDGE)
_STEEP = np.uint8(Reason.STEEP)
_NO_POINT = np.uint8(Reason.NO_POINT)


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _atan2_0_2pi(y, x):  # pragma: no cover - compiled
    """``atan2(y, x)`` in float32 mapped to ``[0, 2 pi)``, branch-free, |error| < 1.5e-7 rad.

    ``atan(a) = a P(a^2)`` on ``[0, 1]`` with ``P`` of degree 7 (minimax, 3.7e-8 rad in exact
    arithmetic), then the octant. The error is 5e-7 px of the finest 20 px period: float32
    rounding of ``u`` dominates.
    """
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    mn = min(ax, ay)
    a = mn / mx  # 0 / 0 (no signal): NaN, which the last line maps to 0 as atan2 does
    s = a * a
    p = np.float32(-0.004054565772773874)
    p = p * s + np.float32(0.021862953069985366)
    p = p * s + np.float32(-0.05591232053743348)
    p = p * s + np.float32(0.09642196935403262)
    p = p * s + np.float32(-0.13908629429165978)
    p = p * s + np.float32(0.19946565636345642)
    p = p * s + np.float32(-0.3332986078429215)
    p = p * s + np.float32(0.9999993355789593)
    r = a * p
    r = np.float32(1.5707964) - r if ay > ax else r
    r = np.float32(3.1415927) - r if x < 0 else r
    r = np.float32(6.2831855) - r if y < 0 else r
    return r if r < np.float32(6.2831855) else np.float32(0.0)


@numba.njit(fastmath=_FAST, error_model="numpy")
def _decode_row(frames, r, block_frame, block_cos, block_sin, block_size, group_block,
                group_bscale, group_ratio, dir_groups, dir_levels, dir_coef, dir_period,
                dir_origin, dir_size, inv_scale, sat_native, min_mod2, cue_mod2, min_alb, tol,
                acc_s, acc_c, b2, total, peak, flags, min_b, fine_b, big_phi,
                u_row, reason_row, mod_row, alb_row):  # pragma: no cover - compiled
    """Decode camera row `r`: ``u_row (n_dirs, W)``, per-pixel reasons, modulation, albedo.

    Every loop runs over the columns without branches (conditional expressions become
    selects), for LLVM's vectoriser; the frames are read as stored (uint8, uint16, float32),
    three at a time, and the amplitudes are kept squared until the output: `min_b` the
    smallest of the coarser (unwrap-only) levels', checked against `cue_mod2`, `fine_b` the
    finest levels', against `min_mod2`.
    """
    width = frames.shape[2]
    zero = np.float32(0.0)
    half = np.float32(0.5)
    two_pi = np.float32(TWO_PI)
    inv_two_pi = np.float32(1.0 / TWO_PI)
    inf = np.float32(np.inf)
    for d in range(dir_groups.shape[0]):
        for j in range(dir_levels[d]):  # coarse to fine
            g = dir_groups[d, j]
            coarse = j < dir_levels[d] - 1
            first = group_block[g, 0]
            for bi in range(first, first + group_block[g, 1]):
                k0, k1, k2 = block_frame[bi, 0], block_frame[bi, 1], block_frame[bi, 2]
                c0, c1, c2 = block_cos[bi, 0], block_cos[bi, 1], block_cos[bi, 2]
                s0, s1, s2 = block_sin[bi, 0], block_sin[bi, 1], block_sin[bi, 2]
                start = (d == 0) & (j == 0) & (bi == first)  # the row's first frames
                if block_size[bi] == 1:  # a frequency's last frame or two, one at a time
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        acc_s[c] += f0 * s0
                        acc_c[c] += f0 * c0
                        total[c] += f0
                        peak[c] = max(peak[c], f0)
                elif start:
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        f1 = np.float32(frames[k1, r, c])
                        f2 = np.float32(frames[k2, r, c])
                        acc_s[c] = f0 * s0 + f1 * s1 + f2 * s2
                        acc_c[c] = f0 * c0 + f1 * c1 + f2 * c2
                        total[c] = f0 + f1 + f2
                        peak[c] = max(f0, max(f1, f2))
                elif bi == first:
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        f1 = np.float32(frames[k1, r, c])
                        f2 = np.float32(frames[k2, r, c])
                        acc_s[c] = f0 * s0 + f1 * s1 + f2 * s2
                        acc_c[c] = f0 * c0 + f1 * c1 + f2 * c2
                        total[c] += f0 + f1 + f2
                        peak[c] = max(peak[c], max(f0, max(f1, f2)))
                else:
                    for c in range(width):
                        f0 = np.float32(frames[k0, r, c])
                        f1 = np.float32(frames[k1, r, c])
                        f2 = np.float32(frames[k2, r, c])
                        acc_s[c] += f0 * s0 + f1 * s1 + f2 * s2
                        acc_c[c] += f0 * c0 + f1 * c1 + f2 * c2
                        total[c] += f0 + f1 + f2
                        peak[c] = max(peak[c], max(f0, max(f1, f2)))
            bscale = group_bscale[g]
            ratio = group_ratio[g]
            # acc_s, acc_c become this level's wrapped phase and period count
            if j == 0:
                for c in range(width):
                    sv = acc_s[c]
                    cv = acc_c[c]
                    q = (sv * sv + cv * cv) * bscale
                    qc = q if coarse else inf
                    min_b[c] = qc if d == 0 else min(min_b[c], qc)
                    phi = _atan2_0_2pi(sv, cv)
                    big_phi[c] = phi
                    acc_s[c] = phi
                    acc_c[c] = zero
                    b2[c] = q
                    flags[c] = np.uint8(0) if d == 0 else flags[c]
            else:
                for c in range(width):
                    sv = acc_s[c]
                    cv = acc_c[c]
                    q = (sv * sv + cv * cv) * bscale
                    min_b[c] = min(min_b[c], q if coarse else inf)
                    phi = _atan2_0_2pi(sv, cv)
                    target = big_phi[c] * ratio
                    k = np.rint((target - phi) * inv_two_pi)
                    unwrapped = phi + two_pi * k
                    flags[c] |= _UNWRAP_ERROR if abs(target - unwrapped) > tol else np.uint8(0)
                    big_phi[c] = unwrapped
                    acc_s[c] = phi
                    acc_c[c] = k
                    b2[c] = q
        # u = phi size / (2 pi n) + k size / n + origin in float64 from the finest level's phase
        # and its exact period count: rounded once, where the float32 unwrapped phase (up to
        # 2 pi n = 402 rad) would carry errors of 1e-4 px
        coef = dir_coef[d]
        period = dir_period[d]
        origin = dir_origin[d]
        upper = dir_size[d] - half
        u_out = u_row[d]
        for c in range(width):
            fine_b[c] = b2[c] if d == 0 else min(fine_b[c], b2[c])
            u = np.float32(np.float64(acc_s[c]) * coef + (np.float64(acc_c[c]) * period + origin))
            u_out[c] = u
            flags[c] |= _OUT_OF_PANEL if (u < -half) | (u > upper) else np.uint8(0)
    for c in range(width):
        alb = total[c] * inv_scale
        f = flags[c]
        f |= _SATURATED if peak[c] >= sat_native else np.uint8(0)
        f |= _SHADOW if alb < min_alb else np.uint8(0)
        f |= _LOW_MODULATION if (min_b[c] < cue_mod2) | (fine_b[c] < min_mod2) else np.uint8(0)
        reason_row[c] = f
        alb_row[c] = alb
        mod_row[c] = np.sqrt(fine_b[c])


@numba.njit(error_model="numpy")
def _check_row(e, height, ring, reason_ring, u_ring, erode, max_gradient, check_gradient,
               flags, near, column):  # pragma: no cover - compiled
    """Per-pixel reasons of row `e` plus :data:`EDGE` and :data:`STEEP` into `flags`, as
    :func:`neighbourhood_reasons` (rows ``e - halo … e + halo`` in the ring buffers).

    EDGE: a pixel within Chebyshev distance `erode` (inside the image) is invalid; STEEP: a
    central-difference gradient of a decoded coordinate exceeds `max_gradient` (all four
    neighbours valid). Compiled without fast-math: the gradients round as the reference's.
    """
    n_dirs = u_ring.shape[1]
    width = u_ring.shape[2]
    slot = e % ring
    here = reason_ring[slot]
    half = np.float32(0.5)
    for c in range(width):
        flags[c] = here[c]
    if erode > 0:
        for c in range(width):
            column[c] = 0
        for rr in range(max(e - erode, 0), min(e + erode + 1, height)):
            row = reason_ring[rr % ring]
            for c in range(width):
                column[c] |= row[c]
        for c in range(width):
            near[c] = column[c]
        for s in range(1, min(erode, width - 1) + 1):  # Chebyshev: the columns s to each side
            for c in range(width - s):
                near[c] |= column[c + s]
            for c in range(width - s):
                near[c + s] |= column[c]
        for c in range(width):
            flags[c] |= _EDGE if (flags[c] == 0) & (near[c] != 0) else np.uint8(0)
    if check_gradient and 0 < e < height - 1:
        g2 = max_gradient * max_gradient
        above = reason_ring[(e - 1) % ring]
        below = reason_ring[(e + 1) % ring]
        ok = column  # STEEP where the pixel and its four neighbours are valid
        for c in range(1, width - 1):
            valid = (here[c] | here[c - 1] | here[c + 1] | above[c] | below[c]) == 0
            ok[c] = _STEEP if valid else np.uint8(0)
        for d in range(n_dirs):
            ua = u_ring[(e - 1) % ring, d]
            uc = u_ring[slot, d]
            ub = u_ring[(e + 1) % ring, d]
            for c in range(1, width - 1):
                gx = (uc[c + 1] - uc[c - 1]) * half
                gy = (ub[c] - ua[c]) * half
                near[c] = ok[c] if gx * gx + gy * gy > g2 else np.uint8(0)
            for c in range(1, width - 1):
                flags[c] |= near[c]


@numba.njit(fastmath=_FAST, error_model="numpy")
def _finish_row(e, height, ring, reason_ring, u_ring, erode, max_gradient, check_gradient,
                keep_invalid, tri_mode, table_dir, num, den, ray_f, ray_i, offsets, mod_row,
                flags, near, column, f64, nan_row, zero_row, out_u, out_int, out_reason,
                out_mask, out_xyz):  # pragma: no cover - compiled
    """Row `e`'s neighbourhood checks (:func:`_check_row`), triangulation and outputs.

    ``tri_mode`` 1: the rational table of one projector coordinate (float32); 2: on the camera
    rays (:func:`_ray_points`, float64). Pixels without a finite point get :data:`NO_POINT`.
    `f64` ``(7, W)`` float64 is scratch; `nan_row`, `zero_row` ``(W,)`` float32 hold NaN, 0.
    """
    width = u_ring.shape[2]
    slot = e % ring
    nan = np.float32(np.nan)
    _check_row(e, height, ring, reason_ring, u_ring, erode, max_gradient, check_gradient, flags,
               near, column)
    x_out, y_out, z_out = f64[0], f64[1], f64[2]
    lo = width  # triangulated: the columns from the row's first valid pixel to its last
    hi = 0
    if tri_mode > 0:
        for c in range(width):
            valid = flags[c] == 0
            lo = min(lo, c) if valid else lo
            hi = max(hi, c + 1) if valid else hi
    if tri_mode == 1 and lo < hi:
        one = np.float32(1.0)
        up = u_ring[slot, table_dir]
        n0, n1, n2, n3, n4, n5 = num[0, e], num[1, e], num[2, e], num[3, e], num[4, e], num[5, e]
        d0, d1 = den[0, e], den[1, e]
        for c in range(lo, hi):
            p = up[c]
            inv = one / (d0[c] + d1[c] * p)
            x_out[c] = (n0[c] + n1[c] * p) * inv
            y_out[c] = (n2[c] + n3[c] * p) * inv
            z_out[c] = (n4[c] + n5[c] * p) * inv
    elif tri_mode == 2 and lo < hi:
        ix, iy = ray_i[4], ray_i[5]
        # a direction the pattern set lacks: the reference's NaN image
        ux = u_ring[slot, ix, lo:hi] if ix >= 0 else nan_row[lo:hi]
        uy = u_ring[slot, iy, lo:hi] if iy >= 0 else nan_row[lo:hi]
        ox = offsets[0, e, lo:hi] if ray_i[6] else zero_row[lo:hi]  # lens-undistorted centres
        oy = offsets[1, e, lo:hi] if ray_i[6] else zero_row[lo:hi]
        xs, ys, zs = x_out[lo:hi], y_out[lo:hi], z_out[lo:hi]
        if ray_i[2]:  # projector lens: ideal coordinates first
            _ideal_panel(ux, uy, ray_f, ray_i, f64[3, lo:hi], f64[4, lo:hi], f64[5, lo:hi],
                         f64[6, lo:hi])
            _ray_points(f64[5, lo:hi], f64[6, lo:hi], np.float64(lo), 1.0, ox, np.float64(e), oy,
                        ray_f, ray_i[0], False, xs, ys, zs)
        else:
            _ray_points(ux, uy, np.float64(lo), 1.0, ox, np.float64(e), oy, ray_f, ray_i[0],
                        ray_i[1] != 0, xs, ys, zs)
    if tri_mode > 0:  # no point: NO_POINT (separate loops: each vectorises)
        for c in range(lo, hi):
            finite = np.isfinite(x_out[c]) & np.isfinite(y_out[c]) & np.isfinite(z_out[c])
            f = flags[c]
            flags[c] = f | (_NO_POINT if (f == 0) & ~finite else np.uint8(0))
        xyz = out_xyz[e]
        for c in range(width):
            valid = flags[c] == 0
            xyz[c, 0] = np.float32(x_out[c]) if valid else nan
            xyz[c, 1] = np.float32(y_out[c]) if valid else nan
            xyz[c, 2] = np.float32(z_out[c]) if valid else nan
    reason = out_reason[e]
    mask = out_mask[e]
    intensity = out_int[e]
    two = np.float32(2.0)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for c in range(width):
        f = flags[c]
        valid = f == 0
        reason[c] = f
        mask[c] = valid
        intensity[c] = min(two * mod_row[c], one) if valid else zero
    for d in range(u_ring.shape[1]):
        src = u_ring[slot, d]
        dst = out_u[d, e]
        for c in range(width):
            dst[c] = src[c] if (flags[c] == 0) | keep_invalid else nan


@numba.njit(parallel=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def _decode_kernel(frames, plan, limits, checks, table, outputs):  # pragma: no cover
    """Decode, check, triangulate: chunks of `chunk` rows in parallel, each decoding its rows
    and ``halo`` rows beyond either end (those the neighbourhood checks read) into ring
    buffers of ``2 halo + 1`` rows; only per-row temporaries, no full-image scratch.

    The arguments are tuples (numba unpacks them at compile time): `plan` the arrays of a
    :class:`_KernelPlan`, `limits` the per-pixel thresholds (float32, squared amplitudes),
    `checks` the neighbourhood checks and the row chunk, `table` the triangulation
    (``tri_mode`` 0 none, 1 rational table, 2 camera rays), `outputs` the result arrays.
    """
    (block_frame, block_cos, block_sin, block_size, group_block, group_bscale, group_ratio,
     dir_groups, dir_levels, dir_coef, dir_period, dir_origin, dir_size) = plan
    inv_scale, sat_native, min_mod2, cue_mod2, min_alb, tol = limits
    erode, max_gradient, check_gradient, keep_invalid, chunk = checks
    tri_mode, table_dir, num, den, ray_f, ray_i, offsets = table
    out_u, out_mod, out_alb, out_int, out_reason, out_mask, out_xyz = outputs
    height = frames.shape[1]
    width = frames.shape[2]
    n_dirs = dir_groups.shape[0]
    halo = max(erode, 1 if check_gradient else 0)
    ring = 2 * halo + 1
    n_chunks = (height + chunk - 1) // chunk
    for ci in numba.prange(n_chunks):
        a = ci * chunk
        b = min(a + chunk, height)
        lo = max(a - halo, 0)
        hi = min(b + halo, height)
        u_ring = np.empty((ring, n_dirs, width), np.float32)
        reason_ring = np.empty((ring, width), np.uint8)
        f32 = np.empty((11, width), np.float32)
        f32[9] = np.nan
        f32[10] = 0.0
        u8 = np.empty((3, width), np.uint8)
        f64 = np.empty((7, width))
        for rr in range(lo, hi):
            slot = rr % ring
            mod_row = f32[8]  # halo rows: modulation and albedo to scratch
            alb_row = f32[8]
            if (rr >= a) & (rr < b):
                mod_row = out_mod[rr]
                alb_row = out_alb[rr]
            _decode_row(frames, rr, block_frame, block_cos, block_sin, block_size, group_block,
                        group_bscale, group_ratio, dir_groups, dir_levels, dir_coef, dir_period,
                        dir_origin, dir_size, inv_scale, sat_native, min_mod2, cue_mod2, min_alb,
                        tol,
                        f32[0], f32[1], f32[2], f32[3], f32[4], u8[0], f32[5], f32[6], f32[7],
                        u_ring[slot], reason_ring[slot], mod_row, alb_row)
            e = rr - halo
            if e >= a:
                _finish_row(e, height, ring, reason_ring, u_ring, erode, max_gradient,
                            check_gradient, keep_invalid, tri_mode, table_dir, num, den, ray_f,
                            ray_i, offsets, out_mod[e], u8[0], u8[1], u8[2], f64, f32[9],
                            f32[10], out_u, out_int, out_reason, out_mask, out_xyz)
        for e in range(max(hi - halo, a), b):  # the last rows of the image
            _finish_row(e, height, ring, reason_ring, u_ring, erode, max_gradient,
                        check_gradient, keep_invalid, tri_mode, table_dir, num, den, ray_f,
                        ray_i, offsets, out_mod[e], u8[0], u8[1], u8[2], f64, f32[9], f32[10],
                        out_u, out_int, out_reason, out_mask, out_xyz)


@dataclass
class _KernelPlan:
    block_frame: np.ndarray  # (n_blocks, 3) frames summed together (single: the first)
    block_cos: np.ndarray  # (n_blocks, 3) float32 cos of the shifts
    block_sin: np.ndarray
    block_size: np.ndarray  # (n_blocks,) 3 or 1
    group_block: np.ndarray  # (n_groups, 2) first block, number of blocks
    group_bscale: np.ndarray  # (2 / (N full_scale))^2
    group_ratio: np.ndarray  # periods / periods of the next coarser frequency
    dir_groups: np.ndarray  # (n_dirs, 16) groups coarse to fine, -1 padded
    dir_levels: np.ndarray  # (n_dirs,) number of groups
    dir_coef: np.ndarray  # float64 size / (2 pi n_finest)
    dir_period: np.ndarray  # float64 size / n_finest
    dir_origin: np.ndarray  # float64
    dir_size: np.ndarray  # float32
    directions: tuple[str, ...]


def _plan(pattern_set: PatternSet, scale: float) -> _KernelPlan:
    block_frame: list[list[int]] = []
    block_cos: list[np.ndarray] = []
    block_sin: list[np.ndarray] = []
    block_size: list[int] = []
    group_block: list[tuple[int, int]] = []
    bscale: list[float] = []
    ratio: list[float] = []
    n_dirs = len(pattern_set.directions)
    dir_groups = -np.ones((n_dirs, 16), dtype=np.int64)
    levels, coef, period, origin, size = [], [], [], [], []
    frame = 0
    for d, direction in enumerate(pattern_set.directions):
        freqs = pattern_set.frequencies(direction)
        if len(freqs) > 16:
            raise ValueError(f"{direction}: at most 16 frequencies per direction")
        first_group = len(group_block)
        for f in freqs:  # groups in frame order; N >= 3: threes, then the one or two left
            shifts = pattern_set.shifts(f.steps)
            starts = [*range(0, f.steps - 2, 3), *range(f.steps - f.steps % 3, f.steps)]
            group_block.append((len(block_frame), len(starts)))
            for b in starts:
                k = [b, b + 1, b + 2] if b + 3 <= f.steps else [b, b, b]
                block_frame.append([frame + i for i in k])
                block_cos.append(np.cos(shifts[k]))
                block_sin.append(np.sin(shifts[k]))
                block_size.append(3 if b + 3 <= f.steps else 1)
            bscale.append((2.0 / (f.steps * scale)) ** 2)
            frame += f.steps
        order = np.argsort([f.periods for f in freqs], kind="stable")
        previous = None
        ratio.extend([1.0] * len(freqs))
        for j, i in enumerate(order):  # unwrapping order: coarse to fine
            g = first_group + int(i)
            dir_groups[d, j] = g
            ratio[g] = 1.0 if previous is None else freqs[i].periods / previous
            previous = freqs[i].periods
        size_px = pattern_set.axis_size(direction)
        assert previous is not None  # a direction has at least one frequency
        levels.append(len(freqs))
        coef.append(size_px / (TWO_PI * previous))
        period.append(size_px / previous)
        origin.append(pattern_set.phase_origin)
        size.append(size_px)
    f32 = np.float32
    return _KernelPlan(
        block_frame=np.asarray(block_frame, np.int64), block_cos=np.asarray(block_cos, f32),
        block_sin=np.asarray(block_sin, f32), block_size=np.asarray(block_size, np.int64),
        group_block=np.asarray(group_block, np.int64), group_bscale=np.asarray(bscale, f32),
        group_ratio=np.asarray(ratio, f32), dir_groups=dir_groups,
        dir_levels=np.asarray(levels, np.int64), dir_coef=np.asarray(coef, np.float64),
        dir_period=np.asarray(period, np.float64), dir_origin=np.asarray(origin, np.float64),
        dir_size=np.asarray(size, f32), directions=tuple(pattern_set.directions),
    )


def planar_table(table) -> tuple[np.ndarray, np.ndarray, str]:
    """A triangulation table as contiguous planes ``num (6, H, W)``, ``den (2, H, W)`` float32.

    Done once per calibration; :func:`decode_fast` accepts the result in place of the table.
    """
    if isinstance(table, tuple):
        return table
    num = np.ascontiguousarray(
        np.moveaxis(np.asarray(table.numerator, np.float32).reshape(*table.numerator.shape[:2], 6),
                    -1, 0))
    den = np.ascontiguousarray(np.moveaxis(np.asarray(table.denominator, np.float32), -1, 0))
    return num, den, table.axis


def _chunk_rows(height: int) -> int:
    """Rows per parallel chunk: four chunks a thread (each decodes ``2 halo`` extra rows)."""
    return max(1, -(-height // (4 * numba.get_num_threads())))


def decode_fast(
    frames,
    pattern_set: PatternSet,
    *,
    table=None,
    min_modulation: float = MIN_MODULATION,
    cue_modulation: float | None = CUE_MODULATION,
    min_albedo: float = MIN_ALBEDO,
    saturation: float = SATURATION,
    unwrap_tolerance: float = UNWRAP_TOLERANCE,
    erode: int = ERODE,
    max_gradient: float | None = None,
    keep_invalid: bool = False,
    full_scale: float | None = None,
    out: Decoded | None = None,
) -> Decoded:
    """Fused decode + unwrap + neighbourhood checks (+ triangulation) in numba, one pass.

    Parallel over chunks of rows; each chunk decodes its rows and the few beyond either end
    that the neighbourhood checks read (``erode`` rows, one for ``max_gradient``) into ring
    buffers, so the only full-size arrays are the frames (read as stored: uint8, uint16 or
    float32) and the outputs. Options as :func:`decode`; the results agree with the NumPy
    reference within float32 rounding: ``xp``, ``yp`` within one float32 step (6.1e-5 px below
    1024 px, 1.2e-4 px above), the arctangent being exact to 1.5e-7 rad; the mask the same but
    for pixels whose value lies within rounding of a threshold (``tests/test_scan_kernels.py``).
    The first call with a frame dtype compiles the kernel (15 s; then cached on disk,
    ``nail2nail._numba_cache``: 0.2 s in a new process).

    Parameters
    ----------
    frames : (n_frames, H, W) uint8, uint16 or float array
        As for :func:`decode`; float64 frames are copied to float32.
    pattern_set : PatternSet
        What was projected.
    min_modulation, cue_modulation, min_albedo, saturation, unwrap_tolerance, erode, max_gradient,
    keep_invalid
        As for :func:`decode` (`cue_modulation` is the plan's threshold of the coarser levels).
    table : RayTable, TriangulationTable or tuple, optional
        Also triangulate into ``Decoded.xyz``: a
        :class:`~nail2nail.scan.triangulation.RayTable`
        (:func:`~nail2nail.scan.triangulation.ray_table`:
        on the camera rays from one or both projector coordinates, float64, the projector's
        distortion compensated) or a :class:`~nail2nail.scan.triangulation.TriangulationTable`
        (one projector coordinate, rational form in float32; :func:`planar_table` saves its
        layout change). Pixels without a finite point get :data:`NO_POINT`.
    full_scale : float, optional
        Value of full intensity of integer frames: 255 for uint8 and 65535 for uint16 by
        default; ``2**bit_depth - 1`` for right-aligned values (``raw=True`` frames).
    out : Decoded, optional
        A previous result of the same shape and table kind, overwritten (no allocation).

    Returns
    -------
    Decoded
        With ``xyz (H, W, 3) float32`` (mm) when `table` is given; ``xp``, ``yp`` are views of
        one ``(n_dirs, H, W)`` buffer.

    Raises
    ------
    ValueError, TypeError
        As :func:`decode`; a table for another image size, or whose projector coordinates the
        pattern set does not decode; a pattern set of another scheme than PMP (the Gray-code
        schemes are decoded by :func:`decode`'s NumPy path).

    Examples
    --------
    >>> from nail2nail.scan.decoding import decode
    >>> from nail2nail.scan.patterns import PatternSet, make_patterns
    >>> ps = PatternSet(x=[(1, 3), (8, 4)], panel_size=(64, 4))
    >>> fast = decode_fast(make_patterns(ps), ps, saturation=1.01)
    >>> ref = decode(make_patterns(ps), ps, saturation=1.01)
    >>> bool((fast.mask == ref.mask).all()), float(np.abs(fast.xp - ref.xp).max()) < 1e-5
    (True, True)
    """

    frames = _check_frames(frames, pattern_set)
    if pattern_set.scheme != "pmp":
        raise ValueError(f"pattern_set: the fused kernel decodes PMP only, got scheme "
                         f"{pattern_set.scheme!r} (decode it with decode(), the NumPy path)")
    erode = _check_erode(erode)
    max_gradient = _check_gradient(max_gradient)
    min_modulation = cast(float, _check_modulation(min_modulation, "min_modulation"))
    cue_modulation = _check_modulation(cue_modulation, "cue_modulation")
    cue = min_modulation if cue_modulation is None else cue_modulation
    if not frames.flags.c_contiguous:
        frames = np.ascontiguousarray(frames)
    if np.issubdtype(frames.dtype, np.floating) and frames.dtype != np.float32:
        frames = frames.astype(np.float32)
    full_scale = _check_scale(full_scale)
    scale = _full_scale(frames.dtype) if full_scale is None else full_scale
    plan = _plan(pattern_set, scale)
    height, width = frames.shape[1:]
    n_dirs = len(plan.directions)
    num = np.zeros((6, 1, 1), np.float32)
    den = np.zeros((2, 1, 1), np.float32)
    ray_f, ray_i = np.zeros(_RAY_SIZE), np.array([0, 0, 0, 0, -1, -1, 0], np.int64)
    offsets = np.zeros((2, 1, 1), np.float32)
    tri_mode, table_dir = 0, -1
    if isinstance(table, RayTable):
        if tuple(table.shape) != (height, width):
            raise ValueError(f"table: expected a table for images of shape {(height, width)}, "
                             f"got {tuple(table.shape)}")
        missing = [d for d in ("x", "y") if d not in plan.directions]
        if missing and table.needs_both:
            raise ValueError(f"table: triangulation with use={table.use!r}, a projector "
                             "distortion model or lens distortion needs both projector "
                             f"coordinates; the pattern set has no {missing[0]!r} direction")
        tri_mode = 2
        packed, codes = _pack_ray(table)
        ray_f = packed
        ix = plan.directions.index("x") if "x" in plan.directions else -1
        iy = plan.directions.index("y") if "y" in plan.directions else -1
        has_offsets = table.pixel_offsets is not None
        ray_i = np.concatenate([codes, [ix, iy, has_offsets]]).astype(np.int64)
        if table.pixel_offsets is not None:
            offsets = table.pixel_offsets
    elif table is not None:
        num, den, axis = planar_table(table)
        if num.shape != (6, height, width) or den.shape != (2, height, width):
            raise ValueError(
                f"table: expected a table for images of shape {(height, width)}, "
                f"got {num.shape[1:]}"
            )
        if axis not in plan.directions:
            raise ValueError(f"table: its axis {axis!r} is not decoded by this pattern set")
        tri_mode, table_dir = 1, plan.directions.index(axis)
    if out is None or out.shape != (height, width) or (table is not None and out.xyz is None):
        u = np.empty((n_dirs, height, width), np.float32)
        out = Decoded(
            xp=u[plan.directions.index("x")] if "x" in plan.directions else None,
            yp=u[plan.directions.index("y")] if "y" in plan.directions else None,
            modulation=np.empty((height, width), np.float32),
            albedo=np.empty((height, width), np.float32),
            intensity=np.empty((height, width), np.float32),
            mask=np.empty((height, width), bool),
            reason=np.empty((height, width), np.uint8),
            xyz=np.empty((height, width, 3), np.float32) if table is not None else None,
            coords=u,
        )
    if out.coords is None or out.coords.shape[0] != n_dirs:
        raise ValueError("out: expected a Decoded returned by decode_fast for this pattern set")
    xyz = (out.xyz if table is not None and out.xyz is not None
           else np.zeros((1, 1, 3), np.float32))
    f32 = np.float32
    _decode_kernel(
        frames,
        (plan.block_frame, plan.block_cos, plan.block_sin, plan.block_size, plan.group_block,
         plan.group_bscale, plan.group_ratio, plan.dir_groups, plan.dir_levels, plan.dir_coef,
         plan.dir_period, plan.dir_origin, plan.dir_size),
        (f32(1.0 / (pattern_set.n_frames * scale)), f32(saturation * scale),
         f32(min_modulation) * f32(min_modulation), f32(cue) * f32(cue), f32(min_albedo),
         f32(unwrap_tolerance)),
        (erode, f32(np.inf if max_gradient is None else max_gradient), max_gradient is not None,
         bool(keep_invalid), _chunk_rows(height)),
        (tri_mode, table_dir, num, den, ray_f, ray_i, offsets),
        (out.coords, out.modulation, out.albedo, out.intensity, out.reason, out.mask, xyz),
    )
    return out

