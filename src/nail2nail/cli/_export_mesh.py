"""``nail2nail export-mesh``: the super scan in the formats 3D tools read (issue 27).

Thin command layer over :func:`nail2nail.io.meshes.write_mesh` (and, with ``--seamless``,
:func:`nail2nail.merge.mesh.seamless_mesh`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from nail2nail.io._json import dumps_json
from nail2nail.io.meshes import MESH_FORMATS, write_mesh
from nail2nail.io.ply import read_ply

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "export-mesh",
        help="the super scan as PLY, OBJ, STL or glTF binary (GLB)",
        description="Write a mesh (merge's super.ply, or any PLY mesh) in the format of the "
        "output's suffix: .ply (binary, normals and colours), .obj (vertex colours and "
        "normals), .stl (binary, triangles only), .glb (glTF 2.0 binary, vertex colours and "
        "normals); millimetres, the super scan's frame. --seamless meshes the vertices again "
        "as one surface (the seams between the cameras' grids closed, as merge "
        "--seamless-mesh does).",
    )
    p.add_argument("mesh", type=Path, metavar="MESH",
                   help="a PLY mesh, or a directory of merge (super.ply) or process "
                   "(merge/super.ply)")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="FILE",
                   help=f"file to write: {', '.join(MESH_FORMATS)}")
    p.add_argument("--seamless", action="store_true",
                   help="mesh the vertices again as one seamless surface (about 10 s for a "
                   "full-resolution finger)")
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(func=run)


def _source(path: Path) -> Path:
    if path.is_dir():
        for candidate in (path / "super.ply", path / "merge" / "super.ply"):
            if candidate.is_file():
                return candidate
        raise ValueError(f"{path}: no super.ply or merge/super.ply in this directory")
    return path


def run(args: argparse.Namespace) -> int:
    if args.out.suffix.lower() not in MESH_FORMATS:
        raise ValueError(f"--out: {args.out}: expected a file name ending in "
                         f"{', '.join(MESH_FORMATS)} (the suffix picks the format)")
    source = _source(args.mesh)
    ply = read_ply(source)
    faces = ply.faces
    start = time.perf_counter()
    if args.seamless:
        from nail2nail.merge.mesh import seamless_mesh

        faces = seamless_mesh(ply.points, normals=ply.normals)
    elif faces is None or not len(faces):
        raise ValueError(f"{source}: a point cloud without triangles; --seamless meshes it")
    mesh_s = time.perf_counter() - start
    write_mesh(args.out, ply.points, faces, colors=ply.colors, normals=ply.normals,
               comments=[f"nail2nail export-mesh of {source.name}"])
    summary = {"source": str(source), "out": str(args.out),
               "format": MESH_FORMATS[args.out.suffix.lower()], "vertices": len(ply.points),
               "faces": len(faces), "seamless": bool(args.seamless),
               "mesh_seconds": round(mesh_s, 3)}
    if args.json:
        print(dumps_json(summary))
        return 0
    print(f"wrote {args.out} ({summary['format']}, {summary['vertices']:,} vertices, "
          f"{summary['faces']:,} triangles{', seamless' if args.seamless else ''})")
    return 0
