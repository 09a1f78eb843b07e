"""This folder's rule: GDQ (package defaults) trained 150k ticks on 4 robots among random blocks, then evaluated
greedily on the varied and the fixed unseen room and on the open arena; one JSON line per room in ``records.jsonl``
beside this file (a rerun skips a trained model and the rooms already recorded).

    python docs/results/many_robots/unseen_room_blocks/run.py --seed 220 --out runs/blocks
"""

import argparse
import json
import pathlib
import time

import torch as th

import envs  # noqa: F401
from envs.turtlebot3 import MultiRobotNavEnv
from sb3_eps import GDQ, make_vec_env
from sb3_eps.common.evaluation import evaluate_team

ROOMS = ("MultiRobotNavUnseen-4-varied-v0", "MultiRobotNavUnseen-4-v0", "MultiRobotNav-4-v0")
RECORDS = pathlib.Path(__file__).with_name("records.jsonl")

parser = argparse.ArgumentParser()
parser.add_argument("--seed", type=int, required=True)
parser.add_argument("--ticks", type=int, default=150_000)
parser.add_argument("--out", required=True)
args = parser.parse_args()
th.set_num_threads(1)
path = pathlib.Path(args.out) / f"gdq_blocks4_seed{args.seed}.zip"
wall_s = None
if not path.is_file():
    start = time.perf_counter()
    venv = make_vec_env(MultiRobotNavEnv, n_envs=4, seed=args.seed, env_kwargs={"n_robots": 4, "scenario": "blocks"})
    model = GDQ("MlpPolicy", venv, seed=args.seed)
    model.learn(args.ticks * venv.n_agents, log_interval=10_000)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    venv.close()
    wall_s = round(time.perf_counter() - start, 1)
model = GDQ.load(path, device="cpu")
done = [json.loads(line) for line in RECORDS.read_text().splitlines()] if RECORDS.is_file() else []
for env_id in ROOMS:
    if any(r["seed"] == args.seed and r["env_id"] == env_id for r in done):
        continue
    summary = evaluate_team(model, env_id, 100, n_envs=4, seed=20_000)
    record = {"arm": "blocks", "seed": args.seed, "env_id": env_id, "ticks": args.ticks, "train_wall_s": wall_s}
    record |= {key: summary[key] for key in ("success_rate", "collision_rate", "team_return_mean") if key in summary}
    with RECORDS.open("a") as file:
        file.write(json.dumps(record) + "\n")
    print(record, flush=True)
