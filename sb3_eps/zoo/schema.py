"""The schema of a config entry: which keys exist, what each may hold, and how an entry becomes objects.

An entry (one env id of a ``zoo_configs/<algo>.yml`` file, see ``docs/usage.md``) has three kinds of keys:

- run keys: ``tuned``, ``notes``, ``n_timesteps``, ``policy``, ``n_envs``, ``vec_env``, ``env_kwargs``, ``callback``;
- the algorithm's constructor arguments (:data:`ALGORITHM_PARAMS`), ``policy_kwargs`` among them (checked against
  the algorithm's policy, :data:`COMMON_POLICY_PARAMS` plus its own);
- nothing else: an unknown key is an error that lists the allowed ones.

:func:`normalize_entry` checks an entry and returns it in canonical form (plain YAML data: names of classes as
strings, ``train_freq`` as a list, ``callback`` as a list of ``{name: kwargs}``), which is what ``config.yml``
holds. :func:`algorithm_kwargs` and :func:`build_callbacks` turn a canonical entry into constructor arguments
and callback objects.
"""

from __future__ import annotations

import importlib
import inspect
import math
import re
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.utils import LinearSchedule
from torch import nn

from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.gdq import GDQ
from sb3_eps.iql import IQL
from sb3_eps.qmix import QMIX, VDN
from sb3_eps.zoo.errors import ConfigError, allowed
from sb3_eps.zoo.literal import parse_literal

# ---------------------------------------------------------------------------------------------- allow-lists
_ACTIVATION_CLASSES: dict[str, type[nn.Module]] = {
    name: getattr(nn, name)
    for name in ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid", "Softplus", "Identity")
}
_OPTIMIZER_CLASSES: dict[str, type[th.optim.Optimizer]] = {
    name: getattr(th.optim, name) for name in ("Adam", "AdamW", "RMSprop", "SGD")
}
#: canonical name -> class, e.g. ``"nn.ReLU"``, ``"th.optim.Adam"``
ACTIVATIONS: dict[str, type[nn.Module]] = {f"nn.{name}": cls for name, cls in _ACTIVATION_CLASSES.items()}
OPTIMIZERS: dict[str, type[th.optim.Optimizer]] = {
    f"th.optim.{name}": cls for name, cls in _OPTIMIZER_CLASSES.items()
}
#: every accepted spelling -> canonical name (``torch.nn.ReLU``, ``th.nn.ReLU``, ``nn.ReLU``, ``ReLU``)
NAME_SPELLINGS: dict[str, str] = {}
for _name in _ACTIVATION_CLASSES:
    for _prefix in ("", "nn.", "th.nn.", "torch.nn."):
        NAME_SPELLINGS[f"{_prefix}{_name}"] = f"nn.{_name}"
for _name in _OPTIMIZER_CLASSES:
    for _prefix in ("", "optim.", "th.optim.", "torch.optim."):
        NAME_SPELLINGS[f"{_prefix}{_name}"] = f"th.optim.{_name}"

_SCHEDULE_PATTERN = re.compile(r"^lin_([0-9.eE+-]+)$")
_FLOAT_PATTERN = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


# ---------------------------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class Param:
    """What one key may hold.

    :param kind: ``int``, ``float``, ``bool``, ``str``, ``choice``, ``schedule``, ``train_freq``, ``int_list``,
        ``mapping``, ``activation``, ``optimizer``
    :param low: smallest allowed number (``int`` / ``float`` / ``int_list`` items)
    :param high: largest allowed number
    :param open_low: ``low`` itself is excluded
    :param open_high: ``high`` itself is excluded
    :param choices: the allowed strings of a ``choice``
    """

    kind: str
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False
    choices: tuple[str, ...] = field(default_factory=tuple)

    def describe(self) -> str:
        """:return: what the key may hold, in words (for error messages)."""
        bounds = self._bounds()
        words = {
            "int": f"an int{bounds}",
            "float": f"a number{bounds}",
            "bool": "true or false",
            "str": "a string",
            "choice": f"one of {allowed(self.choices)}",
            "schedule": f"a number{bounds} or a linear schedule 'lin_<initial value>' (e.g. lin_1e-3)",
            "train_freq": "an int >= 1 or a list [int >= 1, 'step' or 'episode']",
            "int_list": f"a list of ints{bounds}",
            "mapping": "a mapping of names to values (or a 'dict(...)' string)",
            "activation": f"one of {allowed(ACTIVATIONS)}",
            "optimizer": f"one of {allowed(OPTIMIZERS)}",
        }
        return words[self.kind]

    def _bounds(self) -> str:
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.open_low else '>='} {self.low:g}")
        if self.high is not None:
            parts.append(f"{'<' if self.open_high else '<='} {self.high:g}")
        return (" " + " and ".join(parts)) if parts else ""

    def in_bounds(self, number: float) -> bool:
        """:return: whether ``number`` respects ``low`` / ``high``."""
        if math.isnan(number):
            return False
        if self.low is not None and (number < self.low or (self.open_low and number == self.low)):
            return False
        return not (
            self.high is not None and (number > self.high or (self.open_high and number == self.high))
        )


#: Run keys of an entry (not algorithm arguments). ``policy`` and ``callback`` are checked separately.
RUN_PARAMS: dict[str, Param] = {
    "tuned": Param("bool"),
    "notes": Param("str"),
    "n_timesteps": Param("int", low=1),
    "policy": Param("str"),
    "n_envs": Param("int", low=1),
    # dummy: the worlds in the training process; subproc: in worker processes (make_vec_env's vec_env_cls)
    "vec_env": Param("choice", choices=("dummy", "subproc")),
    "env_kwargs": Param("mapping"),
}
CALLBACK_KEY = "callback"
POLICY_KWARGS_KEY = "policy_kwargs"

#: Constructor arguments of :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm` settable from a
#: config (``policy_kwargs`` is checked against the policy). Counts are SB3 timesteps (agent-steps) except
#: ``buffer_size`` / ``batch_size`` (joint rows) and ``train_freq`` (vector-env steps).
ALGORITHM_PARAMS: dict[str, Param] = {
    "learning_rate": Param("schedule", low=0, open_low=True),
    "buffer_size": Param("int", low=1),
    "learning_starts": Param("int", low=0),
    "batch_size": Param("int", low=1),
    "tau": Param("float", low=0, high=1, open_low=True),
    "gamma": Param("float", low=0, high=1),
    "train_freq": Param("train_freq"),
    "gradient_steps": Param("int", low=-1),
    "target_update_interval": Param("int", low=1),
    "n_steps": Param("int", low=1),
    "prioritized_replay": Param("bool"),
    "prioritized_replay_alpha": Param("float", low=0),
    "prioritized_replay_beta0": Param("float", low=0, high=1),
    "double_q": Param("bool"),
    "exploration_fraction": Param("float", low=0, high=1),
    "exploration_initial_eps": Param("float", low=0, high=1),
    "exploration_final_eps": Param("float", low=0, high=1),
    "max_grad_norm": Param("float", low=0, open_low=True),
    "team_reward_mode": Param("choice", choices=("sum", "mean")),
    "stats_window_size": Param("int", low=1),
}
#: Constructor arguments that come from the command line, never from a config.
COMMAND_LINE_ARGUMENTS = (
    "policy",
    "env",
    "tensorboard_log",
    "verbose",
    "seed",
    "device",
    "_init_setup_model",
)

COMMON_POLICY_PARAMS: dict[str, Param] = {
    "net_arch": Param("int_list", low=1),
    "stream_arch": Param("int_list", low=1),
    "activation_fn": Param("activation"),
    "optimizer_class": Param("optimizer"),
    "optimizer_kwargs": Param("mapping"),
    "agent_target": Param("bool"),
    "normalize_images": Param("bool"),
}
GDQ_POLICY_PARAMS: dict[str, Param] = {
    **COMMON_POLICY_PARAMS,
    "global_net_arch": Param("int_list", low=1),
    "global_init": Param("choice", choices=("random", "sum", "mean")),
    "global_bootstrap": Param("float", low=0, high=1),
    "global_values": Param("choice", choices=("recomputed", "stored", "target")),
}
QMIX_POLICY_PARAMS: dict[str, Param] = {
    **COMMON_POLICY_PARAMS,
    "mixing_embed_dim": Param("int", low=1),
    "hypernet_hidden_dim": Param("int", low=1),
    "mixer_init": Param("choice", choices=("random", "sum")),
    "mixer_lr_scale": Param("float", low=0, open_low=True),
}


# ---------------------------------------------------------------------------------------------- algorithms
@dataclass(frozen=True)
class AlgorithmSpec:
    """An algorithm name of the command line and configs.

    :param name: ``iql``, ``gdq``, ``qmix``, ``vdn``, ``eps_iql`` or ``eps_gdq``
    :param algorithm_class: the model class
    :param policy_params: the ``policy_kwargs`` keys it accepts
    :param eps: an ``eps_*`` name: the base algorithm plus an ``EvolutionCallback`` from the config
    :param label: the name in plots and tables (the paper's)
    """

    name: str
    algorithm_class: type[MultiAgentOffPolicyAlgorithm]
    policy_params: dict[str, Param]
    eps: bool
    label: str


ALGORITHMS: dict[str, AlgorithmSpec] = {
    spec.name: spec
    for spec in (
        AlgorithmSpec("iql", IQL, COMMON_POLICY_PARAMS, False, "IL"),
        AlgorithmSpec("gdq", GDQ, GDQ_POLICY_PARAMS, False, "GDQ"),
        AlgorithmSpec("qmix", QMIX, QMIX_POLICY_PARAMS, False, "QMIX"),
        AlgorithmSpec("vdn", VDN, COMMON_POLICY_PARAMS, False, "VDN"),
        AlgorithmSpec("eps_iql", IQL, COMMON_POLICY_PARAMS, True, "EPS-IL"),
        AlgorithmSpec("eps_gdq", GDQ, GDQ_POLICY_PARAMS, True, "EPS-GDQ"),
    )
}


def algorithm_spec(name: str) -> AlgorithmSpec:
    """:return: the spec of an algorithm name. :raises ConfigError: for an unknown name."""
    if name not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {name!r}; allowed: {allowed(ALGORITHMS)}")
    return ALGORITHMS[name]


# ---------------------------------------------------------------------------------------------- callbacks
#: Callbacks a config may name: canonical name -> ``"module:attribute"``. Nothing else is ever imported.
CALLBACKS: dict[str, str] = {"sb3_eps.EvolutionCallback": "sb3_eps.eps:EvolutionCallback"}
EVOLUTION_CALLBACK = "sb3_eps.EvolutionCallback"
_CALLBACK_SPELLINGS: dict[str, str] = {
    "sb3_eps.EvolutionCallback": EVOLUTION_CALLBACK,
    "sb3_eps.eps.EvolutionCallback": EVOLUTION_CALLBACK,
    "EvolutionCallback": EVOLUTION_CALLBACK,
}


def callback_class(name: str, where: str = "callback") -> type[BaseCallback]:
    """Import an allowed callback class.

    :param name: a canonical name of :data:`CALLBACKS`
    :param where: what named it, for error messages
    :raises ConfigError: when it is not allowed or not importable
    """
    canonical = _CALLBACK_SPELLINGS.get(name)
    if canonical is None:
        raise ConfigError(f"{where}: unknown callback {name!r}; allowed: {allowed(CALLBACKS)}")
    module_name, _, attribute = CALLBACKS[canonical].partition(":")
    try:
        return getattr(importlib.import_module(module_name), attribute)
    except (ImportError, AttributeError) as error:
        raise ConfigError(f"{where}: callback {canonical} cannot be imported here ({error})") from None


def callback_parameters(cls: type[BaseCallback]) -> dict[str, inspect.Parameter]:
    """:return: the keyword arguments of a callback's constructor (no ``self``, no ``*args``)."""
    signature = inspect.signature(cls.__init__)
    return {
        name: parameter
        for name, parameter in signature.parameters.items()
        if name != "self" and parameter.kind not in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)
    }


# ---------------------------------------------------------------------------------------------- checking
def normalize_entry(entry: Any, spec: AlgorithmSpec, where: str) -> dict[str, Any]:
    """Check one config entry and return it in canonical form.

    :param entry: the entry as loaded from YAML (or made from ``--hyperparams``)
    :param spec: the algorithm it configures
    :param where: ``"<file>: entry '<env id>'"``, for error messages
    :return: the canonical entry (keys in schema order)
    :raises ConfigError: for an unknown key, a wrong type or value
    """
    if not isinstance(entry, Mapping):
        raise ConfigError(
            f"{where}: an entry must be a mapping of keys to values, got {type(entry).__name__}"
        )
    keys = [*RUN_PARAMS, *ALGORITHM_PARAMS, POLICY_KWARGS_KEY, CALLBACK_KEY]
    for key in entry:
        if key not in keys:
            raise ConfigError(f"{where}: unknown key {key!r}; allowed keys: {allowed(keys)}")
    result: dict[str, Any] = {}
    for key in keys:
        if key not in entry:
            continue
        value = entry[key]
        if key == "policy":
            result[key] = _check_policy(value, spec, f"{where}: policy")
        elif key == CALLBACK_KEY:
            result[key] = normalize_callbacks(value, f"{where}: callback")
        elif key == POLICY_KWARGS_KEY:
            result[key] = normalize_policy_kwargs(value, spec, f"{where}: policy_kwargs")
        else:
            param = RUN_PARAMS.get(key) or ALGORITHM_PARAMS[key]
            result[key] = normalize_value(value, param, f"{where}: {key}")
    return result


def check_complete(entry: Mapping[str, Any], spec: AlgorithmSpec, where: str) -> None:
    """The checks that need the whole (merged) entry.

    :raises ConfigError: when ``n_timesteps`` is missing, or an ``eps_*`` algorithm has no ``EvolutionCallback``
        (or another algorithm has one)
    """
    if "n_timesteps" not in entry:
        raise ConfigError(f"{where}: n_timesteps is missing; give it in the entry, its default, or with -n")
    names = [next(iter(item)) for item in entry.get(CALLBACK_KEY, [])]
    if spec.eps and EVOLUTION_CALLBACK not in names:
        raise ConfigError(
            f"{where}: algorithm {spec.name} is {spec.name[4:]} plus Evolutionary Policy Search: its entry needs "
            f"callback: {EVOLUTION_CALLBACK} (with its arguments)"
        )
    if not spec.eps and EVOLUTION_CALLBACK in names:
        raise ConfigError(
            f"{where}: {EVOLUTION_CALLBACK} belongs to the eps_* algorithms; use --algo eps_{spec.name} "
            "(or remove the callback)"
        )


def normalize_value(value: Any, param: Param, where: str) -> Any:
    """Check one value against its :class:`Param`; return its canonical form.

    :raises ConfigError: naming ``where`` and what is allowed
    """
    if param.kind == "mapping" and isinstance(value, str):
        value = parse_literal(value, {}, where)  # RL Zoo's "dict(...)" string
    result = _CHECKERS[param.kind](value, param)
    if result is _INVALID:
        raise ConfigError(f"{where} must be {param.describe()}, got {value!r} ({type(value).__name__})")
    return result


_INVALID = object()


def _as_number(value: Any) -> Any:
    """YAML 1.1 reads ``1e-4`` as a string: accept numeric strings where a number is expected."""
    if isinstance(value, str) and _FLOAT_PATTERN.match(value.strip()):
        return float(value)
    return value


def _check_int(value: Any, param: Param) -> Any:
    if isinstance(value, bool) or not isinstance(value, int):
        return _INVALID
    return value if param.in_bounds(value) else _INVALID


def _check_float(value: Any, param: Param) -> Any:
    value = _as_number(value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return _INVALID
    return float(value) if param.in_bounds(float(value)) else _INVALID


def _check_bool(value: Any, param: Param) -> Any:
    return value if isinstance(value, bool) else _INVALID


def _check_str(value: Any, param: Param) -> Any:
    return value if isinstance(value, str) else _INVALID


def _check_choice(value: Any, param: Param) -> Any:
    return value if isinstance(value, str) and value in param.choices else _INVALID


def _check_schedule(value: Any, param: Param) -> Any:
    if isinstance(value, str):
        match = _SCHEDULE_PATTERN.match(value.strip())
        if match is None or not _FLOAT_PATTERN.match(match.group(1)):
            return _INVALID
        return f"lin_{match.group(1)}" if param.in_bounds(float(match.group(1))) else _INVALID
    return _check_float(value, param)


def _check_train_freq(value: Any, param: Param) -> Any:
    if isinstance(value, list | tuple):
        if len(value) != 2 or value[1] not in ("step", "episode"):
            return _INVALID
        frequency = _check_int(value[0], Param("int", low=1))
        return _INVALID if frequency is _INVALID else [frequency, value[1]]
    return _check_int(value, Param("int", low=1))


def _check_int_list(value: Any, param: Param) -> Any:
    if not isinstance(value, list | tuple):
        return _INVALID
    items = [_check_int(item, param) for item in value]
    return _INVALID if any(item is _INVALID for item in items) else items


def _check_mapping(value: Any, param: Param) -> Any:
    if not isinstance(value, Mapping) or not all(isinstance(key, str) for key in value):
        return _INVALID
    if not all(_is_plain_data(item) for item in value.values()):
        return _INVALID
    return dict(value)


def _check_name(table: Mapping[str, type]) -> Callable[[Any, Param], Any]:
    def check(value: Any, param: Param) -> Any:
        canonical = NAME_SPELLINGS.get(value) if isinstance(value, str) else None
        return canonical if canonical in table else _INVALID

    return check


_CHECKERS: dict[str, Callable[[Any, Param], Any]] = {
    "int": _check_int,
    "float": _check_float,
    "bool": _check_bool,
    "str": _check_str,
    "choice": _check_choice,
    "schedule": _check_schedule,
    "train_freq": _check_train_freq,
    "int_list": _check_int_list,
    "mapping": _check_mapping,
    "activation": _check_name(ACTIVATIONS),
    "optimizer": _check_name(OPTIMIZERS),
}


def _is_plain_data(value: Any, depth: int = 0) -> bool:
    """Numbers, strings, booleans, None, and lists / string-keyed mappings of them."""
    if depth > 16:
        return False
    if value is None or isinstance(value, bool | int | float | str):
        return True
    if isinstance(value, list | tuple):
        return all(_is_plain_data(item, depth + 1) for item in value)
    if isinstance(value, Mapping):
        return all(isinstance(key, str) and _is_plain_data(item, depth + 1) for key, item in value.items())
    return False


def _check_policy(value: Any, spec: AlgorithmSpec, where: str) -> str:
    aliases = sorted(spec.algorithm_class.policy_aliases)
    if not isinstance(value, str) or value not in aliases:
        raise ConfigError(f"{where} must be one of {allowed(aliases)}, got {value!r}")
    return value


def normalize_policy_kwargs(value: Any, spec: AlgorithmSpec, where: str) -> dict[str, Any]:
    """Check ``policy_kwargs``: a mapping, or RL Zoo's ``"dict(...)"`` string (parsed, never evaluated).

    :raises ConfigError: for an unknown key (listing the algorithm's keys) or a wrong value
    """
    if isinstance(value, str):
        value = parse_literal(value, NAME_SPELLINGS, where)
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where} must be a mapping or a 'dict(...)' string, got {value!r}")
    result: dict[str, Any] = {}
    for key, item in value.items():
        if key not in spec.policy_params:
            raise ConfigError(
                f"{where}: unknown key {key!r} for {spec.name}; allowed keys: {allowed(spec.policy_params)}"
            )
        result[key] = normalize_value(item, spec.policy_params[key], f"{where}: {key}")
    return result


def normalize_callbacks(value: Any, where: str) -> list[dict[str, dict[str, Any]]]:
    """Check ``callback``: a name, ``{name: {kwargs}}``, or a list of those (RL Zoo's forms).

    :return: a list of ``{canonical name: kwargs}``
    :raises ConfigError: for an unknown callback, an unknown argument or a value of the wrong type
    """
    items = value if isinstance(value, list) else [value]
    result: list[dict[str, dict[str, Any]]] = []
    for item in items:
        kwargs: Any
        if isinstance(item, str):
            name, kwargs = item, {}
        elif isinstance(item, Mapping) and len(item) == 1:
            name, kwargs = next(iter(item.items()))
            kwargs = {} if kwargs is None else kwargs
        else:
            raise ConfigError(
                f"{where}: each callback must be a name or {{name: {{arguments}}}}, got {item!r}"
            )
        if not isinstance(name, str):
            raise ConfigError(f"{where}: a callback name must be a string, got {name!r}")
        cls = callback_class(name, where)
        canonical = _CALLBACK_SPELLINGS[name]
        result.append({canonical: _check_callback_kwargs(cls, kwargs, f"{where}: {canonical}")})
    return result


def _check_callback_kwargs(cls: type[BaseCallback], kwargs: Any, where: str) -> dict[str, Any]:
    if isinstance(kwargs, str):
        kwargs = parse_literal(kwargs, {}, where)
    if not isinstance(kwargs, Mapping):
        raise ConfigError(f"{where}: the arguments must be a mapping, got {kwargs!r}")
    parameters = callback_parameters(cls)
    hints = typing.get_type_hints(cls.__init__)
    result: dict[str, Any] = {}
    for key, value in kwargs.items():
        if key not in parameters:
            raise ConfigError(f"{where}: unknown argument {key!r}; allowed: {allowed(parameters)}")
        value = _as_number(value) if isinstance(value, str) and _accepts(hints.get(key), float) else value
        if not _matches_hint(value, hints.get(key, Any)):
            raise ConfigError(f"{where}: {key} must be {_describe_hint(hints.get(key, Any))}, got {value!r}")
        result[key] = float(value) if _is_float_hint(hints.get(key)) and isinstance(value, int) else value
    return result


def _hint_members(hint: Any) -> tuple[Any, ...]:
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        return typing.get_args(hint)
    return (hint,)


def _accepts(hint: Any, kind: type) -> bool:
    return any(member is kind for member in _hint_members(hint))


def _is_float_hint(hint: Any) -> bool:
    return _accepts(hint, float) and not _accepts(hint, int)


def _matches_hint(value: Any, hint: Any) -> bool:
    for member in _hint_members(hint):
        origin = typing.get_origin(member) or member
        if member is Any:
            return _is_plain_data(value)
        if member is type(None) and value is None:
            return True
        if origin is bool and isinstance(value, bool):
            return True
        if origin is int and isinstance(value, int) and not isinstance(value, bool):
            return True
        if origin is float and isinstance(value, int | float) and not isinstance(value, bool):
            return True
        if origin is str and isinstance(value, str):
            return True
        if origin in (dict, Mapping) and isinstance(value, Mapping) and _is_plain_data(value):
            return True
        if origin in (list, tuple) and isinstance(value, list | tuple) and _is_plain_data(value):
            return True
    return False


def _describe_hint(hint: Any) -> str:
    names = {bool: "true/false", int: "an int", float: "a number", str: "a string", type(None): "null"}
    words = [
        names.get(typing.get_origin(m) or m, getattr(m, "__name__", str(m))) for m in _hint_members(hint)
    ]
    return " or ".join(word if word not in ("dict", "Mapping") else "a mapping" for word in words)


# ---------------------------------------------------------------------------------------------- building
def algorithm_kwargs(entry: Mapping[str, Any]) -> dict[str, Any]:
    """The algorithm constructor's keyword arguments of a canonical entry (schedules and classes built).

    :param entry: a canonical entry (:func:`normalize_entry`)
    """
    kwargs: dict[str, Any] = {}
    for key in ALGORITHM_PARAMS:
        if key not in entry:
            continue
        value = entry[key]
        if key == "learning_rate" and isinstance(value, str):
            # RL Zoo's lin_<x>: x at the start, decreasing linearly to 0 at the end of training.
            value = LinearSchedule(float(value[4:]), 0.0, 1.0)
        elif key == "train_freq" and isinstance(value, list):
            value = (value[0], value[1])
        kwargs[key] = value
    if POLICY_KWARGS_KEY in entry:
        kwargs[POLICY_KWARGS_KEY] = policy_kwargs_objects(entry[POLICY_KWARGS_KEY])
    return kwargs


def policy_kwargs_objects(policy_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """:return: canonical ``policy_kwargs`` with the class names replaced by the classes."""
    result = dict(policy_kwargs)
    if "activation_fn" in result:
        result["activation_fn"] = ACTIVATIONS[result["activation_fn"]]
    if "optimizer_class" in result:
        result["optimizer_class"] = OPTIMIZERS[result["optimizer_class"]]
    return result


def build_callbacks(
    entry: Mapping[str, Any], env_id: str, verbose: int, where: str
) -> list[tuple[str, BaseCallback]]:
    """Make the callbacks of a canonical entry.

    ``EvolutionCallback`` gets ``eval_env_id=envs.eps_env_id_for(env_id)`` unless the entry sets it.

    :return: ``(canonical name, callback)`` pairs
    :raises ConfigError: when a constructor refuses its arguments
    """
    import envs

    callbacks = []
    for item in entry.get(CALLBACK_KEY, []):
        name, kwargs = next(iter(item.items()))
        kwargs = dict(kwargs)
        if name == EVOLUTION_CALLBACK:
            kwargs.setdefault("eval_env_id", envs.eps_env_id_for(env_id))
            kwargs.setdefault("verbose", verbose)
        try:
            callbacks.append((name, callback_class(name, where)(**kwargs)))
        except (TypeError, ValueError) as error:
            raise ConfigError(f"{where}: callback {name}: {error}") from None
    return callbacks
