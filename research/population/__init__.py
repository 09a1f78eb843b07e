"""A population of learners (Population Based Training with EPS's safe mutation and a Q-filtered distillation
crossover; ``docs/modules/population.md``): research that was not found to help, kept outside the installed package.

- :class:`~research.population.trainer.PopulationTrainer`: ``k`` learners, the fittest copied over the weakest;
- :func:`~research.population.distillation.q_filtered_distillation`: the distillation crossover;
- :mod:`research.population.zoo`: the ``population:`` key of a config entry. Importing this package registers it, so
  ``python -m sb3_eps.train --gym-packages research.population -conf research/zoo_configs/gdq_population.yml ...`` trains one.
"""

from research.population.distillation import DistillationResult, q_filter, q_filtered_distillation
from research.population.trainer import PopulationTrainer
from research.population.zoo import POPULATION_KEY, run_population

__all__ = [
    "POPULATION_KEY",
    "DistillationResult",
    "PopulationTrainer",
    "q_filter",
    "q_filtered_distillation",
    "run_population",
]
