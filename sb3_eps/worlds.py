"""The library's one door to the project's worlds (``envs``): importing it registers their ids with PettingZoo and
gymnasium, and it reads what the library needs to know of a world from its registration (``envs.EnvSpec``), by env
id. No other module of ``sb3_eps`` imports ``envs`` (an import-linter contract in ``setup.cfg``); the rest reaches
worlds through registered ids (:func:`sb3_eps.common.vec_env.world_constructor`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv

import envs


def is_registered(env_id: str) -> bool:
    """Whether ``env_id`` builds a world: one of the project's, one of ``envs.register`` or of
    ``pettingzoo.register``."""
    return envs.is_registered(env_id)


def is_multi_agent(env_id: str) -> bool:
    """Whether ``env_id`` names a multi-agent (PettingZoo) world. :raises ValueError: for an unknown id."""
    return envs.is_multi_agent(env_id)


def env_ids() -> tuple[str, ...]:
    """Every registered id (multi-agent, single-agent, debug), read now: plug-ins add theirs."""
    return tuple(envs.ENV_IDS)


def multi_agent_ids() -> tuple[str, ...]:
    """The registered team worlds' ids (without the debug worlds)."""
    return tuple(envs.MULTI_AGENT_ENV_IDS)


def single_agent_ids() -> tuple[str, ...]:
    """The registered single-agent ids."""
    return tuple(envs.SINGLE_AGENT_ENV_IDS)


def eps_world(env_id: str) -> str | None:
    """:return: the single-agent id its registration names for EPS's evaluation of a multi-agent id, or None.

    :raises ValueError: for an unknown id
    """
    return envs.spec(env_id).eps_world


def eps_kwargs(env_id: str) -> dict[str, Any]:
    """:return: the options a registered single-agent id takes as EPS's evaluation world by default (``{}``: its own
    defaults, also for an id registered only with gymnasium)."""
    return dict(envs.spec(env_id).eps_kwargs) if envs.is_registered(env_id) else {}


def make_single_env(env_id: str, **kwargs: Any) -> gymnasium.Env:
    """Build the gymnasium env of a registered single-agent id (``envs.make_single_env``)."""
    return envs.make_single_env(env_id, **kwargs)


def make_parallel_env(env_id: str, **kwargs: Any) -> ParallelEnv:
    """Build the PettingZoo ParallelEnv of a registered multi-agent id (``envs.make_parallel_env``)."""
    return envs.make_parallel_env(env_id, **kwargs)


def save_gif(frames: list[np.ndarray], path: str | Path, fps: float = 20) -> Path:
    """Write ``rgb_array`` frames to an animated GIF that loops forever (the worlds' writer). :return: the path."""
    from envs.turtlebot3 import save_gif as write

    return write(frames, path, fps)


def display_available() -> bool:
    """Whether a window can be opened for ``render_mode="human"`` (PyBullet's GUI exits the process without one)."""
    from envs.turtlebot3.world import display_available as available

    return available()
