"""File formats: points tables, calibration files, captures, mat5 scans, PLY."""
