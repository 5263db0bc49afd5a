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
"""

from __future__ import annotations

import contextlib
import glob
import os
import time
from collections.abc import Iterator
from pathlib import Path

from nail2nail._progress import progress_bar
from nail2nail._validation import describe_error
from nail2nail.batch.hashing import inputs_hash
from nail2nail.batch.memory import capture_memory_mb, default_workers
from nail2nail.batch.results import TABLE_CSV, TABLE_JSON, read_results, result_row, write_results
from nail2nail.batch.tasks import clean_stale, run_capture

__all__ = ["capture_memory_mb", "default_workers", "find_captures", "inputs_hash",
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
    """The capture directories (holding ``capture.json``) that the glob `pattern` matches.

    Parameters
    ----------
    pattern : str or path-like
        A glob pattern (:func:`glob.glob`), e.g. ``"captures/*"``.

    Returns
    -------
    list of Path
        The matching directories that hold a ``capture.json``, sorted.

    Raises
    ------
    ValueError
        No capture matched, two captures share a name (their outputs would collide), or a
        name is hidden or that of the results table.
    """
    matched = sorted(Path(p) for p in glob.glob(os.fspath(pattern)))
    captures = [p for p in matched if (p / "capture.json").is_file()]
    if not captures:
        raise ValueError(f"{pattern}: no capture directory (with capture.json) matches "
                         f"({len(matched)} paths matched)")
    _check_names(captures, os.fspath(pattern))
    return captures


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

    if n_workers < 1:
        raise ValueError(f"n_workers: expected at least 1, got {n_workers}")
    if memory_limit is None:
        import psutil

        memory_limit = int(psutil.virtual_memory().total // n_workers)
    # no dashboard; the scheduler's plain HTTP server (health checks) on a free port, so that
    # two clusters never compete for 8787 (dashboard_address=None would still take it)
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                           memory_limit=memory_limit, dashboard_address=":0",
                           scheduler_kwargs={"dashboard": False})
    return Client(cluster)


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
        the calibration file is missing, or another batch is writing to `out` (it holds
        ``OUT/.batch.lock``; POSIX systems only).
    """
    if isinstance(captures, (str, os.PathLike)):
        captures = find_captures(captures)
    captures = [Path(c).resolve() for c in captures]
    if not captures:
        raise ValueError("captures: no capture given")
    _check_names(captures, "captures")
    calibration = Path(calibration).resolve()
    if not calibration.is_file():
        raise ValueError(f"{calibration}: calibration file not found")
    if options.get("masks"):  # the workers may run elsewhere: absolute paths
        options["masks"] = {k: str(Path(v).resolve()) if isinstance(v, (str, os.PathLike)) else v
                            for k, v in options["masks"].items()}
    out = Path(out).resolve()
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
    futures = {}
    for c in captures:
        # pure=False: the same inputs may change on disk between two calls; the key names it.
        # No `retries`: run_capture returns its errors; a lost worker is the scheduler's
        # allowed-failures.
        future = client.submit(run_capture, str(c), str(calibration), str(out / c.name),
                               options, failures.get(c.name), report_points,
                               key=f"nail2nail-batch-{c.name}-{time.time_ns()}", pure=False)
        futures[future] = c
    records: dict[Path, dict] = {}
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
    return [records[c] for c in captures]
