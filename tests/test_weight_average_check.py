"""``benchmarks/weight_average_check.py``: the averages only read the weights, and each is evaluated as itself."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
RUN = ["--algo", "gdq", "--env", "CooperativeNavigation-v0", "--ticks", "1200", "--seeds", "0", "--eval-every", "400",
       "--eval-episodes", "2", "--hyperparams",
       '{"learning_starts": 200, "batch_size": 16, "policy_kwargs": {"weight_average_tau": null}}']  # fmt: skip
NAME = "gdq_CooperativeNavigation-v0_seed0.jsonl"


def _run(script: str, out: pathlib.Path, *extra: str) -> None:
    subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), *extra, *RUN, "--out", str(out)],
        check=True,
        cwd=ROOT,
        capture_output=True,
    )


def _records(path: pathlib.Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _strip(records: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("wall_s", "n_updates", "weight_average_tau")} for r in records]


def test_the_run_is_learning_checks_and_each_average_is_evaluated_as_itself(tmp_path) -> None:
    _run("learning_check.py", tmp_path / "plain")
    _run("weight_average_check.py", tmp_path / "averaged", "--average-taus", "1.0", "0.01", "--average-from", "800")
    plain, averaged = _records(tmp_path / "plain" / NAME), _records(tmp_path / "averaged" / NAME)
    assert _strip(averaged) == _strip(plain)  # training and the model's evaluations are unchanged
    latest = _records(tmp_path / "averaged" / "ema1" / NAME)  # tau 1: the online weights themselves
    assert [r["ticks"] for r in latest] == [800, 1200]
    assert _strip(latest) == _strip([r for r in plain if r["ticks"] >= 800])
    slow = _records(tmp_path / "averaged" / "ema0.01" / NAME)
    assert [r["ticks"] for r in slow] == [800, 1200] and all(r["n_updates"] > 0 for r in slow)
    assert all(r["weight_average_tau"] == 0.01 for r in slow)


def test_a_model_that_keeps_its_own_average_is_refused_before_training(tmp_path) -> None:
    """GDQ's defaults keep a weight average: its evaluations would not be the online network's, so the script stops."""
    run = [a if "learning_starts" not in a else '{"learning_starts": 200, "batch_size": 16}' for a in RUN]
    result = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "weight_average_check.py"), *run, "--out", str(tmp_path / "out")],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0
    assert "keeps its own weight average" in result.stderr and "weight_average_tau" in result.stderr
    assert not list((tmp_path / "out").rglob("*.jsonl"))  # nothing recorded
