"""One training run per seed, evaluated greedily with the online network and with moving averages of its weights.

``benchmarks/learning_check.py`` with one addition: besides the model's own network, the run keeps an exponential
moving average of the agent network's weights for each ``--average-taus`` value (``avg <- (1 - r) avg + r theta``
after the n-th gradient step, ``r = max(tau, 4 / (n + 3))``, ``sb3_eps.common.policies.weight_average_rate``: what
``policy_kwargs=dict(weight_average_tau=tau)`` keeps; until 2026-12-02 both used ``r = tau`` from the
initial weights, which the records of T12-T17 hold), and at every evaluation point from ``--average-from`` on (and at ``--average-also``) it evaluates each
average on the same evaluation worlds as the model. The averages only read the weights, so the training run is
the one ``learning_check.py`` makes with the same arguments, and each comparison is paired within one run.
Rules T12/T13 (``docs/results/baselines/gdq4_weight_average_screen/rules.md``); findings:
``docs/results/gdq_weight_average.md``.

The model's records are written as ``learning_check.py`` writes them; each average's go to
``<out>/ema<tau>/<same file name>``, with ``n_updates`` (gradient steps so far). Every other argument is
``learning_check.py``'s::

    python benchmarks/weight_average_check.py --average-taus 5e-4 2e-4 -- \
        --algo gdq --env MultiRobotNav-4-v0 --ticks 150000 --seeds 163 --eval-every 10000 --eval-episodes 50

A seed whose run restarts (its record file had no final evaluation) starts its average files afresh too. The model
itself must act greedily with its online network: GDQ keeps a weight average by default (rule
T17), so a GDQ run here takes ``--hyperparams '{"policy_kwargs": {"weight_average_tau": null}}'``; the script says so
and stops before it trains otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time
from typing import Any

import torch as th

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import learning_check

from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.common.policies import weight_average_rate
from sb3_eps.common.utils import polyak_update_tensors_


def average_path(path: pathlib.Path, tau: float) -> pathlib.Path:
    """:return: where the records of the average with ``tau`` go, beside the model's ``path``."""
    return path.parent / f"ema{tau:g}" / path.name


def averaged_eval_class(taus: list[float], average_from: int, also: list[int]) -> type:
    """:return: ``learning_check.PeriodicTeamEval`` that also keeps and evaluates the weight averages."""

    class AveragedTeamEval(learning_check.PeriodicTeamEval):
        def _on_training_start(self) -> None:
            if getattr(self.model.policy, "q_net_average", None) is not None:
                # The model's own evaluations would then be its average's, not the online network's.
                raise SystemExit(
                    f"the model keeps its own weight average (weight_average_tau="
                    f"{self.model.policy.weight_average_tau}, GDQ's default): this script compares the online "
                    'network with averages, so pass --hyperparams \'{"policy_kwargs": {"weight_average_tau": null}}\''
                )
            net = self.model.policy.q_net
            self.averages = {tau: [p.detach().clone() for p in net.parameters()] for tau in taus}
            self.seen_updates = self.model._n_updates
            for tau in taus:  # the model's records restart from scratch: so do the averages'
                average_path(self.path, tau).unlink(missing_ok=True)

        def _on_step(self) -> bool:
            # Called after every vector step; SB3 trains after the step, so the averages see each gradient step
            # once (k > 1 only when several steps ran since the last call, with weights read once: exact for
            # k = 1, the default train_freq of 1 and gradient_steps of 1).
            k = self.model._n_updates - self.seen_updates
            if k > 0:
                first, self.seen_updates = self.seen_updates + 1, self.model._n_updates
                params = [p.detach() for p in self.model.policy.q_net.parameters()]
                for tau, average in self.averages.items():
                    # the option's n-th step moves the average by weight_average_rate(tau, n); k steps toward the
                    # same weights compose into one move by 1 - prod(1 - rate)
                    rates = [weight_average_rate(tau, n) for n in range(first, first + k)]
                    rate = rates[0] if k == 1 else 1.0 - math.prod(1.0 - r for r in rates)
                    polyak_update_tensors_(average, params, [], [], rate)
            return super()._on_step()

        def evaluate(self, ticks: int) -> dict[str, Any]:
            record = super().evaluate(ticks)
            if ticks < average_from and ticks not in also:
                return record
            net = self.model.policy.q_net
            online = [p.detach().clone() for p in net.parameters()]
            try:
                for tau, average in self.averages.items():
                    with th.no_grad():
                        for param, value in zip(net.parameters(), average, strict=True):
                            param.copy_(value)
                    summary = evaluate_team(
                        self.model,
                        self.env_id,
                        self.n_episodes,
                        n_envs=4,
                        seed=10_000 + self.seed,
                        env_kwargs=self.env_kwargs,
                    )
                    summary.pop("episodes")
                    row = {
                        "ticks": ticks,
                        "wall_s": round(time.time() - self.start, 1),
                        "n_updates": self.model._n_updates,
                        "weight_average_tau": tau,
                        **summary,
                    }
                    path = average_path(self.path, tau)
                    path.parent.mkdir(parents=True, exist_ok=True)
                    with path.open("a") as file:
                        file.write(json.dumps(row) + "\n")
                    print(json.dumps({"tau": tau, "ticks": ticks, "success_rate": row["success_rate"]}), flush=True)
            finally:
                with th.no_grad():  # training goes on with the online weights, untouched
                    for param, value in zip(net.parameters(), online, strict=True):
                        param.copy_(value)
            return record

    return AveragedTeamEval


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--average-taus", type=float, nargs="+", default=[5e-4, 2e-4])
    parser.add_argument("--average-from", type=int, default=100_000, help="evaluate the averages from these ticks on")
    parser.add_argument("--average-also", type=int, nargs="*", default=[50_000], help="and at these ticks")
    args, rest = parser.parse_known_args(argv)
    if rest and rest[0] == "--":
        rest = rest[1:]
    if not all(0.0 < tau <= 1.0 for tau in args.average_taus):
        parser.error("--average-taus must be in (0, 1]")
    learning_check.PeriodicTeamEval = averaged_eval_class(args.average_taus, args.average_from, args.average_also)
    sys.argv = [sys.argv[0], *rest]
    learning_check.main()


if __name__ == "__main__":
    main()
