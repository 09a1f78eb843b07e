"""The reference controllers of ``CooperativeNavigation-v0`` on Table I's metrics (``docs/results/mpe.md``).

Plays the hand controller, random play and no-op play (``envs.mpe.controllers``) for ``--episodes`` greedy team
episodes each through ``sb3_eps.evaluate_team`` (4 worlds, evaluation seed ``--seed``) and prints one row per
controller: team return, per tick (/ 25, the paper's scale), success, landmarks occupied at the end, final distance
sum, collisions per tick without spawn overlaps and the episodes with a collision (all, and without spawn overlaps).
``--output`` writes the summaries, each with its world (env id, options, level set, episodes), as JSON. Example::

    python benchmarks/mpe_reference_controllers.py --episodes 300 --output docs/results/mpe/reference_controllers.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from envs.mpe.controllers import HandController, NoOpController, RandomController
from sb3_eps import evaluate_team

ENV_ID = "CooperativeNavigation-v0"
#: Summary keys of a row, and how the row writes them.
COLUMNS = {
    "team_return_mean": ("team return", "{:.1f}"),
    "per_tick": ("per tick", "{:.2f}"),
    "success_rate": ("success", "{:.1%}"),
    "occupied_landmarks_mean": ("occupied at the end (of 3)", "{:.2f}"),
    "min_dist_sum_mean": ("final distance sum", "{:.2f}"),
    "collisions_per_tick_mean": ("collisions per tick, spawn out", "{:.3f}"),
    "collision_rate": ("episodes with a collision", "{:.1%}"),
    "collision_after_spawn_rate": ("... spawn overlaps out", "{:.1%}"),
}


def measure(episodes: int, seed: int) -> dict[str, dict[str, Any]]:
    """:return: each controller's summary (episodes left out), with its world and ``per_tick``"""
    controllers = {"hand": HandController(), "random": RandomController(seed), "no-op": NoOpController()}
    results = {}
    for name, controller in controllers.items():
        summary = evaluate_team(controller, ENV_ID, n_eval_episodes=episodes, n_envs=4, seed=seed)
        summary.pop("episodes")
        results[name] = {**summary, "per_tick": summary["team_return_mean"] / summary["length_mean"], "seed": seed}
    return results


def table(results: dict[str, dict[str, Any]]) -> str:
    """:return: the results as a Markdown table"""
    lines = ["| controller | " + " | ".join(label for label, _ in COLUMNS.values()) + " |"]
    lines.append("|---|" + "---|" * len(COLUMNS))
    for name, summary in results.items():
        cells = [form.format(summary[key]) for key, (_, form) in COLUMNS.items()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--seed", type=int, default=1000, help="evaluation seed (world w gets seed + w)")
    parser.add_argument("--output", default=None, help="JSON file of the summaries")
    args = parser.parse_args()
    results = measure(args.episodes, args.seed)
    print(f"{ENV_ID}, {args.episodes} team episodes per controller, evaluation seed {args.seed}")
    print(table(results))
    if args.output:
        Path(args.output).write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
