"""Shared pieces of the command lines: an argparse parser whose errors are one-line :class:`ConfigError` s."""

from __future__ import annotations

import argparse
from typing import NoReturn

from sb3_eps.zoo.errors import ConfigError


class OneLineArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` that raises :class:`ConfigError` instead of printing usage and exiting, so
    every command-line mistake is one line on stderr with exit status 2 (see :func:`~sb3_eps.zoo.errors.run_command`).
    """

    def error(self, message: str) -> NoReturn:
        raise ConfigError(f"{message} (see --help)")


def positive_int(text: str) -> int:
    """argparse type: an int >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an int >= 1, got {value}")
    return value
