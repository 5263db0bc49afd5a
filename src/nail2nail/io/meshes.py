"""Triangle meshes in the formats 3D tools read: PLY, OBJ, STL and glTF binary (GLB).

Written through trimesh (a maintained library) rather than by hand, atomically (a temporary
file beside the target, renamed once complete). What each format keeps of a super scan:

======  ==========================================================================
PLY     binary little-endian: positions, normals, grey colours, triangles
        (:func:`nail2nail.io.ply.write_ply`, the project's own PLY, as ``merge``
        writes it)
OBJ     text: positions, vertex colours (the common ``v x y z r g b`` extension),
        normals, triangles
STL     binary: triangles only (each with its own three corners; no shared vertices,
        colours or vertex normals)
GLB     glTF 2.0 binary: positions, normals, vertex colours (``COLOR_0``), triangles
======  ==========================================================================

Units: millimetres, as the scans (glTF assumes metres: scale by 0.001 on import where a tool
cares); the frame is the super scan's (``super_scan.frame`` in ``merge.json``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from nail2nail.io._atomic import atomic_path, check_output_file
from nail2nail.io.ply import mesh_arrays, write_ply

__all__ = ["MESH_FORMATS", "write_mesh"]

#: File suffixes :func:`write_mesh` writes, and the format of each.
MESH_FORMATS = {".ply": "PLY", ".obj": "OBJ", ".stl": "STL", ".glb": "glTF binary"}


def write_mesh(path: str | os.PathLike, points, faces, *, colors=None, normals=None,
               comments=()) -> Path:
    """Write a triangle mesh in the format of `path`'s suffix (:data:`MESH_FORMATS`).

    Parameters
    ----------
    path : path-like
        Output file: ``.ply``, ``.obj``, ``.stl`` or ``.glb``.
    points : (N, 3) float
        Vertices, mm (finite).
    faces : (M, 3) int
        Triangles, indices into `points` (at least one).
    colors : (N, 3) uint8, optional
        Vertex colours (RGB).
    normals : (N, 3) float, optional
        Vertex normals.
    comments : sequence of str
        PLY header comments (the other formats have none).

    Returns
    -------
    Path
        `path`.

    Raises
    ------
    ValueError
        An unknown suffix, no triangles, or what :func:`nail2nail.io.ply.mesh_arrays` refuses
        (the checks of every mesh writer: shapes, non-finite points, colours, face indices);
        `path` a directory.

    Examples
    --------
    >>> import tempfile, pathlib, trimesh
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "tri.obj"
    >>> _ = write_mesh(p, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> trimesh.load(p).faces.tolist()
    [[0, 1, 2]]
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise ValueError(f"{path}: unknown mesh format {path.suffix!r}; expected one of "
                         f"{', '.join(MESH_FORMATS)}")
    points, colors, normals, faces = mesh_arrays(points, colors, normals, faces)
    if faces is None or len(faces) == 0:
        raise ValueError(f"{path}: a mesh needs triangles (a point cloud is written as PLY by "
                         "merge)")
    check_output_file(path)
    if suffix == ".ply":
        return write_ply(path, points, colors=colors, normals=normals, faces=faces,
                         comments=list(comments))
    import trimesh  # deferred: only the exports need it

    visual = None
    if colors is not None:
        visual = trimesh.visual.ColorVisuals(vertex_colors=np.column_stack(
            [colors, np.full(len(colors), 255, np.uint8)]))
    mesh = trimesh.Trimesh(vertices=points.astype(np.float64), faces=faces.astype(np.int64),
                           visual=visual, process=False,
                           vertex_normals=None if normals is None else normals.astype(np.float64))
    kind = {".obj": "obj", ".stl": "stl", ".glb": "glb"}[suffix]
    if kind == "obj":
        from trimesh.exchange.obj import export_obj

        data: object = export_obj(mesh, include_normals=normals is not None)
    else:
        data = mesh.export(file_type=kind)
    if isinstance(data, str):
        data = data.encode("utf-8")
    if not isinstance(data, bytes):
        raise TypeError(f"trimesh's {kind} export gave {type(data).__name__}, not bytes")
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path
