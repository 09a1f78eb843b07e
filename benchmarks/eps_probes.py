"""Probes behind the EPS defaults (issue 10), each a few minutes in one process on a saved multi-robot model.

``python benchmarks/eps_probes.py MODEL.zip --probe NAME``, NAME one of:

- ``mutation``: on greedy-policy observations of ``MultiRobotNav-4-v0`` (the states the buffer holds), the share
  of greedy actions the mutants change and their mean |dQ|: Algorithm 1's safe mutation (sigma 0.001, floor 0.01,
  clip 0.2), the same with the value stream frozen, and the scale ``calibrate_scale`` finds for target shares.
- ``worlds``: copy 0 (the model itself) played greedily in the EPS worlds (bars / pillars / open, 600- and
  400-tick limits) on the same seeds: success, collision and timeout rates, mean return and length; beside the
  model's greedy team success in ``MultiRobotNav-4-v0``.
- ``quality``: how good the mutants are, measured on many episodes: for target shares of changed greedy actions,
  every mutant and copy 0 on ``--episodes`` common-random-number episodes; the distribution of the mutants' gains
  over copy 0 (what a selection on few episodes tries to find).
- ``acceptance``: rounds as the defaults run them (calibrated mutants, outcome fitness, ``--episode-counts``
  episodes, ``min_gain`` 0.05, copy 0 and the winner reevaluated on ``--fresh`` episodes), and every winner's true
  gain estimated on ``--truth`` further episodes: do accepted winners beat copy 0, and rejected ones not?
- ``alone``: copy 0 (the model with its lidar mask, and without) played greedily by a robot alone in single-robot
  rooms of ``--level-set`` (``SingleRobotNav-v0``, scenario ``rooms``) with the world options of the model's
  ``config.yml`` beside it: what the ``outcome`` fitness of EPS among rooms has to select on.
- ``margins``: EPS rounds without crossover (calibrated mutants, outcome fitness) for several numbers of
  episodes: how often a mutant wins, by how much, and whether its gain holds on fresh episodes (copy 0 and the
  winner replayed on ``--fresh`` new episodes).

Prints Markdown tables; ``docs/results/eps_probes.md`` holds the figures of the committed run.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

import envs  # noqa: F401
from sb3_eps import GDQ, make_vec_env
from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.eps import eps_env_id_for
from sb3_eps.eps.evaluation import InProcessEnvPool, evaluate_population
from sb3_eps.eps.mutations import (
    calibrate_scale,
    evolved_parameter_names,
    mutation_directions,
    network_parameters,
    output_sensitivity,
    policy_change,
    population_from_directions,
    population_outputs,
    select_best,
)

TRAIN_ENV = "MultiRobotNav-4-v0"
EPS_ENV = eps_env_id_for(TRAIN_ENV)


def visited_observations(model: GDQ, n_ticks: int, seed: int) -> th.Tensor:
    """Agent observations met by the model's greedy policy with 5 % random actions (what its buffer would hold)."""
    venv = make_vec_env(TRAIN_ENV, n_envs=1, seed=seed)
    rng = np.random.default_rng(seed)
    observations = venv.reset()
    seen = []
    for _ in range(n_ticks):
        seen.append(observations.copy())
        actions, _ = model.predict(observations, deterministic=True)
        explore = rng.random(len(actions)) < 0.05
        actions[explore] = rng.integers(20, size=int(explore.sum()))
        observations, _, _, _ = venv.step(actions)
    venv.close()
    return th.as_tensor(np.concatenate(seen), dtype=th.float32)


def probe_mutation(model: GDQ, args: argparse.Namespace) -> None:
    q_net = model.policy.q_net
    observations = visited_observations(model, args.ticks, args.seed)
    batch = observations[th.randperm(len(observations), generator=th.Generator().manual_seed(0))[:128]]
    theta = network_parameters(q_net)
    omega = output_sensitivity(q_net, batch)
    with th.no_grad():
        mean_abs_q = float(q_net(observations).abs().mean())
    print(f"{len(observations)} observations, mean |Q| {mean_abs_q:.3f}\n")
    print("| mutation | evolved weights | scale | greedy actions changed | mean abs dQ |")
    print("|---|---|---|---|---|")
    groups = {"all": [], "trunk + advantage": ["value_stream"]}
    for label, frozen in groups.items():
        names = evolved_parameter_names(q_net, frozen)
        n_weights = sum(theta[name].numel() for name in names)
        directions = mutation_directions(theta, args.mutants, th.Generator().manual_seed(1), [omega], 0.01, names)
        population = population_from_directions(theta, directions, 0.001, 0.2)
        flips, dq = policy_change(population_outputs(q_net, population, observations))
        print(
            f"| paper safe (sigma 0.001, floor 0.01, clip 0.2) | {label} ({n_weights}) | 0.001 | "
            f"{100 * flips[1:].mean():.1f} % | {dq[1:].mean():.4f} |"
        )
    names = evolved_parameter_names(q_net, ["value_stream"])
    directions = mutation_directions(theta, args.mutants, th.Generator().manual_seed(1), [omega], 0.01, names)
    for target in (0.02, 0.05, 0.1, 0.2):

        def share_at(scale: float) -> float:
            population = population_from_directions(theta, directions, scale, 0.2)
            return float(policy_change(population_outputs(q_net, population, batch))[0][1:].mean())

        start = time.perf_counter()
        scale, share = calibrate_scale(share_at, target, 0.001)
        seconds = time.perf_counter() - start
        population = population_from_directions(theta, directions, scale, 0.2)
        flips, dq = policy_change(population_outputs(q_net, population, observations))
        print(
            f"| calibrated to {100 * target:.0f} % (batch of 128: {100 * share:.1f} %, {seconds:.2f} s) | "
            f"trunk + advantage | {scale:.2e} | {100 * flips[1:].mean():.1f} % | {dq[1:].mean():.4f} |"
        )
    value_only = {  # the value stream alone, paper step: what fitness cannot see
        name: stacked if name.startswith("value_stream") else theta[name].unsqueeze(0).expand_as(stacked).clone()
        for name, stacked in population_from_directions(
            theta,
            mutation_directions(theta, args.mutants, th.Generator().manual_seed(2), [omega], 0.01),
            0.001,
            0.2,
        ).items()
    }
    flips, dq = policy_change(population_outputs(q_net, value_only, observations))
    value = q_net.value_stream
    with th.no_grad():
        before = value(q_net.trunk(observations)).squeeze(-1)
    print(
        f"| paper safe, value stream only | value_stream | 0.001 | {100 * flips[1:].mean():.1f} % | "
        f"{dq[1:].mean():.4f} (= mean abs dV; mean abs V {float(before.abs().mean()):.3f}) |"
    )


def play(
    q_net: th.nn.Module, kwargs: dict[str, Any], seeds: list[int], safety_margin: float | None = None
) -> dict[str, float]:
    """Copy 0 alone, greedy (through a lidar mask of ``safety_margin``), on the given seeds of the EPS world ``kwargs``."""
    pool = InProcessEnvPool(EPS_ENV, kwargs, 1, len(seeds), q_net, safety_margin=safety_margin)
    try:
        theta = {name: value.unsqueeze(0) for name, value in network_parameters(q_net).items()}
        result = evaluate_population(pool, theta, seeds, timeout=600, fitness="outcome")
    finally:
        pool.close()
    outcomes = result.outcomes[0]
    return {
        "success": float((outcomes == 1).mean()),
        "collision": float((outcomes == -1).mean()),
        "timeout": float((outcomes == 0).mean()),
        "return": float(result.returns[0].mean()),
        "length": float(result.lengths[0].mean()),
        "outcome_fitness": float(result.fitness[0]),
    }


def probe_alone(model: GDQ, args: argparse.Namespace) -> None:
    import yaml

    from sb3_eps.eps.callback import SHARED_WORLD_OPTIONS

    config = Path(args.model).parent / "config.yml"
    entry = next(iter(yaml.safe_load(config.read_text()).values())) if config.is_file() else {}
    trained = entry.get("env_kwargs") or {}
    world = {key: value for key, value in trained.items() if key in SHARED_WORLD_OPTIONS}
    world.update(scenario="rooms", level_set=args.level_set, action_repeat=trained.get("action_repeat", 1))
    seeds = [int(seed) for seed in np.random.default_rng(args.seed).integers(2**31 - 1, size=args.episodes)]
    margin = getattr(model.policy, "safety_margin", None)
    arms = ([("with its mask", margin)] if margin is not None else []) + [("bare network", None)]
    print(f"{EPS_ENV} {world}, {args.episodes} episodes, seed {args.seed}\n")
    print("| copy 0 | success | collision | timeout | mean return | mean length (ticks) | outcome fitness |")
    print("|---|---|---|---|---|---|---|")
    for label, with_margin in arms:
        row = play(model.policy.q_net, world, seeds, with_margin)
        print(
            f"| {label} | {100 * row['success']:.0f} % | {100 * row['collision']:.0f} % | {100 * row['timeout']:.0f} % | "
            f"{row['return']:.2f} | {row['length']:.0f} | {row['outcome_fitness']:.3f} |"
        )


def probe_worlds(model: GDQ, args: argparse.Namespace) -> None:
    team = evaluate_team(model, TRAIN_ENV, args.episodes, n_envs=4, seed=10_000 + args.seed)
    print(
        f"{TRAIN_ENV}, greedy, {args.episodes} episodes: team success {100 * team['success_rate']:.0f} %, "
        f"collision {100 * team['collision_rate']:.0f} %\n"
    )
    seeds = [int(seed) for seed in np.random.default_rng(args.seed).integers(2**31 - 1, size=args.episodes)]
    print("| EPS world | success | collision | timeout | mean return | mean length |")
    print("|---|---|---|---|---|---|")
    for scenario in ("eps", "eps_pillars"):
        for limit in (600, 400):
            row = play(model.policy.q_net, {"scenario": scenario, "max_episode_steps": limit}, seeds)
            print(
                f"| {scenario}, {limit} ticks | {100 * row['success']:.0f} % | {100 * row['collision']:.0f} % | "
                f"{100 * row['timeout']:.0f} % | {row['return']:.2f} | {row['length']:.0f} |"
            )


def probe_margins(model: GDQ, args: argparse.Namespace) -> None:
    q_net = model.policy.q_net
    observations = visited_observations(model, args.ticks, args.seed)
    rng = np.random.default_rng(args.seed)
    theta = network_parameters(q_net)
    names = evolved_parameter_names(q_net, ["value_stream"])
    kwargs = {"scenario": "eps_pillars", "max_episode_steps": 400}
    print("| episodes | round | winner | selection gain | fresh gain (winner - copy 0) | round ticks |")
    print("|---|---|---|---|---|---|")
    summary = []
    for n_episodes in args.episode_counts:
        pool = InProcessEnvPool(EPS_ENV, kwargs, args.mutants + 1, n_episodes, q_net)
        fresh_pool = InProcessEnvPool(EPS_ENV, kwargs, 2, args.fresh, q_net)
        gains = []
        for round_index in range(args.rounds):
            batch = observations[th.as_tensor(rng.choice(len(observations), 128, replace=False))]
            omega = output_sensitivity(q_net, batch)
            generator = th.Generator().manual_seed(int(rng.integers(2**31)))
            directions = mutation_directions(theta, args.mutants, generator, [omega], 0.01, names)

            def share_at(scale: float, directions: Any = directions, batch: th.Tensor = batch) -> float:
                population = population_from_directions(theta, directions, scale, 0.2)
                return float(policy_change(population_outputs(q_net, population, batch))[0][1:].mean())

            scale, _ = calibrate_scale(share_at, 0.1, 0.001)
            population = population_from_directions(theta, directions, scale, 0.2)
            seeds = [int(seed) for seed in rng.integers(2**31 - 1, size=n_episodes)]
            result = evaluate_population(pool, population, seeds, 600, "outcome")
            winner = select_best(result.fitness)
            gain = float(result.fitness[winner] - result.fitness[0])
            ticks = int(result.lengths.sum())
            fresh_gain = float("nan")
            if winner != 0:
                pair = {name: th.stack([stacked[0], stacked[winner]]) for name, stacked in population.items()}
                fresh_seeds = [int(seed) for seed in rng.integers(2**31 - 1, size=args.fresh)]
                fresh = evaluate_population(fresh_pool, pair, fresh_seeds, 600, "outcome")
                fresh_gain = float(fresh.fitness[1] - fresh.fitness[0])
            gains.append((winner, gain, fresh_gain, ticks))
            print(f"| {n_episodes} | {round_index} | {winner} | {gain:.3f} | {fresh_gain:.3f} | {ticks} |")
        pool.close()
        fresh_pool.close()
        summary.append((n_episodes, gains))
    print("\n| episodes | rounds | a mutant won | mean selection gain | mean fresh gain | fresh gain > 0 | ticks/round |")
    print("|---|---|---|---|---|---|---|")
    for n_episodes, gains in summary:
        won = [g for g in gains if g[0] != 0]
        fresh = [g[2] for g in won]
        print(
            f"| {n_episodes} | {len(gains)} | {len(won)} | {np.mean([g[1] for g in won]) if won else float('nan'):.3f} | "
            f"{np.mean(fresh) if fresh else float('nan'):.3f} | {sum(f > 0 for f in fresh)} of {len(fresh)} | "
            f"{np.mean([g[3] for g in gains]):.0f} |"
        )


def calibrated_population(
    q_net: th.nn.Module, observations: th.Tensor, rng: np.random.Generator, n_mutants: int, target: float
) -> tuple[dict[str, th.Tensor], float]:
    """A round's population as the default EPS makes it: safe directions, value stream frozen, calibrated scale."""
    theta = network_parameters(q_net)
    names = evolved_parameter_names(q_net, ["value_stream"])
    batch = observations[th.as_tensor(rng.choice(len(observations), 128, replace=False))]
    omega = output_sensitivity(q_net, batch)
    generator = th.Generator().manual_seed(int(rng.integers(2**31)))
    directions = mutation_directions(theta, n_mutants, generator, [omega], 0.01, names)

    def share_at(scale: float) -> float:
        population = population_from_directions(theta, directions, scale, 0.2)
        return float(policy_change(population_outputs(q_net, population, batch))[0][1:].mean())

    scale, _ = calibrate_scale(share_at, target, 0.001)
    return population_from_directions(theta, directions, scale, 0.2), scale


def probe_quality(model: GDQ, args: argparse.Namespace) -> None:
    q_net = model.policy.q_net
    observations = visited_observations(model, args.ticks, args.seed)
    rng = np.random.default_rng(args.seed)
    kwargs = {"scenario": "eps_pillars", "max_episode_steps": 400}
    pool = InProcessEnvPool(EPS_ENV, kwargs, args.mutants + 1, args.episodes, q_net)
    print(
        f"| target share | rounds x mutants | copy 0 success | mutants' success (mean) | gain: mean | best | "
        f"mutants with gain >= {1 / args.episodes:.3f} | ticks |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for target in args.targets:
        gains, copy0, mutants, ticks = [], [], [], 0
        for _ in range(args.rounds):
            population, _ = calibrated_population(q_net, observations, rng, args.mutants, target)
            seeds = [int(seed) for seed in rng.integers(2**31 - 1, size=args.episodes)]
            result = evaluate_population(pool, population, seeds, 900, "outcome")
            gains.extend((result.fitness[1:] - result.fitness[0]).tolist())
            success = result.successes.mean(axis=1)
            copy0.append(success[0])
            mutants.extend(success[1:].tolist())
            ticks += int(result.lengths.sum())
        gains_array = np.array(gains)
        print(
            f"| {100 * target:.0f} % | {args.rounds} x {args.mutants} | {100 * np.mean(copy0):.0f} % | "
            f"{100 * np.mean(mutants):.0f} % | {gains_array.mean():.3f} | {gains_array.max():.3f} | "
            f"{int((gains_array >= 1 / args.episodes - 1e-9).sum())} of {gains_array.size} | {ticks} |"
        )
    pool.close()


def probe_acceptance(model: GDQ, args: argparse.Namespace) -> None:
    q_net = model.policy.q_net
    observations = visited_observations(model, args.ticks, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    kwargs = {"scenario": "eps_pillars", "max_episode_steps": 400}
    n_episodes = args.episode_counts[0]
    pool = InProcessEnvPool(EPS_ENV, kwargs, args.mutants + 1, n_episodes, q_net)
    pair_pools = {count: InProcessEnvPool(EPS_ENV, kwargs, 2, count, q_net) for count in (args.fresh, args.truth)}

    def pair_gain(population: dict[str, th.Tensor], winner: int, count: int) -> float:
        pair = {name: th.stack([stacked[0], stacked[winner]]) for name, stacked in population.items()}
        seeds = [int(seed) for seed in rng.integers(2**31 - 1, size=count)]
        fitness = evaluate_population(pair_pools[count], pair, seeds, 900, "outcome").fitness
        return float(fitness[1] - fitness[0])

    print(f"| round | winner | selection gain ({n_episodes} ep.) | fresh gain ({args.fresh} ep.) | accepted | "
          f"true gain ({args.truth} ep.) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    rows = []
    for round_index in range(args.rounds):
        population, _ = calibrated_population(q_net, observations, rng, args.mutants, 0.1)
        seeds = [int(seed) for seed in rng.integers(2**31 - 1, size=n_episodes)]
        result = evaluate_population(pool, population, seeds, 900, "outcome")
        winner = select_best(result.fitness)
        gain = float(result.fitness[winner] - result.fitness[0])
        if winner == 0:
            print(f"| {round_index} | 0 | 0 | | no | |")
            continue
        fresh = pair_gain(population, winner, args.fresh) if gain > 0.05 else float("nan")
        accepted = gain > 0.05 and fresh > 0.05
        truth = pair_gain(population, winner, args.truth)
        rows.append((accepted, gain > 0.05, truth))
        print(f"| {round_index} | {winner} | {gain:.3f} | {fresh:.3f} | {'yes' if accepted else 'no'} | {truth:.3f} |")
    for pool_ in (pool, *pair_pools.values()):
        pool_.close()
    # Beyond 0.02 a gain is at least one episode ending better on balance, not the return's tie-break alone.
    print("\n| winners | count | mean true gain | true gain > 0.02 | true gain < -0.02 |")
    print("|---|---|---|---|---|")
    groups = {
        "all winners (paper rule: any gain)": rows,
        "selection gain > 0.05": [row for row in rows if row[1]],
        "accepted (also fresh gain > 0.05)": [row for row in rows if row[0]],
        "rejected": [row for row in rows if not row[0]],
    }
    for label, group in groups.items():
        truths = [row[2] for row in group]
        mean = f"{np.mean(truths):.3f}" if truths else "-"
        better, worse = sum(t > 0.02 for t in truths), sum(t < -0.02 for t in truths)
        print(f"| {label} | {len(group)} | {mean} | {better} | {worse} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="a GDQ model of MultiRobotNav-4-v0 (.zip; alone: any TurtleBot3 model)")
    parser.add_argument("--probe", choices=("mutation", "worlds", "quality", "acceptance", "margins", "alone"), required=True)
    parser.add_argument("--level-set", default="train", help="(alone) the rooms' level set")
    parser.add_argument("--targets", type=float, nargs="+", default=[0.05, 0.1, 0.3], help="(quality)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ticks", type=int, default=500, help="ticks of greedy play for the observations")
    parser.add_argument("--mutants", type=int, default=6)
    parser.add_argument("--episodes", type=int, default=50, help="episodes per world (worlds)")
    parser.add_argument("--episode-counts", type=int, nargs="+", default=[2, 4, 8], help="(margins)")
    parser.add_argument("--rounds", type=int, default=5, help="rounds per episode count (margins)")
    parser.add_argument("--fresh", type=int, default=16, help="fresh episodes of copy 0 and the winner (margins, acceptance)")
    parser.add_argument("--truth", type=int, default=24, help="episodes estimating a winner's true gain (acceptance)")
    args = parser.parse_args()
    th.set_num_threads(1)
    th.manual_seed(args.seed)
    model = GDQ.load(args.model, env=None, device="cpu", buffer_size=1)
    probes = {
        "mutation": probe_mutation,
        "worlds": probe_worlds,
        "quality": probe_quality,
        "acceptance": probe_acceptance,
        "margins": probe_margins,
        "alone": probe_alone,
    }
    probes[args.probe](model, args)


if __name__ == "__main__":
    main()
