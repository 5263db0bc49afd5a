"""Fuzz every file reader with ≥ 10⁵ generated cases (issue 10); the CI version is
``tests/test_fuzz_readers.py`` (same targets, a few thousand cases, derandomized).

Each case: a valid file written by nail2nail's writer, mutated by hypothesis (byte edits for
binary formats, structured edits for JSON and points tables, odd PNG/npz/PLY built from
scratch); the reader must return a valid object or raise ``ValueError``/``TypeError``/
``OSError`` naming the file, within 10 s, opening nothing outside the case directory.

Usage::

    python bench/fuzz_readers.py [--cases 10000] [--seed 0] [--only ply,npz] [--keep DIR]

Prints per reader: cases, failures (distinct messages, first few), seconds; exits 1 if any
case failed. ``--keep DIR`` copies the case directory of each failing case (the input files
as the reader saw them) to ``DIR/READER-N/`` with the message in ``problem.txt``, to turn
into a regression test.
"""

from __future__ import annotations

import argparse
import collections
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_fuzz_readers as fuzz


class _Failures(collections.Counter):
    def __init__(self, case_dir: Path | None = None, keep: Path | None = None, name: str = ""):
        super().__init__()
        self.case_dir, self.keep, self.name = case_dir, keep, name

    def update_one(self, message: str) -> None:
        self[message] += 1
        if self.keep is not None:
            n = sum(self.values())
            dest = self.keep / f"{self.name}-{n}"
            shutil.rmtree(dest, ignore_errors=True)
            shutil.copytree(self.case_dir, dest, symlinks=True)
            (dest / "problem.txt").write_text(message + "\n")


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=10_000, help="cases per reader")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", default="", help="comma-separated reader names")
    p.add_argument("--keep", type=Path, default=None,
                   help="copy each failing case directory here (DIR/READER-N/)")
    args = p.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or sorted(fuzz.TARGETS)
    report = {}
    with tempfile.TemporaryDirectory(prefix="nail2nail-fuzz-") as tmp:
        base = Path(tmp)
        originals = fuzz.make_originals(base)
        for name in names:
            failures = _Failures(base / f"case_{name}", args.keep, name)
            start = time.perf_counter()
            cases = fuzz.run_target(name, originals, base / f"case_{name}",
                                    max_examples=args.cases, derandomize=False,
                                    seed=args.seed, on_failure=failures.update_one)
            seconds = time.perf_counter() - start
            report[name] = {"cases": cases, "failures": sum(failures.values()),
                            "distinct": [m[:200] for m, _ in failures.most_common(5)],
                            "seconds": round(seconds, 1)}
            print(f"{name:15s} {cases:7d} cases {sum(failures.values()):5d} failures "
                  f"{seconds:7.1f} s", flush=True)
            for message, count in failures.most_common(5):
                print(f"    {count:5d}  {message[:200]}", flush=True)
    total = sum(r["cases"] for r in report.values())
    failed = sum(r["failures"] for r in report.values())
    seconds = sum(r["seconds"] for r in report.values())
    print(f"{'total':15s} {total:7d} cases {failed:5d} failures {seconds:7.1f} s")
    print(json.dumps(report, indent=1))
    return report


if __name__ == "__main__":
    result = main()
    sys.exit(1 if any(r["failures"] for r in result.values()) else 0)
