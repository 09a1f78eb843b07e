"""Markdown tables of greedy-evaluation curves written by ``benchmarks/learning_check.py``.

One row per record file (one seed): success at every evaluation, the final one, the best, and the collapse check
of issue 9 (the lowest evaluation after the first one at or above ``--reach``). A group line gives the mean of the
final evaluations. Example::

    python benchmarks/summarize_curves.py docs/results/baselines/gdq2_defaults --reach 0.8 --floor 0.6
"""

from __future__ import annotations

import argparse
import json
import pathlib


def read_curve(path: pathlib.Path) -> list[dict]:
    """:return: the evaluations of one record file, by ticks."""
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return sorted(records, key=lambda record: record["ticks"])


def after_reaching(curve: list[dict], reach: float) -> float | None:
    """:return: the lowest success after the first evaluation at or above ``reach`` (None if never reached)."""
    rates = [record["success_rate"] for record in curve]
    for index, rate in enumerate(rates):
        if rate >= reach:
            return min(rates[index:])
    return None


def table(folder: pathlib.Path, reach: float, floor: float) -> str:
    """:return: the markdown table of every ``*.jsonl`` file in ``folder``."""
    paths = sorted(folder.glob("*.jsonl"))
    if not paths:
        raise SystemExit(f"{folder}: no *.jsonl record files")
    curves = {path.stem: read_curve(path) for path in paths}
    ticks = sorted({record["ticks"] for curve in curves.values() for record in curve})
    header = ["run", *(f"{tick // 1000}k" for tick in ticks), "final", "best", f"min after {reach:.0%}"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    finals = []
    for name, curve in curves.items():
        by_tick = {record["ticks"]: record["success_rate"] for record in curve}
        final = curve[-1]["success_rate"]
        if curve[-1]["ticks"] == ticks[-1]:
            finals.append(final)
        low = after_reaching(curve, reach)
        low_text = "never reached" if low is None else f"{low:.0%}" + (" (below floor)" if low < floor else "")
        if curve[-1]["ticks"] < ticks[-1]:
            name += f" (stopped at {curve[-1]['ticks'] // 1000}k)"
        cells = [name, *(f"{by_tick[tick]:.0%}" if tick in by_tick else "" for tick in ticks)]
        cells += [f"**{final:.0%}**", f"{max(by_tick.values()):.0%}", low_text]
        lines.append("| " + " | ".join(cells) + " |")
    episodes = {record.get("n_episodes") for curve in curves.values() for record in curve}
    lines.append(
        f"\nmean final success {sum(finals) / max(len(finals), 1):.1%} over {len(finals)} finished runs; "
        f"episodes per evaluation: {sorted(e for e in episodes if e)}"
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=pathlib.Path)
    parser.add_argument("--reach", type=float, default=0.8)
    parser.add_argument("--floor", type=float, default=0.6)
    args = parser.parse_args()
    for folder in args.folders:
        print(f"### {folder}\n\n{table(folder, args.reach, args.floor)}\n")


if __name__ == "__main__":
    main()
