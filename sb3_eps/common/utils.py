"""Small typed helpers shared by the algorithms: the constructors' argument checks, and math that cites the equation
it implements."""

from __future__ import annotations

import collections.abc
import inspect
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


def is_number(value: Any) -> bool:
    """Whether ``value`` is a real number (a bool is not)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


def check_arguments(function: Callable[..., Any], values: dict[str, Any], ranges: dict[str, str]) -> None:
    """Check ``values`` against the type hints of ``function`` (a constructor or a dataclass) and the intervals of
    ``ranges`` (``"(0, 1]"``, ``"[1, inf)"``) with :func:`conform`, the checker the config schema uses too.

    :raises ValueError: one line naming the first argument that does not fit and what it may be
    """
    hints = inspect.get_annotations(function, eval_str=True)
    for name, value in values.items():
        hint, interval = hints.get(name, Any), ranges.get(name)
        if conform(value, hint, interval) is INVALID:
            raise ValueError(f"{name} must be {describe_hint(hint, interval)}, got {value!r}")


#: What :func:`conform` returns for a value that does not fit its hint.
INVALID: Any = object()
#: The check of a plain hint: ``(value, hint) ->`` the value in canonical form, or :data:`INVALID`.
Leaf = Callable[[Any, Any], Any]


def leaf(test: Callable[[Any], bool], cast: Callable[[Any], Any] = lambda value: value) -> Leaf:
    """:return: the check of a plain hint that accepts the values passing ``test``, as ``cast`` of them."""
    return lambda value, hint: cast(value) if test(value) else INVALID


#: Each plain type hint (or origin) the constructors check: its words in an error (or a function of the hint giving
#: them) and its :data:`Leaf`. Hints not listed (classes, envs) accept anything and have no words.
PLAIN_HINTS: dict[Any, tuple[str | Callable[[Any], str | None], Leaf]] = {
    type(None): ("None", leaf(lambda value: value is None)),
    bool: ("True or False", leaf(lambda value: isinstance(value, bool | np.bool_), bool)),
    int: ("an int", leaf(is_int, int)),
    float: ("a number", leaf(is_number, float)),
    str: ("a string", leaf(lambda value: isinstance(value, str | os.PathLike))),
    dict: ("a mapping", leaf(lambda value: isinstance(value, collections.abc.Mapping))),
    collections.abc.Callable: ("a schedule (callable)", leaf(callable)),
}


def hint_members(hint: Any) -> tuple[Any, ...]:
    """:return: the members of a union hint (``int | None``), else ``(hint,)``."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        return typing.get_args(hint)
    return (hint,)


def conform(value: Any, hint: Any, interval: str | None = None, plain: dict[Any, Any] = PLAIN_HINTS) -> Any:
    """:return: ``value`` in canonical form (a list for a list or tuple) when it fits ``hint`` and its numbers lie in
    ``interval`` (``"(0, 1]"``, ``"[1, inf)"``; never NaN), else :data:`INVALID`.

    :param plain: the checks of the plain hints (a config's add their own spellings to :data:`PLAIN_HINTS`)
    """
    members, origin, arguments = hint_members(hint), typing.get_origin(hint), typing.get_args(hint)
    if len(members) > 1:
        results = (conform(value, member, interval, plain) for member in members)
        return next((result for result in results if result is not INVALID), INVALID)
    if origin is typing.Literal:
        return value if any(value == choice and type(value) is type(choice) for choice in arguments) else INVALID
    if origin in (list, tuple):
        if not isinstance(value, list | tuple):
            return INVALID
        hints = arguments if origin is tuple and Ellipsis not in arguments else arguments[:1] * len(value)
        items = [conform(item, item_hint, interval, plain) for item, item_hint in zip(value, hints)]
        return items if len(hints) == len(value) and all(item is not INVALID for item in items) else INVALID
    result = plain.get(origin or hint, ("", lambda value, _: value))[1](value, hint)
    if hint not in (int, float) or result is INVALID:
        return result
    return result if _in_interval(result, interval or "[-inf, inf]") else INVALID


def _in_interval(number: float, interval: str) -> bool:
    low, high = (float(bound) for bound in interval[1:-1].split(","))
    above = number > low or (interval[0] == "[" and number == low)
    return above and (number < high or (interval[-1] == "]" and number == high))  # NaN is neither


def describe_hint(hint: Any, interval: str | None = None, plain: dict[Any, Any] = PLAIN_HINTS) -> str | None:
    """:return: what a value of ``hint`` may be, in words (for error messages), with ``interval``; None for a hint
    that ``plain`` has no words for."""
    members, origin, arguments = hint_members(hint), typing.get_origin(hint), typing.get_args(hint)
    if len(members) > 1:
        words = [describe_hint(member, interval, plain) for member in members]
        return None if None in words else " or ".join(words)  # type: ignore[arg-type]
    if origin is typing.Literal:
        return f"one of {', '.join(map(str, arguments))}"
    if origin in (list, tuple):
        items = [describe_hint(item, interval, plain) for item in arguments if item is not Ellipsis]
        if not items or None in items:
            return None
        fixed = origin is tuple and Ellipsis not in arguments
        return f"a list [{', '.join(items)}]" if fixed else f"a list, each {items[0]}"  # type: ignore[arg-type]
    word = plain.get(origin or hint, (None,))[0]
    word = word(hint) if callable(word) else word
    if word is None or interval is None or hint not in (int, float):
        return word
    low, high = (bound.strip() for bound in interval[1:-1].split(","))
    return f"{word} in {interval}" if high != "inf" else f"{word} {'>=' if interval[0] == '[' else '>'} {low}"


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
    greedy_actions: np.ndarray,
    epsilon: float,
    n_actions: int,
    rng: np.random.Generator | None = None,
    allowed: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-agent epsilon-greedy: one independent coin per entry of ``greedy_actions`` (SB3's DQN draws one for the
    batch). ``rng`` None: numpy's global generator, which SB3 seeds. ``allowed``: ``(n, n_actions)`` booleans, each
    row with at least one True; random actions are drawn uniformly among the allowed ones (a safety mask).
    :return: ``(actions, explore_flags)``"""
    draw_uniform = np.random.random if rng is None else rng.random
    draw_integers = np.random.randint if rng is None else rng.integers
    explore = np.asarray(draw_uniform(greedy_actions.shape[0]) < epsilon)
    if allowed is None:
        random_actions = draw_integers(0, n_actions, size=greedy_actions.shape[0])
    else:  # a uniform draw among each row's allowed actions: the largest of uniform keys over them
        keys = draw_uniform((greedy_actions.shape[0], n_actions))
        random_actions = np.where(allowed, keys, -1.0).argmax(axis=1)
    return np.where(explore, random_actions, greedy_actions), explore
