"""The one error type of the command lines: a user mistake, shown as one line with exit code 2."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable

#: Exit status of a command line given a bad flag or configuration (argparse's convention).
USAGE_EXIT_CODE = 2
#: Exit status when a run failed for a reason outside the user's input (a world's worker process died).
RUN_FAILED_EXIT_CODE = 1
#: Exit status after a second SIGINT / SIGTERM (no checkpoint): 128 + SIGINT, as a shell reports it.
INTERRUPTED_EXIT_CODE = 130


class ConfigError(ValueError):
    """A configuration or command-line mistake: the message names the key, where it came from and what is allowed.

    The command lines print it as one line (``<prog>: error: <message>``) and exit with status 2, without a
    traceback. Library callers get an ordinary ``ValueError``.
    """


class RunFailed(RuntimeError):
    """A run stopped by a failure that is not a mistake in its input (a worker process of its worlds died); the
    message says what remains (the last checkpoint) and how to continue. Shown as one line, exit status 1."""


def allowed(values: Iterable[object]) -> str:
    """:return: ``values`` as a short comma-separated list for an error message."""
    return ", ".join(str(value) for value in values)


def run_command(prog: str, main: Callable[[], int | None]) -> None:
    """Run a command line's ``main`` and exit; a :class:`ConfigError` becomes one line on stderr and status 2, a
    ``KeyboardInterrupt`` (a second signal during training) one line and status 130.

    :param prog: the command's name, e.g. ``"python -m sb3_eps.train"``
    :param main: the command; returns its exit status (None means 0)
    """
    try:
        status = main()
    except (ConfigError, RunFailed) as error:
        message = " ".join(str(error).split())  # one line, whatever the message holds
        print(f"{prog}: error: {message}", file=sys.stderr)
        sys.exit(USAGE_EXIT_CODE if isinstance(error, ConfigError) else RUN_FAILED_EXIT_CODE)
    except KeyboardInterrupt as interrupt:
        print(f"{prog}: stopped ({interrupt or 'KeyboardInterrupt'}), without a checkpoint", file=sys.stderr)
        sys.exit(INTERRUPTED_EXIT_CODE)
    sys.exit(status or 0)
