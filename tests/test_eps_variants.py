"""The EPS variants a user picks in one line: each YAML config loads with the package's config reader and builds the
same ``EvolutionCallback`` as its one-line Python equivalent in the docs."""

from __future__ import annotations

from pathlib import Path

import pytest

from sb3_eps import EvolutionCallback
from sb3_eps.zoo.config import resolve_config
from sb3_eps.zoo.schema import EVOLUTION_CALLBACK, build_callbacks

CONFIGS = Path(__file__).resolve().parents[1] / "zoo_configs"
#: the early rounds' settings, as the configs' headers write them
EARLY_ROUNDS = {
    "period": 10_000,
    "rounds_until": 60_000,
    "max_eps_share": None,
    "population_size": 4,
    "n_eval_episodes": 2,
    "n_reevaluation_episodes": 2,
}
#: (config file or None for zoo_configs/eps_gdq.yml, env id, the Python equivalent)
VARIANTS = [
    (None, "MultiRobotNav-4-v0", lambda: EvolutionCallback()),
    (CONFIGS / "eps_gdq_paper.yml", "MultiRobotNav-4-v0", lambda: EvolutionCallback.paper()),
    (
        CONFIGS / "eps_gdq_early_rounds.yml",
        "MultiRobotNav-8-v0",
        lambda: EvolutionCallback(**EARLY_ROUNDS),
    ),
    (
        CONFIGS / "eps_gdq_team_world.yml",
        "MultiRobotNav-8-v0",
        lambda: EvolutionCallback(eval_env_id="MultiRobotNav-4-v0", **EARLY_ROUNDS),
    ),
    (CONFIGS / "eps_gdq_early_rounds.yml", "MultiRobotNav-12-v0", None),
]


@pytest.mark.parametrize(
    ("conf_file", "env_id", "python"),
    VARIANTS,
    ids=["defaults", "paper", "early_rounds", "team_world", "early_rounds_12"],
)
def test_a_variant_config_builds_its_python_equivalent(conf_file, env_id, python) -> None:
    config = resolve_config("eps_gdq", env_id, conf_file)
    assert config.entry["tuned"] is False  # no search produced any of them
    ((name, callback),) = build_callbacks(config.entry, env_id, 0, config.source)
    assert name == EVOLUTION_CALLBACK
    python = python or VARIANTS[2][2]  # the 12-robot entry has the 8-robot entry's callback
    assert callback.settings == python().settings


def test_early_rounds_stop_at_rounds_until() -> None:
    config = resolve_config("eps_gdq", "MultiRobotNav-8-v0", CONFIGS / "eps_gdq_early_rounds.yml")
    ((_, callback),) = build_callbacks(config.entry, "MultiRobotNav-8-v0", 0, config.source)
    assert callback.settings.rounds_until == 60_000 and callback.settings.max_eps_share is None
    assert config.entry["n_timesteps"] == 8 * 300_000 and config.entry["n_envs"] == 4
    config = resolve_config("eps_gdq", "MultiRobotNav-12-v0", CONFIGS / "eps_gdq_early_rounds.yml")
    assert config.entry["n_timesteps"] == 12 * 400_000  # the 12-robot screen's budget
