"""Calibration points tables: ``Xw Yw Zw xc yc xp yp`` (TSV or CSV), extra columns kept.

The thesis's Tables 2 and 3 ship as example data (:func:`thesis_table`).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from nail2nail.io._atomic import atomic_path

__all__ = ["REQUIRED_COLUMNS", "PointsTable", "read_points", "thesis_table", "write_points"]

REQUIRED_COLUMNS = ("Xw", "Yw", "Zw", "xc", "yc", "xp", "yp")


@dataclass
class PointsTable:
    """A calibration points table.

    Attributes
    ----------
    columns : dict[str, (N,) float64]
        Every numeric column by name, in file order (required ones and extras).
    labels : (N,) list of str
        Point labels: the ``point`` column if present, else ``"1" … "N"``.
    """

    columns: dict[str, np.ndarray]
    labels: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.columns["Xw"])

    @classmethod
    def from_arrays(cls, xyz_world, xy_camera, xy_projector, *, extra=None) -> PointsTable:
        """A table from ``(N, 3)`` world mm, ``(N, 2)`` camera px and ``(N, 2)`` projector
        coordinates, with optional extra ``(N,)`` columns by name; points labelled ``1 … N``.
        """
        xyz = np.asarray(xyz_world, dtype=float)
        cam = np.asarray(xy_camera, dtype=float)
        proj = np.asarray(xy_projector, dtype=float)
        columns = {
            "Xw": xyz[:, 0],
            "Yw": xyz[:, 1],
            "Zw": xyz[:, 2],
            "xc": cam[:, 0],
            "yc": cam[:, 1],
            "xp": proj[:, 0],
            "yp": proj[:, 1],
        }
        for name, values in (extra or {}).items():
            columns[name] = np.asarray(values, dtype=float)
        return cls(columns=columns, labels=[str(i + 1) for i in range(len(xyz))])

    @property
    def xyz_world(self) -> np.ndarray:
        """(N, 3) world points, mm."""
        return np.column_stack([self.columns[c] for c in ("Xw", "Yw", "Zw")])

    @property
    def xy_camera(self) -> np.ndarray:
        """(N, 2) camera coordinates ``(xc, yc)``, px."""
        return np.column_stack([self.columns["xc"], self.columns["yc"]])

    @property
    def xy_projector(self) -> np.ndarray:
        """(N, 2) projector coordinates ``(xp, yp)``."""
        return np.column_stack([self.columns["xp"], self.columns["yp"]])


def _sniff_delimiter(header: str, path: Path) -> str:
    if "\t" in header:
        return "\t"
    if "," in header:
        return ","
    if len(header.split()) > 1:
        return " "
    raise ValueError(f"{path}: cannot tell the delimiter of the header line {header!r}")


def read_points(path: str | os.PathLike) -> PointsTable:
    """Read a points table (tab-, comma- or space-separated, with a header line).

    Raises
    ------
    ValueError
        Naming the file: missing required columns, a non-numeric, NaN or infinite cell in a
        required column (with its line), or no rows. A byte-order mark (Excel's UTF-8 or
        UTF-16 exports) is accepted.
    """
    path = Path(path)
    raw = path.read_bytes()
    # Excel writes a byte-order mark: UTF-8 ("CSV UTF-8") or UTF-16 ("Unicode text")
    encoding = "utf-16" if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else "utf-8-sig"
    try:
        text = raw.decode(encoding)
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a text points table (not {encoding.upper()})") from exc
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ValueError(f"{path}: empty points table")
    delimiter = _sniff_delimiter(lines[0], path)
    if delimiter == " ":
        rows = [ln.split() for ln in lines]
    else:
        rows = [[cell.strip() for cell in r] for r in csv.reader(lines, delimiter=delimiter)]
    header, body = rows[0], rows[1:]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)} (header: {header})")
    if not body:
        raise ValueError(f"{path}: no data rows")
    columns: dict[str, np.ndarray] = {}
    labels: list[str] = []
    for j, name in enumerate(header):
        cells = []
        for i, row in enumerate(body):
            if len(row) != len(header):
                raise ValueError(
                    f"{path}: line {i + 2} has {len(row)} fields, the header has {len(header)}"
                )
            cells.append(row[j])
        if name == "point":
            labels = cells
            continue
        try:
            columns[name] = np.array([float(c) for c in cells])
        except ValueError:
            if name in REQUIRED_COLUMNS:
                bad = next(i for i, c in enumerate(cells) if not _is_float(c))
                raise ValueError(
                    f"{path}: line {bad + 2}, column {name}: {cells[bad]!r} is not a number"
                ) from None
            continue  # a non-numeric extra column is ignored
        if name in REQUIRED_COLUMNS and not np.all(np.isfinite(columns[name])):
            bad = int(np.flatnonzero(~np.isfinite(columns[name]))[0])
            raise ValueError(
                f"{path}: line {bad + 2}, column {name}: {cells[bad]!r} is not a finite number"
            )
    return PointsTable(columns=columns, labels=labels or [str(i + 1) for i in range(len(body))])


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def write_points(path: str | os.PathLike, table: PointsTable) -> None:
    """Write `table` as TSV (atomically), required columns first, extras after."""
    names = list(REQUIRED_COLUMNS) + [c for c in table.columns if c not in REQUIRED_COLUMNS]
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            fh.write("\t".join(["point", *names]) + "\n")
            for i, label in enumerate(table.labels):
                values = [repr(float(table.columns[c][i])) for c in names]
                fh.write("\t".join([label, *values]) + "\n")


def thesis_table(camera: int) -> PointsTable:
    """The thesis's Table 2 (`camera` 0) or Table 3 (`camera` 1), shipped with the package.

    Table 2 has the restored minus signs described in ``nail2nail/data/README.md``.

    Examples
    --------
    >>> len(thesis_table(0)), float(thesis_table(0).columns["Xw"][0])
    (30, -7.2817)
    """
    names = {0: "thesis_table2_camera0.tsv", 1: "thesis_table3_camera1.tsv"}
    if camera not in names:
        raise ValueError(f"camera: the thesis has tables for cameras 0 and 1, not {camera}")
    with resources.as_file(resources.files("nail2nail") / "data" / names[camera]) as p:
        return read_points(p)
