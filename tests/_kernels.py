"""One template for compiled kernels against their NumPy references (as kornia's BaseTester).

A compiled kernel (numba) is checked by running it and its NumPy reference on the same input
and comparing the outputs with the tolerance of :data:`TOLERANCES` that names what the output
is; one table, so that a tolerance is stated once, with its reason, and not widened in one test.
A test module lists its cases as :class:`KernelCase` and calls :func:`check_kernel` on each
(``tests/test_kernels.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

#: kind of output -> (rtol, atol, why)
TOLERANCES: dict[str, tuple[float, float, str]] = {
    "same_float64": (0.0, 1e-9,
                     "the same float64 arithmetic in another order (numba without fastmath)"),
    "panel_px_float32": (0.0, 1.3e-4,
                         "one float32 step of a panel coordinate below 2048 px (1.2e-4 px)"),
    "points_mm": (0.0, 1e-5, "float32 points from float64 triangulation, mm"),
    "ray_vs_lsq_mm": (0.0, 1e-6,
                      "the camera ray's solution against least squares with camera weight 1e3"),
    "exact": (0.0, 0.0, "integer or boolean outputs: equal"),
}


@dataclass
class KernelCase:
    """A compiled kernel and its NumPy reference on one input.

    Attributes
    ----------
    name : str
        The test id.
    compiled, reference : callable
        Called with no arguments; each returns a dict of output name -> array.
    kinds : dict of str to str
        Output name -> key of :data:`TOLERANCES`.
    """

    name: str
    compiled: Callable[[], dict[str, np.ndarray]]
    reference: Callable[[], dict[str, np.ndarray]]
    kinds: dict[str, str] = field(default_factory=dict)


def check_kernel(case: KernelCase) -> None:
    """Every output of `case.compiled` against `case.reference`, NaN where NaN."""
    got, want = case.compiled(), case.reference()
    assert set(got) == set(want) == set(case.kinds), (case.name, set(got), set(want))
    for key, kind in case.kinds.items():
        rtol, atol, why = TOLERANCES[kind]
        a, b = np.asarray(got[key]), np.asarray(want[key])
        assert a.shape == b.shape, (case.name, key, a.shape, b.shape)
        if kind == "exact":
            np.testing.assert_array_equal(a, b, err_msg=f"{case.name}: {key}")
        else:
            np.testing.assert_allclose(a, b, rtol=rtol, atol=atol, equal_nan=True,
                                       err_msg=f"{case.name}: {key} ({kind}: {why})")
