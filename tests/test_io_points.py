"""Points tables: reading, writing, errors."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import thesis_table_path

from nail2nail.io.points import read_points, thesis_table, write_points


def test_read_thesis_table():
    table = read_points(thesis_table_path(0))
    assert len(table) == 30
    assert table.xyz_world.shape == (30, 3)
    assert table.labels[:3] == ["1", "2", "3"]
    assert "err_Xw" in table.columns  # extra columns kept
    assert table.xyz_world[0].tolist() == [-7.2817, 19.05, 7.9003]


def test_round_trip_keeps_extra_columns(tmp_path):
    table = thesis_table(1)
    write_points(tmp_path / "t.tsv", table)
    back = read_points(tmp_path / "t.tsv")
    assert back.labels == table.labels
    for name, values in table.columns.items():
        np.testing.assert_array_equal(back.columns[name], values)


def test_csv_is_read(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("Xw,Yw,Zw,xc,yc,xp,yp,note\n1,2,3,4,5,6,7,8\n")
    assert read_points(path).xy_projector.tolist() == [[6.0, 7.0]]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("Xw\tYw\tZw\txc\tyc\txp\n1\t2\t3\t4\t5\t6\n", "missing column"),
        ("Xw\tYw\tZw\txc\tyc\txp\typ\n1\t2\tx\t4\t5\t6\t7\n", "line 2, column Zw"),
        ("Xw\tYw\tZw\txc\tyc\txp\typ\n", "no data rows"),
        ("Xw\tYw\tZw\txc\tyc\txp\typ\n1\t2\t3\n", "line 2 has 3 fields"),
        ("", "empty"),
    ],
)
def test_bad_tables_name_the_file(tmp_path, text, message):
    path = tmp_path / "bad.tsv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        read_points(path)
    assert "bad.tsv" in str(info.value)
