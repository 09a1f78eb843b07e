"""Train an algorithm for a tick budget and evaluate it greedily at fixed tick intervals, per seed.

Writes one JSON line per evaluation to ``<out>/<algo>_<env>_seed<k>.jsonl`` and skips seeds whose file already
holds the final evaluation, so an interrupted run resumes where it stopped (per seed). Example (issue 3's
acceptance check)::

    python benchmarks/learning_check.py --algo gdq --env MultiRobotNav-2-v0 --ticks 100000 --seeds 0 1 2

With ``--eps`` (a JSON dict of ``EvolutionCallback`` arguments, ``{}`` for its defaults) the run is EPS-<algo>: the
ticks of the budget, of the evaluation points and of every record count the EPS evaluation ticks too (``ticks`` =
training ticks + ``eps_ticks``), as the paper's curves do, and training stops when that total reaches ``--ticks``
(``sb3_eps.zoo.callbacks.TickBudgetCallback``): the schedules (a decaying learning rate, PER's exponent, EPS's
alpha) end there too.
A round's EPS ticks can carry the total past an evaluation point: the evaluation then comes at the next step, with
the total it has reached. The files are named ``eps_<algo>_<env>_seed<k>.jsonl``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time
from typing import Any

import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import LinearSchedule

import envs  # noqa: F401
from sb3_eps import GDQ, IQL, QMIX, VDN, EvolutionCallback, make_vec_env
from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.zoo.callbacks import TickBudgetCallback

ALGORITHMS = {"iql": IQL, "gdq": GDQ, "qmix": QMIX, "vdn": VDN}


class PeriodicTeamEval(BaseCallback):
    """Greedy team evaluation every ``eval_every`` training ticks; results appended to a JSON-lines file."""

    def __init__(
        self,
        env_id: str,
        eval_every: int,
        n_episodes: int,
        path: pathlib.Path,
        seed: int,
        eps: EvolutionCallback | None = None,
        env_kwargs: dict[str, Any] | None = None,
    ) -> None:
        super().__init__()
        self.eps = eps
        self.env_kwargs = env_kwargs
        self.env_id, self.eval_every, self.n_episodes, self.path, self.seed = (
            env_id,
            eval_every,
            n_episodes,
            path,
            seed,
        )
        self.next_eval = eval_every
        self.start = time.time()

    def total_ticks(self) -> int:
        """Training ticks, plus the EPS evaluation ticks when EPS runs."""
        eps_ticks = self.eps.eps_ticks if self.eps is not None else 0
        return int(self.model.ticks) + eps_ticks  # type: ignore[attr-defined]

    def _on_step(self) -> bool:
        ticks = self.total_ticks()
        if ticks >= self.next_eval:
            while self.next_eval <= ticks:  # an EPS round can jump over several evaluation points
                self.next_eval += self.eval_every
            self.evaluate(ticks)
        return True

    def evaluate(self, ticks: int) -> dict[str, Any]:
        summary = evaluate_team(
            self.model, self.env_id, self.n_episodes, n_envs=4, seed=10_000 + self.seed, env_kwargs=self.env_kwargs
        )
        summary.pop("episodes")
        record = {"ticks": ticks, "wall_s": round(time.time() - self.start, 1), **summary}
        if self.eps is not None:
            record.update(
                training_ticks=int(self.model.ticks),  # type: ignore[attr-defined]
                eps_ticks=self.eps.eps_ticks,
                eps_rounds=self.eps.n_rounds,
                eps_crossovers=self.eps.n_crossovers,
                eps_shared_rows=getattr(self.eps, "shared_rows", 0),  # replay rows from EPS episodes (share_experience)
            )
        with self.path.open("a") as file:
            file.write(json.dumps(record) + "\n")
        print(
            json.dumps({k: record[k] for k in ("ticks", "wall_s", "success_rate", "team_return_mean")}),
            flush=True,
        )
        return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), default="gdq")
    parser.add_argument("--env", default="MultiRobotNav-2-v0")
    parser.add_argument("--ticks", type=int, default=100_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--n-envs", type=int, default=4)
    parser.add_argument("--eval-every", type=int, default=10_000)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--out", default="docs/results/learning_check")
    parser.add_argument("--log-interval", type=int, default=20, help="episodes between two log rows")
    parser.add_argument("--log-dir", default=None, help="write the train/ and rollout/ logs (progress.csv) here")
    parser.add_argument(
        "--hyperparams",
        type=json.loads,
        default={},
        help='JSON dict of algorithm arguments; "learning_rate": "lin_<x>" is a linear decay from x to 0',
    )
    parser.add_argument(
        "--env-kwargs",
        type=json.loads,
        default=None,
        help="JSON dict of world arguments for the training and evaluation worlds, e.g. '{\"lidar_noise_std\": 0.01}'",
    )
    parser.add_argument(
        "--eps",
        type=json.loads,
        default=None,
        help="JSON dict of EvolutionCallback arguments ({} = its defaults): train EPS-<algo>, EPS ticks counted",
    )
    parser.add_argument(
        "--save-models",
        action="store_true",
        help="save each seed's final model next to its records (<algo>_<env>_seed<k>.zip), to look into later "
        "(benchmarks/failure_anatomy.py)",
    )
    parser.add_argument(
        "--schedules-ignore-eps",
        action="store_true",
        help="EPS runs: let the schedules (learning rate, PER exponent, alpha) run over the whole budget as training "
        "ticks, as in the records made before 2026-12-01 (default: they end when training plus EPS ticks reach the "
        "budget)",
    )
    args = parser.parse_args()
    th.set_num_threads(1)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        prefix = "eps_" if args.eps is not None else ""
        path = out / f"{prefix}{args.algo}_{args.env}_seed{seed}.jsonl"
        if path.exists() and any(json.loads(line)["ticks"] >= args.ticks for line in path.read_text().splitlines()):
            print(f"seed {seed}: done already ({path})")
            continue
        path.unlink(missing_ok=True)  # an unfinished seed restarts from scratch
        venv = make_vec_env(args.env, n_envs=args.n_envs, seed=seed, env_kwargs=args.env_kwargs)
        hyperparams = dict(args.hyperparams)
        learning_rate = hyperparams.get("learning_rate")
        if isinstance(learning_rate, str) and learning_rate.startswith("lin_"):
            # RL Zoo's lin_<x>: x at the start, decreasing linearly to 0 at the end of training.
            hyperparams["learning_rate"] = LinearSchedule(float(learning_rate[4:]), 0.0, 1.0)
        model = ALGORITHMS[args.algo]("MlpPolicy", venv, seed=seed, **hyperparams)
        if args.log_dir:
            from stable_baselines3.common.logger import configure

            model.set_logger(configure(f"{args.log_dir}/{prefix}{args.algo}_{args.env}_seed{seed}", ["csv"]))
        eps = None
        if args.eps is not None:
            eps_kwargs = dict(args.eps)
            if args.log_dir:
                eps_kwargs.setdefault(
                    "diagnostics_path",
                    f"{args.log_dir}/{prefix}{args.algo}_{args.env}_seed{seed}/eps_rounds.jsonl",
                )
            eps_kwargs.setdefault("verbose", 1)
            eps = EvolutionCallback(**eps_kwargs)
        callback = PeriodicTeamEval(args.env, args.eval_every, args.eval_episodes, path, seed, eps, env_kwargs=args.env_kwargs)
        callbacks: BaseCallback = callback
        if eps is not None:  # training stops when its ticks plus the EPS ticks reach the budget
            budget = TickBudgetCallback(args.ticks * venv.n_agents, [eps], schedules_follow=not args.schedules_ignore_eps)
            callbacks = CallbackList([eps, callback, budget])
        model.learn(args.ticks * venv.n_agents, callback=callbacks, log_interval=args.log_interval)
        if callback.next_eval - callback.eval_every < args.ticks:
            callback.evaluate(callback.total_ticks())
        if args.save_models:
            model.save(path.with_suffix(".zip"))
        venv.close()


if __name__ == "__main__":
    main()
