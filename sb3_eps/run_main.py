"""The README's main job (``make run``): train EPS-GDQ on ``MultiRobotNav-4-v0`` with ``zoo_configs/eps_gdq.yml``
for 800,000 timesteps (200,000 ticks), then draw its learning curve and its greedy evaluations beside the committed
5-seed curves of GDQ and EPS-GDQ (:data:`REFERENCES`), print where everything is, and end with one line on what the
committed records say of EPS-GDQ against GDQ on this world (:func:`reference_summary`). SIGINT / SIGTERM stop it with a
checkpoint; ``python -m sb3_eps.train --resume <run folder>`` continues it.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from pathlib import Path

from sb3_eps.zoo.cli import OneLineArgumentParser, TrainOptions, positive_int
from sb3_eps.zoo.errors import run_command
from sb3_eps.zoo.exp_manager import train
from sb3_eps.zoo.plotting import (
    RECORD_FILE,
    RunCurve,
    evaluation_curves,
    label_of,
    load_curve,
    plot_learning_curves,
    record_curves,
)

PROG = "python -m sb3_eps.run_main"
ENV_ID = "MultiRobotNav-4-v0"
BUDGET = 800_000
EVAL_FREQ = 100_000
EVAL_EPISODES = 20
SAVE_FREQ = 100_000
#: Committed greedy evaluations of the package defaults on the same world (docs/results/eps.md).
REFERENCES = {
    "GDQ, seeds 0-4": "docs/results/baselines/gdq4_lambda_report",
    "EPS-GDQ, seeds 0-4": "docs/results/eps/eps_gdq4_lambda",
}
#: Committed (GDQ, EPS-GDQ) record folders of the package defaults on this world at equal total world ticks
#: (training plus EPS ticks): the report seeds of :data:`REFERENCES` and five held-out seeds, paired seed by seed.
#: Both arms ran GDQ with prioritized replay, its default when they were measured.
PAIRED_REFERENCES = (
    tuple(REFERENCES.values()),
    (
        "docs/results/baselines/gdq4_lambda_changes_heldout/defaults",
        "docs/results/eps/eps_gdq4_pairs_heldout",
    ),
)
#: Total world ticks the pairs are compared at, their evaluation spacing, and how many last evaluations make a score.
REFERENCE_BUDGET = 150_000
REFERENCE_EVAL_EVERY = 10_000
REFERENCE_LAST = 3


def reference_curves(root: Path | None = None) -> list[RunCurve]:
    """:return: the curves of :data:`REFERENCES` under ``root`` (default: the repository), one per seed; none
    where the records are not there (an installed package)."""
    root = Path(__file__).resolve().parents[1] if root is None else root
    curves: list[RunCurve] = []
    for label, folder in REFERENCES.items():
        if (root / folder).is_dir():
            curves.extend(curve for curve in record_curves([root / folder], label) if curve.env_id == ENV_ID)
    return curves


def reference_scores(folder: Path) -> dict[int, float]:
    """:return: seed -> mean greedy team success of the last :data:`REFERENCE_LAST` evaluations scheduled at or
    before :data:`REFERENCE_BUDGET` total ticks (an evaluation a round carried past its point counts for that
    point), from the records in ``folder``."""
    scores = {}
    for curve in record_curves([folder]):
        within = curve.x // REFERENCE_EVAL_EVERY * REFERENCE_EVAL_EVERY <= REFERENCE_BUDGET
        match = RECORD_FILE.match(curve.run_dir.name)
        if match is None:
            raise ValueError(f"{curve.run_dir}: not a record file (<algo>_<env id>_seed<n>.jsonl)")
        seed = int(match["seed"])
        scores[seed] = float(curve.values["success"][within][-REFERENCE_LAST:].mean())
    return scores


def reference_difference(root: Path | None = None) -> dict[str, float] | None:
    """The seed-by-seed difference EPS-GDQ minus GDQ over :data:`PAIRED_REFERENCES` under ``root`` (default: the
    repository).

    :return: ``mean`` and ``sem`` (points of team success), ``n`` (pairs), ``ahead`` (pairs EPS-GDQ leads); None where
        the records are not there (an installed package)
    """
    root = Path(__file__).resolve().parents[1] if root is None else root
    differences = []
    for base, eps in PAIRED_REFERENCES:
        if not ((root / base).is_dir() and (root / eps).is_dir()):
            return None
        base_scores, eps_scores = reference_scores(root / base), reference_scores(root / eps)
        differences += [100 * (eps_scores[seed] - base_scores[seed]) for seed in sorted(set(base_scores) & set(eps_scores))]
    if len(differences) < 2:
        return None
    sem = statistics.stdev(differences) / math.sqrt(len(differences))
    return {"mean": statistics.fmean(differences), "sem": sem, "n": len(differences), "ahead": sum(d > 0 for d in differences)}


def reference_summary(difference: dict[str, float]) -> str:
    """:return: the main job's summary line: the measured difference of EPS-GDQ from GDQ and whether EPS helps on
    this world (ahead by more than two standard errors), from :func:`reference_difference`."""
    helps = difference["mean"] - 2 * difference["sem"] > 0
    verdict = "EPS-GDQ is ahead of GDQ on 4 robots" if helps else "EPS has not been found to help on 4 robots"
    return (
        f"EPS-GDQ against GDQ, committed records (GDQ with prioritized replay) at {REFERENCE_BUDGET // 1000}k total "
        "world ticks: "
        f"{difference['mean']:+.1f} points of greedy team success (SE {difference['sem']:.1f}, "
        f"{difference['n']} paired seeds, EPS-GDQ ahead on {difference['ahead']}): {verdict} (docs/results/eps.md)."
    )


def draw_evaluations(run_dir: Path, output: Path, references: list[RunCurve] | None = None) -> Path | None:
    """Draw a run's greedy evaluations beside the reference curves (default :func:`reference_curves`), x axis =
    training + EPS ticks; the README's picture of the main job is drawn so.

    :return: the picture's path, None when the run has no evaluation
    """
    evaluations = evaluation_curves([Path(run_dir)])
    if not evaluations:
        return None
    references = reference_curves() if references is None else references
    for curve in evaluations:
        curve.algo = f"this run: {label_of(curve.algo)}"
    return plot_learning_curves(evaluations + references, output, window=1, title="greedy evaluations")


def main(argv: Sequence[str] | None = None) -> int:
    """Train, plot, print the paths. :return: the exit status."""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__)
    parser.add_argument("-f", "--log-folder", dest="folder", default="logs", help="folder of the run folders")
    parser.add_argument("-n", "--n-timesteps", type=positive_int, default=BUDGET, help="timesteps (agent-steps)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-tb", "--tensorboard-log", default="logs/tensorboard")
    parser.add_argument("--algo", choices=["eps_gdq", "gdq"], default="eps_gdq", help="EPS-GDQ (default) or GDQ alone")
    args = parser.parse_args(argv)

    options = TrainOptions(
        algo=args.algo, env=ENV_ID, n_timesteps=args.n_timesteps, seed=args.seed, folder=args.folder,
        eval_freq=EVAL_FREQ, eval_episodes=EVAL_EPISODES, save_freq=SAVE_FREQ, progress=True,
        tensorboard_log=args.tensorboard_log, device="cpu", log_interval=200,
    )  # fmt: skip
    result = train(options)
    run_dir = result.run_dir
    curve = plot_learning_curves([load_curve(run_dir)], run_dir / "learning_curve.png", window=100)
    references = reference_curves()
    eval_curve = draw_evaluations(run_dir, run_dir / "eval_curve.png", references)
    print()
    if result.status == "interrupted":
        print(f"Interrupted at {result.num_timesteps} timesteps; continue with: python -m sb3_eps.train --resume {run_dir}")
    print(f"Run folder:      {run_dir}")
    print(f"Learning curve:  {curve}")
    if eval_curve is not None:
        print(f"Evaluations:     {eval_curve}" + (" (beside the committed 5-seed curves)" if references else ""))
    print(f"TensorBoard:     tensorboard --logdir {Path(args.tensorboard_log)}")
    print(f"Evaluate it:     python -m sb3_eps.evaluate --run {run_dir} --eval-env MultiRobotNavUnseen-4-v0 -n 100")
    difference = reference_difference()
    if difference is not None:
        print(reference_summary(difference))
    return 0


def cli() -> None:
    """Console-script entry point: run :func:`main`, turning mistakes into one line and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
