"""Every evaluation record names its world: env id, world options, level set, episodes (``world_record``)."""

from __future__ import annotations

import numpy as np

from envs.debug import CorridorEnv
from sb3_eps import MultiAgentVecEnv, evaluate_team, make_vec_env
from sb3_eps.common.evaluation import WORLD_KEYS, world_of, world_record
from sb3_eps.zoo.run_folder import read_evaluation_world

ENV_ID = "Corridor-2-v0"


class StepRight:
    """Every agent takes action 1, whatever it sees."""

    def predict(self, observations, deterministic=True):
        return np.ones(len(observations), dtype=np.int64), None


def test_world_record_names_the_world() -> None:
    assert world_record(ENV_ID, None, 5) == {"env_id": ENV_ID, "env_kwargs": {}, "level_set": None, "n_episodes": 5}
    options = {"length": 3, "level_set": "validation"}
    record = world_record(ENV_ID, options, 2)
    assert record["env_kwargs"] == options and record["env_kwargs"] is not options
    assert record["level_set"] == "validation"  # a world's level_set option names its set
    assert world_record(ENV_ID, {}, 2, level_set="test")["level_set"] == "test"
    assert tuple(record) == WORLD_KEYS


def test_evaluate_team_records_the_world_of_an_id_or_of_make_vec_env() -> None:
    options = {"length": 3, "max_cycles": 5}
    summary = evaluate_team(StepRight(), ENV_ID, n_eval_episodes=3, n_envs=2, env_kwargs=options)
    assert world_of(summary) == {"env_id": ENV_ID, "env_kwargs": options, "level_set": None, "n_episodes": 3}
    assert len(summary["episodes"]) == 3
    venv = make_vec_env(ENV_ID, n_envs=1, seed=0)
    try:
        assert (venv.env_kwargs, venv.level_set) == ({}, None)
        summary = evaluate_team(StepRight(), venv, n_eval_episodes=2)
        assert world_of(summary) == world_record(ENV_ID, {}, 2)
    finally:
        venv.close()


def test_a_vec_env_of_unknown_world_adds_no_world_keys() -> None:
    """A vec env built by hand does not know its world options: its summary claims no world."""
    venv = MultiAgentVecEnv([lambda: CorridorEnv(n_agents=2, length=3, max_cycles=5)], env_id=ENV_ID)
    try:
        summary = evaluate_team(StepRight(), venv, n_eval_episodes=1)
    finally:
        venv.close()
    assert world_of(summary) == {"n_episodes": 1} and "env_id" not in summary


def test_evaluations_written_before_the_world_was_kept_still_read(tmp_path) -> None:
    np.savez(tmp_path / "evaluations.npz", timesteps=np.array([10]), results=np.zeros((1, 2)))
    assert read_evaluation_world(tmp_path) is None
