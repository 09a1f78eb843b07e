"""The run folder of ``python -m sb3_eps.train`` in RL Zoo's layout (``docs/usage.md``, "The run folder"): its file
names, and how to create, find and read one without the training stack. Every reader here also finds ``args.yml``
and ``config.yml`` at a run folder's root."""

from __future__ import annotations

import csv
import json
import re
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_eps.zoo.errors import ConfigError

ARGS_NAME = "args.yml"
CONFIG_NAME = "config.yml"
COMMAND_NAME = "command.txt"
PROGRESS_NAME = "progress.csv"
MONITOR_NAME = "monitor.csv"
EVALUATIONS_NAME = "evaluations.npz"
#: The array of ``evaluations.npz`` that holds the evaluation world (``sb3_eps.common.evaluation.world_record``) as
#: JSON text (:func:`read_evaluation_world`).
EVALUATIONS_WORLD_KEY = "world"
BEST_MODEL_NAME = "best_model.zip"
FINAL_REPORT_NAME = "final_vs_best.txt"
#: RL Zoo's (SB3 ``CheckpointCallback``'s) name of the model snapshots: ``rl_model_<timesteps>_steps.zip``.
SNAPSHOT_PATTERN = re.compile(r"^rl_model_(\d+)_steps\.zip$")


def final_model_name(env_id: str) -> str:
    """:return: the file name of a run's final model (RL Zoo's ``<env id>.zip``)."""
    return f"{env_id}.zip"


def snapshot_name(num_timesteps: int) -> str:
    """:return: the file name of the model snapshot at ``num_timesteps`` (RL Zoo's ``rl_model_<n>_steps.zip``)."""
    return f"rl_model_{int(num_timesteps)}_steps.zip"


def snapshots(run_dir: str | Path) -> dict[int, Path]:
    """:return: timesteps -> model snapshot of a run folder, in order."""
    found = {int(match.group(1)): path for path in Path(run_dir).glob("rl_model_*_steps.zip")
             if (match := SNAPSHOT_PATTERN.match(path.name))}  # fmt: skip
    return dict(sorted(found.items()))


def run_file(run_dir: str | Path, name: str) -> Path:
    """:return: where a run's ``args.yml`` / ``config.yml`` / ``command.txt`` is: in its parameter folder, or at its
    root (older runs); the root path when neither exists."""
    run_dir = Path(run_dir)
    inside = sorted(path for path in run_dir.glob(f"*/{name}") if path.is_file())
    return inside[0] if inside else run_dir / name


def run_dir_of(path: str | Path) -> Path:
    """:return: the run folder ``path`` names: ``path`` itself, or the run above it when ``path`` is the run's
    parameter folder ``<run>/<env id>/`` (RL Zoo's layout: the folder that holds ``config.yml``)."""
    path = Path(path)
    if not (path / ARGS_NAME).is_file():
        return path
    try:
        env_id = read_args(path).get("env")
    except ConfigError:
        return path
    return path.parent if path.name == env_id else path


def is_run_folder(path: str | Path) -> bool:
    """:return: whether ``path`` is a run folder of ``python -m sb3_eps.train`` (it has an ``args.yml``)."""
    return run_file(path, ARGS_NAME).is_file()


def read_args(run_dir: str | Path, where: str = "") -> dict[str, Any]:
    """Read a run's ``args.yml``.

    :param where: what asked (``--resume: ``...), for messages
    :raises ConfigError: when the folder is not a run folder or the file does not name the algo and env
    """
    from sb3_eps.zoo.config import load_yaml

    path = run_file(run_dir, ARGS_NAME)
    if not path.is_file():
        raise ConfigError(f"{where}{run_dir} is not a run folder of sb3_eps.train (no {ARGS_NAME})")
    args = load_yaml(path)
    if not isinstance(args, dict) or "algo" not in args or "env" not in args:
        raise ConfigError(f"{where}{path} does not name the run's algo and env: not a run of sb3_eps.train")
    return args


def command_line(prog: str = "python -m sb3_eps.train", argv: Sequence[str] | None = None) -> str:
    """:return: the command line of a run, as RL Zoo's ``command.txt`` records it (``argv``: its arguments; None:
    this process's)."""
    return shlex.join([*prog.split(), *(sys.argv[1:] if argv is None else argv)])


def run_numbers(parent: Path, env_id: str) -> list[int]:
    """:return: the sorted numbers ``n`` of the ``<env id>_<n>`` folders in ``parent`` (none when it is missing)."""
    pattern = re.compile(rf"^{re.escape(env_id)}_(\d+)$")
    if not parent.is_dir():
        return []
    return sorted(int(match.group(1)) for path in parent.iterdir() if (match := pattern.match(path.name)))


def create_run_folder(folder: str | Path, algo: str, env_id: str, name: str | None = None) -> Path:
    """Create ``<folder>/<algo>/<env id>_<n>`` with the next free ``n`` (safe when processes race), or
    ``<folder>/<algo>/<name>`` when a name is given.

    :raises ConfigError: when the named folder exists already
    """
    parent = Path(folder) / algo
    parent.mkdir(parents=True, exist_ok=True)
    if name is not None:
        path = parent / name
        try:
            path.mkdir()
        except FileExistsError:
            raise ConfigError(
                f"--run-name: {path} exists already; continue it with --resume {path}, or pick another name"
            ) from None
        return path
    number = max(run_numbers(parent, env_id), default=0) + 1
    while True:
        path = parent / f"{env_id}_{number}"
        try:
            path.mkdir()
            return path
        except FileExistsError:
            number += 1


def find_run(folder: str | Path, algo: str, env_id: str, exp_id: int = 0) -> Path:
    """RL Zoo's lookup: ``<folder>/<algo>/<env id>_<exp_id>``, the latest run when ``exp_id`` is 0.

    :raises ConfigError: when there is no such run
    """
    parent = Path(folder) / algo
    numbers = run_numbers(parent, env_id)
    if not numbers:
        raise ConfigError(f"no run of {algo} on {env_id} in {parent}; train one with python -m sb3_eps.train")
    number = numbers[-1] if exp_id == 0 else exp_id
    if number not in numbers:
        raise ConfigError(f"--exp-id {exp_id}: no run {env_id}_{exp_id} in {parent}; runs: {numbers}")
    return parent / f"{env_id}_{number}"


def read_monitor(path: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read a ``monitor.csv``.

    :return: ``(header, columns)``; columns as float arrays (booleans as 0/1)
    """
    path = Path(path)
    with path.open() as file:
        first = file.readline()
        header = json.loads(first[1:]) if first.startswith("#") else {}
        rows = list(csv.DictReader(file))
    columns: dict[str, np.ndarray] = {}
    if rows:
        for key in rows[0]:
            try:
                columns[key] = np.array([float(row[key]) if row[key] != "" else np.nan for row in rows])
            except ValueError:
                continue
    return header, columns


def read_evaluation_world(path: str | Path) -> dict[str, Any] | None:
    """:return: the world a run's periodic evaluations were measured on (``env_id``, ``env_kwargs``, ``level_set``,
    ``n_episodes``) from its ``evaluations.npz`` (``path``: the file or its run folder); None for a file written
    before it was kept."""
    path = Path(path)
    with np.load(path / EVALUATIONS_NAME if path.is_dir() else path) as data:
        return json.loads(str(data[EVALUATIONS_WORLD_KEY])) if EVALUATIONS_WORLD_KEY in data else None
