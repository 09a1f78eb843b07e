"""Shared pieces of the command lines: an argparse parser whose errors are one-line :class:`ConfigError` s, and the
``--gym-packages`` plug-in hook."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import sys
import typing
from collections.abc import Sequence
from typing import Any, NoReturn, TypeVar

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


def positive_int(text: str) -> int:
    """argparse type: an int >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an int >= 1, got {value}")
    return value


GYM_PACKAGES_HELP = (
    "modules to import first (RL Zoo's flag): they register their own worlds (envs.register or pettingzoo.register), "
    "algorithms (sb3_eps.zoo.register_algorithm) and callbacks (sb3_eps.zoo.register_callback)"
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
