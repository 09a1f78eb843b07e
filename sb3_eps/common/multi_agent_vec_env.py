"""The bridge: PettingZoo worlds -> SuperSuit -> an SB3 ``VecEnv`` with one sub-env per agent (parameter sharing).

Sub-env ``w * n_agents + i`` is agent ``i`` of world ``w`` (contract in ``docs/architecture.md``). Before SuperSuit,
:class:`~sb3_eps.common.parallel_wrappers.FixedAgentSet` keeps the agent set fixed and what SuperSuit drops; on top,
:class:`MultiAgentVecEnv` concatenates the worlds (not SuperSuit's ``concat_vec_envs_v1``: its copies of one PyBullet
world would share one physics client, ``benchmarks/bridge_overhead.py``) and adds seeding, ``TimeLimit.truncated``,
episode statistics per world, the global state and per-agent ``alive`` flags. Do not wrap it in SB3's
``VecMonitor``: it would count every agent as an episode.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn
from supersuit import pettingzoo_env_to_vec_env_v1

from sb3_eps.common.parallel_wrappers import FixedAgentSet, SingleAgentParallelEnv, ticks_per_step
from sb3_eps.common.utils import check_seed

# Keys of the env's ``info["team"]`` that the episode dict already carries as SB3's "r" and "l".
_EPISODE_RENAMED_KEYS = ("team_return", "ticks")


class MultiAgentVecEnv(VecEnv):
    """SB3 ``VecEnv`` over ``n_worlds`` PettingZoo worlds of ``n_agents`` agents each, one sub-env per agent.

    Step semantics (``docs/architecture.md``): ``infos[k]["alive"]`` (``self.alive[k]``) says whether agent ``k``
    acted; ``dones[k]`` is set at its own end and at its world's end (dead agents included, with ``alive=False``),
    with ``terminal_observation`` and ``TimeLimit.truncated``; when world ``w`` ends, ``infos[w * n_agents]`` alone
    carries ``"episode"`` (team return, ticks, seconds, the env's ``info["team"]``), ``"is_success"`` and
    ``"terminal_state"``.

    :param env_fns: one constructor per world (a PettingZoo ParallelEnv, or a gymnasium env: a one-agent world)
    :param env_id: the registered id the worlds were built from, for the record
    """

    ticks_per_step = 1  # until __init__ reads the worlds' (and for vec envs pickled before it was kept)
    #: The world options given to :func:`~sb3_eps.make_vec_env` beyond the registration's (None: not known).
    env_kwargs: dict[str, Any] | None = None
    #: The worlds' ``level_set`` option, given or fixed by the env id (None: a world without level sets), for records.
    level_set: Any = None

    def __init__(self, env_fns: Sequence[Callable[[], ParallelEnv | gymnasium.Env]], env_id: str | None = None):
        self._worlds = [FixedAgentSet(_as_parallel_env(env_fn())) for env_fn in env_fns]
        first = self._worlds[0]
        self.n_worlds = len(self._worlds)
        self.env_id = env_id
        for world in self._worlds[1:]:
            if world.possible_agents != first.possible_agents:
                raise ValueError("all worlds must have the same possible_agents")
        if any(ticks_per_step(world.env) != ticks_per_step(first.env) for world in self._worlds[1:]):
            raise ValueError("all worlds must advance the same ticks per step (action_repeat)")
        # SuperSuit: each world becomes a vector env of its agents (it checks that they share their spaces).
        self._agent_venvs = [pettingzoo_env_to_vec_env_v1(world) for world in self._worlds]
        agent_venv = self._agent_venvs[0]
        spaces_ = (agent_venv.observation_space, agent_venv.action_space)
        self._set_layout(first.possible_agents, *spaces_, first.state_space, ticks_per_step(first.env))
        self._slices = [slice(w * self.n_agents, (w + 1) * self.n_agents) for w in range(self.n_worlds)]
        self._discrete_actions = isinstance(self.action_space, spaces.Discrete)
        # Per-step bookkeeping in Python numbers: NumPy's call overhead dominates at a few worlds.
        self._episode_returns = [0.0] * self.n_worlds
        self._episode_start = [0] * self.n_worlds
        self._t_start = time.time()

    def _set_layout(
        self,
        possible_agents: Sequence[str],
        observation_space: spaces.Space,
        action_space: spaces.Space,
        state_space: spaces.Box,
        ticks_per_step: int,
    ) -> None:
        """Set what every bridge keeps of its worlds' layout, and a fresh step state (``n_worlds`` is set before)."""
        self.possible_agents: list[str] = list(possible_agents)
        self.n_agents = len(self.possible_agents)
        self.state_space = state_space
        #: world ticks per step (the worlds' ``action_repeat``; 1 for a world that decides at every tick)
        self.ticks_per_step = ticks_per_step
        VecEnv.__init__(self, self.n_worlds * self.n_agents, observation_space, action_space)
        self.alive = np.ones(self.num_envs, dtype=bool)
        self._actions = np.zeros(self.num_envs, dtype=np.int64)
        self._seed: int | None = None
        self._n_steps = 0
        self._state: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        """Reset every world (world ``w`` with ``seed + w`` after :meth:`seed`) and return all observations."""
        observations = []
        for w, venv in enumerate(self._agent_venvs):
            seed = None if self._seed is None else self._seed + w
            # SB3 keeps options per sub-env; a world takes those of its first agent.
            observations.append(venv.reset(seed=seed, options=self._options[w * self.n_agents] or None)[0])
        obs = observations[0] if self.n_worlds == 1 else np.concatenate(observations)
        self._seed = None
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [world.reset_infos.get(agent, {}) for world in self._worlds for agent in self.possible_agents]
        self.alive = np.ones(self.num_envs, dtype=bool)
        self._episode_returns = [0.0] * self.n_worlds
        self._episode_start = [self._n_steps] * self.n_worlds
        self._state = None
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Store the actions of all agents (one per sub-env) for :meth:`step_wait`."""
        actions = np.asarray(actions)
        if actions.shape[:1] != (self.num_envs,):
            raise ValueError(
                f"expected one action per sub-env ({self.n_worlds} worlds x {self.n_agents} agents = "
                f"{self.num_envs}), got an array of shape {actions.shape}"
            )
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        """Step every world once (a tick) and return ``obs, rewards, dones, infos`` of all agents."""
        actions = self._actions
        if self.n_worlds == 1:
            obs, rewards, terminations, truncations, infos = self._agent_venvs[0].step(self._per_world(actions))
            self.alive = self._worlds[0].step_alive
        else:
            results = [venv.step(self._per_world(actions[part])) for venv, part in zip(self._agent_venvs, self._slices)]
            obs, rewards, terminations, truncations = (np.concatenate([r[i] for r in results]) for i in range(4))
            infos = [info for result in results for info in result[4]]
            self.alive = np.concatenate([world.step_alive for world in self._worlds])
        dones = np.logical_or(terminations, truncations)
        # SuperSuit hands out fresh info dicts every step, so they can take the flag without copying.
        for info, is_alive in zip(infos, self.alive.tolist()):
            info["alive"] = is_alive
        self._n_steps += 1
        self._state = None
        world_rewards = rewards.tolist()
        n = self.n_agents
        for w in range(self.n_worlds):
            self._episode_returns[w] += sum(world_rewards[w * n : (w + 1) * n])
        if any(world.any_end for world in self._worlds):
            for k in np.flatnonzero(dones):
                info = infos[k]
                info["TimeLimit.truncated"] = bool(truncations[k]) and not bool(terminations[k])
                # SuperSuit only adds it when the whole world ends; an agent that ends alone is not reset,
                # so its returned observation is its terminal one.
                if "terminal_observation" not in info:
                    info["terminal_observation"] = obs[k].copy()
            for w, world in enumerate(self._worlds):
                if world.world_done:
                    self._end_episode(w, infos)
        return obs, rewards, dones, infos

    @property
    def total_ticks(self) -> int:
        """Ticks stepped through this vec env, all worlds together (steps x worlds x ``ticks_per_step``)."""
        return self._n_steps * self.n_worlds * self.ticks_per_step

    def get_state(self) -> np.ndarray:
        """The current global state of each world, ``(n_worlds, state_dim)`` float32 (read-only); after an automatic
        reset, the new episode's (the finished one's is ``infos[w * n_agents]["terminal_state"]``)."""
        if self._state is None:
            self._state = np.stack([world.state() for world in self._worlds]).astype(np.float32, copy=False)
        return self._state

    def seed(self, seed: int | None = None) -> list[int | None]:
        """Seed the next reset: world ``w`` is reset with ``seed + w`` (None: a random seed).
        :return: the seed of each sub-env (its world's)"""
        seed = check_seed(seed)
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seed = seed
        self._seeds = [seed + k // self.n_agents for k in range(self.num_envs)]
        return list(self._seeds)

    # -------------------------------------------------------------------------------- pickling
    def __getstate__(self) -> dict[str, Any]:
        """Everything, with the episodes' clock (``t``) kept as the seconds elapsed: a run resumed from a
        checkpoint goes on counting its run time, not the time it spent stopped."""
        state = dict(self.__dict__)
        state["_t_elapsed"] = time.time() - state.pop("_t_start")
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        """The clock starts the pickled seconds elapsed before now (a pickle from before they were kept keeps its
        start)."""
        if "_t_elapsed" in state:
            state["_t_start"] = time.time() - state.pop("_t_elapsed")
        self.__dict__.update(state)

    def close(self) -> None:
        """Close every world."""
        for venv in self._agent_venvs:
            venv.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """An attribute of the env that each selected sub-env's world was built from, one value per sub-env."""
        return self._per_sub_env(indices, "getattr", attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of the env of each world that a selected sub-env belongs to (once per world)."""
        self._per_sub_env(indices, "setattr", attr_name, (value,))

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method of the env of each world that a selected sub-env belongs to, once per world; :return: one
        result per selected sub-env (agents of one world share their world's)."""
        return self._per_sub_env(indices, "method", method_name, method_args, method_kwargs)

    def env_is_wrapped(self, wrapper_class: type[gymnasium.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        """Whether the env of each selected sub-env is a gymnasium env wrapped in ``wrapper_class``."""
        return self._per_sub_env(indices, "is_wrapped", None, (wrapper_class,))

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One picture per world (not per agent), for SB3's ``render``."""
        pictures = self._world_call(range(self.n_worlds), "render")
        return [pictures[w] for w in range(self.n_worlds)]

    def _per_sub_env(
        self,
        indices: VecEnvIndices,
        kind: str,
        name: str | None,
        args: tuple[Any, ...] = (),
        kwargs: dict[str, Any] | None = None,
    ) -> list[Any]:
        """Apply ``kind`` once per world of the selected sub-envs; :return: the result of each sub-env's world."""
        selected = list(self._get_indices(indices))
        worlds = sorted({k // self.n_agents for k in selected})
        results = self._world_call(worlds, kind, name, args, kwargs)
        return [results[k // self.n_agents] for k in selected]

    def _world_call(
        self,
        worlds: Iterable[int],
        kind: str,
        name: str | None = None,
        args: tuple[Any, ...] = (),
        kwargs: dict[str, Any] | None = None,
    ) -> dict[int, Any]:
        """:return: world -> the result of :func:`_apply_to_world` on it (the worker vec env overrides this)."""
        return {w: _apply_to_world(self._worlds[w], self._user_env(w), kind, name, args, kwargs or {}) for w in worlds}

    def _user_env(self, w: int) -> Any:
        """The env world ``w`` was built from (a ParallelEnv, or the gymnasium env of a one-agent world)."""
        env = self._worlds[w].env
        return env.env if isinstance(env, SingleAgentParallelEnv) else env

    def _per_world(self, actions: np.ndarray) -> Any:
        # Discrete actions go on as Python ints: envs turn lists of NumPy scalars into arrays far more slowly.
        return actions.tolist() if self._discrete_actions else actions

    def _get_indices(self, indices: VecEnvIndices) -> Iterable[int]:
        selected = list(super()._get_indices(indices))
        for k in selected:
            if not 0 <= k < self.num_envs:
                raise IndexError(f"sub-env index {k} out of range [0, {self.num_envs})")
        return selected

    def _end_episode(self, w: int, infos: list[dict[str, Any]]) -> None:
        """Put world ``w``'s episode statistics into its first agent's info and restart its counters."""
        world = self._worlds[w]
        team = world.terminal_team or {}
        episode = {
            "r": float(team.get("team_return", self._episode_returns[w])),
            # the world's own tick count where it keeps one (a step of a world with action_repeat is several ticks)
            "l": int(team.get("ticks", self._n_steps - self._episode_start[w])),
            "t": round(time.time() - self._t_start, 6),
        }
        episode.update((key, value) for key, value in team.items() if key not in _EPISODE_RENAMED_KEYS)
        first = infos[w * self.n_agents]
        first["episode"] = episode
        if "success" in team:
            first["is_success"] = bool(team["success"])
        first["terminal_state"] = world.terminal_state
        start = w * self.n_agents
        self.reset_infos[start : start + self.n_agents] = [world.reset_infos.get(a, {}) for a in self.possible_agents]
        self._episode_returns[w] = 0.0
        self._episode_start[w] = self._n_steps


def _as_parallel_env(env: ParallelEnv | gymnasium.Env) -> ParallelEnv:
    if isinstance(env, gymnasium.Env):
        return SingleAgentParallelEnv(env)
    if isinstance(env, ParallelEnv):
        return env
    raise ValueError(f"an env constructor returned {type(env).__name__}; expected a PettingZoo ParallelEnv or a gymnasium Env")


def _apply_to_world(
    world: FixedAgentSet,
    env: Any,
    kind: str,
    name: str | None,
    args: tuple[Any, ...],
    kwargs: dict[str, Any],
) -> Any:
    """One world-level request of ``get_attr`` / ``set_attr`` / ``env_method`` / ``env_is_wrapped`` / ``render``."""
    if kind == "getattr":
        return getattr(env, name)  # type: ignore[arg-type]
    if kind == "setattr":
        return setattr(env, name, args[0])  # type: ignore[arg-type]
    if kind == "method":
        return getattr(env, name)(*args, **kwargs)  # type: ignore[arg-type]
    if kind == "is_wrapped":
        return is_wrapped(env, args[0])
    if kind == "render":
        return world.render()
    raise ValueError(f"unknown world request {kind!r}")
