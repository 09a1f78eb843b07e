"""Small typed math helpers shared by the algorithms; each cites the equation it implements."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th


def is_int(value: Any) -> bool:
    """Whether ``value`` is a Python or NumPy integer (a bool is not)."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def check_seed(seed: Any) -> int | None:
    """:return: ``seed`` as a Python int (or None); :raises ValueError: for anything but None or an int >= 0."""
    if seed is None:
        return None
    if not is_int(seed):
        raise ValueError(
            f"seed must be None or a non-negative int, got {seed!r} of type {type(seed).__name__}"
        )
    if seed < 0:
        raise ValueError(f"seed must be None or a non-negative int, got {seed}")
    return int(seed)


def describe_space(space: Any) -> str:
    """:return: a short one-line description of a gymnasium space (``Box(30,)``, ``Discrete(20)``)."""
    if hasattr(space, "n"):
        return f"{type(space).__name__}({int(space.n)})"
    return f"{type(space).__name__}{tuple(getattr(space, 'shape', ()) or ())}"


def dueling_aggregation(values: th.Tensor, advantages: th.Tensor) -> th.Tensor:
    """Dueling aggregation, EPS paper Eq. 2: ``Q(s, a) = V(s) + A(s, a) - mean_a' A(s, a')``, with ``values``
    ``(..., 1)`` and ``advantages`` ``(..., n_actions)``."""
    # The check is skipped while tracing (ONNX export), where shapes are symbolic.
    if not th.jit.is_tracing() and (values.shape[-1] != 1 or values.shape[:-1] != advantages.shape[:-1]):
        raise ValueError(
            f"values {tuple(values.shape)} must be (..., 1) over advantages {tuple(advantages.shape)}"
        )
    return values + advantages - advantages.mean(dim=-1, keepdim=True)


def td_target(
    rewards: th.Tensor, discounts: th.Tensor, dones: th.Tensor, next_values: th.Tensor
) -> th.Tensor:
    """n-step TD target ``y = G + gamma^k * (1 - done) * next_value`` (Sutton & Barto 7.1): ``rewards`` the n-step
    returns ``G``, ``discounts`` ``gamma ** k``, ``dones`` 1 where the episode terminated inside the window."""
    if not (rewards.shape == discounts.shape == dones.shape == next_values.shape):
        raise ValueError(
            "td_target needs equal shapes, got "
            f"{tuple(rewards.shape)}, {tuple(discounts.shape)}, {tuple(dones.shape)}, {tuple(next_values.shape)}"
        )
    return rewards + discounts * (1.0 - dones) * next_values


def polyak_update_tensors_(
    target_params: list[th.Tensor],
    params: list[th.Tensor],
    target_buffers: list[th.Tensor],
    buffers: list[th.Tensor],
    tau: float,
) -> None:
    """In place ``target = tau * source + (1 - tau) * target`` on parameter lists gathered once (module traversal
    costs more than the update for small networks); buffers are copied."""
    with th.no_grad():
        if target_params:  # a parameter-free module (VDN's sum mixer) has nothing to move
            # One fused call: target + tau * (source - target).
            th._foreach_lerp_(target_params, params, tau)
        for target_buffer, buffer in zip(target_buffers, buffers, strict=True):
            target_buffer.copy_(buffer)


def epsilon_greedy(
    greedy_actions: np.ndarray, epsilon: float, n_actions: int, rng: np.random.Generator | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-agent epsilon-greedy: one independent coin per entry of ``greedy_actions`` (SB3's DQN draws one for the
    batch). ``rng`` None: numpy's global generator, which SB3 seeds. :return: ``(actions, explore_flags)``"""
    draw_uniform = np.random.random if rng is None else rng.random
    draw_integers = np.random.randint if rng is None else rng.integers
    explore = draw_uniform(greedy_actions.shape[0]) < epsilon
    random_actions = draw_integers(0, n_actions, size=greedy_actions.shape[0])
    return np.where(explore, random_actions, greedy_actions), explore


def input_gain(head: Callable[..., th.Tensor], inputs: th.Tensor, *args: Any) -> th.Tensor:
    """``d head(inputs, *args).sum() / d inputs`` without touching any gradient of the head's parameters: the
    gain of a joint head (GDQ's ``V_G``, QMIX's mixer) with respect to each agent's value, per row."""
    probe = inputs.detach().clone().requires_grad_(True)
    with th.enable_grad():
        return th.autograd.grad(head(probe, *args).sum(), probe)[0]
