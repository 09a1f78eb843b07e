"""The 8-robot screen's final models on the unseen room, fixed and varied (``rules.md``, amendment): greedy, 100
episodes each, evaluation seed 20000, one JSON line per model and room (a rerun skips lines already there).

    python docs/results/many_robots/eight_robot_screen/evaluate_unseen.py MODEL.zip ... \\
        --out docs/results/many_robots/eight_robot_screen/unseen_room.jsonl

A model file is named ``<arm>_seed<k>[_rung<i>].zip`` (``benchmarks/team_size_ladder.py --save-models``).
"""

import argparse
import json
import pathlib
import re
import zipfile

import torch as th

import envs  # noqa: F401
from sb3_eps import GDQ
from sb3_eps.common.evaluation import evaluate_team

ROOMS = ("MultiRobotNavUnseen-4-v0", "MultiRobotNavUnseen-4-varied-v0")
EVAL_SEED = 20_000


def load(path: pathlib.Path) -> GDQ:
    """The saved model; one saved before the package dropped the ``angle_features`` policy option (scratch, seed
    220) holds its off value (None), left out so it loads with the weights it was saved with."""
    with zipfile.ZipFile(path) as archive:
        policy_kwargs = json.loads(archive.read("data"))["policy_kwargs"]
    if policy_kwargs.pop("angle_features", "absent") is not None:
        return GDQ.load(path, device="cpu")
    return GDQ.load(path, device="cpu", custom_objects={"policy_kwargs": policy_kwargs})


def evaluate_models(
    models: list[pathlib.Path], out: pathlib.Path, rooms: tuple[str, ...] = ROOMS, env_kwargs: dict | None = None
) -> None:
    """Evaluate every model on every room (built with ``env_kwargs``), appending one JSON line each to ``out`` (lines
    already there are kept)."""
    th.set_num_threads(1)
    done = set()
    if out.exists():
        done = {(r["arm"], r["seed"], r["room"]) for r in map(json.loads, out.read_text().splitlines())}
    for path in models:
        arm, seed = re.fullmatch(r"(.+)_seed(\d+)(_rung\d+)?", path.stem).group(1, 2)
        model = None
        for room in rooms:
            if (arm, int(seed), room) in done:
                continue
            model = model or load(path)
            summary = evaluate_team(model, room, 100, n_envs=4, seed=EVAL_SEED, env_kwargs=env_kwargs)
            summary.pop("episodes")
            record = {"arm": arm, "seed": int(seed), "room": room, **summary}
            with out.open("a") as file:
                file.write(json.dumps(record) + "\n")
            print(arm, seed, room, record["success_rate"], record["collision_rate"], flush=True)


def main(rooms: tuple[str, ...] = ROOMS) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("models", nargs="+", type=pathlib.Path)
    parser.add_argument("--out", required=True, type=pathlib.Path)
    parser.add_argument("--env-kwargs", type=json.loads, default=None, help="JSON dict of world arguments")
    args = parser.parse_args()
    evaluate_models(args.models, args.out, rooms, args.env_kwargs)


if __name__ == "__main__":
    main()
