"""The whole pipeline (``nail2nail demo``) at half scale against the targets of issues 5 and 6.

Moved out of the test suite (it was ``tests/test_pipeline.py``, 80 s of one CI worker, the
suite's largest single item) to keep the suite under ten minutes; the same checks, printed:

- issue 5: the projector distortion's centre within 5 px and ρ within 2 % of the thesis's
  (the virtual scanner uses the thesis's distortion); the merge median drops at least five-fold
  from before correction to the best calibration, on the target and on the finger, and both
  the thesis's LUT and the model-based correction help with the thesis's DLT;
- issue 6: on the finger, cameras 0↔1 and 1↔2, more than 10,000 pairs, merge median ≤ 10 µm
  and p95 ≤ 25 µm;
- the outputs listed exist, the super scan has more than 100,000 vertices.

Usage::

    .venv/bin/python bench/demo_targets.py [--out DIR] [--scale 0.5]

Exit status 1 when a target is missed. About 80 s on one core.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np


def check(result: dict, out: Path) -> list[tuple[str, bool, str]]:
    """Every target: ``(name, met, figures)``."""
    from nail2nail.calibration.distortion import THESIS_CENTER, THESIS_RHO

    rows = []
    d = result["distortion"]
    off = float(np.hypot(*(np.array(d["center_px"]) - THESIS_CENTER)))
    rows.append(("issue 5: distortion centre within 5 px", off < 5, f"{off:.2f} px"))
    rho_err = abs(d["rho"] - THESIS_RHO) / abs(THESIS_RHO)
    rows.append(("issue 5: rho within 2 %", rho_err < 0.02, f"{100 * rho_err:.2f} %"))
    for pair in ("0-1", "1-2"):
        m = result["merge"][pair]
        dist = m["distance_mm"]
        ok = m["pairs"] > 10_000 and dist["median"] <= 0.010 and dist["p95"] <= 0.025
        rows.append((f"issue 6: finger {pair} median <= 10 um, p95 <= 25 um", ok,
                     f"{m['pairs']} pairs, {1e3 * dist['median']:.2f} / "
                     f"{1e3 * dist['p95']:.2f} um"))
    comparison = result["comparison"]
    for obj in ("target", "finger"):
        for pair in ("0-1", "1-2"):
            def med(key, obj=obj, pair=pair):
                return comparison[key][obj][pair]["distance_mm"]["median"]
            before, best = med("before"), med("best")
            ok = best * 5 <= before and med("thesis_lut") < before and med("model_dlt") < before
            rows.append((f"issue 5: {obj} {pair} best at least 5x below before", ok,
                         f"before {1e3 * before:.1f} um, best {1e3 * best:.2f} um"))
    missing = [p for p in result["outputs"] if not Path(p).exists()]
    ok = (not missing and (out / "summary.json").exists()
          and result["thesis"]["yp"]["pairs"] == 24
          and result["super_scan"]["vertices"] > 100_000)
    rows.append(("outputs written, super scan > 100,000 vertices", ok,
                 f"{result['super_scan']['vertices']} vertices, missing {missing}"))
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, help="demo output directory (default: a temporary one)")
    p.add_argument("--scale", type=float, default=0.5)
    args = p.parse_args(argv)
    from nail2nail.cli import main as cli

    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp) / "demo"
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            rc = cli(["demo", "--out", str(out), "--scale", str(args.scale), "--json"])
        if rc != 0:
            print(f"nail2nail demo failed (exit {rc})")
            return 1
        rows = check(json.loads(buffer.getvalue()), out)
    for name, ok, figures in rows:
        print(f"{'met ' if ok else 'MISSED'}  {name}: {figures}")
    return 0 if all(ok for _, ok, _ in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
