"""The per-round record of EPS as JSON lines (one object per round, ``eps_rounds.jsonl`` in the run folder).

The file mirrors ``EvolutionCallback.history``: record ``i`` of the file is ``history[i]``. A run that resumes from a
checkpoint keeps the records of the rounds its checkpoint holds and drops those written after it, so the file never
shows a round twice. Values are plain JSON: numpy arrays become lists, non-finite floats (the ``-inf`` fitness of a
disqualified individual) become ``null``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

DIAGNOSTICS_NAME = "eps_rounds.jsonl"


def json_safe(value: Any) -> Any:
    """:return: ``value`` with numpy types turned into Python ones and non-finite floats into None."""
    if isinstance(value, dict):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(item) for item in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating | float):
        number = float(value)
        return number if math.isfinite(number) else None
    return value


class RoundLog:
    """Appends one JSON object per EPS round to a file, keeping it in step with the callback's history.

    :param path: the ``.jsonl`` file (its folder is created)
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._synced = False

    def append(self, record: dict[str, Any], n_before: int) -> None:
        """Write one round.

        :param record: the round's record
        :param n_before: how many records precede it (``len(history)`` before it); on the first write of a
            ``learn()`` the file is cut to that many lines, so a fresh run starts an empty file and a resumed one
            continues its own
        """
        if not self._synced:
            self._keep_first(n_before)
            self._synced = True
        with self.path.open("a") as stream:
            stream.write(json.dumps(json_safe(record), allow_nan=False) + "\n")

    def _keep_first(self, n_records: int) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        lines = self.path.read_text().splitlines(keepends=True) if self.path.exists() else []
        if len(lines) != n_records:
            self.path.write_text("".join(lines[:n_records]))


def read_round_log(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """:return: the records of an ``eps_rounds.jsonl`` file."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def team_check_changes(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The paired greedy team checks of the rounds that crossed over (``n_team_check_episodes > 0``).

    Each check plays the same episodes (one seed) before and after the crossover, so the change is the crossover's
    effect on the multi-robot policy, apart from the ticks EPS takes from training.

    :param records: the records of an ``eps_rounds.jsonl`` file (or ``EvolutionCallback.history``)
    :return: one dict per checked crossover: ``round``, ``model_ticks``, ``alpha``, ``gain``, the success and the team
        return before and after, and their changes ``success_change`` and ``return_change``
    """
    changes = []
    for record in records:
        if record.get("skipped") or "team_success_after" not in record:
            continue
        before, after = record["team_success_before"], record["team_success_after"]
        changes.append(
            {
                "round": record["round"],
                "model_ticks": record["model_ticks"],
                "alpha": record["alpha"],
                "gain": record["gain"],
                "success_before": before,
                "success_after": after,
                "success_change": after - before,
                "return_change": record["team_return_after"] - record["team_return_before"],
            }
        )
    return changes
