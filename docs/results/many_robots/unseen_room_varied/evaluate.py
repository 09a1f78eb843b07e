"""The measure of this folder's rule: every model of both arms, greedy, 100 episodes on the varied and the fixed
unseen room, one after another on one thread; one JSON line per model and room (a rerun skips lines already there).

    python docs/results/many_robots/unseen_room_varied/evaluate.py --open runs/open --bars runs/bars \\
        --out docs/results/many_robots/unseen_room_varied/records.jsonl
"""

import argparse
import json
import pathlib

import torch as th

import envs  # noqa: F401
from sb3_eps import GDQ
from sb3_eps.common.evaluation import evaluate_team

ROOMS = ("MultiRobotNavUnseen-4-varied-v0", "MultiRobotNavUnseen-4-v0")
EVAL_SEED = 20_000
EPISODE_KEYS = ("success", "collision", "n_arrived", "l")

parser = argparse.ArgumentParser()
parser.add_argument("--open", required=True, help="folder of gdq_open4_seed{0..4}.zip")
parser.add_argument("--bars", required=True, help="folder of gdq_bars4_seed{0..4}.zip")
parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
parser.add_argument("--out", required=True)
args = parser.parse_args()
th.set_num_threads(1)
out = pathlib.Path(args.out)
done = set()
if out.exists():
    done = {(r["arm"], r["seed"], r["env_id"]) for r in map(json.loads, out.read_text().splitlines())}
for arm, folder in (("open", args.open), ("bars", args.bars)):
    for seed in args.seeds:
        model = GDQ.load(pathlib.Path(folder) / f"gdq_{arm}4_seed{seed}.zip", device="cpu")
        for env_id in ROOMS:
            if (arm, seed, env_id) in done:
                continue
            result = evaluate_team(model, env_id, 100, n_envs=4, seed=EVAL_SEED)
            episodes = [{key: episode[key] for key in EPISODE_KEYS} for episode in result["episodes"]]
            record = {
                "arm": arm,
                "seed": seed,
                "env_id": env_id,
                "eval_seed": EVAL_SEED,
                "n_episodes": result["n_episodes"],
                "success_rate": result["success_rate"],
                "collision_rate": result["collision_rate"],
                "timeout_rate": 1.0 - result["success_rate"] - result["collision_rate"],
                "length_mean": result["length_mean"],
                "episodes": episodes,
            }
            with out.open("a") as stream:
                stream.write(json.dumps(record) + "\n")
            print(arm, seed, env_id, record["success_rate"], record["collision_rate"], flush=True)
