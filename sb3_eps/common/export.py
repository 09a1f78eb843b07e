"""Export the decentralised agent network as ONNX plus a JSON description, loadable without pickle.

A robot runs the policy from its own observation only (EPS paper Eq. 3): the ONNX graph maps a batch of
observations ``obs (batch, obs_dim)`` to Q-values ``q_values (batch, n_actions)``; the action is the arg max.

The JSON also names the world (``env_id``, ``env_kwargs``) and, for a world that describes itself (a TurtleBot3
world's ``deployment_description()``: lidar beams, how the observation is built, the action table, the decision
period), what a robot needs to run the policy: ``deployment``. ``sb3_eps/deploy/onnx_runner.py`` runs it without
torch. This module imports no world: the description is read from the env object.
"""

from __future__ import annotations

import importlib.util
import json
import os
import pathlib
import warnings
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from sb3_eps.common.vec_env import world_constructor
from sb3_eps.version import __version__

EXPORT_FORMAT = "sb3-eps-policy"
EXPORT_FORMAT_VERSION = 1


def export_policy(
    model: Any,
    path: str | os.PathLike[str],
    opset_version: int = 17,
    *,
    env: Any = None,
    env_id: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> tuple[str, str]:
    """Write ``<path>.onnx`` (the greedy agent Q-network) and ``<path>.json`` (observation/action layout, the world
    and what a robot needs to run it) of a trained model.

    :param model: the trained model
    :param path: ``<path>`` or ``<path>.onnx``
    :param opset_version: the ONNX opset
    :param env: the world the policy runs in, read for the JSON's ``deployment`` (a vec env of ``make_vec_env``, a
        PettingZoo or gymnasium env): its ``deployment_description()`` where it has one. None: the model's own
        training env (``model.get_env()``), else a world built from ``env_id`` and ``env_kwargs``
    :param env_id: the registered id of the world (None: the vec env's ``env_id``)
    :param env_kwargs: the world options beyond the id's (None: the vec env's, else the described world's)
    :return: the paths of the ``.onnx`` and the ``.json`` file
    :raises ValueError: when ``env_id`` or ``env_kwargs`` contradict the env, or the env's observations or actions
        are not the model's
    """
    policy = getattr(model, "policy", None)
    # The network the greedy actions come from: the weight average when the policy keeps one (weight_average_tau).
    greedy_net = getattr(policy, "greedy_net", None)
    q_net = greedy_net() if greedy_net is not None else getattr(policy, "q_net", None)
    if q_net is None:
        raise ValueError(f"{type(model).__name__} has no agent Q-network (policy.q_net) to export")
    if importlib.util.find_spec("onnx") is None:  # torch's exporter needs it; checked before any file is made
        raise ImportError("export_policy needs the onnx package: pip install 'sb3-eps[export]'")
    observation_space, action_space = model.observation_space, model.action_space
    obs_dim = int(np.prod(observation_space.shape))
    world = _describe_world(model, env, env_id, env_kwargs)
    deployment = world["deployment"]
    if deployment is not None:
        # A world's own description need not say both; where it does, they must be the model's.
        described = ((deployment.get("observation") or {}).get("size"), (deployment.get("actions") or {}).get("n_actions"))
        if None not in described and described != (obs_dim, int(action_space.n)):
            raise ValueError(
                f"the env's observations have {described[0]} floats and {described[1]} actions, the model's "
                f"{obs_dim} and {int(action_space.n)}: pass the env (env_id, env_kwargs) the model was trained with"
            )
    safety_margin = getattr(policy, "safety_margin", None)
    if safety_margin is not None and (deployment is None or deployment.get("kind") != "turtlebot3"):
        raise ValueError("the policy has a lidar safety mask (safety_margin): export it with env= its TurtleBot3 world")
    base = pathlib.Path(path)
    if base.suffix == ".onnx":
        base = base.with_suffix("")
    base.parent.mkdir(parents=True, exist_ok=True)
    onnx_path, json_path = base.with_suffix(".onnx"), base.with_suffix(".json")
    dummy = th.zeros(1, obs_dim, dtype=th.float32, device=model.device)
    was_training = q_net.training
    q_net.set_training_mode(False)
    with warnings.catch_warnings():
        # The TorchScript exporter needs no extra package (the dynamo one needs onnxscript).
        warnings.simplefilter("ignore", DeprecationWarning)
        th.onnx.export(
            q_net,
            (dummy,),
            str(onnx_path),
            dynamo=False,
            input_names=["obs"],
            output_names=["q_values"],
            dynamic_axes={"obs": {0: "batch"}, "q_values": {0: "batch"}},
            opset_version=opset_version,
        )
    q_net.set_training_mode(was_training)
    description = {
        "format": EXPORT_FORMAT,
        "format_version": EXPORT_FORMAT_VERSION,
        "sb3_eps_version": __version__,
        "algorithm": type(model).__name__,
        "onnx_file": onnx_path.name,
        "input": {"name": "obs", "shape": ["batch", obs_dim], "dtype": "float32"},
        "output": {"name": "q_values", "shape": ["batch", int(action_space.n)], "dtype": "float32"},
        "action_selection": "argmax over q_values (decentralised: each agent from its own observation)"
        + ("; the policy's lidar mask first keeps the safe actions (safety_margin)" if safety_margin is not None else ""),
        # The policy's lidar action mask [m] (sb3_eps.common.safety): the runner's act applies it; None: no mask.
        "safety_margin": safety_margin,
        # Which weights: the online network's, or their moving average when the policy keeps one.
        "network": "q_net_average" if getattr(policy, "q_net_average", None) is not None else "q_net",
        "weight_average_tau": getattr(policy, "weight_average_tau", None),
        "observation_space": {
            "low": np.asarray(observation_space.low, dtype=float).reshape(-1).tolist(),
            "high": np.asarray(observation_space.high, dtype=float).reshape(-1).tolist(),
        },
        "n_actions": int(action_space.n),
        "n_agents_trained": int(getattr(model, "n_agents", 0)),
        "obs_dim": obs_dim,
        "env_id": world["env_id"],
        "env_kwargs": world["env_kwargs"],
        # What a robot needs to build an observation and drive (None: the world does not describe itself).
        "deployment": deployment,
    }
    json_path.write_text(json.dumps(description, indent=2))
    return str(onnx_path), str(json_path)


def _describe_world(model: Any, env: Any, env_id: str | None, env_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """The JSON's ``env_id``, ``env_kwargs`` and ``deployment`` (:func:`export_policy`)."""
    if env_id is not None and not isinstance(env_id, str):
        raise ValueError(f"env_id must be a registered env id (a str) or None, got {env_id!r}")
    if env_kwargs is not None and not isinstance(env_kwargs, dict):
        raise ValueError(f"env_kwargs must be a dict of world options or None, got {env_kwargs!r}")
    source = env
    if source is None:
        get_env = getattr(model, "get_env", None)
        source = get_env() if callable(get_env) else None
    built = None
    if source is None and env_id is not None:
        # No env at hand: one world of the id (registered by its package, as make_vec_env finds it), read and closed.
        constructor, registered, _ = world_constructor(env_id)
        source = built = constructor(**{**registered, **(env_kwargs or {})})
    try:
        deployment = deployment_description(source) if source is not None else None
    finally:
        if built is not None:
            built.close()
    recorded_id = getattr(source, "env_id", None) if isinstance(source, VecEnv) else None
    if env_id is not None and isinstance(recorded_id, str) and recorded_id != env_id:
        raise ValueError(f"env_id {env_id!r} contradicts the env, built from {recorded_id!r}: pass env= the world to describe")
    env_id = env_id if env_id is not None else recorded_id if isinstance(recorded_id, str) else None
    world_kwargs = deployment.get("world_kwargs", {}) if deployment is not None else {}
    if env_kwargs is not None:
        clashes = [
            f"{key}={env_kwargs[key]!r}" for key in world_kwargs if key in env_kwargs and env_kwargs[key] != world_kwargs[key]
        ]
        if clashes:
            raise ValueError(f"env_kwargs {', '.join(clashes)} contradict the env, whose world has {world_kwargs}")
    else:
        recorded_kwargs = getattr(source, "env_kwargs", None) if isinstance(source, VecEnv) else None
        env_kwargs = recorded_kwargs if isinstance(recorded_kwargs, dict) else (world_kwargs or None)
    return {"env_id": env_id, "env_kwargs": _json_ready(env_kwargs, "env_kwargs"), "deployment": deployment}


def deployment_description(env: Any) -> dict[str, Any] | None:
    """The world's ``deployment_description()`` (checked JSON-ready), None for a world without one.

    A vec env is asked about its first world (through worker processes too: the name is looked up among the world's
    before it is called, as a missing method would stop a worker); any other env along its ``env`` wrappers."""
    if isinstance(env, VecEnv):
        if "deployment_description" not in env.env_method("__dir__", indices=[0])[0]:
            return None
        description = env.env_method("deployment_description", indices=[0])[0]
    else:
        for _ in range(16):
            describe = getattr(env, "deployment_description", None)
            if callable(describe):
                break
            inner = getattr(env, "env", None)
            if inner is None or inner is env:
                return None
            env = inner
        else:
            return None
        description = describe()
    if not isinstance(description, dict):
        raise ValueError(f"the env's deployment_description() returned {type(description).__name__}, not a dict")
    return _json_ready(description, "the env's deployment_description()")


def _json_ready(value: Any, what: str) -> Any:
    """``value`` as JSON types (NumPy numbers and arrays converted); :raises ValueError: for anything else."""

    def convert(item: Any) -> Any:
        if isinstance(item, (np.generic, np.ndarray)):
            return item.tolist()
        raise TypeError(f"{type(item).__name__} is not JSON")

    try:
        return json.loads(json.dumps(value, default=convert))
    except (TypeError, ValueError) as error:
        raise ValueError(f"{what} must hold JSON values (numbers, strings, lists, dicts): {error}") from error
