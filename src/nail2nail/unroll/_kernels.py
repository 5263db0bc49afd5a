"""Compiled per-pixel and per-sample steps of the unroll (numba), the print unchanged.

Each kernel repeats, element by element, the arithmetic of the NumPy code it replaced, in the
same precision and order, so that ``unroll_scans`` gives the same print to the last bit:

- ridge signal (:mod:`~nail2nail.unroll.ridges`): the valid pixels (:func:`valid_points`),
  the pixel spacing's steps (:func:`row_steps`), ``masked_gaussian``'s block means
  (:func:`block_mean`: NumPy's float32 summation order of ``reshape(...).mean(axis=(1, 3))``
  included), normalisation (:func:`ratio`) and bilinear upsampling (:func:`upsample`), the
  smooth surface's normals, viewing cosine and relief (:func:`surface_relief`), the local
  normalisation (:func:`deviation`, :func:`normalized`) and the camera's outputs
  (:func:`layer_outputs`);
- flattening (:mod:`~nail2nail.unroll.flatten`): the cylinder fit's residual
  (:func:`axis_distance`) and the rolled map (:func:`rolled_map`; the dot products and
  ``atan2`` stay NumPy's);
- blending (:mod:`~nail2nail.unroll.render`): a camera's samples (:func:`camera_points`), the
  print grid's percentiles (:func:`tail_percentile`) and the bilinear splat (:func:`splat`:
  float32 kernel weights, float64 sums in sample order, one per corner of the kernel, added
  corner by corner as the former four ``np.bincount`` were).

``tests/test_unroll_kernels.py`` checks each against the former NumPy code, and the whole
unroll against the pipeline run with the former steps.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from nail2nail._numba_cache import cache_enabled

__all__ = [
    "axis_distance",
    "block_mean",
    "camera_points",
    "deviation",
    "layer_outputs",
    "normalized",
    "ratio",
    "rolled_map",
    "row_steps",
    "splat",
    "surface_relief",
    "tail_percentile",
    "upsample",
    "valid_points",
]

_CACHE = cache_enabled()


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _rolled_map(theta, along, radius, s_table, t_table, origin_s, origin_t, grid_mm,
                st):  # pragma: no cover - compiled
    h, w = s_table.shape
    for i in range(theta.shape[0]):
        c = (radius * theta[i] - origin_s) / grid_mm
        r = (along[i] - origin_t) / grid_mm
        # bilinear s on the table, positions clipped to it
        rc = min(max(r, 0.0), h - 1.0)
        cc = min(max(c, 0.0), w - 1.0)
        r0 = min(max(math.floor(rc), 0), h - 2)
        c0 = min(max(math.floor(cc), 0), w - 2)
        fr = rc - r0
        fc = cc - c0
        f00 = s_table[r0, c0]
        f01 = s_table[r0, c0 + 1]
        f10 = s_table[r0 + 1, c0]
        f11 = s_table[r0 + 1, c0 + 1]
        top = f00 + (f01 - f00) * fc
        bottom = f10 + (f11 - f10) * fc
        s = top + (bottom - top) * fr
        # t: np.interp on rows 0 … h − 1, the end slopes beyond
        if r < 0:
            t = t_table[0] + r * (t_table[1] - t_table[0])
        elif r > h - 1:
            t = t_table[h - 1] + (r - h + 1) * (t_table[h - 1] - t_table[h - 2])
        elif r == h - 1:
            t = t_table[h - 1]
        else:
            j = math.floor(r)
            slope = (t_table[j + 1] - t_table[j]) / 1.0
            t = slope * (r - j) + t_table[j]
        if c < 0:
            s = s + c * grid_mm
        elif c > w - 1:
            s = s + (c - w + 1) * grid_mm
        else:
            s = s + 0.0 * grid_mm
        st[i, 0] = s
        st[i, 1] = t


def rolled_map(flat, xyz=None, *, offsets=None) -> np.ndarray:
    """Print-plane ``(s, t)`` of world points by a :class:`~.flatten.RolledMap`.

    Parameters
    ----------
    flat : RolledMap
    xyz : (N, 3) float32 or float64
        World points, mm.
    offsets : (N, 3) float64, optional
        Instead of `xyz`: the points minus ``flat.cylinder.center``
        (:func:`camera_points`).

    Returns
    -------
    (N, 2) float64
        ``(s, t)``, mm, as ``flat(xyz)`` to the last bit.
    """
    # the cylinder coordinates by NumPy (BLAS dot products, NumPy's atan2), the rest compiled
    cyl = flat.cylinder
    x, z, along = cyl._local(xyz) if offsets is None else cyl._local_offsets(offsets)
    theta = np.arctan2(x, z)
    st = np.empty((len(theta), 2))
    _rolled_map(theta, along, float(cyl.radius),
                np.ascontiguousarray(flat.s_table, np.float64),
                np.ascontiguousarray(flat.t_table, np.float64),
                float(flat.grid_origin[0]), float(flat.grid_origin[1]), float(flat.grid_mm),
                st)
    return st


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _count_samples(signal, weight):  # pragma: no cover - compiled
    n = 0
    for i in range(signal.shape[0]):
        if weight[i] > 0 and np.isfinite(signal[i]):
            n += 1
    return n


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _gather_samples(xyz, signal, weight, center, d, value, wt):  # pragma: no cover
    n = 0
    for i in range(signal.shape[0]):
        if weight[i] > 0 and np.isfinite(signal[i]):
            for k in range(3):
                d[n, k] = np.float64(xyz[i, k]) - center[k]
            value[n] = signal[i]
            wt[n] = weight[i]
            n += 1


def camera_points(xyz, signal, weight, center) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera's samples with data (``weight > 0`` and a finite signal), row-major.

    Parameters
    ----------
    xyz : (H, W, 3) float32
        Points, mm.
    signal, weight : (H, W) float32
    center : (3,) float64
        Subtracted from the points (in float64).

    Returns
    -------
    offsets : (N, 3) float64
        ``float64(xyz[ok]) − center``.
    value, weight : (N,) float32
        ``signal[ok]``, ``weight[ok]``.
    """
    xyz = np.ascontiguousarray(xyz).reshape(-1, 3)
    signal = np.ascontiguousarray(signal, np.float32).ravel()
    weight = np.ascontiguousarray(weight, np.float32).ravel()
    n = _count_samples(signal, weight)
    d = np.empty((n, 3))
    value = np.empty(n, np.float32)
    wt = np.empty(n, np.float32)
    _gather_samples(xyz, signal, weight, np.asarray(center, np.float64), d, value, wt)
    return d, value, wt


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _splat(st, values, weights, s0, t0, pitch, h, w, num, den, cnt):  # pragma: no cover
    # num, den, cnt: (4, h * w) float64, one sum per corner of the kernel
    for i in range(st.shape[0]):
        r = (t0 - st[i, 1]) / pitch
        c = (s0 - st[i, 0]) / pitch
        r0 = math.floor(r)
        c0 = math.floor(c)
        fr = np.float32(r - r0)
        fc = np.float32(c - c0)
        wt = weights[i]
        wv = wt * values[i]
        one = np.float32(1.0)
        for k in range(4):
            dr = k // 2
            dc = k % 2
            rr = r0 + dr
            cc = c0 + dc
            if rr < 0 or rr >= h or cc < 0 or cc >= w:
                continue
            kr = fr if dr else one - fr
            kc = fc if dc else one - fc
            kk = kr * kc
            idx = rr * w + cc
            num[k, idx] += np.float64(kk * wv)
            den[k, idx] += np.float64(kk * wt)
            cnt[k, idx] += np.float64(kk)


def splat(grid, st, values, weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear splat on a print grid: ``Σ w·k·v``, ``Σ w·k`` and ``Σ k`` per print pixel.

    Parameters
    ----------
    grid : PrintGrid
    st : (N, 2) float64
        Print-plane ``(s, t)`` of the samples, mm.
    values, weights : (N,) float32

    Returns
    -------
    num, den, count : (H, W) float64
    """
    h, w = grid.shape
    num = np.zeros((4, h * w))
    den = np.zeros((4, h * w))
    cnt = np.zeros((4, h * w))
    _splat(np.ascontiguousarray(st, np.float64), np.ascontiguousarray(values, np.float32),
           np.ascontiguousarray(weights, np.float32), grid.s0, grid.t0, grid.pitch, h, w,
           num, den, cnt)

    def total(a):
        # corner by corner, as the sums of four np.bincount calls were added
        return (((a[0] + a[1]) + a[2]) + a[3]).reshape(h, w)

    return total(num), total(den), total(cnt)


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _upsample(small, r0, r1, fr, gr, c0, c1, fc, gc, out):  # pragma: no cover - compiled
    # tall = small[r0]·(1 − fr) + small[r1]·fr, one output row at a time; then
    # out[i, j] = tall[c0]·(1 − fc) + tall[c1]·fc, float32, as in NumPy
    ws = small.shape[1]
    nk = out.shape[2]
    tall = np.empty((ws, nk), np.float32)
    for i in range(out.shape[0]):
        a0, a1, wr0, wr1 = r0[i], r1[i], gr[i], fr[i]
        for b in range(ws):
            for k in range(nk):
                tall[b, k] = small[a0, b, k] * wr0 + small[a1, b, k] * wr1
        if nk == 1:
            for j in range(out.shape[1]):
                out[i, j, 0] = tall[c0[j], 0] * gc[j] + tall[c1[j], 0] * fc[j]
        else:
            for j in range(out.shape[1]):
                for k in range(nk):
                    out[i, j, k] = tall[c0[j], k] * gc[j] + tall[c1[j], k] * fc[j]


def upsample(small, r0, r1, fr, c0, c1, fc) -> np.ndarray:
    """Separable bilinear upsampling of ``(h, w, k)`` float32 to ``(len(r0), len(c0), k)``.

    Rows ``r0``/``r1`` with weights ``1 − fr``/``fr`` (float32), then columns alike: the
    float32 arithmetic of ``tall = small[r0]·(1 − fr) + small[r1]·fr`` followed by
    ``tall[:, c0]·(1 − fc) + tall[:, c1]·fc``, without the full-size temporaries.
    """
    fr = np.ascontiguousarray(fr, np.float32)
    fc = np.ascontiguousarray(fc, np.float32)
    out = np.empty((len(r0), len(c0), small.shape[2]), np.float32)
    _upsample(np.ascontiguousarray(small, np.float32), np.ascontiguousarray(r0, np.intp),
              np.ascontiguousarray(r1, np.intp), fr, 1 - fr,
              np.ascontiguousarray(c0, np.intp), np.ascontiguousarray(c1, np.intp), fc, 1 - fc,
              out)
    return out


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy", inline="always")
def _nan_to_num32(x):  # pragma: no cover - compiled
    big = np.float32(3.4028234663852886e38)
    if np.isnan(x):
        return np.float32(0.0)
    if x == np.inf:
        return big
    if x == -np.inf:
        return -big
    return x


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _relief(smooth, xyz, center, has_center, cos_out, relief_out, finite_out):
    # pragma: no cover - compiled
    h, w = smooth.shape[:2]
    two = np.float32(2.0)
    dr = np.empty(3, np.float32)
    dc = np.empty(3, np.float32)
    nv = np.empty(3, np.float32)
    for i in range(h):
        ia = i + 1 if i < h - 1 else i
        ib = i - 1 if i > 0 else i
        for j in range(w):
            ja = j + 1 if j < w - 1 else j
            jb = j - 1 if j > 0 else j
            # np.gradient: central differences inside, one-sided at the edges
            for k in range(3):
                if 0 < i < h - 1:
                    dr[k] = (smooth[ia, j, k] - smooth[ib, j, k]) / two
                else:
                    dr[k] = smooth[ia, j, k] - smooth[ib, j, k]
                if 0 < j < w - 1:
                    dc[k] = (smooth[i, ja, k] - smooth[i, jb, k]) / two
                else:
                    dc[k] = smooth[i, ja, k] - smooth[i, jb, k]
            # np.cross, then division by the norm (einsum's order of the sum of squares)
            nv[0] = dr[1] * dc[2] - dr[2] * dc[1]
            nv[1] = dr[2] * dc[0] - dr[0] * dc[2]
            nv[2] = dr[0] * dc[1] - dr[1] * dc[0]
            norm = np.sqrt(nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2])
            for k in range(3):
                nv[k] = nv[k] / norm
            if has_center:
                v0 = center[0] - smooth[i, j, 0]
                v1 = center[1] - smooth[i, j, 1]
                v2 = center[2] - smooth[i, j, 2]
                vn = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                v0 = v0 / vn
                v1 = v1 / vn
                v2 = v2 / vn
                cos = nv[0] * v0 + nv[1] * v1 + nv[2] * v2
                if cos < 0:
                    for k in range(3):
                        nv[k] = nv[k] * np.float32(-1.0)
                cos_out[i, j] = abs(cos)
            else:
                cos_out[i, j] = np.float32(1.0)
            acc = np.float32(0.0)
            for k in range(3):
                acc = acc + _nan_to_num32(xyz[i, j, k] - smooth[i, j, k]) * _nan_to_num32(nv[k])
            relief_out[i, j] = acc
            finite_out[i, j] = np.isfinite(smooth[i, j, 0] + smooth[i, j, 1] + smooth[i, j, 2]) \
                and np.isfinite(nv[0] + nv[1] + nv[2])


def surface_relief(smooth, xyz, camera_center) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Relief along the smooth surface's normal, the viewing cosine, and where both are defined.

    The float32 arithmetic of ``camera_layer``'s NumPy steps, fused: normals
    ``∂X̄/∂row × ∂X̄/∂col`` (``np.gradient``, ``np.cross``) made unit, turned towards the
    camera, ``cos = |n · v|`` with ``v`` the unit direction to `camera_center`, and
    ``h = nan_to_num(X − X̄) · nan_to_num(n)``.

    Parameters
    ----------
    smooth, xyz : (H, W, 3) float32
        Smooth surface and points, mm (H, W ≥ 2).
    camera_center : (3,) float or None
        Without it the cosine is 1 and the normals keep their orientation.

    Returns
    -------
    cos : (H, W) float32
        NaN where the normal or the view is undefined.
    relief : (H, W) float32
    finite : (H, W) bool
        The smooth point and its normal are finite.
    """
    h, w = smooth.shape[:2]
    cos = np.empty((h, w), np.float32)
    relief = np.empty((h, w), np.float32)
    finite = np.empty((h, w), np.bool_)
    has = camera_center is not None
    center = np.asarray(camera_center if has else (0.0, 0.0, 0.0), np.float32)
    _relief(np.ascontiguousarray(smooth, np.float32), np.ascontiguousarray(xyz, np.float32),
            center, has, cos, relief, finite)
    return cos, relief, finite


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _pairwise(x, n):  # pragma: no cover - compiled
    # NumPy's pairwise float32 sum of a contiguous run (n ≤ 128: eight accumulators)
    if n < 8:
        res = np.float32(0.0)
        for i in range(n):
            res += x[i]
        return res
    r = x[:8].copy()
    i = 8
    while i < n - (n % 8):
        for j in range(8):
            r[j] += x[i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += x[i]
        i += 1
    return res


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _block_mean(values, valid, f, hs, ws, v_out, m_out):  # pragma: no cover - compiled
    h, w, nk = values.shape
    row = np.zeros(f, np.float32)
    acc = np.zeros((ws, nk), np.float32)
    count = np.zeros(ws, np.int64)
    inv = np.float64(f * f)
    zero = np.float32(0.0)
    for bi in range(hs):
        acc[:] = 0
        count[:] = 0
        for a in range(f):
            i = bi * f + a
            inside = i < h
            for bj in range(ws):
                for b in range(f):
                    j = bj * f + b
                    if inside and j < w and valid[i, j]:
                        count[bj] += 1
                for c in range(nk):
                    for b in range(f):
                        j = bj * f + b
                        x = values[i, j, c] if (inside and j < w and valid[i, j]) else zero
                        if nk == 1:
                            row[b] = x
                        else:
                            acc[bj, c] += x  # several channels: over rows, then columns
                    if nk == 1:
                        # one channel: each block row's pairwise sum, added in turn
                        acc[bj, c] = acc[bj, c] + _pairwise(row, f)
        for bj in range(ws):
            m_out[bi, bj] = np.float32(np.float64(np.float32(count[bj])) / inv)
            for c in range(nk):
                v_out[bi, bj, c] = np.float32(np.float64(acc[bj, c]) / inv)


def block_mean(values, valid, f: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of ``f × f`` blocks of masked values and of the mask, zero-padded at the end.

    The float32 results of NumPy's ``reshape(h/f, f, w/f, f, k).mean(axis=(1, 3))`` of the
    values set to 0 off `valid` and of the mask as float32 (the summation order of that
    reduction included: rows then columns for several channels; for one, each block row's
    pairwise sum added in turn), without the padded copies.

    Parameters
    ----------
    values : (H, W, k) float32
    valid : (H, W) bool
    f : int
        Block size, 1 … 128.

    Returns
    -------
    v : (⌈H/f⌉, ⌈W/f⌉, k) float32
    m : (⌈H/f⌉, ⌈W/f⌉) float32
    """
    h, w, k = values.shape
    hs, ws = -(-h // f), -(-w // f)
    v = np.empty((hs, ws, k), np.float32)
    m = np.empty((hs, ws), np.float32)
    _block_mean(np.ascontiguousarray(values, np.float32), np.ascontiguousarray(valid, np.bool_),
                int(f), hs, ws, v, m)
    return v, m


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _axis_distance(d, along, axis, radius, out):  # pragma: no cover - compiled
    for i in range(d.shape[0]):
        x0 = d[i, 0] - along[i] * axis[0]
        x1 = d[i, 1] - along[i] * axis[1]
        x2 = d[i, 2] - along[i] * axis[2]
        out[i] = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2) - radius


def axis_distance(d, axis, radius: float = 0.0) -> np.ndarray:
    """Distance of points from an axis through the origin, minus `radius`.

    ``np.linalg.norm(d − outer(d @ axis, axis), axis=1) − radius`` to the last bit (the dot
    products by NumPy), in one pass.

    Parameters
    ----------
    d : (N, 3) float64
        Points relative to a point of the axis, mm.
    axis : (3,) float64
        Unit axis direction.
    radius : float

    Returns
    -------
    (N,) float64
    """
    d = np.ascontiguousarray(d, np.float64)
    axis = np.ascontiguousarray(axis, np.float64)
    out = np.empty(len(d))
    _axis_distance(d, d @ axis, axis, float(radius), out)
    return out


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _sift_down(heap, i, n):  # pragma: no cover - compiled
    # max-heap of heap[:n]
    while True:
        left = 2 * i + 1
        if left >= n:
            return
        big = left
        if left + 1 < n and heap[left + 1] > heap[left]:
            big = left + 1
        if heap[big] > heap[i]:
            heap[i], heap[big] = heap[big], heap[i]
            i = big
        else:
            return


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _smallest(x, sign, k, heap, n):  # pragma: no cover - compiled
    # push sign·x into a max-heap of the k smallest (heap[:n] filled); new n, −1 on a NaN
    for i in range(x.shape[0]):
        v = sign * x[i]
        if np.isnan(v):
            return -1
        if n < k:
            heap[n] = v
            n += 1
            j = n - 1
            while j > 0 and heap[(j - 1) // 2] < heap[j]:
                heap[(j - 1) // 2], heap[j] = heap[j], heap[(j - 1) // 2]
                j = (j - 1) // 2
        elif v < heap[0]:
            heap[0] = v
            _sift_down(heap, 0, k)
    return n


def _order_statistic_lerp(a, b, virtual, previous):
    """NumPy's ``_lerp`` of the 'linear' quantile (float64 scalars)."""
    gamma = virtual - np.float64(previous)
    diff = b - a
    return b - diff * (1 - gamma) if gamma >= 0.5 else a + diff * gamma


def tail_percentile(x, q: float) -> float:
    """``np.percentile(x, q)`` (method 'linear') for `q` near 0 or 100, without sorting `x`.

    The two order statistics the quantile interpolates are found by keeping the few
    smallest (or largest) values in a heap, in one pass; the interpolation is NumPy's, so the
    result is the same to the last bit. Falls back to ``np.percentile`` when more than 1 %
    of the values would be kept, or `x` holds a NaN.

    Parameters
    ----------
    x : (N,) float64, or a sequence of such arrays
        Any stride; a sequence counts as the concatenation of its arrays.
    q : float
        Percentile, 0 … 100.

    Returns
    -------
    float
    """
    parts = [np.asarray(p, np.float64) for p in x] if isinstance(x, (list, tuple)) \
        else [np.asarray(x, np.float64)]
    n = sum(len(p) for p in parts)
    virtual = (n - 1) * np.true_divide(np.float64(q), 100)
    low = virtual < 0.5 * (n - 1)
    # ranks from the nearer end; the upper tail counts from the top (sign −1)
    rank = virtual if low else (n - 1) - virtual
    k = int(np.floor(rank)) + 2 if np.isfinite(rank) else 0
    if n < 2 or not 0 <= q <= 100 or k > max(16, n // 100):
        return float(np.percentile(np.concatenate(parts), q))
    heap = np.empty(k)
    filled = 0
    for p in parts:
        filled = _smallest(p, 1.0 if low else -1.0, k, heap, filled)
        if filled < 0:
            return float(np.percentile(np.concatenate(parts), q))
    heap.sort()
    previous = int(np.floor(virtual))
    if virtual >= n - 1:
        return float(-heap[0])
    if low:
        a, b = heap[previous], heap[previous + 1]
    else:
        # the sorted values at previous, previous + 1: the (n−1−previous)-th and
        # (n−2−previous)-th largest
        a, b = -heap[n - 1 - previous], -heap[n - 2 - previous]
    return float(_order_statistic_lerp(np.float64(a), np.float64(b), virtual, previous))


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _row_steps(xyz, valid, out):  # pragma: no cover - compiled
    n = 0
    for i in range(xyz.shape[0]):
        for j in range(xyz.shape[1] - 1):
            if valid[i, j + 1] and valid[i, j]:
                d0 = xyz[i, j + 1, 0] - xyz[i, j, 0]
                d1 = xyz[i, j + 1, 1] - xyz[i, j, 1]
                d2 = xyz[i, j + 1, 2] - xyz[i, j, 2]
                out[n] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                n += 1
    return n


def row_steps(xyz, valid) -> np.ndarray:
    """Distances between horizontally adjacent valid points, row-major.

    ``|np.diff(xyz, axis=1)|[valid[:, 1:] & valid[:, :-1]]`` in float32, without the
    full-size differences.

    Parameters
    ----------
    xyz : (H, W, 3) float32
    valid : (H, W) bool

    Returns
    -------
    (N,) float32
    """
    xyz = np.ascontiguousarray(xyz, np.float32)
    out = np.empty(xyz.shape[0] * max(xyz.shape[1] - 1, 0), np.float32)
    n = _row_steps(xyz, np.ascontiguousarray(valid, np.bool_), out)
    return out[:n]


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _valid_points(mask, xyz, out):  # pragma: no cover - compiled
    for i in range(xyz.shape[0]):
        for j in range(xyz.shape[1]):
            out[i, j] = mask[i, j] and np.isfinite(xyz[i, j, 0] + xyz[i, j, 1] + xyz[i, j, 2])


def valid_points(mask, xyz) -> np.ndarray:
    """``mask & isfinite(x + y + z)`` of a grid of float32 points, in one pass.

    Parameters
    ----------
    mask : (H, W) bool
    xyz : (H, W, 3) float32

    Returns
    -------
    (H, W) bool
    """
    out = np.empty(mask.shape, np.bool_)
    _valid_points(np.ascontiguousarray(mask, np.bool_), np.ascontiguousarray(xyz, np.float32),
                  out)
    return out


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _deviation(v, mean, valid, d, dd, ok):  # pragma: no cover - compiled
    for i in range(v.shape[0]):
        for j in range(v.shape[1]):
            x = v[i, j] - mean[i, j]
            d[i, j] = x
            dd[i, j] = x * x
            ok[i, j] = valid[i, j] and np.isfinite(x)


def deviation(v, mean, valid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``d = v − mean``, ``d²`` and ``valid & isfinite(d)`` (float32), in one pass."""
    d = np.empty(v.shape, np.float32)
    dd = np.empty(v.shape, np.float32)
    ok = np.empty(v.shape, np.bool_)
    _deviation(np.ascontiguousarray(v, np.float32), np.ascontiguousarray(mean, np.float32),
               np.ascontiguousarray(valid, np.bool_), d, dd, ok)
    return d, dd, ok


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _normalized(d, mean_square, valid, floor, out):  # pragma: no cover - compiled
    nan = np.float32(np.nan)
    for i in range(d.shape[0]):
        for j in range(d.shape[1]):
            if not valid[i, j]:
                out[i, j] = nan
                continue
            rms = np.sqrt(mean_square[i, j])
            out[i, j] = d[i, j] / (rms if np.isnan(rms) else max(rms, floor))


def normalized(d, mean_square, valid, floor: float) -> np.ndarray:
    """``where(valid, d / maximum(sqrt(mean_square), floor), nan)`` in float32, one pass."""
    out = np.empty(d.shape, np.float32)
    _normalized(np.ascontiguousarray(d, np.float32), np.ascontiguousarray(mean_square, np.float32),
                np.ascontiguousarray(valid, np.bool_), np.float32(floor), out)
    return out


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _layer_outputs(modulation, cos, feather, valid, signal, cos_min, r0, c0, out_signal,
                   out_weight):  # pragma: no cover - compiled
    nan = np.float32(np.nan)
    zero = np.float32(0.0)
    for i in range(signal.shape[0]):
        for j in range(signal.shape[1]):
            mod = _nan_to_num32(modulation[i, j])
            mod = mod if mod >= 0 else zero
            c = _nan_to_num32(cos[i, j])
            w = mod * (c * c) * feather[i, j]
            if np.float64(c) < cos_min:
                w = zero
            s = signal[i, j]
            out_signal[r0 + i, c0 + j] = s if valid[i, j] else nan
            out_weight[r0 + i, c0 + j] = w if (valid[i, j] and np.isfinite(s)) else zero


def layer_outputs(modulation, cos, feather, valid, signal, cos_min: float, box, shape):
    """The ridge signal and blending weight of ``camera_layer`` on the full camera grid.

    ``weight = clip(nan_to_num(modulation), 0) · nan_to_num(cos)² · feather``, 0 where the
    cosine is below `cos_min` (compared in float64); the signal NaN off `valid`, the weight 0
    off ``valid & isfinite(signal)``; both float32, on the `box` of a grid of `shape`.
    """
    out_signal = np.full(shape, np.nan, dtype=np.float32)
    out_weight = np.zeros(shape, dtype=np.float32)
    _layer_outputs(np.ascontiguousarray(modulation, np.float32),
                   np.ascontiguousarray(cos, np.float32), np.ascontiguousarray(feather, np.float32),
                   np.ascontiguousarray(valid, np.bool_), np.ascontiguousarray(signal, np.float32),
                   np.float64(cos_min), box[0].start, box[1].start, out_signal, out_weight)
    return out_signal, out_weight


@numba.njit(cache=_CACHE, nogil=True, error_model="numpy")
def _ratio(num, den, out):  # pragma: no cover - compiled
    nan = np.float32(np.nan)
    least = np.float32(1e-3)
    for i in range(num.shape[0]):
        for j in range(num.shape[1]):
            d = den[i, j]
            for k in range(num.shape[2]):
                out[i, j, k] = num[i, j, k] / d if d > least else nan


def ratio(num, den) -> np.ndarray:
    """``where(den > 1e-3, num / den, nan)`` in float32 (``den`` broadcast over channels).

    Parameters
    ----------
    num : (H, W, k) float32
    den : (H, W) float32

    Returns
    -------
    (H, W, k) float32
    """
    out = np.empty(num.shape, np.float32)
    _ratio(np.ascontiguousarray(num, np.float32), np.ascontiguousarray(den, np.float32), out)
    return out
