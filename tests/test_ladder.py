"""One model trained over a ladder of worlds: from Python, from a config entry / ``--ladder``, resumed after SIGTERM."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

import envs  # noqa: F401
from sb3_eps import GDQ, QMIX, evaluate_team, learn_ladder, make_vec_env, train
from sb3_eps.zoo.checkpoint import load_checkpoint, verify_checkpoint
from sb3_eps.zoo.config import config_file, resolve_config
from sb3_eps.zoo.errors import run_command
from tests.test_zoo_resume import assert_equal_runs, stop_at_checkpoint

SMALL = {"learning_starts": 50, "batch_size": 8, "buffer_size": 500}
POOLED = {"net_arch": [16], "global_head": "pooled"}


class Progress(BaseCallback):
    """Records ``(ticks, agents, progress remaining)`` at every step."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[tuple[int, int, float]] = []

    def _on_step(self) -> bool:
        self.rows.append((self.model.ticks, self.model.n_agents, self.model._current_progress_remaining))
        return True


# ---------------------------------------------------------------------------------------------- Python
def test_a_ladder_counts_every_rungs_ticks_and_runs_the_schedules_once() -> None:
    two, four = (make_vec_env(f"MultiRobotNav-{n}-v0", n_envs=2, seed=n) for n in (2, 4))
    model = GDQ("MlpPolicy", two, seed=0, policy_kwargs=POOLED, **SMALL)
    progress = Progress()
    learn_ladder(model, [(two, 200), (four, 100)], callback=progress)
    # 200 ticks x 2 robots, then 100 ticks x 4: world ticks on the x axis, agent-steps beside them.
    assert (model.ticks, model.num_timesteps, model.n_agents) == (300, 200 * 2 + 100 * 4, 4)
    assert [row[1] for row in progress.rows] == [2] * 100 + [4] * 50  # 2 worlds: 2 ticks per step
    # The schedules run once over the ladder's 800 agent-steps (read before each step of 4, then 8 agent-steps):
    # they do not end with rung 1 and start again on rung 2.
    remaining = [row[2] for row in progress.rows]
    expected = [1 - 4 * step / 800 for step in range(100)] + [1 - (400 + 8 * step) / 800 for step in range(50)]
    assert remaining == pytest.approx(expected)
    assert model.replay_buffer.n_agents == 4 and model.replay_buffer.size() > 0


def test_a_ladder_continues_a_model_part_way_up_from_its_ticks() -> None:
    two, four = (make_vec_env(f"MultiRobotNav-{n}-v0", n_envs=2, seed=n) for n in (2, 4))
    model = GDQ("MlpPolicy", two, seed=0, policy_kwargs=POOLED, **SMALL)
    model.learn(2 * 120)  # 120 of rung 1's 200 ticks
    learn_ladder(model, [(two, 200), (four, 100)], reset_num_timesteps=False)
    assert (model.ticks, model.num_timesteps) == (300, 200 * 2 + 100 * 4)


@pytest.mark.parametrize(
    ("algorithm", "rung", "words"),
    [
        (GDQ, ("MultiRobotNav-4-v0", 100), ["rung 1", "vector env", "make_vec_env"]),
        (GDQ, (None, 0), ["rung 1", "ticks must be an int >= 1"]),
        (GDQ, (None, 100), ["rung 1", "4 agents per world", "global_head='pooled'"]),
        (QMIX, (None, 100), ["rung 1", "4 agents per world", "--init-from"]),
        (GDQ, ("single", 100), ["rung 1", "observation_space"]),
    ],
    ids=["env-id", "no-ticks", "gdq-mlp-head", "qmix", "other-spaces"],
)
def test_a_ladder_refuses_a_rung_in_one_line_before_training(algorithm, rung, words) -> None:
    two = make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=0)
    env, ticks = rung
    if env is None:
        env = make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=1)
    elif env == "single":
        env = make_vec_env("CooperativeNavigation-v0", n_envs=1, seed=1)
    model = algorithm("MlpPolicy", two, seed=0, policy_kwargs={"net_arch": [16]}, **SMALL)
    with pytest.raises(ValueError) as error:
        learn_ladder(model, [(two, 100), (env, ticks)])
    assert "\n" not in str(error.value) and all(word in str(error.value) for word in words), str(error.value)
    assert model.num_timesteps == 0


# ---------------------------------------------------------------------------------------------- config and CLI
LADDER_YAML = """\
MultiRobotNav-4-v0:
  n_envs: 1
  policy_kwargs: "dict(net_arch=[16])"
  learning_starts: 50
  batch_size: 8
  ladder:
"""
GOOD_RUNGS = "    - {env: MultiRobotNav-2-v0, ticks: 60}\n    - {env: MultiRobotNav-4-v0, ticks: 40}\n"

# (case id, ladder lines of -conf, extra flags, words the error line must contain)
ERROR_CASES = [
    ("unknown-env", GOOD_RUNGS.replace("-2-v0", "-3-v0"), [], ["ladder: rung 0", "MultiRobotNav-3-v0", "allowed"]),
    ("zero-ticks", GOOD_RUNGS.replace("60", "0"), [], ["ladder: rung 0", "ticks must be an int >= 1"]),
    ("text-ticks", GOOD_RUNGS.replace("60", "many"), [], ["rung 0", "ticks", "'many'"]),
    ("extra-key", GOOD_RUNGS.replace("ticks: 40", "ticks: 40, seed: 3"), [], ["rung 1", "exactly the keys"]),
    ("not-a-list", "    MultiRobotNav-2-v0\n", [], ["ladder", "a list of rungs"]),
    ("last-rung", GOOD_RUNGS.replace("-4-v0, ticks: 40", "-8-v0, ticks: 40"), [], ["last rung", "--env MultiRobotNav-8-v0"]),
    ("with-n", GOOD_RUNGS, ["-n", "500"], ["-n", "rungs' ticks"]),
    ("mlp-head", GOOD_RUNGS, [], ["rung 1", "4 agents per world", "global_head='pooled'"]),
    ("qmix", GOOD_RUNGS, ["--algo", "qmix"], ["rung 1", "QMIX", "--init-from"]),
    ("eps", GOOD_RUNGS + "  callback: sb3_eps.EvolutionCallback\n", ["--algo", "eps_gdq"], ["EPS", "with gdq"]),
    ("tuning", GOOD_RUNGS, ["-optimize"], ["-optimize", "ladder"]),
    ("flag-format", None, ["--ladder", "MultiRobotNav-4-v0"], ["--ladder", "ENV:TICKS"]),
    ("flag-ticks", None, ["--ladder", "MultiRobotNav-2-v0:-5", "MultiRobotNav-4-v0:10"], ["rung 0", ">= 1"]),
]  # fmt: skip


@pytest.mark.parametrize(("case", "rungs", "flags", "words"), ERROR_CASES, ids=[case[0] for case in ERROR_CASES])
def test_a_bad_ladder_gives_one_line_and_no_run_folder(case, rungs, flags, words, tmp_path, capsys) -> None:
    argv = ["--env", "MultiRobotNav-4-v0", "-f", str(tmp_path / "logs"), "--seed", "0", *flags]
    if "--algo" not in flags:
        argv = ["--algo", "gdq", *argv]
    if rungs is not None:
        (tmp_path / "ladder.yml").write_text(LADDER_YAML + rungs)
        argv += ["-conf", str(tmp_path / "ladder.yml")]
    with pytest.raises(SystemExit) as exit_info:
        run_command(train.PROG, lambda: train.main(argv))
    lines = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(lines) == 1, lines
    assert all(word in lines[0] for word in words), lines[0]
    assert not (tmp_path / "logs").exists() or not list((tmp_path / "logs").rglob("*.*"))


def test_the_example_ladder_in_the_gdq_config_reads_as_a_ladder(tmp_path) -> None:
    """The shipped file shows the ``ladder`` key commented out (its entries are keyed by world, and the 8-robot
    entry is the plain run): uncommented, it is a valid entry."""
    text = config_file("gdq").read_text()
    block = re.search(r"^# (MultiRobotNav-8-v0:\n(?:#   .*\n)+)", text, flags=re.MULTILINE)
    assert block is not None, "the ladder example is missing from zoo_configs/gdq.yml"
    (tmp_path / "example.yml").write_text(block.group(1).replace("#   ", "  "))
    entry = resolve_config("gdq", "MultiRobotNav-8-v0", tmp_path / "example.yml").entry
    assert [rung["env"] for rung in entry["ladder"]] == ["MultiRobotNav-4-v0", "MultiRobotNav-8-v0"]
    assert entry["tuned"] is False and entry["policy_kwargs"]["global_head"] == "pooled"


# ---------------------------------------------------------------------------------------------- resume
ENV_ID = "MultiRobotNav-4-v0"
# 300 ticks on 2 robots, then 600 on 4; checkpoints every 200 agent-steps, evaluations on the 4-robot world.
ARGV = [
    "--algo", "gdq", "--ladder", "MultiRobotNav-2-v0:300", f"{ENV_ID}:600", "--seed", "5", "--verbose", "0",
    "--eval-freq", "700", "--eval-episodes", "2", "--n-eval-envs", "1", "--save-freq", "200", "--keep-checkpoint",
    "--hyperparams", "policy_kwargs:dict(net_arch=[16], global_head='pooled')", "learning_starts:100",
    "batch_size:16", "buffer_size:2000", "train_freq:3", "n_envs:2", "prioritized_replay:True",
]  # fmt: skip


def the_run(folder: Path) -> Path:
    (path,) = (folder / "gdq").iterdir()
    return path


def assert_equal_buffers(run: Path, expected: Path) -> None:
    """The replay buffers that the runs' final checkpoints kept are equal."""
    trainings = [load_checkpoint(path / "checkpoint.zip").training for path in (run, expected)]
    for training in trainings:  # unpickling a checkpoint starts its worlds' workers again
        training["env"].close()
    buffers = [training["replay_buffer"] for training in trainings]
    assert buffers[0].size() == buffers[1].size() > 0
    for name in ("observations", "actions", "team_rewards", "next_observations"):
        np.testing.assert_array_equal(getattr(buffers[0], name), getattr(buffers[1], name), err_msg=name)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("uninterrupted")
    assert train.main([*ARGV, "-f", str(folder)]) == 0
    return the_run(folder)


def test_a_ladder_stopped_by_sigterm_in_rung_two_resumes_to_the_uninterrupted_run(uninterrupted, tmp_path) -> None:
    folder = tmp_path / "interrupted"
    process = subprocess.Popen([sys.executable, "-m", "sb3_eps.train", *ARGV, "-f", str(folder)])
    # a periodic checkpoint inside rung 2 (not at its start): the 4-robot world trains
    inside_rung_two = lambda meta: meta.get("rung") == 1 and meta["rung_ticks"] > 0  # noqa: E731
    stop_at_checkpoint(process, folder, inside_rung_two, 180, "rung 2 could be stopped")
    run = the_run(folder)
    meta = verify_checkpoint(run / "checkpoint.zip")
    assert meta["rung"] == 1 and 0 < meta["rung_ticks"] < 600 and meta["ticks"] == 300 + meta["rung_ticks"]
    assert not (run / f"{ENV_ID}.zip").exists()

    assert train.main(["--resume", str(run), "--verbose", "0"]) == 0
    assert_equal_runs(run, uninterrupted, ENV_ID)  # weights, episodes, logged rows, evaluations
    assert_equal_buffers(run, uninterrupted)
    with np.load(run / "evaluations.npz") as evaluations:
        assert evaluations["ticks"][-1] == 900 and evaluations["timesteps"][-1] == 300 * 2 + 600 * 4


# ---------------------------------------------------------------------------------------------- learning
RUNG_TICKS = (20_000, 5_000)  # 2 robots, then 4
EPISODES = 40
# Greedy team success on the 4-robot world, 40 episodes, GDQ's package defaults with the pooled head, 4 worlds per
# rung, measured on seeds 220-224 before this test was written (2026-12-03, 2-core VM):
# the ladder 50 / 40 / 40 / 32.5 / 15 % (seeds 220-224; this test runs seed 220); untrained, 0 % on every seed;
# the 4-robot rung alone from scratch (the same 5k ticks, a reset policy), 0 % on every seed (2.5 % with 10k ticks on
# seed 220). The threshold sits between: 5 points (2 episodes) under the weakest seed, 10 points (4 episodes) over
# the controls; 40 points under this test's seed.
# This test: 74 s of wall time (54 s of CPU) on the 2-core VM under a load of about 4; 46 s in a quieter full run.
MIN_SUCCESS = 0.1


def test_a_two_then_four_robot_ladder_learns_what_the_four_robot_rung_alone_does_not() -> None:
    th.set_num_threads(1)
    seed = 220
    two = make_vec_env("MultiRobotNav-2-v0", n_envs=4, seed=seed)
    four = make_vec_env("MultiRobotNav-4-v0", n_envs=4, seed=seed + 1)
    model = GDQ("MlpPolicy", two, seed=seed, policy_kwargs={"global_head": "pooled"})
    learn_ladder(model, [(two, RUNG_TICKS[0]), (four, RUNG_TICKS[1])])
    summary = evaluate_team(model, "MultiRobotNav-4-v0", EPISODES, n_envs=4, seed=10_000 + seed)
    assert model.ticks >= sum(RUNG_TICKS) and model.n_agents == 4
    assert summary["success_rate"] >= MIN_SUCCESS, summary
