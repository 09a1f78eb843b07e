"""Loading ``zoo_configs/<algo>.yml`` files safely and resolving the entry of one env id.

A file maps env ids (and ``default``) to entries (schema: :mod:`sb3_eps.zoo.schema`). The entry of an env id is
the constructors' defaults (:func:`~sb3_eps.zoo.schema.package_defaults`), then its ``default`` entry updated key by
key (a shallow merge) with the env id's own entry, then with the command line's
``--hyperparams key:value`` overrides (``policy_kwargs.net_arch:[64]``, ``env_kwargs.<arg>:...``,
``<trainer key>.<setting>:...`` and ``callback.<arg>:...`` update one item of a mapping) and ``-n``. YAML is read
with a safe loader that also refuses duplicate keys; nothing is executed.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.callbacks import BaseCallback

from sb3_eps import worlds
from sb3_eps.common.ladder import Rung
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.subproc_vec_env import overlap_layout
from sb3_eps.common.vec_env import MultiAgentVecEnv, make_vec_env, vec_env_mode
from sb3_eps.zoo.cli import TrainOptions
from sb3_eps.zoo.errors import ConfigError, allowed
from sb3_eps.zoo.schema import (
    CALLBACK_KEY,
    TRAINERS,
    AlgorithmSpec,
    algorithm_spec,
    check_complete,
    normalize_entry,
    normalize_value,
    with_package_defaults,
)

DEFAULT_KEY = "default"
#: Environment variable naming a folder of config files to use instead of the shipped ``zoo_configs/``.
CONFIG_DIR_VARIABLE = "SB3_EPS_CONFIG_DIR"
_MAPPING_KEYS = ("policy_kwargs", "env_kwargs")


@dataclass
class ResolvedConfig:
    """The configuration of one run: ``entry`` is canonical (defaults merged, overrides applied), ``source`` says
    where it came from, for messages and ``config.yml``."""

    algo: str
    env_id: str
    entry: dict[str, Any]
    source: str

    @property
    def spec(self) -> AlgorithmSpec:
        """The algorithm's spec."""
        return algorithm_spec(self.algo)


def default_config_dir() -> Path:
    """The folder of the shipped configs: ``$SB3_EPS_CONFIG_DIR``, the repository's ``zoo_configs/`` (editable
    installs), or ``<prefix>/share/sb3-eps/zoo_configs`` (installed as data files)."""
    if os.environ.get(CONFIG_DIR_VARIABLE):
        return Path(os.environ[CONFIG_DIR_VARIABLE])
    repository = Path(__file__).resolve().parents[2] / "zoo_configs"
    if repository.is_dir():
        return repository
    return Path(sys.prefix) / "share" / "sb3-eps" / "zoo_configs"


def config_file(algo: str, conf_file: str | Path | None = None) -> Path:
    """:return: ``conf_file`` or the shipped file of ``algo``. :raises ConfigError: when it does not exist."""
    algorithm_spec(algo)
    path = Path(conf_file) if conf_file is not None else default_config_dir() / f"{algo}.yml"
    if not path.is_file():
        raise ConfigError(f"config file {path} does not exist; pass an existing file with -conf")
    return path


class _SafeUniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader that refuses a key given twice in one mapping (PyYAML keeps the last silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        self.flatten_mapping(node)  # resolves "<<" merge keys first, which may repeat keys on purpose
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                line = key_node.start_mark.line + 1
                raise ConfigError(f"line {line}: the key {key!r} is given twice in one mapping")
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file with the safe loader.

    :raises ConfigError: for a missing file, invalid YAML, a duplicate key or a tag that would build an object
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(f"cannot read {path}: {error.strerror}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path} is not a text file (binary content); pass a YAML config") from None
    try:
        return yaml.load(text, Loader=_SafeUniqueKeyLoader)  # a SafeLoader subclass
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(error, "problem", None) or str(error)
        tagged = isinstance(error, yaml.constructor.ConstructorError)
        tags = "; configs are read as plain data (no Python tags)" if tagged else ""
        raise ConfigError(f"{path}: not valid YAML: {where}{problem}{tags}") from None


def load_config_entries(path: str | Path, algo: str) -> dict[str, dict[str, Any]]:
    """Read a config file and check every entry.

    :param path: the YAML file
    :param algo: the algorithm it configures
    :return: env id (or ``default``) -> canonical entry as written (not merged with ``default``)
    :raises ConfigError: for any problem, naming the file and the key
    """
    spec = algorithm_spec(algo)
    data = load_yaml(path)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{path}: the file must map env ids (and 'default') to entries, got {type(data).__name__}")
    entries: dict[str, dict[str, Any]] = {}
    for env_id, entry in data.items():
        if env_id != DEFAULT_KEY and not (isinstance(env_id, str) and worlds.is_registered(env_id)):
            keys = [DEFAULT_KEY, *worlds.env_ids()]
            raise ConfigError(
                f"{path}: unknown env id {env_id!r}; allowed keys: {allowed(keys)} (or an id that a --gym-packages "
                "module registers)"
            )
        entries[env_id] = normalize_entry(entry, spec, f"{path}: entry {env_id!r}")
    return entries


def merged_entry(entries: Mapping[str, dict[str, Any]], env_id: str, path: str | Path) -> dict[str, Any]:
    """The entry of ``env_id``: ``default`` updated with the env id's own entry.

    :raises ConfigError: when the file has neither
    """
    if env_id not in entries and DEFAULT_KEY not in entries:
        raise ConfigError(f"{path} has no entry for {env_id!r} and no 'default' entry; its entries: {allowed(entries)}")
    return {**entries.get(DEFAULT_KEY, {}), **entries.get(env_id, {})}


def resolve_config(
    algo: str,
    env_id: str,
    conf_file: str | Path | None = None,
    hyperparams: Sequence[str] = (),
    n_timesteps: int | None = None,
) -> ResolvedConfig:
    """The configuration of a run: file entry, then ``--hyperparams`` overrides, then ``-n``.

    :param algo: algorithm name
    :param env_id: a registered env id
    :param conf_file: a config file (default: the shipped ``zoo_configs/<algo>.yml``)
    :param hyperparams: ``key:value`` overrides (values in YAML syntax; dotted keys update a mapping)
    :param n_timesteps: total SB3 timesteps (agent-steps), overriding the entry's
    :raises ConfigError: for any mistake, in one line
    """
    spec = algorithm_spec(algo)
    check_env_id(env_id)
    path = config_file(algo, conf_file)
    entry = with_package_defaults(merged_entry(load_config_entries(path, algo), env_id, path), spec)
    source = f"{path}: entry {env_id!r}"
    if hyperparams:
        entry = apply_overrides(entry, parse_hyperparams(hyperparams), spec)
        source += " with --hyperparams " + " ".join(hyperparams)
    if n_timesteps is not None:
        entry["n_timesteps"] = normalize_value(n_timesteps, int, "-n (total timesteps, agent-steps)", "n_timesteps")
    check_complete(entry, spec, source)
    return ResolvedConfig(algo, env_id, entry, source)


def check_env_id(env_id: str, flag: str = "--env") -> None:
    """:raises ConfigError: when ``env_id`` is not registered (listing the ids)."""
    if not worlds.is_registered(env_id):
        raise ConfigError(
            f"{flag}: unknown env id {env_id!r}; allowed: {allowed(worlds.env_ids())} (or an id that a --gym-packages "
            "module registers)"
        )


def parse_hyperparams(items: Sequence[str]) -> list[tuple[tuple[str, ...], Any]]:
    """Parse ``key:value`` overrides; values are YAML (``1e-4``, ``[64, 64]``, ``"dict(net_arch=[64])"``).

    :return: ``(key path, value)`` pairs, e.g. ``(("policy_kwargs", "net_arch"), [64])``
    :raises ConfigError: for an item without ``:`` or a value that is not valid YAML
    """
    overrides = []
    for item in items:
        key, separator, text = item.partition(":")
        if not separator or not key.strip():
            raise ConfigError(f"--hyperparams: {item!r} is not key:value (e.g. learning_rate:1e-4)")
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError:
            raise ConfigError(f"--hyperparams: the value of {key!r} is not valid YAML: {text!r}") from None
        path = tuple(part.strip() for part in key.split("."))
        mappings = (*_MAPPING_KEYS, *TRAINERS)
        if len(path) > 2 or (len(path) == 2 and path[0] not in (*mappings, CALLBACK_KEY)):
            raise ConfigError(
                f"--hyperparams: {key!r}: only {allowed(mappings)} and callback take a dotted key "
                "(e.g. policy_kwargs.net_arch:[64])"
            )
        overrides.append((path, value))
    return overrides


def apply_overrides(
    entry: dict[str, Any],
    overrides: Sequence[tuple[tuple[str, ...], Any]],
    spec: AlgorithmSpec,
    where: str = "--hyperparams",
) -> dict[str, Any]:
    """Apply parsed ``--hyperparams`` (or a trial's overrides) to a canonical entry; every override is checked on
    its own first.

    :return: the new canonical entry
    """
    result = {key: (dict(value) if isinstance(value, dict) else value) for key, value in entry.items()}
    for path, value in overrides:
        if len(path) == 1:
            result.update(normalize_entry({path[0]: value}, spec, where))
        elif path[0] == CALLBACK_KEY:
            callbacks = result.get(CALLBACK_KEY, [])
            if len(callbacks) != 1:
                raise ConfigError(f"{where}: callback.{path[1]} needs exactly one callback in the entry")
            name, kwargs = next(iter(callbacks[0].items()))
            checked = normalize_entry({CALLBACK_KEY: [{name: {path[1]: value}}]}, spec, where)
            result[CALLBACK_KEY] = [{name: {**kwargs, **checked[CALLBACK_KEY][0][name]}}]
        else:
            checked = normalize_entry({path[0]: {path[1]: value}}, spec, where)
            result[path[0]] = {**result.get(path[0], {}), **checked[path[0]]}
    return normalize_entry(result, spec, where)


class _EntryDumper(yaml.SafeDumper):
    """Safe YAML writer with lists of scalars in flow style (``net_arch: [128, 64]``), mappings as blocks."""

    def represent_list(self, data: list[Any]) -> yaml.Node:
        flow = all(not isinstance(item, dict | list) for item in data)
        return self.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_EntryDumper.add_representer(list, _EntryDumper.represent_list)


def entry_yaml(env_id: str, entry: Mapping[str, Any], header: str = "") -> str:
    """:return: ``{env_id: entry}`` as YAML that ``-conf`` reads back (with ``header`` as comment lines)."""
    body = yaml.dump({env_id: dict(entry)}, Dumper=_EntryDumper, sort_keys=False, width=110)
    comments = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    return comments + body


@dataclass
class PreparedRun:
    """Everything of a run built and checked, before any file is written."""

    options: TrainOptions
    config: ResolvedConfig
    env: MultiAgentVecEnv
    eval_env: MultiAgentVecEnv | None
    model: MultiAgentOffPolicyAlgorithm
    user_callbacks: list[tuple[str, BaseCallback]]
    # a ladder run's worlds (sb3_eps.zoo.ladder), the first is env
    rungs: list[Rung] = field(default_factory=list)

    def close(self) -> None:
        """Close the envs."""
        close_envs([self.env, self.eval_env, *(rung.env for rung in self.rungs)])


def close_envs(vec_envs: Sequence[Any]) -> None:
    """Close each of ``vec_envs`` once (None and repeats skipped)."""
    for vec_env in {id(vec_env): vec_env for vec_env in vec_envs if vec_env is not None}.values():
        vec_env.close()


def build_env(
    config: ResolvedConfig,
    seed: int | None,
    env_id: str | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
) -> MultiAgentVecEnv:
    """Make the vector env of a config (``env_id`` / ``n_envs`` override the config's, for evaluation worlds;
    ``vec_env``, ``"dummy"`` or ``"subproc"``, the config's ``vec_env``). The training worlds of a config with
    ``overlap_training`` in workers all go to workers (:func:`~sb3_eps.common.subproc_vec_env.overlap_layout`).

    :raises ConfigError: when the env refuses the config's ``env_kwargs``
    """
    env_id = env_id or config.env_id
    n_worlds = n_envs or config.entry.get("n_envs", 1)
    env_kwargs = dict(config.entry.get("env_kwargs", {}))
    try:
        mode = vec_env_mode(vec_env or config.entry.get("vec_env"))
        vec_env_kwargs = None
        if mode == "subproc" and n_envs is None and config.entry.get("overlap_training"):
            # the training worlds: the main process learns beside them
            vec_env_kwargs = overlap_layout(n_worlds)
        return make_vec_env(
            env_id, n_envs=n_worlds, seed=seed, env_kwargs=env_kwargs, vec_env_cls=mode,
            vec_env_kwargs=vec_env_kwargs,
        )  # fmt: skip
    except (TypeError, ValueError) as error:
        raise ConfigError(f"{config.source}: env_kwargs {env_kwargs} for {env_id}: {error}") from None
