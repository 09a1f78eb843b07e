"""Compare EPS-<algo> with <algo> at equal total ticks, from ``benchmarks/learning_check.py`` records (issue 10).

Each folder holds one record file per seed (``[eps_]<algo>_<env>_seed<k>.jsonl``); an EPS record's ``ticks`` count
its training ticks plus its EPS evaluation ticks, as the paper's curves do. Per seed and over the seeds common to
both folders this prints:

- ticks to 80 % and to 90 % (the first evaluation at or above; "-" if never),
- the mean of the last 3 evaluations scheduled at or before ``--budget`` total ticks (the floor of issue 10 compares
  these),
- the area under the success curve from 0 to ``--budget``, as a share of the best possible (success 1 throughout;
  the curve starts at 0 success and 0 ticks, and holds its last value to the budget),

Every evaluation counts at the point it was scheduled for, a multiple of ``--eval-every``: an EPS run evaluates at the
first step at or after each point, and a round can carry its total past the point (90,051 or 104,763 ticks for the
90k and 100k points; a run of 4 worlds also ends 1-3 ticks past its budget, since its counter moves 4 ticks at a
time). Cutting at the recorded total instead would drop an EPS run's final evaluation and average earlier ones; the
records keep the exact totals, and the overshoot is part of the EPS ticks listed.
- the floor (EPS mean of the last 3 at most 3 points below the base's) and the paper's target (EPS mean >= 90 %
  within ``--target-ticks``, reached in at least 1.5x fewer ticks than the base needs for 90 %).

Example::

    python benchmarks/compare_eps.py docs/results/baselines/gdq4_final docs/results/eps/eps_gdq4 --budget 150000 \\
        --plot docs/results/eps/eps_gdq4.png
"""

from __future__ import annotations

import argparse
import pathlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # research/ sits beside the package

from research.results import EvaluationRun, read_evaluation_run


def read_runs(folder: pathlib.Path) -> dict[int, EvaluationRun]:
    """:return: seed -> the evaluations of that seed (``sb3_eps.zoo.plotting``' reader of the committed records)."""
    runs = {run.seed: run for run in map(read_evaluation_run, sorted(folder.glob("*_seed*.jsonl")))}
    if not runs:
        raise SystemExit(f"{folder}: no <algo>_<env id>_seed<k>.jsonl record files")
    return runs


def ticks_to(run: EvaluationRun, level: float) -> int | None:
    """:return: the ticks of the first evaluation at or above ``level``, or None."""
    reached = run.ticks[run.metrics["success_rate"] >= level]
    return int(reached[0]) if len(reached) else None


def scheduled(run: EvaluationRun, every: int) -> np.ndarray:
    """:return: the point each evaluation was scheduled for: its ticks rounded down to a multiple of ``every``."""
    return run.ticks // every * every


def last_mean(run: EvaluationRun, budget: int, every: int, n: int = 3) -> float:
    """:return: the mean success of the last ``n`` evaluations scheduled at or before ``budget`` ticks."""
    within = run.metrics["success_rate"][scheduled(run, every) <= budget]
    return float(np.mean(within[-n:])) if len(within) else float("nan")


def area(run: EvaluationRun, budget: int, every: int) -> float:
    """:return: the area under success(ticks) on [0, budget] over ``budget`` (0 at 0 ticks; the last value held),
    every evaluation at the point it was scheduled for."""
    points = scheduled(run, every)
    within = points <= budget
    x = np.concatenate([[0.0], points[within], [budget]])
    y = np.concatenate([[0.0], run.metrics["success_rate"][within]])
    y = np.append(y, y[-1])
    return float(np.trapezoid(y, x) / budget)


def last_value(run: EvaluationRun, key: str) -> int:
    """:return: the last record's ``key`` (0 when the records do not have it: a run without EPS)."""
    return int(run.metrics[key][-1]) if key in run.metrics else 0


def summary(runs: dict[int, EvaluationRun], seeds: list[int], budget: int, every: int) -> dict[str, list]:
    """:return: per-seed figures, in the order of ``seeds``."""
    return {
        "to80": [ticks_to(runs[s], 0.8) for s in seeds],
        "to90": [ticks_to(runs[s], 0.9) for s in seeds],
        "last3": [last_mean(runs[s], budget, every) for s in seeds],
        "auc": [area(runs[s], budget, every) for s in seeds],
        "eps_ticks": [last_value(runs[s], "eps_ticks") for s in seeds],
        "crossovers": [last_value(runs[s], "eps_crossovers") for s in seeds],
        "rounds": [last_value(runs[s], "eps_rounds") for s in seeds],
    }


def paired_difference(base_last3: list[float], eps_last3: list[float]) -> dict[str, float]:
    """The seed-by-seed differences EPS minus base of the mean of the last 3 (the runs of a seed share everything
    up to the first EPS round, so the pairs are the unit of comparison).

    :return: ``mean`` and ``std`` (sample, ``ddof=1``) of the differences, ``sem`` (``std / sqrt(n)``; NaN for
        one seed), ``n`` and ``ahead`` (seeds where EPS is above its base)
    """
    differences = np.asarray(eps_last3, dtype=float) - np.asarray(base_last3, dtype=float)
    if differences.size == 0:
        raise ValueError("no pairs to compare")
    n = int(differences.size)
    std = float(differences.std(ddof=1)) if n > 1 else float("nan")
    return {
        "mean": float(differences.mean()),
        "std": std,
        "sem": std / np.sqrt(n),
        "n": n,
        "ahead": int((differences > 0).sum()),
    }


def mean_curve(runs: dict[int, EvaluationRun], seeds: list[int], at: list[int]) -> list[float]:
    """:return: the mean over seeds of success interpolated at ``at`` ticks."""
    curves = [np.interp(at, runs[s].ticks, runs[s].metrics["success_rate"]) for s in seeds]
    return [float(value) for value in np.mean(curves, axis=0)]


def report(base_dir: pathlib.Path, eps_dir: pathlib.Path, budget: int, target_ticks: int, every: int = 10_000) -> str:
    base, eps = read_runs(base_dir), read_runs(eps_dir)
    unfinished = {seed for runs in (base, eps) for seed, run in runs.items() if run.ticks[-1] < budget}
    seeds = sorted((set(base) & set(eps)) - unfinished)
    if unfinished:
        print(f"left out, not at {budget} ticks yet: seeds {sorted(unfinished)}")
    if not seeds:
        raise SystemExit(f"no seed in common between {base_dir} and {eps_dir}")
    figures = {"base": summary(base, seeds, budget, every), "eps": summary(eps, seeds, budget, every)}
    names = {"base": base_dir.name, "eps": eps_dir.name}

    def ticks_text(value: int | None) -> str:
        return "-" if value is None else f"{value / 1000:.0f}k"

    lines = [
        f"Budget {budget // 1000}k total ticks (training + EPS); seeds {seeds}.",
        "",
        "| run | seed | ticks to 80 % | ticks to 90 % | mean of last 3 | area under curve | EPS ticks | "
        "EPS rounds (crossovers) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for key in ("base", "eps"):
        f = figures[key]
        for index, seed in enumerate(seeds):
            eps_cells = (
                f"{f['eps_ticks'][index]} | {f['rounds'][index]} ({f['crossovers'][index]})" if key == "eps" else "- | -"
            )
            lines.append(
                f"| {names[key]} | {seed} | {ticks_text(f['to80'][index])} | {ticks_text(f['to90'][index])} | "
                f"{f['last3'][index]:.1%} | {f['auc'][index]:.3f} | {eps_cells} |"
            )
    lines.append("")
    means = {key: float(np.mean(figures[key]["last3"])) for key in figures}
    aucs = {key: float(np.mean(figures[key]["auc"])) for key in figures}
    gap = 100 * (means["eps"] - means["base"])
    lines.append(
        f"Mean of the last 3 evaluations: {names['base']} {means['base']:.1%}, {names['eps']} {means['eps']:.1%} "
        f"({gap:+.1f} points). Area under the curve: {aucs['base']:.3f} against {aucs['eps']:.3f}."
    )
    lines.append(f"Floor (EPS at most 3 points below at equal total ticks): {'met' if gap >= -3 else 'NOT met'}.")
    pairs = paired_difference(figures["base"]["last3"], figures["eps"]["last3"])
    lines.append(
        f"Seed by seed (EPS minus base, mean of the last 3): {100 * pairs['mean']:+.1f} points on average, "
        f"standard deviation {100 * pairs['std']:.1f}, standard error {100 * pairs['sem']:.1f}; EPS ahead on "
        f"{pairs['ahead']} of {pairs['n']} seeds."
    )
    grid = list(range(10_000, target_ticks + 1, 10_000))
    eps_mean = mean_curve(eps, seeds, grid)
    base_mean = mean_curve(base, seeds, list(range(10_000, budget + 1, 10_000)))
    eps_90 = next((t for t, m in zip(grid, eps_mean) if m >= 0.9), None)
    base_90 = next((t for t, m in zip(range(10_000, budget + 1, 10_000), base_mean) if m >= 0.9), None)
    lines.append(
        f"Mean over seeds (interpolated every 10k ticks): {names['eps']} best {max(eps_mean):.1%} within "
        f"{target_ticks // 1000}k, reaching 90 % at {ticks_text(eps_90)}; {names['base']} reaches 90 % at "
        f"{ticks_text(base_90)} (within {budget // 1000}k). Target (>= 90 % within {target_ticks // 1000}k, "
        f"1.5x fewer ticks): {'met' if eps_90 is not None and (base_90 is None or base_90 >= 1.5 * eps_90) else 'NOT met'}."
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("base", type=pathlib.Path, help="records of the base algorithm")
    parser.add_argument("eps", type=pathlib.Path, help="records of EPS-<algo> (ticks include EPS ticks)")
    parser.add_argument("--budget", type=int, required=True, help="total ticks compared")
    parser.add_argument("--target-ticks", type=int, default=100_000)
    parser.add_argument("--eval-every", type=int, default=10_000, help="the evaluation spacing of the runs, in ticks")
    parser.add_argument("--plot", type=pathlib.Path, default=None, help="draw both (mean +/- std over seeds)")
    args = parser.parse_args()
    print(report(args.base, args.eps, args.budget, args.target_ticks, args.eval_every))
    if args.plot is not None:
        from sb3_eps.zoo.plotting import plot_learning_curves, record_curves

        curves = record_curves([args.base, args.eps])
        episodes = {
            int(n)
            for folder in (args.base, args.eps)
            for run in read_runs(folder).values()
            for n in run.metrics.get("n_episodes", [])
        }
        counts = "/".join(str(n) for n in sorted(episodes)) or "?"
        plot_learning_curves(curves, args.plot, window=1, title=f"greedy evaluations ({counts} episodes)")
        print(f"picture: {args.plot}")


if __name__ == "__main__":
    main()
