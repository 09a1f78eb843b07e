"""``benchmarks/seed_spread.py``: the pooled seed figures of issue 9's results page are read from it."""

from __future__ import annotations

import importlib.util
import json
import math
import pathlib
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def seed_spread():
    spec = importlib.util.spec_from_file_location("seed_spread", ROOT / "benchmarks" / "seed_spread.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["seed_spread"] = module  # a dataclass looks its module up there
    spec.loader.exec_module(module)
    return module


def write_seed(folder: pathlib.Path, seed: int, points: list[tuple[int, float]]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    lines = [json.dumps({"ticks": ticks, "success_rate": success}) for ticks, success in points]
    (folder / f"gdq_MultiRobotNav-4-v0_seed{seed}.jsonl").write_text("\n".join(lines) + "\n")


def test_a_label_pools_its_folders_and_reads_the_evaluation_at_the_tick(seed_spread, tmp_path) -> None:
    for seed, final in [(0, 0.92), (1, 0.84)]:
        write_seed(tmp_path / "report", seed, [(140_000, 0.5), (150_000, final), (160_000, 0.1)])
    for seed, final in [(146, 0.88), (147, 0.80)]:
        write_seed(tmp_path / "heldout", seed, [(140_000, 0.5), (150_000, final)])
    spreads = seed_spread.collect([f"GDQ={tmp_path}/report/*.jsonl", f"GDQ={tmp_path}/heldout/*.jsonl"], at=150_000)
    assert len(spreads) == 1
    (spread,) = spreads
    assert spread.values == pytest.approx({0: 92.0, 1: 84.0, 146: 88.0, 147: 80.0})
    assert spread.mean == pytest.approx(86.0)
    assert spread.at_least(88) == 2
    text = seed_spread.report(spreads, 150_000, threshold=90, report_seeds=[0, 1], draws=5)
    assert "mean 86.0 %" in text
    assert "1 of 4 seeds at >= 90 %" in text
    assert "report seeds 88.0 % (2), other seeds 84.0 % (2)" in text


def test_the_chance_falls_as_the_target_rises_above_the_mean(seed_spread) -> None:
    spread = seed_spread.Spread("x", {0: 85.0, 1: 90.0, 2: 80.0, 3: 95.0, 4: 87.5})  # mean 87.5
    assert spread.chance_mean_reaches(87.5, draws=5) == pytest.approx(0.5)
    low, high = spread.chance_mean_reaches(90, draws=5), spread.chance_mean_reaches(85, draws=5)
    assert low < 0.5 < high
    assert low == pytest.approx(1 - high)  # symmetric about the mean
    z = 2.5 / (spread.sd / math.sqrt(5))
    assert low == pytest.approx(0.5 * math.erfc(z / math.sqrt(2)))
    assert spread.chance_mean_reaches(90, draws=50) < low  # more seeds: a mean below the target rarely reaches it
    one = spread.chance_mean_reaches(85, draws=1)
    assert spread.chance_every_reaches(85, draws=5) == pytest.approx(one**5)
    assert spread.chance_every_reaches(85, draws=5) < high  # every seed above 85 is harder than the mean above 85


def test_a_seed_twice_or_a_missing_tick_is_an_error(seed_spread, tmp_path) -> None:
    write_seed(tmp_path / "a", 3, [(150_000, 0.9)])
    write_seed(tmp_path / "b", 3, [(150_000, 0.7)])
    with pytest.raises(SystemExit, match="seed 3 appears twice"):
        seed_spread.collect([f"G={tmp_path}/a/*.jsonl", f"G={tmp_path}/b/*.jsonl"], at=150_000)
    with pytest.raises(SystemExit, match="no evaluation at 100000"):
        seed_spread.collect([f"G={tmp_path}/a/*.jsonl"], at=100_000)
    with pytest.raises(SystemExit, match="LABEL=GLOB"):
        seed_spread.collect([f"{tmp_path}/a/*.jsonl"], at=150_000)
