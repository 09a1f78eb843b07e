"""Evolutionary Policy Search (Marchesini & Farinelli, ICRA 2022) as an SB3 callback, and its math."""

from sb3_eps.eps.callback import EvolutionCallback
from sb3_eps.eps.evaluation import (
    EvaluationFailed,
    InProcessEnvPool,
    PopulationForward,
    PopulationResult,
    SubprocessEnvPool,
    evaluate_population,
)
from sb3_eps.eps.mutations import (
    mutate_population,
    output_sensitivity,
    polyak_crossover_,
    safe_mutation_step,
    select_best,
)

__all__ = [
    "EvaluationFailed",
    "EvolutionCallback",
    "InProcessEnvPool",
    "PopulationForward",
    "PopulationResult",
    "SubprocessEnvPool",
    "evaluate_population",
    "mutate_population",
    "output_sensitivity",
    "polyak_crossover_",
    "safe_mutation_step",
    "select_best",
]
