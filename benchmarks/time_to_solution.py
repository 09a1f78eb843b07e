"""Wall-clock time and world ticks to a trained team: two configurations alternated seed by seed in one run.

For each seed, configuration A trains, then B (then the next seed: A, B ...), so a drift of the machine falls on
both. Each run trains on ``--env`` with ``--n-envs`` worlds and stops at ``--ticks`` world ticks or at the first
greedy evaluation that reaches the last ``--levels`` entry. The evaluations (``--eval-episodes`` team episodes every
``--eval-every`` ticks, separate evaluation worlds) are measurements, not training: their time is left out of the
training wall-clock. Records, one JSON line per evaluation, go to ``<out>/<config>_<env>_seed<k>.jsonl`` (with
``train_s``, the training seconds so far); a seed whose file ends in a finished run is skipped, so an interrupted
invocation resumes. The summary prints, per configuration and level, the median over seeds of the training minutes
and of the ticks to the first evaluation at or above the level, and the ratio B / A of the medians.

A configuration is a preset name from ``PRESETS`` (``defaults-2026-12-03``: the package defaults of that date, kept
so later defaults can be compared with them) or a JSON dict of algorithm arguments (``{"n_envs": 8, ...}``, where
``n_envs`` sets the worlds and the rest goes to the algorithm; with ``"overlap_training": true`` every world steps in a
worker process, as the command line lays them out, ``overlap_layout``). Example::

    python benchmarks/time_to_solution.py --env MultiRobotNav-4-v0 --levels 0.8 0.9 --seeds 0 1 2 \\
        --a defaults-2026-12-03 --b '{"overlap_training": true}'
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import time
from typing import Any

import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.utils import LinearSchedule

import envs  # noqa: F401
from sb3_eps import GDQ, IQL, QMIX, VDN, make_vec_env
from sb3_eps.common.evaluation import evaluate_team, world_of
from sb3_eps.common.subproc_vec_env import overlap_layout

ALGORITHMS = {"iql": IQL, "gdq": GDQ, "qmix": QMIX, "vdn": VDN}
#: Named configurations: algorithm arguments (``n_envs``: the worlds) that differ from the package defaults.
PRESETS: dict[str, dict[str, Any]] = {
    "defaults-2026-12-03": {"n_envs": 4},
    # 8 worlds, learning while they step in a worker: half the gradient steps per tick, each hidden behind the
    # worlds' step (docs/results/time_to_solution/rules.md).
    "overlap8": {"n_envs": 8, "overlap_training": True},
    # The same with twice the batch: as many sampled rows per tick as the defaults, in half the gradient steps.
    "overlap8-b128": {"n_envs": 8, "overlap_training": True, "batch_size": 128},
    # 16 worlds and batch 256: the same sampled rows per tick again, in a quarter of the defaults' gradient steps, so
    # the fixed cost of a vector step (buffer writes, action selection, optimizer) falls on twice the ticks.
    "overlap16-b256": {"n_envs": 16, "overlap_training": True, "batch_size": 256},
}
# The same with the learning rate doubled (6e-4 decaying linearly to 0): a quarter of the gradient steps, longer.
PRESETS["overlap16-b256-lr6e-4"] = {**PRESETS["overlap16-b256"], "learning_rate": LinearSchedule(6e-4, 0.0, 1.0)}


class StopAtLevel(BaseCallback):
    """Evaluates every ``eval_every`` ticks; stops training at the first evaluation at or above ``stop_level``."""

    def __init__(self, args: argparse.Namespace, path: pathlib.Path, seed: int) -> None:
        super().__init__()
        self.args, self.path, self.seed = args, path, seed
        self.next_eval = max(args.eval_start, args.eval_every)
        self.eval_s = 0.0
        self.last: dict[str, Any] | None = None  # the latest evaluation's record
        self.start = time.perf_counter()

    def _on_step(self) -> bool:
        ticks = int(self.model.ticks)  # type: ignore[attr-defined]
        if ticks < self.next_eval:
            return True
        self.next_eval += self.args.eval_every
        return self.evaluate(ticks) < self.args.levels[-1]

    def evaluate(self, ticks: int) -> float:
        began = time.perf_counter()
        summary = evaluate_team(self.model, self.args.env, self.args.eval_episodes, n_envs=4, seed=10_000 + self.seed)
        self.eval_s += time.perf_counter() - began
        record = {
            "ticks": ticks,
            "agent_steps": int(self.model.num_timesteps),
            "train_s": round(time.perf_counter() - self.start - self.eval_s, 2),
            "success_rate": summary["success_rate"],
            "collision_rate": summary["collision_rate"],
            **world_of(summary),
        }
        with self.path.open("a") as file:
            file.write(json.dumps(record) + "\n")
        self.last = record
        print(json.dumps({"file": self.path.name, **record}), flush=True)
        return float(summary["success_rate"])


def configuration(spec: str) -> tuple[str, dict[str, Any]]:
    """:return: a file-safe name and the arguments of a preset name or a JSON dict"""
    if spec in PRESETS:
        return spec, dict(PRESETS[spec])
    try:
        arguments = json.loads(spec)
    except json.JSONDecodeError:
        raise SystemExit(f"configuration {spec!r}: neither a preset ({', '.join(PRESETS)}) nor a JSON dict") from None
    name = "-".join(f"{key}={value}" for key, value in sorted(arguments.items())).replace("/", "_")
    return name or "package-defaults", arguments


def build_model(algo: str, arguments: dict[str, Any], env_id: str, seed: int) -> Any:
    """The algorithm on its worlds: ``arguments["n_envs"]`` worlds (default 4), every one in a worker process with
    ``overlap_training`` (the command line's ``overlap_layout``), the other arguments to the algorithm."""
    arguments = dict(arguments)
    n_envs = int(arguments.pop("n_envs", 4))
    layout = {"vec_env_cls": "subproc", "vec_env_kwargs": overlap_layout(n_envs)} if arguments.get("overlap_training") else {}
    venv = make_vec_env(env_id, n_envs=n_envs, seed=seed, **layout)
    return ALGORITHMS[algo]("MlpPolicy", venv, seed=seed, **arguments)


def run(args: argparse.Namespace, spec: str, seed: int) -> list[dict[str, Any]]:
    """One seed of one configuration; returns its records (resumed from its file when finished)."""
    name, arguments = configuration(spec)
    path = pathlib.Path(args.out) / f"{name}_{args.env}_seed{seed}.jsonl"
    if path.exists():
        records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        if records and (records[-1]["success_rate"] >= args.levels[-1] or records[-1]["ticks"] >= args.ticks):
            return records
        path.unlink()  # an unfinished run restarts
    model = build_model(args.algo, arguments, args.env, seed)
    venv = model.get_env()
    callback = StopAtLevel(args, path, seed)
    model.learn(args.ticks * venv.n_agents, callback=callback, log_interval=1_000_000)
    last = callback.last
    if last is None or (last["success_rate"] < args.levels[-1] and last["ticks"] < int(model.ticks)):
        callback.evaluate(int(model.ticks))  # the budget ended between two evaluations
    venv.close()
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def first_at(records: list[dict[str, Any]], level: float) -> tuple[float, int] | None:
    """:return: training minutes and ticks of the first evaluation at or above ``level`` (None if none)"""
    hit = next((r for r in records if r["success_rate"] >= level), None)
    return None if hit is None else (hit["train_s"] / 60.0, hit["ticks"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), default="gdq")
    parser.add_argument("--env", default="MultiRobotNav-4-v0")
    parser.add_argument("--a", default="defaults-2026-12-03", help="a preset name or a JSON dict")
    parser.add_argument("--b", required=True, help="a preset name or a JSON dict")
    parser.add_argument("--levels", type=float, nargs="+", default=[0.8, 0.9])
    parser.add_argument("--seeds", type=int, nargs="+", default=[220, 221, 222])
    parser.add_argument("--ticks", type=int, default=300_000, help="the most world ticks a run may train")
    parser.add_argument("--eval-every", type=int, default=10_000)
    parser.add_argument("--eval-start", type=int, default=0, help="the first evaluation's tick (default: --eval-every)")
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    th.set_num_threads(1)
    pathlib.Path(args.out).mkdir(parents=True, exist_ok=True)
    results: dict[str, list[list[dict[str, Any]]]] = {args.a: [], args.b: []}
    for seed in args.seeds:
        for spec in (args.a, args.b):
            results[spec].append(run(args, spec, seed))
    print(
        f"{args.algo} on {args.env}, seeds {args.seeds}; medians over seeds (a seed that never got there counts as "
        f"{args.ticks} ticks and its whole training time)"
    )
    for level in args.levels:
        medians = {}
        for spec, runs in results.items():
            hits = [first_at(records, level) or (records[-1]["train_s"] / 60.0, args.ticks) for records in runs]
            medians[spec] = (statistics.median(h[0] for h in hits), statistics.median(h[1] for h in hits))
            print(
                f"  {level:.0%}  {spec}: {medians[spec][0]:.1f} min, {medians[spec][1]:.0f} ticks "
                f"(per seed: {', '.join(f'{h[0]:.1f} min/{h[1]}' for h in hits)})"
            )
        (a_min, a_ticks), (b_min, b_ticks) = medians[args.a], medians[args.b]
        print(f"  {level:.0%}  ratio B / A: wall-clock {b_min / a_min:.2f}, ticks {b_ticks / a_ticks:.2f}")


if __name__ == "__main__":
    main()
