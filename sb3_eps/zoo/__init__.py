"""RL-Zoo-style configs and command lines: train, tune, evaluate, plot (``docs/usage.md``).

- :mod:`sb3_eps.zoo.config` / :mod:`sb3_eps.zoo.schema`: safe loading and checking of ``zoo_configs/*.yml``;
- :mod:`sb3_eps.zoo.exp_manager`: run folders, training, checkpoints and ``--resume``;
- :mod:`sb3_eps.zoo.tuning`: Optuna search; :mod:`sb3_eps.zoo.evaluation`, :mod:`sb3_eps.zoo.plotting`.

Plug-ins: a module named by ``--gym-packages`` registers its own worlds (``envs.register`` or
``pettingzoo.register``), algorithms (:func:`register_algorithm`), callbacks (:func:`register_callback`) and
trainers of their own behind an entry key (:func:`register_trainer`).
"""

from sb3_eps.zoo.config import ResolvedConfig, default_config_dir, load_config_entries, resolve_config
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.schema import ALGORITHMS, algorithm_spec, register_algorithm, register_callback, register_trainer

__all__ = [
    "ALGORITHMS",
    "ConfigError",
    "ResolvedConfig",
    "algorithm_spec",
    "default_config_dir",
    "load_config_entries",
    "register_algorithm",
    "register_callback",
    "register_trainer",
    "resolve_config",
]
