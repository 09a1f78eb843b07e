"""Export the decentralised agent network as ONNX plus a JSON description, loadable without pickle.

A robot runs the policy from its own observation only (EPS paper Eq. 3): the ONNX graph maps a batch of
observations ``obs (batch, obs_dim)`` to Q-values ``q_values (batch, n_actions)``; the action is the arg max.
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

from sb3_eps.version import __version__

EXPORT_FORMAT = "sb3-eps-policy"
EXPORT_FORMAT_VERSION = 1


def export_policy(model: Any, path: str | os.PathLike[str], opset_version: int = 17) -> tuple[str, str]:
    """Write ``<path>.onnx`` (the greedy agent Q-network) and ``<path>.json`` (observation/action layout) of a trained
    model; :return: their paths."""
    policy = getattr(model, "policy", None)
    # The network the greedy actions come from: the weight average when the policy keeps one (weight_average_tau).
    greedy_net = getattr(policy, "greedy_net", None)
    q_net = greedy_net() if greedy_net is not None else getattr(policy, "q_net", None)
    if q_net is None:
        raise ValueError(f"{type(model).__name__} has no agent Q-network (policy.q_net) to export")
    if importlib.util.find_spec("onnx") is None:  # torch's exporter needs it; checked before any file is made
        raise ImportError("export_policy needs the onnx package: pip install 'sb3-eps[export]'")
    base = pathlib.Path(path)
    if base.suffix == ".onnx":
        base = base.with_suffix("")
    base.parent.mkdir(parents=True, exist_ok=True)
    onnx_path, json_path = base.with_suffix(".onnx"), base.with_suffix(".json")
    observation_space, action_space = model.observation_space, model.action_space
    obs_dim = int(np.prod(observation_space.shape))
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
        "action_selection": "argmax over q_values (decentralised: each agent from its own observation)",
        # Which weights: the online network's, or their moving average when the policy keeps one.
        "network": "q_net_average" if getattr(policy, "q_net_average", None) is not None else "q_net",
        "weight_average_tau": getattr(policy, "weight_average_tau", None),
        "observation_space": {
            "low": np.asarray(observation_space.low, dtype=float).reshape(-1).tolist(),
            "high": np.asarray(observation_space.high, dtype=float).reshape(-1).tolist(),
        },
        "n_actions": int(action_space.n),
        "n_agents_trained": int(getattr(model, "n_agents", 0)),
    }
    json_path.write_text(json.dumps(description, indent=2))
    return str(onnx_path), str(json_path)
