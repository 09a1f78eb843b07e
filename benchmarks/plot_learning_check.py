"""Plot greedy team success against training ticks from ``learning_check.py`` records (one curve per group).

Each ``--group LABEL=GLOB`` names the JSON-lines files of one configuration (one file per seed); the plot shows
every seed as a thin line and the mean over seeds as a thick one, and the script prints the table behind it.

    python benchmarks/plot_learning_check.py --out docs/results/gdq_2robot.png \
        --group "IQL=docs/results/learning_check/iql_*.jsonl" \
        --group "GDQ=docs/results/learning_check/gdq_*.jsonl"
"""

from __future__ import annotations

import argparse
import glob
import json
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def read_group(pattern: str) -> dict[str, list[tuple[int, float]]]:
    """:return: ``{file stem: [(ticks, success_rate), ...]}`` for the files matching ``pattern``."""
    paths = sorted(glob.glob(pattern))
    if not paths:
        raise SystemExit(f"no files match {pattern!r}")
    runs = {}
    for path in paths:
        records = [json.loads(line) for line in pathlib.Path(path).read_text().splitlines() if line.strip()]
        runs[pathlib.Path(path).stem] = [(int(r["ticks"]), float(r["success_rate"])) for r in records]
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--group", action="append", required=True, help="LABEL=GLOB of JSON-lines files")
    parser.add_argument("--out", required=True, help="the PNG to write")
    parser.add_argument("--title", default="MultiRobotNav-2-v0: greedy team success (100 episodes)")
    args = parser.parse_args()
    fig, ax = plt.subplots(figsize=(7, 4))
    for index, spec in enumerate(args.group):
        label, _, pattern = spec.partition("=")
        if not pattern:
            raise SystemExit(f"--group must be LABEL=GLOB, got {spec!r}")
        runs = read_group(pattern)
        color = f"C{index}"
        for points in runs.values():
            ax.plot([t for t, _ in points], [100 * s for _, s in points], color=color, alpha=0.3, linewidth=1)
        ticks = sorted({t for points in runs.values() for t, _ in points})
        means = []
        for tick in ticks:
            values = [s for points in runs.values() for t, s in points if t == tick]
            means.append(100 * sum(values) / len(values))
        ax.plot(ticks, means, color=color, linewidth=2.5, label=f"{label} ({len(runs)} seeds)")
        for name, points in runs.items():
            print(f"{label:<24}{name:<44}" + " ".join(f"{t // 1000}k:{100 * s:.0f}%" for t, s in points))
    ax.axhline(80, color="grey", linestyle=":", linewidth=1)
    ax.set_xlabel("training ticks (world steps)")
    ax.set_ylabel("success rate (%)")
    ax.set_ylim(-2, 102)
    ax.set_title(args.title)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
