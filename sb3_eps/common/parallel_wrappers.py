"""PettingZoo ParallelEnv adapters around the SB3 bridge (:mod:`sb3_eps.common.multi_agent_vec_env`).

:class:`FixedAgentSet` keeps every agent in every step, as SuperSuit needs; :class:`SingleAgentParallelEnv` and
:class:`ParallelEnvAsGymnasium` turn gymnasium envs into one-agent worlds and back; :class:`TeamAsGymnasium` makes a
multi-agent world one gymnasium env played by a team (EPS's team worlds).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv


def ticks_per_step(env: Any) -> int:
    """:return: the world ticks one ``step`` of ``env`` advances: its ``action_repeat`` (a TurtleBot3 world holding
    each decision for several ticks), looked up through the wrappers' ``env``; 1 for any other world."""
    for _ in range(16):
        repeat = getattr(env, "action_repeat", None)
        if isinstance(repeat, (int, np.integer)) and not isinstance(repeat, bool):
            return int(repeat)
        inner = getattr(env, "env", None)
        if inner is None or inner is env:
            return 1
        env = inner
    return 1


class SingleAgentParallelEnv(ParallelEnv):
    """A gymnasium env seen as a PettingZoo ParallelEnv with one agent named ``agent``; its global state is the
    env's ``state()`` when it has one (with ``state_space``), else its observation."""

    def __init__(self, env: gymnasium.Env, agent: str = "agent_0") -> None:
        self.env = env
        self.possible_agents = [agent]
        self.agents: list[str] = []
        self.metadata = dict(getattr(env, "metadata", {}))
        self.render_mode = env.render_mode
        self._state_space = getattr(env.unwrapped, "state_space", None)
        self._state_fn = getattr(env.unwrapped, "state", None)
        self._has_state = self._state_space is not None and callable(self._state_fn)
        self.state_space = self._state_space if self._has_state else env.observation_space
        self._last_obs: Any = None

    def observation_space(self, agent: str) -> spaces.Space:
        return self.env.observation_space

    def action_space(self, agent: str) -> spaces.Space:
        return self.env.action_space

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        self._last_obs = obs
        agent = self.possible_agents[0]
        return {agent: obs}, {agent: info}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, Any], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        agent = self.possible_agents[0]
        obs, reward, terminated, truncated, info = self.env.step(actions[agent])
        self._last_obs = obs
        if terminated or truncated:
            self.agents = []
        return {agent: obs}, {agent: float(reward)}, {agent: terminated}, {agent: truncated}, {agent: info}

    def state(self) -> np.ndarray:
        """The env's ``state()``, or its last observation when it has none."""
        if self._has_state:
            return self._state_fn()  # type: ignore[misc]
        return np.asarray(self._last_obs, dtype=np.float32)

    def render(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()


class ParallelEnvAsGymnasium(gymnasium.Env):
    """A one-agent PettingZoo ParallelEnv seen as a gymnasium env: the reverse of :class:`SingleAgentParallelEnv`.

    It gives a world of your own its single-agent variant for EPS (``docs/bring_your_own_world.md``). At an
    episode's end ``info["is_success"]`` is the agent's ``is_success``, ``success`` or ``team["success"]``.
    """

    def __init__(self, env: ParallelEnv) -> None:
        if len(env.possible_agents) != 1:
            raise ValueError(
                f"ParallelEnvAsGymnasium needs a ParallelEnv with one agent, got {len(env.possible_agents)} "
                f"({env.possible_agents}); build your world with a single agent"
            )
        self.env = env
        self.agent = env.possible_agents[0]
        self.observation_space = env.observation_space(self.agent)
        self.action_space = env.action_space(self.agent)
        self.metadata = dict(getattr(env, "metadata", {}))
        self.render_mode = getattr(env, "render_mode", None)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        observations, infos = self.env.reset(seed=seed, options=options)
        return observations[self.agent], dict(infos.get(self.agent, {}))

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observations, rewards, terminations, truncations, infos = self.env.step({self.agent: action})
        terminated, truncated = bool(terminations[self.agent]), bool(truncations[self.agent])
        info = dict(infos.get(self.agent, {}))
        if (terminated or truncated) and "is_success" not in info:
            success = info.get("success", info.get("team", {}).get("success"))
            if success is not None:
                info["is_success"] = bool(success)
        return observations[self.agent], float(rewards[self.agent]), terminated, truncated, info

    def render(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()


class TeamTick(NamedTuple):
    """What one step of a team world said of each agent (``possible_agents`` order), as the bridge would see it."""

    rewards: np.ndarray  # (n,) float32; 0 for an agent whose episode was over
    terminations: np.ndarray  # (n,) bool
    truncations: np.ndarray  # (n,) bool
    alive: np.ndarray  # (n,) bool: the agent acted in this step


class TeamAsGymnasium(gymnasium.Env):
    """A multi-agent ParallelEnv seen as one gymnasium env played by a team that shares one policy.

    Observation ``(n_agents, *obs_shape)`` (a finished agent keeps its last one), a ``MultiDiscrete`` action (one per
    agent), the reward the mean of the agents' (one robot's scale). The episode ends when every agent's has ended,
    truncated when an agent was cut by the time limit; ``info["is_success"]`` and ``info["team"]`` are then the
    team's. ``last_tick`` (:class:`TeamTick`) keeps what the step said of each agent, for experience sharing.

    :param env: a ParallelEnv whose agents all exist at reset and share one observation and one action space
    """

    def __init__(self, env: ParallelEnv) -> None:
        self.env = FixedAgentSet(env)
        self.agents = list(env.possible_agents)
        self.team_size = len(self.agents)
        self.agent_observation_space = env.observation_space(self.agents[0])
        self.agent_action_space = env.action_space(self.agents[0])
        if any(
            env.observation_space(agent) != self.agent_observation_space or env.action_space(agent) != self.agent_action_space
            for agent in self.agents
        ) or not isinstance(self.agent_action_space, spaces.Discrete):
            raise ValueError("TeamAsGymnasium needs agents that share one observation space and one Discrete action space")
        box = self.agent_observation_space
        assert isinstance(box, spaces.Box)
        shape = (self.team_size, *box.shape)
        self.observation_space = spaces.Box(
            np.broadcast_to(box.low, shape), np.broadcast_to(box.high, shape), shape, box.dtype
        )
        self.action_space = spaces.MultiDiscrete([int(self.agent_action_space.n)] * self.team_size)
        self.max_episode_steps = getattr(env, "max_episode_steps", None)
        self.metadata = dict(getattr(env, "metadata", {}))
        self.render_mode = getattr(env, "render_mode", None)
        self.state_space = self.env.state_space  # the global state's, for centralised critics (QMIX)
        self.last_tick: TeamTick | None = None

    def _stack(self, observations: dict[str, Any]) -> np.ndarray:
        return np.stack([observations[agent] for agent in self.agents]).astype(self.observation_space.dtype)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """:return: the team's observations and the first agent's info."""
        super().reset(seed=seed)
        observations, _ = self.env.reset(seed=seed, options=options)
        return self._stack(observations), dict(self.env.reset_infos.get(self.agents[0], {}))

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        actions = np.asarray(action).reshape(-1)
        if actions.shape != (self.team_size,):  # zip would drop the extra actions silently
            raise ValueError(f"expected {self.team_size} actions (one per agent), got {np.shape(action)}")
        observations, rewards, terminations, truncations, _ = self.env.step(
            {agent: int(a) for agent, a in zip(self.agents, actions)}
        )
        agent_rewards = np.array([rewards[agent] for agent in self.agents], dtype=np.float64)
        self.last_tick = TeamTick(
            rewards=agent_rewards.astype(np.float32),
            terminations=np.array([terminations[agent] for agent in self.agents], dtype=bool),
            truncations=np.array([truncations[agent] for agent in self.agents], dtype=bool),
            alive=self.env.step_alive.copy(),
        )
        reward = float(agent_rewards.mean())
        info: dict[str, Any] = {}
        truncated = False
        if self.env.world_done:
            truncated = any(truncations.values())
            team = self.env.terminal_team
            if team is not None:
                info["team"] = dict(team)
                if "success" in team:
                    info["is_success"] = bool(team["success"])
        return self._stack(observations), reward, self.env.world_done and not truncated, truncated, info

    def state(self) -> np.ndarray:
        """The world's global state (:meth:`FixedAgentSet.state`); at the end of an episode its terminal state."""
        return np.asarray(self.env.state(), dtype=np.float32)

    def render(self) -> Any:
        return self.env.env.render()

    def close(self) -> None:
        self.env.env.close()


class FixedAgentSet(ParallelEnv):
    """Keeps every possible agent in every step, so that SuperSuit sees a fixed set of sub-envs.

    An agent whose episode ended before the world's keeps returning its last observation with reward 0,
    terminated False and ``info == {"alive": False}``, and is terminated with the world. After each step the
    bridge reads what SuperSuit cannot carry (it resets the world inside its step): ``step_alive`` (read-only),
    ``any_end``, ``world_done``, ``terminal_state``, ``terminal_team`` (``info["team"]`` at the end) and
    ``reset_infos`` (``reset`` returns empty infos: SuperSuit merges them over the terminal step's). Envs without a
    ``state_space`` get the concatenated observations of all agents as their global state.

    :param env: a PettingZoo ParallelEnv whose agents all exist at reset and share one observation space
        and one action space
    """

    def __init__(self, env: ParallelEnv) -> None:
        self.env = env
        self.possible_agents = list(env.possible_agents)
        self.agents = list(self.possible_agents)
        self.metadata = env.metadata
        self.render_mode = getattr(env, "render_mode", None)
        env_state_space = getattr(env, "state_space", None)
        self._has_state = env_state_space is not None
        self.state_space: spaces.Box = env_state_space if env_state_space is not None else self._stacked_observation_space()
        n_agents = len(self.possible_agents)
        self._alive = np.ones(n_agents, dtype=bool)
        self._n_alive = n_agents
        # Shared by every step in which all agents act; read-only, as the bridge keeps references to it.
        self._everyone = np.ones(n_agents, dtype=bool)
        self._everyone.flags.writeable = False
        self._last_obs: dict[str, Any] = {}
        self.step_alive = self._everyone
        self.world_done = False
        self.any_end = False
        self.terminal_state: np.ndarray | None = None
        self.terminal_team: dict[str, Any] | None = None
        self.reset_infos: dict[str, dict[str, Any]] = {}

    def observation_space(self, agent: str) -> spaces.Space:
        return self.env.observation_space(agent)

    def action_space(self, agent: str) -> spaces.Space:
        return self.env.action_space(agent)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        """Reset the world; every possible agent must be present. The env's infos go to ``reset_infos``."""
        observations, infos = self.env.reset(seed=seed, options=options)
        missing = [agent for agent in self.possible_agents if agent not in observations]
        if missing:
            raise ValueError(f"{missing} got no observation at reset: every possible agent must start the episode")
        self._last_obs = observations
        self._alive[:] = True
        self._n_alive = len(self._alive)
        self.reset_infos = infos
        return observations, {agent: {} for agent in self.possible_agents}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, Any], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        """Step the live agents (dead agents' actions are ignored); fill in the agents whose episode is over."""
        alive = self._alive
        everyone_acts = self._n_alive == len(alive)
        if not everyone_acts:
            actions = {agent: actions[agent] for agent, is_alive in zip(self.possible_agents, alive) if is_alive}
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        if everyone_acts and not (any(terminations.values()) or any(truncations.values())):
            # The common case, kept cheap: everyone acted and nobody's episode ended.
            self.step_alive = self._everyone
            self.world_done = self.any_end = False
            self._last_obs = observations
            return observations, rewards, terminations, truncations, infos
        return self._step_with_ends(observations, rewards, terminations, truncations, infos)

    def _step_with_ends(
        self,
        observations: dict[str, Any],
        rewards: dict[str, float],
        terminations: dict[str, bool],
        truncations: dict[str, bool],
        infos: dict[str, dict[str, Any]],
    ) -> tuple[dict[str, Any], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        alive = self._alive
        self.step_alive = alive.copy()
        last_obs = dict(self._last_obs)
        out_obs: dict[str, Any] = {}
        out_rewards: dict[str, float] = {}
        out_terms: dict[str, bool] = {}
        out_truncs: dict[str, bool] = {}
        out_infos: dict[str, dict[str, Any]] = {}
        team = None
        for index, agent in enumerate(self.possible_agents):
            if self.step_alive[index]:
                out_obs[agent] = last_obs[agent] = observations[agent]
                out_rewards[agent] = rewards[agent]
                terminated, truncated = bool(terminations[agent]), bool(truncations[agent])
                out_terms[agent], out_truncs[agent] = terminated, truncated
                # A copy: SuperSuit writes terminal_observation into these, and an env may share one dict.
                out_infos[agent] = dict(infos.get(agent, {}))
                team = out_infos[agent].get("team", team)
                if terminated or truncated:
                    alive[index] = False
        self._n_alive = int(alive.sum())
        self.world_done = self._n_alive == 0
        self.any_end = self.world_done or self._n_alive < int(self.step_alive.sum())
        for index, agent in enumerate(self.possible_agents):
            if not self.step_alive[index]:
                out_obs[agent] = last_obs[agent]
                out_rewards[agent] = 0.0
                # A dead agent's slot ends with the world, as a termination: after its own end it earns nothing.
                out_terms[agent], out_truncs[agent] = self.world_done, False
                out_infos[agent] = {"alive": False}
        self._last_obs = last_obs
        if self.world_done:
            self.terminal_state = self.state()
            self.terminal_team = team
        return out_obs, out_rewards, out_terms, out_truncs, out_infos

    def state(self) -> np.ndarray:
        """The wrapped env's global state (or all agents' observations concatenated when it has none)."""
        if self._has_state:
            return self.env.state()
        return np.concatenate([np.ravel(self._last_obs[agent]) for agent in self.possible_agents]).astype(np.float32)

    def _stacked_observation_space(self) -> spaces.Box:
        boxes = [self.env.observation_space(agent) for agent in self.possible_agents]
        if not all(isinstance(box, spaces.Box) for box in boxes):
            raise ValueError("an env without state_space needs Box observation spaces to build its global state")
        low = np.concatenate([np.ravel(box.low) for box in boxes]).astype(np.float32)
        high = np.concatenate([np.ravel(box.high) for box in boxes]).astype(np.float32)
        return spaces.Box(low, high, dtype=np.float32)

    def render(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()
