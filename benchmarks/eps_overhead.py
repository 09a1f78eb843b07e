"""EPS overhead, measured side by side in one run (issue 4's acceptance benchmark).

1. Wall time of GDQ and of EPS-GDQ (default ``EvolutionCallback`` settings) for the same number of training
   ticks on ``MultiRobotNav-4-v0``, and their ratio (target <= 1.10; the paper reports 1.04 +/- 0.03). Also
   EPS-GDQ with ``alpha=0``: its rounds run but never change the weights, so it follows GDQ's trajectory exactly
   and its extra time is the cost of EPS alone (a real EPS-GDQ run trains on other episodes once a mutant wins,
   which moves its time by several percent either way). The models train in rotating slices of ``--slice``
   ticks (``learn(..., reset_num_timesteps=False)``, each with its own global RNG states), so a change in the
   machine's background load hits all alike. CPU seconds (main process plus the EPS workers) are reported
   beside wall seconds: on a machine shared with other jobs the wall ratio moves with their load, the CPU ratio
   hardly; it is the wall ratio of a quiet machine evaluating in one process, and an upper bound when the
   workers run on free cores.
2. Seconds per EPS round for population 10 with the envs in worker processes and in the main process, on the
   network the EPS-GDQ run ended with; configurations alternate.
3. How large a mutation is, for the choice of ``sigma``: on visited observations of the EPS-GDQ run, the share
   of greedy actions a mutant changes and the mean |Q change|, for the safe and the Gaussian mutation.

Usage::

    python benchmarks/eps_overhead.py --ticks 20000
"""

from __future__ import annotations

import argparse
import copy
import os
import random
import resource
import time
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.utils import set_random_seed

import envs  # noqa: F401
from sb3_eps import make_vec_env
from sb3_eps.eps import (
    EvolutionCallback,
    PopulationForward,
    eps_env_id_for,
    mutate_population,
    output_sensitivity,
)
from sb3_eps.eps.mutations import network_parameters
from sb3_eps.gdq import GDQ


def make_model(env_id: str, n_envs: int, seed: int) -> GDQ:
    """GDQ with its default hyper-parameters on ``n_envs`` worlds of ``env_id``."""
    return GDQ("MlpPolicy", make_vec_env(env_id, n_envs=n_envs, seed=seed), seed=seed)


def cpu_time() -> float:
    """:return: user + system CPU seconds of this process and of its reaped children (the EPS workers)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def global_rng_state() -> tuple[Any, Any, Any]:
    """:return: the states of Python's, NumPy's and torch's global generators."""
    return random.getstate(), np.random.get_state(), th.get_rng_state()


def set_global_rng_state(state: tuple[Any, Any, Any]) -> None:
    """Restore the states returned by :func:`global_rng_state`."""
    random.setstate(state[0])
    np.random.set_state(state[1])
    th.set_rng_state(state[2])


def overhead(args: argparse.Namespace) -> tuple[GDQ, EvolutionCallback]:
    """Part 1: train GDQ, EPS-GDQ and EPS-GDQ with alpha = 0 in rotating slices; compare wall and CPU times."""
    eval_env_id = eps_env_id_for(args.env)
    runs: list[tuple[str, GDQ, EvolutionCallback | None]] = [
        ("GDQ", make_model(args.env, args.n_envs, args.seed), None),
        (
            "EPS-GDQ",
            make_model(args.env, args.n_envs, args.seed),
            EvolutionCallback(eval_env_id=eval_env_id, seed=args.seed),
        ),
        # alpha = 0: every round runs, but the crossover changes nothing, so this run follows GDQ's trajectory
        # exactly and its extra time is the cost of EPS alone, free of the noise of a different trajectory.
        (
            "EPS a=0",
            make_model(args.env, args.n_envs, args.seed),
            EvolutionCallback(eval_env_id=eval_env_id, alpha=0.0, seed=args.seed),
        ),
    ]
    n_agents = runs[0][1].n_agents
    # Warm up the process (lazy initialisations of torch, PyBullet, the first gradient steps) on a throw-away
    # model: otherwise the run that goes first pays for them (about 5 % of GDQ's time in a 20k-tick run).
    make_model(args.env, args.n_envs, args.seed + 1).learn(args.warmup * n_agents)
    seconds = {name: 0.0 for name, _, _ in runs}
    cpu_seconds = dict(seconds)
    # SB3 draws exploration and replay samples from the global RNGs: each model keeps its own streams, so the
    # runs follow the same trajectory until EPS first changes the weights; all start from the same states.
    set_random_seed(args.seed)
    rng_states = {name: global_rng_state() for name in seconds}
    done, slice_index = 0, 0
    while done < args.ticks:
        ticks = min(args.slice, args.ticks - done)
        order = runs[slice_index % len(runs) :] + runs[: slice_index % len(runs)]  # rotate: no run always first
        for name, model, callback in order:
            set_global_rng_state(rng_states[name])
            start, cpu_start = time.perf_counter(), cpu_time()
            model.learn(ticks * n_agents, reset_num_timesteps=done == 0, callback=callback)
            seconds[name] += time.perf_counter() - start
            cpu_seconds[name] += cpu_time() - cpu_start  # the workers are joined at training end: counted
            rng_states[name] = global_rng_state()
        done += ticks
        slice_index += 1
    print(
        f"== 1. overhead on {args.env}: {args.ticks} training ticks, {args.n_envs} world(s), seed {args.seed}, "
        f"slices of {args.slice} ticks"
    )
    print(f"{'':10s}{'wall s':>9s}{'CPU s':>9s}{'wall/GDQ':>10s}{'CPU/GDQ':>9s}{'episodes':>10s}{'EPS rounds':>12s}")
    for name, model, callback in runs:
        n_rounds = (
            ""
            if callback is None
            else f"{callback.n_rounds} ({sum(r['wall_time'] for r in callback.history if not r['skipped']):.1f} s)"
        )
        print(
            f"{name:10s}{seconds[name]:9.1f}{cpu_seconds[name]:9.1f}{seconds[name] / seconds['GDQ']:10.3f}"
            f"{cpu_seconds[name] / cpu_seconds['GDQ']:9.3f}{model._episode_num:10d}{n_rounds:>12s}"
        )
    print("target: EPS-GDQ / GDQ <= 1.10 (wall)")
    callback = runs[1][2]
    assert callback is not None
    rounds = [record for record in callback.history if not record["skipped"]]
    if rounds:
        print(
            f"EPS-GDQ: {len(rounds)} rounds ({callback.n_skipped_rounds} skipped), {callback.eps_ticks} evaluation "
            f"ticks, {np.mean([r['wall_time'] for r in rounds]):.2f} s per round; winners {[r['winner'] for r in rounds]}"
        )
    return runs[1][1], callback


def round_seconds(model: GDQ, args: argparse.Namespace) -> None:
    """Part 2: time full EPS rounds (population 10) with the envs in workers and in the main process."""
    snapshot = copy.deepcopy(model.policy.state_dict())
    n_agents = model.n_agents
    configs: list[tuple[str, dict[str, Any]]] = [
        ("workers, batched forward", {}),
        ("main process, batched forward", {"n_workers": 0}),
    ]
    times: dict[str, list[float]] = {name: [] for name, _ in configs}
    ticks: dict[str, list[int]] = {name: [] for name, _ in configs}
    for _ in range(args.repeats):
        for name, kwargs in configs:
            model.policy.load_state_dict(snapshot)
            # period 1 tick: a round at every rollout end, i.e. rounds_per_config rounds. Algorithm 1's settings
            # (population 10, 2 episodes, no budget, no reevaluation) keep the rounds comparable with the table.
            callback = EvolutionCallback.paper(
                eval_env_id=eps_env_id_for(args.env),
                period=1,
                period_unit="ticks",
                seed=args.seed,
                **kwargs,
            )
            # agent-steps of one rollout (SB3 turned train_freq into a TrainFreq): one round each
            rollout = model.train_freq.frequency * n_agents  # type: ignore[union-attr]
            model.learn(args.rounds_per_config * rollout, callback=callback, reset_num_timesteps=False)
            for record in callback.history:
                if not record["skipped"]:
                    times[name].append(record["wall_time"])
                    ticks[name].append(int(np.sum(record["episode_lengths"])))
    n_workers = min(os.cpu_count() or 1, 11)
    print(f"== 2. seconds per EPS round, population 10 (+ copy 0), 2 episodes each, {n_workers} worker(s)")
    print(f"{'':40s}{'s/round':>10s}{'+/-':>8s}{'eval ticks':>12s}{'rounds':>8s}")
    for name, _ in configs:
        print(
            f"{name:40s}{np.mean(times[name]):10.2f}{np.std(times[name]):8.2f}"
            f"{np.mean(ticks[name]):12.0f}{len(times[name]):8d}"
        )


def mutation_size(model: GDQ, callback: EvolutionCallback, args: argparse.Namespace) -> None:
    """Part 3: the effect of one mutation on the greedy policy, for a grid of sigma."""
    buffer = model.replay_buffer
    assert buffer is not None
    size = buffer.size()
    visited = buffer.observations[:size][buffer.alive[:size] > 0]
    rng = np.random.default_rng(args.seed)
    q_net = model.policy.q_net
    sensitivity_batch = th.as_tensor(visited[rng.choice(len(visited), callback.settings.sensitivity_batch_size)])
    test = th.as_tensor(visited[rng.choice(len(visited), min(2000, len(visited)), replace=False)])
    omega = output_sensitivity(q_net, sensitivity_batch)
    theta = network_parameters(q_net)
    forward = PopulationForward(q_net)
    with th.no_grad():
        q_values = q_net(test)
    print(f"== 3. one mutation's effect on {len(test)} visited observations (20 mutants per sigma)")
    print(f"{'sigma':>8s}{'safe: actions changed':>24s}{'mean |dQ|':>11s}{'gaussian: changed':>20s}{'mean |dQ|':>11s}")
    for sigma in (0.0003, 0.001, 0.003, 0.01, 0.03, 0.1):
        row = f"{sigma:8.4f}"
        for sensitivities in ([omega], None):
            generator = th.Generator().manual_seed(args.seed)
            population = mutate_population(theta, 20, sigma, generator, sensitivities)
            forward.load(population)
            outputs = forward(test.unsqueeze(0).expand(21, -1, -1))[1:]
            changed = (outputs.argmax(-1) != q_values.argmax(-1)).float().mean().item()
            row += f"{100 * changed:22.0f} %{(outputs - q_values).abs().mean().item():11.2f}"
        print(row)
    print(f"(|Q| of the network: mean {q_values.abs().mean().item():.1f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="MultiRobotNav-4-v0")
    parser.add_argument("--ticks", type=int, default=20_000, help="training ticks per algorithm")
    parser.add_argument("--warmup", type=int, default=1_000, help="untimed ticks of a throw-away GDQ first")
    parser.add_argument("--slice", type=int, default=10_000, help="ticks per alternating slice")
    parser.add_argument("--n-envs", type=int, default=1, help="worlds per vector env")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=2, help="alternations of the round-time configurations")
    parser.add_argument("--rounds-per-config", type=int, default=2)
    args = parser.parse_args()
    th.set_num_threads(1)
    print(f"torch threads 1, CPU cores {os.cpu_count()}, load average {os.getloadavg()[0]:.1f}")
    model, callback = overhead(args)
    round_seconds(model, args)
    mutation_size(model, callback, args)


if __name__ == "__main__":
    main()
