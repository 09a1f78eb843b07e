"""The env registry: env ids -> constructors, and gymnasium registration of the single-agent ids.

Multi-agent ids build PettingZoo ParallelEnvs (:func:`make_parallel_env`, or ``pettingzoo.make("parallel", env_id)``
once this package is imported), single-agent ids gymnasium envs (:func:`make_single_env`, or
``gymnasium.make(env_id)``). Constructors are imported
lazily, so importing ``envs`` neither loads PyBullet nor mpe2.

``Corridor-{n}-v0`` (n = 1 to 4, :data:`DEBUG_ENV_IDS`) are tiny multi-agent sanity worlds with a known optimum
(:mod:`envs.debug`); they are not tasks of the paper.

A user package adds its own worlds with :func:`register` (or, for a multi-agent world, PettingZoo's own
``pettingzoo.register("parallel", env_id, entry_point)``: such ids build through ``pettingzoo.make``); the command
lines import such packages with ``--gym-packages`` (``docs/usage.md``, "Plug-ins"). :data:`ENV_IDS` and the other id
tuples list the registered ids at the time they are read.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import pettingzoo
from pettingzoo import ParallelEnv


@dataclass(frozen=True)
class EnvSpec:
    """How one env id is built, and what the library needs to know of its world beyond the id.

    :param entry_point: ``"module:callable"`` of the constructor
    :param fixed_kwargs: constructor arguments that the id itself fixes (a caller may not change them)
    :param eps_world: for a multi-agent id, the single-agent id in which EPS evaluates the policies trained on it
        (``sb3_eps.eps.eps_env_id_for``); None: none
    :param eps_kwargs: for a single-agent id, the options it takes as EPS's evaluation world when the settings give
        none (``EPSSettings.eval_env_kwargs=None``)
    :param default_kwargs: constructor arguments that the id sets unless the caller gives others (PettingZoo's registry
        holds them as the id's kwargs, so records of the id's worlds name them)
    """

    entry_point: str | Callable[..., Any]
    fixed_kwargs: dict[str, Any] = field(default_factory=dict)
    eps_world: str | None = None
    eps_kwargs: dict[str, Any] = field(default_factory=dict)
    default_kwargs: dict[str, Any] = field(default_factory=dict)


_ROBOTS = "envs.turtlebot3:MultiRobotNavEnv"
_ROBOT_ALONE = "SingleRobotNav-v0"  # every TurtleBot3 team world's robot, evaluated alone by EPS
_MULTI_AGENT_SPECS: dict[str, EnvSpec] = {
    **{
        f"MultiRobotNav-{n}-v0": EnvSpec(_ROBOTS, {"n_robots": n, "scenario": "arena"}, _ROBOT_ALONE)
        for n in (2, 4, 8, 12, 24)
    },
    # Rooms generated from level seeds (envs/turtlebot3/rooms.py), one id per team size and level set: the plain id plays
    # the training levels unless env_kwargs {"level_set": ...} says otherwise, the -validation and -test ids fix their
    # set (an --eval-env of the command lines); docs/envs.md, "Generated rooms and their split".
    **{
        f"MultiRobotNavRooms-{n}{suffix}-v0": EnvSpec(
            _ROBOTS,
            {"n_robots": n, "scenario": "rooms", **({"level_set": level_set} if suffix else {})},
            _ROBOT_ALONE,
            default_kwargs={"level_set": level_set},
        )
        for n in (4, 8, 12, 24)
        for suffix, level_set in (("", "train"), ("-validation", "validation"), ("-test", "test"))
    },
    # The navigator's training worlds: the training rooms and, half the time, the open arena of the team size
    # (docs/results/navigator.md).
    **{
        f"MultiRobotNavMixed-{n}-v0": EnvSpec(
            _ROBOTS, {"n_robots": n, "scenario": "rooms", "level_set": "train", "arena_share": 0.5}, _ROBOT_ALONE
        )
        for n in (4, 8, 12, 24)
    },
    "MultiRobotNavUnseen-4-v0": EnvSpec(_ROBOTS, {"n_robots": 4, "scenario": "unseen"}, _ROBOT_ALONE),
    # The same room, every start and target moved by a seeded offset of up to 0.3 m: 100 episodes, 100 problems.
    "MultiRobotNavUnseen-4-varied-v0": EnvSpec(
        _ROBOTS, {"n_robots": 4, "scenario": "unseen", "placement_jitter": 0.3}, _ROBOT_ALONE
    ),
    # A training world for rooms never seen in training: 12 robots among blocks drawn anew every episode, in the
    # 12-robot arena (6 m, the unseen room's size); docs/results/many_robots.md, "A crowd among random blocks".
    "MultiRobotNavBlocks-12-v0": EnvSpec(_ROBOTS, {"n_robots": 12, "scenario": "blocks"}, _ROBOT_ALONE),
    "CooperativeNavigation-v0": EnvSpec(
        "envs.mpe.cooperative_navigation:CooperativeNavigationEnv", eps_world="CooperativeNavigationSingle-v0"
    ),
}

_DEBUG_SPECS: dict[str, EnvSpec] = {
    f"Corridor-{n}-v0": EnvSpec("envs.debug:CorridorEnv", {"n_agents": n}) for n in (1, 2, 3, 4)
}

_SINGLE_AGENT_SPECS: dict[str, EnvSpec] = {
    # As EPS's world by default: the training arena's 4 m room with three robot-sized pillars instead of the thin bars
    # the training worlds never show, 400 ticks (docs/results/eps_probes.md).
    "SingleRobotNav-v0": EnvSpec(
        "envs.turtlebot3:SingleRobotNavEnv", eps_kwargs={"scenario": "eps_pillars", "max_episode_steps": 400}
    ),
    "CooperativeNavigationSingle-v0": EnvSpec("envs.mpe.cooperative_navigation_single:CooperativeNavigationSingleEnv"),
}

DEBUG_ENV_IDS: tuple[str, ...] = tuple(_DEBUG_SPECS)
# Every id that builds a PettingZoo ParallelEnv.
_PARALLEL_SPECS = {**_MULTI_AGENT_SPECS, **_DEBUG_SPECS}


def __getattr__(name: str) -> tuple[str, ...]:
    """``MULTI_AGENT_ENV_IDS``, ``SINGLE_AGENT_ENV_IDS`` and ``ENV_IDS``, read when asked (plug-ins add ids)."""
    ids = {
        "MULTI_AGENT_ENV_IDS": tuple(_MULTI_AGENT_SPECS),
        "SINGLE_AGENT_ENV_IDS": tuple(_SINGLE_AGENT_SPECS),
    }
    if name in ids:
        return ids[name]
    if name == "ENV_IDS":
        return tuple(_MULTI_AGENT_SPECS) + tuple(_SINGLE_AGENT_SPECS) + DEBUG_ENV_IDS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register(
    env_id: str,
    entry_point: str | Callable[..., Any],
    *,
    multi_agent: bool = True,
    fixed_kwargs: dict[str, Any] | None = None,
    eps_world: str | None = None,
    eps_kwargs: dict[str, Any] | None = None,
) -> None:
    """Register a world of one's own under an env id, for ``make_vec_env``, the configs and the command lines.

    A multi-agent id also enters PettingZoo's registry (``pettingzoo.make("parallel", env_id)``), a single-agent id
    gymnasium's (``gymnasium.make(env_id)``).

    :param env_id: the new id (``Name-v0``); registering an id again with the same spec is allowed
    :param entry_point: ``"module:callable"`` or the callable that builds the env (a PettingZoo ParallelEnv when
        ``multi_agent``, else a gymnasium env)
    :param multi_agent: whether the id builds a PettingZoo ParallelEnv
    :param fixed_kwargs: constructor arguments the id fixes
    :param eps_world: a multi-agent id's single-agent world for EPS (:class:`EnvSpec`)
    :param eps_kwargs: a single-agent id's options as EPS's world (:class:`EnvSpec`)
    :raises ValueError: when the id is taken by another world
    """
    spec = EnvSpec(entry_point, dict(fixed_kwargs or {}), eps_world, dict(eps_kwargs or {}))
    table = _MULTI_AGENT_SPECS if multi_agent else _SINGLE_AGENT_SPECS
    known = _PARALLEL_SPECS.get(env_id) or _SINGLE_AGENT_SPECS.get(env_id)
    if known is not None and (known != spec or env_id not in table):
        raise ValueError(f"env id {env_id!r} is registered already (as {known.entry_point!r}); pick another id")
    table[env_id] = spec
    if multi_agent:
        _PARALLEL_SPECS[env_id] = spec
    _register_with_gymnasium()
    _register_with_pettingzoo()


def is_registered(env_id: str) -> bool:
    """Whether ``env_id`` builds a world here: one of ours, one added with :func:`register`, or a PettingZoo
    ``"parallel"`` id of ``pettingzoo.register``."""
    try:
        _spec(env_id)
    except ValueError:
        return False
    return True


def spec(env_id: str) -> EnvSpec:
    """:return: the registration of ``env_id`` (an id of ``pettingzoo.register`` alone has an empty one).

    :raises ValueError: when the id is unknown
    """
    return _spec(env_id)


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
            f"gymnasium.make({env_id!r}); make_parallel_env takes {list(_PARALLEL_SPECS)}"
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
            f"make_single_env takes {list(_SINGLE_AGENT_SPECS)}"
        )
    return _build(env_id, kwargs)


def _spec(env_id: str) -> EnvSpec:
    spec = _PARALLEL_SPECS.get(env_id) or _SINGLE_AGENT_SPECS.get(env_id)
    if spec is None and env_id in pettingzoo.parallel_registry:  # registered with pettingzoo.register directly
        spec = EnvSpec(functools.partial(pettingzoo.make, "parallel", env_id))
        _PARALLEL_SPECS[env_id] = spec
    if spec is None:
        raise ValueError(
            f"unknown env id {env_id!r}; multi-agent ids: {list(_MULTI_AGENT_SPECS)}, "
            f"single-agent ids: {list(_SINGLE_AGENT_SPECS)}, debug ids: {list(DEBUG_ENV_IDS)}"
        )
    return spec


def _load(entry_point: str | Callable[..., Any]) -> Any:
    if callable(entry_point):
        return entry_point
    module_name, _, attr = entry_point.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def _build(env_id: str, kwargs: dict[str, Any]) -> Any:
    spec = _spec(env_id)
    for name, value in spec.fixed_kwargs.items():
        if name in kwargs and kwargs[name] != value:
            raise ValueError(f"{env_id!r} fixes {name}={value!r}; got {name}={kwargs[name]!r}. Pick another id instead")
    return _load(spec.entry_point)(**{**spec.default_kwargs, **kwargs, **spec.fixed_kwargs})


def _register_with_gymnasium() -> None:
    # Importing this package twice (e.g. importlib.reload) must not make gymnasium warn about overrides.
    for env_id, spec in _SINGLE_AGENT_SPECS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=spec.entry_point, kwargs=dict(spec.fixed_kwargs))


def _register_with_pettingzoo() -> None:
    # PettingZoo 1.27's registry (``pettingzoo.register``); it warns when an id is registered twice. The entry point
    # is make_parallel_env, so an id's fixed arguments hold there too.
    for env_id, spec in _PARALLEL_SPECS.items():
        if env_id not in pettingzoo.parallel_registry:
            entry_point = functools.partial(make_parallel_env, env_id)
            pettingzoo.register("parallel", env_id, entry_point=entry_point, kwargs=dict(spec.default_kwargs))


_register_with_gymnasium()
_register_with_pettingzoo()

__all__ = [
    "DEBUG_ENV_IDS",
    "ENV_IDS",
    "MULTI_AGENT_ENV_IDS",
    "SINGLE_AGENT_ENV_IDS",
    "EnvSpec",
    "is_multi_agent",
    "is_registered",
    "make_parallel_env",
    "make_single_env",
    "register",
    "spec",
]
