"""Corridor: a tiny cooperative PettingZoo env with a known optimum, for sanity checks of the algorithms.

Agents walk on a corridor of ``length`` cells: even agents towards its right end, odd agents towards its left
end (so a learner that mixed up whose observation goes with whose action could not solve it). Agent ``i`` starts
``i % (length - 1)`` cells from the end opposite its goal. Actions: 0 = left, 1 = stay, 2 = right. Reward: -0.01
per tick, +1 on reaching the goal end (the agent then parks and leaves ``env.agents``, as a robot that arrived).
The episode terminates when every agent arrived and is truncated after ``max_cycles`` ticks. Observation: the
one-hot cell plus 1 if the goal is the right end, else 0. The optimal team return is
``sum_i (1 - 0.01 * (d_i - 1))`` with ``d_i`` the distance of agent ``i`` to its goal.

Version history: v0 first version.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

STEP_COST = 0.01


class CorridorEnv(ParallelEnv):
    """The corridor world.

    :param n_agents: number of agents
    :param length: number of cells (>= 2)
    :param max_cycles: time limit in ticks
    """

    metadata = {"name": "corridor_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, n_agents: int = 2, length: int = 4, max_cycles: int = 10) -> None:
        if n_agents < 1 or length < 2 or max_cycles < 1:
            raise ValueError("CorridorEnv needs n_agents >= 1, length >= 2 and max_cycles >= 1")
        self.length = length
        self.max_cycles = max_cycles
        self.possible_agents = [f"agent_{i}" for i in range(n_agents)]
        self.agents: list[str] = []
        self.render_mode = None
        self._goes_right = np.array([i % 2 == 0 for i in range(n_agents)])
        offsets = np.array([i % (length - 1) for i in range(n_agents)])
        self._starts = np.where(self._goes_right, offsets, length - 1 - offsets)
        self._goals = np.where(self._goes_right, length - 1, 0)
        self._positions = self._starts.copy()
        self._ticks = 0
        self._team_return = 0.0
        self.state_space = spaces.Box(0.0, 1.0, (n_agents,), dtype=np.float32)
        # One cached space object shared by all agents (PettingZoo contract).
        self._observation_space = spaces.Box(0.0, 1.0, (length + 1,), dtype=np.float32)
        self._action_space = spaces.Discrete(3)

    def observation_space(self, agent: str) -> spaces.Box:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_space

    def optimal_team_return(self) -> float:
        """:return: the best achievable team return of an episode."""
        distances = np.abs(self._goals - self._starts)
        return float(sum(1.0 - STEP_COST * (distance - 1) for distance in distances))

    def _observe(self, index: int) -> np.ndarray:
        observation = np.zeros(self.length + 1, dtype=np.float32)
        observation[self._positions[index]] = 1.0
        observation[self.length] = float(self._goes_right[index])
        return observation

    def state(self) -> np.ndarray:
        return (self._positions / (self.length - 1)).astype(np.float32)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        self.agents = list(self.possible_agents)
        self._positions = self._starts.copy()
        self._ticks = 0
        self._team_return = 0.0
        observations = {agent: self._observe(i) for i, agent in enumerate(self.possible_agents)}
        return observations, {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        self._ticks += 1
        rewards, terminations, truncations, infos, observations = {}, {}, {}, {}, {}
        for agent in self.agents:
            index = self.possible_agents.index(agent)
            action = int(actions[agent])
            if action not in (0, 1, 2):
                raise ValueError(f"action {action} of {agent} is outside Discrete(3)")
            self._positions[index] = np.clip(self._positions[index] + action - 1, 0, self.length - 1)
            arrived = bool(self._positions[index] == self._goals[index])
            rewards[agent] = 1.0 if arrived else -STEP_COST
            terminations[agent] = arrived
            observations[agent] = self._observe(index)
        self._team_return += sum(rewards.values())
        remaining = [agent for agent in self.agents if not terminations[agent]]
        time_up = self._ticks >= self.max_cycles
        for agent in self.agents:
            truncations[agent] = time_up and not terminations[agent]
        team = {
            "success": not remaining,
            "collision": False,
            "n_arrived": len(self.possible_agents) - len(remaining),
            "team_return": self._team_return,
            "ticks": self._ticks,
        }
        for agent in self.agents:
            infos[agent] = {"arrived": terminations[agent], "team": dict(team)}
        self.agents = [] if time_up else remaining
        return observations, rewards, terminations, truncations, infos
