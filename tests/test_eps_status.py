"""``research/eps_status.py``: the status table of ``docs/results/eps.md`` is what the committed records compute."""

from __future__ import annotations

from pathlib import Path

import pytest

from research import eps_status

ROOT = Path(__file__).resolve().parents[1]


def test_the_committed_page_holds_the_table_the_records_compute() -> None:
    rows = [eps_status.measure(variant) for variant in eps_status.VARIANTS] + [
        eps_status.paper_algorithm_row()
    ]
    page = (ROOT / "docs" / "results" / "eps.md").read_text().splitlines()
    missing = [line for line in eps_status.table(rows).splitlines() if line not in page]
    assert not missing, f"docs/results/eps.md is out of date; run python research/eps_status.py: {missing}"


def test_the_ten_pairs_of_the_package_defaults() -> None:
    (variant,) = [v for v in eps_status.VARIANTS if v.name.endswith("report and held-out seeds")]
    pairs = eps_status.measure(variant).pairs
    assert pairs["n"] == 10 and pairs["ahead"] == 2
    assert 100 * pairs["mean"] == pytest.approx(-2.57, abs=0.01) and 100 * pairs["sem"] == pytest.approx(
        1.33, abs=0.01
    )


def test_seeds_text_joins_runs() -> None:
    assert eps_status.seeds_text([0, 1, 2, 3, 4, 146, 147, 148]) == "0-4, 146-148"
    assert eps_status.seeds_text([100, 101]) == "100, 101"
