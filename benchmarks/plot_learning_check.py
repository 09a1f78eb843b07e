"""Plot greedy team success against training ticks from ``learning_check.py`` records (one curve per group).

Each ``--group LABEL=GLOB`` names the JSON-lines files of one configuration (one file per seed); the plot shows
every seed as a thin line and the mean over seeds as a thick one (``research.results.draw_seed_curves``), and the
script prints the table behind it.

    python benchmarks/plot_learning_check.py --out docs/results/gdq_2robot.png \
        --group "IQL=docs/results/learning_check/iql_*.jsonl" \
        --group "GDQ=docs/results/learning_check/gdq_*.jsonl"
"""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # research/ sits beside the package

from research.results import EvaluationRun, draw_seed_curves, read_evaluation_run


def read_group(pattern: str) -> list[EvaluationRun]:
    """:return: the records of the files matching ``pattern``."""
    paths = sorted(glob.glob(pattern))
    if not paths:
        raise SystemExit(f"no files match {pattern!r}")
    return [read_evaluation_run(path) for path in paths]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--group", action="append", required=True, help="LABEL=GLOB of JSON-lines files")
    parser.add_argument("--out", required=True, help="the PNG to write")
    parser.add_argument("--title", default="MultiRobotNav-2-v0: greedy team success (100 episodes)")
    args = parser.parse_args()
    groups = {}
    for spec in args.group:
        label, _, pattern = spec.partition("=")
        if not pattern:
            raise SystemExit(f"--group must be LABEL=GLOB, got {spec!r}")
        groups[label] = read_group(pattern)
        for run in groups[label]:
            points = zip(run.ticks.tolist(), run.metrics["success_rate"].tolist(), strict=True)
            print(f"{label:<24}{run.path.stem:<44}" + " ".join(f"{t // 1000}k:{100 * s:.0f}%" for t, s in points))
    figure = draw_seed_curves(
        groups, "success_rate", title=args.title, xlabel="training ticks (world steps)", ylabel="success rate (%)"
    )
    axis = figure.axes[0]
    axis.axhline(80, color="grey", linestyle=":", linewidth=1)
    axis.set_ylim(-2, 102)
    figure.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
