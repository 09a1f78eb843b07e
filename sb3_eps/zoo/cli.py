"""Shared pieces of the command lines: an argparse parser whose errors are one-line :class:`ConfigError` s, the
options of a training run, and the ``--gym-packages`` plug-in hook."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import sys
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, NoReturn, TypeVar

import torch as th

from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.schema import normalize_value


class OneLineArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` that raises :class:`ConfigError` instead of printing usage and exiting, so
    every command-line mistake is one line on stderr with exit status 2 (see :func:`~sb3_eps.zoo.errors.run_command`).
    """

    def error(self, message: str) -> NoReturn:
        raise ConfigError(f"{message} (see --help)")


SelfOptions = TypeVar("SelfOptions", bound="NamespaceOptions")


class NamespaceOptions:
    """Base of the option dataclasses of the command lines (training, tuning): a field is named as its flag
    (``eval_freq`` for ``--eval-freq``), its annotation and its range in :data:`~sb3_eps.zoo.schema.RANGES` say what
    it may hold."""

    def check_fields(self, where: str = "") -> None:
        """:raises ConfigError: for a field that does not fit its annotation or range, naming the flag (or ``where``
        and the field)."""
        hints = typing.get_type_hints(type(self))
        for name in (field.name for field in dataclasses.fields(self)):  # type: ignore[arg-type]
            label = f"{where}: {name}" if where else f"--{name.replace('_', '-')}"
            normalize_value(getattr(self, name), hints[name], label, name)

    @classmethod
    def from_namespace(cls: type[SelfOptions], namespace: argparse.Namespace) -> SelfOptions:
        """:return: the options of a parsed command line: the flags named as fields (the others ignored)."""
        names = {field.name for field in dataclasses.fields(cls)}  # type: ignore[arg-type]
        options: Any = cls(**{key: value for key, value in vars(namespace).items() if key in names})
        return options


@dataclass
class TrainOptions(NamespaceOptions):
    """The options of a training run (``python -m sb3_eps.train``; ``args.yml`` holds them resolved).

    Counts (``n_timesteps``, ``eval_freq``, ``save_freq``) are SB3 timesteps = agent-steps, as in RL Zoo.
    """

    algo: str = "gdq"
    env: str = "MultiRobotNav-4-v0"
    conf_file: str | None = None
    n_timesteps: int | None = None
    seed: int | None = None
    folder: str = "logs"
    eval_freq: int = 25_000
    eval_episodes: int = 10
    n_eval_envs: int = 2
    eval_env: str | None = None
    save_freq: int = 100_000
    keep_checkpoint: bool = False
    progress: bool = False
    tensorboard_log: str | None = None
    device: str = "cpu"
    hyperparams: list[str] = dataclasses.field(default_factory=list)
    env_kwargs: list[str] = dataclasses.field(default_factory=list)
    verbose: int = 1
    log_interval: int = -1
    num_threads: int = 1
    init_from: str | None = None
    vec_env: Literal["dummy", "subproc"] | None = None
    run_name: str | None = None
    gym_packages: list[str] = dataclasses.field(default_factory=list)
    command: str | None = None  # the command line as typed (RL Zoo's command.txt)

    @classmethod
    def from_record(cls, record: Any, source: str | Path) -> TrainOptions:
        """:return: the options recorded in a run's ``args.yml`` (unknown keys ignored).

        :raises ConfigError: when the record is not a mapping of options of the right types
        """
        if not isinstance(record, dict):
            raise ConfigError(f"{source} is not a mapping of options: not a run folder of sb3_eps.train")
        names = [field.name for field in dataclasses.fields(cls)]
        options = cls(**{key: value for key, value in record.items() if key in names})
        try:
            options.check_fields(str(source))
        except ConfigError as error:
            raise ConfigError(f"{error}: not a run of sb3_eps.train") from None
        return options

    def check(self) -> None:
        """:raises ConfigError: for a flag of the wrong type or out of range, a bad run name, device or warm start."""
        self.check_fields()
        if self.run_name is not None and (
            not self.run_name or self.run_name in (".", "..") or "/" in self.run_name or "\\" in self.run_name
        ):
            raise ConfigError(f"--run-name must be a plain folder name (no slashes), got {self.run_name!r}")
        check_device(self.device)
        if self.init_from is not None and not Path(self.init_from).is_file():
            raise ConfigError(f"--init-from: {self.init_from} is not a file; pass a model .zip (e.g. a run's best_model.zip)")


def check_device(device: str) -> None:
    """:raises ConfigError: when ``device`` is neither ``auto`` nor a torch device string."""
    try:
        th.device("cpu" if device == "auto" else device)
    except (RuntimeError, TypeError) as error:
        raise ConfigError(f"--device {device!r} is not a torch device (auto, cpu, cuda, cuda:0...): {error}") from None


@dataclass
class TrainResult:
    """What a training command did: ``status`` is ``"complete"``, ``"interrupted"`` or ``"already complete"``."""

    run_dir: Path
    status: str
    num_timesteps: int


def positive_int(text: str) -> int:
    """argparse type: an int >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an int >= 1, got {value}")
    return value


GYM_PACKAGES_HELP = (
    "modules to import first (RL Zoo's flag): they register their own worlds (envs.register or pettingzoo.register), "
    "algorithms (sb3_eps.zoo.register_algorithm), callbacks (sb3_eps.zoo.register_callback) and trainers "
    "(sb3_eps.zoo.register_trainer)"
)


def add_gym_packages_flag(parser: argparse.ArgumentParser) -> None:
    """Add ``--gym-packages MODULE ...`` to a command line."""
    parser.add_argument("--gym-packages", nargs="+", default=[], metavar="MODULE", help=GYM_PACKAGES_HELP)


def import_gym_packages(argv: Sequence[str] | None = None, packages: Sequence[str] = ()) -> list[str]:
    """Import the modules of ``--gym-packages`` (read from ``argv`` before the real parser is built, so that the
    algorithms they register are choices of ``--algo``) and ``packages``.

    :return: the module names, in order
    :raises ConfigError: when one cannot be imported or fails while registering
    """
    pre = argparse.ArgumentParser(add_help=False)
    add_gym_packages_flag(pre)
    known, _ = pre.parse_known_args(list(sys.argv[1:] if argv is None else argv))
    names = list(dict.fromkeys([*packages, *known.gym_packages]))
    for name in names:
        try:
            importlib.import_module(name)
        except ImportError as error:
            raise ConfigError(
                f"--gym-packages: cannot import {name!r} ({error}); put its folder on PYTHONPATH or pip install it"
            ) from None
        except Exception as error:  # the module's own registration failed: say which module and why
            raise ConfigError(f"--gym-packages: importing {name!r} failed: {type(error).__name__}: {error}") from None
    return names
