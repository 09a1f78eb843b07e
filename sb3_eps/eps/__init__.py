"""Evolutionary Policy Search (Marchesini & Farinelli, ICRA 2022) as an SB3 callback, and its math."""

from sb3_eps.eps.callback import EvolutionCallback
from sb3_eps.eps.evaluation import (
    EnvPool,
    EvaluationFailed,
    InProcessEnvPool,
    PopulationForward,
    PopulationResult,
    SubprocessEnvPool,
    evaluate_population,
    population_fitness,
)
from sb3_eps.eps.mutations import (
    calibrate_scale,
    mutate_population,
    output_sensitivity,
    policy_change,
    polyak_crossover_,
    safe_mutation_step,
    select_best,
)
from sb3_eps.eps.round import sample_visited_observations
from sb3_eps.eps.round_log import RoundLog, read_round_log
from sb3_eps.eps.settings import EPS_WORLDS, PAPER_SETTINGS, EPSSettings, eps_env_id_for

__all__ = [
    "EPS_WORLDS",
    "PAPER_SETTINGS",
    "EPSSettings",
    "EnvPool",
    "EvaluationFailed",
    "EvolutionCallback",
    "InProcessEnvPool",
    "PopulationForward",
    "PopulationResult",
    "RoundLog",
    "SubprocessEnvPool",
    "calibrate_scale",
    "eps_env_id_for",
    "evaluate_population",
    "mutate_population",
    "output_sensitivity",
    "policy_change",
    "polyak_crossover_",
    "population_fitness",
    "read_round_log",
    "safe_mutation_step",
    "sample_visited_observations",
    "select_best",
]
