"""The MPE report tables of ``docs/results/mpe.md`` (rule M4) from Table I's records.

Reads the run folders of ``docs/results/paper/runs/table1/<algo>/CooperativeNavigation-v0_seed<k>/`` (written by
``python research/paper_page.py run`` or ``adopt``): the final evaluation (``eval_seed6000.json``, 100 greedy team
episodes), the training curve (``training_curve.csv`` or ``monitor.csv``), the in-training greedy curve
(``evaluations.npz``) and the EPS rounds. Prints, per algorithm, one markdown row per seed and a mean (SE) row; then
each comparison of the paper's ordering paired by seed (GDQ - IL, EPS-IL - IL, EPS-GDQ - GDQ: the mean difference of
the final team return, its standard error, and on how many seeds the first is ahead)::

    python research/mpe_report.py [--runs docs/results/paper/runs/table1] [--algos iql gdq eps_iql eps_gdq]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # sb3_eps sits beside research/

from research import paper_page
from sb3_eps.zoo.plotting import label_of

COLUMNS = ("team return", "per tick", "success", "occupied", "distance sum", "collisions per tick",
           "collision (all / spawn out)", "over training: return, collision % (spawn out)", "curve, 250k-2M",
           "EPS crossovers / rounds", "minutes")  # fmt: skip
#: The paper's orderings of Table I, as (better, base) pairs.
PAIRS = (("gdq", "iql"), ("eps_iql", "iql"), ("eps_gdq", "gdq"))


def seeds_of(runs: Path, algo: str) -> dict[int, paper_page.Seed]:
    """seed -> the finished run's :class:`paper_page.Seed` (runs without a final evaluation are left out)."""
    cell = paper_page.run_cell(runs, algo, paper_page.MPE)
    found = {}
    for seed in cell.seeds if cell else []:
        if seed.final_eval is not None:
            found[int(seed.source.rsplit("seed", 1)[1])] = seed
    return found


FINAL_KEYS = ("team_return_mean", "success_rate", "occupied_landmarks_mean", "min_dist_sum_mean",
              "collisions_per_tick_mean", "collision_rate", "collision_after_spawn_rate")  # fmt: skip
TRAINING_KEYS = ("r", "collision", "collision_after_spawn")


def measures(final: dict[str, float], training: dict[str, float], success_digits: int = 0) -> list[str]:
    """The columns from "per tick" to "over training" of a seed's (or the seeds' mean) final evaluation and
    training means."""
    return [
        f"{final['team_return_mean'] / paper_page.EPISODE_TICKS_MPE:.2f}",
        f"{100 * final['success_rate']:.{success_digits}f} %",
        f"{final['occupied_landmarks_mean']:.2f}",
        f"{final['min_dist_sum_mean']:.2f}",
        f"{final['collisions_per_tick_mean']:.3f}",
        f"{100 * final['collision_rate']:.0f} % / {100 * final['collision_after_spawn_rate']:.0f} %",
        f"{training.get('r', math.nan):.1f}, {100 * training.get('collision', math.nan):.0f} %"
        f" ({100 * training.get('collision_after_spawn', math.nan):.0f} %)",
    ]


def row(label: str, seed: paper_page.Seed) -> list[str]:
    final = seed.final_eval or {}
    crossovers = "-" if seed.eps_rounds is None else f"{seed.eps_rounds[1]} / {seed.eps_rounds[0]}"
    return [
        label,
        f"{final['team_return_mean']:.1f}",
        *measures(final, seed.training),
        " ".join(f"{value:.0f}" for value in seed.team_return),
        crossovers,
        f"{seed.wall_s / 60:.1f}",
    ]


def mean_row(seeds: list[paper_page.Seed]) -> list[str]:
    final = {key: float(np.mean([seed.final_eval[key] for seed in seeds])) for key in FINAL_KEYS}  # type: ignore[index]
    training = {key: float(np.mean([seed.training.get(key, math.nan) for seed in seeds])) for key in TRAINING_KEYS}
    returns = np.array([seed.final_eval["team_return_mean"] for seed in seeds])  # type: ignore[index]
    se = returns.std(ddof=1) / math.sqrt(len(returns)) if len(returns) > 1 else math.nan
    return [
        f"**mean (SE), {len(seeds)} seed{'s' * (len(seeds) > 1)}**",
        f"**{returns.mean():.1f}" + (f" ({se:.1f})**" if math.isfinite(se) else "**"),
        *measures(final, training, success_digits=1),
        "",
        "",
        f"{np.mean([seed.wall_s for seed in seeds]) / 60:.1f}",
    ]


def paired(first: dict[int, paper_page.Seed], base: dict[int, paper_page.Seed]) -> str | None:
    """Mean difference of the final team return over the seeds both have, its SE, and the seeds ``first`` leads."""
    common = sorted(first.keys() & base.keys())
    if not common:
        return None
    diff = np.array([first[s].final_eval["team_return_mean"] - base[s].final_eval["team_return_mean"] for s in common])  # type: ignore[index]
    se = diff.std(ddof=1) / math.sqrt(len(diff)) if len(diff) > 1 else math.nan
    spread = f" (SE {se:.1f})" if math.isfinite(se) else ""
    return (
        f"{diff.mean():+.1f}{spread}, ahead on {int((diff > 0).sum())} of {len(common)} seeds ({', '.join(map(str, common))})"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=paper_page.RUNS / "table1")
    parser.add_argument("--algos", nargs="+", default=list(paper_page.TABLE1_ALGOS))
    args = parser.parse_args(argv)
    found = {algo: seeds_of(args.runs, algo) for algo in args.algos}
    for algo, seeds in found.items():
        if not seeds:
            continue
        print(f"\n{label_of(algo)} (`{algo}`):\n")
        print("| seed | " + " | ".join(COLUMNS) + " |")
        print("|---" * (len(COLUMNS) + 1) + "|")
        for seed_number, seed in sorted(seeds.items()):
            print("| " + " | ".join(row(str(seed_number), seed)) + " |")
        print("| " + " | ".join(mean_row(list(seeds.values()))) + " |")
    print()
    for first, base in PAIRS:
        if first in found and base in found and (line := paired(found[first], found[base])):
            print(f"- {label_of(first)} - {label_of(base)}, final greedy team return paired by seed: {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
