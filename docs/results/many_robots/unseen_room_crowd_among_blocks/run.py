"""This folder's rule: GDQ (package defaults) trained on 12 robots among random blocks (``scenario="blocks"``), each
decision held for 2 ticks, then evaluated greedily on the varied and the fixed unseen room and on the open 12-robot
arena; one JSON line per evaluation in ``records.jsonl`` beside this file (a rerun skips a trained model and the
evaluations already recorded).

    python docs/results/many_robots/unseen_room_crowd_among_blocks/run.py --seed 220 --out runs/crowd_blocks

During training, 50 greedy episodes of the varied room every 100k world ticks (evaluation seed 10000 + seed) draw the
curve; the final model is measured on 100 episodes of each room (seed 20000) and of the open arena.
"""

import argparse
import json
import pathlib
import time
from typing import Any

import torch as th
from stable_baselines3.common.callbacks import BaseCallback

import envs  # noqa: F401
from envs.turtlebot3 import MultiRobotNavEnv
from sb3_eps import GDQ, make_vec_env
from sb3_eps.common.evaluation import evaluate_team

ACTION_REPEAT = 2
VARIED = "MultiRobotNavUnseen-4-varied-v0"
ROOMS = (VARIED, "MultiRobotNavUnseen-4-v0", "MultiRobotNav-12-v0")
RECORDS = pathlib.Path(__file__).with_name("records.jsonl")
KEYS = ("success_rate", "collision_rate", "team_return_mean", "length_mean", "n_episodes")


def write(record: dict[str, Any]) -> None:
    with RECORDS.open("a") as file:
        file.write(json.dumps(record) + "\n")
    print(record, flush=True)


def measure(model: Any, env_id: str, episodes: int, seed: int) -> dict[str, Any]:
    summary = evaluate_team(model, env_id, episodes, n_envs=4, seed=seed, env_kwargs={"action_repeat": ACTION_REPEAT})
    return {key: summary[key] for key in KEYS if key in summary}


class RoomCurve(BaseCallback):
    """50 greedy episodes of the varied room every ``every`` world ticks."""

    def __init__(self, seed: int, every: int) -> None:
        super().__init__()
        self.seed, self.every, self.next = seed, every, every
        self.start = time.perf_counter()

    def _on_step(self) -> bool:
        ticks = int(self.model.ticks)  # type: ignore[attr-defined]
        if ticks >= self.next:
            self.next += self.every
            record = {"arm": "crowd_blocks", "seed": self.seed, "stage": "curve", "env_id": VARIED, "ticks": ticks}
            record |= {"wall_s": round(time.perf_counter() - self.start, 1)}
            write(record | measure(self.model, VARIED, 50, 10_000 + self.seed))
        return True


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--ticks", type=int, default=400_000)
    parser.add_argument("--every", type=int, default=100_000)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    th.set_num_threads(1)
    path = pathlib.Path(args.out) / f"gdq_crowd_blocks12_seed{args.seed}.zip"
    wall_s = None
    if not path.is_file():
        start = time.perf_counter()
        kwargs = {"n_robots": 12, "scenario": "blocks", "action_repeat": ACTION_REPEAT}
        venv = make_vec_env(MultiRobotNavEnv, n_envs=4, seed=args.seed, env_kwargs=kwargs)
        model = GDQ("MlpPolicy", venv, seed=args.seed)
        model.learn(model.timesteps_for_ticks(args.ticks), callback=RoomCurve(args.seed, args.every), log_interval=10_000)
        path.parent.mkdir(parents=True, exist_ok=True)
        model.save(path)
        venv.close()
        wall_s = round(time.perf_counter() - start, 1)
    model = GDQ.load(path, device="cpu")
    done = [json.loads(line) for line in RECORDS.read_text().splitlines()] if RECORDS.is_file() else []
    for env_id in ROOMS:
        if any(r["seed"] == args.seed and r["env_id"] == env_id and r["stage"] == "final" for r in done):
            continue
        record = {"arm": "crowd_blocks", "seed": args.seed, "stage": "final", "env_id": env_id, "ticks": args.ticks}
        write(record | {"train_wall_s": wall_s} | measure(model, env_id, 100, 20_000))


if __name__ == "__main__":
    main()
