"""Fuzz the command-line options of the commands of issue 29 with ≥ 10⁵ generated cases; the
CI version is ``tests/test_fuzz_cli.py`` (same commands and invariant, a few hundred cases).

Each case: one command line run in-process through ``nail2nail.cli._main.main``, 1 to 3 of its
options (sometimes a flag or two beside them) given generated values (huge, tiny, negative,
zero, NaN, infinities, non-numbers, empty and very long strings, invalid choices, paths that
are directories, missing, FIFOs, empty or junk files); the invariant of
``tests/test_fuzz_cli.py``: exit 0 or 2, exit 2 one error line naming the option (or the
input that stops the run), nothing written, at most 30 s (``--seconds``) and 1 GiB
a case.

Usage::

    python bench/fuzz_cli.py [--cases 100000] [--seed 0] [--only report,simulate]
                             [--no-tracemalloc] [--seconds 30]

``--cases`` is the total, shared equally by the commands. Prints per command: cases, exit
0 / exit 2, failures (the first few, distinct), findings (a NaN accepted, or refused only by
the input that stops the run), the failures already known (``KNOWN_UNNAMED``,
``KNOWN_HANGS`` of the test file: reported, not counted as failures), seconds, the slowest case
and the largest memory; exits 1 if any case failed.
"""

from __future__ import annotations

import argparse
import collections
import json
import random
import re
import shutil
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_fuzz_cli as fuzz


def _shape(problem: str) -> str:
    """A failure's message with its values blanked (quoted text, numbers, long runs), so that
    the failures of one cause count together."""
    text = re.sub(r"'[^']*'", "'…'", problem)
    text = re.sub(r"(?<![\w-])[-+]?\d[\w.+-]*", "N", text)
    return re.sub(r"(\S)\1{20,}", r"\1…", text)[:160]


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=100_000, help="cases in all (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", default="", help="comma-separated commands "
                   f"({', '.join(fuzz.COMMANDS)})")
    p.add_argument("--no-tracemalloc", action="store_true",
                   help="measure memory by the peak resident size only (faster)")
    p.add_argument("--seconds", type=float, default=fuzz.CASE_SECONDS,
                   help=f"time limit of a case (default {fuzz.CASE_SECONDS:g} s)")
    args = p.parse_args(argv)
    fuzz.CASE_SECONDS = args.seconds
    commands = [c for c in args.only.split(",") if c] or list(fuzz.COMMANDS)
    unknown = sorted(set(commands) - set(fuzz.COMMANDS))
    if unknown:
        p.error(f"--only: unknown commands {unknown}")
    per_command = max(1, args.cases // len(commands))
    if not args.no_tracemalloc:
        tracemalloc.start()
    report = {}
    with tempfile.TemporaryDirectory(prefix="nail2nail-fuzz-cli-") as tmp:
        base = Path(tmp)
        fixtures = fuzz.make_fixtures(base / "fixtures")
        before = fuzz._tree(fixtures.root)
        for command in commands:
            options = fuzz.command_options(command)
            failures: collections.Counter = collections.Counter()
            examples: dict[str, str] = {}
            findings: collections.Counter = collections.Counter()
            known: collections.Counter = collections.Counter()
            codes: collections.Counter = collections.Counter()
            slowest, heaviest = (0.0, ""), (0.0, "")
            start = time.perf_counter()
            for i in range(per_command):
                rng = random.Random(f"{args.seed}-{command}-{i}")
                cmd, fuzzed = fuzz.random_case(command, fixtures, options, rng)
                argv_ = fuzz.argv_of(cmd)
                outcome = fuzz.check_case(cmd, fuzzed, fuzz.run_case(argv_, base / "case"),
                                          (fixtures.root,))
                codes[outcome.rc] += 1
                shown = " ".join(a if len(a) < 60 else a[:57] + "..." for a in argv_[1:])
                shown = shown.replace(str(fixtures.root), "FIXTURES")
                if outcome.seconds > slowest[0]:
                    slowest = (outcome.seconds, shown)
                if outcome.mebibytes > heaviest[0]:
                    heaviest = (outcome.mebibytes, shown)
                if outcome.problem:
                    key = f"{' '.join(o.name for o in fuzzed)}: {_shape(outcome.problem)}"
                    failures[key] += 1
                    examples.setdefault(key, shown)
                if outcome.known:
                    known[f"{' '.join(o.name for o in fuzzed)}: {_shape(outcome.known)}"] += 1
                for finding in outcome.findings:
                    findings[finding.split(":")[0] + ": " + " ".join(
                        o.name for o in fuzzed)] += 1
            shutil.rmtree(base / "case", ignore_errors=True)
            seconds = time.perf_counter() - start
            report[command] = {
                "cases": per_command, "exit_0": codes[0], "exit_2": codes[2],
                "failures": sum(failures.values()),
                "distinct": [{"count": n, "problem": k, "example": examples[k]}
                             for k, n in failures.most_common(8)],
                "findings": dict(findings.most_common(8)),
                "known": sum(known.values()), "known_distinct": dict(known.most_common(8)),
                "seconds": round(seconds, 1),
                "slowest_s": round(slowest[0], 2), "slowest": slowest[1],
                "peak_mib": round(heaviest[0], 1)}
            print(f"{command:19s} {per_command:7d} cases  exit 0: {codes[0]:6d}  exit 2: "
                  f"{codes[2]:6d}  failures {sum(failures.values()):5d}  known "
                  f"{sum(known.values()):4d}  findings {sum(findings.values()):4d}  "
                  f"{seconds:7.1f} s (slowest {slowest[0]:.2f} s, peak {heaviest[0]:.0f} MiB)",
                  flush=True)
            for key, n in failures.most_common(8):
                print(f"    {n:5d}  {key}\n           e.g. {examples[key][:300]}", flush=True)
            for key, n in known.most_common(4):
                print(f"    {n:5d}  known: {key}", flush=True)
            for key, n in findings.most_common(8):
                print(f"    {n:5d}  finding: {key}", flush=True)
        if fuzz._tree(fixtures.root) != before:
            print("the fixtures were changed by a case", flush=True)
            report["fixtures_changed"] = True  # type: ignore[assignment]
    total = sum(r["cases"] for r in report.values() if isinstance(r, dict))
    failed = sum(r["failures"] for r in report.values() if isinstance(r, dict))
    print(f"{'total':19s} {total:7d} cases  failures {failed}")
    print(json.dumps(report, indent=1))
    return report


if __name__ == "__main__":
    result = main()
    sys.exit(1 if any(not isinstance(r, dict) or r["failures"] for r in result.values())
             else 0)
