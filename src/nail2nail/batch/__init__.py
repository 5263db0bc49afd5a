"""Many captures at once: the whole job of ``nail2nail process`` for each, on Dask.

:func:`process_batch` runs :func:`nail2nail.process.process_capture` for every capture as one
task of a ``dask.distributed`` cluster (a :func:`local_client` or any existing one), writing
``OUT/<capture name>`` exactly as ``nail2nail process CAPTURE --out OUT/<capture name>`` would,
and the results table ``OUT/batch.csv`` and ``OUT/batch.json``.

- Resumable: a capture whose job directory is complete (``process.json``) and whose inputs hash
  (:func:`nail2nail.batch.hashing.inputs_hash`: the capture's files, the calibration, the
  options) equals the one recorded in ``OUT/<capture>/batch.json`` is skipped; a changed one is
  redone, its old directory replaced as a whole. A capture that failed on bad input (its row in
  the previous ``OUT/batch.json``) is not run again while its inputs hash is unchanged: its row
  repeats the error (``ran`` false); ``retry_failed=True`` (``--retry-failed``) runs it again.
  Other failures (file system, lost workers, internal errors) are run again on every call.
- Isolated: a capture's error is its ``failed`` row, the others go on; an error is not retried
  within a call. An output path that is not an earlier job (``OutputRefusedError``) is not
  a bad input: that capture runs again on the next call.
- Exclusive: a batch holds ``OUT/.batch.lock`` (``fcntl.flock``) while it runs; a second
  batch on the same OUT is refused, not interleaved.
- Robust to lost workers: a task whose worker dies is run again elsewhere (the scheduler's
  ``distributed.scheduler.allowed-failures``, 3 by default; the nanny restarts the worker), and
  since a job directory is renamed into place only once complete, no half-written output is
  ever a result; the dead attempt's hidden ``.NAME.tmp-*`` directory is removed at the end.
- Memory: :mod:`nail2nail.batch.memory`.
- Interrupted (Ctrl-C): the workers of a :func:`local_client` never see the signal (it is
  blocked while their processes start, and they inherit that), so only this process stops:
  it cancels the tasks, closes a cluster that runs in this process (its workers are stopped:
  no job goes on after the interrupt), removes what the stopped jobs left, writes the results
  table (the captures not finished: ``failed``, error "interrupted", run again on the next
  call) and raises ``KeyboardInterrupt``; distributed's log lines are silenced meanwhile.
"""

from __future__ import annotations

import contextlib
import glob
import logging
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from nail2nail._progress import progress_bar
from nail2nail._validation import describe_error
from nail2nail.batch.hashing import inputs_hash
from nail2nail.batch.memory import capture_memory_mb, check_workers, default_workers
from nail2nail.batch.results import TABLE_CSV, TABLE_JSON, read_results, result_row, write_results
from nail2nail.batch.tasks import clean_stale, run_capture
from nail2nail.io._atomic import check_output_directory

__all__ = ["capture_memory_mb", "check_cameras", "check_workers", "close_quietly",
           "default_workers", "find_captures", "first_calibration", "inputs_hash",
           "local_client", "process_batch", "result_row", "write_results"]

LOCK = ".batch.lock"  # in OUT, held by the running batch
RESERVED = (TABLE_JSON, TABLE_CSV)  # the results table: not a capture's OUT/<name>


def _check_names(captures: list[Path], what: str) -> None:
    """Refuse names whose outputs ``OUT/<name>`` would collide or hit the results table."""
    names = [p.name for p in captures]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"{what}: captures share the names {twice}; their outputs "
                         "OUT/<name> would collide")
    bad = sorted(n for n in names if n in RESERVED or n.startswith(".") or not n)
    if bad:
        raise ValueError(f"{what}: capture names {bad} are not usable as OUT/<name> (hidden, "
                         f"or the results table {' / '.join(RESERVED)}); rename them")


def find_captures(pattern: str | os.PathLike) -> list[Path]:
    """The capture directories (holding ``capture.json``, or ``projectors.json`` for a capture
    of several projectors) that the glob `pattern` matches.

    Parameters
    ----------
    pattern : str or path-like
        A glob pattern (:func:`glob.glob`), e.g. ``"captures/*"``.

    Returns
    -------
    list of Path
        The matching directories that hold a ``capture.json`` or ``projectors.json``, sorted.

    Raises
    ------
    ValueError
        No capture matched, two captures share a name (their outputs would collide), or a
        name is hidden or that of the results table.
    """
    matched = sorted(Path(p) for p in glob.glob(os.fspath(pattern)))
    captures = [p for p in matched
                if (p / "capture.json").is_file() or (p / "projectors.json").is_file()]
    if not captures:
        raise ValueError(f"{pattern}: no capture directory (with capture.json or "
                         "projectors.json) matches "
                         f"({len(matched)} paths matched)")
    _check_names(captures, os.fspath(pattern))
    return captures


def first_calibration(calibration: str | os.PathLike, captures) -> Path:
    """The first calibration file that `calibration` names for one of `captures`: itself, or
    ``STEM_<capture>.json`` of a capture of several projectors
    (:func:`nail2nail.process.calibration_files`), for the checks made before any task runs.
    A capture whose files are missing fails alone (its task reports it).

    Raises
    ------
    ValueError
        When no capture has its calibration file(s): the first capture's reason.
    """
    from nail2nail.process import calibration_files

    errors = []
    for c in captures:
        try:
            return calibration_files(calibration, c)[0]
        except ValueError as exc:
            errors.append(exc)
    if errors:
        raise errors[0]
    raise ValueError("captures: no capture given")


def check_cameras(captures, calibration, *, frame: str = "world", masks=None,
                  pairs: str | None = None, names: dict[str, str] | None = None) -> None:
    """Check the options that name cameras against the calibration and every capture, before
    any task runs (a bad one would fail every capture, one task at a time).

    Parameters
    ----------
    captures : sequence of path-like
        The capture directories (a capture of several projectors: each of its captures); a
        capture whose ``capture.json`` cannot be read is left out here (its task reports it,
        alone).
    calibration : RigCalibration
        The rig's calibration (:func:`nail2nail.calibration.files.load_calibration`).
    frame : str
        ``"world"`` or a camera's name (:func:`nail2nail.frames.frame_transform`).
    masks : mapping of str to path-like, optional
        User masks by camera name.
    pairs : str, optional
        Merge pairs ``"0-1,1-2"`` (:func:`nail2nail.merge.report.parse_pairs`).
    names : dict of str to str, optional
        How to call ``frame``, ``masks`` and ``pairs`` in the messages (the CLI's
        ``--frame``, ``--mask``, ``--pairs``).

    Raises
    ------
    ValueError
        Naming the option, its value and the cameras that exist: `frame` not ``"world"``
        nor a camera of the calibration and of every capture; a mask for a camera a capture
        lacks; `pairs` naming a camera index a capture lacks.
    """
    from nail2nail.io.capture import read_capture
    from nail2nail.merge.report import parse_pairs

    names = {"frame": "frame", "masks": "masks", "pairs": "pairs", **(names or {})}
    calibrated = [cam.name for cam in calibration.cameras]
    if not isinstance(frame, str) or (frame != "world" and frame not in calibrated):
        raise ValueError(f"{names['frame']}: {frame!r} is neither 'world' nor a camera of the "
                         f"calibration (its cameras: {', '.join(calibrated)})")
    from nail2nail.io.capture import projector_captures

    expanded: list[tuple[Any, Any, int]] = []
    for c in captures:
        try:
            layout = projector_captures(c)
        except ValueError:  # its task reports it, alone
            continue
        expanded += [(c, c, 1)] if layout is None else [(c, p, len(layout)) for _, p in layout]
    for c, path, n_projectors in expanded:
        try:
            cameras = read_capture(path, load=False).camera_names
        except (OSError, ValueError, KeyError, TypeError):  # its task reports it, alone
            continue
        if frame != "world" and frame not in cameras:
            raise ValueError(f"{names['frame']}: {frame!r} is not a camera of capture {c} "
                             f"(its cameras: {', '.join(cameras)}; or 'world')")
        for name in masks or {}:
            if name not in cameras:
                raise ValueError(f"{names['masks']}: a mask for camera {name!r}, which capture "
                                 f"{c} lacks (its cameras: {', '.join(cameras)})")
        if pairs is not None:
            try:
                parse_pairs(pairs, len(cameras) * n_projectors)
            except ValueError as exc:
                reason = str(exc).removeprefix("--pairs: ")
                raise ValueError(f"{names['pairs']} {pairs}: capture {c} has {len(cameras)} "
                                 f"camera(s): {reason}") from None


@contextlib.contextmanager
def _exclusive(out: Path) -> Iterator[None]:
    """Hold ``OUT/.batch.lock`` so that two batches never write one OUT at once."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock (documented)
        yield
        return
    with open(out / LOCK, "a+b") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ValueError(f"{out}: another nail2nail batch is writing to this directory "
                             f"(it holds {LOCK}); wait for it to end or choose another "
                             "output directory") from None
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _clean_tables(out: Path) -> None:
    """Remove the temporary files of a results table write that was interrupted."""
    for name in RESERVED:
        for path in out.glob(f".{name}.*.tmp"):
            path.unlink(missing_ok=True)


def local_client(n_workers: int, *, memory_limit: int | str | None = None):
    """A :class:`dask.distributed.Client` on a new local cluster of `n_workers` processes.

    One thread per worker (the job is single-threaded NumPy and numba, and one capture per
    worker at a time bounds the memory), each worker's memory limit ``total / n_workers``
    (`memory_limit` to override, bytes or ``"4GB"``), no dashboard. Close the client and its
    cluster (``client.close(); client.cluster.close()``, or use both as context managers).
    """
    from distributed import Client, LocalCluster

    if isinstance(n_workers, bool) or not isinstance(n_workers, int) or n_workers < 1:
        raise ValueError(f"n_workers: expected an integer >= 1, got {n_workers!r}")
    if memory_limit is None:
        import psutil

        memory_limit = int(psutil.virtual_memory().total // n_workers)
    # no dashboard; the scheduler's plain HTTP server (health checks) on a free port, so that
    # two clusters never compete for 8787 (dashboard_address=None would still take it).
    # Ctrl-C is for this process alone: blocked while the worker processes start (they inherit
    # the blocked signal, and so do the workers their nannies restart), delivered here after.
    # Dask's own log lines below CRITICAL (a worker restarted, a task cancelled, a worker's
    # heartbeat failing while Ctrl-C closes the scheduler before it) are not printed: what
    # went wrong with a capture is in the results table, with the attempts it took.
    with _sigint_deferred() as deferred:
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                               memory_limit=memory_limit, dashboard_address=":0",
                               scheduler_kwargs={"dashboard": False},
                               silence_logs=logging.CRITICAL)
        try:
            client = Client(cluster)
        except BaseException:
            close_quietly(None, cluster)
            raise
    if deferred.interrupted:  # Ctrl-C while the cluster started: now, with nothing left
        close_quietly(client, cluster)
        raise KeyboardInterrupt
    return client


class _Deferred:
    interrupted = False


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[_Deferred]:
    """Defer Ctrl-C for the block: SIGINT is blocked in this (main) thread, so that the threads
    and processes started inside inherit the blocked signal, and recorded (``interrupted``
    set), not raised, if it arrives meanwhile (at another thread, or pending at the end).
    POSIX main thread only; elsewhere nothing is deferred."""
    state = _Deferred()
    if (not hasattr(signal, "pthread_sigmask") or not hasattr(signal, "sigtimedwait")
            or threading.current_thread() is not threading.main_thread()):
        yield state
        return
    from multiprocessing import resource_tracker

    # started now: starting it (on the first process spawned) unblocks SIGINT in the thread
    # that starts it, and the worker processes that thread spawns would get it again
    resource_tracker.ensure_running()

    def record(signum, frame):
        state.interrupted = True

    handler = signal.signal(signal.SIGINT, record)
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield state
    finally:
        if signal.SIGINT in signal.sigpending():
            signal.sigtimedwait({signal.SIGINT}, 0)  # consumed: not raised at the unblock
            state.interrupted = True
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
        signal.signal(signal.SIGINT, handler)


@contextlib.contextmanager
def _shielded() -> Iterator[None]:
    """While cleaning up after a Ctrl-C: a second Ctrl-C is ignored (the cleanup is short and
    must end), and no log line is printed (distributed's, tornado's, asyncio's)."""
    main = threading.current_thread() is threading.main_thread()
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)
        if main:
            signal.signal(signal.SIGINT, handler)


def close_quietly(client, cluster=None) -> None:
    """Close `client` and `cluster` (either may be ``None``) without a log line and without
    being interrupted by a second Ctrl-C; their errors are ignored (they are going away)."""
    with _shielded():
        for thing in (client, cluster):
            if thing is not None:
                with contextlib.suppress(Exception):
                    thing.close()


def _attempts(client, keys: list[str]) -> dict[str, int]:
    """1 + the workers lost while each task ran (the scheduler's count of 'suspicious' runs)."""

    def count(dask_scheduler, keys):
        return {k: 1 + dask_scheduler.tasks[k].suspicious for k in keys
                if k in dask_scheduler.tasks}

    return client.run_on_scheduler(count, keys=keys)


def _previous_failures(out: Path) -> dict[str, dict]:
    """The bad-input failures of the last call's table ``OUT/batch.json``, by capture name."""
    return {r["capture"]: {k: r.get(k) for k in ("hash", "error", "bad_input")}
            for r in read_results(out) if r.get("status") == "failed"
            and r.get("bad_input") and r.get("hash") and "capture" in r}


def process_batch(captures, calibration: str | os.PathLike, out: str | os.PathLike, client, *,
                  progress: bool = False, retry_failed: bool = False,
                  report_points: int | None = None, **options) -> list[dict]:
    """Process every capture on the Dask cluster of `client`; write the results table.

    Parameters
    ----------
    captures : str or sequence of path-like
        A glob pattern (:func:`find_captures`) or the capture directories; each capture's
        output is ``OUT/<its directory name>``.
    calibration : path-like
        The rig's calibration JSON (read by each task).
    out : path-like
        Output directory; created if needed. The workers must see it (and the captures) at
        the same paths: a local cluster, or a shared file system.
    client : dask.distributed.Client
        The cluster's client (:func:`local_client`, or ``Client("tcp://host:8786")``).
    progress : bool
        A progress bar over the captures on stderr (a terminal only, not inside ``quiet``).
    retry_failed : bool
        Run again the captures that failed on bad input in the previous call even if their
        inputs are unchanged (default: repeat their error without running them).
    report_points : int, optional
        Also write each capture's HTML report, ``OUT/<name>/report.html``, with this many
        points in its 3D viewer (``nail2nail process --report``); default: no report. A
        current job without its report gets the report alone; an existing one is kept.
    **options
        Keyword arguments of :func:`nail2nail.process.process_capture` (``use``, ``ppi`` …;
        not ``progress``); they are part of the inputs hash.

    Returns
    -------
    list of dict
        The rows of ``OUT/batch.json`` (:func:`result_row`), in the order of `captures`.

    Raises
    ------
    ValueError
        No capture matched, two share a name, a name is hidden or that of the results table,
        the calibration file is missing or not valid, an option names a camera that the
        calibration or a capture lacks (:func:`check_cameras`), `out` is a file or a
        read-only directory, or another batch is writing to `out` (it holds
        ``OUT/.batch.lock``; POSIX systems only).
    KeyboardInterrupt
        Ctrl-C: the tasks are cancelled, a cluster of this process closed, the results table
        written (the captures not finished: ``failed``, "interrupted"), and it is raised again.
    """
    if isinstance(captures, (str, os.PathLike)):
        captures = find_captures(captures)
    captures = [Path(c).resolve() for c in captures]
    if not captures:
        raise ValueError("captures: no capture given")
    _check_names(captures, "captures")
    calibration = Path(calibration).resolve()
    from nail2nail.calibration.files import load_calibration

    check_cameras(captures, load_calibration(first_calibration(calibration, captures),
                                             allow_mirrored=bool(
        options.get("allow_mirrored", False))), frame=options.get("frame", "world"),
                  masks=options.get("masks"), pairs=options.get("pairs"))
    if options.get("masks"):  # the workers may run elsewhere: absolute paths
        options["masks"] = {k: str(Path(v).resolve()) if isinstance(v, (str, os.PathLike)) else v
                            for k, v in options["masks"].items()}
    out = check_output_directory(Path(out).resolve())  # not a file, not read-only
    out.mkdir(parents=True, exist_ok=True)
    with _exclusive(out):
        _clean_tables(out)
        for c in captures:
            clean_stale(out, c.name)
        rows = _run(captures, calibration, out, client, options, progress=progress,
                    retry_failed=retry_failed, report_points=report_points)
        for c in captures:  # every task has ended: what a lost attempt left is garbage
            clean_stale(out, c.name)
        write_results(out, rows)
    return rows


def _run(captures: list[Path], calibration: Path, out: Path, client, options: dict, *,
         progress: bool, retry_failed: bool, report_points: int | None) -> list[dict]:
    """Submit a task per capture, gather the rows in the order of `captures`."""
    from distributed import as_completed

    failures = {} if retry_failed else _previous_failures(out)
    futures: dict = {}
    records: dict[Path, dict] = {}
    try:
        for c in captures:
            # pure=False: the same inputs may change on disk between two calls; the key names
            # it. No `retries`: run_capture returns its errors; a lost worker is the
            # scheduler's allowed-failures.
            future = client.submit(run_capture, str(c), str(calibration), str(out / c.name),
                                   options, failures.get(c.name), report_points,
                                   key=f"nail2nail-batch-{c.name}-{time.time_ns()}", pure=False)
            futures[future] = c
        bar = progress_bar(desc="batch", unit="capture", total=len(captures), enabled=progress)
        with bar:
            for future in as_completed(futures):
                c = futures[future]
                attempts = _attempts(client, [future.key]).get(future.key, 1)
                if future.status == "finished":
                    record = future.result()
                else:  # a worker lost too often (KilledWorker), a task cancelled or unrunnable
                    exc = None if future.cancelled() else future.exception()
                    error = ("cancelled: the scheduler dropped the task (restarted or lost?)"
                             if exc is None else f"{type(exc).__name__}: {describe_error(exc)}")
                    record = {"capture": str(c), "out": str(out / c.name), "status": "failed",
                              "error": error, "ran": True, "worker": None}
                records[c] = result_row(record, attempts=attempts)
                bar.update()
    except KeyboardInterrupt:
        _interrupted(captures, out, client, futures, records)
        raise
    return [records[c] for c in captures]


INTERRUPTED = ("interrupted (Ctrl-C) before it ended; it runs again on the next call (what "
               "was completed is kept)")


def _interrupted(captures: list[Path], out: Path, client, futures: dict,
                 records: dict[Path, dict]) -> None:
    """After a Ctrl-C: stop the jobs, keep the results table true to what is on disk."""
    with _shielded():
        with contextlib.suppress(Exception):
            client.cancel(list(futures))
        cluster = getattr(client, "cluster", None)  # a cluster of this process: its workers
        if cluster is not None:  # stop, so that no job goes on after the interrupt
            with contextlib.suppress(Exception):
                cluster.close()
        for c in captures:
            if c not in records:
                records[c] = result_row({"capture": str(c), "out": str(out / c.name),
                                         "status": "failed", "error": INTERRUPTED,
                                         "ran": False, "worker": None})
        if cluster is not None:  # no job runs any more: what a stopped one left is garbage
            for c in captures:
                clean_stale(out, c.name)
        write_results(out, [records[c] for c in captures])
