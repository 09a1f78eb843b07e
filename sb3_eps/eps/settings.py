"""The settings of Evolutionary Policy Search: :class:`EPSSettings`, with :meth:`EPSSettings.paper` the published
method (Marchesini & Farinelli, ICRA 2022, Algorithm 1) and the package defaults what ``docs/results/eps_probes.md``
measured to work better."""

from __future__ import annotations

import copy
import dataclasses
import typing
from dataclasses import dataclass
from typing import Any, Literal

from sb3_eps.common.utils import check_arguments
from sb3_eps.eps.evaluation import FITNESS_KINDS, check_eval_env_id

Mutation = Literal["safe", "gaussian"]
PeriodUnit = Literal["episodes", "ticks"]
AlphaSchedule = Literal["constant", "linear"]
Fitness = Literal["return", "outcome"]
assert typing.get_args(Fitness) == FITNESS_KINDS
#: The intervals of :class:`EPSSettings`'s numbers (its type hints give the rest of its schema).
RANGES = {
    "population_size": "[1, inf)", "period": "[1, inf)", "n_eval_episodes": "[1, inf)", "alpha": "[0, 1]",
    "sensitivity_batch_size": "[1, inf)", "n_reevaluation_episodes": "[0, inf)",
    "sigma": "(0, inf)", "sensitivity_floor": "(0, inf)", "max_step": "(0, inf]", "n_workers": "[0, inf)",
    "eval_timeout": "(0, inf]", "target_flip_share": "(0, 1)", "min_gain": "[0, inf)", "rounds_until": "[1, inf)",
    "max_eps_share": "(0, inf]",
}  # fmt: skip
# Noise scales giving a mean |Q change| of about 5-10 % of |Q| on a mid-training GDQ robot network (measured); with
# a target_flip_share they are only the first scale the calibration tries.
DEFAULT_SIGMA = {"safe": 0.001, "gaussian": 0.03}
#: Algorithm 1 as the paper gives it: the settings :meth:`EPSSettings.paper` sets. The bars world is
#: ``SingleRobotNav-v0``'s default scenario.
PAPER_SETTINGS: dict[str, Any] = {
    "population_size": 10,
    "period": 100,
    "period_unit": "episodes",
    "alpha": 0.3,
    "alpha_schedule": "constant",
    "n_eval_episodes": 2,
    "target_flip_share": None,
    "frozen_groups": [],
    "fitness": "return",
    "min_gain": 0.0,
    "n_reevaluation_episodes": 0,
    "max_eps_share": None,
    "rounds_until": None,
    "eval_env_kwargs": {},
}
#: The single-agent world EPS evaluates in, for a world registered without one (by ``pettingzoo.register`` alone),
#: by training env id or by its family (the id up to its first "-"): ``EPS_WORLDS["LineWorld-2-v0"] =
#: "LineWorldSingle-v0"``. A world registered with ``envs.register(..., eps_world=...)`` names its own; the
#: project's worlds do so in their registrations (``envs/__init__.py``).
EPS_WORLDS: dict[str, str] = {}


def eps_env_id_for(env_id: str) -> str:
    """The single-agent id in which EPS evaluates the policies trained on ``env_id``: :data:`EPS_WORLDS`, else the
    ``eps_world`` of its registration.

    :param env_id: a registered id; a single-agent id maps to itself
    :raises ValueError: when the id is unknown or EPS has no world for it
    """
    from sb3_eps import worlds

    if not worlds.is_multi_agent(env_id):
        return env_id
    eps_env_id = EPS_WORLDS.get(env_id) or EPS_WORLDS.get(env_id.split("-")[0]) or worlds.eps_world(env_id)
    if eps_env_id is None:
        raise ValueError(
            f"EPS has no single-agent world for {env_id!r}: pass eval_env_id, or name one (envs.register(..., "
            "eps_world=...) or sb3_eps.eps.settings.EPS_WORLDS)"
        )
    return eps_env_id


def default_eval_env_kwargs(eval_env_id: str) -> dict[str, Any]:
    """The evaluation world's options when ``eval_env_kwargs`` is None: the ``eps_kwargs`` of its registration
    (``SingleRobotNav-v0``: the 4-robot arena's room with three robot-sized pillars, 400 ticks); other ids: ``{}``,
    their own defaults."""
    from sb3_eps import worlds

    return worlds.eps_kwargs(eval_env_id)


@dataclass
class EPSSettings:
    """What one EPS run does (``docs/modules/eps.md``; the defaults' evidence: ``docs/results/eps_probes.md``).

    :meth:`paper` is Algorithm 1 as published (:data:`PAPER_SETTINGS`); the defaults change what the measurements
    showed to go wrong.

    :param eval_env_id: the evaluation world: single-agent (:func:`eps_env_id_for`), or a multi-agent id where every
        robot acts with the individual's weights and fitness sees robot-robot collisions. Its per-agent spaces must
        equal the model's
    :param population_size: ``m``, the mutated copies; ``m + 1`` individuals are evaluated (paper: 10)
    :param period: the least number of ``period_unit`` between two rounds (``e_s`` of Algorithm 1)
    :param period_unit: ``"ticks"`` (world ticks summed over the worlds: ``model.ticks``) or ``"episodes"`` (the
        paper's epochs); a round starts at the first rollout end after ``period`` units (and within the budget)
    :param sigma: the noise scale ``G ~ N(0, sigma)``, or the calibration's first guess with ``target_flip_share``;
        None: :data:`DEFAULT_SIGMA` of the mutation
    :param alpha: share of the best individual in the crossover, Eq. 5, in [0, 1] (the paper found >= 0.4 harmful)
    :param alpha_schedule: ``"linear"``: ``alpha`` times the share of training still to come; ``"constant"``
    :param n_eval_episodes: common-random-number episodes per individual (paper: 2)
    :param mutation: ``"safe"`` (Eq. 6-normalised noise, the paper's operator) or ``"gaussian"`` (plain noise)
    :param target_flip_share: calibrate the noise scale each round so that the mutants change this share of the
        greedy actions on visited observations (:func:`~sb3_eps.eps.mutations.calibrate_scale`); None: fixed ``sigma``
    :param frozen_groups: parameter groups of ``q_net`` neither mutated nor crossed over; None: a dueling network's
        ``["value_stream"]``; ``[]``: every weight (paper)
    :param fitness: ``"outcome"`` (+1 reached / 0 timed out / -1 failed per episode, plus 0.01 x the return) or
        ``"return"`` (paper); :func:`~sb3_eps.eps.evaluation.population_fitness`
    :param min_gain: the winner's fitness must exceed copy 0's by more than this, in the selection and the
        reevaluation (0.05 is more than the outcome fitness's tie-break can give; paper: 0)
    :param n_reevaluation_episodes: play copy 0 and the winner again on this many fresh episodes (a multiple of
        ``n_eval_episodes``) and cross over only if the winner still wins by ``min_gain``: against the winner's
        curse. 0: no reevaluation (paper)
    :param max_eps_share: a round starts only if the EPS ticks so far plus its expected cost stay within this share
        of the training ticks; None: no budget. A run too short for one round warns once
        (:class:`~sb3_eps.eps.budget.RoundBudget`)
    :param rounds_until: no round starts after this many training world ticks (``model.ticks``): early rounds only,
        while single-robot skill lags the team's (``docs/results/eps.md``); None: rounds all run long
    :param sensitivity_batch_size: ``|b|``, visited observations sampled from the replay buffer for Eq. 6
    :param sensitivity_floor: lower bound on the sensitivity ``omega`` (Lehman et al.'s reference implementation)
    :param max_step: per-weight clip on the safe mutation's step (Lehman et al.); ``float("inf")`` disables it
    :param diagnostics_path: JSON-lines file of the per-round records; None: ``eps_rounds.jsonl`` in the logger's
        folder when it has one; ``""``: no file
    :param n_workers: evaluation worker processes; 0: the main process; None: one per core (at most one per
        individual)
    :param eval_timeout: seconds an evaluation round may take before its workers count as hung (the round is
        skipped, the workers restarted)
    :param eval_env_kwargs: constructor arguments of the evaluation env; None: :func:`default_eval_env_kwargs`;
        ``{}``: the env's own defaults (the bars world, paper)
    :param seed: seed of the noise, the buffer sampling and the evaluation episodes; None: from the model's seed
    """

    eval_env_id: str = "SingleRobotNav-v0"
    population_size: int = 5
    period: int = 10_000
    period_unit: PeriodUnit = "ticks"
    sigma: float | None = None
    alpha: float = 0.3
    alpha_schedule: AlphaSchedule = "linear"
    n_eval_episodes: int = 4
    mutation: Mutation = "safe"
    target_flip_share: float | None = 0.1
    frozen_groups: list[str] | None = None
    fitness: Fitness = "outcome"
    min_gain: float = 0.05
    n_reevaluation_episodes: int = 8
    max_eps_share: float | None = 0.1
    rounds_until: int | None = None
    sensitivity_batch_size: int = 128
    sensitivity_floor: float = 0.01
    max_step: float = 0.2
    diagnostics_path: str | None = None
    n_workers: int | None = None
    eval_timeout: float = 120.0
    eval_env_kwargs: dict[str, Any] | None = None
    seed: int | None = None

    def __post_init__(self) -> None:
        check_arguments(EPSSettings, dataclasses.asdict(self), RANGES)
        check_eval_env_id(self.eval_env_id)
        if self.sigma is None:
            self.sigma = DEFAULT_SIGMA[self.mutation]
        if self.frozen_groups is not None:
            self.frozen_groups = list(self.frozen_groups)
        if self.eval_env_kwargs is None:
            self.eval_env_kwargs = default_eval_env_kwargs(self.eval_env_id)
        self.eval_env_kwargs = copy.deepcopy(dict(self.eval_env_kwargs))

    @classmethod
    def paper(cls, **kwargs: Any) -> EPSSettings:
        """Algorithm 1 as published: :data:`PAPER_SETTINGS`, updated by ``kwargs`` (any field)."""
        return cls(**{**copy.deepcopy(PAPER_SETTINGS), **kwargs})

    @property
    def n_individuals(self) -> int:
        """``m + 1``: the mutants plus the unmutated copy 0."""
        return self.population_size + 1

    @property
    def n_reevaluation_batches(self) -> int:
        """Reevaluation batches of ``n_eval_episodes`` each (``n_reevaluation_episodes`` rounded up)."""
        return -(-self.n_reevaluation_episodes // self.n_eval_episodes)

    @property
    def most_episodes_per_round(self) -> int:
        """Every episode a round may play: selection and reevaluation (both individuals)."""
        return (self.n_individuals + 2 * self.n_reevaluation_batches) * self.n_eval_episodes
