"""``benchmarks/compare_eps.py``: the floor of issue 10 is read from it, so its tick accounting is tested."""

from __future__ import annotations

import importlib.util
import json
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def compare_eps():
    spec = importlib.util.spec_from_file_location("compare_eps", ROOT / "benchmarks" / "compare_eps.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_run(folder: pathlib.Path, name: str, points: list[tuple[int, float]]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    lines = [json.dumps({"ticks": ticks, "success_rate": success, "n_episodes": 100}) for ticks, success in points]
    (folder / f"{name}_MultiRobotNav-4-v0_seed0.jsonl").write_text("\n".join(lines) + "\n")


def test_an_evaluation_a_round_carried_past_its_point_counts_for_that_point(compare_eps, tmp_path) -> None:
    """An EPS run's evaluations land a few ticks past their points (a round, or a counter moving 4 ticks at a
    time); its final one at 30,003 is the 30k point's and must not be dropped for an earlier one."""
    write_run(tmp_path / "base", "gdq", [(10_000, 0.2), (20_000, 0.4), (30_000, 0.6)])
    write_run(tmp_path / "eps", "eps_gdq", [(10_000, 0.2), (20_051, 0.5), (30_003, 0.9), (40_002, 0.1)])
    eps = compare_eps.read_runs(tmp_path / "eps")[0]
    assert compare_eps.last_mean(eps, 30_000, 10_000, n=2) == pytest.approx(0.7)
    assert compare_eps.last_mean(eps, 30_000, 10_000, n=3) == pytest.approx((0.2 + 0.5 + 0.9) / 3)
    # the area uses the scheduled points: 0 -> 0.2 -> 0.5 -> 0.9 at 10k/20k/30k
    expected = (0.5 * 0.2 + 0.5 * (0.2 + 0.5) + 0.5 * (0.5 + 0.9)) * 10_000 / 30_000
    assert compare_eps.area(eps, 30_000, 10_000) == pytest.approx(expected)
    text = compare_eps.report(tmp_path / "base", tmp_path / "eps", budget=30_000, target_ticks=30_000)
    assert "base 40.0%, eps 53.3% (+13.3 points)" in text
    assert "Floor (EPS at most 3 points below at equal total ticks): met." in text


def test_the_paired_difference_is_per_seed_and_can_show_eps_behind(compare_eps) -> None:
    """The differences are taken seed by seed: the spread of the pairs, not of the runs, sets the standard error."""
    pairs = compare_eps.paired_difference([0.80, 0.90, 0.70], [0.78, 0.86, 0.72])
    assert pairs["mean"] == pytest.approx((-0.02 - 0.04 + 0.02) / 3)
    assert pairs["std"] == pytest.approx(0.0305505, rel=1e-4)  # sample std of (-0.02, -0.04, +0.02)
    assert pairs["sem"] == pytest.approx(0.0305505 / 3**0.5, rel=1e-4)
    assert (pairs["n"], pairs["ahead"]) == (3, 1)
    single = compare_eps.paired_difference([0.5], [0.4])
    assert single["mean"] == pytest.approx(-0.1) and single["ahead"] == 0
    assert single["std"] != single["std"]  # NaN: one pair has no spread
    with pytest.raises(ValueError, match="no pairs"):
        compare_eps.paired_difference([], [])
