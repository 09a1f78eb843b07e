"""Team-level evaluation: episodes are counted per world (team), never per agent."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any, cast

import numpy as np

from sb3_eps.common.vec_env import MultiAgentVecEnv, make_vec_env

# Episode keys averaged into the summary when the env reports them (Cooperative Navigation's at the final tick:
# landmarks occupied, distance sum, collisions per tick without the spawn overlaps; docs/envs_mpe.md).
_OPTIONAL_KEYS = (
    "success",
    "collision",
    "collision_after_spawn",
    "collisions_per_tick",
    "n_arrived",
    "distance_travelled",
    "min_dist_sum",
    "occupied_landmarks",
)
#: Episode keys that are true or false: their summary is a share of episodes, ``<key>_rate``.
RATE_KEYS = ("success", "collision", "collision_after_spawn")


def summary_key(stem: str) -> str:
    """:return: the summary's name of an episode key's mean: ``<stem>_rate`` for :data:`RATE_KEYS`, else
    ``<stem>_mean`` (its spread is ``<stem>_std``)."""
    return f"{stem}_rate" if stem in RATE_KEYS else f"{stem}_mean"


def evaluate_team(
    model: Any,
    env: str | MultiAgentVecEnv,
    n_eval_episodes: int = 100,
    n_envs: int = 4,
    deterministic: bool = True,
    seed: int | None = 0,
    env_kwargs: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run the model's decentralised policy for ``n_eval_episodes`` world episodes, a fixed quota per world (so
    short episodes are not over-represented).

    :param model: anything with ``predict(obs, deterministic=...)`` over a batch of agent observations
    :param env: an env id (``n_envs`` worlds built with ``env_kwargs``, closed at the end) or a vec env
    :param seed: seed of the evaluation worlds (world ``w`` gets ``seed + w``)
    :return: the episode dicts and their summary (:func:`summarize_episodes`), with the world they were played in
        (:func:`world_record`) when it is known: an env id, or a vec env made by :func:`~sb3_eps.make_vec_env`
    """
    if n_eval_episodes < 1:
        raise ValueError(f"n_eval_episodes must be >= 1, got {n_eval_episodes}")
    episodes: list[dict[str, Any]] = []
    with _playing_in(env, n_envs, seed, env_kwargs) as venv:
        n_worlds, n_agents = venv.n_worlds, venv.n_agents
        quotas = [n_eval_episodes // n_worlds + (w < n_eval_episodes % n_worlds) for w in range(n_worlds)]
        counts = [0] * n_worlds
        observations = venv.reset()
        while sum(counts) < n_eval_episodes:
            actions, _ = model.predict(observations, deterministic=deterministic)
            next_observations, _, _, infos = venv.step(actions)
            observations = cast(np.ndarray, next_observations)  # a MultiAgentVecEnv's are arrays
            for world in range(n_worlds):
                episode = infos[world * n_agents].get("episode")
                if episode is not None and counts[world] < quotas[world]:
                    counts[world] += 1
                    episodes.append(dict(episode))
        played_in = vec_env_world(venv, len(episodes))
    return summarize_episodes(episodes) | (played_in or {})


#: What an evaluation record says of its world (:func:`world_record`).
WORLD_KEYS = ("env_id", "env_kwargs", "level_set", "n_episodes")


def world_record(env_id: str, env_kwargs: dict[str, Any] | None, n_episodes: int, level_set: Any = None) -> dict[str, Any]:
    """The world an evaluation was measured on, as every evaluation record stores it (:data:`WORLD_KEYS`).

    :param env_id: the registered env id
    :param env_kwargs: the world options the worlds were built with (None: none, recorded as ``{}``)
    :param n_episodes: world (team) episodes played
    :param level_set: the set of levels the worlds drew theirs from (None: the ``level_set`` option of
        ``env_kwargs``, None for a world without level sets)
    :return: ``{"env_id", "env_kwargs", "level_set", "n_episodes"}``
    """
    options = dict(env_kwargs or {})
    if level_set is None:
        level_set = options.get("level_set")
    return {"env_id": env_id, "env_kwargs": options, "level_set": level_set, "n_episodes": int(n_episodes)}


def vec_env_world(venv: MultiAgentVecEnv, n_episodes: int) -> dict[str, Any] | None:
    """:func:`world_record` of a vec env made by :func:`~sb3_eps.make_vec_env` from an env id (which keeps the id,
    the world options and the level set); None for other vec envs (a world without an id, options not known)."""
    env_id, env_kwargs = getattr(venv, "env_id", None), getattr(venv, "env_kwargs", None)
    if env_id is None or env_kwargs is None:
        return None
    return world_record(env_id, env_kwargs, n_episodes, venv.level_set)


def world_of(summary: dict[str, Any]) -> dict[str, Any]:
    """:return: the :data:`WORLD_KEYS` that an evaluation summary (:func:`evaluate_team`) has, for a record that
    keeps only some of its metrics."""
    return {key: summary[key] for key in WORLD_KEYS if key in summary}


@contextlib.contextmanager
def _playing_in(
    env: str | MultiAgentVecEnv, n_envs: int, seed: int | None, env_kwargs: dict[str, Any] | None
) -> Iterator[MultiAgentVecEnv]:
    """The vec env to play in: ``env`` reseeded, or ``n_envs`` worlds built from an id and closed at the end."""
    if isinstance(env, MultiAgentVecEnv):
        if seed is not None:
            env.seed(seed)
        yield env
        return
    venv = make_vec_env(env, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)
    try:
        yield venv
    finally:
        venv.close()


def summarize_episodes(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean and std of the team metrics over episode dicts (``r`` team return, ``l`` length in ticks)."""
    returns = np.array([episode["r"] for episode in episodes], dtype=float)
    lengths = np.array([episode["l"] for episode in episodes], dtype=float)
    summary: dict[str, Any] = {
        "n_episodes": len(episodes),
        "team_return_mean": float(returns.mean()),
        "team_return_std": float(returns.std()),
        "length_mean": float(lengths.mean()),
        "length_std": float(lengths.std()),
        "episodes": episodes,
    }
    for key in _OPTIONAL_KEYS:
        if episodes and key in episodes[0]:
            values = np.array([float(episode[key]) for episode in episodes])
            summary[summary_key(key)] = float(values.mean())
            summary[f"{key}_std"] = float(values.std())
    return summary


def record_frames(
    model: Any,
    env: str | MultiAgentVecEnv,
    n_episodes: int = 1,
    seed: int | None = 0,
    env_kwargs: dict[str, Any] | None = None,
    max_frames: int = 3_000,
    frame_every: int = 1,
) -> tuple[list[np.ndarray], list[dict[str, Any]]]:
    """Play greedy episodes in one world and keep one picture every ``frame_every`` ticks, at most ``max_frames``.

    :param env: an env id (one world drawn as ``rgb_array``, closed at the end) or a one-world vec env
    :return: the pictures (an episode's last is the one before its final tick) and the finished episodes' dicts
    """
    if frame_every < 1:
        raise ValueError(f"frame_every must be >= 1, got {frame_every}")
    frames: list[np.ndarray] = []
    episodes: list[dict[str, Any]] = []
    with _playing_in(env, 1, seed, {**(env_kwargs or {}), "render_mode": "rgb_array"}) as venv:
        observations: Any = venv.reset()
        tick = 0
        while len(episodes) < n_episodes and len(frames) < max_frames:
            picture = venv.get_images()[0]
            if picture is not None and tick % frame_every == 0:
                frames.append(picture)
            actions, _ = model.predict(observations, deterministic=True)
            next_observations, _, _, infos = venv.step(actions)
            observations = cast(np.ndarray, next_observations)  # a MultiAgentVecEnv's are arrays
            tick += 1
            if "episode" in infos[0]:
                # The world has already been reset for the next episode: its picture starts that one.
                episodes.append(dict(infos[0]["episode"]))
                tick = 0
    return frames, episodes
