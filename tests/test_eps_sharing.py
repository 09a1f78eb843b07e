"""EPS experience sharing (``research.eps_variants.ResearchEvolutionCallback(share_experience=True)``, research
outside the package): the team-world episodes of a round become the
rows a training world would write for the same ticks, in real PyBullet worlds."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch as th
from stable_baselines3.common.logger import configure

import envs
from research.eps_variants import ResearchEvolutionCallback, StateRecordingBlock, TeamEpisode, _EpisodeRecorder, share_episodes
from sb3_eps import make_vec_env
from sb3_eps.common.buffers import NStepJointCollector
from sb3_eps.common.parallel_wrappers import TeamAsGymnasium
from sb3_eps.eps import InProcessEnvPool, SubprocessEnvPool, evaluate_population
from sb3_eps.eps.mutations import mutate_population, network_parameters
from sb3_eps.eps.round_log import read_round_log
from sb3_eps.gdq import GDQ
from sb3_eps.iql import IQL
from sb3_eps.qmix import QMIX, VDN
from tests.test_eps import tiny_model

TEAM = "MultiRobotNav-2-v0"
SHORT = {"max_episode_steps": 30}
# With the heading controller below and a 150-tick limit, seeds 2, 3 and 5 of the 2-robot arena end with a collision
# (terminated), both robots arrived (one parked 9 ticks before the other: success) and one robot parked while the
# other is cut by the time limit (a dead slot terminated beside a truncated one).
SCRIPTED = {"max_episode_steps": 150}
SCRIPTED_SEEDS = (2, 3, 5)
ROW_FIELDS = (
    "observations", "next_observations", "actions", "rewards", "dones", "discounts", "alive", "next_alive",
    "team_rewards", "team_dones", "team_discounts", "states", "next_states",
)  # fmt: skip


def heading_controller(obs: np.ndarray) -> np.ndarray:
    """Turn on the spot toward the target (observation [29]: its bearing / pi), then drive at full speed."""
    bearing = obs[:, -1]
    forward = np.where(np.abs(bearing) < 0.02, 17, np.where(bearing > 0, 18, 16))
    return np.where(np.abs(bearing) > 0.06, np.where(bearing > 0, 4, 0), forward)


def scripted_episode(seed: int, record_states: bool) -> TeamEpisode:
    env = TeamAsGymnasium(envs.make_parallel_env(TEAM, **SCRIPTED))
    obs, _ = env.reset(seed=seed)
    recorder = _EpisodeRecorder(env, obs, record_states)
    done = False
    while not done:
        action = heading_controller(obs)
        obs, _, terminated, truncated, _ = env.step(action)
        recorder.add(action, obs)
        done = terminated or truncated
    env.close()
    return recorder.episode()


def training_rows(model, env_kwargs: dict, seed: int, actions: np.ndarray) -> dict[str, np.ndarray]:
    """The rows the training rollout writes when ``actions`` are played in a fresh training world reset with ``seed``
    (the rollout's own ``_store_joint_transition`` and collector, into an empty buffer)."""
    buffer = model._make_replay_buffer()
    venv = make_vec_env(TEAM, n_envs=1, seed=seed, env_kwargs=env_kwargs)
    model.set_env(venv)
    model._last_obs = venv.reset()
    model._collector = NStepJointCollector(buffer, 1, model.n_steps, model.gamma, model.team_reward_mode)
    model._last_state = model._global_state()
    for tick_actions in actions:
        venv.step_async(tick_actions)
        obs, rewards, dones, infos = venv.step_wait()
        model._store_joint_transition(tick_actions, obs, rewards, dones, infos)
    assert dones.all(), "the episode must end where the EPS episode ended"
    venv.close()
    return rows_of(buffer)


def shared_rows(model, episodes: list[TeamEpisode | None]) -> tuple[int, dict[str, np.ndarray]]:
    model.replay_buffer = model._make_replay_buffer()
    n_rows = share_episodes(model, episodes)
    return n_rows, rows_of(model.replay_buffer)


def rows_of(buffer) -> dict[str, np.ndarray]:
    return {name: getattr(buffer, name)[: buffer.size()].copy() for name in ROW_FIELDS}


def assert_same_rows(shared: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> None:
    assert shared.keys() == reference.keys()
    for name in shared:
        np.testing.assert_array_equal(shared[name], reference[name], err_msg=name)


def team_model(algorithm, **kwargs):
    return tiny_model(algorithm, env_id=TEAM, n_envs=1, train_freq=4, **kwargs)


def test_shared_rows_equal_the_training_rows_of_the_same_ticks() -> None:
    """(a) Scripted episodes (collision, success with a parked robot, a time limit beside a parked robot) and greedy
    episodes of a population, in process and in a worker: each episode's rows equal those the training collector
    writes when the same actions are played in the same world from the same seed (QMIX: global states; 3-step
    windows; mean team reward)."""
    model = team_model(QMIX, n_steps=3, team_reward_mode="mean")
    for seed in SCRIPTED_SEEDS:
        episode = scripted_episode(seed, record_states=True)
        n_rows, rows = shared_rows(model, [episode])
        reference = training_rows(model, SCRIPTED, seed, episode.actions)
        assert n_rows == len(episode.actions) == len(reference["actions"])
        assert_same_rows(rows, reference)
    ends = [scripted_episode(seed, record_states=False) for seed in SCRIPTED_SEEDS]
    assert [bool((~episode.alive).any()) for episode in ends] == [False, True, True]  # parked robots
    assert ends[2].truncations[-1].any() and ends[0].terminations[-1].all()

    network = model.policy.q_net
    population = mutate_population(network_parameters(network), 1, 0.05, th.Generator().manual_seed(0), None)
    seeds = [7, 8]
    recorded = []
    for pool in (
        InProcessEnvPool(TEAM, SHORT, 2, 2, network, block_class=StateRecordingBlock),
        SubprocessEnvPool(TEAM, SHORT, 2, 2, network, n_workers=2, block_class=StateRecordingBlock),
    ):
        try:
            recorded.append(evaluate_population(pool, population, seeds, timeout=60).episodes)
        finally:
            pool.close()
    for in_process, in_worker in zip(*recorded, strict=True):
        for name in TeamEpisode.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(in_process, name), getattr(in_worker, name), err_msg=name)
    for index, episode in enumerate(recorded[0]):
        _, rows = shared_rows(model, [episode])
        assert_same_rows(rows, training_rows(model, SHORT, seeds[index % 2], episode.actions))


def sharing_callback(**kwargs) -> ResearchEvolutionCallback:
    defaults = {
        "eval_env_id": TEAM, "eval_env_kwargs": SHORT, "population_size": 2, "period": 40, "n_eval_episodes": 1,
        "max_eps_share": None, "fitness": "return", "min_gain": 0.0, "n_reevaluation_episodes": 2, "alpha": 0.0, "n_workers": 1,
        "seed": 0, "share_experience": True,
    }  # fmt: skip
    defaults.update(kwargs)
    return ResearchEvolutionCallback(**defaults)


@pytest.mark.parametrize(
    ("algorithm", "kwargs"),
    [(GDQ, {}), (IQL, {}), (QMIX, {}), (VDN, {})],
    ids=["gdq", "iql", "qmix", "vdn"],
)
def test_a_round_adds_its_ticks_as_rows_and_survives_a_state_dict_round_trip(tmp_path, algorithm, kwargs) -> None:
    """(b) With one-step rows and no gradient step, the buffer holds one row per training tick plus one per EPS tick
    (selection and reevaluation episodes, played in a worker), and the round records and logs them; (e) the count
    survives ``state_dict``."""
    model = team_model(algorithm, n_steps=1, learning_starts=10**6, **kwargs)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    callback = sharing_callback()
    model.learn(2 * 100, callback=callback)
    rounds = [record for record in callback.history if not record["skipped"]]
    assert len(rounds) >= 2 and any("reevaluation" in record for record in rounds)  # a mutant won a round
    assert [record["shared_rows"] for record in rounds] == [record["ticks_spent"] for record in rounds]
    assert callback.shared_rows == callback.eps_ticks > 0
    assert model.replay_buffer.size() == model.ticks + callback.shared_rows
    assert [record["shared_rows"] for record in read_round_log(tmp_path / "eps_rounds.jsonl")] == [
        record["shared_rows"] for record in callback.history
    ]
    model.logger.dump(model.num_timesteps)  # no world episode ended: nothing was written yet
    logged = pd.read_csv(tmp_path / "progress.csv")["eps/shared_rows_total"].dropna()
    assert logged.iloc[-1] == callback.shared_rows

    state = callback.state_dict()
    restored = sharing_callback(n_workers=0)
    restored.init_callback(model)
    restored.load_state_dict(state)
    assert restored.state_dict()["shared_rows"] == callback.shared_rows
    assert restored.history == callback.history and restored.eps_ticks == callback.eps_ticks
    restored._on_training_end()


def test_sharing_needs_a_team_world_of_the_training_agents() -> None:
    """(c) A single-robot world, a team of another size: one clear error before training, saying what to change."""
    model = team_model(GDQ)
    with pytest.raises(ValueError, match=r"needs a team world as eval_env_id.*share_experience=False"):
        model.learn(8, callback=ResearchEvolutionCallback(eval_env_id="SingleRobotNav-v0", share_experience=True))
    with pytest.raises(ValueError, match="training worlds' 2 agents; the evaluation world has 4"):
        model.learn(8, callback=ResearchEvolutionCallback(eval_env_id="MultiRobotNav-4-v0", share_experience=True))
    with pytest.raises(ValueError, match="share_experience must be True or False"):
        ResearchEvolutionCallback(eval_env_id=TEAM, share_experience="yes")


def test_the_research_config_builds_its_python_equivalent() -> None:
    """``research/zoo_configs/eps_gdq_team_share.yml`` (with ``--gym-packages research.eps_variants``) builds the
    callback of its header."""
    from pathlib import Path

    from sb3_eps.zoo.config import resolve_config
    from sb3_eps.zoo.schema import build_callbacks

    conf = Path(__file__).resolve().parents[1] / "research" / "zoo_configs" / "eps_gdq_team_share.yml"
    config = resolve_config("eps_gdq", "MultiRobotNav-4-v0", conf)
    ((name, callback),) = build_callbacks(config.entry, "MultiRobotNav-4-v0", 0, config.source)
    assert name == "research.eps_variants.ResearchEvolutionCallback"
    expected = ResearchEvolutionCallback(eval_env_id="MultiRobotNav-4-v0", share_experience=True)
    assert callback.settings == expected.settings
