"""A screen's table (rules: ``rules.md`` beside the records): per arm and seed, greedy team success at every
evaluation, the score (mean of the last three), the first ticks at 80 % and the final collisions and time-outs. The
evaluation that stands for each mark and the score are ``research/eps_status.py``'s (``screen_at``,
``screen_score``, the screen's marks), so this table and the EPS page's agree.

    python docs/results/many_robots/eight_robot_screen/summarize.py docs/results/many_robots/eight_robot_screen \
        docs/results/many_robots/team_size_ladder/scratch_seed220.jsonl
    python docs/results/many_robots/eight_robot_screen/summarize.py --robots 12 docs/results/many_robots/twelve_robot_screen
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[4]))
from research.eps_status import SCREEN8, SCREEN12, screen_at, screen_score


def read(path: pathlib.Path) -> list[dict]:
    return sorted((json.loads(line) for line in path.read_text().splitlines() if line.strip()), key=lambda r: r["ticks"])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("paths", nargs="+", type=pathlib.Path, help="record files or folders of them")
    parser.add_argument("--robots", type=int, choices=(8, 12), default=8, help="the screen: 8 or 12 robots")
    args = parser.parse_args()
    screen = SCREEN8 if args.robots == 8 else SCREEN12
    found = [p for path in args.paths for p in (sorted(path.glob("*_seed*.jsonl")) if path.is_dir() else [path])]
    files = sorted(p for p in found if "_rounds" not in p.name and "_selections" not in p.name)
    marks = list(range(screen.every, screen.marks[-1] + 1, screen.every))
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
        at = [screen_at(curve, mark) for mark in marks]
        cells = ["" if record is None else f"{100 * record['success_rate']:.0f}" for record in at]
        score = screen_score(curve, screen.marks)
        if score is not None:
            score *= 100
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
