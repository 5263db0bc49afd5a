"""Where numba (and matplotlib) cache: beside the package, in the user's cache, or a fallback.

``scan/kernels.py``, ``scan/rays.py``, ``merge/`` and ``unroll/`` compile their kernels with
``cache=True``. Numba stores the cache in ``__pycache__`` beside the source, else in the user's
cache directory (``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``); if neither can be written (a
service account with no home, a read-only container) it raises ``RuntimeError: cannot cache
function …: no locator available`` when the kernel is *defined*, so every command would die at
import. Caching is an optimisation: :func:`configure_numba_cache`, run when ``nail2nail`` is
imported, detects that case and points numba at a private temporary directory
(``NUMBA_CACHE_DIR``), with one warning. Nothing changes when numba can cache as usual or
``NUMBA_CACHE_DIR`` is already set. Matplotlib (the figures) has the same need for a writable
configuration directory and warns in two lines without one; in that case ``MPLCONFIGDIR`` gets a
private directory too, and the one warning says so. """

from __future__ import annotations

import os
import stat
import sys
import tempfile
import warnings
from pathlib import Path

__all__ = ["NumbaCacheWarning", "cache_enabled", "configure_numba_cache"]

PACKAGE_DIR = Path(__file__).resolve().parent

_state: dict[str, object] = {"configured": False, "cache": True}


class NumbaCacheWarning(UserWarning):
    """Numba cannot cache beside the package nor in the user's cache; a fallback is used."""


def _can_write(directory: Path) -> bool:
    """What numba's ``ensure_cache_path`` asks: can the directory be made and written to?"""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=directory).close()
    except (OSError, ValueError):
        return False
    return True


def _user_cache_dir() -> Path | None:
    """Numba's user-wide cache directory (its ``appdirs.user_cache_dir``) on this system."""
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA")
        return Path(base) / "numba" / "numba" / "Cache" if base else None
    if sys.platform == "darwin":
        home = os.path.expanduser("~")
        return None if home == "~" else Path(home) / "Library" / "Caches" / "numba"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    return None if base.startswith("~") else Path(base) / "numba"


def _private_dir() -> Path | None:
    """A cache directory in the temporary directory that only this user can write."""
    try:
        uid = os.getuid() if hasattr(os, "getuid") else None
        owner = "user" if uid is None else uid
        shared = Path(tempfile.gettempdir()) / f"nail2nail-cache-{owner}"
        try:
            shared.mkdir(mode=0o700, exist_ok=True)
            info = shared.lstat()
            safe = (stat.S_ISDIR(info.st_mode) and (uid is None or info.st_uid == uid)
                    and not info.st_mode & 0o022)
        except OSError:
            safe = False
        if safe and _can_write(shared):
            return shared  # reused by the next run: the cache stays useful
        return Path(tempfile.mkdtemp(prefix="nail2nail-cache-"))  # this run only
    except OSError:
        return None


def configure_numba_cache() -> Path | None:
    """Give numba a writable cache directory if it would find none; return it (else ``None``).

    Runs once per process. When numba can cache beside the package or in the user's cache, or
    ``NUMBA_CACHE_DIR`` is set, it changes nothing and says nothing. Otherwise it sets
    ``NUMBA_CACHE_DIR`` (and numba's loaded configuration) to a private directory in the
    temporary directory, warning once (:class:`NumbaCacheWarning`); if even that fails, kernels
    are compiled without a cache (:func:`cache_enabled` is then ``False``).
    """
    if _state["configured"]:
        return None
    _state["configured"] = True
    base = None
    notes = []
    if not os.environ.get("MPLCONFIGDIR") and not _matplotlib_can_write():
        base = _private_dir()
        if base is not None and _can_write(base / "matplotlib"):
            os.environ["MPLCONFIGDIR"] = str(base / "matplotlib")
            notes.append(f"matplotlib's in {base / 'matplotlib'}")
    numba_dir = None
    if not os.environ.get("NUMBA_CACHE_DIR") and not _can_write(PACKAGE_DIR / "__pycache__"):
        user = _user_cache_dir()
        if user is None or not _can_write(user):
            base = base or _private_dir()
            if base is not None and _can_write(base / "numba"):
                numba_dir = base / "numba"
                os.environ["NUMBA_CACHE_DIR"] = str(numba_dir)
                if "numba" in sys.modules:  # already configured from the environment
                    sys.modules["numba"].config.CACHE_DIR = str(numba_dir)
                notes.insert(0, f"numba's compiled kernels in {numba_dir}")
            else:
                _state["cache"] = False
                notes.insert(0, "numba's compiled kernels not at all (no writable directory)")
    if notes:
        warnings.warn(
            f"nail2nail: the package directory ({PACKAGE_DIR}) and the home directory are not "
            f"writable; caching {' and '.join(notes)} (set NUMBA_CACHE_DIR, MPLCONFIGDIR to "
            "choose)",
            NumbaCacheWarning, stacklevel=2,
        )
    return numba_dir


def _matplotlib_can_write() -> bool:
    """Whether matplotlib finds its configuration and cache directories writable."""
    home = os.path.expanduser("~")
    config = os.environ.get("XDG_CONFIG_HOME") or os.path.join(home, ".config")
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(home, ".cache")
    if config.startswith("~") or cache.startswith("~"):
        return False
    return _can_write(Path(config) / "matplotlib") and _can_write(Path(cache) / "matplotlib")


def cache_enabled() -> bool:
    """Whether kernels may be compiled with ``cache=True`` (see :func:`configure_numba_cache`)."""
    configure_numba_cache()
    return bool(_state["cache"])
