"""The package helpers the notebooks use: committed results as tables and figures, EPS per-layer summaries,
episode animations."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch as th
from matplotlib.figure import Figure
from torch import nn

import envs  # noqa: F401
from research.eps_inspection import (
    draw_flip_curves,
    draw_layer_bars,
    draw_population,
    flip_share_curve,
    sensitivity_by_layer,
    step_by_layer,
)
from research.notebook import Animation, filmstrip, gif_bytes, show_picture
from research.results import (
    best_covered,
    draw_seed_curves,
    find_evaluation_runs,
    format_table,
    group_runs,
    read_evaluation_run,
    read_progress,
    results_table,
)
from sb3_eps.common.evaluation import record_frames
from sb3_eps.eps.evaluation import PopulationResult
from sb3_eps.eps.mutations import mutation_directions, network_parameters


def _write_records(path, points) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps({"ticks": t, "success_rate": s, "note": "x"}) + "\n" for t, s in points))


def test_evaluation_records_are_read_grouped_and_tabulated(tmp_path) -> None:
    _write_records(tmp_path / "a" / "gdq_MultiRobotNav-4-v0_seed0.jsonl", [(10, 0.2), (20, 0.6)])
    _write_records(tmp_path / "a" / "gdq_MultiRobotNav-4-v0_seed1.jsonl", [(10, 0.4), (20, 0.8)])
    _write_records(tmp_path / "b" / "eps_gdq_MultiRobotNav-4-v0_seed0.jsonl", [(12, 0.5)])
    (tmp_path / "b" / "notes_seed.jsonl").write_text("{}\n")  # not a record name: skipped
    runs = find_evaluation_runs(tmp_path)
    assert [(run.group, run.algo, run.env_id, run.seed) for run in runs] == [
        ("a", "gdq", "MultiRobotNav-4-v0", 0),
        ("a", "gdq", "MultiRobotNav-4-v0", 1),
        ("b", "eps_gdq", "MultiRobotNav-4-v0", 0),
    ]
    assert runs[0].final() == pytest.approx(0.6) and "note" not in runs[0].metrics
    rows = results_table(runs)
    assert rows[0]["seeds"] == 2 and rows[0]["mean"] == pytest.approx(0.7) and rows[0]["std"] == pytest.approx(0.1)
    assert list(best_covered(runs, "MultiRobotNav-4-v0")) == ["eps_gdq (b)", "gdq (a)"]
    assert list(group_runs(runs, ("algo",))) == ["eps_gdq", "gdq"]
    figure = draw_seed_curves(best_covered(runs, "MultiRobotNav-4-v0"))
    assert isinstance(figure, Figure)
    mean_line = [line for line in figure.axes[0].lines if line.get_linewidth() == 2.5][1]
    np.testing.assert_allclose(mean_line.get_ydata(), [30.0, 70.0])  # the mean over seeds, in %
    with pytest.raises(ValueError, match="not an evaluation record name"):
        read_evaluation_run(tmp_path / "b" / "notes_seed.jsonl")


def test_committed_records_are_readable() -> None:
    runs = find_evaluation_runs("docs/results")
    assert {"gdq", "iql"} <= {run.algo for run in runs}
    assert all(len(run.ticks) > 0 for run in runs)


def test_progress_csv_with_late_columns(tmp_path) -> None:
    path = tmp_path / "progress.csv"
    path.write_text("time/ticks,rollout/success_rate,eval/success_rate\n10,0.5,\n20,0.75,1.0\n")
    columns = read_progress(path)
    np.testing.assert_array_equal(columns["time/ticks"], [10, 20])
    assert math.isnan(columns["eval/success_rate"][0]) and columns["eval/success_rate"][1] == 1.0
    figure = draw_seed_curves({"run": [(columns["time/ticks"], columns["rollout/success_rate"])]})
    assert isinstance(figure, Figure)


def test_format_table() -> None:
    text = format_table([{"a": 1, "b": 0.123456}, {"a": 22, "b": None}])
    assert text.splitlines() == ["a   b", "--  -----", "1   0.123", "22"]
    assert format_table([]) == "(no rows)"


def test_sensitivity_and_step_tables_by_hand() -> None:
    omega = {"w": th.tensor([[0.0, 0.005], [0.02, 0.04]]), "b": th.tensor([0.5, 0.5])}
    rows = {row["layer"]: row for row in sensitivity_by_layer(omega, floor=0.01)}
    assert rows["w"]["n_weights"] == 4
    assert rows["w"]["mean"] == pytest.approx(0.01625)
    assert rows["w"]["at_floor"] == pytest.approx(0.25)  # 0.005 only: a zero counts as 1
    assert rows["b"]["at_floor"] == 0.0 and rows["b"]["max"] == 0.5
    directions = {"w": th.tensor([[[1.0, -3.0], [0.5, 0.0]]])}
    (step,) = step_by_layer(directions, scale=0.1, max_step=0.2)
    assert step["mean_abs_step"] == pytest.approx((0.1 + 0.2 + 0.05 + 0.0) / 4)
    assert step["max_abs_step"] == pytest.approx(0.2) and step["clipped"] == pytest.approx(0.25)


def test_flip_share_grows_with_the_scale_and_figures_draw() -> None:
    th.manual_seed(0)
    network = nn.Sequential(nn.Linear(4, 16), nn.ReLU(), nn.Linear(16, 5))
    theta = network_parameters(network)
    generator = th.Generator().manual_seed(0)
    directions = mutation_directions(theta, 4, generator)
    observations = th.randn(64, 4)
    shares = flip_share_curve(network, theta, directions, observations, [1e-6, 1.0, 100.0])
    assert shares[0] == 0.0 and shares[0] <= shares[1] <= shares[2] and shares[2] > 0.3
    assert isinstance(draw_flip_curves([1e-6, 1.0, 100.0], {"gaussian": shares}, target=0.1), Figure)
    tables = {"a": step_by_layer(directions, 0.1), "b": step_by_layer(directions, 0.2)}
    assert isinstance(draw_layer_bars(tables, "mean_abs_step"), Figure)
    result = PopulationResult(
        returns=np.array([[1.0, -1.0], [0.5, 0.2]]),
        lengths=np.array([[10, 5], [10, 10]]),
        valid=np.array([True, True]),
        fitness=np.array([0.0, 0.35]),
        outcomes=np.array([[1, -1], [0, 1]]),
    )
    figure = draw_population(result, flip_share=np.array([0.0, 0.1]), winner=1)
    assert len(figure.axes) >= 3


def test_animation_of_a_recorded_episode(tmp_path) -> None:
    class Still:
        def predict(self, observations, deterministic=True):
            return np.zeros(len(observations), dtype=np.int64), None

    frames, episodes = record_frames(Still(), "MultiRobotNav-2-v0", env_kwargs={"max_episode_steps": 6}, frame_every=2)
    assert len(episodes) == 1 and episodes[0]["l"] == 6
    assert len(frames) == 3 and frames[0].ndim == 3  # before ticks 1, 3 and 5
    data = gif_bytes(frames, fps=10)
    assert data[:6] == b"GIF89a"
    assert len(gif_bytes(frames, fps=10, shrink=2)) < len(data)
    animation = Animation(frames, fps=10, width=300)
    assert animation._repr_html_().startswith('<img src="data:image/gif;base64,')
    assert animation.save(tmp_path / "episode.gif").read_bytes() == data
    assert isinstance(filmstrip(frames, n_pictures=3), Figure)
    assert isinstance(show_picture(frames[0], title="world"), Figure)
    with pytest.raises(ValueError, match="at least one frame"):
        gif_bytes([])
