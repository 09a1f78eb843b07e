"""The env registry: env ids -> constructors, and gymnasium registration of the single-agent ids.

Multi-agent ids build PettingZoo ParallelEnvs (:func:`make_parallel_env`, or ``pettingzoo.make("parallel", env_id)``
once this package is imported), single-agent ids gymnasium envs (:func:`make_single_env`, or
``gymnasium.make(env_id)``). Constructors are imported
lazily, so importing ``envs`` neither loads PyBullet nor mpe2.

Each multi-agent id has a single-agent counterpart for Evolutionary Policy Search (:func:`eps_env_id_for`): the
robots' EPS world for every ``MultiRobotNav*`` id, and the single-agent Cooperative Navigation for the MPE id.

``Corridor-{n}-v0`` (n = 1 to 4, :data:`DEBUG_ENV_IDS`) are tiny multi-agent sanity worlds with a known optimum
(:mod:`envs.debug`); they are not tasks of the paper and have no EPS counterpart.
"""

from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import pettingzoo
from pettingzoo import ParallelEnv


@dataclass(frozen=True)
class EnvSpec:
    """How one env id is built.

    :param entry_point: ``"module:callable"`` of the constructor
    :param fixed_kwargs: constructor arguments that the id itself fixes (a caller may not change them)
    :param eps_env_id: the single-agent id EPS evaluates in
    """

    entry_point: str
    fixed_kwargs: dict[str, Any] = field(default_factory=dict)
    eps_env_id: str | None = None


_MULTI_AGENT_SPECS: dict[str, EnvSpec] = {
    **{
        f"MultiRobotNav-{n}-v0": EnvSpec(
            "envs.turtlebot3:MultiRobotNavEnv", {"n_robots": n, "scenario": "arena"}, "SingleRobotNav-v0"
        )
        for n in (2, 4, 8, 12)
    },
    "MultiRobotNavUnseen-4-v0": EnvSpec(
        "envs.turtlebot3:MultiRobotNavEnv", {"n_robots": 4, "scenario": "unseen"}, "SingleRobotNav-v0"
    ),
    "CooperativeNavigation-v0": EnvSpec(
        "envs.mpe.cooperative_navigation:CooperativeNavigationEnv", {}, "CooperativeNavigationSingle-v0"
    ),
}

_DEBUG_SPECS: dict[str, EnvSpec] = {
    f"Corridor-{n}-v0": EnvSpec("envs.debug:CorridorEnv", {"n_agents": n}) for n in (1, 2, 3, 4)
}

_SINGLE_AGENT_SPECS: dict[str, EnvSpec] = {
    "SingleRobotNav-v0": EnvSpec("envs.turtlebot3:SingleRobotNavEnv"),
    "CooperativeNavigationSingle-v0": EnvSpec(
        "envs.mpe.cooperative_navigation_single:CooperativeNavigationSingleEnv"
    ),
}

MULTI_AGENT_ENV_IDS: tuple[str, ...] = tuple(_MULTI_AGENT_SPECS)
SINGLE_AGENT_ENV_IDS: tuple[str, ...] = tuple(_SINGLE_AGENT_SPECS)
DEBUG_ENV_IDS: tuple[str, ...] = tuple(_DEBUG_SPECS)
ENV_IDS: tuple[str, ...] = MULTI_AGENT_ENV_IDS + SINGLE_AGENT_ENV_IDS + DEBUG_ENV_IDS
# Every id that builds a PettingZoo ParallelEnv.
_PARALLEL_SPECS = {**_MULTI_AGENT_SPECS, **_DEBUG_SPECS}


def is_multi_agent(env_id: str) -> bool:
    """Whether ``env_id`` names a multi-agent (PettingZoo) env.

    :param env_id: a registered env id
    :return: True for multi-agent ids, False for single-agent ids
    :raises ValueError: when the id is unknown
    """
    _spec(env_id)
    return env_id in _PARALLEL_SPECS


def make_parallel_env(env_id: str, **kwargs: Any) -> ParallelEnv:
    """Build the PettingZoo ParallelEnv registered under a multi-agent id.

    :param env_id: one of :data:`MULTI_AGENT_ENV_IDS` or :data:`DEBUG_ENV_IDS`
    :param kwargs: constructor arguments (the ones the id fixes, such as ``n_robots``, cannot be changed)
    :return: the env
    :raises ValueError: for an unknown id, a single-agent id or an argument that contradicts the id
    """
    if env_id in _SINGLE_AGENT_SPECS:
        raise ValueError(
            f"{env_id!r} is a single-agent env: build it with envs.make_single_env({env_id!r}) or "
            f"gymnasium.make({env_id!r}); make_parallel_env takes {list(MULTI_AGENT_ENV_IDS + DEBUG_ENV_IDS)}"
        )
    return _build(env_id, kwargs)


def make_single_env(env_id: str, **kwargs: Any) -> gymnasium.Env:
    """Build the gymnasium env registered under a single-agent id (without gymnasium.make's checker wrappers).

    :param env_id: one of :data:`SINGLE_AGENT_ENV_IDS`
    :param kwargs: constructor arguments
    :return: the env
    :raises ValueError: for an unknown id or a multi-agent id
    """
    if env_id in _PARALLEL_SPECS:
        raise ValueError(
            f"{env_id!r} is a multi-agent env: build it with envs.make_parallel_env({env_id!r}); "
            f"make_single_env takes {list(SINGLE_AGENT_ENV_IDS)}"
        )
    return _build(env_id, kwargs)


def eps_env_id_for(env_id: str) -> str:
    """The single-agent id in which EPS evaluates the policies trained on ``env_id``.

    :param env_id: a registered id; a single-agent id maps to itself
    :return: the single-agent counterpart
    :raises ValueError: when the id is unknown or a debug id (which has no counterpart)
    """
    spec = _spec(env_id)
    if env_id in _DEBUG_SPECS:
        raise ValueError(f"{env_id!r} is a debug world without a single-agent EPS counterpart")
    return spec.eps_env_id if spec.eps_env_id is not None else env_id


def _spec(env_id: str) -> EnvSpec:
    spec = _PARALLEL_SPECS.get(env_id) or _SINGLE_AGENT_SPECS.get(env_id)
    if spec is None:
        raise ValueError(
            f"unknown env id {env_id!r}; multi-agent ids: {list(MULTI_AGENT_ENV_IDS)}, "
            f"single-agent ids: {list(SINGLE_AGENT_ENV_IDS)}, debug ids: {list(DEBUG_ENV_IDS)}"
        )
    return spec


def _load(entry_point: str) -> Any:
    module_name, _, attr = entry_point.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def _build(env_id: str, kwargs: dict[str, Any]) -> Any:
    spec = _spec(env_id)
    for name, value in spec.fixed_kwargs.items():
        if name in kwargs and kwargs[name] != value:
            raise ValueError(
                f"{env_id!r} fixes {name}={value!r}; got {name}={kwargs[name]!r}. Pick another id instead"
            )
    return _load(spec.entry_point)(**{**kwargs, **spec.fixed_kwargs})


def _register_with_gymnasium() -> None:
    # Importing this package twice (e.g. importlib.reload) must not make gymnasium warn about overrides.
    for env_id, spec in _SINGLE_AGENT_SPECS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=spec.entry_point, kwargs=dict(spec.fixed_kwargs))


def _register_with_pettingzoo() -> None:
    # PettingZoo 1.27's registry (``pettingzoo.register``); it warns when an id is registered twice. The entry point
    # is make_parallel_env, so an id's fixed arguments hold there too.
    for env_id in _PARALLEL_SPECS:
        if env_id not in pettingzoo.parallel_registry:
            pettingzoo.register("parallel", env_id, entry_point=functools.partial(make_parallel_env, env_id))


_register_with_gymnasium()
_register_with_pettingzoo()

__all__ = [
    "DEBUG_ENV_IDS",
    "ENV_IDS",
    "MULTI_AGENT_ENV_IDS",
    "SINGLE_AGENT_ENV_IDS",
    "EnvSpec",
    "eps_env_id_for",
    "is_multi_agent",
    "make_parallel_env",
    "make_single_env",
]
