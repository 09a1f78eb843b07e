"""Training throughput of SB3's own DQN and of IQL, GDQ, QMIX, VDN, measured side by side in one run.

Same env (``MultiRobotNav-4-v0``, 2 worlds by default), same trunk sizes, same train frequency and the same
number of agent transitions per gradient step (SB3 DQN's batch = our rows x agents). Every algorithm runs
``--repeats`` times, interleaved (A B C D E, A B C D E, ...), so background load on a shared machine hits all
of them alike; the median wall time per agent-step is reported with its ratio to SB3 DQN. Targets (issue 3):
IQL <= 1.2x, GDQ and VDN <= 1.3x, QMIX <= 1.5x SB3 DQN's wall time per step.

    python benchmarks/train_throughput.py --steps 20000 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import torch as th
from stable_baselines3 import DQN

import envs  # noqa: F401
from sb3_eps import GDQ, IQL, QMIX, VDN, make_vec_env

TARGETS = {"IQL": 1.2, "GDQ": 1.3, "VDN": 1.3, "QMIX": 1.5}


def build(name: str, env_id: str, n_envs: int, rows: int, learning_starts: int) -> Any:
    venv = make_vec_env(env_id, n_envs=n_envs, seed=0)
    common = {"learning_starts": learning_starts, "train_freq": 4, "gradient_steps": 1, "seed": 0, "buffer_size": 50_000}
    if name == "SB3-DQN":
        # SB3's MLP with the same hidden sizes as our trunk + one stream layer.
        return DQN(
            "MlpPolicy",
            venv,
            batch_size=rows * venv.n_agents,
            policy_kwargs={"net_arch": [128, 64, 64]},
            **common,
        )
    algorithm = {"IQL": IQL, "GDQ": GDQ, "QMIX": QMIX, "VDN": VDN, "IQL-noPER-1step": IQL}[name]
    extra = {"prioritized_replay": False, "n_steps": 1} if name.endswith("noPER-1step") else {}
    return algorithm("MlpPolicy", venv, batch_size=rows, **common, **extra)


def time_per_step(name: str, args: argparse.Namespace) -> float:
    model = build(name, args.env, args.n_envs, args.rows, args.learning_starts)
    model.learn(args.learning_starts + 1_000)  # warm-up: fill the buffer, first updates, allocations
    start = time.perf_counter()
    model.learn(args.steps, reset_num_timesteps=False)
    elapsed = time.perf_counter() - start
    model.env.close()
    return elapsed / args.steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--env", default="MultiRobotNav-4-v0")
    parser.add_argument("--n-envs", type=int, default=2)
    parser.add_argument("--rows", type=int, default=64, help="our batch in joint rows (SB3 DQN: rows x agents)")
    parser.add_argument("--steps", type=int, default=20_000, help="timed agent-steps per run")
    parser.add_argument("--learning-starts", type=int, default=2_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--algos", nargs="+", default=["SB3-DQN", "IQL", "GDQ", "QMIX", "VDN", "IQL-noPER-1step"])
    args = parser.parse_args()
    th.set_num_threads(1)
    samples: dict[str, list[float]] = {name: [] for name in args.algos}
    for repeat in range(args.repeats):
        for name in args.algos:
            samples[name].append(time_per_step(name, args))
            print(f"repeat {repeat} {name}: {1 / samples[name][-1]:.0f} agent-steps/s", flush=True)
    baseline = statistics.median(samples["SB3-DQN"]) if "SB3-DQN" in samples else None
    print(
        f"\n{args.env}, {args.n_envs} worlds, batch {args.rows} rows, {args.steps} timed agent-steps, median of {args.repeats}"
    )
    print(f"{'algorithm':<18}{'agent-steps/s':>14}{'time/step vs SB3 DQN':>22}{'target':>8}")
    for name, values in samples.items():
        median = statistics.median(values)
        ratio = f"{median / baseline:.2f}x" if baseline else "-"
        target = f"<={TARGETS[name]}x" if name in TARGETS else ""
        print(f"{name:<18}{1 / median:>14.0f}{ratio:>22}{target:>8}")


if __name__ == "__main__":
    main()
