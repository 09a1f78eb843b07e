"""The `bars` arm of this folder's rule: GDQ, package defaults, 4 robots in the arena with the EPS world's bars.

python docs/results/many_robots/unseen_room_obstacle_training/run.py --seed 220 --out runs/bars
"""

import argparse
import pathlib

import torch as th

import envs  # noqa: F401
from envs.turtlebot3 import MultiRobotNavEnv
from sb3_eps import GDQ, make_vec_env

parser = argparse.ArgumentParser()
parser.add_argument("--seed", type=int, default=220)
parser.add_argument("--ticks", type=int, default=150_000)
parser.add_argument("--out", required=True)
parser.add_argument("--scenario", default="eps", help='"eps" (the bars) or "arena" (the open arena, the paper\'s protocol)')
args = parser.parse_args()
th.set_num_threads(1)
venv = make_vec_env(MultiRobotNavEnv, n_envs=4, seed=args.seed, env_kwargs={"n_robots": 4, "scenario": args.scenario})
model = GDQ("MlpPolicy", venv, seed=args.seed)
model.learn(args.ticks * venv.n_agents, log_interval=10_000)
pathlib.Path(args.out).mkdir(parents=True, exist_ok=True)
model.save(pathlib.Path(args.out) / f"gdq_{'bars' if args.scenario == 'eps' else 'open'}4_seed{args.seed}.zip")
