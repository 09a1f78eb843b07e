"""Train on a ladder of team sizes (for example 4 robots, then 8), or on one world with EPS or a population of
learners, and evaluate greedily on the target world throughout, every ``--eval-every`` world ticks of the whole run.

Modes (one evaluation protocol for all, so their curves compare):

- ``--carry agent`` (default): each rung is a fresh model of the algorithm on its world whose agent network (``q_net``, its target and the weight
average) starts from the previous rung's (``sb3_eps.zoo.exp_manager.load_agent_weights``, the warm start of
``--init-from``); the joint modules (GDQ's ``V_G``, mixers), the optimizer, the replay buffer and the schedules start
fresh. ``--later-eps`` sets the exploration of the rungs after the first (a transferred policy already navigates).
The x axis counts the world ticks of every rung (``ticks``), with the agent-steps (``agent_steps``) beside: a rung of
4 robots spends 4 agent-steps per tick, a rung of 8 spends 8.
- ``--carry whole``: one model climbs the rungs (``sb3_eps.learn_ladder``): networks, optimizer and schedules carry
  over; it needs joint modules that read any team size (GDQ with ``global_head="pooled"`` in ``--hyperparams``).
- ``--eps JSON`` (one rung): an ``EvolutionCallback`` with these settings; the EPS world's ticks are paid from the
  run's ticks (``ticks`` = training + EPS world ticks; ``eps_ticks`` and ``eps_agent_steps`` beside).
- ``--population JSON`` (one rung): a ``PopulationTrainer`` with these settings (``k``, ``n_envs``...); ``ticks``
  are every learner's, the evaluated model is the fittest learner (``best``).

``--env-kwargs JSON`` builds every world with these arguments; with ``action_repeat = k`` a decision holds k ticks, and
the rungs' ticks, ``--eval-every`` and ``ticks`` stay world ticks (``model.ticks``), ``agent_steps`` robot-ticks,
with ``decisions`` (per world, all worlds together) beside.

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
from research.population import PopulationTrainer
from sb3_eps import GDQ, IQL, QMIX, VDN, learn_ladder, make_vec_env
from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.common.ladder import Rung, rung_at
from sb3_eps.eps import EvolutionCallback
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

        self.eps: EvolutionCallback | None = None
        self.rungs: list[Rung] | None = None  # a whole-learner ladder's rungs
        self.total = 0  # the run's ticks: training stops there (an EPS run's rounds are paid from them)

    def eps_ticks(self) -> int:
        return self.eps.eps_ticks if self.eps is not None else 0

    def total_ticks(self) -> int:
        return self.ticks_before + int(self.model.ticks) + self.eps_ticks()  # type: ignore[attr-defined]

    def _on_step(self) -> bool:
        if self.total_ticks() >= self.next_eval:
            while self.next_eval <= self.total_ticks():
                self.next_eval += self.args.eval_every
            self.evaluate()
        return not (self.eps is not None and self.total_ticks() >= self.total)

    def evaluate(self) -> None:
        record: dict[str, Any] = {
            "ticks": self.total_ticks(),
            "agent_steps": self.steps_before + robot_ticks(self.model),
            "decisions": int(self.model.num_timesteps) // max(int(self.model.n_agents), 1),
            "rung": self.rung if self.rungs is None else min(rung_at(self.rungs, self.model.ticks), len(self.rungs) - 1),
            "wall_s": round(time.time() - self.start, 1),
        }
        if self.eps is not None:
            record.update(eps_ticks=self.eps_ticks(), rounds=self.eps.n_rounds, crossovers=self.eps.n_crossovers)
        write_evaluation(self.args, self.path, self.seed, self.model, record)


def robot_ticks(model: Any) -> int:
    """:return: the model's ticks times its robots (agent-steps at one decision per tick; a world with
    ``action_repeat = k`` makes k of them per decision)."""
    return int(model.num_timesteps) * int(getattr(model, "ticks_per_step", 1))


def write_evaluation(args: argparse.Namespace, path: pathlib.Path, seed: int, model: Any, record: dict[str, Any]) -> None:
    """Evaluate ``model`` greedily on every ``--eval-env`` and append the record as one JSON line."""
    for env_id in args.eval_env:
        summary = evaluate_team(model, env_id, args.eval_episodes, n_envs=4, seed=10_000 + seed, env_kwargs=args.env_kwargs)
        summary.pop("episodes")
        key = "" if env_id == args.eval_env[0] else f"{env_id}/"
        record.update({f"{key}{name}": value for name, value in summary.items()})
    with path.open("a") as file:
        file.write(json.dumps(record) + "\n")
    print(
        json.dumps({k: record[k] for k in ("ticks", "rung", "wall_s", "success_rate", "collision_rate")}),
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    parser.add_argument(
        "--env-kwargs",
        type=json.loads,
        default=None,
        help="JSON dict of world arguments, for the training and the evaluation worlds (lidar_frames...)",
    )
    parser.add_argument(
        "--carry",
        choices=("agent", "whole"),
        default="agent",
        help="agent: a fresh learner per rung from the agent network; whole: one model climbs (learn_ladder)",
    )
    parser.add_argument("--eps", type=json.loads, default=None, help="JSON dict of EvolutionCallback settings")
    parser.add_argument("--population", type=json.loads, default=None, help="JSON dict of PopulationTrainer settings")
    parser.add_argument("--name", default=None)
    parser.add_argument("--out", required=True)
    parser.add_argument("--save-models", action="store_true")
    args = parser.parse_args()
    th.set_num_threads(1)
    rungs = [(spec.rsplit(":", 1)[0], int(spec.rsplit(":", 1)[1])) for spec in args.rungs]
    if (args.eps is not None or args.population is not None) and (len(rungs) > 1 or args.carry == "whole"):
        parser.error("--eps and --population train on one rung with --carry agent")
    if args.eps is not None and args.population is not None:
        parser.error("give --eps or --population, not both")
    total = sum(ticks for _, ticks in rungs)
    name = args.name or f"{args.algo}_" + "_".join(f"{env}-{ticks}" for env, ticks in rungs)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        path = out / f"{name}_seed{seed}.jsonl"
        if path.exists() and any(json.loads(line)["ticks"] >= total for line in path.read_text().splitlines()):
            print(f"seed {seed}: done already ({path})")
            continue
        path.unlink(missing_ok=True)
        if args.population is not None:
            train_population(args, rungs[0], seed, path, out / f"{name}_seed{seed}")
            continue
        if args.carry == "whole":
            train_whole(args, rungs, seed, path, out / f"{name}_seed{seed}.zip")
            continue
        ticks_before = steps_before = 0
        next_eval, start, previous = args.eval_every, time.time(), None
        with tempfile.TemporaryDirectory() as scratch:
            for index, (env_id, ticks) in enumerate(rungs):
                venv = make_vec_env(env_id, n_envs=args.n_envs, seed=seed + 1000 * index, env_kwargs=args.env_kwargs)
                hyperparams = dict(args.hyperparams)
                if index > 0 and args.later_eps is not None:
                    hyperparams["exploration_initial_eps"] = args.later_eps
                model = ALGORITHMS[args.algo]("MlpPolicy", venv, seed=seed + 1000 * index, **hyperparams)
                if previous is not None:
                    load_agent_weights(model, previous)
                callback = LadderEval(args, path, seed, index, ticks_before, steps_before, next_eval, start)
                callbacks: list[BaseCallback] = [callback]
                if args.eps is not None:
                    settings = {
                        "seed": seed,
                        "diagnostics_path": str(out / f"{name}_seed{seed}_rounds.jsonl"),
                    }
                    callback.eps = EvolutionCallback(**{**settings, **args.eps})
                    callback.total = ticks
                    callbacks.insert(0, callback.eps)
                model.learn(model.timesteps_for_ticks(ticks), callback=callbacks, log_interval=10_000)
                ticks_before += int(model.ticks)
                steps_before += robot_ticks(model)
                next_eval = callback.next_eval
                previous = pathlib.Path(scratch) / f"rung{index}.zip"
                model.save(previous)
                if args.save_models:
                    model.save(out / f"{name}_seed{seed}_rung{index}.zip")
                venv.close()
            if next_eval - args.eval_every < ticks_before:
                callback.evaluate()


def train_whole(
    args: argparse.Namespace, rungs: list[tuple[str, int]], seed: int, path: pathlib.Path, save: pathlib.Path
) -> None:
    """One model over every rung (``learn_ladder``); rung ``i``'s worlds seeded ``seed + 1000 i``. Rungs of one env id
    share its worlds (built for the first of them), so a ladder that alternates two worlds runs two vector envs."""
    built: dict[str, Any] = {}
    for i, (env_id, _) in enumerate(rungs):
        if env_id not in built:
            built[env_id] = make_vec_env(env_id, n_envs=args.n_envs, seed=seed + 1000 * i, env_kwargs=args.env_kwargs)
    venvs = [built[env_id] for env_id, _ in rungs]
    model = ALGORITHMS[args.algo]("MlpPolicy", venvs[0], seed=seed, **args.hyperparams)
    callback = LadderEval(args, path, seed, 0, 0, 0, args.eval_every, time.time())
    callback.rungs = [Rung(venv, ticks) for venv, (_, ticks) in zip(venvs, rungs)]
    learn_ladder(model, callback.rungs, callback=callback, log_interval=10_000)
    if callback.next_eval - args.eval_every < model.ticks:
        callback.evaluate()
    if args.save_models:
        model.save(save)
    for venv in built.values():
        venv.close()


def train_population(
    args: argparse.Namespace, rung: tuple[str, int], seed: int, path: pathlib.Path, save: pathlib.Path
) -> None:
    """A population of learners on one world, its fittest learner evaluated every ``--eval-every`` ticks of all.

    One ``learn`` call over the whole total, the evaluations made between turns: the learners' schedules (learning
    rate, exploration) run once over the run, as in a command-line run (a call per mark would restart them)."""
    env_id, total = rung
    settings = {"log_path": str(save) + "_selections.jsonl", "seed": seed, "env_kwargs": args.env_kwargs, **args.population}
    population = PopulationTrainer(ALGORITHMS[args.algo], env_id, **settings, **args.hyperparams)
    start, marks = time.time(), list(range(args.eval_every, total + args.eval_every, args.eval_every))

    def evaluate() -> None:
        best = population.best
        record = {
            "ticks": population.ticks,
            "agent_steps": sum(int(learner.num_timesteps) for learner in population.learners),
            "rung": 0,
            "wall_s": round(time.time() - start, 1),
            "best": population.learners.index(best),
            "selections": len(population.history),
        }
        write_evaluation(args, path, seed, best, record)

    def after_turn() -> bool:
        if marks and population.ticks >= min(marks[0], total) and population.next_learner == 0:
            while marks and population.ticks >= min(marks[0], total):
                marks.pop(0)
            evaluate()
        return True

    population.learn(total, after_turn=after_turn)
    if marks:
        evaluate()
    if args.save_models:
        population.save(str(save) + "_population.zip")
        population.best.save(str(save) + ".zip")


if __name__ == "__main__":
    main()
