"""Research tooling, outside the installed package: committed results as tables and figures: the greedy-evaluation records of ``benchmarks/learning_check.py``
(``docs/results/**/<algo>_<env id>_seed<k>.jsonl``, one JSON object per evaluation) and SB3's ``progress.csv`` logs.

Run folders of ``python -m sb3_eps.train`` have their own reader and plots (:mod:`sb3_eps.zoo.plotting`); this
module reads what the results pages are made from, so a notebook (``notebooks/03_compare.ipynb``) or a script can
redraw them. Figures are made without pyplot (``display(figure)`` shows one in a notebook).

Example::

    runs = find_evaluation_runs("docs/results")
    print(format_table(results_table(runs)))
    figure = draw_seed_curves(group_runs(runs, ("algo", "env_id")))
"""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from sb3_eps.zoo.plotting import RECORD_FILE

__all__ = [
    "RECORD_FILE",
    "EvaluationRun",
    "best_covered",
    "draw_seed_curves",
    "find_evaluation_runs",
    "format_table",
    "group_runs",
    "read_evaluation_run",
    "read_progress",
    "results_table",
]


@dataclass
class EvaluationRun:
    """The greedy evaluations of one seed of one configuration.

    :param path: the JSON-lines file
    :param group: the configuration's name (the file's folder below the searched root)
    :param algo: algorithm name (``gdq``, ``eps_gdq``...)
    :param env_id: env id
    :param seed: the seed
    :param ticks: ``(n,)`` ticks at each evaluation (EPS records count the EPS ticks too)
    :param metrics: ``{name: (n,) values}`` of every numeric field of the records (``success_rate``...)
    """

    path: Path
    group: str
    algo: str
    env_id: str
    seed: int
    ticks: np.ndarray
    metrics: dict[str, np.ndarray] = field(default_factory=dict)

    def final(self, key: str = "success_rate") -> float:
        """:return: the last evaluation's value of ``key`` (NaN without evaluations)."""
        values = self.metrics.get(key, np.zeros(0))
        return float(values[-1]) if len(values) else math.nan


def read_evaluation_run(path: str | Path, group: str | None = None) -> EvaluationRun:
    """Read one ``<algo>_<env id>_seed<k>.jsonl`` file.

    :param path: the file
    :param group: the configuration's name; None: the file's folder name
    :raises ValueError: when the file name does not follow the pattern or a record has no ``ticks``
    """
    path = Path(path)
    match = RECORD_FILE.match(path.name)
    if match is None:
        raise ValueError(f"{path.name}: not an evaluation record name (<algo>_<env id>_seed<k>.jsonl)")
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if any("ticks" not in record for record in records):
        raise ValueError(f"{path}: every record needs 'ticks'")
    numeric = sorted(
        {key for record in records for key, value in record.items() if isinstance(value, int | float)} - {"ticks"}
    )
    metrics = {key: np.array([float(record.get(key, math.nan)) for record in records]) for key in numeric}
    return EvaluationRun(
        path=path,
        group=group if group is not None else path.parent.name,
        algo=match["algo"],
        env_id=match["env_id"],
        seed=int(match["seed"]),
        ticks=np.array([int(record["ticks"]) for record in records], dtype=np.int64),
        metrics=metrics,
    )


def find_evaluation_runs(root: str | Path, pattern: str = "**/*_seed*.jsonl") -> list[EvaluationRun]:
    """Every evaluation record below ``root`` whose name follows :data:`RECORD_FILE` (others are skipped).

    :param root: a results folder (``docs/results``)
    :param pattern: glob below ``root``
    :return: the runs, sorted by group, algorithm, env id and seed; a run's group is its folder relative to
        ``root`` (``baselines/gdq4_final``)
    """
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"{root} is not a folder")
    runs = []
    for path in sorted(root.glob(pattern)):
        if RECORD_FILE.match(path.name) and path.stat().st_size > 0:
            folder = path.parent.relative_to(root).as_posix()
            runs.append(read_evaluation_run(path, group=folder if folder != "." else root.name))
    return sorted(runs, key=lambda run: (run.group, run.algo, run.env_id, run.seed))


def group_runs(
    runs: Iterable[EvaluationRun], by: Sequence[str] = ("group", "algo", "env_id")
) -> dict[str, list[EvaluationRun]]:
    """Gather the seeds of each configuration.

    :param runs: evaluation runs
    :param by: the attributes that name a configuration
    :return: ``{"value / value ...": [runs]}`` in sorted order
    """
    groups: dict[str, list[EvaluationRun]] = defaultdict(list)
    for run in runs:
        groups[" / ".join(str(getattr(run, name)) for name in by)].append(run)
    return dict(sorted(groups.items()))


def best_covered(runs: Iterable[EvaluationRun], env_id: str) -> dict[str, list[EvaluationRun]]:
    """For each algorithm measured on ``env_id``, the group with the most seeds (then the longest runs).

    Picks what to compare without a hard-coded list of folders, so new records (``eps_gdq_*``) join by themselves.

    :return: ``{"<algo> (<group>)": [runs]}``
    """
    candidates: dict[str, dict[str, list[EvaluationRun]]] = defaultdict(lambda: defaultdict(list))
    for run in runs:
        if run.env_id == env_id:
            candidates[run.algo][run.group].append(run)
    chosen = {}
    for algo, groups in sorted(candidates.items()):
        group, members = max(groups.items(), key=lambda item: (len(item[1]), min(int(run.ticks[-1]) for run in item[1])))
        chosen[f"{algo} ({group})"] = members
    return chosen


def results_table(runs: Iterable[EvaluationRun], key: str = "success_rate") -> list[dict[str, Any]]:
    """One row per configuration: seeds, the last evaluation's ticks and ``key`` (mean, std, per seed).

    :param runs: evaluation runs
    :param key: the metric
    :return: rows with ``group``, ``algo``, ``env_id``, ``seeds``, ``ticks``, ``mean``, ``std``, ``per_seed``
    """
    rows = []
    for members in group_runs(runs).values():
        finals = np.array([run.final(key) for run in members])
        first = members[0]
        rows.append(
            {
                "group": first.group,
                "algo": first.algo,
                "env_id": first.env_id,
                "seeds": len(members),
                "ticks": min(int(run.ticks[-1]) if len(run.ticks) else 0 for run in members),
                "mean": float(np.nanmean(finals)) if np.isfinite(finals).any() else math.nan,
                "std": float(np.nanstd(finals)) if np.isfinite(finals).any() else math.nan,
                "per_seed": " / ".join(f"{value:.2f}" for value in finals),
            }
        )
    return rows


#: Keys of older ``progress.csv`` files (the committed records in docs/results keep them) -> the SB3 keys now written.
LEGACY_PROGRESS_KEYS = {
    "eval/team_return": "eval/mean_reward",
    "eval/length": "eval/mean_ep_length",
    "eval/team_return_std": "eval/std_reward",
    "rollout/team_return": "rollout/ep_rew_mean",
}


def read_progress(path: str | Path) -> dict[str, np.ndarray]:
    """Read SB3's ``progress.csv`` (columns appear as they are first logged, so earlier rows leave them empty).

    A file written before SB3's evaluation keys were used also gets them, copied from its old keys
    (:data:`LEGACY_PROGRESS_KEYS`), so one reader serves old and new runs.

    :return: ``{column: (rows,) float values}``, NaN where a row has no value
    """
    with Path(path).open(newline="") as file:
        rows = list(csv.DictReader(file))
    names = sorted({key for row in rows for key in row if key})
    columns = {name: np.array([_to_float(row.get(name)) for row in rows], dtype=float) for name in names}
    for old, new in LEGACY_PROGRESS_KEYS.items():
        if old in columns and new not in columns:
            columns[new] = columns[old]
    return columns


def _to_float(text: str | None) -> float:
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def draw_seed_curves(
    groups: Mapping[str, Sequence[EvaluationRun | tuple[np.ndarray, np.ndarray]]],
    key: str = "success_rate",
    title: str | None = None,
    xlabel: str = "ticks",
    ylabel: str | None = None,
    axis: Any = None,
) -> Figure:
    """Every seed as a thin line and the mean over the seeds as a thick one, one colour per group.

    :param groups: ``{label: runs}`` (:func:`group_runs`, :func:`best_covered`), or ``{label: [(x, y), ...]}``
        for curves of any source (e.g. :func:`read_progress` columns)
    :param key: the metric of :class:`EvaluationRun` groups (rates are drawn in %)
    :param title: the axis title
    :param xlabel: the x label
    :param ylabel: the y label (default: ``key``)
    :param axis: draw into this matplotlib axis (its figure is returned); None: a new figure
    :return: the figure
    """
    if axis is None:
        figure = Figure(figsize=(7, 4))
        axis = figure.subplots()
    else:
        figure = axis.figure
    percent = key.endswith("_rate")
    for index, (label, members) in enumerate(groups.items()):
        curves = [_xy(member, key) for member in members]
        curves = [(x, 100 * y if percent else y) for x, y in curves if len(x)]
        if not curves:
            continue
        color = f"C{index % 10}"
        for x, y in curves:
            axis.plot(x, y, color=color, alpha=0.3, linewidth=1)
        x_mean, y_mean = _mean_curve(curves)
        axis.plot(
            x_mean,
            y_mean,
            color=color,
            linewidth=2.5,
            label=f"{label} ({len(curves)} seed{'s' if len(curves) > 1 else ''})",
        )
    axis.set_xlabel(xlabel)
    axis.set_ylabel(ylabel or (f"{key} (%)" if percent else key))
    if title:
        axis.set_title(title)
    axis.grid(alpha=0.3)
    axis.legend(fontsize="small")
    figure.tight_layout()
    return figure


def _xy(member: Any, key: str) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(member, EvaluationRun):
        return member.ticks.astype(float), member.metrics.get(key, np.full(len(member.ticks), math.nan))
    x, y = member
    keep = np.isfinite(np.asarray(x, dtype=float)) & np.isfinite(np.asarray(y, dtype=float))
    return np.asarray(x, dtype=float)[keep], np.asarray(y, dtype=float)[keep]


def _mean_curve(curves: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """The mean over seeds: at shared x values when the seeds share them, else interpolated on the common range."""
    x_sets = [set(x.tolist()) for x, _ in curves]
    shared = sorted(x_sets[0].intersection(*x_sets[1:]))
    if len(shared) >= 2:
        grid = np.array(shared)
        return grid, np.mean([y[np.searchsorted(x, grid)] for x, y in curves], axis=0)
    start, end = max(x[0] for x, _ in curves), min(x[-1] for x, _ in curves)
    grid = np.linspace(start, end, 100) if end > start else np.array([end])
    return grid, np.mean([np.interp(grid, x, y) for x, y in curves], axis=0)


def format_table(rows: list[dict[str, Any]], columns: list[str] | None = None, precision: int = 3) -> str:
    """Rows of dicts as a fixed-width text table: a header line, a rule and one line per row (``columns``
    default to the first row's keys; floats with ``precision`` significant digits)."""
    if not rows:
        return "(no rows)"
    columns = list(columns or rows[0])

    def cell(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.{precision}g}"
        return "" if value is None else str(value)

    cells = [[cell(row.get(column)) for column in columns] for row in rows]
    widths = [max(len(column), *(len(line[i]) for line in cells)) for i, column in enumerate(columns)]
    lines = ["  ".join(column.ljust(width) for column, width in zip(columns, widths, strict=True))]
    lines.append("  ".join("-" * width for width in widths))
    lines += ["  ".join(value.ljust(width) for value, width in zip(line, widths, strict=True)) for line in cells]
    return "\n".join(line.rstrip() for line in lines)


def seeds_line(records: list[dict[str, Any]]) -> str:
    """One line for a results page: the seeds' greedy success and collisions (``success_rate``, ``collision_rate``
    of one evaluation record per seed), each seed then the mean, in percent, with the standard error over seeds.

    :param records: one evaluation record per seed, in the order to print
    """
    success = [100 * record["success_rate"] for record in records]
    collision = [100 * record["collision_rate"] for record in records]
    spread = np.std(success, ddof=1) / np.sqrt(len(success)) if len(success) > 1 else float("nan")
    return (
        f"{' / '.join(f'{value:.0f}' for value in success)} -> {np.mean(success):.1f} % (s.e. {spread:.1f}),"
        f" collisions {' / '.join(f'{value:.0f}' for value in collision)} -> {np.mean(collision):.1f} %"
    )
