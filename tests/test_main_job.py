"""The README's main job (``make run`` = ``examples/main_job.py``): it runs end to end on a tiny budget, says what EPS
did from the run's rounds, and draws its evaluations beside GDQ's committed 8-robot curves."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("main_job", ROOT / "examples" / "main_job.py")
assert _spec is not None and _spec.loader is not None
main_job = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(main_job)


def test_the_main_job_runs_end_to_end_on_a_tiny_budget(tmp_path, capsys) -> None:
    assert main_job.main(["-n", "800", "--eval-episodes", "2", "-f", str(tmp_path), "-tb", str(tmp_path / "tb")]) == 0
    out = capsys.readouterr().out
    (run,) = (tmp_path / "eps_gdq").iterdir()
    record = json.loads((run / "eval_MultiRobotNav-8-v0.json").read_text())
    # The final evaluation stores the world it was measured in: the entry's options.
    assert record["n_episodes"] == 2 and record["env_kwargs"] == {"action_repeat": 4, "lidar_range": 1.0}
    assert (run / "team.gif").stat().st_size > 1000 and (run / "learning_curve.png").is_file()
    assert "EPS played no round in this run." in out and "Team GIF:" in out and "success" in out


def test_what_eps_did_is_read_from_the_rounds(tmp_path) -> None:
    rounds = [
        {"round": 1, "eps_ticks": 4000, "accepted": False, "skipped": False},
        {"round": 2, "eps_ticks": 9000, "accepted": True, "skipped": False},
        {"round": None, "eps_ticks": 9000, "skipped": True},
    ]
    (tmp_path / "eps_rounds.jsonl").write_text("\n".join(json.dumps(row) for row in rounds) + "\n")
    line = main_job.eps_summary(tmp_path, 300_000)
    assert line.startswith("EPS: 2 rounds, 1 crossed over") and "9000 single-robot ticks (3.0 %" in line


def test_the_evaluations_are_drawn_beside_the_committed_gdq_curves(tmp_path) -> None:
    references = sorted(path for path in main_job.REFERENCE.iterdir() if path.is_dir())
    assert len(references) == 5  # GDQ's 8-robot entry, seeds 0-4
    picture = main_job.draw_evaluations(references[0], tmp_path / "eval.png")
    assert picture is not None and picture.stat().st_size > 10_000
    assert main_job.draw_evaluations(tmp_path, tmp_path / "none.png") is None  # no evaluations: nothing drawn
