"""One seamless triangle mesh over the super scan's vertices, and its topology's figures.

The super scan's own mesh (:func:`nail2nail.merge.fusion.grid_mesh`) joins neighbouring pixels
of one camera's grid: where the ownership passes from one camera to the next the grids stop a
pixel apart, and the mesh is in pieces along every seam (issue 27: 67,827 boundary edges on the
demo finger, most of them seams). :func:`param_mesh` triangulates all the cameras' vertices
together in a plane that is a one-to-one image of the surface (Delaunay), and keeps the
triangles whose edges are short in 3D for their neighbourhood: the seams are closed, the
outline and the holes stay open, and the result is edge-manifold by construction (a subset of
a planar triangulation: no edge has more than two triangles), wound one way.

Such planes: the projector's (every vertex has projector coordinates, and the projector sees
each lit surface point once; the thesis merges the cameras in projector space for that
reason, chapter four), an unrolling's print plane (``nail2nail.unroll.flatten``), or
:func:`finger_plane`, a cylinder about the points' principal axis, unrolled (arc length ×
height). The projector's is far from isometric where the finger turns away from it (its
sides, the tip): the Delaunay triangles there are thin in 3D, and some are dropped as too
long. On the demo finger's 60,000-vertex copy (the report's): 644 boundary edges and 10
bow-tie vertices in projector coordinates, 196 and none in the rolled map's print plane, 241
and 6 in :func:`finger_plane`'s, the last two all on the outline. :func:`seamless_mesh` uses
:func:`finger_plane`, which needs nothing but the points.

:func:`mesh_topology` counts what a mesh tool checks: boundary edges, non-manifold edges and
vertices (bow-ties: more than two boundary edges at a vertex), windings that disagree.

Cost: a Delaunay triangulation of all the vertices (``scipy.spatial.Delaunay``, Qhull): about
10–15 s for the 676,000 vertices of the full-resolution demo finger (its boundary edges
67,828 → 7,161: the outline, at full resolution ragged, and 183 holes the fusion leaves;
2,484 with the holes of edges up to 1 mm closed, :data:`FILL_HOLES_MM`), 0.5 s for the
report's 60,000-vertex copy. So the super scan's PLY is meshed this way on request
(``merge --seamless-mesh``), the report's viewer always. :func:`boundary_figures` tells the
outline from the holes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["EDGE_FACTOR", "FILL_HOLES_MM", "NEIGHBOURS", "boundary_figures", "finger_plane",
           "mesh_topology", "param_mesh", "seamless_mesh"]

#: A triangle's longest edge may be this many local spacings (:func:`param_mesh`): on the
#: demo finger's 60,000-vertex copy (the report's) in :func:`finger_plane`, 2, 3 and 4
#: spacings of the 6th neighbour leave 896, 241 and 130 boundary edges (40, 6, 0 bow-tie
#: vertices): at 2, stripes of holes where a camera sees the skin at a grazing angle and
#: samples it sparsely; at 3 the outline alone; 4 bevels the outline's notches further
#: (a triangle may bridge 4 spacings of a real gap)
EDGE_FACTOR = 3.0
#: The neighbour whose distance is a vertex's local spacing (:func:`param_mesh`)
NEIGHBOURS = 6
#: :func:`seamless_mesh` closes the holes inside the outline whose edges are at most this long,
#: mm (:func:`param_mesh`'s `fill_holes_mm`)
FILL_HOLES_MM = 1.0


def param_mesh(points, uv, *, edge_factor: float = EDGE_FACTOR, neighbours: int = NEIGHBOURS,
               normals=None, fill_holes_mm: float = 0.0) -> np.ndarray:
    """Triangles over `points` from a Delaunay triangulation of their 2-D parameters `uv`.

    Parameters
    ----------
    points : (N, 3) float
        Vertices, world mm.
    uv : (N, 2) float
        A one-to-one (fold-free) image of the surface in a plane: the projector coordinates
        of the decoded phase (panel px), or an unrolling's print plane (mm). The nearer it is
        to isometric, the fewer thin triangles (see the module's note).
    edge_factor, neighbours : float, int
        A triangle is kept when its longest 3-D edge is at most `edge_factor` × the distance
        from one of its corners to that corner's `neighbours`-th nearest vertex: the local
        spacing, which grows where a camera sees the skin at a grazing angle and samples it
        sparsely. The triangulation's hull spans the outline's concave parts and the holes;
        the long triangles there go. At a vertex where two fans of the kept triangles touch
        (a bow-tie), the fans but the largest are cut away, so the mesh is vertex-manifold
        too (a small piece may be left as an island).
    normals : (N, 3) float, optional
        Vertex normals: the surface is wound counter-clockwise seen from the side most of them
        point to (one flip of every triangle, so the winding stays consistent). Default:
        counter-clockwise in the plane of `uv` (``u`` right, ``v`` up).
    fill_holes_mm : float
        Close the holes inside the surface whose triangles' edges are all at most this long
        (mm): the triangles dropped as too long that are not connected, through other dropped
        triangles, to the triangulation's hull (what lies outside the scanned outline) are
        put back, a hole at a time, when the hole's longest edge is within this. 0 (default):
        no hole is closed. The triangles are flat across the hole: they bridge missing points,
        they do not extend the scanned area.

    Returns
    -------
    faces : (F, 3) int64
        Vertex indices.

    Raises
    ------
    ValueError
        Shapes that disagree, non-finite values, fewer than ``neighbours + 1`` points, or a
        non-positive `edge_factor`.

    Examples
    --------
    >>> x, y = np.meshgrid(np.arange(4.0), np.arange(3.0))
    >>> pts = np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], -1)
    >>> param_mesh(pts, pts[:, :2], neighbours=2).shape
    (12, 3)
    """
    from scipy.spatial import Delaunay, cKDTree

    points = np.asarray(points, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or uv.shape != (len(points), 2):
        raise ValueError(f"points (N, 3) and uv (N, 2) expected, got {points.shape} and "
                         f"{uv.shape}")
    if not (np.isfinite(points).all() and np.isfinite(uv).all()):
        raise ValueError("points, uv: expected finite values")
    if len(points) <= neighbours:
        raise ValueError(f"points: more than neighbours={neighbours} needed, got {len(points)}")
    if not edge_factor > 0:
        raise ValueError(f"edge_factor: expected a positive factor, got {edge_factor}")
    tri = Delaunay(uv)
    faces = tri.simplices.astype(np.int64)
    spacing = cKDTree(points).query(points, k=neighbours + 1)[0][:, neighbours]
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    longest = np.sqrt(np.maximum.reduce([((a - b) ** 2).sum(1), ((b - c) ** 2).sum(1),
                                         ((c - a) ** 2).sum(1)]))
    keep = longest <= edge_factor * spacing[faces].max(axis=1)
    if fill_holes_mm > 0:
        keep |= _interior_holes(tri.neighbors, keep, longest, float(fill_holes_mm))
    faces = _without_bowties(faces[keep], len(points))
    p, q, r = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    clockwise = ((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1])
                 - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])) < 0
    faces[clockwise] = faces[clockwise][:, [0, 2, 1]]
    if normals is not None and len(faces):
        n = np.nan_to_num(np.asarray(normals, dtype=np.float64))
        a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
        facing = (np.cross(b - a, c - a) * (n[faces[:, 0]] + n[faces[:, 1]] + n[faces[:, 2]]))
        if np.count_nonzero(facing.sum(1) < 0) > len(faces) / 2:
            faces = faces[:, [0, 2, 1]]
    return faces


def _without_bowties(faces: np.ndarray, n_vertices: int, rounds: int = 4) -> np.ndarray:
    """`faces` less the triangles that make a vertex non-manifold: at a vertex where two or
    more fans of triangles touch (a bow-tie: more than two boundary edges meet there), the
    fans other than the largest are cut away from it. Repeated while cutting makes new ones
    (at most `rounds` times)."""
    for _ in range(rounds):
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        edges.sort(axis=1)
        key, count = np.unique(edges[:, 0] * n_vertices + edges[:, 1], return_counts=True)
        boundary = key[count == 1]
        ends = np.bincount(np.concatenate([boundary // n_vertices, boundary % n_vertices]),
                           minlength=n_vertices)
        bowties = np.flatnonzero(ends > 2)
        if not bowties.size:
            break
        order = np.argsort(faces.ravel(), kind="stable")
        first = np.searchsorted(faces.ravel()[order], bowties, side="left")
        last = np.searchsorted(faces.ravel()[order], bowties, side="right")
        drop = np.zeros(len(faces), dtype=bool)
        for v, lo, hi in zip(bowties, first, last, strict=True):  # a few defects, not pixels
            tris = order[lo:hi] // 3
            others = [tuple(int(w) for w in faces[t] if w != v) for t in tris]
            fan = list(range(len(tris)))  # union-find over triangles sharing an edge at v

            def root(i, fan=fan):
                while fan[i] != i:
                    fan[i] = fan[fan[i]]
                    i = fan[i]
                return i

            by_vertex: dict[int, int] = {}
            for i, pair in enumerate(others):
                for w in pair:
                    if w in by_vertex:
                        fan[root(i)] = root(by_vertex[w])
                    else:
                        by_vertex[w] = i
            roots = np.array([root(i) for i in range(len(tris))])
            sizes = np.bincount(roots, minlength=len(tris))
            drop[tris[roots != np.argmax(sizes)]] = True
        faces = faces[~drop]
    return faces


def _interior_holes(neighbors, keep, longest, max_edge_mm: float) -> np.ndarray:
    """(T,) bool: the dropped triangles of the holes inside the kept surface whose longest
    edge is at most `max_edge_mm` (see :func:`param_mesh`)."""
    import scipy.sparse
    import scipy.sparse.csgraph

    n = len(keep)
    dropped = ~keep
    i = np.repeat(np.arange(n), 3)
    j = neighbors.ravel()
    link = (j >= 0) & dropped[i] & dropped[np.maximum(j, 0)]
    graph = scipy.sparse.coo_matrix((np.ones(int(link.sum())), (i[link], j[link])),
                                    shape=(n, n))
    _, label = scipy.sparse.csgraph.connected_components(graph, directed=False)
    # a dropped region that reaches the hull is outside the scanned outline
    outside = np.zeros(label.max() + 1, dtype=bool)
    on_hull = dropped & (neighbors < 0).any(axis=1)
    outside[label[on_hull]] = True
    widest = np.zeros(label.max() + 1)
    np.maximum.at(widest, label[dropped], longest[dropped])
    fill = ~outside & (widest <= max_edge_mm)
    return dropped & fill[label]


def finger_plane(points) -> np.ndarray:
    """A one-to-one plane of a finger's scanned surface: a cylinder about it, unrolled.

    The axis is the points' first principal direction (through their centroid); the section's
    circle is fitted by least squares (Kåsa 1976) to the points projected along it; a point's
    plane coordinates are ``(R θ, h)``: its angle about the circle's centre from the pad's
    side (the third principal direction, towards most points), times the radius, and its
    height along the axis, mm. One-to-one wherever each ray from the axis meets the surface
    once, as on a finger's front half and its tip seen by the cameras. (The unroll's
    :func:`nail2nail.unroll.flatten.fit_cylinder` fits an elliptic cone for the print's
    geometry; the merge stage may not import it, and a mesh needs only a fold-free plane.)

    Parameters
    ----------
    points : (N, 3) float
        Surface points, mm (N ≥ 3).

    Returns
    -------
    uv : (N, 2) float64
        Plane coordinates, mm.

    Examples
    --------
    A cylinder of radius 5 mm, ±1 rad about its axis and 20 mm long, unrolls to 10 × 20 mm:

    >>> t, h = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(0, 20, 12))
    >>> pts = np.stack([5 * np.sin(t.ravel()), h.ravel(), 5 * np.cos(t.ravel())], -1)
    >>> np.round(np.ptp(finger_plane(pts), axis=0), 6).tolist()
    [10.0, 20.0]
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 3:
        raise ValueError(f"points: expected (N, 3) with N >= 3, got {points.shape}")
    centre = points.mean(axis=0)
    d = points - centre
    axes = np.linalg.svd(d, full_matrices=False)[2]
    axis = axes[0]
    pad = axes[2] * (1.0 if np.median(d @ axes[2]) >= 0 else -1.0)
    side = np.cross(axis, pad)
    x, y = d @ side, d @ pad
    a = np.column_stack([x, y, np.ones_like(x)])
    (bx, by, c), *_ = np.linalg.lstsq(a, x * x + y * y, rcond=None)
    cx, cy = bx / 2, by / 2
    radius = float(np.sqrt(max(c + cx * cx + cy * cy, 0.0)))
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError("points: no cylinder fits them (a plane or a line)")
    return np.column_stack([radius * np.arctan2(x - cx, y - cy), d @ axis])


def seamless_mesh(points, *, normals=None, fill_holes_mm: float = FILL_HOLES_MM) -> np.ndarray:
    """:func:`param_mesh` of `points` in :func:`finger_plane`: one mesh of a finger's scan.

    Parameters
    ----------
    points : (N, 3) float
        Vertices, mm.
    normals : (N, 3) float, optional
        Vertex normals, for the winding (:func:`param_mesh`).
    fill_holes_mm : float
        Holes inside the outline closed up to this edge length (:func:`param_mesh`), mm.

    Returns
    -------
    faces : (F, 3) int64
    """
    return param_mesh(points, finger_plane(points), normals=normals,
                      fill_holes_mm=fill_holes_mm)


def mesh_topology(faces, n_vertices: int) -> dict:
    """Counts of a triangle mesh's topology.

    Parameters
    ----------
    faces : (F, 3) int
        Triangles.
    n_vertices : int
        Vertices of the mesh (those of no triangle count as isolated).

    Returns
    -------
    dict
        ``faces``, ``edges``, ``boundary_edges`` (one triangle), ``non_manifold_edges`` (more
        than two), ``non_manifold_vertices`` (more than two boundary edges meet: two fans
        touching at a vertex), ``isolated_vertices``, ``inconsistent_edges`` (an interior
        edge its two triangles run the same way: they are wound against each other).

    Examples
    --------
    >>> mesh_topology([[0, 1, 2], [0, 2, 3]], 4)["boundary_edges"]
    4
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    lo, hi = directed.min(axis=1), directed.max(axis=1)
    key = lo * n_vertices + hi
    unique, inverse, count = np.unique(key, return_inverse=True, return_counts=True)
    # a consistent orientation runs an interior edge once each way
    forward = np.bincount(inverse, weights=directed[:, 0] < directed[:, 1],
                          minlength=len(unique))
    boundary = unique[count == 1]
    ends = np.concatenate([boundary // n_vertices, boundary % n_vertices])
    at_vertex = np.bincount(ends, minlength=n_vertices)
    used = np.zeros(n_vertices, bool)
    used[faces.ravel()] = True
    return {
        "faces": len(faces),
        "edges": len(unique),
        "boundary_edges": len(boundary),
        "non_manifold_edges": int(np.count_nonzero(count > 2)),
        "non_manifold_vertices": int(np.count_nonzero(at_vertex > 2)),
        "isolated_vertices": int(n_vertices - np.count_nonzero(used)),
        "inconsistent_edges": int(np.count_nonzero((count == 2) & (forward != 1))),
    }


def boundary_figures(faces, vertices, *, far_spacings: float = 2.0) -> dict:
    """Where a mesh's boundary lies: its outline, and the holes inside it.

    The boundary edges (one triangle each) are split into connected loops; in each piece of
    the mesh the loop of the greatest length is its outline (the edge of the scanned area),
    every other one a hole.
    A hole edge whose midpoint is farther than `far_spacings` grid spacings (the median edge
    length) from every outline vertex is a hole inside the surface, not a notch at its edge.

    Parameters
    ----------
    faces : (F, 3) int
    vertices : (N, 3) float
        mm.
    far_spacings : float

    Returns
    -------
    dict
        ``spacing_mm`` (median edge length), ``pieces`` (of the mesh), ``outline_edges``,
        ``holes`` (loops other than the outlines), ``hole_edges``, ``hole_edges_far``
        (farther than `far_spacings` spacings from any outline), ``hole_distance_max_mm``.

    Examples
    --------
    A 7 × 7 grid of unit squares with two missing: one next to the edge, one in the middle.

    >>> rr, cc = np.mgrid[0:8, 0:8]
    >>> v = np.stack([cc.ravel(), rr.ravel(), 0 * rr.ravel()], -1).astype(float)
    >>> quads = [(r * 8 + c, r * 8 + c + 1, r * 8 + c + 9, r * 8 + c + 8)
    ...          for r in range(7) for c in range(7) if (r, c) not in ((1, 1), (3, 3))]
    >>> f = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    >>> fig = boundary_figures(f, v)
    >>> fig["outline_edges"], fig["holes"], fig["hole_edges"], fig["hole_edges_far"]
    (28, 2, 8, 4)
    """
    import scipy.sparse
    import scipy.sparse.csgraph
    import scipy.spatial

    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=np.float64)
    n = len(vertices)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges.sort(axis=1)
    unique, count = np.unique(edges[:, 0] * n + edges[:, 1], return_counts=True)
    pairs = np.stack([unique // n, unique % n], axis=-1)
    length = np.linalg.norm(vertices[pairs[:, 0]] - vertices[pairs[:, 1]], axis=-1)
    spacing = float(np.median(length)) if length.size else float("nan")
    boundary = pairs[count == 1]
    empty = {"spacing_mm": spacing, "pieces": 1 if len(faces) else 0, "outline_edges": 0,
             "holes": 0, "hole_edges": 0, "hole_edges_far": 0, "hole_distance_max_mm": 0.0}
    if not len(boundary):
        return empty
    graph = scipy.sparse.coo_matrix((np.ones(len(boundary)), (boundary[:, 0], boundary[:, 1])),
                                    shape=(n, n))
    _, label = scipy.sparse.csgraph.connected_components(graph, directed=False)
    loop = label[boundary[:, 0]]
    loop_length = np.bincount(loop, weights=length[count == 1])
    # each piece of the mesh (vertices joined by its edges) has its own outline: its longest
    # loop; a piece joined to the rest at one vertex only is an island, not a hole
    mesh_graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                         shape=(n, n))
    _, piece = scipy.sparse.csgraph.connected_components(mesh_graph, directed=False)
    loop_piece = np.zeros(loop_length.size, dtype=np.int64)
    loop_piece[loop] = piece[boundary[:, 0]]
    longest = np.zeros(piece.max() + 1)
    np.maximum.at(longest, loop_piece, loop_length)
    outline_loops = loop_length >= longest[loop_piece]
    on_outline = outline_loops[loop]
    hole = boundary[~on_outline]
    out = {**empty, "pieces": len(np.unique(piece[faces.ravel()])),
           "outline_edges": int(np.count_nonzero(on_outline)),
           "holes": len(np.unique(loop[~on_outline])), "hole_edges": len(hole)}
    if len(hole):
        tree = scipy.spatial.cKDTree(vertices[np.unique(boundary[on_outline])])
        mid = 0.5 * (vertices[hole[:, 0]] + vertices[hole[:, 1]])
        d, _ = tree.query(mid)
        out["hole_edges_far"] = int(np.count_nonzero(d > far_spacings * spacing))
        out["hole_distance_max_mm"] = round(float(d.max()), 4)
    return out
