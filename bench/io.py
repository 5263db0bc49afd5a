"""Reading frames and writing outputs at the speed of the disk (issue 11): one run, ratios.

Usage::

    .venv/bin/python bench/io.py [--capture DIR] [--scans DIR] [--calib RIG.json]
                                 [--repeats 5] [--json]

Defaults: the demo's finger capture (``demo-output/captures/finger``) and its scans
(``demo-output/scans/best/finger``, only read); without those scans the capture is scanned now
with ``--calib`` (``demo-output/calib/rig_best.json``); without the capture, a virtual finger
is rendered at scale 0.5 into a temporary directory and scanned with its true calibration.
Every file is written into a temporary directory (page cache: no ``fsync``, as the writers).

Prints, as medians of `repeats` interleaved runs:

- **frame reading** of every camera's PNG frames: a plain sequential PIL loop
  (``np.asarray(Image.open(f))``), the same loop in ``min(os.cpu_count(), n)`` threads, and
  nail2nail's reader (``read_capture(load=False)`` + ``Capture.load_frames(raw=True)`` per
  camera: every check, frames decoded in threads straight into the stack), with ratios;
- **scan outputs** per format, all cameras: seconds to write and to read back, MB on disk,
  and the write time as a multiple of the frame reading (the job's whole budget is 3 ×):
  the scan ``.npz`` in the packed layout (stored, as written; and with zlib 6), the layout
  before issue 11 (every array whole, ``np.savez_compressed``) and whole but uncompressed
  (``np.savez``) as peers; the PLY point clouds; the legacy mat5 sets; ``save_scans`` with
  them all (a scan directory as ``nail2nail scan`` writes it, cameras in threads) and
  ``load_scans``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ARRAYS = ("xyz", "xp", "yp", "albedo", "intensity", "modulation", "mask")


def _median_times(tasks: dict, repeats: int, setup=None) -> dict[str, float]:
    """Median seconds of each task (name -> function), the tasks interleaved per repeat;
    ``setup(name)``, if given, runs before each, untimed."""
    times = {name: [] for name in tasks}
    for _ in range(repeats):
        for name, task in tasks.items():
            if setup is not None:
                setup(name)
            start = time.perf_counter()
            task()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def frame_reading(capture_dir: Path, repeats: int) -> dict:
    """Seconds to read every camera's frames: plain PIL loop, threaded PIL loop, nail2nail."""
    from PIL import Image

    from nail2nail.io.capture import read_capture

    capture = read_capture(capture_dir, load=False)
    files = [capture.path / f for name in capture.camera_names
             for f in capture.camera(name)["frames"]]

    def decode(file):
        with Image.open(file) as im:
            return np.asarray(im)

    def plain():
        for file in files:
            decode(file)

    def plain_threads():
        with ThreadPoolExecutor(max_workers=min(os.cpu_count() or 1, len(files))) as pool:
            list(pool.map(decode, files))

    def ours():
        cap = read_capture(capture_dir, load=False)
        for name in cap.camera_names:
            cap.load_frames(name, raw=True)

    ours()  # the page cache warm for every contender
    seconds = _median_times({"plain": plain, "plain_threads": plain_threads, "ours": ours},
                            repeats)
    frame = decode(files[0])
    return {"files": len(files), "frame": f"{frame.shape[1]} x {frame.shape[0]} {frame.dtype}",
            "cpus": os.cpu_count(), **{k: round(v, 3) for k, v in seconds.items()},
            "ours_over_plain": round(seconds["ours"] / seconds["plain"], 2),
            "ours_over_plain_threads": round(seconds["ours"] / seconds["plain_threads"], 2)}


def _scans(args, work: Path) -> list:
    from nail2nail.io.scans import load_scans

    if args.scans is not None and (args.scans / "scan.json").is_file():
        return load_scans(args.scans)
    from nail2nail.calibration.files import load_calibration
    from nail2nail.io.capture import read_capture
    from nail2nail.scan.capture import scan_capture

    calib = args.calib if args.calib is not None and args.calib.is_file() else (
        args.capture / "truth" / "calibration.json")
    print(f"scanning {args.capture} with {calib} …", file=sys.stderr, flush=True)
    return scan_capture(read_capture(args.capture, load=False), load_calibration(calib))


def _size(paths) -> int:
    return sum(Path(p).stat().st_size for p in paths)


def scan_outputs(scans: list, work: Path, repeats: int) -> dict:
    """Write and read seconds and MB of each scan format, for all cameras."""
    from nail2nail.io.mat5 import MAT5_SUFFIXES, read_mat5, write_mat5
    from nail2nail.io.ply import read_ply, write_scan_ply
    from nail2nail.io.scans import load_scan_npz, load_scans, save_scan_npz, save_scans

    def whole(scan) -> dict:
        arrays = {k: getattr(scan, k) for k in ARRAYS}
        return {"name": np.array(scan.name), **arrays,
                "camera_center": np.asarray(scan.camera_center, dtype=float)}

    def npz_writer(kind):
        def write():
            for scan in scans:
                path = work / kind / f"{scan.name}.npz"
                if kind == "npz_packed":
                    save_scan_npz(path, scan)
                elif kind == "npz_packed_zlib6":
                    save_scan_npz(path, scan, compress=True)
                else:
                    save = np.savez_compressed if kind == "npz_layout1_zlib6" else np.savez
                    with open(path, "wb") as fh:
                        save(fh, **whole(scan))
        return write

    kinds = {
        "npz_packed": "packed layout, floats stored (save_scan_npz default)",
        "npz_packed_zlib6": "packed layout, zlib 6 (compress=True)",
        "npz_layout1_zlib6": "before issue 11: whole arrays, np.savez_compressed",
        "npz_layout1_stored": "whole arrays, np.savez (peer)",
        "ply": "binary PLY point clouds (write_scan_ply)",
        "mat5": "legacy mat5 sets (write_mat5)",
        "scan_dir": "save_scans: npz + PLY + mat5 + scan.json, cameras in threads",
    }
    def fresh(kind):  # every write into an empty directory (replacing files costs more)
        shutil.rmtree(work / kind, ignore_errors=True)
        (work / kind).mkdir(parents=True)

    writers = {kind: npz_writer(kind) for kind in kinds if kind.startswith("npz")}
    writers["ply"] = lambda: [write_scan_ply(work / "ply" / f"{s.name}.ply", s) for s in scans]
    writers["mat5"] = lambda: [write_mat5(work / "mat5" / s.name, s) for s in scans]
    writers["scan_dir"] = lambda: save_scans(work / "scan_dir" / "out", scans)
    write = _median_times(writers, repeats, setup=fresh)

    readers = {kind: (lambda kind=kind: [load_scan_npz(work / kind / f"{s.name}.npz")
                                         for s in scans]) for kind in writers if
               kind.startswith("npz")}
    readers["ply"] = lambda: [read_ply(work / "ply" / f"{s.name}.ply") for s in scans]
    readers["mat5"] = lambda: [read_mat5(work / "mat5" / s.name) for s in scans]
    readers["scan_dir"] = lambda: load_scans(work / "scan_dir" / "out")
    read = _median_times(readers, repeats)

    sizes = {kind: _size(p for p in (work / kind).iterdir() if p.is_file())
             for kind in kinds if kind != "scan_dir"}
    sizes["scan_dir"] = _size((work / "scan_dir" / "out").iterdir())
    assert all(len(list((work / "mat5").glob(f"*{s}"))) == len(scans) for s in MAT5_SUFFIXES)
    return {kind: {"what": what, "write_s": round(write[kind], 3),
                   "read_s": round(read[kind], 3), "mb": round(sizes[kind] / 1e6, 1)}
            for kind, what in kinds.items()}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--capture", type=Path, default=REPO / "demo-output/captures/finger")
    p.add_argument("--scans", type=Path, default=REPO / "demo-output/scans/best/finger",
                   help="scan directory to take the scans from (only read)")
    p.add_argument("--calib", type=Path, default=REPO / "demo-output/calib/rig_best.json",
                   help="calibration to scan the capture with when --scans has none")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json", action="store_true", help="print the figures as JSON only")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="nail2nail-io-") as tmp:
        work = Path(tmp)
        if not (args.capture / "capture.json").is_file():
            from nail2nail.simulation.capture import simulate_capture

            print("rendering a virtual finger (scale 0.5) …", file=sys.stderr, flush=True)
            args.capture, args.scans, args.calib = work / "finger", None, None
            simulate_capture(args.capture, "finger", scale=0.5)
        frames = frame_reading(args.capture, args.repeats)
        scans = _scans(args, work)
        outputs = scan_outputs(scans, work / "out", args.repeats)
        shutil.rmtree(work / "out", ignore_errors=True)
    report = {"capture": str(args.capture), "cameras": [s.name for s in scans],
              "valid_pixels": [int(s.mask.sum()) for s in scans], "frames": frames,
              "outputs": outputs}
    if args.json:
        print(json.dumps(report, indent=2))
        return report
    f = frames
    print(f"frame reading, {f['files']} PNG files of {f['frame']}, {f['cpus']} CPUs "
          f"(median of {args.repeats}):")
    print(f"  plain PIL loop        {f['plain']:7.3f} s")
    print(f"  plain PIL, threads    {f['plain_threads']:7.3f} s")
    print(f"  nail2nail load_frames {f['ours']:7.3f} s   {f['ours_over_plain']:.2f} x plain, "
          f"{f['ours_over_plain_threads']:.2f} x threaded")
    layout1 = outputs["npz_layout1_zlib6"]
    print(f"scan outputs, {len(scans)} cameras {scans[0].shape[1]} x {scans[0].shape[0]}, "
          f"{sum(report['valid_pixels'])} valid pixels:")
    print(f"  {'format':20s} {'write s':>8s} {'read s':>8s} {'MB':>7s} {'write/frames':>12s} "
          f"{'vs layout 1 (w, r, MB)':>24s}")
    for kind, o in outputs.items():
        vs = ""
        if kind.startswith("npz"):
            vs = (f"{o['write_s'] / layout1['write_s']:6.2f} {o['read_s'] / layout1['read_s']:6.2f}"
                  f" {o['mb'] / layout1['mb']:6.2f}")
        print(f"  {kind:20s} {o['write_s']:8.3f} {o['read_s']:8.3f} {o['mb']:7.1f} "
              f"{o['write_s'] / f['ours']:12.2f} {vs:>24s}")
    for kind, o in outputs.items():
        print(f"    {kind}: {o['what']}")
    return report


if __name__ == "__main__":
    main()
