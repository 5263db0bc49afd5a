"""Issue 10: a user who cannot write the package directory and has no writable home can run.

Numba's ``cache=True`` raises at import when it finds no cache directory; nail2nail falls back
to a private temporary directory with one warning (``nail2nail._numba_cache``). The package is
copied to a read-only directory and run in a subprocess; as root, without the capabilities that
let root write anywhere (``setpriv``), so that file permissions apply.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

import nail2nail
from nail2nail import _numba_cache

SCRIPT = """
import os, sys, warnings
import numpy as np
import nail2nail
assert nail2nail.__file__.startswith(sys.argv[1]), nail2nail.__file__
import nail2nail.merge  # its kernel is cached too
from nail2nail.cli import main
from nail2nail.scan.patterns import PatternSet, make_patterns
from nail2nail.scan.decoding import decode
ps = PatternSet(x=[(1, 3), (8, 4)], panel_size=(64, 4))
d = decode(make_patterns(ps), ps, saturation=1.01, method="numba")
assert np.abs(d.xp - np.arange(64)).max() < 0.05
print("NUMBA_CACHE_DIR=" + str(os.environ.get("NUMBA_CACHE_DIR")))
sys.exit(main(["--help"]))
"""


def _unprivileged(tmp_path) -> list[str]:
    """Command prefix under which file permissions apply to this process, or skip."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root and setpriv is not installed: cannot drop root's "
                    "permission to write read-only directories")
    prefix = [setpriv, "--inh-caps=-all", "--bounding-set=-all"]
    probe = tmp_path / "probe"
    probe.mkdir(mode=0o555)
    result = subprocess.run([*prefix, sys.executable, "-c", f"open({str(probe / 'x')!r}, 'w')"],
                            capture_output=True, text=True)
    probe.chmod(0o755)
    if result.returncode == 0:
        pytest.skip("setpriv could not drop root's permission to write read-only directories")
    return prefix


def _package_copy(tmp_path, *, writable: bool) -> Path:
    root = tmp_path / "pkg"
    shutil.copytree(Path(nail2nail.__file__).parent, root / "nail2nail",
                    ignore=shutil.ignore_patterns("__pycache__"))
    if not writable:
        for path in [*sorted(root.rglob("*"), reverse=True), root]:
            path.chmod(0o555 if path.is_dir() else 0o444)
    return root


def _run(tmp_path, prefix, pkg, home):
    tmp = tmp_path / "tmp"
    tmp.mkdir(exist_ok=True)
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(home),
           "PYTHONPATH": str(pkg), "TMPDIR": str(tmp), "NUMBA_NUM_THREADS": "1"}
    return subprocess.run([*prefix, sys.executable, "-c", SCRIPT, str(pkg)], env=env,
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)


def test_read_only_package_and_home(tmp_path):
    prefix = _unprivileged(tmp_path)
    pkg = _package_copy(tmp_path, writable=False)
    home = tmp_path / "home"
    home.mkdir(mode=0o555)
    try:
        result = _run(tmp_path, prefix, pkg, home)
        again = _run(tmp_path, prefix, pkg, home)  # finds the cache there, says the same once
    finally:
        for path in [pkg, *pkg.rglob("*"), home]:
            path.chmod(0o755)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and "no locator" not in result.stderr
    assert "usage: nail2nail" in result.stdout
    cache = tmp_path / "tmp" / f"nail2nail-cache-{os.getuid()}" / "numba"
    assert f"NUMBA_CACHE_DIR={cache}" in result.stdout
    assert any(cache.rglob("*.nbi"))  # the kernels were cached there
    assert result.stderr.count("Warning") == 1, result.stderr  # one warning, matplotlib's none
    assert "NumbaCacheWarning" in result.stderr
    assert again.returncode == 0 and again.stderr.count("Warning") == 1, again.stderr


def test_normal_case_no_warning(tmp_path):
    pkg = _package_copy(tmp_path, writable=True)
    home = tmp_path / "home"
    home.mkdir()
    result = _run(tmp_path, [], pkg, home)
    assert result.returncode == 0, result.stderr
    assert "NUMBA_CACHE_DIR=None" in result.stdout
    assert "Warning" not in result.stderr, result.stderr
    assert any((pkg / "nail2nail").rglob("__pycache__/*.nbi"))  # beside the kernels' modules


def test_no_writable_directory_at_all(monkeypatch, tmp_path):
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    monkeypatch.setattr(_numba_cache, "_state", {"configured": False, "cache": True})
    monkeypatch.setattr(_numba_cache, "_can_write", lambda directory: False)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("MPLCONFIGDIR", "/somewhere")
    with pytest.warns(_numba_cache.NumbaCacheWarning, match="not at all"):
        assert _numba_cache.configure_numba_cache() is None
    assert not _numba_cache.cache_enabled()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _numba_cache.configure_numba_cache() is None  # once per process
