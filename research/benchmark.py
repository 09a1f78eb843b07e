"""``python -m research.benchmark``: evaluate every finished run in a log folder and write a Markdown table.

Example (paper Table II: the 4-robot models on the unseen world)::

    python -m research.benchmark -f logs --env MultiRobotNav-4-v0 --eval-env MultiRobotNavUnseen-4-v0 -n 100

One row per (algorithm, training env, evaluation env): success %, collision %, team return and episode length,
each the mean +/- std over the runs (seeds) of the runs' greedy means. Written to ``-o`` (default
``<folder>/benchmark.md``) with the per-run numbers as JSON beside it.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_eps.zoo.cli import OneLineArgumentParser, positive_int
from sb3_eps.zoo.errors import run_command
from sb3_eps.zoo.schema import ALGORITHMS

PROG = "python -m research.benchmark"
_COLUMNS = (("success_rate", "success %", 100.0), ("collision_rate", "collision %", 100.0),
            ("team_return_mean", "team return", 1.0), ("length_mean", "length (ticks)", 1.0))  # fmt: skip


def make_parser() -> argparse.ArgumentParser:
    """:return: the parser of ``python -m research.benchmark``."""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-f", "--log-folder", dest="folder", default="logs")
    parser.add_argument("--algo", nargs="+", choices=list(ALGORITHMS), default=None)
    parser.add_argument("--env", nargs="+", default=None, help="training env ids to include")
    parser.add_argument("--eval-env", default=None, help="evaluate on this env id (default: each run's own)")
    parser.add_argument("-n", "--n-episodes", type=positive_int, default=100)
    parser.add_argument("--n-envs", type=positive_int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--load-best", action="store_true")
    parser.add_argument("-o", "--output", default=None, help="Markdown file (default <folder>/benchmark.md)")
    parser.add_argument("--device", default="auto")
    return parser


def benchmark_table(results: list[dict[str, Any]]) -> str:
    """:return: the Markdown table of per-run evaluation summaries, grouped by algorithm and envs."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for result in results:
        groups[(result["algo"], result["train_env_id"], result["env_id"])].append(result)
    header = "| algorithm | trained on | evaluated on | runs | " + " | ".join(c[1] for c in _COLUMNS) + " |"
    lines = [header, "|" + "---|" * (4 + len(_COLUMNS))]
    for (algo, train_env, eval_env), members in sorted(groups.items()):
        cells = []
        for key, _, scale in _COLUMNS:
            values = [scale * m[key] for m in members if key in m]
            cells.append(f"{np.mean(values):.2f} +/- {np.std(values):.2f}" if values else "-")
        lines.append(f"| {ALGORITHMS[algo].label} | {train_env} | {eval_env} | {len(members)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line. :return: the exit status."""
    args = make_parser().parse_args(argv)
    from sb3_eps.zoo.checkpoint import write_text_atomic
    from sb3_eps.zoo.errors import ConfigError
    from sb3_eps.zoo.evaluation import evaluate_run, load_run
    from sb3_eps.zoo.plotting import find_run_dirs

    results = []
    for run_dir in find_run_dirs([args.folder]):
        try:
            run = load_run(run_dir, "best" if args.load_best else "final", args.device)
        except ConfigError as error:
            print(f"skipped: {error}")
            continue
        if (args.algo and run.algo not in args.algo) or (args.env and run.env_id not in args.env):
            continue
        summary = evaluate_run(run, args.eval_env, args.n_episodes, args.n_envs, args.seed)
        summary.pop("episodes")
        results.append(summary)
        print(
            f"{run_dir}: success {100 * summary.get('success_rate', float('nan')):.1f} %, team return {summary['team_return_mean']:.2f}"
        )
    if not results:
        raise ConfigError(f"no finished run to evaluate in {args.folder} (with the given --algo / --env)")
    table = benchmark_table(results)
    output = Path(args.output) if args.output else Path(args.folder) / "benchmark.md"
    write_text_atomic(output, table + "\n")
    write_text_atomic(output.with_suffix(".json"), json.dumps(results, indent=2, default=float))
    print(table)
    print(f"Table: {output}")
    return 0


def cli() -> None:
    """Console-script entry point: run :func:`main`, turning mistakes into one line and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
