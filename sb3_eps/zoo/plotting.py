"""Learning curves and aggregate metrics from run folders (``python -m sb3_eps.plot``).

Curves follow the paper's Fig. 4: smoothed training episodes against the ticks including EPS's, mean +/- std over
seeds. Aggregates: mean, median and IQM of the runs' final scores with stratified-bootstrap 95 % confidence
intervals (Agarwal et al., NeurIPS 2021), computed here (``docs/usage.md``).
"""

from __future__ import annotations

import json
import re
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import EngFormatter

from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.run_folder import EVALUATIONS_NAME, MONITOR_NAME, is_run_folder, read_args, read_monitor
from sb3_eps.zoo.schema import ALGORITHMS

PANELS = {"r": "team return", "success": "success rate"}


@dataclass
class RunCurve:
    """The training episodes of one run: ``x`` the ticks at each episode's end, EPS ticks included; ``values`` column
    -> per-episode values (``r``, ``success``...)."""

    run_dir: Path
    algo: str
    env_id: str
    x: np.ndarray
    values: dict[str, np.ndarray]


def find_run_dirs(paths: list[str | Path]) -> list[Path]:
    """:return: the run folders (holding ``monitor.csv`` and an ``args.yml``) at or below ``paths``, sorted.

    :raises ConfigError: when a path does not exist or none holds a run
    """
    found: set[Path] = set()
    for path in map(Path, paths):
        if not path.exists():
            raise ConfigError(f"{path} does not exist")
        candidates = [path] if (path / MONITOR_NAME).is_file() else [p.parent for p in path.rglob(MONITOR_NAME)]
        found.update(c for c in candidates if is_run_folder(c))
    if not found:
        raise ConfigError(f"no run folder (with {MONITOR_NAME} and args.yml) in {', '.join(map(str, paths))}")
    return sorted(found)


def load_curve(run_dir: Path) -> RunCurve:
    """Read a run's ``monitor.csv``: x = ``ticks + eps_ticks`` at each episode's end."""
    args = read_args(run_dir)
    _, columns = read_monitor(run_dir / MONITOR_NAME)
    if "ticks" not in columns:
        columns = {"ticks": np.zeros(0), "eps_ticks": np.zeros(0), "r": np.zeros(0)}
    x = columns["ticks"] + columns.get("eps_ticks", np.zeros_like(columns["ticks"]))
    values = {key: columns[key] for key in PANELS if key in columns}
    return RunCurve(run_dir, str(args["algo"]), str(args["env"]), x, values)


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` values (fewer at the start), as the paper smooths its curves."""
    if window < 1:
        raise ValueError(f"the smoothing window must be >= 1, got {window}")
    sums = np.cumsum(np.insert(np.asarray(values, dtype=float), 0, 0.0))
    ends = np.arange(1, len(values) + 1)
    starts = np.maximum(ends - window, 0)
    return (sums[ends] - sums[starts]) / (ends - starts)


def group_curves(
    curves: list[RunCurve], key: str, window: int, n_points: int = 200
) -> dict[tuple[str, str], dict[str, np.ndarray]]:
    """Mean and std over the runs of each (env id, algorithm) on a common grid of ticks.

    :return: ``{(env_id, algo): {"x", "mean", "std", "n_runs"}}`` for the runs that report ``key``
    """
    groups: dict[tuple[str, str], list[RunCurve]] = defaultdict(list)
    for curve in curves:
        if key in curve.values and len(curve.x) > 0:
            groups[(curve.env_id, curve.algo)].append(curve)
    result = {}
    for group, members in groups.items():
        end = min(float(curve.x[-1]) for curve in members)
        start = max(float(curve.x[0]) for curve in members)
        grid = np.linspace(start, end, n_points) if end > start else np.array([end])
        stacked = np.stack([np.interp(grid, curve.x, smooth(curve.values[key], window)) for curve in members])
        result[group] = {
            "x": grid,
            "mean": stacked.mean(0),
            "std": stacked.std(0),
            "n_runs": np.array(len(members)),
        }
    return result


def label_of(algo: str) -> str:
    """:return: the paper's name of an algorithm (``eps_gdq`` -> ``EPS-GDQ``)."""
    return ALGORITHMS[algo].label if algo in ALGORITHMS else algo


def draw_learning_curves(curves: list[RunCurve], window: int = 100, title: str | None = None) -> Figure:
    """The learning curves as a figure: one column per env id, rows team return and (if reported) success rate.

    The figure is made without pyplot, so drawing it neither needs nor changes a backend (a notebook shows it with
    ``display(figure)``).

    :param curves: the runs (:func:`load_curve` or :func:`evaluation_curves`)
    :param window: episodes of the trailing mean (1: no smoothing)
    :param title: prefix of each column's title
    :return: the figure
    """
    env_ids = sorted({curve.env_id for curve in curves}, key=natural_key)  # 2, 4, 8, 12 robots, not 12, 2, 4, 8
    keys = [key for key in PANELS if any(key in curve.values for curve in curves)]
    figure = Figure(figsize=(5.5 * len(env_ids), 3.4 * len(keys)))
    axes = figure.subplots(len(keys), len(env_ids), squeeze=False)
    for row, key in enumerate(keys):
        grouped = group_curves(curves, key, window)
        for column, env_id in enumerate(env_ids):
            axis = axes[row][column]
            for (group_env, algo), stats in sorted(grouped.items()):
                if group_env != env_id:
                    continue
                label = f"{label_of(algo)} ({int(stats['n_runs'])} run{'s' if stats['n_runs'] > 1 else ''})"
                axis.plot(stats["x"], stats["mean"], label=label)
                axis.fill_between(stats["x"], stats["mean"] - stats["std"], stats["mean"] + stats["std"], alpha=0.2)
            axis.set_xlabel("ticks (training + EPS)")
            axis.xaxis.set_major_formatter(EngFormatter(sep=""))  # 150k ticks
            axis.set_ylabel(PANELS[key] if window == 1 else f"{PANELS[key]} ({window}-episode mean)")
            if row == 0:
                axis.set_title(env_id if title is None else f"{title}: {env_id}")
            axis.grid(alpha=0.3)
            axis.legend(fontsize="small")
    figure.tight_layout()
    return figure


def natural_key(text: str) -> list[Any]:
    """:return: a sort key that orders the numbers inside ``text`` by value (``"Nav-2-v0"`` before ``"Nav-12-v0"``)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]


def plot_learning_curves(curves: list[RunCurve], output: str | Path, window: int = 100, title: str | None = None) -> Path:
    """Draw the learning curves (:func:`draw_learning_curves`) into an image file.

    :return: the image's path
    """
    figure = draw_learning_curves(curves, window, title)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(output, dpi=120)
    return output


# ---------------------------------------------------------------------------------------------- aggregates
def interquartile_mean(values: np.ndarray) -> float:
    """The mean of the middle 50 % of the values (``scipy.stats.trim_mean(values, 0.25)``)."""
    ordered = np.sort(np.ravel(values))
    cut = int(0.25 * len(ordered))
    return float(ordered[cut : len(ordered) - cut].mean())


AGGREGATES: dict[str, Callable[[np.ndarray], float]] = {
    "mean": lambda x: float(np.mean(x)),
    "median": lambda x: float(np.median(x)),
    "iqm": interquartile_mean,
}


def bootstrap_intervals(
    scores: dict[str, list[float]], n_resamples: int = 2_000, confidence: float = 0.95, seed: int = 0
) -> dict[str, tuple[float, float, float]]:
    """Point estimates and stratified-bootstrap percentile intervals of :data:`AGGREGATES` over one algorithm's
    runs (tasks = env ids are resampled separately, runs with replacement inside each).

    :param scores: env id -> final scores of the runs
    :return: aggregate name -> ``(estimate, low, high)``
    """
    rng = np.random.default_rng(seed)
    tasks = [np.asarray(values, dtype=float) for values in scores.values() if len(values)]
    everything = np.concatenate(tasks)
    result = {}
    for name, function in AGGREGATES.items():
        resampled = np.array(
            [
                function(np.concatenate([task[rng.integers(len(task), size=len(task))] for task in tasks]))
                for _ in range(n_resamples)
            ]
        )
        tail = 100 * (1 - confidence) / 2
        result[name] = (
            float(function(everything)),
            float(np.percentile(resampled, tail)),
            float(np.percentile(resampled, 100 - tail)),
        )
    return result


def aggregate_table(curves: list[RunCurve], key: str, window: int) -> list[dict[str, Any]]:
    """Per algorithm: number of runs and mean / median / IQM of the final scores with 95 % CIs
    (:func:`bootstrap_intervals`)."""
    scores: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for curve in curves:  # a run's final score: the mean of its last window episodes
        if key in curve.values and len(curve.values[key]):
            scores[curve.algo][curve.env_id].append(float(np.mean(curve.values[key][-window:])))
    rows = []
    for algo, by_env in sorted(scores.items()):
        intervals = bootstrap_intervals(by_env)
        row: dict[str, Any] = {
            "algo": label_of(algo),
            "metric": key,
            "n_runs": sum(len(v) for v in by_env.values()),
        }
        for name, (estimate, low, high) in intervals.items():
            row.update({name: estimate, f"{name}_low": low, f"{name}_high": high})
        rows.append(row)
    return rows


def format_aggregates(rows: list[dict[str, Any]]) -> str:
    """:return: the aggregate rows as a Markdown table."""
    lines = [
        "| algorithm | metric | runs | mean [95 % CI] | median [95 % CI] | IQM [95 % CI] |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        cells = [f"{row[n]:.3f} [{row[n + '_low']:.3f}, {row[n + '_high']:.3f}]" for n in AGGREGATES]
        lines.append(f"| {row['algo']} | {PANELS[row['metric']]} | {row['n_runs']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def evaluation_curves(run_dirs: list[Path]) -> list[RunCurve]:
    """The periodic greedy evaluations (``evaluations.npz``) of runs as curves (x = ticks + EPS ticks)."""
    curves = []
    for run_dir in run_dirs:
        path = run_dir / EVALUATIONS_NAME
        if not path.is_file():
            continue
        args = read_args(run_dir)
        data = np.load(path)
        values = {"r": data["results"].mean(axis=1)}
        if not np.isnan(data["successes"]).all():
            values["success"] = np.nanmean(data["successes"], axis=1)
        curves.append(RunCurve(run_dir, str(args["algo"]), str(args["env"]), data["ticks"] + data["eps_ticks"], values))
    return curves


#: ``<algo>_<env id>_seed<k>.jsonl``: algorithm names are lower case with underscores (``eps_gdq``), env ids have
#: no underscore and end in ``-v<N>``.
RECORD_FILE = re.compile(r"^(?P<algo>[a-z][a-z_]*?)_(?P<env_id>[A-Za-z0-9-]+-v\d+)_seed(?P<seed>\d+)\.jsonl$")
#: The fields of a record that the curves draw.
RECORD_COLUMNS = ("ticks", "team_return_mean", "success_rate")


def record_curves(paths: list[str | Path], label: str | None = None) -> list[RunCurve]:
    """Greedy-evaluation records (``<algo>_<env id>_seed<k>.jsonl`` of ``benchmarks/learning_check.py``, whose
    ``ticks`` count the EPS ticks too) as curves, one per file, to draw beside run folders.

    :param paths: such files, or folders searched for ``*.jsonl`` directly inside
    :param label: the group name of every curve (default: the algorithm of the file name, e.g. ``eps_gdq``)
    :raises ConfigError: when a path does not exist or a file is not such a record
    """
    files: list[Path] = []
    for path in map(Path, paths):
        if not path.exists():
            raise ConfigError(f"{path} does not exist")
        files.extend(sorted(path.glob("*.jsonl")) if path.is_dir() else [path])
    curves = []
    for file in files:
        match = RECORD_FILE.match(file.name)
        try:
            records = [json.loads(line) for line in file.read_text().splitlines() if line.strip()]
            columns = {key: np.array([float(record[key]) for record in records]) for key in RECORD_COLUMNS}
        except (ValueError, KeyError, TypeError) as error:
            raise ConfigError(f"{file}: not an evaluation record ({error})") from error
        if match is None:
            raise ConfigError(f"{file}: not an evaluation record (<algo>_<env id>_seed<k>.jsonl)")
        values = {"r": columns["team_return_mean"], "success": columns["success_rate"]}
        curves.append(RunCurve(file, label or match["algo"], match["env_id"], columns["ticks"], values))
    return curves
