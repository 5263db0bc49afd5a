"""ANSI/NIST-ITL round trips of prints (issue 28): WSQ ratio and fidelity, ten-finger batch.

Usage::

    .venv/bin/python bench/nist_roundtrip.py [--print-dir demo-output/print] [--scale 0.25]
                                             [--rates 0.75 0.6 0.55] [--no-batch] [--json]

**WSQ on the demo print** (``--print-dir``: the ``print/`` directory of ``make demo``; by
default ``demo-output/print``, else the demo is run at ``--demo-scale`` in a temporary
directory, a few minutes): for each bit rate, a one-finger transaction is written
(:func:`nail2nail.interchange.export_transaction`), read back with ``nistitl``
(:func:`~nail2nail.interchange.read_transaction`) and with the tests' independent reader, and
the print decoded from it is compared with the original: compression ratio (pixels / WSQ
bytes), RMS grey error, and the SourceAFIS score of the decoded print against the original
over the original's score against itself (target ≥ 0.95). SourceAFIS: ``bench/sourceafis.py``
(Java 17 and Maven; skipped with a line when missing).

**The same codec on real impressions** (``--real-prints``, default
``../shared/data/prints``: ``probe.png``, ``matching.png``, ``nonmatching.png``, Apache-2.0):
each real print encoded and decoded at every rate (:func:`nail2nail.io.prints.encode_wsq`),
with the same ratio, RMS and score against itself, so that the demo print's figures can be read
against what NBIS's encoder does to a real print (``--real-prints ''`` skips it).

**Blank paper** (:func:`blank_space`): WSQ's ratio at a rate grows with the image's blank area,
so each print (the demo's and the real ones) is also encoded at the first rate cut to the box
of its ridges (:func:`ridge_area`), to compare the codec on like content.

**Ten fingers from a batch** (unless ``--no-batch``): ten virtual captures (seeds 1–10, scale
``--scale``, the rig's true calibration) through ``nail2nail batch … --subjects TABLE`` (two
workers): one transaction of ten Type-14 records, read back by both readers; its size and each
print's ratio.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests"))


def demo_print_dir(args, tmp: Path) -> Path:
    if args.print_dir is not None:
        return args.print_dir
    if (ROOT / "demo-output" / "print" / "print.json").is_file():
        return ROOT / "demo-output" / "print"
    from nail2nail.cli import main

    print(f"running the demo at scale {args.demo_scale} (no demo-output/print) ...",
          file=sys.stderr)
    assert main(["-q", "demo", "--out", str(tmp / "demo"), "--scale", str(args.demo_scale),
                 "--no-report"]) == 0
    return tmp / "demo" / "print"


def ridge_area(image: np.ndarray) -> np.ndarray:
    """Pixels of a print that hold ridges, not blank paper: the grey level's standard deviation
    over 15 × 15 px above 12 levels, closed over 5 px (a bench heuristic for 500 ppi prints)."""
    from scipy import ndimage as ndi

    f = image.astype(np.float64)
    mean = ndi.uniform_filter(f, 15)
    std = np.sqrt(np.maximum(ndi.uniform_filter(f * f, 15) - mean * mean, 0.0))
    return ndi.binary_closing(std > 12, iterations=5)


def blank_space(image: np.ndarray, rate: float) -> dict:
    """The image's blank fraction, and WSQ at `rate` on the box of its ridges alone.

    WSQ's rate sets the quantisation (the distortion), not the size: the entropy coder spends
    almost nothing on blank paper, so an image's ratio grows with its blank area (the FBI's
    "about 15 : 1" at 0.75 bpp is an average over card prints with their margins). Cropping
    every print to its ridges compares the codec on like content."""
    from nail2nail.io.prints import encode_wsq

    ridges = ridge_area(image)
    rows, cols = np.nonzero(ridges)
    crop = image[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    size = len(encode_wsq(crop, bitrate=rate))
    return {"blank_fraction": round(1.0 - float(ridges.mean()), 3),
            "ridge_box_shape": list(crop.shape), "ridge_box_ratio": round(crop.size / size, 2),
            "ridge_box_bpp": round(8 * size / crop.size, 3)}


def wsq_rates(print_dir: Path, rates, tmp: Path, *, imageio_grey: bool = False) -> dict:
    import sourceafis
    from test_interchange import _independent_read

    from nail2nail.interchange import export_transaction, read_job, read_transaction

    original = read_job(print_dir).image
    rows, pngs = [], {}
    sourceafis.save_png(tmp / "original.png", original)
    for rate in rates:
        out = tmp / f"demo_{rate:g}.an2"
        summary = export_transaction([print_dir], out, positions=[2], wsq_bitrate=rate)
        back = read_transaction(out)
        records = _independent_read(out.read_bytes())["records"]
        assert records[1][1][999] == back["type14"][0][999]
        decoded = back["images"][0]
        rms = float(np.sqrt(np.mean((decoded.astype(float) - original) ** 2)))
        pngs[rate] = sourceafis.save_png(tmp / f"decoded_{rate:g}.png", decoded)
        p = summary["prints"][0]
        rows.append({"bitrate_bpp": rate, "achieved_bpp": p["bits_per_pixel"],
                     "ratio": p["compression_ratio"], "rms_grey": round(rms, 2),
                     "transaction_bytes": summary["bytes"]})
    result = {"print_dir": str(print_dir), "shape": list(original.shape), "rates": rows,
              "blank_space": blank_space(original, rates[0]), "sourceafis": None}
    if not sourceafis.available():
        print("SourceAFIS: java or mvn missing; scores skipped", file=sys.stderr)
        return result
    pairs = [(tmp / "original.png", tmp / "original.png")]
    pairs += [(pngs[r], tmp / "original.png") for r in rates]
    start = time.perf_counter()
    scores = sourceafis.score_pairs(pairs, dpi=500, imageio_grey=imageio_grey)
    self_score = float(scores[0])
    for row, score in zip(rows, scores[1:], strict=True):
        row["score_vs_original"] = round(float(score), 1)
        row["score_ratio"] = round(float(score) / self_score, 3)
        row["passes_0.95"] = bool(score >= 0.95 * self_score)
    result["sourceafis"] = {"self_score": round(self_score, 1),
                            "seconds": round(time.perf_counter() - start, 1)}
    return result


def real_print_rates(prints: Path, rates, tmp: Path, *, imageio_grey: bool = False) -> dict:
    """WSQ ratio, RMS and SourceAFIS score against itself of each real print at each rate."""
    import sourceafis

    from nail2nail.io.prints import decode_wsq, encode_wsq, read_print_image

    rows, pairs, blank = [], [], {}
    for path in sorted(prints.glob("*.png")):
        image, _ = read_print_image(path)
        blank[path.name] = blank_space(image, rates[0])
        original = sourceafis.save_png(tmp / f"real_{path.stem}.png", image)
        pairs.append((original, original))
        for rate in rates:
            data = encode_wsq(image, bitrate=rate)
            decoded = decode_wsq(data, name=path.name)
            rms = float(np.sqrt(np.mean((decoded.astype(float) - image) ** 2)))
            pairs.append((sourceafis.save_png(tmp / f"real_{path.stem}_{rate:g}.png", decoded),
                          original))
            rows.append({"print": path.name, "shape": list(image.shape), "bitrate_bpp": rate,
                         "achieved_bpp": round(8 * len(data) / image.size, 3),
                         "ratio": round(image.size / len(data), 2), "rms_grey": round(rms, 2)})
    result = {"prints": str(prints), "rates": rows, "blank_space": blank, "sourceafis": None}
    if not rows or not sourceafis.available():
        return result
    scores = sourceafis.score_pairs(pairs, dpi=500, imageio_grey=imageio_grey)
    per_print = len(rates) + 1
    for k, row in enumerate(rows):
        block, offset = divmod(k, len(rates))
        self_score = float(scores[block * per_print])
        score = float(scores[block * per_print + 1 + offset])
        row["self_score"] = round(self_score, 1)
        row["score_vs_original"] = round(score, 1)
        row["score_ratio"] = round(score / self_score, 3)
    result["sourceafis"] = True
    return result


def ten_fingers(scale: float, tmp: Path) -> dict:
    from test_interchange import _independent_read

    from nail2nail.calibration.files import RigCalibration, save_calibration
    from nail2nail.cli import main
    from nail2nail.interchange import read_transaction
    from nail2nail.simulation.capture import simulate_capture
    from nail2nail.simulation.rig import default_rig, ideal_calibration

    rig = default_rig(scale, projector_distortion="none")
    calib = tmp / "rig.json"
    save_calibration(calib, RigCalibration.from_dict(ideal_calibration(rig)))
    start = time.perf_counter()
    lines = ["capture,subject,finger_position"]
    for position in range(1, 11):
        name = f"finger{position:02d}"
        simulate_capture(tmp / "captures" / name, "finger", rig=rig, seed=position,
                         write_truth=False)
        lines.append(f"{name},person1,{position}")
    (tmp / "subjects.csv").write_text("\n".join(lines) + "\n")
    simulated = time.perf_counter() - start
    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):  # its table: not in this script's --json
        code = main(["-q", "batch", str(tmp / "captures" / "*"), "--calib", str(calib),
                     "--out", str(tmp / "out"), "--workers", "2", "--subjects",
                     str(tmp / "subjects.csv")])
    batch_s = time.perf_counter() - start
    path = tmp / "out" / "transactions" / "person1.an2"
    back = read_transaction(path)
    records = _independent_read(path.read_bytes())["records"]
    assert code == 0 and [int(r[13]) for r in back["type14"]] == list(range(1, 11))
    assert [int(f[13]) for _, f in records[1:]] == list(range(1, 11))
    sizes = [len(r[999]) for r in back["type14"]]
    pixels = [img.size for img in back["images"]]
    return {"scale": scale, "simulate_s": round(simulated, 1), "batch_s": round(batch_s, 1),
            "records": [t for t, _ in records], "bytes": path.stat().st_size,
            "ratios": [round(n / s, 2) for n, s in zip(pixels, sizes, strict=True)],
            "impression": sorted({r[3] for r in back["type14"]})}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--print-dir", type=Path, default=None)
    parser.add_argument("--demo-scale", type=float, default=1.0)
    parser.add_argument("--rates", type=float, nargs="+", default=[0.75, 0.6, 0.55])
    parser.add_argument("--scale", type=float, default=0.25)
    parser.add_argument("--real-prints", default=str(ROOT.parent / "shared" / "data" / "prints"),
                        help="directory of real 500 ppi prints (PNG) to measure the codec on; "
                             "'' skips them")
    parser.add_argument("--no-batch", action="store_true")
    parser.add_argument("--imageio-grey", action="store_true",
                        help="SourceAFIS reads the grey PNGs through ImageIO, brightened, as "
                             "before 2026-12-08 (bench/sourceafis.py)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="nist_roundtrip_") as tmp_name:
        tmp = Path(tmp_name)
        results = {"wsq": wsq_rates(demo_print_dir(args, tmp), args.rates, tmp,
                                    imageio_grey=args.imageio_grey)}
        if args.real_prints and Path(args.real_prints).is_dir():
            results["real_prints"] = real_print_rates(Path(args.real_prints), args.rates, tmp,
                                                      imageio_grey=args.imageio_grey)
        if not args.no_batch:
            (tmp / "batch").mkdir()
            results["ten_fingers"] = ten_fingers(args.scale, tmp / "batch")
    if args.json:
        print(json.dumps(results, indent=2))
        return results
    w = results["wsq"]
    print(f"demo print {w['print_dir']} ({w['shape'][1]} x {w['shape'][0]} px)")
    if w["sourceafis"]:
        print(f"SourceAFIS: original vs itself {w['sourceafis']['self_score']}")
    for r in w["rates"]:
        score = (f", SourceAFIS {r['score_vs_original']} = {r['score_ratio']:.3f} x self "
                 f"({'pass' if r['passes_0.95'] else 'FAIL'} >= 0.95)"
                 if "score_ratio" in r else "")
        print(f"  WSQ {r['bitrate_bpp']:g} bpp: achieved {r['achieved_bpp']:.3f} bpp, "
              f"{r['ratio']:.2f}:1, RMS grey error {r['rms_grey']:.2f}{score}")
    def blank_line(name, b):
        print(f"  {name}: blank {100 * b['blank_fraction']:.0f} %; WSQ {args.rates[0]:g} bpp on "
              f"the box of its ridges ({b['ridge_box_shape'][1]} x {b['ridge_box_shape'][0]} "
              f"px): {b['ridge_box_ratio']:.2f}:1, {b['ridge_box_bpp']:.3f} bpp")

    blank_line("demo print", w["blank_space"])
    for r in results.get("real_prints", {}).get("rates", []):
        score = (f", SourceAFIS {r['score_vs_original']} = {r['score_ratio']:.3f} x self"
                 if "score_ratio" in r else "")
        print(f"  real {r['print']} ({r['shape'][1]} x {r['shape'][0]} px), WSQ "
              f"{r['bitrate_bpp']:g} bpp: achieved {r['achieved_bpp']:.3f} bpp, "
              f"{r['ratio']:.2f}:1, RMS grey error {r['rms_grey']:.2f}{score}")
    for name, b in results.get("real_prints", {}).get("blank_space", {}).items():
        blank_line(f"real {name}", b)
    if "ten_fingers" in results:
        t = results["ten_fingers"]
        print(f"ten virtual captures (scale {t['scale']}): simulate {t['simulate_s']} s, batch "
              f"{t['batch_s']} s; transaction {t['bytes']} bytes, records {t['records']}, "
              f"IMP {t['impression']}, ratios {min(t['ratios'])}-{max(t['ratios'])}:1; read "
              "back by nistitl and the independent reader")
    return results


if __name__ == "__main__":
    main()
