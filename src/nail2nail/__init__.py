"""nail2nail: touchless 3D fingerprint capture with a multi-camera structured-light scanner.

The pipeline runs one way: capture → decode → reconstruct → merge → unroll → report.
Conventions (pixel centres, frames, units): ``docs/conventions.md``.
"""

__version__ = "0.1.0"

from nail2nail._numba_cache import configure_numba_cache as _configure_numba_cache

_configure_numba_cache()  # before any kernel is compiled with cache=True (issue 10)
