"""The README's main job (``make run``): train EPS-GDQ on ``MultiRobotNav-4-v0`` with ``zoo_configs/eps_gdq.yml``
for 800,000 timesteps (200,000 ticks), then draw its learning curve and its greedy evaluations beside the committed
5-seed curves of GDQ and EPS-GDQ (:data:`REFERENCES`) and print where everything is. SIGINT / SIGTERM stop it with a
checkpoint; ``python -m sb3_eps.train --resume <run folder>`` continues it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from sb3_eps.zoo.cli import OneLineArgumentParser, positive_int
from sb3_eps.zoo.errors import run_command

if TYPE_CHECKING:
    from sb3_eps.zoo.plotting import RunCurve

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


def reference_curves(root: Path | None = None) -> list[RunCurve]:
    """:return: the curves of :data:`REFERENCES` under ``root`` (default: the repository), one per seed; none
    where the records are not there (an installed package)."""
    from sb3_eps.zoo.plotting import record_curves

    root = Path(__file__).resolve().parents[1] if root is None else root
    curves: list[RunCurve] = []
    for label, folder in REFERENCES.items():
        if (root / folder).is_dir():
            curves.extend(curve for curve in record_curves([root / folder], label) if curve.env_id == ENV_ID)
    return curves


def draw_evaluations(run_dir: Path, output: Path, references: list[RunCurve] | None = None) -> Path | None:
    """Draw a run's greedy evaluations beside the reference curves (default :func:`reference_curves`), x axis =
    training + EPS ticks; the README's picture of the main job is drawn so.

    :return: the picture's path, None when the run has no evaluation
    """
    from sb3_eps.zoo.plotting import evaluation_curves, label_of, plot_learning_curves

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
    parser.add_argument(
        "-n", "--n-timesteps", type=positive_int, default=BUDGET, help="timesteps (agent-steps)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-tb", "--tensorboard-log", default="logs/tensorboard")
    parser.add_argument(
        "--algo", choices=["eps_gdq", "gdq"], default="eps_gdq", help="EPS-GDQ (default) or GDQ alone"
    )
    args = parser.parse_args(argv)

    from sb3_eps.zoo.exp_manager import TrainOptions, train
    from sb3_eps.zoo.plotting import load_curve, plot_learning_curves

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
        print(
            f"Interrupted at {result.num_timesteps} timesteps; continue with: python -m sb3_eps.train --resume {run_dir}"
        )
    print(f"Run folder:      {run_dir}")
    print(f"Learning curve:  {curve}")
    if eval_curve is not None:
        print(
            f"Evaluations:     {eval_curve}" + (" (beside the committed 5-seed curves)" if references else "")
        )
    print(f"TensorBoard:     tensorboard --logdir {Path(args.tensorboard_log)}")
    print(
        f"Evaluate it:     python -m sb3_eps.evaluate --run {run_dir} --eval-env MultiRobotNavUnseen-4-v0 -n 100"
    )
    return 0


def cli() -> None:
    """Console-script entry point: run :func:`main`, turning mistakes into one line and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
