"""The recipe of docs/bring_your_own_world.md on a world that exists only in this file.

``LineWorld``: agents on a line of cells, each sent to a goal cell drawn every episode. A policy must read the
sign of its observation's second entry to walk the right way, so a random one mostly times out. The test trains
IQL and GDQ through ``make_vec_env(callable)``, checks the greedy team success against a random policy's, and runs
one EPS round in the one-agent variant registered with gymnasium.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo import ParallelEnv

from sb3_eps import GDQ, IQL, EvolutionCallback, evaluate_team, make_vec_env
from sb3_eps.common.parallel_wrappers import ParallelEnvAsGymnasium

STEP_COST = 0.02


class LineWorld(ParallelEnv):
    """``n_agents`` agents on ``size`` cells; actions 0 = left, 1 = stay, 2 = right; +1 and parked on arrival."""

    metadata = {"name": "line_world_v0", "render_modes": []}

    def __init__(self, n_agents: int = 2, size: int = 9, max_cycles: int = 12) -> None:
        self.possible_agents = [f"agent_{i}" for i in range(n_agents)]
        self.agents: list[str] = []
        self.size, self.max_cycles = size, max_cycles
        self.render_mode = None
        self._observation_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        self._action_space = spaces.Discrete(3)
        self._rng = np.random.default_rng()
        self._positions = np.zeros(n_agents, dtype=int)
        self._goals = np.zeros(n_agents, dtype=int)
        self._ticks, self._team_return = 0, 0.0

    def observation_space(self, agent: str) -> spaces.Box:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_space

    def _observe(self, i: int) -> np.ndarray:
        scale = self.size - 1
        return np.array([self._positions[i] / scale, (self._goals[i] - self._positions[i]) / scale], np.float32)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        n = len(self.possible_agents)
        self._positions = np.full(n, self.size // 2)
        # Goals 3 or 4 cells away, left or right: a random walk rarely gets there in time.
        self._goals = self._positions + self._rng.choice([-4, -3, 3, 4], size=n)
        self._ticks, self._team_return = 0, 0.0
        self.agents = list(self.possible_agents)
        return {a: self._observe(i) for i, a in enumerate(self.possible_agents)}, {a: {} for a in self.agents}

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        self._ticks += 1
        observations, rewards, terminations = {}, {}, {}
        for agent in self.agents:
            i = self.possible_agents.index(agent)
            self._positions[i] = np.clip(self._positions[i] + int(actions[agent]) - 1, 0, self.size - 1)
            terminations[agent] = bool(self._positions[i] == self._goals[i])
            rewards[agent] = 1.0 if terminations[agent] else -STEP_COST
            observations[agent] = self._observe(i)
        self._team_return += sum(rewards.values())
        remaining = [agent for agent in self.agents if not terminations[agent]]
        time_up = self._ticks >= self.max_cycles
        truncations = {agent: time_up and not terminations[agent] for agent in self.agents}
        team = {"success": not remaining, "team_return": self._team_return, "ticks": self._ticks}
        infos = {agent: {"team": dict(team)} for agent in self.agents}
        self.agents = [] if time_up else remaining
        return observations, rewards, terminations, truncations, infos


class RandomPolicy:
    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def predict(self, observations: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self.rng.integers(0, 3, size=len(observations)), None


SINGLE_ID = "LineWorldSingle-v0"


def make_line_world_single(**kwargs: Any) -> gymnasium.Env:
    return ParallelEnvAsGymnasium(LineWorld(n_agents=1, **kwargs))


if SINGLE_ID not in gymnasium.registry:
    gymnasium.register(SINGLE_ID, entry_point=make_line_world_single)


def _model(algorithm: type, venv: Any) -> Any:
    return algorithm(
        "MlpPolicy",
        venv,
        policy_kwargs={"net_arch": [32], "stream_arch": [32]},
        learning_starts=300,
        batch_size=32,
        learning_rate=3e-3,
        exploration_fraction=0.4,
        n_steps=3,
        gamma=0.95,
        seed=0,
    )


@pytest.mark.parametrize("algorithm", [IQL, GDQ], ids=lambda a: a.__name__)
def test_trains_on_a_world_of_this_file(algorithm: type) -> None:
    venv = make_vec_env(LineWorld, n_envs=2, seed=0, env_kwargs={"n_agents": 2})
    assert venv.env_id is None and venv.n_agents == 2 and venv.num_envs == 4
    eval_env = make_vec_env(LineWorld, n_envs=2, env_kwargs={"n_agents": 2})
    random_success = evaluate_team(RandomPolicy(0), eval_env, n_eval_episodes=40, seed=1)["success_rate"]
    model = _model(algorithm, venv)
    model.learn(6_000)
    trained = evaluate_team(model, eval_env, n_eval_episodes=40, seed=1)
    assert random_success < 0.2
    assert trained["success_rate"] >= 0.8, trained["success_rate"]


def test_one_eps_round_in_the_single_agent_variant() -> None:
    env = gymnasium.make(SINGLE_ID)
    observation, _ = env.reset(seed=0)
    assert observation.shape == (2,)
    venv = make_vec_env(LineWorld, n_envs=2, seed=0, env_kwargs={"n_agents": 3})
    model = _model(IQL, venv)
    callback = EvolutionCallback(
        eval_env_id=SINGLE_ID, population_size=3, period=200, n_eval_episodes=2, n_reevaluation_episodes=2,
        max_eps_share=None, n_workers=0, diagnostics_path="", seed=0,
    )  # fmt: skip
    model.learn(1_200, callback=callback)
    assert callback.n_rounds >= 1
    record = callback.history[0]
    assert np.asarray(record["episode_lengths"]).shape == (4, 2)
    # The one-agent variant reports arrivals, so the outcome fitness sees successes and timeouts.
    assert set(np.unique(record["outcomes"])) <= {-1, 0, 1}
    assert callback.eps_ticks > 0


def test_the_single_agent_variant_needs_one_agent() -> None:
    with pytest.raises(ValueError, match="one agent"):
        ParallelEnvAsGymnasium(LineWorld(n_agents=2))


def test_the_single_agent_variant_reports_arrivals_as_successes() -> None:
    env = make_line_world_single()
    observation, _ = env.reset(seed=3)
    terminated = truncated = False
    info: dict = {}
    while not (terminated or truncated):
        action = 2 if observation[1] > 0 else 0  # walk toward the goal
        observation, _, terminated, truncated, info = env.step(action)
    assert terminated and info["is_success"] is True
