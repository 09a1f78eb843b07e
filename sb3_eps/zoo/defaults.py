"""The package defaults as config entries, and a tool that keeps the ``default:`` entries of ``zoo_configs/`` equal
to them.

``python -m sb3_eps.zoo.defaults --check`` exits with status 1 (listing the differences) when a ``default:``
entry differs from the constructors' defaults; without ``--check`` it rewrites those entries in place (the rest
of each file, comments included, is left as it is). ``tests/test_zoo_configs.py`` runs the check.
"""

from __future__ import annotations

import argparse
import inspect
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_eps.zoo.config import DEFAULT_KEY, config_file, entry_yaml, load_config_entries
from sb3_eps.zoo.schema import (
    ALGORITHM_PARAMS,
    ALGORITHMS,
    CALLBACK_KEY,
    EVOLUTION_CALLBACK,
    POLICY_KWARGS_KEY,
    callback_class,
    callback_parameters,
)

#: EvolutionCallback arguments the ``eps_*`` files list (the others keep their defaults silently).
EPS_LISTED_ARGUMENTS = (
    "population_size",
    "period",
    "period_unit",
    "sigma",
    "alpha",
    "alpha_schedule",
    "n_eval_episodes",
    "mutation",
    "target_flip_share",
    "frozen_groups",
    "fitness",
    "min_gain",
    "n_reevaluation_episodes",
    "max_eps_share",
    "sensitivity_batch_size",
    "sensitivity_floor",
    "max_step",
    "per_robot",
    "n_team_check_episodes",
    "eval_env_kwargs",
)
# Run keys of the default entries (not package defaults: a budget and the number of worlds of make_vec_env).
_RUN_DEFAULTS = {"tuned": False, "notes": "package defaults (docs/modules/common.md)", "n_timesteps": 800_000}


def _signature_defaults(function: Any) -> dict[str, Any]:
    return {
        name: parameter.default
        for name, parameter in inspect.signature(function).parameters.items()
        if parameter.default is not inspect.Parameter.empty
    }


GDQ_EXTRA_POLICY_DEFAULTS = ("global_init", "global_bootstrap", "global_values")


def package_policy_kwargs(algo: str) -> dict[str, Any]:
    """:return: the policy defaults of an algorithm as canonical ``policy_kwargs`` (``None`` sizes resolved)."""
    from sb3_eps.common.policies import DEFAULT_NET_ARCH, DEFAULT_STREAM_ARCH, MultiAgentQPolicy
    from sb3_eps.gdq.policies import DEFAULT_GLOBAL_NET_ARCH

    spec = ALGORITHMS[algo]
    policy_class = spec.algorithm_class.policy_aliases["MlpPolicy"]
    defaults = {
        **_signature_defaults(MultiAgentQPolicy.__init__),
        **_signature_defaults(policy_class.__init__),
    }
    fallbacks = {
        "net_arch": DEFAULT_NET_ARCH,
        "stream_arch": DEFAULT_STREAM_ARCH,
        "global_net_arch": DEFAULT_GLOBAL_NET_ARCH,
    }
    result: dict[str, Any] = {
        "net_arch": list(defaults["net_arch"] or fallbacks["net_arch"]),
        "stream_arch": list(defaults["stream_arch"] or fallbacks["stream_arch"]),
        "activation_fn": f"nn.{defaults['activation_fn'].__name__}",
        "agent_target": bool(spec.algorithm_class.default_agent_target),
    }
    for name in spec.policy_params:
        if name in GDQ_EXTRA_POLICY_DEFAULTS or name in (
            "global_net_arch",
            "mixing_embed_dim",
            "hypernet_hidden_dim",
            "mixer_init",
            "mixer_lr_scale",
        ):
            value = defaults[name]
            result[name] = list(value or fallbacks[name]) if name == "global_net_arch" else value
    return result


def config_value(value: Any) -> Any:
    """A constructor default as a config value: SB3's ``LinearSchedule(x, 0, 1)`` is RL Zoo's ``lin_<x>``."""
    from stable_baselines3.common.utils import LinearSchedule

    if isinstance(value, LinearSchedule):
        if value.end != 0.0 or value.end_fraction != 1.0:
            raise ValueError(f"a default {value!r} has no config form: only lin_<x> (x -> 0 over training) has")
        return f"lin_{value.start}"
    return value


def package_default_entry(algo: str) -> dict[str, Any]:
    """:return: the canonical ``default:`` entry of ``zoo_configs/<algo>.yml`` made from the package defaults."""
    from sb3_eps.common.vec_env import make_vec_env

    spec = ALGORITHMS[algo]
    algorithm_defaults = _signature_defaults(spec.algorithm_class.__init__)
    entry: dict[str, Any] = {
        **_RUN_DEFAULTS,
        "policy": "MlpPolicy",
        "n_envs": _signature_defaults(make_vec_env)["n_envs"],
    }
    entry.update((name, config_value(algorithm_defaults[name])) for name in ALGORITHM_PARAMS)
    entry[POLICY_KWARGS_KEY] = package_policy_kwargs(algo)
    if spec.eps:
        parameters = callback_parameters(callback_class(EVOLUTION_CALLBACK))
        arguments = {name: parameters[name].default for name in EPS_LISTED_ARGUMENTS}
        entry[CALLBACK_KEY] = [{EVOLUTION_CALLBACK: arguments}]
    return entry


def differences(algo: str, path: str | Path | None = None) -> list[str]:
    """:return: one line per key where the file's ``default:`` entry differs from the package defaults."""
    path = config_file(algo, path)
    written = load_config_entries(path, algo).get(DEFAULT_KEY, {})
    expected = package_default_entry(algo)
    lines = []
    for key, value in expected.items():
        if key in _RUN_DEFAULTS:
            continue
        if written.get(key) != value:
            lines.append(f"{path}: default {key}: file {written.get(key)!r}, package {value!r}")
    return lines


def _zoo_string(policy_kwargs: dict[str, Any]) -> str:
    """``policy_kwargs`` in RL Zoo's ``dict(...)`` form (class names unquoted)."""
    parts = [
        f"{key}={value if key == 'activation_fn' else repr(value)}" for key, value in policy_kwargs.items()
    ]
    return f"dict({', '.join(parts)})"


def rewrite_default(algo: str, path: str | Path | None = None) -> bool:
    """Replace the ``default:`` block of a config file (up to its first blank line) with the package defaults,
    keeping the file's run keys (``tuned``, ``notes``, ``n_timesteps``). :return: whether the file changed."""
    path = config_file(algo, path)
    text = path.read_text()
    match = re.search(r"^default:\n(?:.+\n)*", text, flags=re.MULTILINE)
    if match is None:
        raise ValueError(f"{path} has no 'default:' block to rewrite")
    written = load_config_entries(path, algo).get(DEFAULT_KEY, {})
    entry = package_default_entry(algo)
    entry.update((key, written[key]) for key in _RUN_DEFAULTS if key in written)
    block = entry_yaml(DEFAULT_KEY, entry)
    block = re.sub(
        r"^  policy_kwargs:\n(?:    .+\n)+",
        f'  policy_kwargs: "{_zoo_string(entry[POLICY_KWARGS_KEY])}"\n',
        block,
        flags=re.MULTILINE,
    )
    new_text = text[: match.start()] + block + text[match.end() :]
    if new_text != text:
        path.write_text(new_text)
    return new_text != text


def main(argv: Sequence[str] | None = None) -> int:
    """Check (``--check``) or rewrite the ``default:`` entries. :return: the exit status."""
    parser = argparse.ArgumentParser(prog="python -m sb3_eps.zoo.defaults", description=__doc__)
    parser.add_argument("--check", action="store_true", help="only report differences (exit 1 if any)")
    args = parser.parse_args(argv)
    if args.check:
        lines = [line for algo in ALGORITHMS for line in differences(algo)]
        print("\n".join(lines) if lines else "zoo_configs default entries equal the package defaults")
        return 1 if lines else 0
    for algo in ALGORITHMS:
        if rewrite_default(algo):
            print(f"rewrote the default entry of {config_file(algo)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
