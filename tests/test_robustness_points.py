"""Issue 10: points tables: Excel's byte-order marks, and errors that say which table."""

from __future__ import annotations

import numpy as np
import pytest
from _robustness import _one_error_line

from nail2nail.cli import main
from nail2nail.io.points import read_points


def _write(path, table, *, encoding="utf-8", bom=False, rows=None):
    lines = table.read_text().splitlines()
    lines = lines[: rows + 1] if rows is not None else lines
    text = "\r\n".join(lines) + "\r\n"
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode(encoding))
    return path


@pytest.mark.parametrize(("encoding", "bom"), [("utf-8", True), ("utf-16", False)])
def test_excel_byte_order_mark_accepted(tmp_path, capsys, table_paths, encoding, bom):
    excel = _write(tmp_path / "excel.tsv", table_paths[0], encoding=encoding, bom=bom)
    table, plain = read_points(excel), read_points(table_paths[0])
    assert list(table.columns) == list(plain.columns)  # "Xw", not "\ufeffXw"
    np.testing.assert_array_equal(table.xyz_world, plain.xyz_world)
    assert main(["calibrate", str(excel), "-o", str(tmp_path / "c.json")]) == 0
    capsys.readouterr()


def test_too_few_points_names_the_table(tmp_path, capsys, table_paths):
    short = _write(tmp_path / "short.tsv", table_paths[0], rows=5)
    assert main(["calibrate", str(short), "-o", str(tmp_path / "c.json")]) == 2
    _one_error_line(capsys, "short.tsv", "at least 6 points")
    assert not (tmp_path / "c.json").exists()
    assert main(["crosscheck", str(table_paths[0]), str(short)]) == 2
    line = _one_error_line(capsys, "short.tsv", "at least 6 points")
    assert str(table_paths[0]) not in line


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-Infinity"])
def test_non_finite_cell_names_line(tmp_path, capsys, table_paths, cell):
    lines = table_paths[1].read_text().splitlines()
    header = lines[0].split("\t")
    row = lines[3].split("\t")
    row[header.index("Yw")] = cell
    lines[3] = "\t".join(row)
    bad = tmp_path / "bad.tsv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"bad.tsv: line 4, column Yw: .* not a finite number"):
        read_points(bad)
    assert main(["crosscheck", str(table_paths[0]), str(bad)]) == 2
    _one_error_line(capsys, "bad.tsv", "line 4")


@pytest.mark.parametrize("shape", ["coplanar", "collinear"])
def test_degenerate_points_name_the_table(tmp_path, capsys, table_paths, shape):
    table = read_points(table_paths[0])
    xyz = table.xyz_world.copy()
    xyz[:, 2] = 5.0  # a plane
    if shape == "collinear":
        xyz[:, 1] = 2.0 * xyz[:, 0]
    lines = [["Xw", "Yw", "Zw", "xc", "yc", "xp", "yp"]]
    for (x, y, z), (xc, yc), (xp, yp) in zip(xyz, table.xy_camera, table.xy_projector,
                                             strict=True):
        lines.append([repr(float(v)) for v in (x, y, z, xc, yc, xp, yp)])
    flat = tmp_path / f"{shape}.csv"
    flat.write_text("\n".join(",".join(r) for r in lines) + "\n")
    assert main(["calibrate", str(flat), "--json"]) == 2
    _one_error_line(capsys, f"{shape}.csv", shape)
    assert main(["crosscheck", str(flat), str(table_paths[1])]) == 2
    _one_error_line(capsys, f"{shape}.csv", shape)
