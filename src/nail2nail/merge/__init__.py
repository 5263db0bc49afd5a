"""Merge: the cameras' scans joined in projector space (thesis chapter four) and fused.

Modules, in the order the data flows through them:

- :mod:`~nail2nail.merge.correspondence`: pairs of pixels of two cameras with the same
  projector coordinates, their world distance (the merge error), and the pairs dropped or
  rejected, with the reason;
- :mod:`~nail2nail.merge.statistics`: the summary figures of the merge error, and local outliers;
- :mod:`~nail2nail.merge.fusion`: the super scan, one nail-to-nail point cloud and mesh, and the
  super mat5;
- :mod:`~nail2nail.merge.mesh`: one seamless mesh over the super scan's vertices (a Delaunay
  triangulation in a plane that images the surface one-to-one), and a mesh's topology figures;
- :mod:`~nail2nail.merge.report`: the whole merge step written to a directory
  (:func:`~nail2nail.merge.report.write_merge`, behind ``nail2nail merge``);
- :mod:`~nail2nail.merge.figures`: its figures (matplotlib, imported only when drawn);
- :mod:`~nail2nail.merge.alignment`: point-to-plane ICP (Open3D), the baseline the
  projector-space merge is compared with.
"""

from nail2nail.merge.correspondence import (
    DROP_REASONS,
    PAIR_BY,
    REJECT_REASONS,
    Correspondence,
    check_pair_by,
    correspond,
    grid_normals,
    incidence_cosine,
    nearest_bruteforce,
    nearest_kdtree,
    pairing_coordinates,
    refine_subpixel,
    restrict_pairs,
    same_pixel_pairs,
    sample_pixels,
    valid_mask,
    view_cosine,
)
from nail2nail.merge.fusion import SuperScan, fuse_scans, write_super_mat5, write_super_ply
from nail2nail.merge.mesh import boundary_figures, mesh_topology, param_mesh
from nail2nail.merge.report import parse_pairs, write_merge
from nail2nail.merge.statistics import local_outliers, merge_statistics

__all__ = [
    "DROP_REASONS",
    "PAIR_BY",
    "REJECT_REASONS",
    "Correspondence",
    "SuperScan",
    "boundary_figures",
    "check_pair_by",
    "correspond",
    "fuse_scans",
    "grid_normals",
    "incidence_cosine",
    "local_outliers",
    "merge_statistics",
    "mesh_topology",
    "nearest_bruteforce",
    "nearest_kdtree",
    "pairing_coordinates",
    "param_mesh",
    "parse_pairs",
    "refine_subpixel",
    "restrict_pairs",
    "same_pixel_pairs",
    "sample_pixels",
    "valid_mask",
    "view_cosine",
    "write_merge",
    "write_super_mat5",
    "write_super_ply",
]
