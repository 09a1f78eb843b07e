"""``python -m sb3_eps.train``: train or tune from the RL-Zoo-style configs in ``zoo_configs/``.

Examples::

    python -m sb3_eps.train --algo gdq --env MultiRobotNav-4-v0 -n 400000 --seed 0 -f logs --progress
    python -m sb3_eps.train --algo eps_gdq --env MultiRobotNav-4-v0 --hyperparams learning_rate:lin_1e-3
    python -m sb3_eps.train --resume logs/gdq/MultiRobotNav-4-v0_1
    python -m sb3_eps.train --algo gdq --ladder MultiRobotNav-4-v0:150000 MultiRobotNav-8-v0:150000 \
        --hyperparams policy_kwargs.global_head:pooled
    python -m sb3_eps.train --algo gdq --env MultiRobotNav-4-v0 -optimize --n-trials 20 --n-jobs 2

Counts (``-n``, ``--eval-freq``, ``--save-freq``) are SB3 timesteps = agent-steps (ticks x robots), as in
``model.learn``. A mistake in a flag or config is one line on stderr and exit status 2; SIGINT / SIGTERM write a
checkpoint and exit 0. See ``docs/usage.md``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from sb3_eps.zoo.cli import OneLineArgumentParser, TrainOptions, add_gym_packages_flag, import_gym_packages
from sb3_eps.zoo.errors import run_command
from sb3_eps.zoo.exp_manager import resume, train
from sb3_eps.zoo.ladder import ladder_option
from sb3_eps.zoo.run_folder import command_line
from sb3_eps.zoo.schema import ALGORITHMS
from sb3_eps.zoo.tuning import TuningOptions, tune

PROG = "python -m sb3_eps.train"
DEFAULT_ENV = "MultiRobotNav-4-v0"


def make_parser() -> argparse.ArgumentParser:
    """:return: the parser of ``python -m sb3_eps.train`` (flags follow ``rl_zoo3.train``)."""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=list(ALGORITHMS), default="gdq", help="algorithm (default gdq)")
    parser.add_argument("--env", default=None, help=f"env id (default {DEFAULT_ENV}, or the last rung of --ladder)")
    parser.add_argument("-conf", "--conf-file", default=None, help="config YAML (default zoo_configs/<algo>.yml)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="total timesteps (agent-steps); default: config")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: drawn and recorded)")
    parser.add_argument("-f", "--log-folder", dest="folder", default="logs", help="folder of the run folders")
    parser.add_argument(
        "--run-name",
        default=None,
        help="run folder name under <log folder>/<algo>/ (default: <env id>_<next free number>)",
    )
    parser.add_argument("--eval-freq", type=int, default=25_000, help="timesteps between team evaluations (0: none)")
    parser.add_argument("--eval-episodes", type=int, default=10, help="world episodes per evaluation")
    parser.add_argument("--n-eval-envs", type=int, default=2, help="evaluation worlds run side by side")
    parser.add_argument(
        "--vec-env",
        choices=["dummy", "subproc"],
        default=None,
        help="worlds in this process (dummy) or in worker processes, one per core (subproc); default: config",
    )
    parser.add_argument("--eval-env", default=None, help="env id of the evaluation worlds (default: --env)")
    parser.add_argument("--save-freq", type=int, default=100_000, help="timesteps between checkpoints (0: on signals only)")
    parser.add_argument("--keep-checkpoint", action="store_true", help="keep checkpoint.zip after the run finishes")
    parser.add_argument("-P", "--progress", action="store_true", help="show a progress bar")
    parser.add_argument("-tb", "--tensorboard-log", default=None, help="TensorBoard folder")
    parser.add_argument("--device", default="auto", help="torch device (auto, cpu, cuda)")
    parser.add_argument(
        "-params",
        "--hyperparams",
        nargs="+",
        default=[],
        metavar="KEY:VALUE",
        help="config overrides, e.g. learning_rate:1e-4 policy_kwargs.net_arch:[64,64]",
    )
    parser.add_argument(
        "--ladder",
        nargs="+",
        default=[],
        metavar="ENV:TICKS",
        help="train one model on these worlds in turn, e.g. MultiRobotNav-4-v0:150000 MultiRobotNav-8-v0:150000",
    )
    parser.add_argument("--env-kwargs", nargs="+", default=[], metavar="KEY:VALUE", help="env constructor overrides")
    parser.add_argument("--verbose", type=int, default=None, help="0 silent, 1 info (default 1, or as the resumed run)")
    parser.add_argument("--log-interval", type=int, default=-1, help="episodes between log dumps (-1: 4)")
    parser.add_argument("--num-threads", type=int, default=1, help="torch threads (results repeat at equal counts)")
    parser.add_argument(
        "--init-from",
        default=None,
        metavar="MODEL.zip",
        help="warm start: load this model's agent network (q_net and target)",
    )
    parser.add_argument("--resume", default=None, metavar="RUN_DIR", help="continue an interrupted run to its total")
    add_gym_packages_flag(parser)
    tuning = parser.add_argument_group("tuning (Optuna)")
    tuning.add_argument("-optimize", "--optimize-hyperparameters", action="store_true", help="run a hyper-parameter search")
    tuning.add_argument("--n-trials", type=int, default=20, help="trials of this process")
    tuning.add_argument("--n-jobs", type=int, default=1, help="trials run in parallel (threads) by this process")
    tuning.add_argument("--sampler", choices=["tpe", "random"], default="tpe")
    tuning.add_argument("--pruner", choices=["median", "halving", "none"], default="median")
    tuning.add_argument("--n-startup-trials", type=int, default=5, help="random trials before TPE, unpruned trials")
    tuning.add_argument("--n-evaluations", type=int, default=4, help="evaluations per trial (pruning points)")
    tuning.add_argument("--storage", default=None, help="Optuna storage URL (default: sqlite file in the tuning folder)")
    tuning.add_argument("--study-name", default=None, help="study name (default <algo>-<env>)")
    tuning.add_argument(
        "--n-seeds-per-trial",
        type=int,
        default=1,
        help="train each trial on seeds --seed, --seed + 1, ... and score the mean (noisy worlds need several)",
    )
    tuning.add_argument(
        "--sampler-seed",
        type=int,
        default=None,
        help="seed of the sampler (default: --seed); give each process that joins a study its own",
    )
    tuning.add_argument(
        "--eps-only",
        action="store_true",
        help="eps_* algorithms: search only the EPS arguments; the base algorithm keeps the entry's settings",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line. :return: the exit status."""
    import_gym_packages(argv)  # first: the algorithms they register are choices of --algo
    args = make_parser().parse_args(argv)
    if args.resume is not None:
        resume(args.resume, progress=args.progress or None, verbose=args.verbose)
        return 0
    if args.verbose is None:
        args.verbose = 1
    if args.ladder:
        args.hyperparams = [*args.hyperparams, ladder_option(args.ladder)]
    if args.env is None:
        args.env = args.ladder[-1].rpartition(":")[0] if args.ladder else DEFAULT_ENV
    options = TrainOptions.from_namespace(args)
    options.command = command_line(PROG, sys.argv[1:] if argv is None else argv)
    if args.optimize_hyperparameters:
        tune(options, TuningOptions.from_namespace(args))
        return 0
    train(options)
    return 0


def cli() -> None:
    """Console-script entry point: run :func:`main`, turning mistakes into one line and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
