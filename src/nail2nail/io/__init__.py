"""File formats: points tables, calibration files, captures, mat5 scans, PLY, mesh exports (OBJ,
STL, glTF binary: :mod:`nail2nail.io.meshes`)."""
