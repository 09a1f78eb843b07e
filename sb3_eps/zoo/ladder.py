"""The ``ladder`` key of a config entry: one run trained over a list of worlds (:mod:`sb3_eps.common.ladder`).

An entry's ``ladder`` lists the rungs in order, each ``{env: <env id>, ticks: <world ticks>}``; the last rung is the
entry's own world (``--env``), which names the run folder and is the evaluation world unless ``--eval-env`` says
otherwise. The run's total (``n_timesteps``, agent-steps) is the rungs' ticks times their robots, so ``-n`` is
refused beside a ladder. The command line's ``--ladder ENV:TICKS ...`` sets the key. A checkpoint records the rung
it was taken in and the ticks spent in it; ``--resume`` continues there.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from sb3_eps import worlds
from sb3_eps.common.ladder import Rung, check_ladder, ladder_timesteps, rung_at, rung_ends
from sb3_eps.common.vec_env import MultiAgentVecEnv
from sb3_eps.zoo.errors import ConfigError, allowed

LADDER_KEY = "ladder"
#: The training worlds of rung ``i`` are seeded ``seed + i * RUNG_SEED_OFFSET`` (below the evaluation worlds' offset).
RUNG_SEED_OFFSET = 1_000
_RUNG_KEYS = ("env", "ticks")


def normalize_ladder(value: Any, where: str) -> list[dict[str, Any]]:
    """Check an entry's ``ladder``: a non-empty list of ``{env: <registered id>, ticks: <int >= 1>}``.

    :return: the rungs as plain data, keys in order
    :raises ConfigError: naming the rung and what is wrong, in one line
    """
    if not isinstance(value, list) or not value:
        raise ConfigError(
            f"{where}: a list of rungs is needed, e.g. [{{env: MultiRobotNav-4-v0, ticks: 150000}}, "
            f"{{env: MultiRobotNav-8-v0, ticks: 150000}}], got {value!r}"
        )
    rungs = []
    for index, rung in enumerate(value):
        here = f"{where}: rung {index}"
        if not isinstance(rung, Mapping) or set(rung) != set(_RUNG_KEYS):
            raise ConfigError(f"{here}: a rung is a mapping with exactly the keys {allowed(_RUNG_KEYS)}, got {rung!r}")
        env_id, ticks = rung["env"], rung["ticks"]
        if not (isinstance(env_id, str) and worlds.is_registered(env_id)):
            raise ConfigError(
                f"{here}: unknown env id {env_id!r}; allowed: {allowed(worlds.env_ids())} (or an id that a "
                "--gym-packages module registers)"
            )
        if isinstance(ticks, bool) or not isinstance(ticks, int) or ticks < 1:
            raise ConfigError(f"{here}: ticks must be an int >= 1 (world ticks), got {ticks!r}")
        rungs.append({"env": env_id, "ticks": ticks})
    return rungs


def ladder_option(items: list[str]) -> str:
    """:return: the ``--hyperparams`` item of ``--ladder ENV:TICKS ...`` (``ladder:[{env: ..., ticks: ...}]``).

    :raises ConfigError: for an item that is not ``ENV:TICKS``
    """
    rungs = []
    for item in items:
        env_id, separator, ticks = item.rpartition(":")
        if not separator or not env_id or not ticks:
            raise ConfigError(f"--ladder: {item!r} is not ENV:TICKS (e.g. MultiRobotNav-4-v0:150000)")
        rungs.append(f"{{env: '{env_id}', ticks: {ticks}}}")
    return f"{LADDER_KEY}:[{', '.join(rungs)}]"


def check_ladder_run(entry: Mapping[str, Any], env_id: str, n_timesteps: int | None, algo: str, source: str) -> None:
    """The checks of a ladder run that need the command line: the last rung is ``--env``; no ``-n``; no EPS.

    :raises ConfigError: in one line
    """
    last = entry[LADDER_KEY][-1]["env"]
    if last != env_id:
        raise ConfigError(
            f"{source}: the ladder's last rung is {last}, the run's env {env_id}: a ladder run is named after its "
            f"last world; use --env {last}"
        )
    if n_timesteps is not None:
        raise ConfigError(f"-n: a ladder's total is its rungs' ticks ({source}); change those instead")
    if algo.startswith("eps_"):
        raise ConfigError(f"{source}: --algo {algo}: EPS runs on one world; train a ladder with {algo[4:]}")


def build_rungs(
    entry: Mapping[str, Any],
    first_env: MultiAgentVecEnv,
    seed: int,
    build_env: Callable[[str, int], MultiAgentVecEnv],
) -> list[Rung]:
    """:return: the rungs of an entry's ladder: ``first_env`` for the first, ``build_env(env id, seed)`` for the others
    (rung ``i`` seeded ``seed + i * RUNG_SEED_OFFSET``)."""
    rungs = [Rung(first_env, entry[LADDER_KEY][0]["ticks"])]
    for index, rung in enumerate(entry[LADDER_KEY][1:], start=1):
        rungs.append(Rung(build_env(rung["env"], seed + index * RUNG_SEED_OFFSET), rung["ticks"]))
    return rungs


def check_rungs(model: Any, rungs: list[Rung], source: str) -> int:
    """Check that ``model`` can train on every rung.

    :return: the ladder's total agent-steps (the run's ``n_timesteps``)
    :raises ConfigError: naming the rung, in one line
    """
    try:
        check_ladder(model, rungs)
    except ValueError as error:
        raise ConfigError(f"{source}: {error}") from None
    return ladder_timesteps(rungs)


def ladder_progress(rungs: list[Rung], ticks: int) -> dict[str, int]:
    """:return: the rung that ``ticks`` are in and the ticks spent in it (a checkpoint's ``meta.json`` records them)."""
    rung = min(rung_at(rungs, ticks), len(rungs) - 1)
    start = ([0, *rung_ends(rungs)])[rung]
    return {"rung": rung, "rung_ticks": ticks - start}
