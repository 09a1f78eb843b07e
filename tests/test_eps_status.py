"""``research/eps_status.py``: the status table of ``docs/results/eps.md`` is what the committed records compute."""

from __future__ import annotations

from pathlib import Path

import pytest

from research import eps_status

ROOT = Path(__file__).resolve().parents[1]


def test_the_committed_page_holds_the_table_the_records_compute() -> None:
    rows = eps_status.all_rows()
    page = (ROOT / "docs" / "results" / "eps.md").read_text().splitlines()
    missing = [line for line in eps_status.table(rows).splitlines() if line not in page]
    assert not missing, f"docs/results/eps.md is out of date; run python research/eps_status.py: {missing}"


def test_the_ten_pairs_of_the_package_defaults() -> None:
    (variant,) = [v for v in eps_status.VARIANTS if v.name.endswith("report and held-out seeds")]
    pairs = eps_status.measure(variant).pairs
    assert pairs["n"] == 10 and pairs["ahead"] == 2
    assert 100 * pairs["mean"] == pytest.approx(-2.57, abs=0.01) and 100 * pairs["sem"] == pytest.approx(1.33, abs=0.01)


def test_seeds_text_joins_runs() -> None:
    assert eps_status.seeds_text([0, 1, 2, 3, 4, 146, 147, 148]) == "0-4, 146-148"
    assert eps_status.seeds_text([100, 101]) == "100, 101"


def test_the_8_robot_screen_pairs_each_arm_with_scratch_on_finished_seeds(tmp_path) -> None:
    """An unfinished run (no evaluation at 300k) is left out; the score is the mean of the last three evaluations."""
    import json

    screen, ladder = tmp_path / eps_status.SCREEN8.folder, tmp_path / eps_status.SCREEN8.scratch_folders[0]
    screen.mkdir(parents=True)
    ladder.mkdir(parents=True)

    def write(path, rates, **last):
        records = [{"ticks": 25_000 * (i + 1), "success_rate": rate} for i, rate in enumerate(rates)]
        records[-1].update(last)
        path.write_text("".join(json.dumps(record) + "\n" for record in records))

    write(ladder / "scratch_seed220.jsonl", [0.5] * 9 + [0.7, 0.8, 0.9])
    write(screen / "eps_early_seed220.jsonl", [0.5] * 9 + [0.6, 0.6, 0.6], rounds=3, crossovers=1, eps_ticks=9000)
    write(screen / "eps_early_seed221.jsonl", [0.5] * 12, rounds=3, crossovers=0, eps_ticks=9000)  # no scratch
    write(screen / "eps_team4_seed220.jsonl", [0.5] * 11, rounds=2, crossovers=0, eps_ticks=100)  # unfinished
    rows = {row.variant.name: row for row in eps_status.screen_rows(eps_status.SCREEN8, tmp_path)}
    early = rows[eps_status.SCREEN8.arms["eps_early"]]
    assert early.seeds == [220] and early.rounds == 3 and early.crossovers == 1 and early.eps_ticks == [9000]
    assert early.base_scores == pytest.approx([0.8]) and early.eps_scores == pytest.approx([0.6])
    assert eps_status.SCREEN8.arms["eps_team4"] not in rows


def test_the_unseen_room_screen_scores_the_final_models_on_the_room(tmp_path) -> None:
    """An unseen-room screen pairs each arm's final-model success on the room with GDQ's, seed by seed; a seed
    without GDQ's record, or a record of another room, is left out."""
    import json

    screen = eps_status.SCREEN_UNSEEN
    folder = tmp_path / screen.folder
    folder.mkdir(parents=True)
    for arm, seed in (("gdq", 220), ("eps_early", 220), ("eps_early", 221)):
        final = {"ticks": 150_000, "success_rate": 0.9, "rounds": 5, "crossovers": 1, "eps_ticks": 7000}
        (folder / f"{arm}_seed{seed}.jsonl").write_text(json.dumps(final) + "\n")
    rooms = [
        {"arm": "gdq", "seed": 220, "room": screen.unseen_room, "success_rate": 0.2},
        {"arm": "eps_early", "seed": 220, "room": screen.unseen_room, "success_rate": 0.35},
        {"arm": "eps_early", "seed": 220, "room": "MultiRobotNavUnseen-4-v0", "success_rate": 0.99},
        {"arm": "eps_early", "seed": 221, "room": screen.unseen_room, "success_rate": 0.5},
    ]
    (folder / "unseen_room.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rooms))
    (row,) = eps_status.screen_rows(screen, tmp_path)
    assert row.variant.name == screen.arms["eps_early"] and row.seeds == [220]
    assert row.base_scores == pytest.approx([0.2]) and row.eps_scores == pytest.approx([0.35])
    assert row.rounds == 5 and row.crossovers == 1 and row.variant.robots == 4
