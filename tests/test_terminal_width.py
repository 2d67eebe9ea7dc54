"""Readable in a terminal (issue 50): tables and legends fit 120 columns; a table wider than that is split into
tables one under the other, each led by the column that says what its rows are (the full figures are in the
JSON). Before: ``zentrack sim``'s table was 182 columns wide."""
from __future__ import annotations

from zentrack.cli import main
from zentrack.common.report import MAX_WIDTH, table


def test_a_wide_table_is_split_into_blocks_that_fit_each_led_by_the_first_column():
    headers = ["what"] + [f"figure {i:02d}" for i in range(15)]
    rows = [[f"row {r}"] + [f"{r * 1000 + i:>10}" for i in range(15)] for r in range(3)]
    text = table(headers, rows)
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= MAX_WIDTH < sum(len(h) + 2 for h in headers)
    blocks = text.split("\n\n")
    assert len(blocks) >= 2 and all(block.startswith("what") for block in blocks)
    assert all(h in text for h in headers) and "2014" in text  # every column and figure is somewhere


def test_sims_table_of_five_filters_and_two_rules_fits_120_columns(capsys):
    assert main(["sim", "--scenario", "exp2", "--runs", "2", "--steps", "10", "--filter", "teskf,eskf,ekf,ukf,ckf",
                 "--fusion", "ci,centralized"]) == 0
    out = capsys.readouterr().out
    assert "teskf" in out and "ckf" in out
    assert max(len(line) for line in out.splitlines()) <= MAX_WIDTH, max(out.splitlines(), key=len)
