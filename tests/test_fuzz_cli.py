"""Issue 29: derandomised fuzzing of the command-line options of every command.

Each case runs one command line in-process through :func:`nail2nail.cli._main.main`, stdout and
stderr captured, with generated values for one or more options (huge, tiny, negative, zero,
NaN, infinities, non-numbers, empty and very long strings, invalid choices, paths that are
directories, missing, FIFOs, empty or junk files, under a file, too long). The invariant
(:func:`check_case`):

- the exit code is 0 or 2 (never 1, an internal error; argparse's usage errors leave
  :func:`~nail2nail.cli._main.main` as ``SystemExit(2)``, its documented way);
- exit 2: stderr is one line ``nail2nail COMMAND: error: …`` (argparse: its usage block, then
  that line) naming a fuzzed option (its flag, or the value of a fuzzed path) or the input
  that stops the run (below); nothing is written (the case's directory and the fixtures are as
  they were);
- at most :data:`CASE_SECONDS` s and :data:`CASE_MEBIBYTES` MiB (tracemalloc's peak of the
  case, which sees NumPy's arrays, and the growth of the process's peak resident size).

Cases that would pass validation and start real work stay cheap: ``scan``, ``process``,
``batch``, ``unroll``, ``calibrate-board`` and ``simulate`` are given an input that is
refused once the options are checked (a capture whose first frame is corrupt, a scan whose
npz is empty, a glob that matches nothing, a pose directory without ``capture.json``, a
missing ``--patterns`` directory: the command's *stop*); ``report``, ``import-calibration``,
``export-calibration`` and ``print-target`` run on tiny real inputs (exit 0 allowed, its
outputs removed with the case's directory).

Besides the invariant, each case records *findings* that are not failures: a NaN accepted
(exit 0) or refused only by the stop, not by the option's check. ``bench/fuzz_cli.py`` runs
≥ 10⁵ cases with counts per command; this file runs a few hundred, reproducibly.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import random
import resource
import shutil
import string
import sys
import time
import tracemalloc
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from _robustness import Timeout, time_limit
from PIL import Image

from nail2nail.cli._main import build_parser, main
from nail2nail.io._json import write_json
from nail2nail.io.capture import write_frame, write_manifest
from nail2nail.io.ply import write_ply
from nail2nail.scan.patterns import Frequency, PatternSet
from nail2nail.simulation.rig import default_rig, ideal_calibration

#: Longest a case may take, s (the slowest real case, a report, takes about 1 s).
CASE_SECONDS = 30.0
#: Most memory a case may take, MiB (tracemalloc peak; growth of the peak resident size).
CASE_MEBIBYTES = 1024

#: The commands fuzzed (issue 29) and, per command, the options left alone: output format
#: switches and flags that only select what is printed.
COMMANDS = ("unroll", "process", "report", "batch", "import-calibration", "export-calibration",
            "calibrate-board", "print-target", "simulate", "simulate-print", "simulate-board",
            "scan", "export-mesh")
_PARSER_OF = {"simulate-print": "simulate", "simulate-board": "simulate"}

#: Failures this fuzz found in files of other parts of issue 29, reported and not fixed here:
#: ``(command, option) → the message``, an error that names neither the option nor an input.
#: Their cases still run; such a message is counted as known, not as a failure. Each has a
#: strict xfail test below, which fails once it is fixed: then remove the entry.
KNOWN_UNNAMED: dict[tuple[str, str], str] = {}
#: A FIFO given where a JSON file is read waited forever for a writer (fixed: ``read_json``
#: refuses what is not a regular file); none known now.
KNOWN_HANGS: set[tuple[str, str]] = set()
_LEFT_ALONE = {"-q", "--quiet", "--json", "-h", "--help"}

# --------------------------------------------------------------------------------------------
# generated values

NUMBERS = ["0", "-0", "1", "-1", "0.5", "-0.5", "2", "64", "1e308", "-1e308", "1e309", "-1e309",
           "1e-320", "5e-324", "-5e-324", "nan", "NaN", "-nan", "inf", "-inf", "Infinity",
           "2147483647", "2147483648", "-2147483649", "9223372036854775808",
           "18446744073709551616", "1e999999", "1" + "0" * 300, "9" * 5000, "abc", "", " ",
           "1,5", "0x10", "1_000", "1.5", "1e", "٣", "１", "+1", "1e3", "-1e-3", "0.0001"]
STRINGS = ["", " ", "abc", "cam0", "cam1", "cam9", "world", "board", "0-1", "0-0", "1-0",
           "0-1,1-2", "0-9", "-1-0", "a-b", "0-1,", ",", "99999999999999999999-0", "nan", "inf",
           "0,1,0", "0,0,0", "nan,0,0", "1e308,1e308,1e308", "1,2", "1,2,3,4", "cam0=",
           "=x", "cam0=a_dir", "cam9=junk.txt", "cam0=missing.png", "x=y=z", "k1", "k1,k2",
           "none", "full", "radial", "DICT_4X4_50", "DICT_99X99_1", "a" * 5000, "é", "\t",
           "../x", "a/b", "*", "?", "[", "tcp://", "x" * 300]
#: Paths, relative to the case's directory (made afresh for every case).
PATHS = ["missing", "a_dir", "a_fifo", "empty.json", "junk.txt", "empty.json/x", "x" * 300, "",
         ".", "..", "a_dir/", "missing/x.json"]
#: Suffixes tried on output file names (print-target wants .svg/.pdf, export .xml/.yml …).
SUFFIXES = ["", ".svg", ".pdf", ".json", ".yml", ".xml", ".yaml", ".html", ".png", ".txt"]


def _random_number(rng: random.Random) -> str:
    kind = rng.randrange(6)
    if kind == 0:
        return str(rng.randint(-10, 10) * 10 ** rng.randint(0, 30))
    if kind == 1:
        return repr(rng.choice((-1, 1)) * 10 ** rng.uniform(-330, 308))
    if kind == 2:
        return str(rng.randint(-5, 5000))
    if kind == 3:
        return f"{rng.uniform(-2, 2):.{rng.randint(0, 6)}f}"
    if kind == 4:
        return "".join(rng.choice("0123456789.-+eE_ x") for _ in range(rng.randint(1, 12)))
    return rng.choice(NUMBERS)


def _random_string(rng: random.Random) -> str:
    kind = rng.randrange(4)
    if kind == 0:
        alphabet = string.ascii_letters + string.digits + "-_=,.:*?[]~ "
        return "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 40)))
    if kind == 1:
        return ",".join(_random_number(rng) for _ in range(rng.randint(1, 4)))
    if kind == 2:
        return f"{rng.choice(['cam0', 'cam1', 'cam2', 'x', ''])}={rng.choice(PATHS)}"
    return rng.choice(STRINGS)


def _random_path(rng: random.Random) -> str:
    if rng.random() < 0.2:
        return rng.choice(PATHS[:6]) + rng.choice(SUFFIXES)
    return rng.choice(PATHS)


@dataclass
class Option:
    """One option of a command as argparse knows it."""

    flags: tuple[str, ...]  # () for a positional
    dest: str
    kind: str  # "number", "path", "string", "choice", "flag"
    nargs: int = 1
    choices: tuple = ()

    @property
    def name(self) -> str:
        return self.flags[-1] if self.flags else self.dest

    def names(self) -> tuple[str, ...]:
        """How an error may name it: its flags (or a positional's name) and ``-o/--output``
        style pairs."""
        return (*self.flags, self.dest) if not self.flags else self.flags


def command_options(command: str) -> list[Option]:
    """The options of `command` (the parser's), classified by the values they take."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    out = []
    for action in sub.choices[_PARSER_OF.get(command, command)]._actions:
        if set(action.option_strings) & _LEFT_ALONE or isinstance(action, argparse._HelpAction):
            continue
        if action.nargs == 0:
            kind = "flag"
        elif action.choices:
            kind = "choice"
        elif action.type in (int, float) or getattr(action.type, "__name__", "") in (
                "_size", "_vector"):
            kind = "number"
        elif action.type is Path:
            kind = "path"
        else:
            kind = "string"
        nargs = action.nargs if isinstance(action.nargs, int) else 1
        out.append(Option(tuple(action.option_strings), action.dest, kind, nargs,
                          tuple(action.choices or ())))
    return out


def values_for(option: Option, rng: random.Random) -> list[str]:
    """Generated values (one per ``nargs``) for `option`."""
    def one() -> str:
        if option.kind == "number":
            if getattr(option, "dest", "") == "tip_direction":  # "x,y,z"
                return _random_string(rng) if rng.random() < 0.5 else ",".join(
                    _random_number(rng) for _ in range(3))
            return _random_number(rng)
        if option.kind == "path":
            return _random_path(rng)
        if option.kind == "choice":
            return rng.choice([*map(str, option.choices), _random_string(rng)])
        return _random_string(rng)
    return [one() for _ in range(option.nargs)]


# --------------------------------------------------------------------------------------------
# fixtures: tiny inputs, each command's stop


@dataclass
class Fixtures:
    root: Path
    calibration: Path  # pinhole, cam0..cam2, no projector distortion (exportable)
    capture: Path  # cam0, cam1, a pattern set of both directions; cam0's first frame corrupt
    corrupt_frame: Path
    scans: Path  # scan.json naming an empty npz
    merge: Path  # a merge directory: merge.json only (report: real, fast)
    opencv: Path  # the calibration exported (import-calibration: real)
    poses: Path  # a pose directory without capture.json
    print_png: Path  # an 8-bit grayscale print, 500 ppi (simulate --print: read for real)
    patterns: Path  # a missing --patterns directory (simulate's stop)
    mesh: Path  # a directory with a small super.ply mesh (export-mesh: real)


def make_fixtures(root: Path) -> Fixtures:
    """The commands' inputs under `root` (read only during the cases)."""
    root.mkdir(parents=True, exist_ok=True)
    calibration = ideal_calibration(default_rig(0.0625))
    calibration.pop("projector_distortion")
    write_json(root / "calibration.json", calibration)
    pattern = PatternSet(x=(Frequency(1, 3),), y=(Frequency(1, 3),))
    cams = []
    rng = np.random.default_rng(0)
    for name in ("cam0", "cam1"):
        frames = []
        for i in range(pattern.n_frames):
            frames.append(f"{name}/{i:03d}.png")
            write_frame(root / "capture" / frames[-1], rng.integers(0, 256, (80, 64), np.uint8))
        cams.append({"name": name, "size": [64, 80], "frames": frames})
    write_manifest(root / "capture", {"bit_depth": 8, "n_frames": pattern.n_frames,
                                      "pattern_set": pattern.to_dict(), "cameras": cams})
    corrupt = root / "capture" / "cam0" / "000.png"
    corrupt.write_bytes(corrupt.read_bytes()[:40])
    (root / "scans").mkdir()
    (root / "scans" / "cam0.npz").write_bytes(b"")
    write_json(root / "scans" / "scan.json", {"format": "nail2nail-scan", "version": 1,
                                              "cameras": [{"name": "cam0", "npz": "cam0.npz"}]})
    (root / "merge").mkdir()
    write_json(root / "merge" / "merge.json", {"merge": {}})
    opencv = root / "calibration.yml"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["-q", "export-calibration", str(root / "calibration.json"), "-o",
                     str(opencv)]) == 0
    (root / "poses" / "pose00").mkdir(parents=True)
    Image.fromarray(rng.integers(0, 256, (96, 96), np.uint8)).save(root / "print.png",
                                                                    dpi=(500, 500))
    t, h = np.meshgrid(np.linspace(-1, 1, 8), np.linspace(0, 6, 10))
    points = np.stack([5 * np.sin(t), h, 5 * np.cos(t)], -1).reshape(-1, 3)
    idx = np.arange(80).reshape(10, 8)
    faces = np.concatenate([np.stack([idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:]], -1),
                            np.stack([idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]], -1)])
    write_ply(root / "mesh" / "super.ply", points, faces=faces.reshape(-1, 3),
              colors=np.full((80, 3), 128, np.uint8))
    return Fixtures(root, root / "calibration.json", root / "capture", corrupt, root / "scans",
                    root / "merge", opencv, root / "poses" / "pose00", root / "print.png",
                    root / "no_patterns", root / "mesh")


@dataclass
class Command:
    """A command line to fuzz: its positionals, its options (flag → values) and the needles
    that say its stop was reached (empty: it runs for real)."""

    name: str
    positionals: list[str]
    options: dict[str, list[str]]
    stop: tuple[str, ...] = ()
    key: str = ""  # the entry of COMMANDS (simulate-print …)


def base_command(command: str, fx: Fixtures) -> Command:
    """The command line whose options are fuzzed: valid options, the command's stop."""
    cmd = _base_commands(fx)[command]
    cmd.key = command
    return cmd


def _base_commands(fx: Fixtures) -> dict[str, Command]:
    f = {k: str(v) for k, v in vars(fx).items()}
    capture_stop = (f["corrupt_frame"], f["capture"])
    return {
        "unroll": Command("unroll", [f["scans"]], {"--out": ["out_u"]}, (f["scans"],)),
        "process": Command("process", [f["capture"]],
                           {"--calib": [f["calibration"]], "--out": ["out_p"]}, capture_stop),
        "scan": Command("scan", [f["capture"]],
                        {"--calib": [f["calibration"]], "--out": ["out_s"]}, capture_stop),
        "report": Command("report", [f["merge"]], {"--out": ["r.html"],
                                                   "--report-points": ["200"]}),
        "batch": Command("batch", ["nothing_here*"],
                         {"--calib": [f["calibration"]], "--out": ["out_b"]},
                         ("nothing_here*",)),
        "import-calibration": Command("import-calibration", [f["opencv"]],
                                      {"--out": ["imp.json"]}),
        "export-calibration": Command("export-calibration", [f["calibration"]],
                                      {"--out": ["exp.yml"]}),
        "calibrate-board": Command("calibrate-board", [f["poses"]],
                                   {"--board": ["checkerboard"], "--rows": ["6"],
                                    "--cols": ["5"], "--spacing": ["2"], "--output": ["cb.json"]},
                                   (f["poses"],)),
        "print-target": Command("print-target", ["board"], {"--output": ["t.svg"]}),
        "export-mesh": Command("export-mesh", [f["mesh"]], {"--out": ["m.glb"]}),
        "simulate": Command("simulate", [], {"--out": ["sim"], "--scale": ["0.0625"],
                                             "--patterns": [f["patterns"]]}, (f["patterns"],)),
        "simulate-print": Command("simulate", [], {"--out": ["sim"], "--scale": ["0.0625"],
                                                   "--print": [f["print_png"]],
                                                   "--patterns": [f["patterns"]]},
                                  (f["patterns"],)),
        "simulate-board": Command("simulate", [], {"--out": ["sim"], "--scale": ["0.0625"],
                                                   "--scene": ["board"],
                                                   "--patterns": [f["patterns"]]},
                                  (f["patterns"],)),
    }


def argv_of(cmd: Command) -> list[str]:
    """The argument list: options as ``--flag=value`` (a value may start with ``-``), options
    of several values as ``--flag v1 v2``, then ``--`` and the positionals."""
    argv = ["-q", cmd.name]
    for flag, values in cmd.options.items():
        if values is None:  # a flag
            argv.append(flag)
        elif len(values) == 1:
            argv.append(f"{flag}={values[0]}")
        else:
            argv += [flag, *values]
    return [*argv, "--", *cmd.positionals] if cmd.positionals else argv


# --------------------------------------------------------------------------------------------
# one case


@dataclass
class Outcome:
    rc: int | None
    stderr: str
    seconds: float
    mebibytes: float
    problem: str | None = None
    findings: list[str] = field(default_factory=list)
    known: str | None = None  # a failure of KNOWN_UNNAMED / KNOWN_HANGS




def _prepare_case_dir(case: Path) -> None:
    """The relative paths of :data:`PATHS`, made afresh."""
    if case.exists():
        shutil.rmtree(case)
    (case / "a_dir").mkdir(parents=True)
    os.mkfifo(case / "a_fifo")
    (case / "empty.json").write_bytes(b"")
    (case / "junk.txt").write_bytes(b"\x00\xffnot json {[")


def _tree(root: Path) -> dict[str, tuple[int, int]]:
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = os.path.join(dirpath, name)
            st = os.lstat(path)
            out[os.path.relpath(path, root)] = (st.st_size, st.st_mtime_ns)
    return out


def run_case(argv: list[str], case: Path) -> Outcome:
    """Run `argv` with `case` as the working directory; stdout/stderr captured."""
    _prepare_case_dir(case)
    before = _tree(case)
    err, out = io.StringIO(), io.StringIO()
    rc: int | None = None
    problem = None
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracing = tracemalloc.is_tracing()
    if tracing:
        tracemalloc.reset_peak()
    start = time.perf_counter()
    try:
        with contextlib.chdir(case), contextlib.redirect_stdout(out), \
                contextlib.redirect_stderr(err), warnings.catch_warnings(), \
                time_limit(CASE_SECONDS):
            warnings.simplefilter("default")  # as on the command line
            try:
                rc = main(argv)
            except SystemExit as exc:  # argparse's usage errors
                rc = exc.code if isinstance(exc.code, int) else 2
    except Timeout:
        problem = f"no answer within {CASE_SECONDS:g} s"
    except BaseException as exc:  # an exception out of main: the contract is broken
        problem = f"{type(exc).__name__} escaped main: {' '.join(str(exc).split())[:300]}"
    seconds = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1] / 2**20 if tracing else 0.0
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
    outcome = Outcome(rc, err.getvalue(), seconds, max(peak, grown), problem)
    if problem is None and outcome.mebibytes > CASE_MEBIBYTES:
        outcome.problem = f"took {outcome.mebibytes:.0f} MiB"
    if outcome.problem is None and rc == 2 and _tree(case) != before:
        changed = sorted(set(_tree(case).items()) ^ set(before.items()))
        outcome.problem = f"exit 2 but wrote {[c[0] for c in changed][:3]}"
    return outcome


def _error_line(command: str, stderr: str) -> tuple[str | None, bool]:
    """``(the error line, from argparse)``, or ``(None, …)`` when stderr is not one."""
    lines = stderr.strip("\n").splitlines()
    prefix = f"nail2nail {command}: error: "
    if lines and lines[0].startswith("usage: "):  # argparse: the usage block, then the line
        return (lines[-1] if lines[-1].startswith(prefix) and
                all(not line.startswith("nail2nail") for line in lines[:-1]) else None), True
    return (lines[0] if len(lines) == 1 and lines[0].startswith(prefix) else None), False


def check_case(cmd: Command, fuzzed: list[Option], outcome: Outcome,
               inputs: tuple = ()) -> Outcome:
    """Apply the invariant to the outcome of `cmd` (whose `fuzzed` options were generated;
    `inputs`: directories of the inputs the command line gives, which an error may name)."""
    if outcome.problem is not None:
        if outcome.problem.startswith("no answer") and any(
                (cmd.key, o.name) in KNOWN_HANGS and any("fifo" in v for v in _given(cmd, o))
                for o in fuzzed):
            outcome.known, outcome.problem = outcome.problem, None
        return outcome
    if outcome.rc not in (0, 2):
        outcome.problem = f"exit {outcome.rc}: {outcome.stderr.strip()[-300:]}"
        return outcome
    values = [v for o in fuzzed for v in _given(cmd, o)]
    if outcome.rc == 2:
        line, from_argparse = _error_line(cmd.name, outcome.stderr)
        if line is None:
            outcome.problem = f"exit 2 without one error line: {outcome.stderr[-400:]!r}"
            return outcome
        names_option = any(n in line for o in fuzzed for n in o.names())
        # a file (a path option's value or a positional) is named by its path
        names_value = any((v and v in line) or str(Path(v)) in line
                          for o in fuzzed if o.kind == "path" or not o.flags
                          for v in _given(cmd, o))
        names_value = names_value or any(  # CAMERA=IMAGE: the image
            "=" in v and len(v.split("=", 1)[1]) > 2 and v.split("=", 1)[1] in line
            for o in fuzzed if o.kind == "string" for v in _given(cmd, o))
        at_stop = any(n in line for n in cmd.stop)
        names_input = any(str(p) in line for p in inputs)
        if not (names_option or names_value or at_stop or names_input or from_argparse):
            outcome.problem = f"error naming no fuzzed option nor an input: {line[:300]}"
            if any((cmd.key, o.name) in KNOWN_UNNAMED for o in fuzzed):
                outcome.known, outcome.problem = outcome.problem, None
        elif at_stop and not (names_option or names_value):
            if any(o.kind == "number" and any(v.strip().lower().lstrip("+-") == "nan"
                                              for v in _given(cmd, o)) for o in fuzzed):
                outcome.findings.append("NaN refused only by the stop: " + _label(fuzzed, values))
    elif any(o.kind == "number" and any(v.strip().lower().lstrip("+-") == "nan"
                                        for v in _given(cmd, o)) for o in fuzzed):
        outcome.findings.append("NaN accepted (exit 0): " + _label(fuzzed, values))
    return outcome


def _given(cmd: Command, option: Option) -> list[str]:
    if option.flags:
        return cmd.options.get(option.flags[-1]) or []
    return cmd.positionals


def _label(fuzzed: list[Option], values: list[str]) -> str:
    return " ".join(o.name for o in fuzzed) + " " + " ".join(repr(v[:40]) for v in values)


def fuzzed_command(command: str, fx: Fixtures, options: list[Option], rng: random.Random,
                   chosen: list[Option], values: list[list[str]] | None = None) -> Command:
    """`command`'s base line with the `chosen` options given generated `values`."""
    cmd = base_command(command, fx)
    cmd.options = dict(cmd.options)
    cmd.positionals = list(cmd.positionals)
    for i, option in enumerate(chosen):
        given = values[i] if values is not None else values_for(option, rng)
        if option.kind == "flag":
            cmd.options[option.flags[-1]] = None  # type: ignore[assignment]
            continue
        if option.flags:
            for flag in option.flags:  # a required option given under another spelling
                cmd.options.pop(flag, None)
            cmd.options[option.flags[-1]] = given
        else:
            cmd.positionals = given
    return cmd


def random_case(command: str, fx: Fixtures, options: list[Option], rng: random.Random
                ) -> tuple[Command, list[Option]]:
    """A case of the bench: 1 to 3 options fuzzed, sometimes a flag or two beside them."""
    valued = [o for o in options if o.kind != "flag"]
    chosen = rng.sample(valued, min(len(valued), rng.choice((1, 1, 1, 2, 3))))
    flags = [o for o in options if o.kind == "flag"]
    extra = rng.sample(flags, min(len(flags), rng.choice((0, 0, 1, 2))))
    return fuzzed_command(command, fx, options, rng, chosen + extra), chosen


def sweep_cases(command: str, fx: Fixtures, per_option: int, seed: int = 0
                ) -> list[tuple[Command, list[Option]]]:
    """The test suite's cases: every option of `command`, `per_option` values each (the
    special values of its kind in turn, then generated ones), reproducibly."""
    options = command_options(command)
    cases = []
    for option in options:
        if option.kind == "flag":
            continue
        pool = {"number": NUMBERS, "path": PATHS, "string": STRINGS,
                "choice": STRINGS}[option.kind]
        rng = random.Random(f"{seed}-{command}-{option.name}")
        start = rng.randrange(len(pool))
        for i in range(per_option):
            if i < len(pool) and i < per_option // 2 + 1:
                value = pool[(start + 7 * i) % len(pool)]
                given = [value] * option.nargs
            else:
                given = values_for(option, rng)
            if (command, option.name) in KNOWN_HANGS and any("fifo" in v for v in given):
                given = ["missing.json"] * option.nargs
            cases.append((fuzzed_command(command, fx, options, rng, [option], [given]),
                          [option]))
    return cases


# --------------------------------------------------------------------------------------------
# the test suite's cases


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    return make_fixtures(tmp_path_factory.mktemp("fuzz_cli") / "fixtures")


#: Values per option in the test suite, by command (the real ones cost more than a stop).
_PER_OPTION = {"report": 6, "print-target": 4, "import-calibration": 4, "export-calibration": 4,
               "simulate-print": 2, "simulate-board": 2}


@pytest.mark.parametrize("command", COMMANDS)
def test_cli_options_fuzzed(command, fixtures, tmp_path):
    before = _tree(fixtures.root)
    problems = []
    cases = sweep_cases(command, fixtures, _PER_OPTION.get(command, 3))
    for i, (cmd, fuzzed) in enumerate(cases):
        outcome = check_case(cmd, fuzzed, run_case(argv_of(cmd), tmp_path / f"case{i}"),
                             (fixtures.root,))
        if outcome.problem:
            problems.append(f"{argv_of(cmd)}: {outcome.problem}")
        shutil.rmtree(tmp_path / f"case{i}", ignore_errors=True)
    assert _tree(fixtures.root) == before, "a case changed the fixtures"
    assert not problems, "\n".join(problems[:10])


_KNOWN_VALUES = {"--frame": "cam9", "--rows": "2", "--cols": "2", "--marker": "3", "--camera": "x",
                 "--layout": "stereo", "--mask": "cam9=junk.txt"}


#: Options whose message named the library's argument until issue 29's second round (found by
#: this fuzz): now each names the option.
ONCE_UNNAMED = [("calibrate-board", "--cols"), ("calibrate-board", "--marker"),
                ("calibrate-board", "--rows"), ("export-calibration", "--camera"),
                ("export-calibration", "--layout"), ("scan", "--frame"), ("scan", "--mask")]


@pytest.mark.parametrize(("command", "option"), ONCE_UNNAMED)
def test_once_unnamed_options_are_named(command, option, fixtures, tmp_path):
    options = {o.name: o for o in command_options(command)}
    values = [_KNOWN_VALUES[option]]
    cmd = fuzzed_command(command, fixtures, list(options.values()), random.Random(0),
                         [options[option]], [values])
    if command == "calibrate-board" and option == "--marker":
        cmd.options["--board"] = ["circles"]
    if command == "export-calibration" and option == "--camera":
        cmd.options["--layout"] = ["stereo"]
    outcome = run_case(argv_of(cmd), tmp_path / "case")
    assert outcome.rc == 2
    line, _ = _error_line(cmd.name, outcome.stderr)
    flags = (option, "--camera") if option == "--layout" else (option,)  # give --camera
    assert line is not None and any(flag in line for flag in flags), outcome.stderr


def _layouts():
    from nail2nail.calibration.opencv_files import LAYOUTS

    return list(LAYOUTS)


@pytest.mark.parametrize("layout", _layouts())
def test_every_one_camera_layout_names_its_options(layout, fixtures, tmp_path):
    """Found by ``bench/fuzz_cli.py`` (127 of 4,166 cases): ``--layout slstudio`` without
    ``--camera`` said "layout 'slstudio' holds one camera", naming no option (only ``stereo``
    was translated)."""
    options = {o.name: o for o in command_options("export-calibration")}
    cmd = fuzzed_command("export-calibration", fixtures, list(options.values()),
                         random.Random(0), [options["--layout"]], [[layout]])
    cmd.options.pop("--camera", None)
    outcome = run_case(argv_of(cmd), tmp_path / "case")
    assert outcome.rc in (0, 2), outcome.stderr
    if outcome.rc == 2:
        line, _ = _error_line(cmd.name, outcome.stderr)
        assert line is not None and f"--layout {layout}" in line and "--camera" in line, line


@pytest.mark.parametrize(("command", "option"), [("process", "--calib"),
                                                 ("export-calibration", "calibration")])
def test_a_fifo_given_as_a_json_file_is_refused(command, option, fixtures, tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "CASE_SECONDS", 2.0)
    options = {o.name: o for o in command_options(command)}
    cmd = fuzzed_command(command, fixtures, list(options.values()), random.Random(0),
                         [options[option]], [["a_fifo"]])
    outcome = run_case(argv_of(cmd), tmp_path / "case")
    assert outcome.problem is None and outcome.rc == 2, outcome.problem
