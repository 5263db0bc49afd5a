"""Peak memory of a scan: one 2.3 Mpx camera (issue 11) and captures 1x and 4x the default size
(issue 10).

Rendering the virtual finger above scale 1 is slow, so larger captures are synthesised: the
finger is rendered at scale 1 (``nail2nail simulate``, 1024 x 1280 px per camera), every frame is
upsampled (Pillow bilinear, which keeps the pixel-centre convention: new pixel ``x'`` samples old
``(x' + 1/2) / f - 1/2``), and the calibration is the rig's ideal one with each camera scaled by
:func:`nail2nail.simulation.rig.scale_camera` (``c' = (c + 1/2) f - 1/2``, the same mapping).
``f = 21/16`` gives the one-camera 1344 x 1680 capture (2.26 Mpx, the size of a 1920 x 1200
camera), ``f = 2`` the 2048 x 2560 one.

Every scan runs in a child process; its peak resident set size is ``ru_maxrss`` of
``resource.getrusage(RUSAGE_CHILDREN)`` in a wrapper process that runs nothing else. Measured:
the library's :func:`nail2nail.scan.capture.scan_capture` alone (``lib``, both methods) and the
whole
``nail2nail scan`` command, which also writes the mat5, PLY and npz files (``cli``).

Usage::

    python bench/scan_memory.py [--work bench-output/scan_memory] [--reuse] [--no-scale2]

Prints a JSON summary (peak RSS in MiB, wall time, valid pixels per camera) and writes it to
``WORK/summary.json``.

Measured (2 shared cores, ``--reuse``): before the banded scan, 1378 MiB / 24 s at 1024 x 1280
and 5005 MiB / 76 s at 2048 x 2560 (every camera's float32 frames and whole-image float64
triangulation temporaries); with one camera's 8-bit frames at a time and bands of rows
(``scanning.BAND_PIXELS``), 409 MiB / 13 s and 871 MiB / 39 s, same valid pixels per camera.
Issue 11, the fused kernel (one camera's 8-bit frames, the outputs and per-row temporaries): see
``WORK/summary.json`` and the README.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from fractions import Fraction
from pathlib import Path

import numpy as np
from PIL import Image

#: Peak RSS target of ``nail2nail scan`` at 4x the default size (issue 10).
TARGET_MIB = 2048
#: Peak RSS target of scanning one 2.3 Mpx camera with the library (issue 11).
TARGET_ONE_CAMERA_MIB = 400

_LIBRARY_SCAN = (
    "import sys; from nail2nail.calibration.files import load_calibration; "
    "from nail2nail.io.capture import read_capture; from nail2nail.scan.capture import "
    "scan_capture; "
    "scans = scan_capture(read_capture(sys.argv[1], load=False), load_calibration(sys.argv[2]), "
    "method=sys.argv[3]); print('VALID', *(int(s.mask.sum()) for s in scans))"
)


def _peak_rss(cmd: list[str]) -> tuple[int, float, int, str]:
    """(exit code, wall seconds, peak RSS in KiB, stdout) of `cmd` run in a fresh wrapper."""
    wrapper = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
               "out = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
               "sys.stderr.write(out.stderr); print(out.stdout); "
               "print('RSS', out.returncode, time.perf_counter() - t, "
               "resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", wrapper, *cmd], capture_output=True, text=True)
    line = [ln for ln in out.stdout.splitlines() if ln.startswith("RSS ")]
    if not line:
        raise RuntimeError(f"measurement failed: {out.stdout} {out.stderr}")
    _, rc, wall, rss = line[-1].split()
    if int(rc) != 0:
        sys.stderr.write(out.stderr[-3000:])
    return int(rc), float(wall), int(rss), out.stdout


def _upsample_capture(src: Path, dst: Path, factor: Fraction = Fraction(2),
                      cameras: int | None = None) -> dict:
    """`src` upsampled by `factor` (the sizes must stay integers) into `dst`, with its first
    `cameras` cameras (all by default) and the scaled ideal calibration ``dst/calib.json``."""
    from nail2nail.io._json import read_json, write_json
    from nail2nail.io.capture import read_frame, write_frame
    from nail2nail.simulation.rig import Rig, ideal_calibration, scale_camera

    manifest = read_json(src / "capture.json")
    manifest["cameras"] = manifest["cameras"][:cameras]
    bit_depth = manifest.get("bit_depth", 8)
    for cam in manifest["cameras"]:
        for rel in cam["frames"]:
            frame = read_frame(src / rel, bit_depth=bit_depth)
            h, w = frame.shape
            if (w * factor).denominator != 1 or (h * factor).denominator != 1:
                raise ValueError(f"factor {factor}: {w} x {h} px would not scale to integers")
            size = (int(w * factor), int(h * factor))
            big = np.asarray(Image.fromarray(frame).resize(size, Image.Resampling.BILINEAR))
            levels = 2**bit_depth - 1
            values = np.rint(np.clip(big, 0, 1) * levels)
            if bit_depth == 8:
                out = values.astype(np.uint8)
            else:
                out = (values.astype(np.uint16) << (16 - bit_depth)).astype(np.uint16)
            write_frame(dst / rel, out)
        cam["size"] = [int(v * factor) for v in cam["size"]]
    rig = Rig.from_dict(manifest["rig"])
    rig.cameras = [scale_camera(c, float(factor)) for c in rig.cameras]
    rig.scale = rig.scale * float(factor)
    manifest["rig"] = rig.to_dict()
    manifest.pop("truth", None)
    write_json(dst / "calib.json", ideal_calibration(rig))
    write_json(dst / "capture.json", manifest)
    return manifest


def _measure_cli(exe, cap: Path, out: Path) -> dict:
    from nail2nail.io._json import read_json

    manifest = read_json(cap / "capture.json")
    rc, wall, rss_kib, _ = _peak_rss([*exe, "scan", str(cap), "--calib", str(cap / "calib.json"),
                                      "--out", str(out)])
    entry = {
        "camera_size_wh": manifest["cameras"][0]["size"],
        "n_cameras": len(manifest["cameras"]),
        "n_frames": manifest["n_frames"],
        "exit_code": rc,
        "wall_s": round(wall, 1),
        "peak_rss_mib": round(rss_kib / 1024, 1),
    }
    if rc == 0:
        scans = read_json(out / "scan.json")
        entry["valid_pixels"] = {c["name"]: c.get("valid_pixels") for c in scans["cameras"]}
    return entry


def _measure_library(cap: Path, method: str) -> dict:
    rc, wall, rss_kib, stdout = _peak_rss([sys.executable, "-c", _LIBRARY_SCAN, str(cap),
                                           str(cap / "calib.json"), method])
    valid = [ln.split()[1:] for ln in stdout.splitlines() if ln.startswith("VALID")]
    return {"method": method, "exit_code": rc, "wall_s": round(wall, 1),
            "peak_rss_mib": round(rss_kib / 1024, 1),
            "valid_pixels": [int(v) for v in valid[0]] if valid else None}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, default=Path("bench-output/scan_memory"))
    p.add_argument("--reuse", action="store_true", help="reuse captures already in --work")
    p.add_argument("--no-scale2", action="store_true", help="skip the 2048 x 2560 capture")
    args = p.parse_args(argv)
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    exe = [str(Path(sys.executable).with_name("nail2nail"))]
    cap1, cap2, cap_one = work / "cap1", work / "cap2", work / "cap_2mpx"
    summary: dict = {"target_mib": TARGET_MIB, "target_one_camera_mib": TARGET_ONE_CAMERA_MIB}
    if not (args.reuse and (cap1 / "capture.json").is_file()):
        t = time.perf_counter()
        subprocess.run([*exe, "simulate", "--scene", "finger", "--out", str(cap1)], check=True)
        summary["simulate_s"] = round(time.perf_counter() - t, 1)
        from nail2nail.io._json import read_json, write_json
        from nail2nail.simulation.rig import Rig, ideal_calibration

        write_json(cap1 / "calib.json",
                   ideal_calibration(Rig.from_dict(read_json(cap1 / "capture.json")["rig"])))
    if not (args.reuse and (cap_one / "capture.json").is_file()):
        _upsample_capture(cap1, cap_one, Fraction(21, 16), cameras=1)
    if not args.no_scale2 and not (args.reuse and (cap2 / "capture.json").is_file()):
        t = time.perf_counter()
        _upsample_capture(cap1, cap2)
        summary["upsample_s"] = round(time.perf_counter() - t, 1)

    one = {"camera_size_wh": None, "lib": [], "cli": None}
    from nail2nail.io._json import read_json

    one["camera_size_wh"] = read_json(cap_one / "capture.json")["cameras"][0]["size"]
    first = _measure_library(cap_one, "numba")  # fills numba's cache: compiling takes memory
    one["first_run_peak_rss_mib"] = first["peak_rss_mib"]
    for method in ("numba", "numpy"):
        one["lib"].append(_measure_library(cap_one, method))
        print("one camera, library", json.dumps(one["lib"][-1]), flush=True)
    one["cli"] = _measure_cli(exe, cap_one, work / "scans_2mpx")
    print("one camera, cli", json.dumps(one["cli"]), flush=True)
    one["within_target"] = one["lib"][0]["peak_rss_mib"] <= TARGET_ONE_CAMERA_MIB
    summary["one_camera_2mpx"] = one
    for label, cap in (("scale1", cap1), ("scale2", cap2)):
        if label == "scale2" and args.no_scale2:
            continue
        summary[label] = _measure_cli(exe, cap, work / f"scans_{label}")
        print(label, json.dumps(summary[label]), flush=True)
    if "scale2" in summary:
        summary["within_target"] = summary["scale2"]["peak_rss_mib"] <= TARGET_MIB
    (work / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
