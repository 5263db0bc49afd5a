"""Write-then-rename, so that an interrupted or failed write never leaves a partial file.

:func:`atomic_path` does it for one file, :func:`atomic_directory` for a whole output directory
(a capture, a scan or merge directory, a print, a pattern set), :func:`atomic_files` for a group
of files beside each other (a calibration and its points tables). ``docs/conventions.md``,
"Files".
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

__all__ = [
    "OutputRefusedError",
    "atomic_directory",
    "atomic_files",
    "atomic_path",
    "check_output_directory",
    "check_output_file",
    "relocate_paths",
    "save_figure",
    "write_npz",
]


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` only if the block succeeds.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("hello")
    >>> target.read_text()
    'hello'
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError as exc:  # a file where a directory of `path` should be: name `path`
        raise NotADirectoryError(errno.ENOTDIR, f"cannot write: {exc.filename} is a file, not a "
                                 "directory", str(path)) from exc
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual permissions
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _usual_mode(path: Path, mode: int) -> None:
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, mode & ~umask)  # mkdtemp makes 0700; give the usual permissions


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink()


class OutputRefusedError(ValueError):
    """An output path that may not be replaced (a file, or a directory not of this command).

    A ``ValueError`` (the command exits 2), told apart from the errors of the inputs: the
    batch (:mod:`nail2nail.batch`) runs such a capture again once the path is cleared.
    """


def _writable(path: Path) -> bool:
    """Whether this process may write in the directory `path` and its owner made it writable
    (no write permission bit at all: made read-only on purpose, even for root)."""
    return os.access(path, os.W_OK) and bool(path.stat().st_mode & 0o222)


def check_output_directory(path: str | os.PathLike, *,
                           marker: str | tuple[str, ...] | None = None) -> Path:
    """Check that :func:`atomic_directory` may replace `path`; return it (links followed).

    Writers call it before their long computation, so that a refusal comes first.
    """
    path = Path(path)
    if path.is_symlink() and path.is_dir():
        path = Path(os.path.realpath(path))
    if path.exists() and not path.is_dir():
        raise OutputRefusedError(f"{path}: exists and is not a directory")
    if path.is_dir() and not _writable(path):  # the user protected it: not replaced
        raise OutputRefusedError(f"{path}: the directory is read-only: not replaced (make it "
                                 "writable or choose another directory)")
    if marker is not None and path.is_dir():
        markers = (marker,) if isinstance(marker, str) else tuple(marker)
        if any(path.iterdir()) and not any((path / m).exists() for m in markers):
            raise OutputRefusedError(
                f"{path}: exists, is not empty and holds no {' or '.join(markers)}, so it is "
                "not an earlier result of this command: not replaced (remove it or choose "
                "another directory)")
    return path


def check_output_file(path: str | os.PathLike) -> Path:
    """Check that :func:`atomic_path` may write the file `path`; return it as a ``Path``.

    Refused (``ValueError`` naming `path` as given, never the hidden temporary file): an
    existing directory, or a path under an existing non-directory. Writers call it before
    their computation and before writing anything else (a calibration's points tables).
    """
    path = Path(path)
    if path.is_dir():
        raise OutputRefusedError(f"{path}: is a directory; give the file to write")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputRefusedError(f"{path}: cannot write ({parent} is not a directory)")
            break
    return path


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, *, marker: str | tuple[str, ...] | None = None
                     ) -> Iterator[Path]:
    """Yield an empty temporary directory that replaces the directory `path` as a whole.

    The block writes the new result into the yielded directory, a sibling of `path` named
    ``.NAME.tmp-XXXXXXXX``. When the block succeeds the old `path` (if any) is moved aside, the
    new directory renamed into its place and the old one deleted; when it fails or is
    interrupted (an exception, Ctrl-C) the temporary directory is removed and `path` is left
    as it was. So `path` always holds the old result or the new one, never a mix; a run killed
    outright (``SIGKILL``, power loss) leaves only the hidden temporary directory behind.

    Parameters
    ----------
    path : path-like
        The output directory; its parent is created if needed. A symbolic link to a directory
        is followed: the directory it points to is replaced.
    marker : str or tuple of str, optional
        The file (any of the files) that marks a directory as this writer's earlier result,
        e.g. ``"capture.json"``. An existing, non-empty `path` holding none of them is not
        replaced: it may be the user's other data (``--out .``).

    Raises
    ------
    ValueError
        `path` exists and is not a directory, is a read-only directory, or is a non-empty
        directory without `marker`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "out"
    >>> with atomic_directory(target, marker="a.txt") as tmp:
    ...     _ = (tmp / "a.txt").write_text("new")
    >>> sorted(p.name for p in target.iterdir())
    ['a.txt']
    """
    path = check_output_directory(path, marker=marker)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    try:
        _usual_mode(tmp, 0o777)
        yield tmp
        old = None
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
            os.replace(path, old)  # onto the empty directory just made
        os.replace(tmp, path)
    except BaseException:
        _remove(tmp)
        raise
    if old is not None:
        _remove(old)


@contextlib.contextmanager
def atomic_files(directory: str | os.PathLike, names: list[str]) -> Iterator[Path]:
    """Yield a temporary directory; on success move the files `names` from it into `directory`.

    For a group of files that belong together but share their directory with other files (a
    calibration JSON and its points tables): the block writes every file of `names` into the
    yielded directory (a hidden sibling of them), nothing of `directory` changes until it
    succeeds; then each file replaces its namesake, in the order of `names` (put the file that
    makes the group usable last). On failure or interrupt the temporary directory is removed.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".nail2nail.tmp-", dir=directory))
    try:
        yield tmp
        for name in names:
            if not (tmp / name).is_file():
                raise FileNotFoundError(f"{tmp / name}: not written")
        for name in names:
            os.replace(tmp / name, directory / name)
    finally:
        _remove(tmp)


def save_figure(fig, path: str | os.PathLike, *, dpi: int = 100) -> Path:
    """Write a matplotlib figure as PNG at `path` (atomically); return `path` as a ``Path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return path


def write_npz(path: str | os.PathLike, arrays: dict,
              *, compress: bool | int | Mapping[str, bool | int] = True) -> Path:
    """Write `arrays` (name -> array) to an ``.npz`` at `path`, atomically.

    The file is what :func:`numpy.savez_compressed` (`compress` ``True``) or :func:`numpy.savez`
    (``False``) writes, read by :func:`numpy.load`; no array may need pickle.

    Parameters
    ----------
    path : path-like
        Used as given (no ``.npz`` suffix is appended).
    arrays : dict of str to array_like
        The arrays, in file order.
    compress : bool, int or mapping of str to bool or int
        ``True``: zlib at its default level 6 (``np.savez_compressed``); ``False`` or 0: stored
        uncompressed (fastest to write and read: float noise compresses little and slowly,
        ``bench/io.py``); 1 … 9: zlib at that level. A mapping gives it per array name; the
        arrays it does not name are stored.

    Returns
    -------
    Path
        `path`.

    Raises
    ------
    ValueError
        A `compress` value not a bool or 0 … 9, or an array of objects (it would need pickle).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "a.npz"
    >>> _ = write_npz(target, {"x": np.arange(3)}, compress=False)
    >>> np.load(target)["x"].tolist()
    [0, 1, 2]
    """
    if isinstance(compress, Mapping):
        levels = {name: _zlib_level(compress.get(name, False)) for name in arrays}
    else:
        level = _zlib_level(compress)
        levels = dict.fromkeys(arrays, level)
    path = Path(path)
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", allowZip64=True) as archive:
        for name, value in arrays.items():
            level = levels[name]
            # ZipFile.open(name, "w") takes the archive's method and level (None: zlib's 6)
            archive.compression = zipfile.ZIP_STORED if level == 0 else zipfile.ZIP_DEFLATED
            archive.compresslevel = level or None
            # as np.savez: one NPY file per array; force_zip64 since the size is unknown here
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
    return path


def _zlib_level(compress) -> int | None:
    if isinstance(compress, (bool, np.bool_)):
        return None if compress else 0
    if isinstance(compress, (int, np.integer)) and 0 <= compress <= 9:
        return int(compress)
    raise ValueError(f"compress: expected a bool or a zlib level 0 … 9, got {compress!r}")


def relocate_paths(obj, old: str, new: str):
    """`obj` with every string path under `old` moved under `new` (dicts and lists walked)."""
    if isinstance(obj, dict):
        return {k: relocate_paths(v, old, new) for k, v in obj.items()}
    if isinstance(obj, list):
        return [relocate_paths(v, old, new) for v in obj]
    if isinstance(obj, str) and (obj == old or obj.startswith(old + os.sep)):
        return new + obj[len(old):]
    return obj
