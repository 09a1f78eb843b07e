"""Ship trained runs as the package's pretrained models (``sb3_eps/trained_agents/``) and measure their cards.

    python research/trained_agents.py ship --run logs/gdq/MultiRobotNav-8-v0_1 --commit abc1234 [--serves ...]
    python research/trained_agents.py evaluate [-n 100] [--seed 1000]       # the cards' figures, README pages
    python research/trained_agents.py reproduce [-n 100] [--seed 2000] -o research/trained_agents/reproduce.json

``ship`` copies what predicting needs (``args.yml``, ``config.yml``, the final zip), scrubs this machine's paths from
the recorded options, and writes a card without figures; ``evaluate`` plays 100 greedy team episodes in every world a
card serves (evaluation seed 1000) and writes the figures and the card's page; ``reproduce`` plays them again with
another evaluation seed and reports each figure's difference from its card (the acceptance: within 5 points).
"""

from __future__ import annotations

import argparse
import json
import platform
import re
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from sb3_eps.zoo import run_folder
from sb3_eps.zoo.evaluation import evaluate_run, run_env_kwargs
from sb3_eps.zoo.pretrained import CARD_PAGE_NAME, TRAINED_AGENTS, ModelCard, _cards, pretrained_run, sha256_of

CARD_SEED = 1000
REPRODUCE_SEED = 2000
KEYS = ("success_rate", "collision_rate", "team_return_mean", "length_mean")


def scrubbed_args(args: dict[str, Any], algo: str, env_id: str) -> dict[str, Any]:
    """:return: ``args.yml`` with the run's folders as a user's (``logs/...``), no path of the training machine."""
    folder = str(args.get("folder", "logs"))
    args = {**args, "folder": "logs", "run_dir": f"logs/{algo}/{env_id}_1", "tensorboard_log": None}
    if isinstance(args.get("command"), str):
        args["command"] = args["command"].replace(folder, "logs")
    return args


def ship(run_dir: Path, commit: str, serves: list[str], notes: str, root: Path = TRAINED_AGENTS) -> ModelCard:
    """Copy a finished run into ``root/<algo>/<env id>/`` with a card without figures. :return: the card"""
    args = run_folder.read_args(run_dir)
    algo, env_id = str(args["algo"]), str(args["env"])
    target = root / algo / env_id
    target.mkdir(parents=True, exist_ok=True)
    model = run_dir / run_folder.final_model_name(env_id)
    shutil.copyfile(model, target / model.name)
    config = run_folder.run_file(run_dir, run_folder.CONFIG_NAME).read_text()
    # The header names the config file it was resolved from: as the repository names it, not this machine's path.
    config = re.sub(r"resolved from \S*/(zoo_configs/[\w.-]+)", r"resolved from \1", config)
    (target / run_folder.CONFIG_NAME).write_text(config)
    clean = scrubbed_args(args, algo, env_id)
    (target / run_folder.ARGS_NAME).write_text(yaml.safe_dump(clean, sort_keys=False))
    _, monitor = run_folder.read_monitor(run_dir / run_folder.MONITOR_NAME)
    env_kwargs = run_env_kwargs(target, env_id)  # the resolved entry's: the config's and the command line's
    card = ModelCard(
        algo=algo, env_id=env_id, serves=[env_id, *[e for e in serves if e != env_id]], env_kwargs=env_kwargs,
        seed=int(args["seed"]), command=str(clean["command"]), code_version=f"{args.get('version')} ({commit})",
        training_ticks=int(monitor["ticks"][-1]) if len(monitor["ticks"]) else 0,
        wall_time_s=round(float(monitor["t"][-1]), 1) if len(monitor["t"]) else 0.0,
        machine=f"{platform.machine()}, 2 CPU cores (two runs at a time), no GPU", sha256=sha256_of(target / model.name),
        notes=notes, folder=target,
    )  # fmt: skip
    (target / "card.json").write_text(card.to_json())
    return card


def measure(card: ModelCard, n_episodes: int, seed: int) -> dict[str, dict[str, Any]]:
    """:return: env id -> greedy evaluation of the card's model in every world it serves."""
    figures = {}
    for env_id in card.serves:
        run = pretrained_run(card.algo, env_id)
        start = time.perf_counter()
        summary = evaluate_run(run, env_id, n_episodes, n_envs=4, seed=seed)
        figure = {key: round(float(summary[key]), 4) for key in KEYS if key in summary}
        figure.update(
            n_episodes=n_episodes, seed=seed, env_kwargs=card.env_kwargs, seconds=round(time.perf_counter() - start, 1)
        )
        figures[env_id] = figure
        print(f"{card.algo} {env_id}: {json.dumps(figure)}", flush=True)
    return figures


def card_page(card: ModelCard) -> str:
    """:return: the card's page (``README.md`` of the model's folder)."""
    options = ", ".join(f"{key}={value}" for key, value in card.env_kwargs.items()) or "none (the paper's world)"
    lines = [
        f"# {card.algo.upper()} on {card.env_id}: model card",
        "",
        "Written by `research/trained_agents.py` from `card.json`; do not edit.",
        "",
        f"- Load: `sb3_eps.pretrained({card.algo!r}, {card.env_id!r})`; watch: "
        f"`python -m sb3_eps.enjoy --algo {card.algo} --env {card.env_id}`.",
        f"- World options it needs everywhere: {options}.",
        f"- Trained by: `{card.command}` (seed {card.seed}), code {card.code_version}.",
        f"- Training: {card.training_ticks} world ticks, {card.wall_time_s / 60:.1f} min wall time on {card.machine}.",
        f"- Model zip SHA-256: `{card.sha256}` (checked on every load).",
        f"- Setting: {card.notes}",
        "",
        "| world | success | collisions | team return | episode length (ticks) | episodes, evaluation seed |",
        "|---|---|---|---|---|---|",
    ]
    for env_id, figure in card.figures.items():
        lines.append(
            f"| `{env_id}` | {100 * figure['success_rate']:.1f} % | {100 * figure.get('collision_rate', 0.0):.1f} % | "
            f"{figure['team_return_mean']:.2f} | {figure.get('length_mean', float('nan')):.0f} | "
            f"{figure['n_episodes']} greedy team episodes, seed {figure['seed']} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    ship_parser = commands.add_parser("ship")
    ship_parser.add_argument("--run", type=Path, required=True)
    ship_parser.add_argument("--commit", required=True, help="the commit of the code that trained it")
    ship_parser.add_argument("--serves", nargs="*", default=[])
    ship_parser.add_argument("--notes", default="")
    for name, seed in (("evaluate", CARD_SEED), ("reproduce", REPRODUCE_SEED)):
        sub = commands.add_parser(name)
        sub.add_argument("-n", "--n-episodes", type=int, default=100)
        sub.add_argument("--seed", type=int, default=seed)
        sub.add_argument("--only", nargs="*", default=None, help="env ids of the cards to measure (default: all)")
        sub.add_argument("-o", "--output", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.command == "ship":
        card = ship(args.run, args.commit, args.serves, args.notes)
        print(f"shipped {card.folder}")
        return 0
    cards = [card for card in _cards(TRAINED_AGENTS) if args.only is None or card.env_id in args.only]
    report = []
    for card in cards:
        figures = measure(card, args.n_episodes, args.seed)
        if args.command == "evaluate":
            card.figures = figures
            (card.folder / "card.json").write_text(card.to_json())
            (card.folder / CARD_PAGE_NAME).write_text(card_page(card))
            continue
        for env_id, figure in figures.items():
            listed = card.figures[env_id]["success_rate"]
            difference = 100 * (figure["success_rate"] - listed)
            report.append({"algo": card.algo, "env_id": env_id, "card": listed, "measured": figure, "difference_points": difference,
                           "within_5_points": abs(difference) <= 5})  # fmt: skip
            print(f"  card {100 * listed:.1f} %, now {100 * figure['success_rate']:.1f} %: {difference:+.1f} points")
    if args.command == "reproduce" and args.output is not None:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(json.dumps(report, indent=2) + "\n")
    return 0 if all(row["within_5_points"] for row in report) else 1


if __name__ == "__main__":
    sys.exit(main())
