"""The one CSV reader of the contract tables (core.tables): every problem at the file line it is on."""

import pytest

from pipeline.core.errors import InputError
from pipeline.core.tables import FLOAT, STR, Problems, csv_rows, read_table

COLUMNS = {"point_id": STR, "q1": FLOAT, "q2": FLOAT}


def _refusal(tmp_path, text):
    path = tmp_path / "poses.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as err:
        read_table(path, COLUMNS)
    return err.value


def test_a_value_after_a_blank_line_is_named_at_its_own_line(tmp_path):
    # line 4 holds the bad value: a blank line 3 must not shift it to line 3
    exc = _refusal(tmp_path, "point_id,q1,q2\nA,1,2\n\nB,x,3\n")
    assert (exc.line, exc.column) == (4, "q1")
    path = tmp_path / "ok.csv"
    path.write_text("point_id,q1,q2\nA,1,2\n\n\nB,3,4\n", encoding="utf-8")
    assert read_table(path, COLUMNS)["_line"].tolist() == [2, 5]


@pytest.mark.parametrize("text, line", [
    ("point_id,q1,q2\nA,1,2\nB,3\n", 3),        # a short row is not a row of empty cells
    ("point_id,q1,q2\nA,1,2,9\nB,3,4\n", 2),    # one field too many on the first row shifts no column
    ("point_id,q1,q2\nA,1,2\nB,3,4\nC,5,6,7\n", 4),
])
def test_a_row_with_the_wrong_number_of_fields_is_refused_at_its_line(tmp_path, text, line):
    exc = _refusal(tmp_path, text)
    assert exc.line == line and "fields, the header has 3" in exc.message


def test_a_column_twice_in_the_header_is_refused(tmp_path):
    exc = _refusal(tmp_path, "point_id,q1,q2,q1\nA,1,2,3\n")
    assert (exc.line, exc.column) == (1, "q1") and "twice" in exc.message


def test_collected_problems_and_rows_read_as_written(tmp_path):
    header, line, rows = csv_rows('\npoint_id, q1 ,q2\n"A", 1,2\n,,\nB,"3",4\n')
    assert (header, line) == (["point_id", "q1", "q2"], 2)
    assert rows == [(3, ["A", "1", "2"]), (5, ["B", "3", "4"])]
    path = tmp_path / "t.csv"
    path.write_text("point_id,q1,q2\nA,1,2\nB,3\n", encoding="utf-8")
    problems = Problems()
    assert read_table(path, COLUMNS, problems=problems) is None
    assert [(p.line, p.column) for p in problems] == [(3, None)]


def test_a_table_passed_through_keeps_every_column_and_its_lines(tmp_path):
    from pipeline.core.tables import csv_header, text_table

    frame, lines = text_table("\ufeffencoder_deg,note\n10.0,a\n\n95.5,b\n", "<stdin>")
    assert list(frame.columns) == ["encoder_deg", "note"] and lines.tolist() == [2, 4]
    with pytest.raises(InputError) as err:
        text_table("encoder_deg,note\n10.0\n", "<stdin>")
    assert err.value.line == 2
    path = tmp_path / "t.csv"
    path.write_text("\n point_id , q1\nA,1\n", encoding="utf-8")
    assert csv_header(path) == ["point_id", "q1"]


def test_a_repeated_id_is_named_at_its_line_with_the_callers_message(tmp_path):
    """check_unique_ids: the first row repeating an earlier id, at its own file line (a blank line
    before it counted), in the caller's words; collected instead of raised when given Problems."""
    from pipeline.core.tables import check_unique_ids

    path = tmp_path / "poses.csv"
    path.write_text("point_id,q1,q2\nA,1,2\nB,1,2\n\nC,1,2\nB,3,4\nA,5,6\n", encoding="utf-8")
    frame = read_table(path, COLUMNS)
    with pytest.raises(InputError) as err:
        check_unique_ids(path, frame, "point_id '{id}' again (first on line {first})")
    e = err.value
    assert (e.line, e.column) == (6, "point_id")          # B repeats first, on line 6; A only on line 7
    assert e.message == "point_id 'B' again (first on line 3)"
    problems = Problems()
    assert check_unique_ids(path, frame, "duplicate '{id}'", problems=problems) is None
    assert [(p.line, p.message) for p in problems] == [(6, "duplicate 'B'")]
    unique = read_table(path, COLUMNS).iloc[:3]
    check_unique_ids(path, unique, "never raised '{id}'")    # A, B, C: no error


def test_seen_ids_remember_the_first_line():
    from pipeline.core.tables import SeenIds

    seen = SeenIds()
    assert seen.earlier("P1", 2) is None and seen.earlier("P2", 3) is None
    assert seen.earlier("P1", 9) == 2 and seen.earlier("P1", 12) == 2      # always the first line
    assert seen.earlier("p1", 13) is None                                  # ids are case-sensitive
