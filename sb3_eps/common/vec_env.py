"""``make_vec_env``: an env id (or a world constructor) -> the parameter-shared SB3 vector env.

Env ids are resolved through PettingZoo's registry (multi-agent worlds) and gymnasium's (one-agent worlds): the core
knows no world. This project's worlds register their ids when the package ``envs`` is imported; a plug-in registers
its own the same way (``docs/bring_your_own_world.md``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import gymnasium
import pettingzoo
from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from sb3_eps.common.multi_agent_vec_env import MultiAgentVecEnv
from sb3_eps.common.subproc_vec_env import SubprocMultiAgentVecEnv
from sb3_eps.common.utils import check_seed, is_int

__all__ = ["VEC_ENV_MODES", "MultiAgentVecEnv", "make_vec_env", "vec_env_mode", "world_constructor"]

#: Names of the two modes of :func:`make_vec_env` (configs' ``vec_env``, the command line's ``--vec-env``).
VEC_ENV_MODES = ("dummy", "subproc")


def vec_env_mode(vec_env_cls: type[VecEnv] | str | None) -> str:
    """:return: ``"dummy"`` or ``"subproc"`` for SB3's ``DummyVecEnv`` / ``SubprocVecEnv`` (or those names)."""
    if vec_env_cls is None:
        return "dummy"
    if isinstance(vec_env_cls, str):
        mode = vec_env_cls.lower()
        if mode in VEC_ENV_MODES:
            return mode
    elif isinstance(vec_env_cls, type):
        for mode, cls in zip(VEC_ENV_MODES, (DummyVecEnv, SubprocVecEnv)):
            if issubclass(vec_env_cls, cls):
                return mode
    raise ValueError(
        f"vec_env_cls must be DummyVecEnv (worlds in this process) or SubprocVecEnv (worlds in worker "
        f"processes), or their names 'dummy' / 'subproc'; got {vec_env_cls!r}"
    )


def make_vec_env(
    env_id: str | Callable[..., ParallelEnv | gymnasium.Env],
    n_envs: int = 1,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    vec_env_cls: type[VecEnv] | str | None = None,
    vec_env_kwargs: dict[str, Any] | None = None,
) -> MultiAgentVecEnv:
    """Build the parameter-shared SB3 vector env of a registered env id, or of your own world.

    :param env_id: a registered id (:func:`world_constructor`), or a callable that returns a new world (a PettingZoo
        ``ParallelEnv`` whose agents share their spaces, or a gymnasium env) from ``env_kwargs``
    :param n_envs: number of worlds (the VecEnv has ``n_envs * n_agents`` sub-envs)
    :param seed: seed of the first reset (world ``w`` gets ``seed + w``); None for random
    :param vec_env_cls: ``DummyVecEnv`` (None: every world in this process) or ``SubprocVecEnv`` (worlds in worker
        processes, :class:`~sb3_eps.common.subproc_vec_env.SubprocMultiAgentVecEnv`, whose arguments
        ``vec_env_kwargs`` are); also ``"dummy"`` / ``"subproc"``. Both give the same results for the same seed
    :return: the vec env; it keeps ``env_id`` (None for a callable), ``env_kwargs`` (as given) and ``level_set``
        (the worlds' ``level_set`` option, None without one), which evaluations record
    """
    if not isinstance(env_id, str) and not callable(env_id):
        raise ValueError(
            "env_id must be a registered id (envs.ENV_IDS lists this project's) or a callable returning a "
            f"PettingZoo ParallelEnv (or a gymnasium env); got {env_id!r}"
        )
    if not (is_int(n_envs) and n_envs >= 1):
        raise ValueError(f"n_envs (the number of worlds) must be an int >= 1, got {n_envs!r}")
    seed = check_seed(seed)
    mode = vec_env_mode(vec_env_cls)
    vec_kwargs = dict(vec_env_kwargs or {})
    allowed = {"n_workers", "start_method", "main_worlds", "spin_s"} if mode == "subproc" else set()
    if set(vec_kwargs) - allowed:
        raise ValueError(
            f"vec_env_kwargs {sorted(set(vec_kwargs) - allowed)} not understood with {mode!r}; "
            f"allowed: {sorted(allowed) or 'none'}"
        )
    kwargs = dict(env_kwargs or {})
    make_world: Callable[..., ParallelEnv | gymnasium.Env]
    if isinstance(env_id, str):
        make_world, registered_kwargs, _ = world_constructor(env_id)
        kwargs = {**registered_kwargs, **kwargs}
        recorded_id: str | None = env_id
    else:
        make_world, recorded_id = env_id, None

    def env_fn() -> ParallelEnv | gymnasium.Env:
        return make_world(**kwargs)

    venv: MultiAgentVecEnv
    if mode == "subproc":
        # Build one world here first, so a bad env_kwargs is a plain ValueError / TypeError, not a worker's.
        env_fn().close()
        venv = SubprocMultiAgentVecEnv([env_fn] * int(n_envs), env_id=recorded_id, **vec_kwargs)
    else:
        venv = MultiAgentVecEnv([env_fn] * int(n_envs), env_id=recorded_id)
    # The options the worlds were made with beyond their registration (EvolutionCallback's world takes the view
    # and the decision rate from them; records store them).
    venv.env_kwargs = dict(env_kwargs or {})
    venv.level_set = kwargs.get("level_set")  # the set of levels a generated world draws from, for the records
    if seed is not None:
        venv.seed(seed)
    return venv


def world_constructor(env_id: str) -> tuple[Callable[..., ParallelEnv | gymnasium.Env], dict[str, Any], bool]:
    """The constructor registered under ``env_id`` in PettingZoo's registry, else gymnasium's.

    :return: ``(constructor, its registered keyword arguments, whether it builds a multi-agent world)``
    """
    spec: Any = pettingzoo.parallel_registry.get(env_id)
    multi_agent = spec is not None
    if spec is None:
        spec = gymnasium.registry.get(env_id)
    if spec is None:
        ours = pettingzoo.parallel_registry  # PettingZoo's own worlds have namespaced ids ("atari/...")
        raise ValueError(
            f"unknown env id {env_id!r}; multi-agent ids: {[key for key in ours if '/' not in key]}. "
            "Register a world "
            "with pettingzoo.register('parallel', ...) or gymnasium.register(...) (this project's worlds are "
            "registered when the package envs is imported)"
        )
    entry_point = spec.entry_point
    if isinstance(entry_point, str):
        module_name, _, name = entry_point.partition(":")
        entry_point = getattr(importlib.import_module(module_name), name)
    return entry_point, dict(spec.kwargs or {}), multi_agent
