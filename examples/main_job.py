"""The README's main job (``make run``): EPS-GDQ, the package's headline (GDQ with ``EvolutionCallback``), trained on
8 robots in the setting that reaches the package's best there, then judged the way every result here is judged.

1. Train ``--algo eps_gdq --env MultiRobotNav-8-v0`` with the GDQ 8-robot entry's setting: each decision held for 4
   ticks and a 1 m lidar view (``action_repeat 4, lidar_range 1.0``), 300k world ticks, 4 worlds, seed 0; EPS's
   single-robot world takes the same options (docs/results/main_job/rules.md, rule R6, chose it).
2. Evaluate the final model greedily on 100 team episodes of separate evaluation worlds (their own seed) and write
   the record (the world's env id and options with it) into the run folder.
3. Write a GIF of one greedy episode and the greedy-evaluation curve beside the committed 5-seed curves of GDQ's
   8-robot entry, and say what EPS did (rounds, crossovers, its share of the ticks).

SIGINT / SIGTERM stop the training with a checkpoint; ``python -m sb3_eps.train --resume <run folder>`` continues it.
Run it from the repository root: ``python examples/main_job.py`` (``make run``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

from sb3_eps.eps.round_log import DIAGNOSTICS_NAME, read_round_log, round_counts
from sb3_eps.zoo.cli import OneLineArgumentParser, TrainOptions, positive_int
from sb3_eps.zoo.errors import run_command
from sb3_eps.zoo.evaluation import evaluate_run, format_summary, load_run, record_gif, save_summary
from sb3_eps.zoo.exp_manager import train
from sb3_eps.zoo.plotting import evaluation_curves, label_of, load_curve, plot_learning_curves

PROG = "python examples/main_job.py"
ENV_ID = "MultiRobotNav-8-v0"
#: The GDQ 8-robot entry's world options (zoo_configs/gdq.yml): decisions at 5 Hz, a 1 m view.
ENV_KWARGS = ["action_repeat:4", "lidar_range:1.0"]
#: 300k ticks x 8 robots / 4 ticks per decision: SB3 timesteps (agent-steps).
BUDGET = 600_000
HYPERPARAMS = ["n_envs:4"]
EVAL_FREQ = 150_000
EVAL_EPISODES = 20
FINAL_EPISODES = 100
#: Evaluation worlds' seed, apart from the training worlds' (seed 0 onwards) and the in-training evaluations'.
FINAL_EVAL_SEED = 10_000
#: The committed greedy evaluations of GDQ's 8-robot entry, seeds 0-4 (docs/results/many_robots.md).
REFERENCE = Path(__file__).resolve().parents[1] / "docs/results/many_robots/short_lidar_crowds_5hz_more_seeds/report/runs/gdq"
REFERENCE_LABEL = "GDQ, 8-robot entry, seeds 0-4"


def eps_summary(run_dir: Path, training_ticks: int) -> str:
    """:return: one line on what EPS did in the run: rounds, crossovers, EPS ticks against the training ticks."""
    rounds = [record for path in sorted(run_dir.rglob(DIAGNOSTICS_NAME)) for record in read_round_log(path)]
    played = [record for record in rounds if not record.get("skipped")]
    if not played:
        return "EPS played no round in this run."
    crossed = round_counts(rounds)["crossovers"]
    eps_ticks = max(int(record.get("eps_ticks", 0)) for record in played)
    share = eps_ticks / training_ticks if training_ticks else 0.0
    return (
        f"EPS: {len(played)} rounds, {crossed} crossed over into the team's network; {eps_ticks} single-robot ticks "
        f"({100 * share:.1f} % of the {training_ticks} training ticks), counted on the x axis."
    )


def draw_evaluations(run_dir: Path, output: Path, reference: Path = REFERENCE) -> Path | None:
    """Draw the run's greedy evaluations beside the committed curves of :data:`REFERENCE` (where present); x axis:
    training + EPS ticks. :return: the picture's path, None when the run has no evaluation"""
    curves = evaluation_curves([run_dir])
    if not curves:
        return None
    for curve in curves:
        curve.algo = f"this run: {label_of(curve.algo)}"
    if reference.is_dir():
        references = evaluation_curves(sorted(path for path in reference.iterdir() if path.is_dir()))
        for curve in references:
            curve.algo = REFERENCE_LABEL
        curves += references
    return plot_learning_curves(curves, output, window=1, title=f"{ENV_ID}: greedy evaluations")


def main(argv: Sequence[str] | None = None) -> int:
    """Train, evaluate, draw, summarise. :return: the exit status"""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__)
    parser.add_argument("-f", "--log-folder", dest="folder", default="logs", help="folder of the run folders")
    parser.add_argument("-n", "--n-timesteps", type=positive_int, default=BUDGET, help="timesteps (agent-steps)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=positive_int, default=FINAL_EPISODES, help="final greedy episodes")
    parser.add_argument("-tb", "--tensorboard-log", default="logs/tensorboard")
    parser.add_argument("--algo", choices=["eps_gdq", "gdq"], default="eps_gdq", help="EPS-GDQ (default) or GDQ alone")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    options = TrainOptions(
        algo=args.algo, env=ENV_ID, n_timesteps=args.n_timesteps, seed=args.seed, folder=args.folder,
        eval_freq=EVAL_FREQ, eval_episodes=EVAL_EPISODES, save_freq=BUDGET, progress=sys.stderr.isatty(),
        tensorboard_log=args.tensorboard_log, device="cpu", log_interval=200, env_kwargs=list(ENV_KWARGS),
        hyperparams=list(HYPERPARAMS), verbose=0,
    )  # fmt: skip
    result = train(options)
    run_dir = result.run_dir
    if result.status == "interrupted":
        print(f"Interrupted at {result.num_timesteps} timesteps; continue with: python -m sb3_eps.train --resume {run_dir}")
        return 0
    trained = time.perf_counter() - start
    run = load_run(run_dir)
    summary = evaluate_run(run, n_episodes=args.eval_episodes, seed=FINAL_EVAL_SEED)
    record = save_summary(summary, run_dir / f"eval_{ENV_ID}.json")
    gif = record_gif(run, run_dir / "team.gif", seed=FINAL_EVAL_SEED)
    curve = plot_learning_curves([load_curve(run_dir)], run_dir / "learning_curve.png", window=100)
    eval_curve = draw_evaluations(run_dir, run_dir / "eval_curve.png")
    ticks = int(getattr(run.model, "ticks", 0))
    print()
    print(format_summary(summary))
    if args.algo == "eps_gdq":
        print(eps_summary(run_dir, ticks))
    print(f"Training:        {trained / 60:.1f} min; everything: {(time.perf_counter() - start) / 60:.1f} min")
    print(f"Run folder:      {run_dir}")
    print(f"Evaluation:      {record}")
    print(f"Team GIF:        {gif}")
    print(f"Learning curve:  {curve}")
    if eval_curve is not None:
        print(f"Evaluations:     {eval_curve}" + (" (beside GDQ's committed 5-seed curves)" if REFERENCE.is_dir() else ""))
    print(f"TensorBoard:     tensorboard --logdir {Path(args.tensorboard_log)}")
    print(f"Watch it:        python -m sb3_eps.enjoy --run {run_dir} --gif team.gif -n 5")
    return 0


if __name__ == "__main__":
    run_command(PROG, lambda: main())
