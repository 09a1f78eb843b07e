"""``python -m sb3_eps.plot``: learning curves (paper Fig. 4 style) and aggregate metrics from run folders.

Examples::

    python -m sb3_eps.plot logs/gdq logs/eps_gdq -o curves.png
    python -m sb3_eps.plot -f logs --algo gdq eps_gdq --env MultiRobotNav-4-v0 --aggregate

Curves: team return and success rate of the training episodes, smoothed over 100 episodes, mean +/- std over the
runs (seeds) of each algorithm, against ticks including the ticks of EPS evaluation. ``--eval`` draws the periodic
greedy evaluations instead; ``--records`` adds the greedy-evaluation records of ``benchmarks/learning_check.py``
(the JSON-lines files committed under ``docs/results/``) beside them, e.g. to draw a run against the published
seeds. ``--aggregate`` prints mean, median and IQM of the runs' final scores with bootstrap
95 % confidence intervals (and writes them beside the picture).
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Sequence
from pathlib import Path

from sb3_eps.zoo.cli import OneLineArgumentParser, positive_int
from sb3_eps.zoo.errors import ConfigError, run_command
from sb3_eps.zoo.plotting import (
    aggregate_table,
    evaluation_curves,
    find_run_dirs,
    format_aggregates,
    load_curve,
    plot_learning_curves,
    record_curves,
)
from sb3_eps.zoo.schema import ALGORITHMS

PROG = "python -m sb3_eps.plot"


def make_parser() -> argparse.ArgumentParser:
    """:return: the parser of ``python -m sb3_eps.plot``."""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="*", help="run folders or folders holding runs")
    parser.add_argument("-f", "--log-folder", dest="folder", default="logs", help="used when no path is given")
    parser.add_argument("--algo", nargs="+", choices=list(ALGORITHMS), default=None, help="keep these algorithms")
    parser.add_argument("--env", nargs="+", default=None, help="keep these env ids")
    parser.add_argument("-o", "--output", default="learning_curves.png", help="image file (.png, .pdf, .svg)")
    parser.add_argument("--window", type=positive_int, default=100, help="episodes of the smoothing window")
    parser.add_argument("--eval", action="store_true", help="plot the periodic greedy evaluations instead")
    parser.add_argument("--aggregate", action="store_true", help="aggregate metrics with bootstrap CIs")
    parser.add_argument(
        "--records",
        nargs="+",
        default=None,
        help="also draw these greedy-evaluation records (JSON-lines files or folders of them, docs/results/...);"
        " implies --eval",
    )
    parser.add_argument("--title", default=None)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line. :return: the exit status."""
    args = make_parser().parse_args(argv)
    if args.records:
        args.eval = True
    run_dirs = find_run_dirs(args.paths or [args.folder]) if args.paths or not args.records else []
    curves = evaluation_curves(run_dirs) if args.eval else [load_curve(run_dir) for run_dir in run_dirs]
    curves += record_curves(args.records) if args.records else []
    curves = [
        curve
        for curve in curves
        if (args.algo is None or curve.algo in args.algo) and (args.env is None or curve.env_id in args.env)
    ]
    if not curves:
        raise ConfigError("no run matches --algo / --env (or none has evaluations with --eval)")
    window = 1 if args.eval else args.window
    output = plot_learning_curves(curves, args.output, window, args.title)
    print(f"{len(curves)} runs -> {output}")
    if args.aggregate:
        rows = [row for key in ("success", "r") for row in aggregate_table(curves, key, args.window)]
        print(format_aggregates(rows))
        table = Path(output).with_suffix(".aggregate.csv")
        with table.open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"Aggregates: {table}")
    return 0


def cli() -> None:
    """Console-script entry point: run :func:`main`, turning mistakes into one line and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
