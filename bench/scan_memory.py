"""Peak memory of ``nail2nail scan`` on a capture 4x the default pixel count (issue 10).

Rendering the virtual finger at scale 2 (2048 x 2560 px per camera) is slow, so the capture is
synthesised: the finger is rendered at scale 1 (``nail2nail simulate``), every frame is
upsampled x2 (Pillow bilinear, which keeps the pixel-centre convention: new pixel ``x'`` samples
old ``(x' + 1/2) / 2 - 1/2``), and the calibration is the rig's ideal one with each camera
scaled by :func:`nail2nail.simulation.rig.scale_camera` (``c' = (c + 1/2) 2 - 1/2``, the same
mapping). The scan then runs in a child process; its peak resident set size is
``ru_maxrss`` of ``resource.getrusage(RUSAGE_CHILDREN)`` in a wrapper process that runs
nothing else. Also measured for the scale-1 capture, for comparison.

Usage::

    python bench/scan_memory.py [--work bench-output/scan_memory] [--reuse]

Prints a JSON summary (peak RSS in MiB, wall time, valid pixels per camera) and writes it to
``WORK/summary.json``.

Measured (2 shared cores, ``--reuse``): before the banded scan, 1378 MiB / 24 s at 1024 x 1280
and 5005 MiB / 76 s at 2048 x 2560 (every camera's float32 frames and whole-image float64
triangulation temporaries); with one camera's 8-bit frames at a time and bands of rows
(``scanning.BAND_PIXELS``), 409 MiB / 13 s and 871 MiB / 39 s, same valid pixels per camera.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

TARGET_MIB = 2048


def _peak_rss(cmd: list[str]) -> tuple[int, float, int]:
    """(exit code, wall seconds, peak RSS in KiB) of `cmd` run in a fresh wrapper process."""
    wrapper = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
               "rc = subprocess.run(sys.argv[1:]).returncode; "
               "print('RSS', rc, time.perf_counter() - t, "
               "resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", wrapper, *cmd], capture_output=True, text=True)
    line = [ln for ln in out.stdout.splitlines() if ln.startswith("RSS ")]
    if not line:
        raise RuntimeError(f"measurement failed: {out.stdout} {out.stderr}")
    _, rc, wall, rss = line[-1].split()
    if int(rc) != 0:
        sys.stderr.write(out.stderr[-3000:])
    return int(rc), float(wall), int(rss)


def _upsample_capture(src: Path, dst: Path, factor: int = 2) -> dict:
    from nail2nail.io._json import read_json, write_json
    from nail2nail.io.capture import read_frame, write_frame
    from nail2nail.simulation.rig import Rig, ideal_calibration, scale_camera

    manifest = read_json(src / "capture.json")
    bit_depth = manifest.get("bit_depth", 8)
    for cam in manifest["cameras"]:
        for rel in cam["frames"]:
            frame = read_frame(src / rel, bit_depth=bit_depth)
            h, w = frame.shape
            big = np.asarray(Image.fromarray(frame).resize((w * factor, h * factor),
                                                           Image.Resampling.BILINEAR))
            levels = 2**bit_depth - 1
            values = np.rint(np.clip(big, 0, 1) * levels)
            if bit_depth == 8:
                out = values.astype(np.uint8)
            else:
                out = (values.astype(np.uint16) << (16 - bit_depth)).astype(np.uint16)
            write_frame(dst / rel, out)
        cam["size"] = [int(v) * factor for v in cam["size"]]
    rig = Rig.from_dict(manifest["rig"])
    rig.cameras = [scale_camera(c, factor) for c in rig.cameras]
    rig.scale = rig.scale * factor
    manifest["rig"] = rig.to_dict()
    manifest.pop("truth", None)
    write_json(dst / "calib.json", ideal_calibration(rig))
    write_json(dst / "capture.json", manifest)
    return manifest


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, default=Path("bench-output/scan_memory"))
    p.add_argument("--reuse", action="store_true", help="reuse captures already in --work")
    args = p.parse_args(argv)
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    exe = [str(Path(sys.executable).with_name("nail2nail"))]
    cap1, cap2 = work / "cap1", work / "cap2"
    summary: dict = {"target_mib": TARGET_MIB}
    if not (args.reuse and (cap1 / "capture.json").is_file()):
        t = time.perf_counter()
        subprocess.run([*exe, "simulate", "--scene", "finger", "--out", str(cap1)], check=True)
        summary["simulate_s"] = round(time.perf_counter() - t, 1)
        from nail2nail.io._json import read_json, write_json
        from nail2nail.simulation.rig import Rig, ideal_calibration

        write_json(cap1 / "calib.json",
                   ideal_calibration(Rig.from_dict(read_json(cap1 / "capture.json")["rig"])))
    if not (args.reuse and (cap2 / "capture.json").is_file()):
        t = time.perf_counter()
        _upsample_capture(cap1, cap2)
        summary["upsample_s"] = round(time.perf_counter() - t, 1)
    from nail2nail.io._json import read_json

    for label, cap in (("scale1", cap1), ("scale2", cap2)):
        manifest = read_json(cap / "capture.json")
        out = work / f"scans_{label}"
        rc, wall, rss_kib = _peak_rss([*exe, "scan", str(cap), "--calib", str(cap / "calib.json"),
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
        summary[label] = entry
        print(label, json.dumps(entry), flush=True)
    summary["within_target"] = summary["scale2"]["peak_rss_mib"] <= TARGET_MIB
    (work / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
