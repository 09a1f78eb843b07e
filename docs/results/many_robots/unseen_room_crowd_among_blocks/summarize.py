"""This folder's records as a table, and one record file per report seed and world for the paper page's best per
world (``report/seed<k>_<env id>.jsonl``, one line: the final model's 100 greedy episodes).

    python docs/results/many_robots/unseen_room_crowd_among_blocks/summarize.py [--write]
"""

import argparse
import json
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[4]))  # research/ sits beside the package

from research.results import seeds_line

HERE = pathlib.Path(__file__).resolve().parent
WORLDS = ("MultiRobotNavUnseen-4-varied-v0", "MultiRobotNavUnseen-4-v0", "MultiRobotNav-12-v0")
KEYS = ("ticks", "success_rate", "collision_rate", "team_return_mean", "n_episodes")

parser = argparse.ArgumentParser()
parser.add_argument("--write", action="store_true", help="write report/seed<k>_<env id>.jsonl for seeds 0-4")
args = parser.parse_args()
records = [json.loads(line) for line in (HERE / "records.jsonl").read_text().splitlines()]
finals = {(r["seed"], r["env_id"]): r for r in records if r["stage"] == "final"}
for label, seeds in (("screen", (220, 221)), ("report", (0, 1, 2, 3, 4))):
    print(f"{label}:")
    for env_id in WORLDS:
        rows = [finals[(seed, env_id)] for seed in seeds if (seed, env_id) in finals]
        if not rows:
            continue
        print(f"  {env_id}: {seeds_line(rows)}")
    walls = [finals[(s, WORLDS[0])].get("train_wall_s") for s in seeds if (s, WORLDS[0]) in finals]
    print(f"  training minutes: {' / '.join(f'{w / 60:.1f}' for w in walls if w)}")
if args.write:
    (HERE / "report").mkdir(exist_ok=True)
    for (seed, env_id), record in finals.items():
        if seed < 5:
            line = {key: record[key] for key in KEYS} | {"eval_seed": 20_000}
            (HERE / "report" / f"seed{seed}_{env_id}.jsonl").write_text(json.dumps(line) + "\n")
