"""Every rendered cell shows its count, even when the value's text happens to equal the count."""

from vladrivebench._analysis.report import cell_text
from vladrivebench._analysis.tables import Cell


def test_a_rate_whose_text_equals_its_count_still_shows_the_count():
    cell = Cell.rate(100, 100)
    assert cell.display == "100"
    assert cell_text(cell) == "100 (100)"


def test_a_count_cell_is_shown_once():
    assert cell_text(Cell("42", 42)) == "42"
