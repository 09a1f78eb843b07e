"""How one setting's greedy success at a fixed tick spreads over every seed it was run on, against a target.

An acceptance point such as "mean >= 90 % at 150k ticks over seeds 0-4" is a statement about five draws. This
script pools every record of one setting (report seeds and held-out seeds alike, from any number of folders),
takes each seed's evaluation at ``--at`` ticks, and prints: the values, their mean, standard deviation and
standard error, how many seeds reach the threshold, the report seeds' mean against the other seeds' mean, and the
chance that the mean of ``--draws`` fresh seeds reaches the threshold, and that each of them does (normal
approximation with the pooled mean and standard deviation). It selects nothing: it says how far a target is from
what the setting does on average.

    python benchmarks/seed_spread.py --at 150000 --threshold 90 \
        --group "GDQ 4 robots=docs/results/baselines/gdq4_lambda_report/*.jsonl" \
        --group "GDQ 4 robots=docs/results/baselines/gdq4_lambda_changes_heldout/defaults/*.jsonl"

A ``LABEL`` given more than once pools its globs. A seed found in two folders of one label is an error (two runs
of one seed are not two draws).
"""

from __future__ import annotations

import argparse
import glob
import math
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # research/ sits beside the package

from research.results import read_evaluation_run


@dataclass
class Spread:
    """One setting's values at one tick, a seed each."""

    label: str
    values: dict[int, float]  # seed -> success (%) at the tick

    @property
    def mean(self) -> float:
        return statistics.fmean(self.values.values())

    @property
    def sd(self) -> float:
        return statistics.stdev(self.values.values()) if len(self.values) > 1 else math.nan

    def at_least(self, threshold: float) -> int:
        return sum(value >= threshold for value in self.values.values())

    def chance_mean_reaches(self, threshold: float, draws: int) -> float:
        """:return: P(mean of ``draws`` new seeds >= threshold), normal approximation with the pooled mean and sd."""
        if not self.sd > 0:
            return float(self.mean >= threshold)
        z = (threshold - self.mean) / (self.sd / math.sqrt(draws))
        return 0.5 * math.erfc(z / math.sqrt(2))

    def chance_every_reaches(self, threshold: float, draws: int) -> float:
        """:return: P(each of ``draws`` new seeds >= threshold), the same approximation for one seed, to the power."""
        return self.chance_mean_reaches(threshold, 1) ** draws


def collect(specs: list[str], at: int) -> list[Spread]:
    """:param specs: ``LABEL=GLOB`` strings; a label repeated pools its globs.
    :param at: the tick whose evaluation is read (a seed without an evaluation at exactly ``at`` is an error)
    :return: one :class:`Spread` per label, in the order the labels first appear
    """
    spreads: dict[str, Spread] = {}
    for spec in specs:
        label, _, pattern = spec.partition("=")
        if not label or not pattern:
            raise SystemExit(f"--group must be LABEL=GLOB, got {spec!r}")
        paths = sorted(glob.glob(pattern))
        if not paths:
            raise SystemExit(f"no files match {pattern!r}")
        spread = spreads.setdefault(label, Spread(label, {}))
        for path in paths:
            run = read_evaluation_run(path)
            hits = [i for i, ticks in enumerate(run.ticks.tolist()) if ticks == at]
            if not hits:
                raise SystemExit(f"{path}: no evaluation at {at} ticks (it has {run.ticks.tolist()})")
            if run.seed in spread.values:
                raise SystemExit(f"{label}: seed {run.seed} appears twice ({path}); pool each seed once")
            spread.values[run.seed] = 100.0 * float(run.metrics["success_rate"][hits[0]])
    return list(spreads.values())


def report(spreads: list[Spread], at: int, threshold: float, report_seeds: list[int], draws: int) -> str:
    """:return: the printed table, a paragraph per setting."""
    lines = []
    for spread in spreads:
        seeds = sorted(spread.values)
        n = len(seeds)
        lines.append(f"{spread.label}: success at {at // 1000}k ticks over {n} seeds")
        lines.append("  " + " ".join(f"{seed}:{spread.values[seed]:.0f}" for seed in seeds))
        se = spread.sd / math.sqrt(n) if n > 1 else math.nan
        lines.append(
            f"  mean {spread.mean:.1f} %, sd {spread.sd:.1f}, SE {se:.1f}; "
            f"{spread.at_least(threshold)} of {n} seeds at >= {threshold:g} %"
        )
        reported = [spread.values[s] for s in seeds if s in report_seeds]
        others = [spread.values[s] for s in seeds if s not in report_seeds]
        if reported and others:
            lines.append(
                f"  report seeds {statistics.fmean(reported):.1f} % ({len(reported)}), "
                f"other seeds {statistics.fmean(others):.1f} % ({len(others)})"
            )
        lines.append(
            f"  chance that the mean of {draws} new seeds reaches {threshold:g} %: "
            f"{100 * spread.chance_mean_reaches(threshold, draws):.0f} %; that each of them does: "
            f"{100 * spread.chance_every_reaches(threshold, draws):.0f} % (normal approximation)"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--group", action="append", required=True, help="LABEL=GLOB; a label repeated pools")
    parser.add_argument("--at", type=int, required=True, help="the tick whose evaluation is read")
    parser.add_argument("--threshold", type=float, required=True, help="the target, in percent")
    parser.add_argument("--report-seeds", type=int, nargs="*", default=[0, 1, 2, 3, 4])
    parser.add_argument("--draws", type=int, default=5, help="seeds in the target's mean")
    args = parser.parse_args()
    print(report(collect(args.group, args.at), args.at, args.threshold, args.report_seeds, args.draws))


if __name__ == "__main__":
    main()
