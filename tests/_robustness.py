"""Shared helpers of the issue-10 robustness tests: small real files, one-line stderr checks."""

from __future__ import annotations

import contextlib
import os
import signal

import numpy as np

from nail2nail.calibration.files import CameraCalibration, RigCalibration, save_calibration
from nail2nail.io._json import write_json
from nail2nail.io.capture import write_frame, write_manifest


def _one_error_line(capsys, *needles):
    """The stderr of the last command: exactly one line, no traceback, holding `needles`."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert str(needle) in lines[0], lines[0]
    return lines[0]


def _calibration(path, names=("cam0",), size=(8, 6)):
    p = np.hstack([np.eye(3), np.ones((3, 1))])
    cams = [CameraCalibration(n, p, p, size) for n in names]
    save_calibration(path, RigCalibration(cameras=cams))
    return path


def _capture(directory, *, frames=None, bit_depth=8, size=(8, 6), names=("cam0",), **extra):
    """A capture directory with real PNG frames (no pattern set)."""
    frames = frames if frames is not None else [np.full((6, 8), 100, np.uint8)] * 2
    cams = []
    for name in names:
        files = []
        for i, frame in enumerate(frames):
            rel = f"{name}/{i:03d}.png"
            write_frame(directory / rel, frame)
            files.append(rel)
        cams.append({"name": name, "size": list(size), "frames": files})
    manifest = {"bit_depth": bit_depth, "n_frames": len(frames), "pattern_set": None,
                "cameras": cams, **extra}
    write_manifest(directory, manifest)
    return directory


def _scan_dir(directory, *, npz=b"", name="cam0", npz_path=None):
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"{name}.npz").write_bytes(npz)
    write_json(directory / "scan.json", {
        "format": "nail2nail-scan", "version": 1,
        "cameras": [{"name": name, "npz": f"{name}.npz" if npz_path is None else npz_path},
                    {"name": "cam1", "npz": "cam1.npz"}]})
    return directory


class Timeout(BaseException):
    """Raised by :func:`time_limit` when its time is up (a BaseException: no ``except
    Exception`` in the code under test swallows it)."""


@contextlib.contextmanager
def time_limit(seconds: float):
    """Raise :class:`Timeout` in the main thread after `seconds` (POSIX interval timer;
    elsewhere no limit)."""
    if not hasattr(signal, "setitimer") or os.name != "posix":
        yield
        return

    def handler(signum, frame):
        raise Timeout()

    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
