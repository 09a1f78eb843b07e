"""This folder's final models as a table, and one record file per report seed and world for the paper page's best
per world (``report/seed<k>_<room>.jsonl``, one line: the final model's 100 greedy episodes).

    python docs/results/many_robots/unseen_room_short_lidar/summarize.py [--write]
"""

import argparse
import json
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[4]))  # research/ sits beside the package

from research.results import seeds_line

HERE = pathlib.Path(__file__).resolve().parent
ROOMS = ("MultiRobotNavUnseen-4-varied-v0", "MultiRobotNavUnseen-4-v0", "MultiRobotNav-4-v0")
REPORT_ARM = "range1_repeat4_arena4"
KEYS = ("success_rate", "collision_rate", "team_return_mean", "n_episodes")

parser = argparse.ArgumentParser()
parser.add_argument("--write", action="store_true", help="write report/seed<k>_<room>.jsonl for the report arm")
args = parser.parse_args()
records = [json.loads(line) for line in (HERE / "final_models.jsonl").read_text().splitlines()]
finals = {(r["arm"], r["seed"], r["room"]): r for r in records}
for arm in sorted({r["arm"] for r in records}):
    for label, seeds in (("screen", (220, 221)), ("report", (0, 1, 2, 3, 4))):
        for room in ROOMS:
            rows = [finals[(arm, seed, room)] for seed in seeds if (arm, seed, room) in finals]
            if not rows:
                continue
            print(f"{arm} {label} {room}: {seeds_line(rows)}")
if args.write:
    (HERE / "report").mkdir(exist_ok=True)
    for (arm, seed, room), record in finals.items():
        if arm == REPORT_ARM and seed < 5:
            line = {"ticks": 150_000} | {key: record[key] for key in KEYS} | {"eval_seed": 20_000}
            (HERE / "report" / f"seed{seed}_{room}.jsonl").write_text(json.dumps(line) + "\n")
