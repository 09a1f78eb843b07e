"""Per-tick cost of the SB3 bridge (``sb3_eps.make_vec_env``) next to the raw PettingZoo loop it wraps.

Measured side by side in one process, on one core, with random actions drawn in advance; every figure is the
best of ``--repeats`` runs of CPU time (``time.process_time``), which the other programs on a shared machine
disturb less than wall time. Three pairs:

- a no-op 4-agent ParallelEnv: what is left is the bridge's own overhead (adapter + SuperSuit + SB3 VecEnv);
- Cooperative Navigation: mpe2 ``simple_spread_v3.parallel_env`` raw, our ``CooperativeNavigation-v0`` raw,
  stock SuperSuit (``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1``) over mpe2, and the bridge;
- ``MultiRobotNav-4-v0`` raw and through the bridge (robot-steps per second).

Usage::

    python benchmarks/bridge_overhead.py [--ticks 3000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

import envs
from sb3_eps import make_vec_env
from sb3_eps.common.vec_env import MultiAgentVecEnv


class NoOpEnv(ParallelEnv):
    """4 agents, 30-float observations, Discrete(20), truncated after 100 ticks, nothing computed."""

    metadata = {"name": "no_op_v0"}

    def __init__(self, n_agents: int = 4) -> None:
        self.possible_agents = [f"agent_{i}" for i in range(n_agents)]
        self.agents: list[str] = []
        self.render_mode = None
        self.state_space = spaces.Box(-1.0, 1.0, (9 * n_agents,), np.float32)
        self._observation_space = spaces.Box(-1.0, 1.0, (30,), np.float32)
        self._action_space = spaces.Discrete(20)
        self._obs = np.zeros(30, dtype=np.float32)
        self._state = np.zeros(9 * n_agents, dtype=np.float32)
        self._ticks = 0

    def observation_space(self, agent: str) -> spaces.Space:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Space:
        return self._action_space

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        self.agents = list(self.possible_agents)
        self._ticks = 0
        return dict.fromkeys(self.agents, self._obs), {agent: {} for agent in self.agents}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        self._ticks += 1
        truncated = self._ticks >= 100
        team = {"team_return": 0.0, "ticks": self._ticks}
        result = (
            dict.fromkeys(actions, self._obs),
            dict.fromkeys(actions, 0.0),
            dict.fromkeys(actions, False),
            dict.fromkeys(actions, truncated),
            {agent: {"team": team} for agent in actions},
        )
        if truncated:
            self.agents = []
        return result

    def state(self) -> np.ndarray:
        return self._state


def cpu_per_tick_raw(env: ParallelEnv, n_ticks: int) -> float:
    """CPU seconds per tick of a plain ``reset`` / ``step`` loop with action dicts."""
    env.reset(seed=0)
    n_actions = env.action_space(env.possible_agents[0]).n
    actions = np.random.default_rng(0).integers(n_actions, size=(n_ticks, len(env.possible_agents)))
    start = time.process_time()
    for tick in range(n_ticks):
        env.step({agent: int(actions[tick, i]) for i, agent in enumerate(env.agents)})
        if not env.agents:
            env.reset()
    return (time.process_time() - start) / n_ticks


def cpu_per_tick_vec(venv: Any, n_worlds: int, n_ticks: int) -> float:
    """CPU seconds per tick (one world stepping once) of an SB3 vector env."""
    venv.reset()
    n_steps = max(n_ticks // n_worlds, 1)
    actions = np.random.default_rng(0).integers(venv.action_space.n, size=(n_steps, venv.num_envs))
    start = time.process_time()
    for step_actions in actions:
        venv.step(step_actions)
    return (time.process_time() - start) / (n_steps * n_worlds)


def best_of(repeats: int, measure: Callable[[], float]) -> float:
    return min(measure() for _ in range(repeats))


def stock_supersuit_mpe(n_worlds: int) -> Any:
    """mpe2 through stock SuperSuit into SB3, as the SuperSuit docs do it (the comparison path)."""
    import supersuit
    from mpe2 import simple_spread_v3

    agent_venv = supersuit.pettingzoo_env_to_vec_env_v1(simple_spread_v3.parallel_env(N=3, max_cycles=25))
    return supersuit.concat_vec_envs_v1(agent_venv, n_worlds, base_class="stable_baselines3")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    ticks, repeats = args.ticks, args.repeats

    def show(label: str, seconds: float, n_agents: int, reference: float | None = None) -> None:
        ratio = f"  x{seconds / reference:.2f}" if reference else ""
        print(f"  {label:<46} {seconds * 1e6:8.1f} us/tick {n_agents / seconds:10.0f} agent-steps/s{ratio}")

    print("no-op 4-agent env (the bridge's own cost):")
    raw = best_of(repeats, lambda: cpu_per_tick_raw(NoOpEnv(), 10 * ticks))
    show("raw ParallelEnv loop", raw, 4)
    for n_worlds in (1, 4):
        vec = best_of(repeats, lambda n=n_worlds: cpu_per_tick_vec(MultiAgentVecEnv([NoOpEnv] * n), n, 10 * ticks))
        show(f"bridge, {n_worlds} world(s)  (overhead {(vec - raw) * 1e6:.1f} us/tick)", vec, 4)

    print("Cooperative Navigation (3 agents):")
    from mpe2 import simple_spread_v3

    mpe = best_of(repeats, lambda: cpu_per_tick_raw(simple_spread_v3.parallel_env(N=3, max_cycles=25), ticks))
    show("mpe2 simple_spread_v3 raw loop", mpe, 3)
    ours = best_of(repeats, lambda: cpu_per_tick_raw(envs.make_parallel_env("CooperativeNavigation-v0"), ticks))
    show("CooperativeNavigation-v0 raw loop", ours, 3, mpe)
    stock = best_of(repeats, lambda: cpu_per_tick_vec(stock_supersuit_mpe(2), 2, ticks))
    show("mpe2 via stock SuperSuit, 2 worlds", stock, 3, mpe)
    bridge = best_of(repeats, lambda: cpu_per_tick_vec(make_vec_env("CooperativeNavigation-v0", 2, seed=0), 2, ticks))
    show("CooperativeNavigation-v0 via bridge, 2 worlds", bridge, 3, mpe)

    print("MultiRobotNav-4-v0 (4 robots):")
    robots_raw = best_of(repeats, lambda: cpu_per_tick_raw(envs.make_parallel_env("MultiRobotNav-4-v0"), ticks))
    show("raw loop", robots_raw, 4)
    robots = best_of(repeats, lambda: cpu_per_tick_vec(make_vec_env("MultiRobotNav-4-v0", 1, seed=0), 1, ticks))
    show(f"bridge, 1 world  (overhead {(robots - robots_raw) * 1e6:.1f} us/tick)", robots, 4, robots_raw)


if __name__ == "__main__":
    main()
