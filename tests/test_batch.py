"""``nail2nail batch``: many captures on a local Dask cluster (issue 14).

Six small virtual captures (scale 0.25; two simulated fingers, copied), one with a truncated
frame; two local workers, one of them killed while it runs a capture. Every good capture's
output must equal the single-process ``process`` command's, the corrupt one be reported with
its error, nothing be left half-written, and a second run skip everything (the corrupt capture's
error repeated without running it, unless asked to retry).
"""

from __future__ import annotations

import json
import os
import shutil
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from nail2nail.batch import find_captures, inputs_hash, local_client, process_batch
from nail2nail.batch.tasks import run_capture
from nail2nail.calibration.files import RigCalibration, save_calibration
from nail2nail.cli import main
from nail2nail.cli._batch import process_options
from nail2nail.cli._main import build_parser
from nail2nail.simulation.capture import simulate_capture
from nail2nail.simulation.rig import default_rig, ideal_calibration

SCALE = 0.25
SEEDS = (1, 2)
GOOD = [f"finger{i}" for i in range(5)]  # copies of the SEEDS' fingers, alternating
TIMINGS = {"seconds", "scan_seconds", "merge_seconds", "peak_rss_mb", "timings_s"}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The captures directory, the calibration, and the single-process output per seed."""
    root = tmp_path_factory.mktemp("batch")
    rig = default_rig(SCALE, projector_distortion="none")
    calib = root / "rig.json"
    save_calibration(calib, RigCalibration.from_dict(ideal_calibration(rig)))
    captures = root / "captures"
    reference = {}
    for seed in SEEDS:
        simulate_capture(root / f"seed{seed}", "finger", rig=rig, seed=seed, write_truth=False)
        reference[seed] = root / f"reference{seed}"
        assert main(["process", str(root / f"seed{seed}"), "--calib", str(calib),
                     "--out", str(reference[seed])]) == 0
    for i, name in enumerate(GOOD):
        shutil.copytree(root / f"seed{SEEDS[i % 2]}", captures / name)
    shutil.copytree(root / f"seed{SEEDS[0]}", captures / "corrupt")
    frame = sorted((captures / "corrupt").glob("cam1/*.png"))[3]
    frame.write_bytes(frame.read_bytes()[:200])  # a truncated PNG
    return root, captures, calib, reference


@pytest.fixture(scope="module")
def client():
    with local_client(2, memory_limit="4GB") as c:
        yield c
        c.cluster.close()


def _cli_options(calib: Path) -> dict:
    """The options of ``nail2nail batch`` by default: those of ``nail2nail process``."""
    return process_options(build_parser().parse_args(["batch", "*", "--calib", str(calib),
                                                      "--out", "o"]))


def _kill_first_busy_worker(client, done: threading.Event) -> str | None:
    """Kill (os._exit) the first worker seen running a task; return that task's key."""
    while not done.is_set():
        for address, keys in client.processing().items():
            if keys:
                try:
                    client.run(os._exit, 1, workers=[address])
                except Exception:  # the worker dies before answering: that is the point
                    pass
                return keys[0]
        time.sleep(0.05)
    return None


@pytest.fixture(scope="module")
def first_run(inputs, client):
    root, captures, calib, _ = inputs
    out = root / "out"
    # what a worker killed inside atomic_directory leaves: a hidden, half-written sibling
    (out / ".finger0.tmp-killed" / "scans").mkdir(parents=True)
    (out / ".finger0.tmp-killed" / "scans" / "scan.json").write_text("{")
    done, result = threading.Event(), {}

    def batch():
        result["rows"] = process_batch(f"{captures}/*", calib, out, client,
                                       **_cli_options(calib))
        done.set()

    thread = threading.Thread(target=batch)
    thread.start()
    killed = _kill_first_busy_worker(client, done)
    thread.join()
    return out, result["rows"], killed


def _normalised(data, paths: dict[str, str]):
    if isinstance(data, dict):
        return {k: _normalised(v, paths) for k, v in data.items() if k not in TIMINGS}
    if isinstance(data, list):
        return [_normalised(v, paths) for v in data]
    if isinstance(data, str):
        for path, name in paths.items():
            data = data.replace(path, name)
    return data


def _assert_same_job(job: Path, reference: Path, capture: Path, ref_capture: Path) -> None:
    names = sorted(p.relative_to(reference).as_posix() for p in reference.rglob("*")
                   if p.is_file())
    assert names == sorted(p.relative_to(job).as_posix() for p in job.rglob("*")
                           if p.is_file() and p.name != "batch.json")
    for name in names:
        a, b = job / name, reference / name
        if name.endswith(".npz"):
            with np.load(a) as x, np.load(b) as y:
                assert sorted(x.files) == sorted(y.files), name
                for key in x.files:
                    np.testing.assert_array_equal(x[key], y[key], err_msg=f"{name}: {key}")
        elif name.endswith(".png"):
            np.testing.assert_array_equal(cv2.imread(str(a), cv2.IMREAD_UNCHANGED),
                                          cv2.imread(str(b), cv2.IMREAD_UNCHANGED), name)
        elif name.endswith(".json"):
            paths_a = {str(job): "OUT", str(capture): "CAPTURE"}
            paths_b = {str(reference): "OUT", str(ref_capture): "CAPTURE"}
            assert (_normalised(json.loads(a.read_text()), paths_a)
                    == _normalised(json.loads(b.read_text()), paths_b)), name
        else:  # super.ply, the WSQ print
            assert a.read_bytes() == b.read_bytes(), name


def test_batch_equals_process_despite_a_lost_worker(inputs, first_run):
    root, captures, _, reference = inputs
    out, rows, killed = first_run
    assert killed is not None, "no task was seen running"
    by_name = {r["capture"]: r for r in rows}
    assert sorted(by_name) == sorted([*GOOD, "corrupt"])
    killed_name = next(n for n in by_name if f"-{n}-" in killed)
    assert by_name[killed_name]["attempts"] >= 2
    for i, name in enumerate(GOOD):
        row = by_name[name]
        assert row["status"] == "done" and row["error"] is None
        assert row["seconds"]["total"] > 0 and row["super_vertices"] > 0
        assert row["merge_median_um"] and row["clarity_median"] is not None
        assert 0 <= row["motion_um"] < 20  # still virtual fingers
        seed = SEEDS[i % 2]
        _assert_same_job(out / name, reference[seed], (captures / name).resolve(),
                         (root / f"seed{seed}").resolve())
    bad = by_name["corrupt"]
    assert bad["status"] == "failed" and "cam1" in bad["error"] and "\n" not in bad["error"]
    assert not (out / "corrupt").exists()
    # nothing half-written: no hidden temporary directory, every job directory complete
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [".batch.lock"]
    assert all((out / n / "process.json").is_file() for n in GOOD)
    table = json.loads((out / "batch.json").read_text())
    assert [r["capture"] for r in table] == [r["capture"] for r in rows]
    header = (out / "batch.csv").read_text().splitlines()[0].split(",")
    for column in ("capture", "status", "error", "seconds_scan", "merge_median_um_0-1",
                   "valid_pixels_cam0", "super_vertices", "clarity_median", "motion_um", "worker",
                   "attempts", "ran", "bad_input", "hash"):
        assert column in header


def test_second_run_skips(inputs, first_run, client):
    _, captures, calib, _ = inputs
    out, rows, _ = first_run
    before = {n: (out / n / "process.json").stat().st_mtime_ns for n in GOOD}
    again = process_batch(f"{captures}/*", calib, out, client, **_cli_options(calib))
    status = {r["capture"]: r["status"] for r in again}
    assert status == {**dict.fromkeys(GOOD, "skipped"), "corrupt": "failed"}
    # nothing ran: the corrupt capture's bad-input error is repeated while it is unchanged
    assert not any(r["ran"] for r in again)
    first, second = ({r["capture"]: r for r in table}["corrupt"] for table in (rows, again))
    assert first["ran"] and first["bad_input"] and second["bad_input"]
    assert second["error"] == first["error"] and second["hash"] == first["hash"]
    assert before == {n: (out / n / "process.json").stat().st_mtime_ns for n in GOOD}
    # the skipped rows still report the job's figures
    assert [r["super_vertices"] for r in again] == [r["super_vertices"] for r in rows]
    # asked to, the failed capture is run again (and fails again), the rest still skipped
    retried = process_batch(f"{captures}/*", calib, out, client, retry_failed=True,
                            **_cli_options(calib))
    assert {r["capture"]: r["ran"] for r in retried} == {**dict.fromkeys(GOOD, False),
                                                          "corrupt": True}
    assert {r["capture"]: r for r in retried}["corrupt"]["error"] == first["error"]


def test_changed_input_is_redone(inputs, first_run, tmp_path):
    _, captures, calib, _ = inputs
    out, _, _ = first_run
    job = tmp_path / "finger0"
    shutil.copytree(out / "finger0", job)
    capture = str(captures / "finger0")
    options = _cli_options(calib)
    assert run_capture(capture, str(calib), str(job), options)["status"] == "skipped"
    marker = json.loads((job / "batch.json").read_text())
    (job / "batch.json").write_text(json.dumps({**marker, "hash": "0" * 64}))  # other inputs
    record = run_capture(capture, str(calib), str(job), options)
    assert record["status"] == "done" and record["hash"] == marker["hash"]
    assert run_capture(capture, str(calib), str(job), {})["status"] == "done"  # other options
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_report_of_a_current_job(inputs, first_run, tmp_path):
    _, captures, calib, _ = inputs
    out, _, _ = first_run
    job = tmp_path / "finger1"
    shutil.copytree(out / "finger1", job)
    capture, options = str(captures / "finger1"), _cli_options(calib)
    processed = (job / "process.json").stat().st_mtime_ns
    record = run_capture(capture, str(calib), str(job), options, report_points=2000)
    assert record["status"] == "done" and record["ran"] and record["error"] is None
    assert "<html" in (job / "report.html").read_text(encoding="utf-8")[:2000].lower()
    assert (job / "process.json").stat().st_mtime_ns == processed  # the report alone
    again = run_capture(capture, str(calib), str(job), options, report_points=2000)
    assert again["status"] == "skipped" and again["hash"] == record["hash"]
    # without --report: the same job, its report kept
    assert run_capture(capture, str(calib), str(job), options)["status"] == "skipped"
    assert (job / "report.html").is_file()
    (job / "report.html").unlink()  # asked for and missing: written again
    assert run_capture(capture, str(calib), str(job), options,
                       report_points=2000)["status"] == "done"
    assert (job / "process.json").stat().st_mtime_ns == processed
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_inputs_hash(inputs, tmp_path, monkeypatch):
    root, _, calib, _ = inputs
    capture = tmp_path / "c"
    shutil.copytree(root / f"seed{SEEDS[0]}", capture)
    h = inputs_hash(capture, calib)
    assert h == inputs_hash(capture, calib, {}) and len(h) == 64
    assert inputs_hash(capture, calib, {"ppi": 1000}) != h
    monkeypatch.setattr("nail2nail.batch.hashing.__version__", "0.0.0")  # another release
    assert inputs_hash(capture, calib) != h
    monkeypatch.undo()
    # a mask counts by its content, a mask array by all of its values
    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), np.full((8, 8), 255, np.uint8))
    with_mask = inputs_hash(capture, calib, {"masks": {"cam0": str(mask)}})
    cv2.imwrite(str(mask), np.zeros((8, 8), np.uint8))
    assert inputs_hash(capture, calib, {"masks": {"cam0": str(mask)}}) != with_mask
    ones = np.ones((1024, 1280), bool)
    other = ones.copy()
    other[500, 600] = False  # where repr() would elide it
    assert (inputs_hash(capture, calib, {"masks": {"cam0": ones}})
            != inputs_hash(capture, calib, {"masks": {"cam0": other}}))
    frame = sorted(capture.glob("cam0/*.png"))[0]
    data = bytearray(frame.read_bytes())
    data[-20] ^= 1
    frame.write_bytes(bytes(data))
    assert inputs_hash(capture, calib) != h
    (capture / ".stale.tmp").write_text("ignored")  # hidden files are not inputs
    assert inputs_hash(capture, calib) == inputs_hash(capture, calib)


def test_bad_input(inputs, tmp_path, capsys):
    _, captures, calib, _ = inputs
    with pytest.raises(ValueError, match="no capture directory"):
        find_captures(tmp_path / "nothing*")
    assert main(["batch", str(tmp_path / "nothing*"), "--calib", str(calib),
                 "--out", str(tmp_path / "o")]) == 2
    assert "no capture directory" in capsys.readouterr().err
    assert main(["batch", f"{captures}/*", "--calib", str(tmp_path / "missing.json"),
                 "--out", str(tmp_path / "o")]) == 2
    assert "missing.json" in capsys.readouterr().err


def test_bad_names_workers_and_a_second_batch_on_one_out(inputs, tmp_path, capsys):
    import fcntl

    _, captures, calib, _ = inputs
    twins = [captures / "finger0", tmp_path / "finger0"]
    with pytest.raises(ValueError, match="share the names"):
        process_batch(twins, calib, tmp_path / "o", client=None)
    reserved = tmp_path / "batch.json"
    reserved.mkdir()
    with pytest.raises(ValueError, match="results table"):
        process_batch([reserved], calib, tmp_path / "o", client=None)
    assert main(["batch", f"{captures}/*", "--calib", str(calib), "--out",
                 str(tmp_path / "o"), "--workers", "0"]) == 2
    assert "--workers: expected at least 1" in capsys.readouterr().err
    out = tmp_path / "busy"
    out.mkdir()
    with open(out / ".batch.lock", "a+b") as lock:  # another batch is running on `out`
        fcntl.flock(lock, fcntl.LOCK_EX)
        with pytest.raises(ValueError, match="another nail2nail batch"):
            process_batch(f"{captures}/*", calib, out, client=None)
    assert [p.name for p in out.iterdir()] == [".batch.lock"]  # nothing else written


def test_job_directory_cases(inputs, first_run, tmp_path):
    """A corrupt marker is redone; an output path that is not a job is not a bad input."""
    from nail2nail.batch.tasks import clean_stale

    _, captures, calib, _ = inputs
    out, _, _ = first_run
    capture, options = str(captures / "finger2"), _cli_options(calib)
    job = tmp_path / "finger2"
    shutil.copytree(out / "finger2", job)
    (job / "batch.json").write_text("[1, 2")  # killed mid-write by an older version, say
    assert run_capture(capture, str(calib), str(job), options)["status"] == "done"
    assert run_capture(capture, str(calib), str(job), options)["status"] == "skipped"
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    record = run_capture(capture, str(calib), str(user), options)
    assert record["status"] == "failed" and not record["bad_input"]
    assert "OutputRefusedError" in record["error"] and (user / "notes.txt").exists()
    again = run_capture(capture, str(calib), str(user), options,
                        failed={"hash": record["hash"], "error": record["error"],
                                "bad_input": record["bad_input"]})
    assert again["ran"]  # not a bad input: run again, not repeated
    # names are literal, not glob patterns
    (tmp_path / ".scan[1].tmp-x").mkdir()
    (tmp_path / ".scan1.tmp-x").mkdir()
    assert clean_stale(tmp_path, "scan[1]") == [tmp_path / ".scan[1].tmp-x"]
    assert (tmp_path / ".scan1.tmp-x").is_dir()


def test_cli_resumes_and_reports(inputs, first_run, capsys):
    _, captures, calib, _ = inputs
    out, _, _ = first_run
    code = main(["batch", f"{captures}/*", "--calib", str(calib), "--out", str(out),
                 "--workers", "1", "--json"])
    assert code == 2  # the corrupt capture: bad input, the others written
    captured = capsys.readouterr()
    rows = json.loads(captured.out)
    assert {r["capture"]: r["status"] for r in rows} == {**dict.fromkeys(GOOD, "skipped"),
                                                         "corrupt": "failed"}
    assert not any(r["ran"] for r in rows)
    assert "1 of 6 captures failed" in captured.err


def test_memory_rule(inputs, tmp_path):
    from nail2nail.batch import capture_memory_mb, default_workers
    from nail2nail.batch.memory import BASE_MB, COPIES

    _, captures, _, _ = inputs
    capture = captures / GOOD[0]
    manifest = json.loads((capture / "capture.json").read_text())
    pixels = sum(c["size"][0] * c["size"][1] * len(c["frames"]) for c in manifest["cameras"])
    assert capture_memory_mb(capture) == pytest.approx(BASE_MB + COPIES * 4 * pixels / 2**20)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "capture.json").write_text("{")  # its task reports it; the others still count
    assert 1 <= default_workers([capture, broken]) <= 2
    assert default_workers([capture] * 4, memory_mb=1e9) == 1  # nothing fits: still one
    assert 1 <= default_workers([capture] * 4) <= min(4, os.cpu_count())
