"""The action-repeat lead on the report seeds: each run's curve (50 greedy episodes at every evaluation) and its
final model on 100 greedy episodes (evaluation seed 30000), as one table; ``--records`` also writes each final
evaluation as a one-line ``final/seed<k>.jsonl`` (the paper page's record format, ``docs/results/paper/records.yml``).

    python docs/results/many_robots/action_repeat/report/summarize.py docs/results/many_robots/action_repeat/report
    python docs/results/many_robots/action_repeat/report/summarize.py docs/results/many_robots/action_repeat/report_12
"""

import argparse
import json
import pathlib

import numpy as np

parser = argparse.ArgumentParser()
parser.add_argument("folder", type=pathlib.Path, help="holds runs/gdq/<env>_seed<k>/ and final/seed<k>.json")
parser.add_argument("--records", action="store_true", help="write final/seed<k>.jsonl")
args = parser.parse_args()
runs = sorted((args.folder / "runs" / "gdq").glob("*_seed*"), key=lambda path: int(path.name.rsplit("seed", 1)[1]))
marks = None
finals = []
minutes = []
for run in runs:
    seed = int(run.name.rsplit("seed", 1)[1])
    data = np.load(run / "evaluations.npz")
    ticks, success = data["ticks"], 100 * data["successes"].mean(axis=1)
    if marks is None:
        marks = ticks
        print(
            "| seed | "
            + " | ".join(f"{t // 1000}k" for t in ticks)
            + " | final model, 100 episodes: success / collisions / time-outs |"
        )
        print("|---" * (len(ticks) + 2) + "|")
    rows = [line.split(",") for line in (run / "monitor.csv").read_text().splitlines()[1:]]
    minutes.append(float(rows[-1][rows[0].index("t")]) / 60)  # the last training episode's end
    final = json.loads((args.folder / "final" / f"seed{seed}.json").read_text())
    s, c = 100 * final["success_rate"], 100 * final["collision_rate"]
    finals.append((s, c))
    if args.records:
        keys = ("success_rate", "collision_rate", "team_return_mean", "n_episodes")
        line = {"ticks": int(ticks[-1]), **{key: final[key] for key in keys}, "eval_seed": final["seed"]}
        (args.folder / "final" / f"seed{seed}.jsonl").write_text(json.dumps(line) + "\n")
    print(f"| {seed} | " + " | ".join(f"{v:.0f}" for v in success) + f" | **{s:.0f}** / {c:.0f} / {100 - s - c:.0f} % |")
success = np.array([f[0] for f in finals])
collision = np.array([f[1] for f in finals])
print(
    f"\nfinal models: success {success.mean():.1f} % (s.e. {success.std(ddof=1) / np.sqrt(len(success)):.1f}, "
    f"lowest {success.min():.0f} %), collisions {collision.mean():.1f} %; training {min(minutes):.0f}-{max(minutes):.0f} min "
    "a run"
)
