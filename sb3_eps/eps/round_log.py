"""The per-round records of EPS: :class:`RoundRecords` (the history, its counters and the logger's ``eps/`` keys)
and :class:`RoundLog`, the records as JSON lines (``eps_rounds.jsonl``: line ``i`` is ``history[i]``, a resumed run
drops the lines written after its checkpoint; non-finite floats become ``null``).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.logger import Logger

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
            self.path.parent.mkdir(parents=True, exist_ok=True)
            lines = self.path.read_text().splitlines(keepends=True) if self.path.exists() else []
            if len(lines) != n_before:
                self.path.write_text("".join(lines[:n_before]))
            self._synced = True
        with self.path.open("a") as stream:
            stream.write(json.dumps(json_safe(record), allow_nan=False) + "\n")


def read_round_log(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """:return: the records of an ``eps_rounds.jsonl`` file."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def round_counts(records: list[dict[str, Any]]) -> dict[str, int]:
    """What a run's EPS did, from its round records (:func:`read_round_log`, or a callback's ``history``).

    :return: ``rounds`` (played), ``crossovers`` (played rounds whose winner was crossed over into the model) and
        ``skipped`` (rounds whose evaluation failed)
    """
    played = [record for record in records if not record.get("skipped")]
    return {
        "rounds": len(played),
        "crossovers": sum(bool(record.get("accepted")) for record in played),
        "skipped": len(records) - len(played),
    }


class RoundRecords:
    """The record of every round (``history``), their counters, the :class:`RoundLog` file and the ``eps/`` keys of
    SB3's logger.

    :param verbose: 1: one line per round on stdout
    """

    def __init__(self, verbose: int = 0) -> None:
        self.verbose = verbose
        self.history: list[dict[str, Any]] = []
        """One record per round (see docs/modules/eps.md, "The round record"); also in the :class:`RoundLog`."""
        self.n_rounds = 0
        self.n_skipped_rounds = 0
        self.eps_time = 0.0
        """Wall-clock seconds of the rounds."""
        self.file: RoundLog | None = None

    @property
    def n_crossovers(self) -> int:
        """Rounds whose winner was crossed over into the model (of the ``n_rounds`` played)."""
        return round_counts(self.history)["crossovers"]

    def open(self, path: str | None, logger: Logger | None) -> None:
        """Write to ``path``; None: ``eps_rounds.jsonl`` in the logger's folder when it has one; ``""``: no file."""
        folder = logger.get_dir() if logger is not None else None
        if path is None and folder:
            path = os.path.join(folder, DIAGNOSTICS_NAME)
        self.file = RoundLog(path) if path else None

    def played(self, record: dict[str, Any], wall_time: float, ticks_spent: int, counters: dict[str, Any]) -> dict[str, Any]:
        """Add a played round.

        :param record: what the round measured
        :param ticks_spent: the EPS ticks the round played
        :param counters: ``model_ticks`` and ``eps_ticks``
        :return: the full record
        """
        self.n_rounds += 1
        self.eps_time += wall_time
        record = {"round": self.n_rounds, **_counted(counters, ticks_spent), **record}
        # The run's crossovers so far, this round's included: the last record of a log says how many rounds of the
        # run crossed over.
        record.update(wall_time=wall_time, skipped=False, crossovers=self.n_crossovers + bool(record.get("accepted")))
        self._write(record)
        return record

    def skipped(self, reason: str, wall_time: float, ticks_spent: int, counters: dict[str, Any]) -> None:
        """Add a round whose evaluation failed."""
        self.n_skipped_rounds += 1
        self.eps_time += wall_time
        self._write({"round": None, **_counted(counters, ticks_spent), "skipped": True, "reason": reason})

    def _write(self, record: dict[str, Any]) -> None:
        if self.file is not None:
            self.file.append(record, n_before=len(self.history))
        self.history.append(record)

    def log(self, logger: Logger, record: dict[str, Any], totals: dict[str, Any]) -> None:
        """Record a played round under ``eps/`` (and print it when ``verbose``).

        :param totals: ``model_ticks``, ``eps_ticks`` (all rounds) and ``time_share``
        """
        fitness = np.asarray(record["fitness"], dtype=float)
        finite = fitness[np.isfinite(fitness)]
        successes = np.asarray(record["successes"], dtype=float).mean(axis=1)
        winner, eps_ticks, model_ticks = record["winner"], totals["eps_ticks"], totals["model_ticks"]
        logger.record("eps/round", self.n_rounds)
        logger.record("eps/ticks", eps_ticks)
        logger.record("eps/total_ticks", model_ticks + eps_ticks)
        logger.record("eps/round_ticks", record["ticks_spent"])
        logger.record("eps/tick_share", eps_ticks / max(model_ticks, 1))
        for index, value in enumerate(fitness):
            logger.record(f"eps/fitness_{index}", float(value))
        logger.record("eps/fitness_mean", float(finite.mean()) if finite.size else float("-inf"))
        logger.record("eps/fitness_max", float(fitness.max()))
        logger.record("eps/fitness_min", float(fitness.min()))
        logger.record("eps/success_0", float(successes[0]))
        logger.record("eps/success_max", float(successes.max()))
        logger.record("eps/n_invalid", int((~np.isfinite(fitness)).sum()))
        logger.record("eps/winner", winner)
        logger.record("eps/fitness_gain", record["gain"])
        logger.record("eps/runner_up_margin", record["runner_up_margin"])
        logger.record("eps/reevaluation_gain", record.get("reevaluation_gain", float("nan")))
        logger.record("eps/accepted", int(record["accepted"]))
        logger.record("eps/crossovers", self.n_crossovers)
        logger.record("eps/alpha", record["alpha"])
        logger.record("eps/mutation_scale", record["scale"])
        logger.record("eps/flip_share", float(np.mean(record["flip_share"])))
        logger.record("eps/mean_abs_dq", float(np.mean(record["mean_abs_dq"])))
        logger.record("eps/mean_abs_q", record["mean_abs_q"])
        logger.record("eps/mean_abs_delta", record["mean_abs_delta"])
        logger.record("eps/round_time", record["wall_time"])
        logger.record("eps/time_share", totals["time_share"])
        logger.record("eps/skipped_rounds", self.n_skipped_rounds)
        if self.verbose >= 1:
            verdict = "crossed over" if record["mean_abs_delta"] > 0 else "kept"
            print(
                f"EPS round {self.n_rounds}: copy 0 {fitness[0]:.3f} ({100 * successes[0]:.0f} % reached), best "
                f"{fitness[winner]:.3f} (individual {winner}), {verdict} (alpha {record['alpha']:.3f}); scale "
                f"{record['scale']:.2e} flipped {100 * np.mean(record['flip_share']):.0f} % of greedy actions; "
                f"{self.n_crossovers} of {self.n_rounds} rounds crossed over; "
                f"{record['ticks_spent']} ticks, {record['wall_time']:.2f} s; {eps_ticks} EPS ticks "
                f"({100 * eps_ticks / max(model_ticks, 1):.1f} % of training)"
            )


def _counted(counters: dict[str, Any], ticks_spent: int) -> dict[str, Any]:
    return {
        "model_ticks": counters["model_ticks"],
        "eps_ticks": counters["eps_ticks"],
        "ticks_spent": ticks_spent,
    }
