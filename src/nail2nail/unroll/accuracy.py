"""Geometric accuracy of a rolled print against the true skin coordinates of its pixels.

Used on the virtual scanner (its ``truth/camN.npz`` gives, per camera pixel, the rolled-print
coordinates ``param_u, param_v`` of the true surface point the pixel sees) or on any rig with a
known reference. The print-plane coordinates of every print pixel are paired with the mean true
skin coordinates of the camera pixels that land in it; one best-fit similarity transform
(rotation, uniform scale, translation; no reflection) maps the print onto the truth, and

- the **residual displacement** is the distance left after it, mm;
- the **local scale error** is ``max(|σ1 − 1|, |σ2 − 1|)`` with ``σ`` the singular values of
  the local Jacobian of the print → truth map divided by the similarity's scale (finite
  differences over `baseline_mm`), as a fraction;

following the geometric-accuracy idea of the FBI/NIST image quality specification for rolled
equivalents (±1.5 % scale).
"""

from __future__ import annotations

import numpy as np

from nail2nail.unroll.quality import block_quality
from nail2nail.unroll.ridges import scan_valid
from nail2nail.unroll.rolled import RolledPrint

__all__ = ["geometric_accuracy", "similarity_fit"]


def similarity_fit(src, dst) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ≈ scale · R @ src + t``, without reflection.

    Umeyama, *Least-squares estimation of transformation parameters between two point
    patterns*, IEEE TPAMI 13(4), 376–380, 1991, doi:10.1109/34.88573.

    Parameters
    ----------
    src, dst : (N, 2) float
        Corresponding points (e.g. print plane and true skin coordinates, mm), N ≥ 2.

    Returns
    -------
    scale : float
    R : (2, 2) float
        Rotation, ``det R = +1``.
    t : (2,) float

    Examples
    --------
    >>> src = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    >>> scale, R, t = similarity_fit(src, 3 * src + [1, 2])
    >>> round(scale, 9), np.round(t, 9).tolist()
    (3.0, [1.0, 2.0])
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    u, s, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.ones(2)
    if np.linalg.det(u @ vt) < 0:
        d[-1] = -1
    rot = u @ np.diag(d) @ vt
    scale = float((s * d).sum() / (a * a).sum(axis=1).mean())
    return scale, rot, md - scale * rot @ ms


def geometric_accuracy(rolled: RolledPrint, scans, truth_uv, *, baseline_mm: float = 1.0,
                       truth_sampler=None, maps: bool = False) -> dict:
    """Compare a print with the true skin coordinates of its pixels.

    Parameters
    ----------
    rolled : RolledPrint
    scans : sequence of Scan
        The scans the print was made from.
    truth_uv : sequence of ((H, W) float, (H, W) float)
        Per scan, the true print-plane coordinates ``(u, v)`` (mm; ``u`` around the finger
        towards ``axis × pad``, ``v`` towards the tip, the orientation of the print plane's
        ``(s, t)``) of the surface point each camera pixel sees; NaN where unknown.
    baseline_mm : float
        Finite-difference baseline of the local Jacobian, mm.
    maps : bool
        Also return the per-pixel maps of the scale error and the displacement.
    truth_sampler : callable, optional
        ``(u, v) -> ridge field`` of the true print (positive on crests). If given, the true
        print is rendered on the print's grid and the local ridge periods of both are compared
        block by block.

    Returns
    -------
    dict
        ``similarity`` (scale, rotation in degrees, reflected: False), ``scale_error``
        (median, p95, max of the local scale error, fraction), ``displacement_mm`` (median,
        p95, max of the residual), ``pixels`` compared; with `truth_sampler`, ``period_ratio``
        (median and p90 of |ratio − 1| of the periods of 3.2 mm blocks, print / truth) and
        ``truth_on_grid`` ((H, W) uint8, the true print through the similarity); with `maps`,
        ``scale_error_map`` and ``displacement_map`` ((H, W) float32, NaN where not measured).
    """
    grid = rolled.grid
    h, w = grid.shape
    st_all, uv_all = [], []
    for scan, (tu, tv) in zip(scans, truth_uv, strict=True):
        tu = np.asarray(tu, dtype=np.float64)
        tv = np.asarray(tv, dtype=np.float64)
        ok = scan_valid(scan) \
            & np.isfinite(tu) & np.isfinite(tv)
        st_all.append(rolled.flattening(np.asarray(scan.xyz, dtype=np.float64)[ok]))
        uv_all.append(np.stack([tu[ok], tv[ok]], -1))
    st = np.concatenate(st_all)
    uv = np.concatenate(uv_all)
    r, c = grid.pixel(st)
    ri, ci = np.rint(r).astype(np.intp), np.rint(c).astype(np.intp)
    inside = (ri >= 0) & (ri < h) & (ci >= 0) & (ci < w)
    inside[inside] = rolled.mask[ri[inside], ci[inside]]
    st, uv, ri, ci = st[inside], uv[inside], ri[inside], ci[inside]
    scale, rot, t = similarity_fit(st, uv)
    resid = np.linalg.norm(uv - (scale * st @ rot.T + t), axis=1)
    # per print pixel: the mean residual of the camera pixels in it (the print's area counts,
    # not the cameras' sampling density)
    pix = ri * w + ci
    n_pix = np.bincount(pix, minlength=h * w)
    have = n_pix > 0
    flat = np.full(h * w, np.nan)
    flat[have] = np.bincount(pix, resid, minlength=h * w)[have] / n_pix[have]
    dmap = flat.reshape(h, w)
    displacement = dmap[np.isfinite(dmap)]
    # the local Jacobian of print (s, t) -> truth (u, v): a least-squares affine fit of the
    # samples in each block of baseline_mm × baseline_mm
    bs = np.floor(st / baseline_mm).astype(np.intp)
    bs -= bs.min(axis=0)
    nb = bs.max(axis=0) + 1
    block = bs[:, 1] * nb[0] + bs[:, 0]
    nblk = int(nb[0] * nb[1])
    # coordinates relative to each block's centroid: a well-conditioned fit per block
    x = st - np.stack([np.bincount(block, st[:, k], nblk)[block]
                       / np.bincount(block, minlength=nblk)[block] for k in range(2)], -1)
    cnt = np.bincount(block, minlength=nblk).astype(float)
    basis = [x[:, 0], x[:, 1], np.ones(len(x))]
    A = np.stack([np.stack([np.bincount(block, bi * bj, nblk) for bj in basis], -1)
                  for bi in basis], -2)  # (nblk, 3, 3)
    rhs = np.stack([np.stack([np.bincount(block, bi * uv[:, k], nblk) for bi in basis], -1)
                    for k in range(2)], -1)  # (nblk, 3, 2)
    # blocks mostly covered (an edge block's thin sliver gives an ill-conditioned fit)
    full = cnt >= 0.5 * np.median(cnt[cnt > 0])
    coef = np.linalg.solve(A[full], rhs[full])  # (B, 3, 2): rows s, t, 1
    J = np.transpose(coef[:, :2, :], (0, 2, 1))  # (B, 2, 2): d(u, v)/d(s, t)
    sv = np.linalg.svd(J, compute_uv=False) / scale
    err = np.max(np.abs(sv - 1), axis=1)
    if maps:
        eb = np.full(nblk, np.nan)
        eb[full] = err
        pr, pc = np.nonzero(rolled.mask)
        pst = grid.plane(pr, pc)
        pb = np.floor(pst / baseline_mm).astype(np.intp) - np.floor(
            st.min(axis=0) / baseline_mm).astype(np.intp)
        okb = (pb >= 0).all(axis=1) & (pb[:, 0] < nb[0]) & (pb[:, 1] < nb[1])
        emap = np.full((h, w), np.nan, np.float32)
        emap[pr[okb], pc[okb]] = eb[pb[okb, 1] * nb[0] + pb[okb, 0]]
    angle = float(np.degrees(np.arctan2(rot[1, 0], rot[0, 0])))
    out = {
        "pixels": len(resid),
        "similarity": {"scale": round(scale, 6), "rotation_deg": round(angle, 4),
                       "reflected": False},
        "scale_error": _stats(err),
        "scale_error_blocks": len(err),
        "displacement_mm": _stats(displacement),
    }
    if maps:
        out["scale_error_map"], out["displacement_map"] = emap, dmap.astype(np.float32)
    if truth_sampler is not None:
        # the true print on this print's grid, through the fitted similarity (what the
        # print would be with a perfect scan and a perfect unroll)
        gr, gc = np.nonzero(rolled.mask)
        tuv = scale * grid.plane(gr, gc) @ rot.T + t
        truth = np.full((h, w), 255.0)
        truth[gr, gc] = 127.5 - 127.5 * truth_sampler(tuv[:, 0], tuv[:, 1])
        block = round(3.2 / grid.pitch)
        # the print before its sharpening: the unsharp mask biases the measured period
        plain = rolled.plain if rolled.plain is not None else rolled.image
        qa = block_quality(plain, rolled.mask, block_px=block)
        qb = block_quality(truth, rolled.mask, block_px=block)
        both = (qa["clarity"] > 0.3) & (qb["clarity"] > 0.3)
        ratio = qa["period_px"][both] / qb["period_px"][both] / scale
        dev = np.abs(ratio - 1)
        out["period_ratio"] = {
            "blocks": int(both.sum()),
            "median_ratio": round(float(np.median(ratio)), 5) if ratio.size else None,
            "median_abs_deviation": round(float(np.median(dev)), 5) if ratio.size else None,
            "p90_abs_deviation": round(float(np.percentile(dev, 90)), 5) if ratio.size else None,
        }
        out["truth_on_grid"] = truth.astype(np.uint8)
    return out


def _stats(x) -> dict:
    x = np.asarray(x, dtype=np.float64)
    return {"median": round(float(np.median(x)), 5), "p95": round(float(np.percentile(x, 95)), 5),
            "max": round(float(np.max(x)), 5)}
