"""The schema of a config entry: which keys exist, what each may hold, and how an entry becomes objects.

An entry (one env id of a ``zoo_configs/<algo>.yml`` file, ``docs/usage.md``) holds run keys (:data:`RUN_PARAMS`,
``callback``, ``ladder``: :mod:`sb3_eps.zoo.ladder`, and the keys of plug-in trainers, :func:`register_trainer`) and
the algorithm's constructor arguments, ``policy_kwargs`` among them, read from the signatures; an unknown key is an
error that lists the allowed ones. :func:`normalize_entry` returns an entry in canonical form
(plain YAML data, what ``config.yml`` holds); :func:`algorithm_kwargs` and :func:`build_callbacks` make objects
of it.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import inspect
import re
import sys
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import TrainFrequencyUnit
from stable_baselines3.common.utils import LinearSchedule
from torch import nn

from sb3_eps.common import buffers
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import INVALID, PLAIN_HINTS, Leaf, conform, describe_hint, hint_members, is_number, leaf
from sb3_eps.eps import EvolutionCallback, eps_env_id_for
from sb3_eps.gdq import GDQ
from sb3_eps.iql import IQL
from sb3_eps.qmix import QMIX, VDN
from sb3_eps.zoo.errors import ConfigError, allowed
from sb3_eps.zoo.ladder import LADDER_KEY, normalize_ladder
from sb3_eps.zoo.literal import parse_literal

# ---------------------------------------------------------------------------------------------- allow-lists
#: canonical name -> class, e.g. ``"nn.ReLU"``, ``"th.optim.Adam"``
ACTIVATIONS: dict[str, type[nn.Module]] = {
    f"nn.{name}": getattr(nn, name)
    for name in ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid", "Softplus", "Identity")
}
OPTIMIZERS: dict[str, type[th.optim.Optimizer]] = {
    f"th.optim.{name}": getattr(th.optim, name) for name in ("Adam", "AdamW", "RMSprop", "SGD")
}
#: every accepted spelling -> canonical name (``torch.nn.ReLU``, ``th.nn.ReLU``, ``nn.ReLU``, ``ReLU``)
NAME_SPELLINGS: dict[str, str] = {
    f"{prefix}{canonical.rpartition('.')[2]}": canonical
    for canonical in [*ACTIVATIONS, *OPTIMIZERS]
    for module in [canonical.removeprefix("th.").rpartition(".")[0]]  # nn or optim
    for prefix in ("", f"{module}.", f"th.{module}.", f"torch.{module}.")
}
#: The joint replay buffers a config may name (``replay_buffer_class``): those of :mod:`sb3_eps.common.buffers`.
REPLAY_BUFFER_CLASSES: dict[str, type[buffers.JointReplayBuffer]] = {
    name: cls for name, cls in vars(buffers).items() if isinstance(cls, type) and issubclass(cls, buffers.JointReplayBuffer)
}

_NUMBER = r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?"
_SCHEDULE_PATTERN, _FLOAT_PATTERN = re.compile(rf"^lin_({_NUMBER})$"), re.compile(rf"^{_NUMBER}$")


# ---------------------------------------------------------------------------------------------- parameters
#: The ranges of every number a key holds, in interval notation: the algorithm constructor's own (``argument_ranges``),
#: the policies', the run keys' and the command lines' (:class:`~sb3_eps.zoo.cli.NamespaceOptions`). A config out of
#: range fails when it is loaded, before a run folder exists. Type hints hold no ranges.
RANGES: dict[str, str] = {
    **MultiAgentOffPolicyAlgorithm.argument_ranges, "net_arch": "[1, inf)", "stream_arch": "[1, inf)",
    "weight_average_tau": "(0, 1]", "n_timesteps": "[1, inf)", "n_envs": "[1, inf)", "train_freq": "[1, inf)",
    "seeds": "[0, inf)", "cpus_per_run": "[1, inf)", "seed": "[0, inf)", "eval_freq": "[0, inf)",
    "eval_episodes": "[1, inf)", "n_eval_envs": "[1, inf)", "save_freq": "[0, inf)", "num_threads": "[0, inf)",
    "n_trials": "[1, inf)", "n_jobs": "[1, inf)", "n_evaluations": "[1, inf)", "n_seeds_per_trial": "[1, inf)",
    "n_startup_trials": "[0, inf)",
}  # fmt: skip
#: The classes a ``type[...]`` hint may name: base class -> {config name: class}.
CLASS_NAMES: dict[Any, dict[str, type]] = {
    nn.Module: ACTIVATIONS,
    th.optim.Optimizer: OPTIMIZERS,
    buffers.JointReplayBuffer: REPLAY_BUFFER_CLASSES,
}


def _classes(hint: Any) -> dict[str, type] | None:
    """:return: the classes a ``type[...]`` hint may name in a config (:data:`CLASS_NAMES`), or None."""
    arguments = typing.get_args(hint)
    return CLASS_NAMES.get(arguments[0]) if arguments else None


def _class_name(value: Any, hint: Any) -> Any:
    canonical = NAME_SPELLINGS.get(value, value) if isinstance(value, str) else None
    return canonical if canonical in (_classes(hint) or {}) else INVALID


def _schedule(value: Any, hint: Any) -> Any:
    """RL Zoo's ``lin_<x>``: x at the start, decreasing linearly to 0."""
    match = _SCHEDULE_PATTERN.match(value.strip()) if isinstance(value, str) else None
    return f"lin_{match[1]}" if match else INVALID


def _mapping(value: Any, hint: Any) -> Any:
    value = parse_literal(value, {}, "a 'dict(...)' string") if isinstance(value, str) else value  # RL Zoo's form
    return dict(value) if isinstance(value, Mapping) and _is_plain_data(value) else INVALID


def _is_numeric(value: Any) -> bool:
    """A number, or a numeric string (YAML 1.1 reads ``1e-4`` as a string)."""
    return is_number(value) or (isinstance(value, str) and _FLOAT_PATTERN.match(value.strip()) is not None)


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


#: The plain hints of a config value: the constructors' (:data:`~sb3_eps.common.utils.PLAIN_HINTS`) and what only a
#: config needs: YAML's null and numeric strings, RL Zoo's ``lin_<x>`` schedules and ``dict(...)`` strings, class
#: names, plain data. A hint without words here is one a config cannot hold.
CONFIG_HINTS: dict[Any, tuple[Any, Leaf]] = {
    **PLAIN_HINTS,
    type(None): ("null", PLAIN_HINTS[type(None)][1]),
    float: ("a number", leaf(_is_numeric, float)),
    dict: ("a mapping of names to values (or a 'dict(...)' string)", _mapping),
    Any: ("plain data (numbers, strings, lists, mappings)", leaf(_is_plain_data)),
    collections.abc.Callable: ("a linear schedule 'lin_<initial value>' (e.g. lin_1e-3)", _schedule),
    type: (lambda hint: f"one of {allowed(_classes(hint) or ())}" if _classes(hint) else None, _class_name),
}
#: Run keys of an entry (not algorithm arguments) and their types. ``policy`` and ``callback`` are checked separately.
RUN_PARAMS: dict[str, Any] = {
    "tuned": bool,
    "notes": str,
    "n_timesteps": int,
    "policy": str,
    "n_envs": int,
    # dummy: the worlds in the training process; subproc: in worker processes (make_vec_env's vec_env_cls)
    "vec_env": Literal["dummy", "subproc"],
    "env_kwargs": dict,
}
CALLBACK_KEY = "callback"
POLICY_KWARGS_KEY = "policy_kwargs"
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
#: Policy constructor arguments the algorithm sets itself.
_POLICY_INTERNALS = (
    "observation_space", "action_space", "lr_schedule", "n_agents", "state_dim", "features_extractor_class",
    "features_extractor_kwargs",
)  # fmt: skip


def params_from_signature(function: Callable[..., Any], skip: Sequence[str] = (), every: bool = False) -> dict[str, Any]:
    """:return: ``{argument: type hint}`` of the keyword arguments of ``function`` whose hint a config can hold
    (:data:`CONFIG_HINTS`); with ``every``, the others too, as plain data. A keyword whose hint is a dataclass
    (``EPSSettings``) stands for the dataclass's fields."""
    hints = typing.get_type_hints(function)
    params: dict[str, Any] = {}
    for name, parameter in inspect.signature(function).parameters.items():
        variadic = parameter.kind in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)
        if variadic or name in skip or name == "self" or (name not in hints and not every):
            continue
        hint = hints.get(name, Any)
        settings = [member for member in hint_members(hint) if isinstance(member, type) and dataclasses.is_dataclass(member)]
        if settings:
            params.update(params_from_signature(settings[0], skip, every))
        elif (holdable := describe_hint(hint, None, CONFIG_HINTS) is not None) or every:
            params[name] = hint if holdable else Any
    return params


#: Arguments of :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm` a config may set, read from its
#: signature (``policy_kwargs`` is checked against the policy). Counts are SB3 timesteps (agent-steps) except
#: ``buffer_size`` / ``batch_size`` (joint rows) and ``train_freq`` (vector-env steps).
ALGORITHM_PARAMS: dict[str, Any] = params_from_signature(
    MultiAgentOffPolicyAlgorithm.__init__, (*COMMAND_LINE_ARGUMENTS, POLICY_KWARGS_KEY)
)
#: SB3's ``train_freq`` unit is a plain ``str`` in the signature; a config names one of its units.
ALGORITHM_PARAMS["train_freq"] = int | tuple[int, Literal[tuple(unit.value for unit in TrainFrequencyUnit)]]  # type: ignore[misc]
#: ``policy_kwargs`` keys of every algorithm, read from the shared policy's signature.
COMMON_POLICY_PARAMS: dict[str, Any] = params_from_signature(MultiAgentQPolicy.__init__, _POLICY_INTERNALS)


# ---------------------------------------------------------------------------------------------- algorithms
@dataclass(frozen=True)
class AlgorithmSpec:
    """An algorithm name of the command line and configs.

    :param name: ``iql``, ``gdq``, ``qmix``, ``vdn``, ``eps_iql`` or ``eps_gdq``
    :param algorithm_class: the model class
    :param policy_params: the ``policy_kwargs`` keys it accepts
    :param eps: an ``eps_*`` name: the base algorithm plus an ``EvolutionCallback`` from the config
    :param label: the name in plots and tables (the paper's)
    :param extra_params: constructor arguments of its own beyond :data:`ALGORITHM_PARAMS`
    """

    name: str
    algorithm_class: type[MultiAgentOffPolicyAlgorithm]
    policy_params: dict[str, Any]
    eps: bool
    label: str
    extra_params: dict[str, Any] = field(default_factory=dict)

    @property
    def params(self) -> dict[str, Any]:
        """Every constructor argument a config may set (``policy_kwargs`` apart)."""
        return {**ALGORITHM_PARAMS, **self.extra_params}


#: The algorithm names of the configs and command lines; plug-ins add theirs with :func:`register_algorithm`.
ALGORITHMS: dict[str, AlgorithmSpec] = {}


def register_algorithm(
    name: str,
    algorithm_class: type[MultiAgentOffPolicyAlgorithm],
    *,
    label: str | None = None,
    eps: bool = False,
) -> AlgorithmSpec:
    """Make an algorithm of one's own a name of the configs and command lines (``--algo <name>``); a module that
    ``--gym-packages`` imports calls it. Its config keys come from its signatures: the base's arguments, its own
    constructor arguments and its policy's (:func:`params_from_signature`).

    :param name: the name (lower case, digits and ``_``); its config file is ``<name>.yml``
    :param algorithm_class: a subclass of :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm`
    :param label: its name in plots and tables (default: the class name)
    :param eps: it runs with an ``EvolutionCallback`` from its config (as ``eps_gdq``)
    :return: the spec
    :raises ValueError: for a bad name, a name taken by another algorithm, or a class of another kind
    """
    if not isinstance(name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", name):
        raise ValueError(f"an algorithm name is lower case letters, digits and _, got {name!r}")
    if not (isinstance(algorithm_class, type) and issubclass(algorithm_class, MultiAgentOffPolicyAlgorithm)):
        raise ValueError(f"{algorithm_class!r} is not a subclass of sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm")
    known = ALGORITHMS.get(name)
    if known is not None and known.algorithm_class is not algorithm_class:
        raise ValueError(f"algorithm name {name!r} is taken by {known.algorithm_class.__name__}; pick another")
    own = params_from_signature(algorithm_class.__init__, (*ALGORITHM_PARAMS, *COMMAND_LINE_ARGUMENTS, POLICY_KWARGS_KEY))
    policy_class = algorithm_class.policy_aliases["MlpPolicy"]
    policy_params = dict(COMMON_POLICY_PARAMS)
    if "__init__" in vars(policy_class):  # a policy that only inherits its constructor adds no keys (VDN's)
        policy_params.update(params_from_signature(policy_class.__init__, (*_POLICY_INTERNALS, *COMMON_POLICY_PARAMS)))
    spec = AlgorithmSpec(name, algorithm_class, policy_params, eps, label or algorithm_class.__name__, own)
    ALGORITHMS[name] = spec
    return spec


def algorithm_spec(name: str) -> AlgorithmSpec:
    """:return: the spec of an algorithm name. :raises ConfigError: for an unknown name."""
    if name not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {name!r}; allowed: {allowed(ALGORITHMS)}")
    return ALGORITHMS[name]


# ---------------------------------------------------------------------------------------------- trainers
@dataclass(frozen=True)
class EntryTrainer:
    """A config key whose runs a trainer of its own trains instead of one model's ``learn`` (a plug-in's:
    :func:`register_trainer`).

    :param key: the entry key; it holds the trainer's settings (a mapping)
    :param params: ``{setting: type hint}``: what the key may hold, checked as constructor arguments are
    :param check: ``check(config, options)``: the run's own checks, before anything is written (raises ``ConfigError``)
    :param run: ``run(prepared, run_dir, checkpoint_path, extra_callbacks) -> TrainResult``: train the prepared run
        (:class:`~sb3_eps.zoo.config.PreparedRun`) in its folder; ``checkpoint_path`` continues that checkpoint of
        the run (``--resume``), None starts it
    """

    key: str
    params: dict[str, Any]
    check: Callable[..., None]
    run: Callable[..., Any]


#: The plug-in trainers by their entry key (:func:`register_trainer`).
TRAINERS: dict[str, EntryTrainer] = {}


def register_trainer(key: str, params: Mapping[str, Any], check: Callable[..., None], run: Callable[..., Any]) -> EntryTrainer:
    """Make ``key`` an entry key whose runs ``run`` trains (``python -m sb3_eps.train`` and ``--resume``); a module
    that ``--gym-packages`` imports calls it (a population of learners' ``population``, for one). ``-optimize``
    refuses such an entry. Arguments: :class:`EntryTrainer`.

    :return: the trainer
    :raises ValueError: for a bad key, a key of the schema's own or one taken by another trainer
    """
    if not isinstance(key, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", key):
        raise ValueError(f"a trainer's key is lower case letters, digits and _, got {key!r}")
    if key in (*RUN_PARAMS, *ALGORITHM_PARAMS, POLICY_KWARGS_KEY, CALLBACK_KEY, LADDER_KEY):
        raise ValueError(f"{key!r} is a key of every entry already; pick another")
    known = TRAINERS.get(key)
    if known is not None and (known.check, known.run) != (check, run):
        raise ValueError(f"entry key {key!r} is taken by the trainer of {known.run.__module__}; pick another")
    TRAINERS[key] = EntryTrainer(key, dict(params), check, run)
    return TRAINERS[key]


def entry_trainer(entry: Mapping[str, Any]) -> EntryTrainer | None:
    """:return: the plug-in trainer of a canonical entry, or None when one model's ``learn`` trains it."""
    return next((trainer for key, trainer in TRAINERS.items() if key in entry), None)


def entry_keys(spec: AlgorithmSpec) -> list[str]:
    """:return: every key an entry of ``spec`` may hold, in schema order."""
    return [*RUN_PARAMS, *spec.params, POLICY_KWARGS_KEY, CALLBACK_KEY, LADDER_KEY, *TRAINERS]


# ---------------------------------------------------------------------------------------------- callbacks
#: Callbacks a config may name: canonical name -> class. Nothing else is ever built from a config.
CALLBACKS: dict[str, type[BaseCallback]] = {}
EVOLUTION_CALLBACK = "sb3_eps.EvolutionCallback"
_CALLBACK_SPELLINGS: dict[str, str] = {"sb3_eps.eps.EvolutionCallback": EVOLUTION_CALLBACK}


def register_callback(callback_class: type[BaseCallback], name: str | None = None) -> str:
    """Make a callback of one's own a name that configs may list (``callback: mypkg.MyCallback``); a module that
    ``--gym-packages`` imports calls it. Its arguments are checked against its constructor's type hints.

    :param callback_class: an SB3 ``BaseCallback`` subclass with ``state_dict()`` / ``load_state_dict()`` (a run's
        checkpoint keeps its state; return ``{}`` when it keeps none)
    :param name: its name in configs (default ``<module>.<class name>``; the bare class name is accepted too)
    :return: the name
    :raises ValueError: for another kind of class, one without a state, or a name taken by another callback
    """
    if not (isinstance(callback_class, type) and issubclass(callback_class, BaseCallback)):
        raise ValueError(f"{callback_class!r} is not a stable_baselines3 BaseCallback subclass")
    if not all(hasattr(callback_class, method) for method in ("state_dict", "load_state_dict")):
        raise ValueError(
            f"{callback_class.__name__} needs state_dict() and load_state_dict() so that a checkpoint resumes it "
            "(return {} when it keeps no state)"
        )
    canonical = name or f"{callback_class.__module__}.{callback_class.__qualname__}"
    known = CALLBACKS.get(canonical, callback_class)
    if known is not callback_class:
        raise ValueError(f"callback name {canonical!r} is taken by {known.__module__}.{known.__qualname__}; pick another")
    CALLBACKS[canonical] = callback_class
    for spelling in (canonical, callback_class.__name__):
        _CALLBACK_SPELLINGS.setdefault(spelling, canonical)
    return canonical


def callback_class(name: str, where: str = "callback") -> type[BaseCallback]:
    """:return: the callback class of a config name (:data:`CALLBACKS`).

    :param name: a name of :data:`CALLBACKS`, or another accepted spelling of one
    :param where: what named it, for error messages
    :raises ConfigError: when it is not allowed
    """
    canonical = _CALLBACK_SPELLINGS.get(name)
    if canonical is None:
        raise ConfigError(f"{where}: unknown callback {name!r}; allowed: {allowed(CALLBACKS)}")
    return CALLBACKS[canonical]


def is_evolution(name: str) -> bool:
    """:return: whether the callback of canonical name ``name`` is an ``EvolutionCallback`` (or a subclass's)."""
    return issubclass(CALLBACKS.get(name, BaseCallback), EvolutionCallback)


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
        raise ConfigError(f"{where}: an entry must be a mapping of keys to values, got {type(entry).__name__}")
    keys = entry_keys(spec)
    for key in entry:
        if key not in keys:
            raise ConfigError(
                f"{where}: unknown key {key!r}; allowed keys: {allowed(keys)} (a plug-in's key needs its module: "
                "--gym-packages MODULE)"
            )
    result: dict[str, Any] = {}
    for key in keys:
        if key not in entry:
            continue
        value = entry[key]
        if key == "policy":
            policies = Literal[tuple(sorted(spec.algorithm_class.policy_aliases))]  # type: ignore[valid-type]
            result[key] = normalize_value(value, policies, f"{where}: policy")
        elif key == CALLBACK_KEY:
            result[key] = normalize_callbacks(value, f"{where}: callback")
        elif key == POLICY_KWARGS_KEY:
            result[key] = normalize_arguments(value, spec.policy_params, f"{where}: policy_kwargs", NAME_SPELLINGS)
        elif key == LADDER_KEY:
            result[key] = normalize_ladder(value, f"{where}: ladder")
        elif key in TRAINERS:
            result[key] = normalize_arguments(value, TRAINERS[key].params, f"{where}: {key}")
        else:
            hint = RUN_PARAMS[key] if key in RUN_PARAMS else spec.params[key]
            result[key] = normalize_value(value, hint, f"{where}: {key}", key)
    return result


def check_complete(entry: Mapping[str, Any], spec: AlgorithmSpec, where: str) -> None:
    """The checks that need the whole (merged) entry.

    :raises ConfigError: when ``n_timesteps`` is missing, or an ``eps_*`` algorithm has no ``EvolutionCallback``
        (or another algorithm has one; a subclass counts as one)
    """
    if "n_timesteps" not in entry and LADDER_KEY not in entry:  # a ladder's total is its rungs
        raise ConfigError(f"{where}: n_timesteps is missing; give it in the entry, its default, or with -n")
    evolution = [name for item in entry.get(CALLBACK_KEY, []) if is_evolution(name := next(iter(item)))]
    if spec.eps and not evolution:
        raise ConfigError(
            f"{where}: algorithm {spec.name} is {spec.name[4:]} plus Evolutionary Policy Search: its entry needs "
            f"callback: {EVOLUTION_CALLBACK} (with its arguments)"
        )
    if not spec.eps and evolution:
        raise ConfigError(
            f"{where}: {evolution[0]} belongs to the eps_* algorithms; use --algo eps_{spec.name} (or remove the callback)"
        )


def normalize_value(value: Any, hint: Any, where: str, name: str = "") -> Any:
    """Check one value against its type hint (and the :data:`RANGES` interval of ``name``) with the constructors'
    checker (:func:`~sb3_eps.common.utils.conform`) and the config spellings of :data:`CONFIG_HINTS`; return its
    canonical form.

    :raises ConfigError: naming ``where`` and what is allowed
    """
    try:
        result = conform(value, hint, RANGES.get(name), CONFIG_HINTS)
    except ConfigError as error:  # a 'dict(...)' string that does not parse
        raise ConfigError(f"{where}: {error}") from None
    if result is INVALID:
        words = describe_hint(hint, RANGES.get(name), CONFIG_HINTS)
        raise ConfigError(f"{where} must be {words}, got {value!r} ({type(value).__name__})")
    return result


def normalize_arguments(
    value: Any, params: Mapping[str, Any], where: str, names: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """Check keyword arguments (``policy_kwargs``, a callback's) against the type hints of ``params``: a mapping, or
    RL Zoo's ``"dict(...)"`` string (parsed, never evaluated; ``names`` are the class names it may hold).

    :raises ConfigError: for an unknown key (listing the allowed ones) or a wrong value
    """
    if isinstance(value, str):
        value = parse_literal(value, names or {}, where)
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where} must be a mapping or a 'dict(...)' string, got {value!r}")
    for key in value:
        if key not in params:
            raise ConfigError(f"{where}: unknown key {key!r}; allowed keys: {allowed(params)}")
    return {key: normalize_value(item, params[key], f"{where}: {key}", key) for key, item in value.items()}


def normalize_callbacks(value: Any, where: str) -> list[dict[str, dict[str, Any]]]:
    """Check ``callback``: a name, ``{name: {kwargs}}``, or a list of those (RL Zoo's forms).

    :return: a list of ``{canonical name: kwargs}``
    :raises ConfigError: for an unknown callback, an unknown argument or a value of the wrong type
    """
    result: list[dict[str, dict[str, Any]]] = []
    for item in value if isinstance(value, list) else [value]:
        item = {item: None} if isinstance(item, str) else item
        if not (isinstance(item, Mapping) and len(item) == 1):
            raise ConfigError(f"{where}: each callback must be a name or {{name: {{arguments}}}}, got {item!r}")
        name, kwargs = next(iter(item.items()))
        params = params_from_signature(callback_class(name, where).__init__, every=True)
        canonical = _CALLBACK_SPELLINGS[name]
        kwargs = {} if kwargs is None else kwargs
        result.append({canonical: normalize_arguments(kwargs, params, f"{where}: {canonical}")})
    return result


# ---------------------------------------------------------------------------------------------- defaults
def package_defaults(spec: AlgorithmSpec) -> dict[str, Any]:
    """The constructors' defaults as a canonical entry (the algorithm's arguments and its ``policy_kwargs``, read
    from the signatures): what an entry that sets nothing trains with. :func:`~sb3_eps.zoo.config.resolve_config`
    puts them under every entry, so the config files list only what differs and a run's ``config.yml`` still
    holds every value it trained with. A None default stands for the ``DEFAULT_<NAME>`` constant of the class's
    module when there is one (``DEFAULT_NET_ARCH``), as the constructors read it; other None defaults are left out.
    """
    algorithm = _constructor_defaults(spec.algorithm_class)
    entry = {name: _config_value(algorithm[name]) for name in spec.params if algorithm.get(name) is not None}
    policy = _constructor_defaults(spec.algorithm_class.policy_aliases["MlpPolicy"])
    policy["agent_target"] = spec.algorithm_class.default_agent_target
    entry[POLICY_KWARGS_KEY] = {
        name: _config_value(policy[name]) for name in spec.policy_params if policy.get(name) is not None
    }
    return entry


def with_package_defaults(entry: Mapping[str, Any], spec: AlgorithmSpec) -> dict[str, Any]:
    """:return: ``entry`` over :func:`package_defaults` (``policy_kwargs`` merged key by key), in schema order."""
    defaults = package_defaults(spec)
    merged = {**defaults, **entry}
    merged[POLICY_KWARGS_KEY] = {**defaults[POLICY_KWARGS_KEY], **entry.get(POLICY_KWARGS_KEY, {})}
    return {key: merged[key] for key in entry_keys(spec) if key in merged}


def _constructor_defaults(cls: type) -> dict[str, Any]:
    """:return: the keyword defaults of every ``__init__`` along ``cls``'s MRO, the base's first and each subclass's
    over them (a subclass that passes ``**kwargs`` on keeps its base's); a None default becomes the
    ``DEFAULT_<NAME>`` constant of the class's module where there is one."""
    defaults: dict[str, Any] = {}
    for owner in reversed(cls.__mro__):
        if "__init__" not in vars(owner) or owner is object:
            continue
        module = sys.modules[owner.__module__]
        for name, parameter in inspect.signature(vars(owner)["__init__"]).parameters.items():
            if parameter.default is not inspect.Parameter.empty:
                value = parameter.default
                defaults[name] = getattr(module, f"DEFAULT_{name.upper()}", None) if value is None else value
    return defaults


def _config_value(value: Any) -> Any:
    """A constructor default as a config value: SB3's ``LinearSchedule(x, 0, 1)`` is RL Zoo's ``lin_<x>``; classes
    are their config names (``nn.ReLU``, ``th.optim.Adam``, ``JointReplayBuffer``)."""
    if isinstance(value, LinearSchedule):
        if value.end != 0.0 or value.end_fraction != 1.0:
            raise ValueError(f"a default {value!r} has no config form: only lin_<x> (x -> 0 over training) has")
        return f"lin_{value.start}"
    if isinstance(value, type):
        names = {cls: name for name, cls in {**ACTIVATIONS, **OPTIMIZERS}.items()}
        return names.get(value, value.__name__)
    if isinstance(value, tuple):
        return list(value)
    return value


# ---------------------------------------------------------------------------------------------- building
def algorithm_kwargs(entry: Mapping[str, Any], spec: AlgorithmSpec) -> dict[str, Any]:
    """The algorithm constructor's keyword arguments of a canonical entry (schedules and classes built).

    :param entry: a canonical entry (:func:`normalize_entry`)
    :param spec: the algorithm it configures
    """
    kwargs = {key: to_object(value, spec.params[key]) for key, value in entry.items() if key in spec.params}
    if POLICY_KWARGS_KEY in entry:
        policy_kwargs = entry[POLICY_KWARGS_KEY].items()
        kwargs[POLICY_KWARGS_KEY] = {key: to_object(value, spec.policy_params[key]) for key, value in policy_kwargs}
    return kwargs


def to_object(value: Any, hint: Any) -> Any:
    """:return: a canonical config value as its constructor takes it: RL Zoo's ``lin_<x>`` as SB3's
    ``LinearSchedule(x, 0, 1)`` (x at the start, decreasing linearly to 0 at the end of training), a class name as
    the class, a list as a tuple where the hint says ``tuple``."""
    for member in hint_members(hint):
        origin, arguments = typing.get_origin(member), typing.get_args(member)
        if isinstance(value, str) and origin is collections.abc.Callable:
            return LinearSchedule(float(value[4:]), 0.0, 1.0)
        if isinstance(value, str) and origin is type:
            return CLASS_NAMES[arguments[0]][value]
        if isinstance(value, list) and origin is tuple:
            return tuple(value)
    return value


def build_callbacks(entry: Mapping[str, Any], env_id: str, verbose: int, where: str) -> list[tuple[str, BaseCallback]]:
    """Make the callbacks of a canonical entry.

    An ``EvolutionCallback`` gets ``eval_env_id=eps_env_id_for(env_id)`` unless the entry sets it.

    :return: ``(canonical name, callback)`` pairs
    :raises ConfigError: when a constructor refuses its arguments
    """
    callbacks = []
    for item in entry.get(CALLBACK_KEY, []):
        name, kwargs = next(iter(item.items()))
        kwargs = dict(kwargs)
        if is_evolution(name):
            kwargs.setdefault("eval_env_id", eps_env_id_for(env_id))
            kwargs.setdefault("verbose", verbose)
        try:
            callbacks.append((name, callback_class(name, where)(**kwargs)))
        except (TypeError, ValueError) as error:
            raise ConfigError(f"{where}: callback {name}: {error}") from None
    return callbacks


# The package's own algorithms and callback, registered as a plug-in's would be (keys read from the signatures).
for _name, _class, _label in (
    ("iql", IQL, "IL"),
    ("gdq", GDQ, "GDQ"),
    ("qmix", QMIX, "QMIX"),
    ("vdn", VDN, "VDN"),
):
    register_algorithm(_name, _class, label=_label)
for _name, _class, _label in (("eps_iql", IQL, "EPS-IL"), ("eps_gdq", GDQ, "EPS-GDQ")):
    register_algorithm(_name, _class, label=_label, eps=True)
register_callback(EvolutionCallback, EVOLUTION_CALLBACK)
