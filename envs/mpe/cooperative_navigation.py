"""Cooperative Navigation (``CooperativeNavigation-v0``): mpe2's ``simple_spread`` with a global state and team metrics.

N agents (3 by default) must cover N landmarks without colliding (Lowe et al. 2017; the preliminary benchmark of
Marchesini & Farinelli, ICRA 2022, Table I). The world, observations (18 floats for N=3), Discrete(5) actions and
rewards are mpe2's ``simple_spread_v3.parallel_env(N, local_ratio=0.5, max_cycles=25, continuous_actions=False)``,
unchanged; this wrapper adds:

- one shared observation space and one shared action space object for all agents (parameter sharing);
- ``state()`` / ``state_space`` (mpe2's: the concatenated observations of all agents, 18 N floats);
- ``infos[agent]["team"]``, the same dict for every agent, with running team metrics (see ``docs/envs_mpe.md``);
- actions outside the action space raise ``ValueError`` (mpe2 asserts).

The episode always ends by truncation after ``max_cycles`` ticks (mpe2 never terminates simple_spread by default).

Version history:

- v0: first version (mpe2 1.1 ``simple_spread_v3``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from mpe2 import simple_spread_v3
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from envs.mpe._common import (
    RENDER_MODES,
    CollisionCounter,
    is_valid_action,
    landmark_coverage,
    positions,
    team_metrics,
)
from envs.seeding import check_seed


class CooperativeNavigationEnv(ParallelEnv):
    """PettingZoo ParallelEnv of Cooperative Navigation, built on mpe2's ``simple_spread_v3``.

    :param n_agents: number of agents and of landmarks (the paper uses 3)
    :param local_ratio: weight of the local collision penalty; ``1 - local_ratio`` weighs the global
        coverage reward (mpe2's argument)
    :param max_cycles: ticks per episode; the episode is truncated after them
    :param render_mode: None, ``"rgb_array"`` or ``"human"`` (mpe2's pygame drawing)
    :param benchmark_data: also put mpe2's per-agent ``benchmark_data`` tuple into the infos (slower)
    """

    metadata = {
        "name": "cooperative_navigation_v0",
        "render_modes": RENDER_MODES,
        "is_parallelizable": True,
        "render_fps": 10,
    }

    def __init__(
        self,
        n_agents: int = 3,
        local_ratio: float = 0.5,
        max_cycles: int = 25,
        render_mode: str | None = None,
        benchmark_data: bool = False,
    ) -> None:
        if isinstance(n_agents, bool) or not isinstance(n_agents, int) or n_agents < 2:
            raise ValueError(f"n_agents must be an int >= 2, got {n_agents!r}")
        if not 0.0 <= local_ratio <= 1.0:
            raise ValueError(f"local_ratio must lie in [0, 1], got {local_ratio!r}")
        if isinstance(max_cycles, bool) or not isinstance(max_cycles, int) or max_cycles < 1:
            raise ValueError(f"max_cycles must be an int >= 1, got {max_cycles!r}")
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be None or one of {RENDER_MODES}, got {render_mode!r}")
        self._env = simple_spread_v3.parallel_env(
            N=n_agents,
            local_ratio=local_ratio,
            max_cycles=max_cycles,
            continuous_actions=False,
            render_mode=render_mode,
            benchmark_data=benchmark_data,
        )
        self._world = self._env.unwrapped.world
        self.n_agents = n_agents
        self.max_cycles = max_cycles
        self.render_mode = render_mode
        self.possible_agents = list(self._env.possible_agents)
        self.agents = list(self.possible_agents)
        first = self.possible_agents[0]
        # mpe2 builds one space object per agent; parameter sharing wants a single one (PettingZoo asks for the
        # same object on every call, so that seeding a space sticks).
        self._observation_space = self._env.observation_space(first)
        self._action_space = self._env.action_space(first)
        self.state_space = self._env.state_space
        self._count_collisions = CollisionCounter(self._world.agents)
        self._reset_metrics()

    def observation_space(self, agent: str) -> spaces.Space:
        """The observation space of ``agent`` (one object shared by all agents)."""
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Space:
        """The action space of ``agent`` (one object shared by all agents)."""
        return self._action_space

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start a new episode.

        :param seed: reseeds the world's random generator when given (non-negative int)
        :param options: ignored (accepted for the PettingZoo API)
        :return: observations and infos of all agents
        """
        observations, _ = self._env.reset(seed=check_seed(seed), options=options)
        self.agents = list(self._env.agents)
        self._reset_metrics()
        agent_pos = positions(self._world.agents)
        self._count_collisions.start(agent_pos)
        team = self._team_metrics((0, 0), agent_pos)
        return observations, {agent: {"team": team} for agent in self.agents}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        """Advance the world one tick.

        :param actions: one Discrete(5) action per live agent
        :return: observations, rewards, terminations, truncations and infos of the agents that acted
        """
        for agent, action in actions.items():
            if not is_valid_action(action):
                raise ValueError(f"action {action!r} of {agent} is outside the action space {self._action_space}")
        observations, rewards, terminations, truncations, inner_infos = self._env.step(actions)
        self.agents = list(self._env.agents)
        self._ticks += 1
        self._team_return += float(sum(rewards.values()))
        agent_pos = positions(self._world.agents)
        team = self._team_metrics(self._count_collisions(agent_pos), agent_pos)
        infos = {agent: {**inner_infos.get(agent, {}), "team": team} for agent in observations}
        # mpe2 hands out a defaultdict of rewards; a plain dict does not invent rewards for unknown agents.
        return observations, dict(rewards), terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The global state: the observations of all agents concatenated (float32, ``state_space``)."""
        return self._env.state()

    def render(self) -> np.ndarray | None:
        """Draw the world with mpe2's renderer (an RGB array in ``"rgb_array"`` mode)."""
        return self._env.render()

    def close(self) -> None:
        """Release the renderer."""
        self._env.close()

    def _reset_metrics(self) -> None:
        self._ticks = 0
        self._team_return = 0.0
        self._n_collisions = 0
        self._n_collisions_after_spawn = 0

    def _team_metrics(self, new_collisions: tuple[int, int], agent_pos: list[list[float]]) -> dict[str, Any]:
        """:param new_collisions: this tick's colliding pairs, all and without the unseparated spawn overlaps"""
        self._n_collisions += new_collisions[0]
        self._n_collisions_after_spawn += new_collisions[1]
        min_dist_sum, occupied = landmark_coverage(agent_pos, positions(self._world.landmarks))
        return team_metrics(
            n_landmarks=len(self._world.landmarks),
            min_dist_sum=min_dist_sum,
            occupied_landmarks=occupied,
            n_collisions=self._n_collisions,
            n_collisions_after_spawn=self._n_collisions_after_spawn,
            team_return=self._team_return,
            ticks=self._ticks,
        )


def parallel_env(**kwargs: Any) -> CooperativeNavigationEnv:
    """Build the ParallelEnv (PettingZoo's module convention, used by ``pettingzoo.test.max_cycles_test``).

    :param kwargs: arguments of :class:`CooperativeNavigationEnv`
    :return: the env
    """
    return CooperativeNavigationEnv(**kwargs)


def env(**kwargs: Any) -> AECEnv:
    """Build the AEC version of the env (PettingZoo's module convention, for the compliance tests).

    :param kwargs: arguments of :class:`CooperativeNavigationEnv`
    :return: the env wrapped by ``pettingzoo.utils.conversions.parallel_to_aec``
    """
    return parallel_to_aec(CooperativeNavigationEnv(**kwargs))
