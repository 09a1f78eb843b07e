"""Small typed helpers shared by the algorithms: the constructors' argument checks, and math that cites the equation
it implements."""

from __future__ import annotations

import collections.abc
import inspect
import math
import numbers
import os
import types
import typing
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th


def is_int(value: Any) -> bool:
    """Whether ``value`` is a Python or NumPy integer (a bool is not)."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def check_arguments(function: Callable[..., Any], values: dict[str, Any], ranges: dict[str, str]) -> None:
    """Check ``values`` against the type hints of ``function`` (a constructor or a dataclass) and the intervals of
    ``ranges`` (``"(0, 1]"``, ``"[1, inf)"``), one config schema derived from the signatures.

    :raises ValueError: one line naming the first argument that does not fit and what it may be
    """
    hints = inspect.get_annotations(function, eval_str=True)
    for name, value in values.items():
        hint, interval = hints.get(name, Any), ranges.get(name)
        in_range = interval is None or not _is_number(value) or _in_interval(float(value), interval)
        if not (_fits(value, hint) and in_range):
            raise ValueError(f"{name} must be {_describe(hint, interval)}, got {value!r}")


def base_arguments(base_init: Callable[..., Any], values: dict[str, Any]) -> dict[str, Any]:
    """The arguments of ``base_init`` (a base class's constructor) among ``values`` (a subclass constructor's
    ``locals()``): a subclass states its defaults in its own explicit signature and hands the shared arguments on."""
    return {name: values[name] for name in inspect.signature(base_init).parameters if name != "self" and name in values}


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


#: What each plain type hint accepts, and its name in an error.
_PLAIN_HINTS: dict[Any, tuple[str, Callable[[Any], bool]]] = {
    type(None): ("None", lambda value: value is None),
    bool: ("True or False", lambda value: isinstance(value, bool | np.bool_)),
    int: ("an int", is_int),
    float: ("a number", _is_number),
    str: ("a string", lambda value: isinstance(value, str | os.PathLike)),
    dict: ("a mapping", lambda value: isinstance(value, collections.abc.Mapping)),
    collections.abc.Callable: ("a schedule (callable)", callable),
}


def _in_interval(number: float, interval: str) -> bool:
    low, high = (float(bound) for bound in interval[1:-1].split(","))
    above = number > low or (interval[0] == "[" and number == low)
    return above and (number < high or (interval[-1] == "]" and number == high))


def _fits(value: Any, hint: Any) -> bool:
    """Whether ``value`` fits ``hint``; hints a config cannot hold (classes, envs) accept anything."""
    origin, arguments = typing.get_origin(hint), typing.get_args(hint)
    if isinstance(hint, types.UnionType) or origin is typing.Union:
        return any(_fits(value, member) for member in arguments)
    if origin is typing.Literal:
        return any(value == choice and type(value) is type(choice) for choice in arguments)
    if origin in (list, tuple):
        if not isinstance(value, list | tuple):
            return False
        items = arguments if origin is tuple and Ellipsis not in arguments else arguments[:1] * len(value)
        return len(items) == len(value) and all(map(_fits, value, items))
    return _PLAIN_HINTS.get(origin or hint, ("", lambda _: True))[1](value)


def _describe(hint: Any, interval: str | None) -> str:
    origin, arguments = typing.get_origin(hint), typing.get_args(hint)
    if isinstance(hint, types.UnionType) or origin is typing.Union:
        return " or ".join(_describe(member, interval) for member in arguments)
    if origin is typing.Literal:
        return f"one of {arguments}"
    if origin in (list, tuple):
        return f"a list of {'/'.join(getattr(item, '__name__', '') for item in arguments if item is not Ellipsis)}"
    word = _PLAIN_HINTS.get(origin or hint, (getattr(hint, "__name__", str(hint)),))[0]
    if interval is None or hint not in (int, float):
        return word
    low, high = interval[1:-1].split(", ")
    if math.isinf(float(high)):
        return f"{word} {'>=' if interval[0] == '[' else '>'} {low}"
    return f"{word} in {interval}"


def check_seed(seed: Any) -> int | None:
    """:return: ``seed`` as a Python int (or None); :raises ValueError: for anything but None or an int >= 0."""
    if seed is None:
        return None
    if not is_int(seed) or seed < 0:
        raise ValueError(f"seed must be None or a non-negative int, got {seed!r} of type {type(seed).__name__}")
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
        raise ValueError(f"values {tuple(values.shape)} must be (..., 1) over advantages {tuple(advantages.shape)}")
    return values + advantages - advantages.mean(dim=-1, keepdim=True)


def td_target(rewards: th.Tensor, discounts: th.Tensor, dones: th.Tensor, next_values: th.Tensor) -> th.Tensor:
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


#: The tensor lists of each target module and the online module they were gathered with (see :func:`polyak_update_`).
_POLYAK_LISTS: weakref.WeakKeyDictionary[th.nn.Module, tuple[Any, list[list[th.Tensor]]]] = weakref.WeakKeyDictionary()


def polyak_update_(target: th.nn.Module, online: th.nn.Module, tau: float) -> None:
    """:func:`polyak_update_tensors_` of ``target`` toward ``online``, on tensor lists gathered once per pair (module
    traversal costs more than the update for small networks; parameters are only ever updated in place)."""
    cached = _POLYAK_LISTS.get(target)
    if cached is None or cached[0]() is not online:
        lists = [list(part) for net in (target, online) for part in (net.parameters(), net.buffers())]
        cached = _POLYAK_LISTS[target] = (weakref.ref(online), lists)
    target_params, target_buffers, params, buffers = cached[1]
    polyak_update_tensors_(target_params, params, target_buffers, buffers, tau)


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
