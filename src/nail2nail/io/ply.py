"""Binary PLY point clouds and triangle meshes (write binary little-endian; read binary and ASCII).

Vertices carry ``x y z`` (``float32``), optional ``red green blue`` (``uchar``) and optional
``nx ny nz`` (``float32``); faces are triangles ``property list uchar int vertex_indices``.
The reader accepts any vertex properties (unknown ones are kept in :attr:`PlyData.extra`) in
``binary_little_endian``, ``binary_big_endian`` or ``ascii`` PLY 1.0.

References
----------
G. Turk, "The PLY Polygon File Format" (1994).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nail2nail._validation import as_points, file_kind
from nail2nail.io._atomic import atomic_path

__all__ = ["PlyData", "mesh_arrays", "read_ply", "write_ply", "write_scan_ply"]

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


@dataclass
class PlyData:
    """Content of a PLY file.

    Attributes
    ----------
    points : (N, 3) float32
        Vertex positions.
    colors : (N, 3) uint8 or None
        Vertex colours (RGB).
    normals : (N, 3) float32 or None
        Vertex normals.
    faces : (M, 3) int32 or None
        Triangles as vertex indices.
    extra : dict of str to (N,) arrays
        Other vertex properties (e.g. ``quality``).
    comments : list of str
        Header comments.
    """

    points: np.ndarray
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    faces: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    comments: list[str] = field(default_factory=list)


def mesh_arrays(points, colors=None, normals=None, faces=None) -> tuple:
    """A mesh's arrays checked and converted, as every mesh writer takes them.

    Returns
    -------
    points : (N, 3) float32
        Finite positions.
    colors : (N, 3) uint8 or None
        Integers 0..255 (any numeric dtype accepted).
    normals : (N, 3) float32 or None
    faces : (M, 3) integer array or None
        Indices in ``[0, N)``; an empty array becomes ``(0, 3)``.

    Raises
    ------
    ValueError
        Naming the array: a wrong shape, non-finite points, colours outside 0..255, face
        indices out of range.
    """
    points = as_points(points, "points", 3).astype(np.float32)
    n = points.shape[0]
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (n, 3):
            raise ValueError(f"colors: expected shape ({n}, 3), got {colors.shape}")
        if colors.dtype != np.uint8:
            if not np.issubdtype(colors.dtype, np.number) or np.any(
                (colors < 0) | (colors > 255) | (colors != np.round(colors))
            ):
                raise ValueError("colors: expected integers 0..255 (or a uint8 array)")
            colors = colors.astype(np.uint8)
    if normals is not None:
        normals = as_points(normals, "normals", 3, finite=False).astype(np.float32)
        if normals.shape[0] != n:
            raise ValueError(f"normals: expected shape ({n}, 3), got {normals.shape}")
    if faces is not None:
        faces = np.asarray(faces)
        if faces.size == 0:
            faces = faces.reshape(0, 3)
        if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
            raise ValueError(f"faces: expected an (M, 3) integer array, got {faces.dtype} "
                             f"{faces.shape}")
        if faces.size and (faces.min() < 0 or faces.max() >= n):
            raise ValueError(f"faces: vertex indices must lie in [0, {n}), got "
                             f"[{faces.min()}, {faces.max()}]")
    return points, colors, normals, faces


def write_ply(
    path: str | os.PathLike,
    points,
    *,
    colors=None,
    normals=None,
    faces=None,
    comments: list[str] | tuple[str, ...] = (),
) -> Path:
    """Write a binary little-endian PLY (atomically: temporary file, then rename).

    Parameters
    ----------
    path : path-like
        Output file.
    points : (N, 3) array_like
        Vertex positions (stored as float32; finite).
    colors : (N, 3) array_like of int 0..255, optional
        RGB colours (uchar).
    normals : (N, 3) array_like, optional
        Normals (float32).
    faces : (M, 3) array_like of int, optional
        Triangles, indices into `points`.
    comments : sequence of str
        Header comments (one line each).

    Returns
    -------
    Path
        `path`.

    Raises
    ------
    ValueError
        On shape mismatches, non-finite points, colours outside 0..255 or face indices out of
        range.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "tri.ply"
    >>> _ = write_ply(p, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])
    >>> read_ply(p).faces.tolist()
    [[0, 1, 2]]
    """
    points, colors, normals, faces = mesh_arrays(points, colors, normals, faces)
    n = points.shape[0]
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    for comment in comments:
        if "\n" in comment or "\r" in comment:
            raise ValueError("comments: a comment must be a single line")
    vertex = np.empty(n, dtype=fields)
    vertex["x"], vertex["y"], vertex["z"] = points.T
    if colors is not None:
        vertex["red"], vertex["green"], vertex["blue"] = colors.T
    if normals is not None:
        vertex["nx"], vertex["ny"], vertex["nz"] = normals.T
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {c}" for c in comments]
    header += [f"element vertex {n}"]
    names = {"<f4": "float", "u1": "uchar"}
    header += [f"property {names[t]} {name}" for name, t in fields]
    if faces is not None:
        header += [f"element face {faces.shape[0]}", "property list uchar int vertex_indices"]
    tri = None
    if faces is not None:
        tri = np.empty(faces.shape[0], dtype=[("n", "u1"), ("v", "<i4", (3,))])
        tri["n"] = 3
        tri["v"] = faces
    return _write_binary(path, header, vertex, tri)


def _write_binary(path, header: list[str], vertex: np.ndarray, faces: np.ndarray | None) -> Path:
    """Write the header lines (``end_header`` added) and the element tables, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join([*header, "end_header"]) + "\n").encode("ascii"))
        vertex.tofile(fh)
        if faces is not None:
            faces.tofile(fh)
    return path


def write_scan_ply(path: str | os.PathLike, scan) -> Path:
    """Write the valid points of a :class:`~nail2nail.scan.results.Scan` with albedo as grey.

    Points are the pixels with ``scan.mask`` and finite ``xyz``, in row-major pixel order; the
    colour is ``round(255 albedo)`` in R, G and B (NaN as 0).
    """
    xyz = np.asarray(scan.xyz, dtype=np.float32)
    mask = np.asarray(scan.mask, dtype=bool)
    if xyz.shape != (*mask.shape, 3):
        raise ValueError(f"scan.xyz: expected shape {(*mask.shape, 3)}, got {xyz.shape}")
    name = str(scan.name)
    if "\n" in name or "\r" in name:
        raise ValueError("comments: a comment must be a single line")
    xyz = np.ascontiguousarray(xyz)
    valid = mask & np.isfinite(xyz[..., 0])
    valid &= np.isfinite(xyz[..., 1])
    valid &= np.isfinite(xyz[..., 2])
    grey = np.multiply(np.asarray(scan.albedo)[valid], 255.0, dtype=np.float64)
    np.fmax(grey, 0.0, out=grey)  # fmax/fmin drop NaN: 0
    np.fmin(grey, 255.0, out=grey)
    # x y z red green blue, 15 bytes a vertex, as write_ply lays them out
    vertex = np.empty(grey.size, dtype=[("xyz", "<f4", (3,)), ("rgb", "u1", (3,))])
    pixels = xyz.view(np.dtype((np.void, 12))).reshape(mask.shape)  # whole pixels: fast
    vertex["xyz"] = pixels[valid].view(np.float32).reshape(-1, 3)
    vertex["rgb"] = np.rint(grey, out=grey).astype(np.uint8)[:, None]
    header = ["ply", "format binary_little_endian 1.0", f"comment nail2nail scan {name}",
              f"element vertex {grey.size}", "property float x", "property float y",
              "property float z", "property uchar red", "property uchar green",
              "property uchar blue"]
    return _write_binary(path, header, vertex, None)


def _parse_header(fh, path: Path, size: int):
    if fh.readline(16).strip() != b"ply":
        raise ValueError(f"{path}: not a PLY file (no 'ply' magic)")
    fmt = None
    comments: list[str] = []
    elements: list[tuple[str, int, list]] = []
    while True:
        line = fh.readline(4096)
        if not line:
            raise ValueError(f"{path}: PLY header has no end_header")
        text = line.decode("ascii", "replace")
        words = text.split()
        if not words:
            continue
        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            fmt = words[1] if len(words) > 1 else None
        elif key in ("comment", "obj_info"):
            comments.append(text.rstrip("\r\n")[len(key) + 1:])
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit() or not words[2].isascii():
                raise ValueError(f"{path}: bad header line {text.strip()!r} (expected "
                                 "'element NAME COUNT')")
            count = int(words[2])
            if count > size:  # every element takes at least a byte: a count beyond the file
                raise ValueError(f"{path}: element {words[1]} claims {count} items, more than "
                                 f"the file's {size} bytes")
            elements.append((words[1], count, []))
        elif key == "property":
            if not elements:
                raise ValueError(f"{path}: property before any element")
            is_list = len(words) > 1 and words[1] == "list"
            types = words[2:4] if is_list else words[1:2]
            if len(words) != (5 if is_list else 3) or any(t not in _TYPES for t in types):
                raise ValueError(f"{path}: bad header line {text.strip()!r} (expected "
                                 "'property TYPE NAME' or 'property list TYPE TYPE NAME', "
                                 f"TYPE one of {', '.join(_TYPES)})")
            if is_list:
                elements[-1][2].append((words[4], ("list", _TYPES[words[2]], _TYPES[words[3]])))
            else:
                elements[-1][2].append((words[2], _TYPES[words[1]]))
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise ValueError(f"{path}: unsupported PLY format {fmt!r}")
    for name, _, props in elements:
        names = [p[0] for p in props]
        if len(set(names)) != len(names):
            raise ValueError(f"{path}: element {name} repeats a property name")
        if any(isinstance(p[1], tuple) for p in props) and len(props) != 1:
            raise ValueError(f"{path}: element {name}: only a single list property supported")
    return fmt, comments, elements


def _read_element(fh, fmt, count, props, path, name):
    endian = ">" if fmt == "binary_big_endian" else "<"
    lists = [p for p in props if isinstance(p[1], tuple)]
    if fmt == "ascii":
        rows = []
        for i in range(count):
            line = fh.readline()
            if not line:
                raise ValueError(f"{path}: truncated element {name} ({i} of {count} rows)")
            rows.append(line.split())
        if lists:
            _, (_, count_t, item_t) = props[0]
            data = []
            for i, r in enumerate(rows):
                if not r or not r[0].isdigit() or len(r) != 1 + int(r[0]):
                    raise ValueError(f"{path}: element {name}, row {i}: bad list {r[:8]}")
                data.append(np.asarray([int(v) for v in r[1:]], dtype=np.int64))
            return {props[0][0]: data}
        if any(len(r) != len(props) for r in rows):
            bad = next(i for i, r in enumerate(rows) if len(r) != len(props))
            raise ValueError(f"{path}: element {name}, row {bad}: {len(rows[bad])} values, "
                             f"expected {len(props)}")
        table = np.asarray(rows, dtype=np.float64).reshape(count, len(props))
        with np.errstate(invalid="ignore", over="ignore"):
            return {p[0]: table[:, i].astype(p[1]) for i, p in enumerate(props)}
    if lists:
        pname, (_, count_t, item_t) = props[0]
        dtype = np.dtype([("n", endian + count_t), ("v", endian + item_t, (3,))])
        raw = fh.read(dtype.itemsize * count)
        if len(raw) != dtype.itemsize * count:
            raise ValueError(f"{path}: truncated element {name}")
        table = np.frombuffer(raw, dtype=dtype)
        if count and np.any(table["n"] != 3):
            raise ValueError(f"{path}: only triangle faces are supported")
        return {pname: table["v"].astype(np.int64)}
    dtype = np.dtype([(p[0], endian + p[1]) for p in props])
    raw = fh.read(dtype.itemsize * count)
    if len(raw) != dtype.itemsize * count:
        raise ValueError(f"{path}: truncated element {name} ({len(raw)} of "
                         f"{dtype.itemsize * count} bytes)")
    table = np.frombuffer(raw, dtype=dtype)
    return {p[0]: table[p[0]].astype(table.dtype[p[0]].newbyteorder("=")) for p in props}


def read_ply(path: str | os.PathLike) -> PlyData:
    """Read a PLY point cloud or triangle mesh.

    Returns
    -------
    PlyData

    Raises
    ------
    ValueError
        Naming the file: not a regular file (a FIFO would block: refused before it is
        opened), not PLY, an unsupported format, a malformed header line (unknown type, bad
        count, a count beyond the file's size), no ``x y z`` vertex properties, non-triangle
        faces, face indices out of range, or truncated.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise ValueError(f"{path}: not a regular file ({file_kind(path.stat().st_mode)}); "
                         "expected a PLY file")
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        try:
            fmt, comments, elements = _parse_header(fh, path, size)
            data = {}
            for name, count, props in elements:
                data[name] = _read_element(fh, fmt, count, props, path, name)
        except ValueError as exc:
            if str(exc).startswith(f"{path}: "):
                raise
            raise ValueError(f"{path}: not a valid PLY file ({exc})") from exc
    vertex = data.get("vertex")
    if vertex is None or not all(k in vertex for k in "xyz"):
        raise ValueError(f"{path}: no vertex element with x, y, z")
    if any(isinstance(v, list) for v in vertex.values()):
        raise ValueError(f"{path}: vertex element with a list property")
    colors = normals = faces = None
    with np.errstate(over="ignore", invalid="ignore"):  # doubles beyond float32 become inf
        points = np.stack([vertex.pop(k) for k in "xyz"], axis=1).astype(np.float32)
        if all(k in vertex for k in ("red", "green", "blue")):
            colors = np.stack([vertex.pop(k) for k in ("red", "green", "blue")], 1
                              ).astype(np.uint8)
        if all(k in vertex for k in ("nx", "ny", "nz")):
            normals = np.stack([vertex.pop(k) for k in ("nx", "ny", "nz")], 1
                               ).astype(np.float32)
    face = data.get("face")
    if face:
        faces = next(iter(face.values()))
        if isinstance(faces, np.ndarray) and (faces.ndim != 2 or faces.shape[1] != 3):
            raise ValueError(f"{path}: face element without a vertex_indices list")
        if isinstance(faces, list):
            if any(f.size != 3 for f in faces):
                raise ValueError(f"{path}: only triangle faces are supported")
            faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if faces.size and (faces.min() < 0 or faces.max() >= len(points)):
            raise ValueError(f"{path}: face vertex indices must lie in [0, {len(points)}), got "
                             f"[{faces.min()}, {faces.max()}]")
        faces = faces.astype(np.int32)
    return PlyData(points=points, colors=colors, normals=normals, faces=faces, extra=vertex,
                   comments=comments)
