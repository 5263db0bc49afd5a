"""Compiled kernels against their NumPy references, through one template (tests/_kernels.py).

Each case runs a kernel and its reference on the same input; the tolerances come from the one
table :data:`_kernels.TOLERANCES`. The kernels' wider checks (every option, the virtual
finger) stay with their stages' tests (``test_scan_kernels.py``, ``test_merge_fast.py``,
``test_merge_fusion_fast.py``, ``test_unroll_kernels.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from _kernels import KernelCase, check_kernel

from nail2nail._interpolate import bilinear, bilinear_gradient, bilinear_value
from nail2nail.calibration.camera_models import dlt_from_pinhole, project_dlt
from nail2nail.scan.decoding import decode
from nail2nail.scan.kernels import decode_fast
from nail2nail.scan.patterns import PatternSet, make_patterns
from nail2nail.scan.triangulation import reconstruct_points_lsq, reconstruct_points_ray
from nail2nail.simulation.rig import default_rig


def _bilinear_case() -> KernelCase:
    rng = np.random.default_rng(0)
    image = rng.normal(size=(10, 12)).astype(np.float32)
    r, c = rng.uniform(0, 9, 200), rng.uniform(0, 11, 200)
    return KernelCase(
        "bilinear_value",
        compiled=lambda: {"value": np.array([bilinear_value(image, a, b)
                                             for a, b in zip(r, c, strict=True)])},
        reference=lambda: {"value": bilinear(image.astype(np.float64), r, c)[0]},
        kinds={"value": "same_float64"},
    )


def _bilinear_gradient_case() -> KernelCase:
    rng = np.random.default_rng(3)
    image = rng.normal(size=(10, 12)).astype(np.float32)
    r, c = rng.uniform(-1, 10, 200), rng.uniform(-1, 12, 200)  # some beyond the image

    def compiled():
        out = np.array([bilinear_gradient(image, a, b) for a, b in zip(r, c, strict=True)])
        return {"value": out[:, 0], "d_dr": out[:, 1], "d_dc": out[:, 2]}

    def reference():
        value, d_dr, d_dc = bilinear(image.astype(np.float64), r, c)
        return {"value": value, "d_dr": d_dr, "d_dc": d_dc}

    return KernelCase("bilinear_gradient", compiled=compiled, reference=reference,
                      kinds=dict.fromkeys(("value", "d_dr", "d_dc"), "same_float64"))


def _decode_case() -> KernelCase:
    ps = PatternSet(x=[(1, 3), (8, 4)], y=[(1, 3), (8, 4)], panel_size=(64, 48))
    frames = make_patterns(ps)
    rng = np.random.default_rng(1)
    frames = np.clip(frames + rng.normal(scale=2.0, size=frames.shape), 0, 255).astype(np.uint8)

    def outputs(decoded):
        return {"xp": decoded.xp, "yp": decoded.yp, "mask": decoded.mask,
                "reason": decoded.reason}

    return KernelCase(
        "decode_fast",
        compiled=lambda: outputs(decode_fast(frames, ps, saturation=1.01)),
        reference=lambda: outputs(decode(frames, ps, saturation=1.01)),
        kinds={"xp": "panel_px_float32", "yp": "panel_px_float32", "mask": "exact",
               "reason": "exact"},
    )


def _ray_case() -> KernelCase:
    rig = default_rig(0.25, projector_distortion="none")
    Mc, Mp = dlt_from_pinhole(rig.cameras[0]), dlt_from_pinhole(rig.projector)
    rng = np.random.default_rng(2)
    X = rng.normal(scale=5.0, size=(100, 3))
    xc, yc = project_dlt(Mc, X).T
    xp, yp = (project_dlt(Mp, X) + rng.normal(scale=0.05, size=(100, 2))).T
    return KernelCase(
        "reconstruct_points_ray",
        compiled=lambda: {"xyz": reconstruct_points_ray(Mc, Mp, xc, yc, xp, yp)},
        reference=lambda: {"xyz": reconstruct_points_lsq(Mc, Mp, xc, yc, xp, yp,
                                                         camera_weight=1e3)},
        kinds={"xyz": "ray_vs_lsq_mm"},
    )


CASES = [_bilinear_case, _bilinear_gradient_case, _decode_case, _ray_case]


@pytest.mark.parametrize("make", CASES, ids=lambda f: f.__name__.strip("_"))
def test_kernel_matches_its_reference(make):
    check_kernel(make())


def test_the_template_fails_a_wrong_kernel():
    """The template is not vacuous: a kernel off by more than its tolerance fails."""
    case = _bilinear_case()
    wrong = KernelCase(case.name, compiled=lambda: {"value": case.compiled()["value"] + 1e-6},
                       reference=case.reference, kinds=case.kinds)
    with pytest.raises(AssertionError, match="same_float64"):
        check_kernel(wrong)
