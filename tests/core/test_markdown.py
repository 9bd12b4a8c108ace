"""hypa.reporting.markdown: the one way every report writes a table."""

import pytest

from hypa.reporting.markdown import cell, row, table


def test_table_lines_header_alignment_rows():
    assert table(["parameter", "value", "unit"], [["mass", 92.6, "kg"], ["J", "1.5e+03", "kg m²"]], align="lrl") == [
        "| parameter | value | unit |",
        "|---|---:|---|",
        "| mass | 92.6 | kg |",
        "| J | 1.5e+03 | kg m² |",
    ]


def test_alignment_defaults_to_left_and_knows_center():
    assert table(["a", "b"], [])[1] == "|---|---|"
    assert table(["a", "b", "c"], [], align="lrc")[1] == "|---|---:|:---:|"


def test_cell_escapes_a_bare_pipe_once_and_joins_lines():
    assert cell("std / |mean|") == "std / \\|mean\\|"
    assert cell("std / \\|mean\\|") == "std / \\|mean\\|"  # already escaped: left as it is
    assert cell("first\nsecond") == "first second"
    assert cell(3) == "3" and cell(None) == "None"
    assert row(["a|b", "", 1]) == "| a\\|b |  | 1 |"  # an empty cell stays a cell


def test_table_refuses_a_row_of_the_wrong_length():
    with pytest.raises(ValueError, match="row 1 has 2 cells for 3 columns"):
        table(["a", "b", "c"], [[1, 2, 3], [1, 2]])
    with pytest.raises(ValueError, match="row 0 has 4 cells"):
        table(["a", "b", "c"], [[1, 2, 3, 4]])


@pytest.mark.parametrize("align", ["lr", "lrrl", "lxr"])
def test_table_refuses_a_bad_alignment(align):
    with pytest.raises(ValueError, match="one of l, r, c per column"):
        table(["a", "b", "c"], [], align=align)
