"""``python -m sb3_eps.enjoy``: watch a trained team, RL Zoo's ``enjoy`` for multi-robot worlds.

Examples::

    python -m sb3_eps.enjoy --algo gdq --env MultiRobotNav-12-v0                  # a shipped model, no training
    python -m sb3_eps.enjoy --algo gdq --env MultiRobotNav-12-v0 --no-render --gif team.gif -n 5
    python -m sb3_eps.enjoy --algo gdq --env MultiRobotNav-8-v0 -f logs --load-best   # your own run
    python -m sb3_eps.enjoy --run logs/eps_gdq/MultiRobotNav-8-v0_1 --env MultiRobotNav-12-v0 --mp4 team.mp4

The model comes from the shipped pretrained models (``sb3_eps.pretrained``) unless ``-f`` names a log folder or
``--run`` a run folder. It plays ``-n`` greedy team episodes in one world with its own world options, in PyBullet's
window where a display exists; ``--gif`` / ``--mp4`` record them (headless with no display and no file named: a GIF
``enjoy_<env id>.gif``), ``--no-render`` plays without pictures. Each episode prints a line as it ends: robots
arrived, collisions, length, team return; the last line sums them up.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_eps import worlds
from sb3_eps.common.vec_env import make_vec_env
from sb3_eps.zoo.cli import OneLineArgumentParser, add_gym_packages_flag, check_device, import_gym_packages
from sb3_eps.zoo.config import check_env_id
from sb3_eps.zoo.errors import ConfigError, run_command
from sb3_eps.zoo.evaluation import LoadedRun, check_spaces, load_run
from sb3_eps.zoo.pretrained import pretrained_run
from sb3_eps.zoo.run_folder import find_run
from sb3_eps.zoo.schema import ALGORITHMS

PROG = "python -m sb3_eps.enjoy"
#: A recording's frames: one per decision. Its speed: ``--speed`` times real time.
DEFAULT_SPEED = 2.0
MAX_FRAMES = 6_000


def make_parser() -> argparse.ArgumentParser:
    """:return: the parser (RL Zoo ``enjoy``'s flags and a few of ours)."""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=list(ALGORITHMS), default="gdq")
    parser.add_argument("--env", default=None, help="the world to play in (default: the model's training world)")
    parser.add_argument("-f", "--folder", default=None, help="log folder of your runs (default: the shipped models)")
    parser.add_argument("--run", default=None, help="a run folder (instead of --algo / -f / --exp-id)")
    parser.add_argument("--exp-id", type=int, default=0, help="run number in -f (0: the latest)")
    parser.add_argument("--load-best", action="store_true", help="the run's best evaluated model")
    parser.add_argument("-n", "--n-episodes", type=int, default=5, help="team episodes to play")
    parser.add_argument("--no-render", action="store_true", help="no window and no pictures (a recording still draws)")
    parser.add_argument("--gif", default=None, metavar="PATH", help="record the episodes as an animated GIF")
    parser.add_argument("--mp4", default=None, metavar="PATH", help="record the episodes as MP4 (needs imageio-ffmpeg)")
    parser.add_argument("--speed", type=float, default=DEFAULT_SPEED, help="a recording's speed, times real time")
    parser.add_argument("--seed", type=int, default=0, help="seed of the world")
    parser.add_argument("--env-kwargs", nargs="+", default=[], metavar="KEY:VALUE", help="world options on top of the model's")
    parser.add_argument("--device", default="cpu")
    add_gym_packages_flag(parser)
    return parser


def find_model(args: argparse.Namespace) -> LoadedRun:
    """:return: the run to play: ``--run``, a run of ``-f``, or the shipped model for ``--algo`` on ``--env``."""
    which = "best" if args.load_best else "final"
    if args.run is not None:
        return load_run(args.run, which, args.device)
    if args.folder is not None:
        if args.env is None:
            raise ConfigError("-f: name the run's world with --env (or the run folder with --run)")
        return load_run(find_run(args.folder, args.algo, args.env, args.exp_id), which, args.device)
    if args.load_best or args.exp_id:
        raise ConfigError("--load-best and --exp-id pick a run of -f: the shipped models have one model each")
    return pretrained_run(args.algo, args.env or "MultiRobotNav-4-v0", args.device)


def render_mode(args: argparse.Namespace) -> str | None:
    """:return: ``rgb_array`` when recording, ``human`` with a display, None otherwise."""
    if args.gif or args.mp4:
        return "rgb_array"
    if args.no_render:
        return None
    return "human" if worlds.display_available() else "rgb_array"


def episode_line(number: int, total: int, episode: dict[str, Any], n_agents: int) -> str:
    """:return: one printed line for a finished team episode."""
    parts = [f"episode {number}/{total}:"]
    if "n_arrived" in episode:
        parts.append(f"{int(episode['n_arrived'])}/{n_agents} robots arrived,")
    if "collision" in episode:
        parts.append(f"collision {'yes' if episode['collision'] else 'no'},")
    parts.append(f"{int(episode['l'])} ticks, team return {float(episode['r']):.2f}")
    if "success" in episode:
        parts.append("(success)" if episode["success"] else "(failure)")
    return " ".join(parts)


def write_video(frames: list[np.ndarray], path: str, fps: float) -> Path:
    """Write the frames as a GIF (the worlds' writer) or, for ``.mp4``, a video. :return: the path"""
    target = Path(path)
    if target.suffix.lower() != ".mp4":
        return worlds.save_gif(frames, target, fps)
    import imageio.v2 as imageio

    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        imageio.mimsave(target, [np.asarray(frame, dtype=np.uint8) for frame in frames], fps=fps, macro_block_size=1)
    except (ImportError, ValueError, RuntimeError) as error:
        raise ConfigError(f"--mp4 needs imageio-ffmpeg (pip install imageio-ffmpeg): {error}") from None
    return target


def play(
    run: LoadedRun, env_id: str, n_episodes: int, mode: str | None, seed: int, env_kwargs: dict[str, Any]
) -> tuple[list[dict[str, Any]], list[np.ndarray], int]:
    """Play greedy team episodes in one world, printing a line per episode.

    :return: the episodes, the frames (one per decision) and the world ticks a decision is held
    """
    kwargs = {**run.env_kwargs, **env_kwargs}
    if mode is not None:
        kwargs["render_mode"] = mode
    try:
        venv = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=kwargs)
    except (TypeError, ValueError) as error:
        raise ConfigError(
            f"{env_id} does not take the world options {kwargs} (the model's and --env-kwargs): {error}; pick a world "
            "of the model's kind"
        ) from None
    episodes: list[dict[str, Any]] = []
    frames: list[np.ndarray] = []
    try:
        check_spaces(run.model, venv, env_id, f"the model {run.model_path.name}")
        observations: Any = venv.reset()
        while len(episodes) < n_episodes:
            if mode is not None:
                picture = venv.get_images()[0]
                if mode == "rgb_array" and picture is not None and len(frames) < MAX_FRAMES:
                    frames.append(picture)
            actions, _ = run.model.predict(observations, deterministic=True)
            observations, _, _, infos = venv.step(actions)
            if "episode" in infos[0]:
                episodes.append(dict(infos[0]["episode"]))
                print(episode_line(len(episodes), n_episodes, episodes[-1], venv.n_agents), flush=True)
        ticks_per_frame = venv.ticks_per_step
    finally:
        venv.close()
    return episodes, frames, ticks_per_frame


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line. :return: the exit status"""
    import_gym_packages(argv)
    args = make_parser().parse_args(argv)
    if args.n_episodes < 1 or args.speed <= 0:
        raise ConfigError(f"-n must be >= 1 and --speed > 0, got {args.n_episodes} and {args.speed}")
    check_device(args.device)
    from sb3_eps.zoo.config import parse_hyperparams

    env_kwargs = {path[0]: value for path, value in parse_hyperparams(args.env_kwargs)}
    run = find_model(args)
    env_id = args.env or run.env_id
    check_env_id(env_id, "--env")
    mode = render_mode(args)
    record = args.gif or args.mp4
    if mode == "rgb_array" and not record:
        record = f"enjoy_{env_id}.gif"
        print(f"No display: recording to {record} (--no-render plays without pictures)")
    options = {**run.env_kwargs, **env_kwargs}
    print(f"{run.algo} from {run.model_path} on {env_id}" + (f" with {options}" if options else ""), flush=True)
    episodes, frames, ticks_per_frame = play(run, env_id, args.n_episodes, mode, args.seed, env_kwargs)
    successes = [bool(episode.get("success", False)) for episode in episodes]
    collisions = [bool(episode.get("collision", False)) for episode in episodes]
    print(
        f"{len(episodes)} episodes: success {sum(successes)}/{len(episodes)} ({100 * np.mean(successes):.0f} %), "
        f"collisions in {sum(collisions)} ({100 * np.mean(collisions):.0f} %)"
    )
    if record and frames:
        fps = args.speed * 20.0 / ticks_per_frame  # the worlds tick at 20 Hz; a frame per decision
        try:
            path = write_video(frames, str(record), fps)
        except OSError as error:
            raise ConfigError(f"cannot write {record}: {error.strerror or error}") from None
        print(f"Recording: {path} ({len(frames)} frames, {args.speed:g}x real time)")
    return 0


def cli() -> None:
    """Console-script entry point: run :func:`main`, turning mistakes into one line and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
