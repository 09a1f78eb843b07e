"""The main job's summary line (``python -m sb3_eps.run_main``, ``make run``): it states what the committed records
say of EPS-GDQ against GDQ, and says something else when the records say something else."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sb3_eps.run_main import PAIRED_REFERENCES, reference_difference, reference_summary


def write_arm(folder: Path, algo: str, finals: dict[int, float]) -> None:
    """Records of one arm: per seed, evaluations every 10k ticks to 150k, the last three at ``finals[seed]``; an
    EPS arm's last evaluation lands a few ticks past 150k, as a round leaves it."""
    folder.mkdir(parents=True)
    for seed, final in finals.items():
        rows = [{"ticks": 10_000 * k, "success_rate": 0.1, "team_return_mean": 0.0} for k in range(1, 13)]
        rows += [{"ticks": 10_000 * k, "success_rate": final, "team_return_mean": 1.0} for k in (13, 14, 15)]
        if algo == "eps_gdq":
            rows[-1]["ticks"] = 150_003
        rows.append({"ticks": 160_000, "success_rate": 0.0, "team_return_mean": 0.0})  # past the budget: not counted
        lines = "\n".join(json.dumps(row) for row in rows)
        (folder / f"{algo}_MultiRobotNav-4-v0_seed{seed}.jsonl").write_text(lines + "\n")


def write_references(root: Path, base: list[float], eps: list[float]) -> None:
    for index, (base_folder, eps_folder) in enumerate(PAIRED_REFERENCES):
        seeds = range(10 * index, 10 * index + len(base))
        write_arm(root / base_folder, "gdq", dict(zip(seeds, base)))
        write_arm(root / eps_folder, "eps_gdq", dict(zip(seeds, eps)))


def test_the_summary_line_states_the_committed_records() -> None:
    """The repository's records: ten pairs, EPS-GDQ 2.6 points behind GDQ (SE 1.3), ahead on 2."""
    difference = reference_difference()
    assert difference["n"] == 10 and difference["ahead"] == 2
    assert difference["mean"] == pytest.approx(-2.57, abs=0.01)
    assert difference["sem"] == pytest.approx(1.33, abs=0.01)
    line = reference_summary(difference)
    assert "-2.6 points" in line and "SE 1.3" in line and "10 paired seeds" in line
    assert "EPS has not been found to help on 4 robots" in line and "\n" not in line


def test_the_summary_line_follows_records_where_eps_helps(tmp_path) -> None:
    write_references(tmp_path, base=[0.50, 0.60, 0.70], eps=[0.60, 0.71, 0.79])
    difference = reference_difference(tmp_path)
    assert difference["n"] == 6 and difference["ahead"] == 6
    assert difference["mean"] == pytest.approx(10.0, abs=1e-9)
    line = reference_summary(difference)
    assert "+10.0 points" in line and "ahead of GDQ" in line and "not been found" not in line


def test_the_summary_line_is_left_out_without_the_records(tmp_path) -> None:
    """An installed package has no committed records: no line rather than a line about nothing."""
    assert reference_difference(tmp_path) is None
