"""The crossovers' effect on the multi-robot policy, from the paired greedy team checks of EPS runs (issue 10).

An EPS run made with ``EvolutionCallback(n_team_check_episodes=k)`` plays the same ``k`` greedy episodes of the
training world before and after every crossover (``eps_rounds.jsonl`` in each run folder). This prints one row per
crossover and the mean change over all of them, with its standard error: the effect of the crossover itself, apart
from the ticks EPS takes from training.

Example::

    python benchmarks/crossover_effects.py docs/results/eps/diag_team_check/logs
"""

from __future__ import annotations

import argparse
import math
import pathlib
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # research/ sits beside the package

from research.eps_inspection import team_check_changes
from sb3_eps.eps.round_log import DIAGNOSTICS_NAME, read_round_log


def report(folders: list[pathlib.Path]) -> str:
    """:return: a markdown table of every checked crossover under ``folders`` and the mean change."""
    files = sorted(path for folder in folders for path in folder.rglob(DIAGNOSTICS_NAME))
    if not files:
        raise SystemExit(f"no {DIAGNOSTICS_NAME} under {', '.join(map(str, folders))}")
    lines = [
        "| run | round | training ticks | alpha | fitness gain | team success before | after | change | team return change |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    success, returns = [], []
    for path in files:
        for change in team_check_changes(read_round_log(path)):
            success.append(100 * change["success_change"])
            returns.append(change["return_change"])
            lines.append(
                f"| {path.parent.name} | {change['round']} | {change['model_ticks']:,} | {change['alpha']:.3f} "
                f"| {change['gain']:+.2f} | {100 * change['success_before']:.0f} % | {100 * change['success_after']:.0f} % "
                f"| {success[-1]:+.0f} | {returns[-1]:+.3f} |"
            )
    if not success:
        raise SystemExit("no crossover with a team check (run with n_team_check_episodes > 0)")
    lines.append("")
    lines.append(f"{len(success)} crossovers: success {_mean_se(success)} points, team return {_mean_se(returns, 3)}")
    return "\n".join(lines)


def _mean_se(values: list[float], digits: int = 1) -> str:
    mean = statistics.fmean(values)
    if len(values) < 2:
        return f"{mean:+.{digits}f}"
    sd = statistics.stdev(values)
    return f"{mean:+.{digits}f} (SD {sd:.{digits}f}, SE {sd / math.sqrt(len(values)):.{digits}f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=pathlib.Path, help="run folders (searched for eps_rounds.jsonl)")
    print(report(parser.parse_args().folders))


if __name__ == "__main__":
    main()
