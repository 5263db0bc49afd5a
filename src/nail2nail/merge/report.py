"""Merge report: the merge error of camera pairs and the fused super scan, written to a directory.

:func:`write_merge` is the whole merge step on scans already in memory; ``nail2nail merge``
(which reads a scan directory with :func:`nail2nail.io.scans.load_scans`) and
:func:`nail2nail.pipeline.run_demo` call it.
"""

from __future__ import annotations

import importlib
import itertools
import os
import time
import warnings
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from nail2nail._progress import progress_bar
from nail2nail._timing import StepClock
from nail2nail._validation import as_int
from nail2nail.frames import _check_transform, superscan_in_frame
from nail2nail.io._atomic import atomic_directory, relocate_paths, write_npz
from nail2nail.io._json import write_json
from nail2nail.merge.correspondence import (
    CorrespondenceCache,
    check_pair_by,
    correspond,
    restrict_pairs,
    same_pixel_pairs,
)
from nail2nail.merge.fusion import (
    fuse_scans,
    pair_kind,
    scan_groups,
    write_super_mat5,
    write_super_ply,
)
from nail2nail.merge.mesh import boundary_figures, mesh_topology
from nail2nail.merge.mesh import seamless_mesh as seamless

__all__ = ["RENDER_VIEWS", "default_pairs", "parse_pairs", "write_merge"]

#: Views of the super-scan renders: name -> (elev, azim) in degrees.
RENDER_VIEWS = {"front": (10.0, 0.0), "side": (15.0, 70.0)}


def parse_pairs(text: str | None, n_cameras: int) -> list[tuple[int, int]]:
    """Camera pairs from ``"0-1,1-2"`` (parent-child indices in scan order).

    ``None`` gives the neighbouring pairs ``0-1, 1-2, …``; an empty or blank string is refused
    (an empty shell variable, say, is not a request for the default).

    Examples
    --------
    >>> parse_pairs("0-1,2-1", 3)
    [(0, 1), (2, 1)]
    >>> parse_pairs(None, 3)
    [(0, 1), (1, 2)]
    """
    if text is None:
        return [(i, i + 1) for i in range(n_cameras - 1)]
    if not text.strip():
        raise ValueError(f"--pairs: expected PARENT-CHILD camera indices like 0-1,1-2, got "
                         f"{text!r}")
    pairs = []
    for item in text.split(","):
        parts = item.strip().split("-")
        try:
            i, j = (int(p) for p in parts)
        except ValueError:
            raise ValueError(f"--pairs: expected PARENT-CHILD camera indices like 0-1, got "
                             f"{item.strip()!r}") from None
        if not (0 <= i < n_cameras and 0 <= j < n_cameras) or i == j:
            raise ValueError(f"--pairs: {item.strip()!r} must name two different cameras "
                             f"among 0..{n_cameras - 1}")
        pairs.append((i, j))
    return pairs


def _save_mapping(path: Path, corr) -> Path:
    # float32 (µm-level values at mm scale keep ~7 digits) halves the files; the integer and
    # string arrays (the mapping matrix is mostly −1) deflate at level 1, the float noise is
    # stored: on the full-resolution finger 13 MB in 0.07 s, against 11 MB in 1.3 s all at zlib 6
    arrays = {
        "mapping": corr.mapping, "parent_rc": corr.parent_rc.astype(np.int32),
        "child_rc": corr.child_rc.astype(np.float32),
        "xyz_parent": corr.xyz_parent.astype(np.float32),
        "xyz_child": corr.xyz_child.astype(np.float32),
        "distance_mm": corr.distance_mm.astype(np.float32),
        "residual_px": corr.residual_px.astype(np.float32),
    }
    if corr.rejected is not None:  # the rejected pairs too: nothing is hidden
        r = corr.rejected
        arrays |= {
            "rejected_parent_rc": r.parent_rc.astype(np.int32),
            "rejected_child_rc": r.child_rc.astype(np.float32),
            "rejected_distance_mm": r.distance_mm.astype(np.float32),
            "rejected_reason": np.asarray(r.reason, dtype=str),
        }
    return write_npz(path, arrays, compress={
        name: 1 for name, a in arrays.items() if a.dtype.kind in "iuU"})


def write_merge(
    scans,
    out: str | os.PathLike,
    *,
    pairs: list[tuple[int, int]] | None = None,
    stride: int = 1,
    max_residual_px: float = 0.5,
    border_px: int = 2,
    figures: bool = True,
    super_scan: bool = True,
    data: bool = True,
    mat5: bool = True,
    progress: bool = False,
    frame: str = "world",
    transform=None,
    final_dir: str | os.PathLike | None = None,
    seamless_mesh: bool = False,
    projectors=None,
    cameras=None,
    pair_by: str = "auto",
) -> dict:
    """Merge error of each camera pair and the fused super scan, written under `out`.

    Per pair ``P-C``: ``merge_P-C_mapping.npz`` (the thesis's mapping matrix, the kept pairs
    and the rejected ones with their reason: ``rejected_parent_rc``, ``rejected_child_rc``,
    ``rejected_distance_mm``, ``rejected_reason``),
    and with `figures` ``merge_P-C_heatmap.png``, ``_histogram.png``, ``_points3d.png``,
    ``_marked.png``. With `super_scan`: ``super.ply``, the super mat5 ``superC.bmp`` …
    (:func:`nail2nail.merge.fusion.super_mat5_scan`), and with `figures` ``super_front.png``,
    ``super_side.png``. Also ``merge.json``, the returned summary.

    Parameters
    ----------
    scans : sequence of Scan
        One per camera, in camera order (world mm).
    out : path-like
        Output directory, written as a whole (:func:`nail2nail.io._atomic.atomic_directory`):
        an earlier merge there is replaced only once the new one is complete; a non-empty
        directory without ``merge.json`` is refused.
    pairs : list of (int, int), optional
        ``(parent, child)`` scan indices; default the neighbours ``(0, 1), (1, 2), …``; with
        several projectors, the neighbouring cameras of each projector and, for each camera,
        its neighbouring projectors (:func:`default_pairs`).
    stride, max_residual_px, border_px
        The merge error's sampling and tests, as :func:`nail2nail.merge.correspond`;
        `max_residual_px` (panel px) also the fusion's. With `super_scan` the pairs are the
        fusion's own (:func:`nail2nail.merge.fusion.fuse_scans` matches every ordered pair
        once, every pixel, a 1-pixel border), narrowed to `border_px` and `stride`
        (:func:`nail2nail.merge.restrict_pairs`) rather than searched again; without it,
        searched here.
    figures : bool
        Write the PNG figures.
    super_scan : bool
        Fuse all scans into the super scan and write it.
    data : bool
        Write the data files: the mapping files and the super scan's PLY and mat5. Without
        them, ``merge.json`` and the figures only (a comparison run that keeps its numbers
        and pictures, not megabytes of points).
    mat5 : bool
        With `data`, also write the super mat5 (the legacy grid files: about 95 MB for three
        1280 × 1024 cameras; the PLY holds the same points in a third of that).
    progress : bool
        Progress bar on stderr (a terminal only: :mod:`nail2nail._progress`): one step per
        camera pair, then the fusion, writing the super scan and waiting for the figures.
    frame, transform
        The frame the super scan's PLY and mat5 are written in, and its ``T_frame_world``
        (:func:`nail2nail.frames.frame_transform`); everything is computed in the world frame
        (figures included). Recorded as ``super_scan.frame`` and ``super_scan.T_frame_world``.
    final_dir : path-like, optional
        Where `out` will be once a caller renames the directory that holds it (``process``
        writes into a temporary job directory): the paths in ``merge.json`` and in the returned
        summary name the files there. Default: `out`.
    seamless_mesh : bool
        Mesh ``super.ply`` as one surface (:func:`nail2nail.merge.mesh.seamless_mesh`: the
        seams between the cameras' grids closed; about 10 s for a full-resolution finger)
        instead of the cameras' grids side by side; ``super_scan.mesh`` in ``merge.json``
        gives its topology (:func:`~nail2nail.merge.mesh.mesh_topology`) and, under
        ``boundary``, where its boundary lies (:func:`~nail2nail.merge.mesh.boundary_figures`:
        the outline, the holes inside it). The super mat5 is
        the cameras' grids either way.
    projectors, cameras : sequence of int, optional
        A rig of several projectors: per scan, its projector's and its camera's index
        (:func:`nail2nail.io.scans.load_scan_dirs`). A pair of one projector is matched in its
        projector space, a pair of one camera at the same pixel
        (:func:`nail2nail.merge.same_pixel_pairs`); a pair sharing neither is refused. Each
        pair's summary names its ``kind``: ``"projector"`` or ``"camera"``.
    pair_by : {"auto", "xpyp", "xp", "yp"}
        What pairs two scans of one projector (:func:`nail2nail.merge.correspond`): both
        projector coordinates (the thesis), or one coordinate and the surface along it; by
        default the coordinate both scans were triangulated from when it is one (a stabilised
        moving capture), both otherwise. Each pair's summary names it (``pair_by``;
        ``"pixel"`` for a pair of one camera).

    Returns
    -------
    dict
        ``{"out", "merge": {"P-C": {parent, child, stride, pair_by, sampled, pairs, dropped,
        rejected, distance_mm: {median, mean, rms, p90, p95, max, frac_below_0_05}, squared_mm2,
        before_rejection: {pairs, distance_mm, squared_mm2}, files}}, "super_scan": {...} |
        None, "seconds": {correspond, fuse, write, figures}, "outputs": [paths]}``
        (``fuse``: the fusion, its correspondences included; ``correspond``: the pairs'
        statistics; ``figures``: the wait for the figures drawn beside the merge).
        ``distance_mm`` is over the kept pairs; ``rejected`` counts the pairs rejected per reason
        (:data:`nail2nail.merge.REJECT_REASONS`) and ``before_rejection`` gives the
        statistics of all pairs found. The super scan's
        ``rejected_pairs`` and ``points_rejected`` count what fusion left out; its ``mesh``
        is the seamless mesh's topology and seconds with `seamless_mesh`, else None.
    """
    scans = list(scans)
    stride = as_int(stride, "stride", minimum=1)
    groups = scan_groups(len(scans), projectors, cameras)
    pairs = (default_pairs(*groups) if pairs is None
             else [(int(p[0]), int(p[1])) for p in pairs])
    for i, j in pairs:
        if not (0 <= i < len(scans) and 0 <= j < len(scans)) or i == j:
            raise ValueError(f"pairs: ({i}, {j}) is not a pair of two of the {len(scans)} scans")
        if pair_kind(groups, i, j) is None:
            raise ValueError(f"pairs: {scans[i].name!r} and {scans[j].name!r} share neither a "
                             "projector nor a camera")
    max_residual_px = float(max_residual_px)
    if not max_residual_px > 0:
        raise ValueError(f"max_residual_px: expected a positive number, got {max_residual_px}")
    border_px = as_int(border_px, "border_px", minimum=1)  # as correspond: checked up front
    check_pair_by(pair_by)

    transform = np.eye(4) if transform is None else _check_transform(transform)
    out = Path(out)
    with atomic_directory(out, marker="merge.json") as tmp:
        summary = _write_merge(scans, tmp, pairs=pairs, stride=stride,
                               max_residual_px=max_residual_px, border_px=border_px,
                               figures=figures, super_scan=super_scan, data=data,
                               mat5=mat5, progress=progress, frame=frame, transform=transform,
                               seamless_mesh=seamless_mesh, groups=groups,
                               pair_by=pair_by)
        summary = relocate_paths(summary, str(tmp), str(out if final_dir is None else final_dir))
        write_json(tmp / "merge.json", summary)
    return summary


def default_pairs(projectors, cameras) -> list[tuple[int, int]]:
    """The merge report's pairs of a rig's scans: per projector its neighbouring cameras
    (in camera order), then per camera its neighbouring projectors (in projector order).

    For one projector and a camera per scan, the neighbours ``(0, 1), (1, 2), …``.

    Examples
    --------
    >>> default_pairs([0, 0, 0], [0, 1, 2])
    [(0, 1), (1, 2)]
    >>> default_pairs([0, 0, 1, 1], [0, 1, 0, 1])
    [(0, 1), (2, 3), (0, 2), (1, 3)]
    """
    proj, cams = list(projectors), list(cameras)
    pairs: list[tuple[int, int]] = []
    for key, other in ((proj, cams), (cams, proj)):
        for group in dict.fromkeys(key):
            members = sorted((other[i], i) for i in range(len(key)) if key[i] == group)
            pairs.extend((a[1], b[1]) for a, b in itertools.pairwise(members))
    return pairs


#: A camera pair keeping less than this fraction of the pairs found gets a warning.
MIN_KEPT_FRACTION = 0.2


def _check_kept(corr, stats: dict | None = None) -> None:
    """0 pairs kept of a camera pair: an error; fewer than :data:`MIN_KEPT_FRACTION`: a warning.

    `stats` is ``corr.statistics()`` if already computed."""
    stats = corr.statistics() if stats is None else stats
    kept, found = int(stats["pairs"]), int(stats["before_rejection"]["pairs"])
    pair = f"{corr.parent_name} ↔ {corr.child_name}"
    if kept == 0:
        raise ValueError(f"merge {pair}: 0 corresponding points kept of {found} found "
                         f"({stats['sampled']} sampled): the scans share no usable surface")
    if kept < MIN_KEPT_FRACTION * found:
        warnings.warn(f"merge {pair}: keeps {kept} of {found} corresponding points found "
                      f"({100 * kept / found:.1f} %, less than {100 * MIN_KEPT_FRACTION:.0f} %)",
                      UserWarning, stacklevel=4)


def _write_merge(scans, out: Path, *, pairs, stride, max_residual_px, border_px, figures,
                 super_scan, data, mat5, progress, frame="world", transform=None,
                 seamless_mesh=False, groups=None, pair_by="auto") -> dict:
    """Write every file of :func:`write_merge` but ``merge.json`` under `out`; the summary.

    The figures are drawn on one thread beside the merge: matplotlib needs the GIL, the
    correspondence and fusion kernels mostly run without it, so drawing overlaps them.
    """
    drawing = None
    if figures:
        drawing = ThreadPoolExecutor(1, thread_name_prefix="merge-figures")
        drawing.submit(importlib.import_module, f"{__package__}.figures")  # matplotlib: ~0.5 s
    try:
        summary = _merge_files(scans, out, pairs=pairs, stride=stride,
                               max_residual_px=max_residual_px, border_px=border_px,
                               super_scan=super_scan, data=data, mat5=mat5,
                               progress=progress, drawing=drawing, frame=frame,
                               transform=transform, seamless_mesh=seamless_mesh,
                               groups=groups or scan_groups(len(scans)), pair_by=pair_by)
    except BaseException:
        if drawing is not None:
            drawing.shutdown(wait=True, cancel_futures=True)
        raise
    if drawing is not None:
        drawing.shutdown(wait=True)
    return summary


def _merge_files(scans, out: Path, *, pairs, stride, max_residual_px, border_px, super_scan,
                 data, mat5, progress, drawing, groups, frame="world", transform=None,
                 seamless_mesh=False, pair_by="auto") -> dict:
    """:func:`_write_merge` with the figures drawn on `drawing` (an executor; None: none)."""
    summary: dict = {"out": str(out), "merge": {}, "super_scan": None, "outputs": []}
    lap = StepClock()
    for part in ("correspond", "fuse", "write", "figures"):  # every part, in this order
        lap.seconds[part] = 0.0

    drawn: list[tuple[dict, Future | dict]] = []  # files of a pair or super scan, figures
    mat5_files: list[Path] = []
    bar = progress_bar(desc="merge", unit="step", enabled=progress,
                       total=len(pairs) + 2 * bool(super_scan) + 1)
    sup = None
    if super_scan:
        # the fusion matches every ordered pair once; the statistics read those pairs
        bar.set_postfix_str("fuse")
        sup = fuse_scans(scans, max_residual_px=max_residual_px, projectors=groups[0],
                         cameras=groups[1], pair_by=pair_by)
        lap("fuse")
        bar.update()
    else:
        cache = CorrespondenceCache()  # each scan's masks, cosine and grid, once for all pairs
    for i, j in pairs:
        bar.set_postfix_str(f"pair {i}-{j}", refresh=False)
        if sup is not None:
            corr = restrict_pairs(sup.correspondences[i, j], scans[i], scans[j],
                                  border_px=border_px, stride=stride,
                                  parent_valid=sup.valid_masks[i],
                                  child_valid=sup.valid_masks[j])
        elif pair_kind(groups, i, j) == "projector":
            corr = correspond(scans[i], scans[j], stride=stride,
                              max_residual_px=max_residual_px, border_px=border_px,
                              cache=cache, pair_by=pair_by)
        else:
            corr = same_pixel_pairs(scans[i], scans[j], stride=stride, border_px=border_px,
                                    cache=cache)
        key = f"{i}-{j}"
        stats = corr.statistics()
        _check_kept(corr, stats)
        lap("correspond")
        files = ({"mapping": str(_save_mapping(out / f"merge_{key}_mapping.npz", corr))}
                 if data else {})
        lap("write")
        if drawing is not None:
            drawn.append((files, drawing.submit(
                _pair_figures, corr, scans[i].albedo, scans[j].albedo, out, key, stride)))
        summary["merge"][key] = {**stats, "kind": pair_kind(groups, i, j), "files": files}
        del corr
        bar.update()
    if sup is None:
        del cache
    else:
        bar.set_postfix_str("write")
        if drawing is not None:
            renders = {}
            for view, (elev, azim) in RENDER_VIEWS.items():
                renders[f"render_{view}"] = drawing.submit(
                    _render, sup.vertices, out / f"super_{view}.png", sup.vertex_normals,
                    sup.colors, elev, azim, f"super scan ({view}): {sup.n_vertices} points")
        files = {}
        mesh = None
        faces = None
        if seamless_mesh:  # its time is part of "write", and its own in the summary
            start = time.perf_counter()
            faces = seamless(sup.vertices, normals=sup.vertex_normals)
            mesh = {"seamless": True, **mesh_topology(faces, sup.n_vertices),
                    "boundary": boundary_figures(faces, sup.vertices),
                    "seconds": round(time.perf_counter() - start, 3)}
        if data:

            written = sup if transform is None else superscan_in_frame(sup, transform)
            files["ply"] = str(write_super_ply(out / "super.ply", written, faces=faces))
            if mat5:
                mat5_files = write_super_mat5(out / "super", written)
                files["mat5"] = str(out / "super")
            del written
        # "faces": those written to super.ply (the seamless mesh's, when asked for)
        summary["super_scan"] = {**sup.summary(), **({"faces": mesh["faces"]} if mesh else {}),
                                 "mesh": mesh, "files": files, "frame": frame,
                                 "T_frame_world": (np.eye(4) if transform is None
                                                   else transform).tolist()}
        if drawing is not None:
            drawn.append((files, renders))
        del sup
        lap("write")
        bar.update()
    bar.set_postfix_str("figures" if drawing is not None else "done")
    for files, figures in drawn:  # wait for the figures, in order; a failure raises here
        if isinstance(figures, dict):
            files.update({k: str(f.result()) for k, f in figures.items()})
        else:
            files.update({k: str(v) for k, v in figures.result().items()})
    lap("figures")  # what is left of the drawing once the merge is done
    bar.update()
    bar.close()
    summary["seconds"] = {k: round(v, 3) for k, v in lap.seconds.items()}
    outputs = summary["outputs"]
    for m in summary["merge"].values():
        outputs.extend(m["files"].values())
    if summary["super_scan"] is not None:
        outputs.extend(str(p) for p in mat5_files)
        outputs.extend(v for k, v in summary["super_scan"]["files"].items() if k != "mat5")
    outputs.append(str(out / "merge.json"))
    return summary


def _pair_figures(corr, parent_albedo, child_albedo, out: Path, key: str, stride: int) -> dict:
    """The four figures of one camera pair: ``{heatmap, histogram, points3d, marked}`` paths."""
    # Deferred: merge.figures imports matplotlib (0.9 s), needed only when figures are drawn.
    from nail2nail.merge.figures import (
        plot_correspondence_images,
        plot_correspondences_3d,
        plot_merge_heatmap,
        plot_merge_histogram,
    )

    every = max(20 // stride, 1) * stride
    return {
        "heatmap": plot_merge_heatmap(corr, out / f"merge_{key}_heatmap.png",
                                      background=parent_albedo),
        "histogram": plot_merge_histogram(
            corr.distance_mm, out / f"merge_{key}_histogram.png",
            title=f"{corr.parent_name} ↔ {corr.child_name}: merge error"),
        "points3d": plot_correspondences_3d(corr, out / f"merge_{key}_points3d.png",
                                            every=every),
        "marked": plot_correspondence_images(corr, parent_albedo, child_albedo,
                                             out / f"merge_{key}_marked.png", every=every),
    }


def _render(vertices, path: Path, normals, colors, elev, azim, title) -> Path:
    """:func:`nail2nail.merge.figures.render_points` of the super scan."""
    from nail2nail.merge.figures import render_points  # deferred, as in _pair_figures

    return render_points(vertices, path, normals=normals, colors=colors, elev=elev, azim=azim,
                         title=title)
