"""Loading a run's model and evaluating it greedily on any compatible env id (``python -m sb3_eps.evaluate``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sb3_eps import worlds
from sb3_eps.common.evaluation import evaluate_team, record_frames, summary_key
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.utils import describe_space
from sb3_eps.common.vec_env import make_vec_env
from sb3_eps.zoo import run_folder
from sb3_eps.zoo.checkpoint import write_text_atomic
from sb3_eps.zoo.cli import import_gym_packages
from sb3_eps.zoo.config import check_env_id, load_yaml
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.schema import algorithm_spec

#: Metrics of an evaluation: summary key stem -> (label, unit, scale for printing).
METRICS = {
    "success": ("success", "%", 100.0),
    "collision": ("collision", "%", 100.0),
    "collision_after_spawn": ("collision, spawns left out", "%", 100.0),
    "collisions_per_tick": ("collisions/tick, no spawns", "", 1.0),
    "occupied_landmarks": ("landmarks occupied (end)", "", 1.0),
    "min_dist_sum": ("distance sum (end)", "", 1.0),
    "team_return": ("team return", "", 1.0),
    "distance_travelled": ("path length (all robots)", "m", 1.0),
    "path_length_per_robot": ("path length per robot", "m", 1.0),
    "length": ("episode length", "ticks", 1.0),
}


@dataclass
class LoadedRun:
    """A run folder (its algorithm, the env id it trained on) and the model loaded from ``model_path``, without an
    env: it predicts on any world with the same spaces. ``env_kwargs``: the world arguments the run trained with (its
    ``config.yml``), which its evaluations start from (a model trained on stacked scans needs worlds that stack them)."""

    run_dir: Path
    algo: str
    env_id: str
    model: MultiAgentOffPolicyAlgorithm
    model_path: Path
    env_kwargs: dict[str, Any] = field(default_factory=dict)


def run_env_kwargs(run_dir: str | Path, env_id: str) -> dict[str, Any]:
    """:return: the ``env_kwargs`` of a run's resolved entry (its ``config.yml``), empty when it has none."""
    path = run_folder.run_file(run_dir, run_folder.CONFIG_NAME)
    if not path.is_file():
        return {}
    config = load_yaml(path)
    entry = config.get(env_id) if isinstance(config, dict) else None
    kwargs = entry.get("env_kwargs") if isinstance(entry, dict) else None
    return dict(kwargs) if isinstance(kwargs, dict) else {}


def load_run(run_dir: str | Path, which: str | int = "final", device: str = "auto") -> LoadedRun:
    """Load the final, best or a numbered snapshot's model of a run folder.

    :param run_dir: a folder written by ``python -m sb3_eps.train``
    :param which: ``"final"`` (``<env id>.zip``), ``"best"`` (``best_model.zip``), or the timesteps of a snapshot
        (``rl_model_<timesteps>_steps.zip``, RL Zoo's ``--load-checkpoint``); ``"last"``: the latest snapshot
    :param device: torch device
    :raises ConfigError: when the folder or the model is missing
    """
    run_dir = Path(run_dir)
    args = run_folder.read_args(run_dir)
    snapshots = run_folder.snapshots(run_dir)
    if which == "last" and snapshots:
        which = list(snapshots)[-1]
    names = {"best": run_folder.BEST_MODEL_NAME, "final": run_folder.final_model_name(str(args["env"]))}
    name = names.get(str(which)) or run_folder.snapshot_name(int(which) if str(which).isdigit() else 0)
    path = run_dir / name
    if not path.is_file():
        hints = {
            "final": "it has not finished: resume it, or use --load-best",
            "best": "it ran without evaluations",
        }
        hint = hints.get(str(which), f"its snapshots are at timesteps {list(snapshots) or 'none'}")
        raise ConfigError(f"{run_dir} has no {name} ({hint})")
    import_gym_packages([], args.get("gym_packages") or [])  # the run's plug-ins (its world, its algorithm)
    cls = algorithm_spec(str(args["algo"])).algorithm_class
    # buffer_size=1: no replay memory is needed to predict.
    model = cls.load(path, env=None, device=device, buffer_size=1)
    env_id = str(args["env"])
    return LoadedRun(run_dir, str(args["algo"]), env_id, model, path, run_env_kwargs(run_dir, env_id))


def evaluate_run(
    run: LoadedRun,
    env_id: str | None = None,
    n_episodes: int = 100,
    n_envs: int = 4,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Evaluate a run's greedy model on ``env_id`` (default: its training env id), world episodes counted per team.
    The worlds get the run's own ``env_kwargs`` updated by ``env_kwargs``.

    :return: the summary of :func:`~sb3_eps.evaluate_team` plus ``path_length_per_robot`` and what was run
    :raises ConfigError: when the env id is unknown or its spaces differ from the model's
    """
    env_id = env_id or run.env_id
    env_kwargs = {**run.env_kwargs, **(env_kwargs or {})} or None
    check_env_id(env_id, "--eval-env")
    if n_episodes < 1 or n_envs < 1:
        raise ConfigError(f"-n (episodes) and --n-envs must be >= 1, got {n_episodes} and {n_envs}")
    try:
        venv = make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)
    except (TypeError, ValueError) as error:
        raise ConfigError(f"--env-kwargs {env_kwargs}: {error}") from None
    try:
        check_spaces(run.model, venv, env_id, f"the model of {run.run_dir}")
        summary = evaluate_team(run.model, venv, n_episodes, seed=seed)
        n_agents = venv.n_agents
    finally:
        venv.close()
    if "distance_travelled_mean" in summary:
        per_robot = np.array([e["distance_travelled"] / n_agents for e in summary["episodes"]])
        summary["path_length_per_robot_mean"] = float(per_robot.mean())
        summary["path_length_per_robot_std"] = float(per_robot.std())
    summary.update(
        env_id=env_id, algo=run.algo, train_env_id=run.env_id, run_dir=str(run.run_dir), model=str(run.model_path),
        seed=seed, n_agents=n_agents,
    )  # fmt: skip
    return summary


def check_spaces(model: Any, venv: Any, env_id: str, whose: str = "the model", flag: str = "") -> None:
    """:raises ConfigError: when the env's observation or action space differs from the model's (evaluation
    worlds, warm starts)."""
    for kind in ("observation_space", "action_space"):
        if getattr(venv, kind) != getattr(model, kind):
            raise ConfigError(
                f"{flag}{env_id} has {kind} {describe_space(getattr(venv, kind))} but {whose} expects "
                f"{describe_space(getattr(model, kind))}; pick a world of the same kind (robots with robots, MPE with MPE)"
            )


def format_summary(summary: dict[str, Any]) -> str:
    """:return: the metrics as aligned lines, ``mean +/- std``."""
    lines = [
        f"{algorithm_spec(summary['algo']).label} trained on {summary['train_env_id']}, evaluated on "
        f"{summary['env_id']} ({summary['n_episodes']} episodes, greedy):"
    ]
    for stem, (label, unit, scale) in METRICS.items():
        mean_key = summary_key(stem)
        if mean_key not in summary:
            continue
        mean, std = scale * summary[mean_key], scale * summary[f"{stem}_std"]
        lines.append(f"  {label:<26} {mean:9.2f} +/- {std:7.2f} {unit}")
    return "\n".join(lines)


def save_summary(summary: dict[str, Any], path: str | Path) -> Path:
    """Write an evaluation summary (episodes included) as JSON, atomically."""
    path = Path(path)
    write_text_atomic(path, json.dumps(summary, indent=2, default=lambda value: value.tolist()))  # NumPy values
    return path


def record_gif(
    run: LoadedRun,
    path: str | Path,
    env_id: str | None = None,
    n_episodes: int = 1,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
) -> Path:
    """Play ``n_episodes`` greedy episodes (3,000 frames at most) in one world drawn as ``rgb_array`` and write them
    as an animated GIF at 20 frames per second (the robots decide at 20 Hz: it plays in real time).

    :return: the GIF's path
    """
    env_id = env_id or run.env_id
    kwargs = {**run.env_kwargs, **(env_kwargs or {}), "render_mode": "rgb_array"}
    venv = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=kwargs)
    try:
        check_spaces(run.model, venv, env_id, f"the model of {run.run_dir}")
        frames, _ = record_frames(run.model, venv, n_episodes, max_frames=3_000)
    finally:
        venv.close()
    return worlds.save_gif(frames, path, fps=20)
