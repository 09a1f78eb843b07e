"""The measure of this folder's rule: every model of both arms, greedy, 100 episodes on the varied and the fixed
unseen room, one after another on one thread; one JSON line per model and room (a rerun skips lines already there).
``--summary`` prints the page's table from the records instead.

    python docs/results/many_robots/unseen_room_varied/evaluate.py --open runs/open --bars runs/bars \\
        --out docs/results/many_robots/unseen_room_varied/records.jsonl
    python docs/results/many_robots/unseen_room_varied/evaluate.py --summary \\
        --out docs/results/many_robots/unseen_room_varied/records.jsonl
"""

import argparse
import json
import pathlib
import zipfile

import torch as th

import envs  # noqa: F401
from sb3_eps import GDQ
from sb3_eps.common.evaluation import evaluate_team

ROOMS = ("MultiRobotNavUnseen-4-varied-v0", "MultiRobotNavUnseen-4-v0")
EVAL_SEED = 20_000
EPISODE_KEYS = ("success", "collision", "n_arrived", "l")

parser = argparse.ArgumentParser()
parser.add_argument("--open", help="folder of gdq_open4_seed{0..4}.zip")
parser.add_argument("--bars", help="folder of gdq_bars4_seed{0..4}.zip")
parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
parser.add_argument("--out", required=True)
parser.add_argument("--summary", action="store_true", help="print the table of the records in --out and stop")
args = parser.parse_args()


def percent(records: list[dict], key: str) -> str:
    return " / ".join(f"{100 * record[key]:.0f}" for record in records)


def load(path: pathlib.Path) -> GDQ:
    """The saved model; the bars models, saved before the package dropped the ``angle_features`` policy option, hold
    its off value (None), which is left out so they load with the weights they were saved with."""
    with zipfile.ZipFile(path) as archive:
        policy_kwargs = json.loads(archive.read("data"))["policy_kwargs"]
    if policy_kwargs.pop("angle_features", "absent") is not None:
        return GDQ.load(path, device="cpu")
    return GDQ.load(path, device="cpu", custom_objects={"policy_kwargs": policy_kwargs})


if args.summary:
    records = [json.loads(line) for line in pathlib.Path(args.out).read_text().splitlines()]
    print("| arm | room | success, seeds " + ", ".join(map(str, args.seeds)) + " | mean | collisions | mean |")
    print("|---|---|---|---|---|---|")
    for arm in ("open", "bars"):
        for env_id in ROOMS:
            rows = sorted((r for r in records if (r["arm"], r["env_id"]) == (arm, env_id)), key=lambda r: r["seed"])
            rows = [r for r in rows if r["seed"] in args.seeds]
            mean_success = 100 * sum(r["success_rate"] for r in rows) / len(rows)
            mean_collision = 100 * sum(r["collision_rate"] for r in rows) / len(rows)
            print(
                f"| {arm} | `{env_id}` | {percent(rows, 'success_rate')} | {mean_success:.1f} % "
                f"| {percent(rows, 'collision_rate')} | {mean_collision:.1f} % |"
            )
    raise SystemExit(0)
if args.open is None or args.bars is None:
    parser.error("--open and --bars name the folders of the models (or pass --summary)")
th.set_num_threads(1)
out = pathlib.Path(args.out)
done = set()
if out.exists():
    done = {(r["arm"], r["seed"], r["env_id"]) for r in map(json.loads, out.read_text().splitlines())}
for arm, folder in (("open", args.open), ("bars", args.bars)):
    for seed in args.seeds:
        model = load(pathlib.Path(folder) / f"gdq_{arm}4_seed{seed}.zip")
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
