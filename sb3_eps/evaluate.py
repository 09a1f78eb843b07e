"""``python -m sb3_eps.evaluate``: evaluate a trained run greedily on any compatible env id.

Examples::

    python -m sb3_eps.evaluate --run logs/eps_gdq/MultiRobotNav-4-v0_1 --eval-env MultiRobotNavUnseen-4-v0 -n 100
    python -m sb3_eps.evaluate --algo gdq --env MultiRobotNav-4-v0 -f logs --load-best --gif gdq.gif

Prints success %, collision %, team return, path length and episode length (mean +/- std over world episodes)
and saves them with every episode as JSON (default ``<run>/eval_<env id>[_best].json``).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

from sb3_eps.zoo.cli import OneLineArgumentParser, add_gym_packages_flag, check_device, import_gym_packages
from sb3_eps.zoo.config import parse_hyperparams
from sb3_eps.zoo.errors import ConfigError, run_command
from sb3_eps.zoo.evaluation import evaluate_run, format_summary, load_run, record_gif, save_summary
from sb3_eps.zoo.run_folder import find_run
from sb3_eps.zoo.schema import ALGORITHMS

PROG = "python -m sb3_eps.evaluate"


def make_parser() -> argparse.ArgumentParser:
    """:return: the parser of ``python -m sb3_eps.evaluate`` (run lookup as ``rl_zoo3.enjoy``)."""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", default=None, help="the run folder (or use --algo, --env, -f, --exp-id)")
    parser.add_argument("--algo", choices=list(ALGORITHMS), default=None)
    parser.add_argument("--env", default=None, help="the env id the run trained on")
    parser.add_argument("-f", "--log-folder", dest="folder", default="logs")
    parser.add_argument("--exp-id", type=int, default=0, help="run number (0: the latest)")
    which = parser.add_mutually_exclusive_group()  # none of them: the final model
    which.add_argument("--load-best", dest="which", action="store_const", const="best", help="the best evaluated model")
    which.add_argument(
        "--load-checkpoint", dest="which", type=int, metavar="N",
        help="the model snapshot at N timesteps (rl_model_N_steps.zip, written every --save-freq)",
    )  # fmt: skip
    which.add_argument("--load-last-checkpoint", dest="which", action="store_const", const="last", help="the latest snapshot")
    parser.add_argument("--eval-env", default=None, help="env id to evaluate on (default: the training env id)")
    parser.add_argument("-n", "--n-episodes", type=int, default=100, help="world (team) episodes")
    parser.add_argument("--n-envs", type=int, default=4, help="worlds run side by side")
    parser.add_argument("--seed", type=int, default=0, help="seed of the evaluation worlds")
    parser.add_argument(
        "--env-kwargs",
        nargs="+",
        default=[],
        metavar="KEY:VALUE",
        help="env constructor arguments, updating the run's own (its config.yml's env_kwargs)",
    )
    parser.add_argument("--gif", default=None, metavar="PATH", help="also write a GIF of greedy episodes")
    parser.add_argument("--gif-episodes", type=int, default=1, help="episodes in the GIF")
    parser.add_argument("--output", default=None, help="JSON file of the results")
    parser.add_argument("--device", default="auto")
    add_gym_packages_flag(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line. :return: the exit status."""
    import_gym_packages(argv)  # a run's own --gym-packages are imported again by load_run
    args = make_parser().parse_args(argv)
    if args.run is None:
        if args.algo is None or args.env is None:
            raise ConfigError("name the run: --run RUN_DIR, or --algo, --env (and -f, --exp-id)")
        args.run = find_run(args.folder, args.algo, args.env, args.exp_id)
    check_device(args.device)
    for flag, path in (("--gif", args.gif), ("--output", args.output)):
        if path is not None and not _can_create(Path(path)):
            raise ConfigError(f"{flag}: cannot write {path}: its folder is not writable")
    env_kwargs = {path[0]: value for path, value in parse_hyperparams(args.env_kwargs)}
    which = "final" if args.which is None else args.which
    run = load_run(args.run, which, args.device)
    summary = evaluate_run(run, args.eval_env, args.n_episodes, args.n_envs, args.seed, env_kwargs or None)
    print(format_summary(summary))
    suffix = {"final": "", "best": "_best", "last": "_last"}.get(str(which), f"_{which}_steps")
    output = Path(args.output) if args.output else run.run_dir / f"eval_{summary['env_id']}{suffix}.json"
    print(f"Results: {save_summary(summary, output)}")
    if args.gif is not None:
        try:
            path = record_gif(run, args.gif, args.eval_env, args.gif_episodes, args.seed, env_kwargs or None)
        except OSError as error:
            raise ConfigError(f"--gif: cannot write {args.gif}: {error.strerror or error}") from None
        print(f"GIF: {path}")
    return 0


def _can_create(path: Path) -> bool:
    """:return: whether ``path`` can be written (its missing folders are created): the nearest existing folder
    above it is a writable directory."""
    folder = path.resolve().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder.is_dir() and os.access(folder, os.W_OK)


def cli() -> None:
    """Console-script entry point: run :func:`main`, turning mistakes into one line and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
