"""The 8-robot screen's table (rule: ``rules.md`` beside this file): per arm and seed, greedy team success at every
evaluation, the score (mean of the last three), the first ticks at 80 % and the final collisions and time-outs.

    python docs/results/many_robots/eight_robot_screen/summarize.py docs/results/many_robots/eight_robot_screen \
        docs/results/many_robots/team_size_ladder/scratch_seed220.jsonl
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re

ARMS = ("scratch", "ladder_whole", "eps_early", "eps_team4", "pop_copy", "pop_distill")


def read(path: pathlib.Path) -> list[dict]:
    return sorted(
        (json.loads(line) for line in path.read_text().splitlines() if line.strip()), key=lambda r: r["ticks"]
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("paths", nargs="+", type=pathlib.Path, help="record files or folders of them")
    args = parser.parse_args()
    found = [
        p for path in args.paths for p in (sorted(path.glob("*_seed*.jsonl")) if path.is_dir() else [path])
    ]
    files = sorted(p for p in found if "_rounds" not in p.name and "_selections" not in p.name)
    marks = list(range(25_000, 300_001, 25_000))
    print(
        "| arm, seed | "
        + " | ".join(str(m // 1000) for m in marks)
        + " | score | ticks to 80 % | final collisions / time-outs | EPS |"
    )
    print("|---" * (len(marks) + 5) + "|")
    scores: dict[str, list[float]] = {}
    for path in files:
        match = re.match(r"(.+)_seed(\d+)\.jsonl", path.name)
        arm, seed = match.group(1), int(match.group(2))
        curve = read(path)
        by_mark = {}
        for mark in marks:  # the first evaluation at or after each mark
            later = [r for r in curve if r["ticks"] >= mark]
            if later and later[0]["ticks"] < mark + 25_000:
                by_mark[mark] = later[0]
        cells = [f"{100 * by_mark[m]['success_rate']:.0f}" if m in by_mark else "" for m in marks]
        last = [by_mark[m]["success_rate"] for m in marks[-3:] if m in by_mark]
        score = 100 * sum(last) / 3 if len(last) == 3 else None
        if score is not None:
            scores.setdefault(arm, []).append(score)
        reach = next((r["ticks"] for r in curve if r["success_rate"] >= 0.8), None)
        final = curve[-1]
        timeouts = 1 - final["success_rate"] - final["collision_rate"]
        eps = (
            f"{final['rounds']} rounds, {final['crossovers']} crossovers, {final['eps_ticks']} ticks"
            if "rounds" in final
            else ""
        )
        print(
            f"| {arm}, {seed} | " + " | ".join(cells) + f" | {'' if score is None else f'**{score:.1f}**'} | "
            f"{'' if reach is None else f'{reach // 1000}k'} | {100 * final['collision_rate']:.0f} / {100 * timeouts:.0f} % | {eps} |"
        )
    print()
    for arm, values in scores.items():
        print(f"{arm}: mean score {sum(values) / len(values):.1f} over {len(values)} seed(s)")


if __name__ == "__main__":
    main()
