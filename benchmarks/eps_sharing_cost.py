"""What EPS experience sharing costs in a round: the same population played with and without recording, side by side.

A GDQ model (package defaults) trains briefly on
``MultiRobotNav-4-v0``; then, alternating, one round's population (copy 0 and ``--mutants`` mutants at a small
Gaussian scale, ``--episodes`` common-random-number episodes each) is played by the same kind of pool without
recording, and with recording plus :func:`research.eps_variants.share_episodes` into the model's buffer. Printed: the
seconds of each, the ticks, the rows written and the ratio (with sharing / without). Example::

    python benchmarks/eps_sharing_cost.py --train-ticks 5000 --repeats 3
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch as th

import envs  # noqa: F401
from research.eps_variants import RecordingBlock, share_episodes
from sb3_eps import GDQ, make_vec_env
from sb3_eps.eps import InProcessEnvPool, SubprocessEnvPool, evaluate_population
from sb3_eps.eps.evaluation import EvaluationBlock
from sb3_eps.eps.mutations import mutate_population, network_parameters

ENV_ID = "MultiRobotNav-4-v0"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--train-ticks", type=int, default=5_000, help="training ticks before the rounds")
    parser.add_argument("--mutants", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--n-workers", type=int, default=0, help="0: in the main process")
    args = parser.parse_args()
    th.set_num_threads(1)
    venv = make_vec_env(ENV_ID, n_envs=4, seed=0)
    model = GDQ("MlpPolicy", venv, seed=0, learning_starts=1_000)
    model.learn(args.train_ticks * venv.n_agents)
    network = model.policy.q_net
    population = mutate_population(network_parameters(network), args.mutants, 1e-3, th.Generator().manual_seed(0), None)
    n_individuals = args.mutants + 1
    pools = {}
    for record, block_class in ((None, EvaluationBlock), ("ticks", RecordingBlock)):
        if args.n_workers:
            pools[record] = SubprocessEnvPool(
                ENV_ID, {}, n_individuals, args.episodes, network, n_workers=args.n_workers, block_class=block_class
            )
        else:
            pools[record] = InProcessEnvPool(ENV_ID, {}, n_individuals, args.episodes, network, block_class=block_class)
    times: dict[str | None, list[float]] = {None: [], "ticks": []}
    try:
        for repeat in range(args.repeats):
            seeds = [100 * repeat + j for j in range(args.episodes)]
            for record, pool in pools.items():
                start = time.perf_counter()
                result = evaluate_population(pool, population, seeds, timeout=600)
                rows = share_episodes(model, result.episodes) if record else 0
                times[record].append(time.perf_counter() - start)
                ticks = int(result.lengths.sum())
                print(f"repeat {repeat} record={record}: {times[record][-1]:.2f} s, {ticks} ticks, {rows} rows")
    finally:
        for pool in pools.values():
            pool.close()
    plain, shared = np.array(times[None]), np.array(times["ticks"])
    print(
        f"without sharing {plain.mean():.2f} s, with sharing {shared.mean():.2f} s per round "
        f"(ratio {np.mean(shared / plain):.3f}, {args.repeats} repeats, n_workers={args.n_workers})"
    )


if __name__ == "__main__":
    main()
