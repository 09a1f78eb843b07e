"""Short robot runs: the online network against weight averages with different warm-ups, read off one run.

Each average follows ``avg <- (1 - r) avg + r theta`` after the n-th gradient step with ``r = max(tau, (eta + 1) /
(n + eta))`` (polynomial-decay averaging, Shamir & Zhang, ICML 2013; ``eta`` 0 is the mean of all weights so far).
The model trains without an average of its own, so its run is the package defaults' training run; at the end the
online network and every average are evaluated greedily on the same evaluation worlds. Amendment 2
of rule T17 (``docs/results/baselines/gdq4_weight_average_check/rules.md``): it chose the warm-up of
``weight_average_tau``::

    python benchmarks/average_warmup_check.py --seeds 189 190 191 --ticks 20000 \
        --out docs/results/baselines/gdq2_average_warmup/records.jsonl
"""

from __future__ import annotations

import argparse
import json
import pathlib

import torch as th
from stable_baselines3.common.callbacks import BaseCallback

import envs  # noqa: F401
from sb3_eps import GDQ, make_vec_env
from sb3_eps.common.evaluation import evaluate_team, world_record
from sb3_eps.common.policies import weight_average_rate
from sb3_eps.common.utils import polyak_update_tensors_


class WarmupAverages(BaseCallback):
    """Keeps one average of ``policy.q_net``'s weights per ``eta``, stepped once per gradient step."""

    def __init__(self, tau: float, etas: list[int]) -> None:
        super().__init__()
        self.tau, self.etas = tau, etas

    def _on_training_start(self) -> None:
        self.averages = {eta: [p.detach().clone() for p in self.model.policy.q_net.parameters()] for eta in self.etas}
        self.seen = 0

    def _on_step(self) -> bool:
        while self.seen < self.model._n_updates:
            self.seen += 1
            params = [p.detach() for p in self.model.policy.q_net.parameters()]
            for eta, average in self.averages.items():
                polyak_update_tensors_(average, params, [], [], weight_average_rate(self.tau, self.seen, eta))
        return True


def success(model: GDQ, env_id: str, episodes: int, seed: int) -> float:
    """:return: greedy team success of ``model`` on the evaluation worlds of ``seed``."""
    return float(evaluate_team(model, env_id, episodes, n_envs=4, seed=10_000 + seed)["success_rate"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="MultiRobotNav-2-v0")
    parser.add_argument("--seeds", type=int, nargs="+", default=[189, 190, 191])
    parser.add_argument("--ticks", type=int, default=20_000)
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--tau", type=float, default=2e-4)
    parser.add_argument("--etas", type=int, nargs="+", default=[0, 3, 7])
    parser.add_argument("--out", type=pathlib.Path, required=True, help="JSON-lines file, one row per seed")
    args = parser.parse_args()
    th.set_num_threads(1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        venv = make_vec_env(args.env, n_envs=4, seed=seed)
        model = GDQ("MlpPolicy", venv, seed=seed, policy_kwargs={"weight_average_tau": None})
        callback = WarmupAverages(args.tau, args.etas)
        model.learn(args.ticks * venv.n_agents, callback=callback)
        venv.close()

        row = {"env": args.env, "seed": seed, "ticks": args.ticks, "n_updates": model._n_updates, "tau": args.tau}
        row |= world_record(args.env, None, args.episodes)  # every success below: greedy episodes of this world
        row["online"] = success(model, args.env, args.episodes, seed)
        with th.no_grad():
            for eta, average in callback.averages.items():
                for param, value in zip(model.policy.q_net.parameters(), average, strict=True):
                    param.copy_(value)
                row[f"eta{eta}"] = success(model, args.env, args.episodes, seed)
        print(json.dumps(row), flush=True)
        with args.out.open("a") as file:
            file.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
