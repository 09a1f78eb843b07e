"""This folder's records as a table: ``records.jsonl`` holds one line per model (robots trained among, seed) and room.

    python docs/results/many_robots/unseen_room_from_10hz_crowds/summarize.py [evaluation JSON files ... --write]

With JSON files of ``python -m sb3_eps.evaluate`` named ``n<robots>_seed<k>_<room id>.json`` and ``--write``, the
lines are (re)written from them first.
"""

import argparse
import json
import pathlib
import re

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
RECORDS = HERE / "records.jsonl"
ROOMS = {"MultiRobotNavUnseen-4-varied-v0": "varied, 100 problems", "MultiRobotNavUnseen-4-v0": "fixed, 5 problems x 20"}

parser = argparse.ArgumentParser()
parser.add_argument("evaluations", nargs="*", type=pathlib.Path)
parser.add_argument("--write", action="store_true")
args = parser.parse_args()
if args.write:
    lines = []
    for path in sorted(args.evaluations):
        robots, seed, room = re.fullmatch(r"n(\d+)_seed(\d+)_(.+)", path.stem).groups()
        summary = json.loads(path.read_text())
        keys = ("success_rate", "collision_rate", "team_return_mean", "n_episodes")
        lines.append({"robots": int(robots), "seed": int(seed), "room": room, **{key: summary[key] for key in keys}})
    RECORDS.write_text("".join(json.dumps(line) + "\n" for line in lines))
records = [json.loads(line) for line in RECORDS.read_text().splitlines()]
print("| trained among | room | success, seeds 0-4 | mean (s.e.) | collisions, seeds 0-4 | mean |")
print("|---|---|---|---|---|---|")
for robots in sorted({r["robots"] for r in records}):
    for room, label in ROOMS.items():
        rows = sorted((r for r in records if r["robots"] == robots and r["room"] == room), key=lambda r: r["seed"])
        if not rows:
            continue
        success = np.array([100 * r["success_rate"] for r in rows])
        collision = np.array([100 * r["collision_rate"] for r in rows])
        se = success.std(ddof=1) / np.sqrt(len(success)) if len(success) > 1 else float("nan")
        print(
            f"| {robots} robots, 10 Hz | {label} | {' / '.join(f'{v:.0f}' for v in success)} | **{success.mean():.1f} %** "
            f"({se:.1f}) | {' / '.join(f'{v:.0f}' for v in collision)} | {collision.mean():.1f} % |"
        )
