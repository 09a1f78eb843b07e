"""The status table of ``docs/results/eps.md``: every EPS variant measured against its base, computed from the
committed greedy-evaluation records.

Each row pairs the records of an EPS run with its base's on the same seeds (both runs of a seed are the same run up
to the first EPS round, so the pair is the unit of comparison) and gives the seed-by-seed difference of the mean of
the last evaluations at equal total world ticks, its standard error, the EPS rounds and crossovers and the EPS ticks.
The figures come from ``benchmarks/compare_eps.py``'s functions, so the table and that script agree.

Usage, from the repository root::

    python research/eps_status.py            # the table in Markdown
    python research/eps_status.py --searches # also the two Optuna studies of the EPS settings
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import math
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BASELINES = "docs/results/baselines"
EPS = "docs/results/eps"


def _compare_eps():
    """``benchmarks/compare_eps.py`` as a module (benchmarks/ is a folder of scripts, not a package)."""
    spec = importlib.util.spec_from_file_location("compare_eps", ROOT / "benchmarks" / "compare_eps.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


compare_eps = _compare_eps()


@dataclass(frozen=True)
class Variant:
    """One EPS variant against its base.

    :param name: what the variant is (the page's words)
    :param base: what it is compared with
    :param base_dirs: the base's record folders (a seed is read from the first folder that has it)
    :param eps_dirs: the EPS run's record folders, likewise
    :param budget: total world ticks compared (training plus EPS ticks where ``paid``)
    :param paid: whether the EPS ticks were paid from ``budget`` (equal total world ticks)
    :param every: the evaluation spacing, in ticks
    :param last: how many of the last evaluations at or before the budget are averaged
    :param section: the page's section that reports it
    :param robots: the robots of the training worlds
    """

    name: str
    base: str
    base_dirs: tuple[str, ...]
    eps_dirs: tuple[str, ...]
    budget: int
    paid: bool = True
    every: int = 10_000
    last: int = 3
    section: str = ""
    robots: int = 4


GDQ_PAPER = "GDQ, paper's target"
GDQ_LAMBDA = "GDQ-lambda 0.1"


def team_world_screen(name: str, folder: str) -> Variant:
    """:return: a 2-seed screen of ``docs/results/eps/screens/<folder>`` against the screens' GDQ runs (4 robots)."""
    return Variant(name, GDQ_PAPER, (f"{EPS}/screens/gdq4_screen",), (f"{EPS}/screens/{folder}",), 150_000,
                   section="team-world")  # fmt: skip


#: Every EPS variant with committed records of both arms, in the order of the page's table.
VARIANTS: tuple[Variant, ...] = (
    # 2 robots
    Variant("EPS-GDQ, package defaults, 2 robots", GDQ_PAPER, (f"{BASELINES}/gdq2_final",),
            (f"{EPS}/eps_gdq2",), 100_000, section="2-robots", robots=2),
    Variant("EPS-GDQ, package defaults, 2 robots", GDQ_LAMBDA, (f"{BASELINES}/gdq2_lambda_defaults",),
            (f"{EPS}/eps_gdq2_lambda",), 100_000, section="2-robots", robots=2),
    Variant("EPS-IQL, package defaults, 2 robots", "IQL", (f"{BASELINES}/iql2",),
            (f"{EPS}/eps_iql2",), 100_000, section="2-robots", robots=2),
    # 4 robots, report seeds
    Variant("EPS-GDQ, package defaults, schedules over the nominal budget", GDQ_PAPER, (f"{BASELINES}/gdq4_final",),
            (f"{EPS}/eps_gdq4",), 150_000, section="4-robots"),
    Variant("EPS-GDQ, package defaults, round cost from the last round's episodes", GDQ_PAPER,
            (f"{BASELINES}/gdq4_final",), (f"{EPS}/eps_gdq4_head", f"{EPS}/eps_gdq4"), 150_000, section="4-robots"),
    Variant("EPS-GDQ, package defaults, schedules ending with the budget", GDQ_PAPER, (f"{BASELINES}/gdq4_final",),
            (f"{EPS}/eps_gdq4_budget",), 150_000, section="4-robots"),
    Variant("EPS-GDQ, package defaults", GDQ_LAMBDA, (f"{BASELINES}/gdq4_lambda_report",),
            (f"{EPS}/eps_gdq4_lambda",), 150_000, section="4-robots"),
    Variant("EPS-GDQ, package defaults, held-out seeds", GDQ_LAMBDA,
            (f"{BASELINES}/gdq4_lambda_changes_heldout/defaults",), (f"{EPS}/eps_gdq4_pairs_heldout",), 150_000,
            section="4-robots"),
    Variant("EPS-GDQ, package defaults, report and held-out seeds", GDQ_LAMBDA,
            (f"{BASELINES}/gdq4_lambda_report", f"{BASELINES}/gdq4_lambda_changes_heldout/defaults"),
            (f"{EPS}/eps_gdq4_lambda", f"{EPS}/eps_gdq4_pairs_heldout"), 150_000, section="4-robots"),
    Variant("EPS-GDQ, package defaults, held-out seeds", GDQ_PAPER, (f"{BASELINES}/gdq4_lambda_ho/gdq",),
            (f"{EPS}/eps_gdq4_ho138",), 150_000, section="4-robots"),
    Variant("EPS-IQL, package defaults, schedules over the nominal budget", "IQL", (f"{BASELINES}/iql4_final",),
            (f"{EPS}/eps_iql4",), 100_000, section="4-robots"),
    Variant("EPS-IQL, package defaults, schedules ending with the budget", "IQL", (f"{BASELINES}/iql4_final",),
            (f"{EPS}/eps_iql4_budget",), 100_000, section="4-robots"),
    # team worlds for fitness and shared experience, 4 robots
    team_world_screen("EPS-GDQ, 4-robot team world", "eps_team_gdq4_screen"),
    team_world_screen("EPS-GDQ, team world + shared experience", "eps_team_share_gdq4_screen"),
    Variant("EPS-GDQ, team world + shared experience", GDQ_PAPER, (f"{BASELINES}/gdq4_final",),
            (f"{EPS}/eps_gdq4_share",), 150_000, section="team-world"),
    team_world_screen("EPS-GDQ, team world + shared experience, EPS share 0.2", "eps_team_share02_gdq4_screen"),
    team_world_screen("EPS-GDQ, team world + shared rows trained on at once", "eps_team_share_train_gdq4_screen"),
    team_world_screen("EPS-GDQ, team world + shared rows trained on, spread", "eps_team_share_spread_gdq4_screen"),
    Variant("EPS-GDQ, free EPS (team world, shared rows and their gradient steps)", GDQ_PAPER,
            (f"{EPS}/free_eps_heldout/gdq",), (f"{EPS}/free_eps_heldout/eps_gdq_free",), 150_000,
            section="team-world"),
    Variant("EPS-IQL, searched setting (team world + sharing, trial 4), held-out seeds", "IQL",
            (f"{EPS}/tuning_eps_iql4/check_trial4_seeds112-116/iql",),
            (f"{EPS}/tuning_eps_iql4/check_trial4_seeds112-116/eps_iql",), 100_000, every=50_000, last=1,
            section="searches"),
    # 8 robots
    Variant("EPS-GDQ, package defaults, 8 robots", GDQ_PAPER, (f"{BASELINES}/gdq8",), (f"{EPS}/eps_gdq8",),
            200_000, every=20_000, section="8-robots", robots=8),
    Variant("EPS-GDQ, package defaults, 8 robots", GDQ_LAMBDA, (f"{BASELINES}/gdq8_lambda",),
            (f"{EPS}/eps_gdq8_lambda",), 200_000, every=20_000, section="8-robots", robots=8),
    Variant("EPS-IQL, package defaults, 8 robots", "IQL", (f"{BASELINES}/iql8",), (f"{EPS}/eps_iql8",), 200_000,
            every=20_000, section="8-robots", robots=8),
)  # fmt: skip

#: Algorithm 1 with the paper's settings, 4 robots, 3 seeds, 20-episode evaluations at 200k training ticks; the EPS
#: ticks (about 50k) came on top of the training ticks. Written by the main job of the time as text lines.
PAPER_ALGORITHM_RECORDS = "docs/results/main_job"
EVAL_LINE = re.compile(r"Eval at \d+ timesteps \((?P<ticks>\d+) ticks\): success (?P<success>\d+) %")


@dataclass
class Row:
    """A variant's figures: per-seed scores and their paired differences."""

    variant: Variant
    seeds: list[int]
    base_scores: list[float]
    eps_scores: list[float]
    rounds: int
    crossovers: int
    eps_ticks: list[int]

    @property
    def pairs(self) -> dict[str, float]:
        """:return: ``compare_eps.paired_difference`` of the scores (``mean``, ``std``, ``sem``, ``n``, ``ahead``)."""
        return compare_eps.paired_difference(self.base_scores, self.eps_scores)


def read_seeds(folders: Sequence[str], root: Path = ROOT) -> dict[int, object]:
    """:return: seed -> evaluations, each seed from the first of ``folders`` that has it."""
    runs: dict[int, object] = {}
    for folder in reversed(folders):
        runs.update(compare_eps.read_runs(root / folder))
    return runs


def measure(variant: Variant, root: Path = ROOT) -> Row:
    """:return: the figures of ``variant`` over the seeds both arms have."""
    base, eps = read_seeds(variant.base_dirs, root), read_seeds(variant.eps_dirs, root)
    seeds = sorted(set(base) & set(eps))
    if not seeds:
        raise ValueError(f"{variant.name}: no seed in both {variant.base_dirs} and {variant.eps_dirs}")

    def score(run: object) -> float:
        return compare_eps.last_mean(run, variant.budget, variant.every, variant.last)

    return Row(
        variant,
        seeds,
        [score(base[seed]) for seed in seeds],
        [score(eps[seed]) for seed in seeds],
        sum(compare_eps.last_value(eps[seed], "eps_rounds") for seed in seeds),
        sum(compare_eps.last_value(eps[seed], "eps_crossovers") for seed in seeds),
        [compare_eps.last_value(eps[seed], "eps_ticks") for seed in seeds],
    )


def paper_algorithm_row(root: Path = ROOT) -> Row:
    """:return: Algorithm 1's runs (text records of the main job of the time): final success (%) of GDQ and EPS-GDQ
    per seed; rounds, crossovers (Algorithm 1 crosses over whenever a mutant wins) and EPS ticks from the EPS runs'
    ``progress.csv``."""
    finals: dict[str, dict[int, float]] = {"gdq": {}, "eps_gdq": {}}
    for path in sorted((root / PAPER_ALGORITHM_RECORDS).glob("*_seed*_evals.txt")):
        algo, seed = re.fullmatch(r"(.+)_seed(\d+)_evals", path.stem).groups()
        evaluations = [m for m in map(EVAL_LINE.match, path.read_text().splitlines()) if m]
        finals[algo][int(seed)] = float(evaluations[-1]["success"])
    seeds = sorted(set(finals["gdq"]) & set(finals["eps_gdq"]))
    rounds = []
    for seed in seeds:
        with open(root / PAPER_ALGORITHM_RECORDS / f"eps_gdq_seed{seed}_progress.csv") as file:
            rounds.append([row for row in csv.DictReader(file) if row.get("eps/round")])
    variant = Variant(
        "EPS-GDQ, Algorithm 1 with the paper's settings (final evaluation, 20 episodes)", "GDQ of the time",
        (), (), 200_000, paid=False, section="4-robots",
    )  # fmt: skip
    return Row(
        variant,
        seeds,
        [finals["gdq"][s] / 100 for s in seeds],
        [finals["eps_gdq"][s] / 100 for s in seeds],
        sum(len(logged) for logged in rounds),
        sum(row["eps/winner"] != "0" for logged in rounds for row in logged),
        [int(float(logged[-1]["eps/ticks"])) for logged in rounds],
    )


@dataclass(frozen=True)
class Screen:
    """A screen of ``benchmarks/team_size_ladder.py`` (held-out seeds): EPS or population arms against GDQ from
    scratch with the package defaults at equal total world ticks (EPS world ticks and every learner's paid from them).

    :param folder: the screen's records (``<arm>_seed<k>.jsonl``; a population's ``_selections.jsonl`` beside)
    :param scratch_folders: where the scratch arm's records are, each seed from the last folder that has it
    :param arms: arm -> the page's name of the variant
    :param marks: the evaluations whose mean is a run's score (:func:`screen_score`)
    :param every: the evaluation spacing, in ticks
    :param robots: the robots of the training worlds
    :param section: the page's section that reports it
    :param unseen_room: score the final model on this room instead (``unseen_room.jsonl`` in ``folder``)
    :param base_arm: the arm every other arm is paired with (GDQ alone)
    """

    folder: str
    scratch_folders: tuple[str, ...]
    arms: dict[str, str]
    marks: tuple[int, ...]
    every: int
    robots: int
    section: str
    unseen_room: str | None = None
    base_arm: str = "scratch"


#: The 8-robot screen (``docs/results/many_robots/eight_robot_screen/``), 300k total world ticks, 50 greedy episodes
#: every 25k ticks. The scratch arm's seed 220 is the team-size ladder screen's record, same script and protocol.
SCREEN8 = Screen(
    "docs/results/many_robots/eight_robot_screen",
    ("docs/results/many_robots/team_size_ladder", "docs/results/many_robots/eight_robot_screen"),
    {
        "eps_early": "EPS-GDQ, early rounds (every 10k ticks up to 60k), 8 robots",
        "eps_team4": "EPS-GDQ, early rounds in a 4-robot team world, 8 robots",
        "pop_copy": "population of 4 GDQ learners, copy + safe mutation (rounds: selections; crossovers: copies), 8 robots",
        "pop_distill": "population of 4 GDQ learners, distillation crossover (rounds: selections; crossovers: copies), 8 robots",
    },
    (250_000, 275_000, 300_000),
    25_000,
    8,
    "8-robot-screen",
)
#: The 12-robot screen (``docs/results/many_robots/twelve_robot_screen/``), 400k ticks, 50 episodes every 50k.
SCREEN12 = Screen(
    "docs/results/many_robots/twelve_robot_screen",
    ("docs/results/many_robots/twelve_robot_screen",),
    {
        "eps_default": "EPS-GDQ, package defaults, 12 robots",
        "eps_early": "EPS-GDQ, early rounds (every 10k ticks up to 60k), 12 robots",
    },
    (300_000, 350_000, 400_000),
    50_000,
    12,
    "12-robot-screen",
)
#: EPS on the varied unseen room (``docs/results/eps/unseen_room_eps/``): 4-robot models trained 150k ticks on the
#: open arena, scored by their final model's success on 100 distinct problems of the room.
SCREEN_UNSEEN = Screen(
    "docs/results/eps/unseen_room_eps",
    ("docs/results/eps/unseen_room_eps",),
    {
        "eps_default": "EPS-GDQ, package defaults, 4 robots, scored on the varied unseen room",
        "eps_early": "EPS-GDQ, early rounds (every 10k ticks up to 60k), 4 robots, scored on the varied unseen room",
    },
    (150_000,),
    25_000,
    4,
    "unseen-room",
    unseen_room="MultiRobotNavUnseen-4-varied-v0",
    base_arm="gdq",
)
SCREENS = (SCREEN8, SCREEN12, SCREEN_UNSEEN)


def screen_curves(arm: str, folders: Sequence[str], root: Path = ROOT) -> dict[int, list[dict]]:
    """:return: seed -> the evaluations of one arm of a screen, by ticks (each seed from the last folder that has it)."""
    curves: dict[int, list[dict]] = {}
    for folder in folders:
        for path in sorted((root / folder).glob(f"{arm}_seed*.jsonl")):
            seed = re.fullmatch(rf"{arm}_seed(\d+)", path.stem)
            if seed:
                records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
                curves[int(seed[1])] = sorted(records, key=lambda record: record["ticks"])
    return curves


def screen_at(curve: list[dict], mark: int) -> dict | None:
    """:return: the evaluation that stands for ``mark`` ticks: the first at or after it, within 25k (a round or a
    rollout carries an evaluation a few ticks past its point); None if there is none."""
    return next((record for record in curve if mark <= record["ticks"] < mark + 25_000), None)


def screen_score(curve: list[dict], marks: Sequence[int] = SCREEN8.marks) -> float | None:
    """:return: the mean success of the evaluations at ``marks`` (:func:`screen_at`); None for an unfinished run."""
    found = [screen_at(curve, mark) for mark in marks]
    return None if None in found else sum(r["success_rate"] for r in found) / len(found)  # type: ignore[index]


def unseen_scores(screen: Screen, arm: str, root: Path = ROOT) -> dict[int, float]:
    """:return: seed -> the final model's success on ``screen.unseen_room`` (``unseen_room.jsonl``)."""
    path = root / screen.folder / "unseen_room.jsonl"
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
    return {r["seed"]: r["success_rate"] for r in records if r["arm"] == arm and r["room"] == screen.unseen_room}


def screen_rows(screen: Screen, root: Path = ROOT) -> list[Row]:
    """:return: one row per EPS or population arm of ``screen`` over the seeds both it and scratch finished (none for
    an arm without such a seed). A population's rounds are its selections and its crossovers the copies made; it
    plays no EPS ticks."""
    if screen.unseen_room:
        scratch = unseen_scores(screen, screen.base_arm, root)
    else:
        curves = screen_curves(screen.base_arm, screen.scratch_folders, root)
        scratch = {s: screen_score(c, screen.marks) for s, c in curves.items()}
    rows = []
    for arm, name in screen.arms.items():
        curves = screen_curves(arm, (screen.folder,), root)
        scores = (
            unseen_scores(screen, arm, root)
            if screen.unseen_room
            else {s: screen_score(curve, screen.marks) for s, curve in curves.items()}
        )
        seeds = sorted(s for s in curves if scores.get(s) is not None and scratch.get(s) is not None)
        if not seeds:
            continue
        rounds = crossovers = 0
        for seed in seeds:
            if arm.startswith("pop"):
                with open(root / screen.folder / f"{arm}_seed{seed}_selections.jsonl") as file:
                    selections = [json.loads(line) for line in file if line.strip()]
                rounds += len(selections)
                crossovers += sum("skipped" not in selection for selection in selections)
            else:
                rounds += curves[seed][-1]["rounds"]
                crossovers += curves[seed][-1]["crossovers"]
        variant = Variant(name, "GDQ, package defaults", (), (), screen.marks[-1], every=screen.every,
                          section=screen.section, robots=screen.robots)  # fmt: skip
        rows.append(Row(
            variant, seeds, [scratch[s] for s in seeds], [scores[s] for s in seeds], rounds,
            crossovers, [int(curves[s][-1].get("eps_ticks", 0)) for s in seeds],
        ))  # fmt: skip
    return rows


def all_rows(root: Path = ROOT) -> list[Row]:
    """:return: the page's table rows: :data:`VARIANTS`, Algorithm 1 and the screens of :data:`SCREENS`."""
    screens = [row for screen in SCREENS for row in screen_rows(screen, root)]
    return [measure(variant, root) for variant in VARIANTS] + [paper_algorithm_row(root), *screens]


def seeds_text(seeds: Sequence[int]) -> str:
    """:return: the seeds with runs of three or more consecutive ones joined by a dash: ``0-4, 146-150``."""
    runs: list[list[int]] = []
    for seed in seeds:
        if runs and seed == runs[-1][-1] + 1:
            runs[-1].append(seed)
        else:
            runs.append([seed])
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 2 else ", ".join(map(str, r)) for r in runs)


def difference_text(pairs: dict[str, float]) -> str:
    """:return: ``-3.7 (SE 1.7)`` points; the SE left out for a single pair."""
    se = "" if math.isnan(pairs["sem"]) else f" (SE {100 * pairs['sem']:.1f})"
    return f"{100 * pairs['mean']:+.1f}{se}"


def table(rows: Sequence[Row]) -> str:
    """:return: the status table in Markdown, one line per variant."""
    lines = [
        "| variant | base | robots | difference, points (SE) | EPS ahead | seeds | rounds (crossovers) | "
        "EPS ticks per run | world ticks | EPS ticks paid from them |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        v, pairs = row.variant, row.pairs
        low, high = min(row.eps_ticks) / 1000, max(row.eps_ticks) / 1000
        lines.append(
            f"| {v.name} | {v.base} | {v.robots} | {difference_text(pairs)} | {pairs['ahead']} of {pairs['n']} | "
            f"{seeds_text(row.seeds)} | {row.rounds} ({row.crossovers}) | {low:.1f}-{high:.1f}k | "
            f"{v.budget // 1000}k{'' if v.paid else ' + EPS'} | {'yes' if v.paid else 'no'} |"
        )
    return "\n".join(lines)


def search_summary(study: str, algo: str) -> str:
    """:return: one line on an Optuna study of the EPS settings (``trials.csv`` of its folder)."""
    with open(ROOT / EPS / study / "trials.csv") as file:
        trials = [t for t in csv.DictReader(file) if t["state"] == "COMPLETE"]
    scores = np.array([100 * float(t["value"]) for t in trials])
    no_round = [100 * float(t["value"]) for t in trials if set(t["eps_ticks"].split("/")) == {"0"}]
    recorded = [t for t in trials if t["eps_rounds"]]
    rounds = sum(int(n) for t in recorded for n in t["eps_rounds"].split("/"))
    crossovers = sum(int(n) for t in recorded for n in t["eps_crossovers"].split("/"))
    base = no_round[0] if no_round else float("nan")
    return (
        f"{algo}: {len(trials)} complete trials on seeds 110, 111; the base (trials without a round) scores "
        f"{base:.1f}, the best trial {scores.max():.1f} ({scores.max() - base:+.1f} points, selected among "
        f"{len(trials)}), the median {np.median(scores):.1f}; {len(no_round)} trials never ran a round; "
        f"{rounds} rounds with {crossovers} crossover(s) in the {len(recorded)} trials that recorded them."
    )


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--searches", action="store_true", help="also summarise the Optuna studies")
    args = parser.parse_args(argv)
    print(table(all_rows()))
    if args.searches:
        print()
        print(search_summary("tuning_eps_gdq4", "EPS-GDQ"))
        print(search_summary("tuning_eps_iql4", "EPS-IQL"))


if __name__ == "__main__":
    main()
