"""Train on a ladder of team sizes (for example 4 robots, then 8) and evaluate greedily on the target world throughout.

Each rung is a fresh model of the algorithm on its world whose agent network (``q_net``, its target and the weight
average) starts from the previous rung's (``sb3_eps.zoo.exp_manager.load_agent_weights``, the warm start of
``--init-from``); the joint modules (GDQ's ``V_G``, mixers), the optimizer, the replay buffer and the schedules start
fresh. ``--later-eps`` sets the exploration of the rungs after the first (a transferred policy already navigates).
The x axis counts the world ticks of every rung (``ticks``), with the agent-steps (``agent_steps``) beside: a rung of
4 robots spends 4 agent-steps per tick, a rung of 8 spends 8.

Writes one JSON line per evaluation to ``<out>/<name>_seed<k>.jsonl`` and skips seeds whose file already holds the
final evaluation (an unfinished seed restarts). Example::

    python benchmarks/team_size_ladder.py --rungs MultiRobotNav-4-v0:150000 MultiRobotNav-8-v0:150000 \\
        --eval-env MultiRobotNav-8-v0 --seeds 220 --out runs/ladder
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile
import time
from typing import Any

import torch as th
from stable_baselines3.common.callbacks import BaseCallback

import envs  # noqa: F401
from sb3_eps import GDQ, IQL, QMIX, VDN, make_vec_env
from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.zoo.exp_manager import load_agent_weights

ALGORITHMS = {"iql": IQL, "gdq": GDQ, "qmix": QMIX, "vdn": VDN}


class LadderEval(BaseCallback):
    """Greedy team evaluation every ``eval_every`` world ticks of the whole ladder; one JSON line each."""

    def __init__(
        self,
        args: argparse.Namespace,
        path: pathlib.Path,
        seed: int,
        rung: int,
        ticks_before: int,
        steps_before: int,
        next_eval: int,
        start: float,
    ) -> None:
        super().__init__()
        self.args, self.path, self.seed, self.rung = args, path, seed, rung
        self.ticks_before, self.steps_before, self.next_eval, self.start = (
            ticks_before,
            steps_before,
            next_eval,
            start,
        )

    def total_ticks(self) -> int:
        return self.ticks_before + int(self.model.ticks)  # type: ignore[attr-defined]

    def _on_step(self) -> bool:
        if self.total_ticks() >= self.next_eval:
            while self.next_eval <= self.total_ticks():
                self.next_eval += self.args.eval_every
            self.evaluate()
        return True

    def evaluate(self) -> None:
        record: dict[str, Any] = {
            "ticks": self.total_ticks(),
            "agent_steps": self.steps_before + int(self.model.num_timesteps),
            "rung": self.rung,
            "wall_s": round(time.time() - self.start, 1),
        }
        for env_id in self.args.eval_env:
            summary = evaluate_team(
                self.model, env_id, self.args.eval_episodes, n_envs=4, seed=10_000 + self.seed
            )
            summary.pop("episodes")
            key = "" if env_id == self.args.eval_env[0] else f"{env_id}/"
            record.update({f"{key}{name}": value for name, value in summary.items()})
        with self.path.open("a") as file:
            file.write(json.dumps(record) + "\n")
        print(
            json.dumps({k: record[k] for k in ("ticks", "rung", "wall_s", "success_rate", "collision_rate")}),
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), default="gdq")
    parser.add_argument("--rungs", nargs="+", required=True, help="ENV_ID:TICKS, trained in this order")
    parser.add_argument("--eval-env", nargs="+", required=True, help="the first is the target world")
    parser.add_argument("--seeds", type=int, nargs="+", default=[220])
    parser.add_argument("--n-envs", type=int, default=4)
    parser.add_argument("--eval-every", type=int, default=25_000)
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument(
        "--later-eps",
        type=float,
        default=None,
        help="exploration_initial_eps of the rungs after the first (default: the algorithm's)",
    )
    parser.add_argument("--hyperparams", type=json.loads, default={}, help="JSON dict of algorithm arguments")
    parser.add_argument("--name", default=None)
    parser.add_argument("--out", required=True)
    parser.add_argument("--save-models", action="store_true")
    args = parser.parse_args()
    th.set_num_threads(1)
    rungs = [(spec.rsplit(":", 1)[0], int(spec.rsplit(":", 1)[1])) for spec in args.rungs]
    total = sum(ticks for _, ticks in rungs)
    name = args.name or f"{args.algo}_" + "_".join(f"{env}-{ticks}" for env, ticks in rungs)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        path = out / f"{name}_seed{seed}.jsonl"
        if path.exists() and any(
            json.loads(line)["ticks"] >= total for line in path.read_text().splitlines()
        ):
            print(f"seed {seed}: done already ({path})")
            continue
        path.unlink(missing_ok=True)
        ticks_before = steps_before = 0
        next_eval, start, previous = args.eval_every, time.time(), None
        with tempfile.TemporaryDirectory() as scratch:
            for index, (env_id, ticks) in enumerate(rungs):
                venv = make_vec_env(env_id, n_envs=args.n_envs, seed=seed + 1000 * index)
                hyperparams = dict(args.hyperparams)
                if index > 0 and args.later_eps is not None:
                    hyperparams["exploration_initial_eps"] = args.later_eps
                model = ALGORITHMS[args.algo]("MlpPolicy", venv, seed=seed + 1000 * index, **hyperparams)
                if previous is not None:
                    load_agent_weights(model, previous)
                callback = LadderEval(args, path, seed, index, ticks_before, steps_before, next_eval, start)
                model.learn(ticks * venv.n_agents, callback=callback, log_interval=10_000)
                ticks_before += int(model.ticks)
                steps_before += int(model.num_timesteps)
                next_eval = callback.next_eval
                previous = pathlib.Path(scratch) / f"rung{index}.zip"
                model.save(previous)
                if args.save_models:
                    model.save(out / f"{name}_seed{seed}_rung{index}.zip")
                venv.close()
            if next_eval - args.eval_every < ticks_before:
                callback.evaluate()


if __name__ == "__main__":
    main()
