"""Worlds that hold each decision for several ticks (``action_repeat``): every tick is counted on the x axis."""

from __future__ import annotations

import numpy as np
import pytest

import envs  # noqa: F401
from sb3_eps import GDQ, EvolutionCallback, learn_ladder, make_vec_env, train
from sb3_eps.zoo.run_folder import read_monitor

SMALL = {"learning_starts": 50, "batch_size": 8, "buffer_size": 500, "policy_kwargs": {"net_arch": [16]}}


def test_ticks_count_world_ticks_when_a_decision_holds_four() -> None:
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=2, seed=1, env_kwargs={"action_repeat": 4, "max_episode_steps": 40})
    assert venv.ticks_per_step == 4
    model = GDQ("MlpPolicy", venv, seed=1, **SMALL)
    assert model.timesteps_for_ticks(800) == 200 * 2 and model.timesteps_for_ticks(801) == 201 * 2
    model.learn(model.timesteps_for_ticks(800))
    decisions = model.num_timesteps // 2  # both worlds together
    assert model.ticks == 4 * decisions and 800 <= model.ticks < 800 + 4 * 2
    assert venv.total_ticks == model.ticks
    venv.close()


def test_a_ladder_counts_the_ticks_of_a_rung_with_another_repeat() -> None:
    every_tick = make_vec_env("MultiRobotNav-2-v0", n_envs=2, seed=2)
    held = make_vec_env("MultiRobotNav-2-v0", n_envs=2, seed=3, env_kwargs={"action_repeat": 4})
    model = GDQ("MlpPolicy", every_tick, seed=2, **SMALL)
    learn_ladder(model, [(every_tick, 300), (held, 400)])
    assert 700 <= model.ticks < 700 + 4 * 2
    assert model.ticks_per_step == 4
    for venv in (every_tick, held):
        venv.close()


def test_episode_lengths_are_world_ticks() -> None:
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=4, env_kwargs={"action_repeat": 3, "max_episode_steps": 30})
    venv.reset()
    lengths = []
    while not lengths:
        _, _, _, infos = venv.step(np.full(venv.num_envs, 2))  # stand still until the time limit
        lengths += [info["episode"]["l"] for info in infos if "episode" in info]
    assert lengths == [30]
    venv.close()


def test_eps_evaluates_in_the_training_worlds_decision_rate_and_view_and_counts_world_ticks() -> None:
    kwargs = {"action_repeat": 2, "lidar_range": 1.0}
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=5, env_kwargs=kwargs)
    model = GDQ("MlpPolicy", venv, seed=5, **SMALL)
    callback = EvolutionCallback(
        period=40, n_workers=0, max_eps_share=None, population_size=1, n_eval_episodes=1,
        n_reevaluation_episodes=0, eval_env_kwargs={"scenario": "arena", "max_episode_steps": 30},
    )  # fmt: skip
    model.learn(model.timesteps_for_ticks(200), callback=callback)
    # The single-robot world took the training worlds' options; its episodes (30-tick limit) count world ticks.
    assert callback.settings.eval_env_kwargs == {"scenario": "arena", "max_episode_steps": 30, **kwargs}
    assert callback.n_rounds >= 1
    lengths = np.concatenate([np.ravel(record["episode_lengths"]) for record in callback.history])
    assert lengths.max() <= 30 and (lengths % 2 == 0).all() and lengths.max() > 15
    assert callback.eps_ticks == int(lengths.sum())
    venv.close()


@pytest.mark.parametrize(
    ("eval_env_kwargs", "message"),
    [({"action_repeat": 1}, r"action_repeat=1 but the model's worlds have action_repeat=2"),
     ({"lidar_range": 3.5}, r"lidar_range=3.5 but the model's worlds have lidar_range=1.0")],
)  # fmt: skip
def test_eps_refuses_an_evaluation_world_other_than_the_training_worlds(eval_env_kwargs, message) -> None:
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=5, env_kwargs={"action_repeat": 2, "lidar_range": 1.0})
    model = GDQ("MlpPolicy", venv, seed=5, **SMALL)
    with pytest.raises(ValueError, match=message):
        model.learn(20, callback=EvolutionCallback(period=10, n_workers=0, eval_env_kwargs=eval_env_kwargs))
    venv.close()


def test_a_command_line_run_records_world_ticks(tmp_path) -> None:
    argv = ["--algo", "gdq", "--env", "MultiRobotNav-2-v0", "-n", "400", "--seed", "0", "-f", str(tmp_path),
            "--verbose", "0", "--eval-freq", "200", "--eval-episodes", "1", "--n-eval-envs", "1",
            "--hyperparams", "learning_starts:50", "batch_size:8", "buffer_size:500", "n_envs:1",
            "--env-kwargs", "action_repeat:4", "max_episode_steps:24"]  # fmt: skip
    assert train.main(argv) == 0
    (run,) = (tmp_path / "gdq").iterdir()
    _, columns = read_monitor(run / "monitor.csv")
    # The episodes here run to the 24-tick limit: 6 decisions of 4 ticks each, counted as 24 ticks.
    assert list(columns["l"])[:3] == [24, 24, 24] and list(columns["ticks"])[:3] == [24, 48, 72]
    npz = np.load(run / "evaluations.npz")
    assert list(npz["timesteps"]) == [200, 400] and list(npz["ticks"]) == [400, 800]


def test_eps_does_not_warn_of_no_round_when_held_decisions_make_the_ticks_enough(recwarn) -> None:
    """The no-round warning counts the run's end in world ticks: 400 timesteps of 2 robots holding 4 ticks = 800."""
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=6, env_kwargs={"action_repeat": 4, "max_episode_steps": 40})
    model = GDQ("MlpPolicy", venv, seed=6, **SMALL)
    callback = EvolutionCallback(
        period=100, n_workers=0, max_eps_share=0.1, population_size=1, n_eval_episodes=1, n_reevaluation_episodes=0,
        eval_env_kwargs={"scenario": "arena", "max_episode_steps": 100},
    )  # fmt: skip
    # A round is expected to cost half of (2 individuals x 1 episode x 100 ticks) = 100 ticks <= 0.1 x 1600 ticks,
    # but more than 0.1 x 400 (the end counted in decisions).
    model.learn(800, callback=callback)
    assert not [warning for warning in recwarn if "no EPS round" in str(warning.message)]
    venv.close()
