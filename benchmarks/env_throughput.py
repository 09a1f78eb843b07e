"""Env throughput: robot-steps per second of the TurtleBot3 worlds next to mpe2 ``simple_spread_v3`` (N=3).

Everything is measured side by side in one run, in this process (one core, no rendering, random actions drawn
in advance), twice per env:

- ``raw``: the PettingZoo ``ParallelEnv`` stepped directly with action dicts;
- ``vec``: through the same SB3 vector-env conversion for both. That is ``sb3_eps.make_vec_env`` when it
  builds the env (``--bridge auto``, the default), else plain SuperSuit
  (``pettingzoo_env_to_vec_env_v1`` then ``concat_vec_envs_v1(..., base_class="stable_baselines3")``) with
  :class:`KeepAllAgents`, a padding adapter SuperSuit needs because robots park (leave ``agents``) early.

A robot-step (agent-step) is one agent acting once; a tick steps every robot of a world once. The ratio column
divides by mpe2's throughput through the same path. Results: ``docs/benchmarks.md``.

Usage::

    python benchmarks/env_throughput.py [--seconds 3] [--bridge auto|sb3_eps|supersuit] [--robots 2 4 8 12]
        [--rooms 4 12 24]

``--robots`` measures the open arenas ``MultiRobotNav-{n}-v0`` (n = 2, 4, 8, 12, 24), ``--rooms`` the generated rooms
``MultiRobotNavRooms-{n}-v0`` (n = 4, 8, 12, 24; training levels, a new room at every reset).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv

from envs.turtlebot3 import MultiRobotNavEnv


class KeepAllAgents(ParallelEnv):
    """Keeps every agent in the returned dicts until the whole episode ends (benchmark-only padding).

    SuperSuit's ``MarkovVectorEnv`` refuses envs whose agents leave early, and its ``black_death_v3`` is broken
    in 3.11; a parked robot here repeats its last observation with reward 0 and stays terminated.

    :param env: the multi-agent env to pad
    """

    def __init__(self, env: ParallelEnv) -> None:
        self.env = env
        self.possible_agents = env.possible_agents
        self.metadata = env.metadata
        self.render_mode = None
        self.agents: list[str] = []
        self._last_obs: dict[str, Any] = {}
        self._finished: set[str] = set()

    @property
    def unwrapped(self) -> ParallelEnv:
        return self

    def observation_space(self, agent: str) -> Any:
        return self.env.observation_space(agent)

    def action_space(self, agent: str) -> Any:
        return self.env.action_space(agent)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        obs, infos = self.env.reset(seed=seed, options=options)
        self._last_obs = dict(obs)
        self._finished = set()
        self.agents = self.possible_agents[:]
        return obs, infos

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        live = set(self.env.agents)
        obs, rewards, terms, truncs, infos = self.env.step({a: act for a, act in actions.items() if a in live})
        self._last_obs.update(obs)
        self._finished.update(a for a in obs if terms[a] or truncs[a])
        agents = self.possible_agents
        out = (
            {a: self._last_obs[a] for a in agents},
            {a: rewards.get(a, 0.0) for a in agents},
            {a: terms.get(a, a in self._finished) for a in agents},
            {a: truncs.get(a, False) for a in agents},
            {a: infos.get(a, {}) for a in agents},
        )
        if not self.env.agents:
            self.agents = []
        return out

    def close(self) -> None:
        self.env.close()


def padded_robots(n_robots: int, scenario: str = "arena") -> ParallelEnv:
    """An n-robot world (the arena, or ``scenario``) wrapped for plain SuperSuit."""
    return KeepAllAgents(MultiRobotNavEnv(n_robots=n_robots, scenario=scenario))


def mpe_env() -> ParallelEnv:
    """mpe2 Cooperative Navigation as the paper runs it (3 agents, discrete actions, 25-step episodes)."""
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False)


# The clock that throughput is measured against (see --clock): process CPU time by default, so that other
# tenants of a shared machine, who steal wall time but not this process's CPU time, do not skew the figures.
CLOCKS: dict[str, Callable[[], float]] = {"cpu": time.process_time, "wall": time.perf_counter}


def time_raw(env: ParallelEnv, seconds: float, clock: Callable[[], float]) -> float:
    """Agent-steps per second of a ParallelEnv stepped directly."""
    env.reset(seed=0)
    n_actions = env.action_space(env.possible_agents[0]).n
    actions = np.random.default_rng(0).integers(0, n_actions, size=(4096, len(env.possible_agents))).tolist()
    steps, k = 0, 0
    start = clock()
    deadline = start + seconds
    while True:
        for _ in range(100):
            row = actions[k % 4096]
            k += 1
            step_actions = {agent: row[i] for i, agent in enumerate(env.agents)}
            env.step(step_actions)
            steps += len(step_actions)
            if not env.agents:
                env.reset()
        if clock() > deadline:
            break
    return steps / (clock() - start)


def time_vec(venv: Any, n_agents: int, seconds: float, clock: Callable[[], float]) -> float:
    """Agent-steps per second of an SB3 VecEnv with one sub-env per agent (ticks x agents)."""
    venv.reset()
    n_actions = venv.action_space.n
    actions = np.random.default_rng(0).integers(0, n_actions, size=(4096, venv.num_envs))
    calls, k = 0, 0
    start = clock()
    deadline = start + seconds
    while True:
        for _ in range(100):
            venv.step(actions[k % 4096])
            k += 1
            calls += 1
        if clock() > deadline:
            break
    return calls * n_agents / (clock() - start)


def supersuit_vec(env_fn: Callable[[], ParallelEnv]) -> Any:
    """Plain SuperSuit conversion to an SB3 VecEnv (one world)."""
    import supersuit

    venv = supersuit.pettingzoo_env_to_vec_env_v1(env_fn())
    return supersuit.concat_vec_envs_v1(venv, 1, num_cpus=0, base_class="stable_baselines3")


def bridge_vec(env_id: str) -> Any:
    """The project's bridge, ``sb3_eps.make_vec_env`` (one world)."""
    from sb3_eps import make_vec_env

    return make_vec_env(env_id, n_envs=1, seed=0)


def pick_bridge(requested: str) -> str:
    """Use the project's bridge when it builds both envs, else plain SuperSuit (or what was asked)."""
    if requested != "auto":
        return requested
    try:
        for env_id in ("MultiRobotNav-2-v0", "CooperativeNavigation-v0"):
            venv = bridge_vec(env_id)
            venv.reset()
            venv.step(np.zeros(venv.num_envs, dtype=int))
            venv.close()
        return "sb3_eps"
    except Exception as error:  # the bridge is optional here: fall back and say why
        print(f"sb3_eps.make_vec_env unusable ({type(error).__name__}: {error}); measuring through SuperSuit.")
        return "supersuit"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring time per env and path")
    parser.add_argument("--bridge", choices=["auto", "sb3_eps", "supersuit"], default="auto")
    parser.add_argument("--robots", type=int, nargs="+", default=[2, 4, 8, 12], help="arenas: MultiRobotNav-{n}-v0")
    parser.add_argument("--rooms", type=int, nargs="*", default=[], help="generated rooms: MultiRobotNavRooms-{n}-v0")
    parser.add_argument(
        "--clock",
        choices=list(CLOCKS),
        default="cpu",
        help="cpu: steps per CPU-second of this (single-threaded) process; wall: per wall-clock second",
    )
    args = parser.parse_args()
    clock = CLOCKS[args.clock]
    bridge = pick_bridge(args.bridge)

    def vec_of(env_id: str, env_fn: Callable[[], ParallelEnv]) -> Any:
        return bridge_vec(env_id) if bridge == "sb3_eps" else supersuit_vec(env_fn)

    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, python {platform.python_version()}")
    print(f"clock: {args.clock} ({'process CPU time' if args.clock == 'cpu' else 'wall time'})")
    print(f"vec path: {'sb3_eps.make_vec_env' if bridge == 'sb3_eps' else 'SuperSuit + KeepAllAgents'}")
    env = mpe_env()
    mpe_raw = time_raw(env, args.seconds, clock)
    env.close()
    mpe_venv = vec_of("CooperativeNavigation-v0", mpe_env)
    mpe_vec = time_vec(mpe_venv, 3, args.seconds, clock)
    mpe_venv.close()

    header = f"{'env':<28}{'agents':>7}{'raw steps/s':>13}{'vec steps/s':>13}{'raw / mpe2':>11}{'vec / mpe2':>11}"
    print(header)
    print("-" * len(header))
    print(f"{'mpe2 simple_spread_v3':<28}{3:>7}{mpe_raw:>13,.0f}{mpe_vec:>13,.0f}{1.0:>11.2f}{1.0:>11.2f}")
    worlds = [(f"MultiRobotNav-{n}-v0", n, "arena") for n in args.robots]
    worlds += [(f"MultiRobotNavRooms-{n}-v0", n, "rooms") for n in args.rooms]
    for name, n, scenario in worlds:
        env = MultiRobotNavEnv(n_robots=n, scenario=scenario)
        raw = time_raw(env, args.seconds, clock)
        env.close()
        venv = vec_of(name, partial(padded_robots, n, scenario))
        vec = time_vec(venv, n, args.seconds, clock)
        venv.close()
        print(f"{name:<28}{n:>7}{raw:>13,.0f}{vec:>13,.0f}{raw / mpe_raw:>11.2f}{vec / mpe_vec:>11.2f}")


if __name__ == "__main__":
    main()
