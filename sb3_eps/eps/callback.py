"""``EvolutionCallback``: Evolutionary Policy Search (Marchesini & Farinelli, ICRA 2022, Algorithm 1) as an SB3
callback on any model with a shared agent network ``model.policy.q_net`` and a replay buffer."""

from __future__ import annotations

import copy
import os
import time
import warnings
import weakref
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from torch import nn

from sb3_eps.eps.diagnostics import DIAGNOSTICS_NAME, RoundLog
from sb3_eps.eps.evaluation import (
    FITNESS_KINDS,
    EnvPool,
    EvaluationFailed,
    InProcessEnvPool,
    PopulationResult,
    SubprocessEnvPool,
    agent_space,
    check_eval_env_id,
    evaluate_population,
    make_eval_env,
    population_fitness,
)
from sb3_eps.eps.mutations import (
    Parameters,
    calibrate_scale,
    evolved_parameter_names,
    finite_individuals,
    individual,
    mutation_directions,
    network_parameters,
    output_sensitivity,
    policy_change,
    polyak_crossover_,
    population_from_directions,
    population_outputs,
    select_best,
)
from sb3_eps.eps.sharing import (
    record_mode,
    rollout_gradient_steps,
    share_episodes,
    shared_gradient_steps,
    sharing_problem,
    train_on_shared,
)

MUTATIONS = ("safe", "gaussian")
# Noise scales giving a mean |Q change| of about 5-10 % of |Q| on a mid-training GDQ robot network (measured); with
# a target_flip_share they are only the first scale the calibration tries.
DEFAULT_SIGMA = {"safe": 0.001, "gaussian": 0.03}
PERIOD_UNITS = ("episodes", "ticks")
ALPHA_SCHEDULES = ("constant", "linear")
#: Algorithm 1 as the paper gives it (and this package's EPS before issue 10's measurements): the arguments
#: :meth:`EvolutionCallback.paper` sets. The bars world is ``SingleRobotNav-v0``'s default scenario.
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
    "eval_env_kwargs": {},
}
#: The evaluation world's options when ``eval_env_kwargs`` is None, by evaluation env id: the default EPS world
#: drops the thin bars the training worlds never show and puts three robot-sized pillars in the 4-robot arena's
#: room, with a 400-tick limit (docs/results/eps_probes.md). Other ids: their own defaults.
DEFAULT_EVAL_ENV_KWARGS: dict[str, dict[str, Any]] = {
    "SingleRobotNav-v0": {"scenario": "eps_pillars", "max_episode_steps": 400},
}
#: The dueling network's state-value stream: greedy actions (hence fitness) never see it, GDQ feeds it to V_G'.
VALUE_STREAM = "value_stream"


class EvolutionCallback(BaseCallback):
    """Evolutionary Policy Search (EPS; Marchesini & Farinelli, "Enhancing Deep Reinforcement Learning
    Approaches for Multi-Robot Navigation via Single-Robot Evolutionary Policy Search", ICRA 2022, Algorithm 1).

    A round, at the end of a rollout (before the gradient steps): copy the shared agent network
    ``model.policy.q_net`` ``population_size + 1`` times; mutate all copies but copy 0 with Gaussian noise
    normalised by the output-gradient sensitivity of Eq. 6 (computed on visited observations from the replay
    buffer); evaluate every copy greedily for ``n_eval_episodes`` common-random-number episodes in independent
    single-agent worlds; pick the best (Eq. 4) and move the agent network (and its target network, if any) toward it
    by Polyak averaging (Eq. 5). When the unmutated copy 0 wins nothing changes. See ``docs/modules/eps.md``.

    :meth:`EvolutionCallback.paper` is Algorithm 1 as published (:data:`PAPER_SETTINGS`: fixed noise scale, every
    weight mutated, mean return as fitness, any gain accepted, a round every 100 episodes, the bars world). The
    defaults change what the measurements of ``docs/results/eps_probes.md`` showed to go wrong: the
    mutation size is calibrated each round to change ``target_flip_share`` of the greedy actions on visited states;
    the value stream is neither mutated nor crossed over; fitness ranks reaching the target above the shaped return
    and waiting above crashing; the winner must beat copy 0 again on fresh episodes; alpha decays to 0 by the end of
    training; rounds come by ticks and only while EPS has spent at most ``max_eps_share`` of the training ticks; the
    evaluation world is the training arena's room with robot-sized pillars.

    :param eval_env_id: the evaluation world: single-agent (``"SingleRobotNav-v0"`` for the robots,
        ``"CooperativeNavigationSingle-v0"`` for Cooperative Navigation; see ``envs.eps_env_id_for``), or a
        multi-agent id (a team world, e.g. ``"MultiRobotNav-4-v0"``: every robot acts with the individual's
        weights, as in training, and fitness sees robot-robot collisions; an episode's ticks are world ticks, the
        unit of the training ticks). Its (per-agent) observation and action spaces must equal the model's.
    :param population_size: ``m``, the number of mutated copies; ``m + 1`` individuals are evaluated. Default 5
        (paper: 10, the author's earlier evolutionary work)
    :param period: the least number of ``period_unit`` between two rounds (``e_s`` of Algorithm 1). Default 10,000
        ticks; the budget ``max_eps_share`` usually spaces the rounds further
    :param period_unit: ``"ticks"`` (simulator steps of one world, summed over the worlds: ``model.ticks``) or
        ``"episodes"`` (world episodes, the paper's epochs). A round starts at the first rollout end after ``period``
        units since the previous round (and within the budget)
    :param sigma: the noise scale ``G ~ N(0, sigma)``. With ``target_flip_share`` it is only the calibration's first
        guess (later rounds start from the previous round's scale). Default None: 0.001 for ``mutation="safe"``,
        0.03 for ``"gaussian"``
    :param alpha: share of the best individual in the crossover, Eq. 5, in [0, 1]. Default 0.3 (the paper found
        alpha >= 0.4 harmful), decaying under ``alpha_schedule``
    :param alpha_schedule: ``"linear"`` (default): ``alpha`` times the share of training still to come
        (``model._current_progress_remaining``), so crossovers fade out before the final evaluations;
        ``"constant"``: always ``alpha``
    :param n_eval_episodes: common-random-number episodes per individual. Default 4 (paper settings: 2)
    :param mutation: ``"safe"`` (Eq. 6-normalised noise, the paper's operator) or ``"gaussian"`` (plain noise)
    :param target_flip_share: calibrate the noise scale each round so that the mutants change on average this share
        of the greedy actions on the visited observations of the sensitivity batch (:func:`calibrate_scale`);
        None keeps the fixed ``sigma``. Default 0.1
    :param frozen_groups: parameter groups (module or parameter names of ``q_net``) neither mutated nor crossed
        over. Default None: the value stream of a dueling network (``["value_stream"]``), nothing for other networks;
        ``[]`` evolves every weight (paper)
    :param fitness: ``"outcome"`` (default: mean of +1 reached / 0 timed out / -1 failed per episode, plus 0.01 x
        the mean return) or ``"return"`` (the paper's mean return); see :func:`population_fitness`
    :param min_gain: the winner's fitness must exceed copy 0's by more than this, in the selection and in the
        reevaluation. Default 0.05: with ``fitness="outcome"`` more than the return's tie-break can give (0.01 x a
        few units of return), so at least one episode must end better on balance; 0 accepts any gain (paper)
    :param n_reevaluation_episodes: before a crossover, play copy 0 and the winner again on this many fresh
        common-random-number episodes (rounded up to a multiple of ``n_eval_episodes``) and cross over only if the
        winner beats copy 0 by more than ``min_gain`` there too; the ticks count as EPS ticks. Against the winner's
        curse: the best of ``m + 1`` noisy scores wins by chance (docs/results/eps_probes.md). Default 8; 0: no
        reevaluation (paper)
    :param max_eps_share: a round starts only if the EPS ticks so far plus the expected cost of the round stay
        within this share of the training ticks (default 0.1; None: no budget). The expected cost is every episode a
        round may play (selection, reevaluation, team checks) at the previous round's mean episode length, or before
        the first round half of the most the round can cost
    :param sensitivity_batch_size: ``|b|``, visited observations (alive agents' entries) sampled from the replay
        buffer for Eq. 6, the calibration and the diagnostics. Default 128
    :param sensitivity_floor: lower bound on the sensitivity ``omega`` (a sensitivity of exactly 0 counts as 1).
        Default 0.01, as in Lehman et al.'s reference implementation
    :param max_step: per-weight clip on the safe mutation's step. Default 0.2, Lehman et al.'s value;
        ``float("inf")`` disables it. Not applied to ``mutation="gaussian"``
    :param n_team_check_episodes: greedy episodes of the multi-robot training env (``model.get_env().env_id``)
        played before and after every crossover, with the same seeds, to see what the crossover did to the team;
        their ticks count as EPS ticks. Default 0: no check
    :param diagnostics_path: JSON-lines file of the per-round records (``history``). Default None: ``eps_rounds.jsonl``
        in the logger's folder when it has one (the run folder of ``python -m sb3_eps.train``, or SB3's
        ``tensorboard_log`` run folder), else no file; ``""`` writes none
    :param n_workers: evaluation worker processes; 0 evaluates in the main process. Default None: one per CPU core
        (at most one per individual)
    :param eval_timeout: seconds a whole evaluation round may take before its workers count as hung; the round is
        then skipped and the workers restarted. Default 120
    :param batched_forward: one ``vmap``-ed ``functional_call`` per tick for a block of individuals (default True)
    :param per_robot: normalise mutant ``i`` by the sensitivity computed on robot ``i % n_agents``'s own visited
        observations (paper III-B's "individual experiences"). Needs ``mutation="safe"``
    :param eval_env_kwargs: constructor arguments of the evaluation env. Default None: the world of
        :data:`DEFAULT_EVAL_ENV_KWARGS` (robot-sized pillars for ``SingleRobotNav-v0``); ``{}``: the env's own
        defaults (the bars world, paper)
    :param worker_start_method: multiprocessing start method of the workers; None: ``"fork"`` where available
    :param seed: seed of the noise, the buffer sampling and the evaluation episodes; None: derived from the
        model's seed (a seeded model gives a reproducible EPS), or random when the model has none
    :param share_experience: write every tick of every evaluation episode (all individuals, the reevaluation
        episodes too) into the model's replay buffer, as a training world's tick is written (Evolutionary RL,
        Khadka & Tumer, NeurIPS 2018: the population's transitions feed the RL agent's replay buffer). Needs a team
        world whose agents are the training worlds' (same agent count, spaces and global-state size) and one of
        this package's algorithms. Default False
    :param train_on_shared_rows: with ``share_experience``, take the gradient steps the training rollout would take
        for the round's shared ticks (:func:`~sb3_eps.eps.sharing.shared_gradient_steps`), as Evolutionary RL trains
        on the population's steps, spread over the next rollouts (at most as many extra steps per rollout as its own):
        the shared rows are then learned from as training rows are, not only sampled among them. Needs
        ``train_freq`` in steps. Default False (the training's gradient steps as they are): screened on 4 robots, it
        did not end higher than sharing alone (docs/results/eps.md)
    :param verbose: 0 silent, 1 one line per round, 2 also worker restarts
    """

    def __init__(
        self,
        eval_env_id: str = "SingleRobotNav-v0",
        population_size: int = 5,
        period: int = 10_000,
        period_unit: str = "ticks",
        sigma: float | None = None,
        alpha: float = 0.3,
        alpha_schedule: str = "linear",
        n_eval_episodes: int = 4,
        mutation: str = "safe",
        target_flip_share: float | None = 0.1,
        frozen_groups: list[str] | None = None,
        fitness: str = "outcome",
        min_gain: float = 0.05,
        n_reevaluation_episodes: int = 8,
        max_eps_share: float | None = 0.1,
        sensitivity_batch_size: int = 128,
        sensitivity_floor: float = 0.01,
        max_step: float = 0.2,
        n_team_check_episodes: int = 0,
        diagnostics_path: str | None = None,
        n_workers: int | None = None,
        eval_timeout: float = 120.0,
        batched_forward: bool = True,
        per_robot: bool = False,
        eval_env_kwargs: dict[str, Any] | None = None,
        worker_start_method: str | None = None,
        seed: int | None = None,
        share_experience: bool = False,
        train_on_shared_rows: bool = False,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose=verbose)
        for name, flag in (("share_experience", share_experience), ("train_on_shared_rows", train_on_shared_rows)):
            if not isinstance(flag, bool):
                raise ValueError(f"{name} must be True or False, got {flag!r}")
        _check_arguments(
            population_size=population_size, period=period, period_unit=period_unit, sigma=sigma, alpha=alpha,
            alpha_schedule=alpha_schedule, n_eval_episodes=n_eval_episodes, mutation=mutation,
            target_flip_share=target_flip_share, frozen_groups=frozen_groups, fitness=fitness, min_gain=min_gain,
            n_reevaluation_episodes=n_reevaluation_episodes, max_eps_share=max_eps_share,
            sensitivity_batch_size=sensitivity_batch_size, sensitivity_floor=sensitivity_floor, max_step=max_step,
            n_workers=n_workers, eval_timeout=eval_timeout, per_robot=per_robot,
            n_team_check_episodes=n_team_check_episodes,
        )  # fmt: skip
        check_eval_env_id(eval_env_id)
        self.eval_env_id = eval_env_id
        self.population_size = population_size
        self.period = period
        self.period_unit = period_unit
        self.sigma = DEFAULT_SIGMA[mutation] if sigma is None else sigma
        self.alpha = alpha
        self.alpha_schedule = alpha_schedule
        self.n_eval_episodes = n_eval_episodes
        self.mutation = mutation
        self.target_flip_share = target_flip_share
        self.frozen_groups = None if frozen_groups is None else list(frozen_groups)
        self.fitness = fitness
        self.min_gain = min_gain
        self.n_reevaluation_episodes = n_reevaluation_episodes
        self.max_eps_share = max_eps_share
        self.sensitivity_batch_size = sensitivity_batch_size
        self.sensitivity_floor = sensitivity_floor
        self.max_step = max_step
        self.n_team_check_episodes = n_team_check_episodes
        self.diagnostics_path = diagnostics_path
        self.n_workers = n_workers
        self.eval_timeout = eval_timeout
        self.batched_forward = batched_forward
        self.per_robot = per_robot
        if eval_env_kwargs is None:
            eval_env_kwargs = DEFAULT_EVAL_ENV_KWARGS.get(eval_env_id, {})
        self.eval_env_kwargs = copy.deepcopy(dict(eval_env_kwargs))
        self.worker_start_method = worker_start_method
        self.seed = seed
        self.share_experience = share_experience
        self.train_on_shared_rows = train_on_shared_rows
        # Public counters and records (they survive across learn() calls).
        self.eps_ticks = 0
        """Cumulative single-agent ticks simulated in EPS evaluation (add to the training ticks in plots)."""
        self.n_rounds = 0
        self.n_skipped_rounds = 0
        self.eps_time = 0.0
        self.shared_rows = 0
        """Replay rows written from the evaluation episodes (``share_experience``), all rounds together."""
        self._round_shared_rows = 0
        self.shared_gradient_steps = 0
        """Gradient steps taken for the shared rows (``train_on_shared_rows``), all rounds together."""
        self.shared_step_debt = 0
        """Gradient steps owed to the shared rows and not taken yet (paid over the next rollouts)."""
        self.history: list[dict[str, Any]] = []
        """One record per round (see docs/modules/eps.md, "The round record"); also in ``diagnostics_path``."""
        self._scale: float | None = None  # the last calibrated noise scale: the next calibration starts there
        self._rng: np.random.Generator | None = None
        self._generator: th.Generator | None = None
        self._pool: EnvPool | None = None
        self._pool_finalizer: weakref.finalize | None = None
        self._last_round_mark: int | None = None
        self._training_start = 0.0
        self._episode_limit = 0  # the evaluation env's time limit, for the first round's cost estimate
        self._evolved: list[str] = []
        self._round_log: RoundLog | None = None

    @classmethod
    def paper(cls, **kwargs: Any) -> EvolutionCallback:
        """Algorithm 1 as published: :data:`PAPER_SETTINGS`, updated by ``kwargs``.

        :param kwargs: any constructor argument (``EvolutionCallback.paper(alpha=0.2)``)
        """
        return cls(**{**copy.deepcopy(PAPER_SETTINGS), **kwargs})

    @property
    def n_individuals(self) -> int:
        """``m + 1``: the mutants plus the unmutated copy 0."""
        return self.population_size + 1

    @property
    def n_crossovers(self) -> int:
        """Rounds whose winner was crossed over into the model (of the ``n_rounds`` played)."""
        return sum(bool(record.get("accepted")) for record in self.history if not record.get("skipped"))

    @property
    def worker_pids(self) -> list[int]:
        """Process ids of the evaluation workers (empty when the envs run in the main process or are closed)."""
        return self._pool.pids if self._pool is not None else []

    @property
    def evolved_parameters(self) -> list[str]:
        """Names of the ``q_net`` parameters that EPS mutates and crosses over (known after ``init_callback``)."""
        return list(self._evolved)

    def state_dict(self) -> dict[str, Any]:
        """The training state (counters, records, generators, calibrated scale), for checkpoints."""
        return {
            "eps_ticks": self.eps_ticks,
            "n_rounds": self.n_rounds,
            "n_skipped_rounds": self.n_skipped_rounds,
            "eps_time": self.eps_time,
            "history": copy.deepcopy(self.history),
            "scale": self._scale,
            "rng": copy.deepcopy(self._rng),
            "generator": self._generator.get_state() if self._generator is not None else None,
            "last_round_mark": self._last_round_mark,
            "shared_rows": self.shared_rows,
            "shared_gradient_steps": self.shared_gradient_steps,
            "shared_step_debt": self.shared_step_debt,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` (after ``init_callback``, which made the generators).

        Also takes the attribute dictionary that checkpoints held before the callback had a ``state_dict``.
        """
        if "_rng" in state:
            state = {
                **state,
                "scale": None,
                "rng": state["_rng"],
                "generator": state.get("_generator"),
                "last_round_mark": state["_last_round_mark"],
            }
        self.eps_ticks, self.n_rounds = int(state["eps_ticks"]), int(state["n_rounds"])
        self.n_skipped_rounds, self.eps_time = int(state["n_skipped_rounds"]), float(state["eps_time"])
        self.history = copy.deepcopy(state["history"])
        self._scale, self._last_round_mark = state["scale"], state["last_round_mark"]
        self.shared_rows = int(state.get("shared_rows", 0))  # checkpoints from before experience sharing: none
        self.shared_gradient_steps = int(state.get("shared_gradient_steps", 0))
        self.shared_step_debt = int(state.get("shared_step_debt", 0))
        self._rng = copy.deepcopy(state["rng"])
        if state["generator"] is not None and self._generator is not None:
            self._generator.set_state(state["generator"])

    # ------------------------------------------------------------------ SB3 hooks
    def _init_callback(self) -> None:
        q_net = self._check_model()
        self._check_eval_env()
        frozen = self.frozen_groups
        if frozen is None:  # auto: the dueling value stream when there is one
            frozen = (
                [VALUE_STREAM]
                if any(n.startswith(f"{VALUE_STREAM}.") for n, _ in q_net.named_parameters())
                else []
            )
        self._evolved = evolved_parameter_names(q_net, frozen)
        if self._rng is None:
            model_seed = getattr(self.model, "seed", None)
            self._rng = np.random.default_rng(self.seed if self.seed is not None else model_seed)
            device = next(q_net.parameters()).device
            self._generator = th.Generator(device=device)
            self._generator.manual_seed(int(self._rng.integers(2**62)))
        self._round_log = self._make_round_log()
        self._start_pool()
        # A learn() that continues the count (reset_num_timesteps=False) keeps the period running.
        if self._last_round_mark is None or self._progress() < self._last_round_mark:
            self._last_round_mark = self._progress()
        self._training_start = time.perf_counter()

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        # The rollout has been stored and the episodes counted; the gradient steps come next.
        assert self._last_round_mark is not None
        self._pay_shared_steps()
        if self._progress() - self._last_round_mark < self.period or not self._within_budget():
            return
        if not self._visited_mask(None).any():
            return  # nothing visited yet: Eq. 6 and the calibration need states; try after the next rollout
        self._last_round_mark = self._progress()
        self._run_round()

    def _on_training_end(self) -> None:
        self._close_pool()

    # ------------------------------------------------------------------ one round (Algorithm 1, lines 3-13)
    def _run_round(self) -> None:
        start = time.perf_counter()
        self._round_shared_rows = 0
        q_net = self._q_net()
        theta = network_parameters(q_net)  # line 5: the copies of theta^e
        observations = self._visited_observations(None, self.sensitivity_batch_size)
        assert observations is not None and self._generator is not None and self._rng is not None
        sensitivities = self._sensitivities(q_net, observations) if self.mutation == "safe" else None  # 7-8
        directions = mutation_directions(  # lines 6 and 9 at unit scale: G ~ N(0, 1), G / omega
            theta, self.population_size, self._generator, sensitivities, self.sensitivity_floor, self._evolved
        )
        max_step = self.max_step if self.mutation == "safe" else float("inf")
        scale = self._mutation_scale(q_net, theta, directions, observations, max_step)
        population = population_from_directions(theta, directions, scale, max_step)
        outputs = population_outputs(q_net, population, observations)
        flip_share, mean_abs_dq = policy_change(outputs)
        record: dict[str, Any] = {
            "scale": scale,
            "flip_share": flip_share[1:].tolist(),
            "mean_abs_dq": mean_abs_dq[1:].tolist(),
            "mean_abs_q": float(outputs[0].abs().mean()),
        }
        try:
            result = self._evaluate(population, record)  # line 10
            if not result.valid.all():
                _warn_disqualified(population, result.valid)
            winner = select_best(result.fitness)  # line 11, Eq. 4 (never a disqualified individual)
            accepted = self._accept(population, result, winner, record)
        except EvaluationFailed as error:
            record["shared_gradient_steps"] = self._owe_shared_steps()
            self._skip_round(error, time.perf_counter() - start, record)
            return
        alpha = self._current_alpha()
        record.update(winner=winner, accepted=accepted, alpha=alpha, mean_abs_delta=0.0)
        if accepted and alpha > 0:  # line 13, Eq. 5 (copy 0 winning would leave theta as it is)
            self._team_check(record, "before")
            best = individual(population, winner)
            record["mean_abs_delta"] = polyak_crossover_(q_net, best, alpha, self._evolved)
            target = getattr(self.model.policy, "q_net_target", None)
            if isinstance(target, nn.Module):
                polyak_crossover_(target, best, alpha, self._evolved)
            self._team_check(record, "after")
        record["shared_gradient_steps"] = self._owe_shared_steps()
        self._record_round(record, time.perf_counter() - start)

    def _owe_shared_steps(self) -> int:
        """``train_on_shared_rows``: owe the gradient steps of the round's shared ticks (taken by
        :meth:`_pay_shared_steps` over the next rollouts). :return: the steps owed"""
        if not (self.share_experience and self.train_on_shared_rows and self._round_shared_rows):
            return 0
        steps = shared_gradient_steps(self._model, self._round_shared_rows)
        self.shared_step_debt += steps
        return steps

    def _pay_shared_steps(self) -> None:
        """Take owed gradient steps, at most as many per rollout as the rollout's own (a burst of thousands of steps
        right after a round, with no new ticks between them, cut greedy success to 8-14 % in both screened runs)."""
        if self.shared_step_debt <= 0:
            return
        model = self._model
        steps = train_on_shared(model, min(self.shared_step_debt, max(rollout_gradient_steps(model), 1)))
        self.shared_step_debt -= steps
        self.shared_gradient_steps += steps

    def _mutation_scale(
        self,
        q_net: nn.Module,
        theta: Parameters,
        directions: Parameters,
        observations: th.Tensor,
        max_step: float,
    ) -> float:
        """The noise scale of this round: ``sigma``, or calibrated to ``target_flip_share`` of greedy actions."""
        if self.target_flip_share is None:
            return self.sigma

        def flip_share_at(scale: float) -> float:
            population = population_from_directions(theta, directions, scale, max_step)
            return float(policy_change(population_outputs(q_net, population, observations))[0][1:].mean())

        initial = self._scale if self._scale is not None else self.sigma
        self._scale, _ = calibrate_scale(flip_share_at, self.target_flip_share, initial)
        return self._scale

    def _play(
        self, population: Parameters, active: np.ndarray | None = None
    ) -> tuple[list[int], PopulationResult]:
        """Play the population on fresh common-random-number episodes and count their ticks."""
        assert self._pool is not None and self._rng is not None
        seeds = [int(seed) for seed in self._rng.integers(2**31 - 1, size=self.n_eval_episodes)]
        result = evaluate_population(self._pool, population, seeds, self.eval_timeout, self.fitness, active)
        self.eps_ticks += int(result.lengths.sum())
        if self.share_experience and result.episodes is not None:
            rows = share_episodes(self._model, result.episodes)  # before any crossover: the round's network
            self._round_shared_rows += rows
            self.shared_rows += rows
            result.episodes = None  # the arrays are in the buffer now
        return seeds, result

    def _evaluate(self, population: Parameters, record: dict[str, Any]) -> PopulationResult:
        """Algorithm 1, line 10, with every episode noted in the round's record."""
        seeds, result = self._play(population)
        outcomes = result.outcomes if result.outcomes is not None else np.zeros_like(result.lengths)
        record.update(
            round_ticks=int(result.lengths.sum()),
            episode_seeds=seeds,
            returns=result.returns.tolist(),
            successes=result.successes.astype(int).tolist(),
            outcomes=outcomes.tolist(),
            episode_lengths=result.lengths.tolist(),
            fitness=result.fitness.tolist(),
        )
        return result

    def _accept(
        self, population: Parameters, result: PopulationResult, winner: int, record: dict[str, Any]
    ) -> bool:
        """The acceptance rule: a gain over copy 0 beyond ``min_gain``, and again on fresh episodes."""
        fitness = result.fitness
        gain = float(fitness[winner] - fitness[0]) if np.isfinite(fitness[0]) else float("nan")
        finite = np.sort(fitness[np.isfinite(fitness)])
        record["gain"] = gain
        record["runner_up_margin"] = float(finite[-1] - finite[-2]) if finite.size >= 2 else float("nan")
        accepted = winner != 0 and gain_accepted(gain, self.min_gain)
        if accepted and self.n_reevaluation_episodes > 0:
            record["reevaluation"] = self._reevaluate(population, winner)
            record["reevaluation_gain"] = record["reevaluation"]["gain"]
            accepted = gain_accepted(record["reevaluation_gain"], self.min_gain)
        return accepted

    def _reevaluate(self, population: Parameters, winner: int) -> dict[str, Any]:
        """Copy 0 and the winner on ``n_reevaluation_episodes`` fresh episodes (in batches of the pool's size)."""
        active = np.zeros(self.n_individuals, dtype=bool)
        active[[0, winner]] = True
        pair = [0, winner]
        seeds: list[int] = []
        returns, outcomes, lengths = [], [], []
        for _ in range(-(-self.n_reevaluation_episodes // self.n_eval_episodes)):  # ceil
            batch_seeds, result = self._play(population, active)
            seeds += batch_seeds
            returns.append(result.returns[pair])
            outcomes.append(
                result.outcomes[pair] if result.outcomes is not None else np.zeros_like(result.lengths[pair])
            )
            lengths.append(result.lengths[pair])
            valid = result.valid[pair]
        returns_, outcomes_ = np.concatenate(returns, axis=1), np.concatenate(outcomes, axis=1)
        fitness = population_fitness(returns_, outcomes_, valid, self.fitness)
        return {
            "episode_seeds": seeds,
            "returns": returns_.tolist(),
            "successes": (outcomes_ == 1).astype(int).tolist(),
            "outcomes": outcomes_.tolist(),
            "episode_lengths": np.concatenate(lengths, axis=1).tolist(),
            "fitness": fitness.tolist(),
            "gain": float(fitness[1] - fitness[0]) if np.isfinite(fitness[0]) else float("nan"),
            "ticks": int(sum(int(part.sum()) for part in lengths)),
        }

    def _current_alpha(self) -> float:
        """Eq. 5's alpha of this round under ``alpha_schedule``."""
        remaining = float(getattr(self.model, "_current_progress_remaining", 1.0))
        return scheduled_alpha(self.alpha, self.alpha_schedule, remaining)

    def _team_check(self, record: dict[str, Any], when: str) -> None:
        """Greedy episodes of the training env, same seeds before and after the crossover (optional)."""
        if self.n_team_check_episodes == 0:
            return
        from sb3_eps.common.evaluation import evaluate_team

        env_id = self.model.get_env().env_id  # type: ignore[union-attr]  # checked in _check_model
        if when == "before":
            record["team_check_seed"] = int(self._rng.integers(2**31 - 1))  # type: ignore[union-attr]
        # The online network, the one the crossover changed (a kept weight average, GDQ's default, follows it only
        # slowly): its greedy actions without the model's exploration.
        online = _OnlineGreedy(self.model.policy)
        summary = evaluate_team(online, env_id, self.n_team_check_episodes, n_envs=1, seed=record["team_check_seed"])
        ticks = int(sum(episode["l"] for episode in summary["episodes"]))
        self.eps_ticks += ticks
        record[f"team_success_{when}"] = summary.get("success_rate", float("nan"))
        record[f"team_return_{when}"] = summary["team_return_mean"]
        record["team_check_ticks"] = record.get("team_check_ticks", 0) + ticks

    def _within_budget(self) -> bool:
        """Whether a round now keeps the EPS ticks within ``max_eps_share`` of the training ticks, if it plays every
        episode it may (the reevaluation too) at the previous round's mean episode length."""
        if self.max_eps_share is None:
            return True
        return self.eps_ticks + self._expected_round_cost() <= self.max_eps_share * self._model_ticks()

    def _expected_round_cost(self) -> float:
        n_reevaluations = -(-self.n_reevaluation_episodes // self.n_eval_episodes)  # ceil
        n_played = (self.n_individuals + 2 * n_reevaluations) * self.n_eval_episodes + 2 * self.n_team_check_episodes
        # The last round's episodes stand for the policy now; the mean of earlier rounds' costs underestimated a
        # round that reevaluated, or whose policy had learned to survive longer (16-17 % EPS shares, eps.md).
        done = [record for record in self.history if not record.get("skipped")]
        last = done[-1] if done else {}
        played = np.concatenate(
            [np.ravel(last.get("episode_lengths", [])), np.ravel(last.get("reevaluation", {}).get("episode_lengths", []))]
        ).astype(float)
        played = played[played > 0]  # disqualified individuals' unplayed episodes
        if not played.size:  # before the first round: half the most a round can cost
            return 0.5 * n_played * self._episode_limit
        return float(played.mean()) * n_played

    def _sensitivities(self, q_net: nn.Module, observations: th.Tensor) -> list[Parameters]:
        """Eq. 6 on a batch of visited observations: one for all mutants, or one per robot (``per_robot``)."""
        if not self.per_robot:
            return [output_sensitivity(q_net, observations)]
        # Mutant i follows robot i % n: the paper's m = n when population_size = n_agents.
        n_agents = int(self._model.n_agents)
        robots = sorted({index % n_agents for index in range(self.population_size)})
        by_robot = {robot: self._sensitivity_of(q_net, robot) for robot in robots}
        return [by_robot[index % n_agents] for index in range(self.population_size)]

    def _sensitivity_of(self, q_net: nn.Module, robot: int | None) -> Parameters:
        """Eq. 6 on visited observations of one robot (None: of every robot)."""
        observations = self._visited_observations(robot, self.sensitivity_batch_size)
        if observations is None:  # this robot has no alive entry yet: use every robot's states
            observations = self._visited_observations(None, self.sensitivity_batch_size)
        assert observations is not None
        return output_sensitivity(q_net, observations)

    def _visited_mask(self, robot: int | None) -> np.ndarray:
        return visited_mask(self._model.replay_buffer, robot)

    def _visited_observations(self, robot: int | None, batch_size: int) -> th.Tensor | None:
        assert self._rng is not None
        return sample_visited_observations(self.model, batch_size, self._rng, robot)

    # ------------------------------------------------------------------ records
    def _make_round_log(self) -> RoundLog | None:
        if self.diagnostics_path == "":
            return None
        if self.diagnostics_path is not None:
            return RoundLog(self.diagnostics_path)
        # The logger is set by learn(); it is absent when init_callback is called on its own.
        logger = getattr(self.model, "_logger", None)
        folder = logger.get_dir() if logger is not None else None
        return RoundLog(os.path.join(folder, DIAGNOSTICS_NAME)) if folder else None

    def _write(self, record: dict[str, Any]) -> None:
        if self._round_log is not None:
            self._round_log.append(record, n_before=len(self.history))
        self.history.append(record)

    def _record_round(self, record: dict[str, Any], wall_time: float) -> None:
        self.n_rounds += 1
        self.eps_time += wall_time
        ticks_spent = record["round_ticks"] + record.get("reevaluation", {}).get("ticks", 0)
        ticks_spent += record.get("team_check_ticks", 0)
        record = {
            "round": self.n_rounds,
            "model_ticks": self._model_ticks(),
            "eps_ticks": self.eps_ticks,
            "ticks_spent": ticks_spent,
            "shared_rows": self._round_shared_rows,
            **record,
            "wall_time": wall_time,
            "skipped": False,
        }
        self._write(record)
        self._log(record, wall_time)

    def _log(self, record: dict[str, Any], wall_time: float) -> None:
        fitness = np.asarray(record["fitness"], dtype=float)
        finite = fitness[np.isfinite(fitness)]
        successes = np.asarray(record["successes"], dtype=float).mean(axis=1)
        winner = record["winner"]
        logger = self.logger
        logger.record("eps/round", self.n_rounds)
        logger.record("eps/ticks", self.eps_ticks)
        logger.record("eps/total_ticks", self._model_ticks() + self.eps_ticks)
        logger.record("eps/round_ticks", record["ticks_spent"])
        if self.share_experience:
            logger.record("eps/shared_rows", record["shared_rows"])
            logger.record("eps/shared_rows_total", self.shared_rows)
            logger.record("eps/shared_gradient_steps", record.get("shared_gradient_steps", 0))
        logger.record("eps/tick_share", self.eps_ticks / max(self._model_ticks(), 1))
        for index, value in enumerate(fitness):
            logger.record(f"eps/fitness_{index}", float(value))
        logger.record("eps/fitness_mean", float(finite.mean()) if finite.size else float("-inf"))
        logger.record("eps/fitness_max", float(fitness.max()))
        logger.record("eps/fitness_min", float(fitness.min()))
        logger.record("eps/success_0", float(successes[0]))
        logger.record("eps/success_max", float(successes.max()))
        logger.record("eps/n_invalid", int((~np.isfinite(fitness)).sum()))
        logger.record("eps/winner", winner)
        logger.record("eps/fitness_gain", record["gain"])
        logger.record("eps/runner_up_margin", record["runner_up_margin"])
        logger.record("eps/reevaluation_gain", record.get("reevaluation_gain", float("nan")))
        logger.record("eps/accepted", int(record["accepted"]))
        logger.record("eps/alpha", record["alpha"])
        logger.record("eps/mutation_scale", record["scale"])
        logger.record("eps/flip_share", float(np.mean(record["flip_share"])))
        logger.record("eps/mean_abs_dq", float(np.mean(record["mean_abs_dq"])))
        logger.record("eps/mean_abs_q", record["mean_abs_q"])
        logger.record("eps/mean_abs_delta", record["mean_abs_delta"])
        for when in ("before", "after"):
            if f"team_success_{when}" in record:
                logger.record(f"eps/team_success_{when}", record[f"team_success_{when}"])
        logger.record("eps/round_time", wall_time)
        logger.record("eps/time_share", self._time_share())
        logger.record("eps/skipped_rounds", self.n_skipped_rounds)
        if self.verbose >= 1:
            verdict = "crossed over" if record["mean_abs_delta"] > 0 else "kept"
            print(
                f"EPS round {self.n_rounds}: copy 0 {fitness[0]:.3f} ({100 * successes[0]:.0f} % reached), best "
                f"{fitness[winner]:.3f} (individual {winner}), {verdict} (alpha {record['alpha']:.3f}); scale "
                f"{record['scale']:.2e} flipped {100 * np.mean(record['flip_share']):.0f} % of greedy actions; "
                f"{record['ticks_spent']} ticks, {wall_time:.2f} s; {self.eps_ticks} EPS ticks "
                f"({100 * self.eps_ticks / max(self._model_ticks(), 1):.1f} % of training)"
                + (f"; {record['shared_rows']} replay rows shared" if self.share_experience else "")
            )

    def _skip_round(self, error: EvaluationFailed, wall_time: float, record: dict[str, Any]) -> None:
        self.n_skipped_rounds += 1
        self.eps_time += wall_time
        self._write(
            {
                "round": None,
                "model_ticks": self._model_ticks(),
                "eps_ticks": self.eps_ticks,
                "ticks_spent": record.get("round_ticks", 0),
                "shared_rows": self._round_shared_rows,
                "shared_gradient_steps": record.get("shared_gradient_steps", 0),
                "skipped": True,
                "reason": str(error),
            }
        )
        warnings.warn(
            f"EPS round skipped, restarting the evaluation workers: {error}", RuntimeWarning, stacklevel=2
        )
        self.logger.record("eps/skipped_rounds", self.n_skipped_rounds)
        self._close_pool()
        self._start_pool()
        if self.verbose >= 2:
            print(f"EPS: evaluation workers restarted (pids {self.worker_pids})")

    # ------------------------------------------------------------------ helpers
    def _progress(self) -> int:
        if self.period_unit == "episodes":
            return int(self.model._episode_num)
        return self._model_ticks()

    def _model_ticks(self) -> int:
        return int(getattr(self.model, "ticks", self.model.num_timesteps))

    def _time_share(self) -> float:
        elapsed = time.perf_counter() - self._training_start
        return self.eps_time / elapsed if elapsed > 0 else 0.0

    @property
    def _model(self) -> Any:
        # The model's multi-agent attributes (n_agents, replay_buffer) are not on SB3's BaseAlgorithm type.
        return self.model

    def _q_net(self) -> nn.Module:
        q_net = self._model.policy.q_net
        assert isinstance(q_net, nn.Module)
        return q_net

    def _n_workers(self) -> int:
        # A worker evaluates whole individuals, so more workers than individuals would idle.
        if self.n_workers is not None:
            return min(self.n_workers, self.n_individuals)
        return min(os.cpu_count() or 1, self.n_individuals)

    def _start_pool(self) -> None:
        # The workers get the architecture only (a CPU copy); each round sends them the weights.
        template = copy.deepcopy(self._q_net()).to("cpu")
        arguments = (
            self.eval_env_id,
            self.eval_env_kwargs,
            self.n_individuals,
            self.n_eval_episodes,
            template,
        )
        n_workers = self._n_workers()
        record = record_mode(self._model) if self.share_experience else None
        if n_workers == 0:
            self._pool = InProcessEnvPool(*arguments, batched=self.batched_forward, record=record)
        else:
            self._pool = SubprocessEnvPool(
                *arguments,
                batched=self.batched_forward,
                n_workers=n_workers,
                start_method=self.worker_start_method,
                record=record,
            )
        # Close the workers even when training dies with an exception (no _on_training_end then).
        self._pool_finalizer = weakref.finalize(self, self._pool.close)

    def _close_pool(self) -> None:
        if self._pool_finalizer is not None:
            self._pool_finalizer()  # calls pool.close() once
        self._pool, self._pool_finalizer = None, None

    def _check_model(self) -> nn.Module:
        """The model needs a shared agent network and a replay buffer of visited observations."""
        policy = getattr(self.model, "policy", None)
        q_net = getattr(policy, "q_net", None)
        if not isinstance(q_net, nn.Module):
            raise ValueError(
                f"EvolutionCallback needs a model with a shared agent network at model.policy.q_net "
                f"(IQL, GDQ, QMIX, VDN or SB3's DQN); {type(self.model).__name__} has none"
            )
        buffer = getattr(self.model, "replay_buffer", None)
        if buffer is None or not hasattr(buffer, "observations") or not hasattr(buffer, "size"):
            raise ValueError(
                f"EvolutionCallback samples visited observations from model.replay_buffer; "
                f"{type(self.model).__name__} has no replay buffer: use an off-policy model (IQL, GDQ, QMIX, VDN)"
            )
        if self.n_team_check_episodes > 0 and getattr(self.model.get_env(), "env_id", None) is None:
            raise ValueError(
                "n_team_check_episodes > 0 replays the training env, which needs a vec env made by "
                "sb3_eps.make_vec_env (it records its env_id); set n_team_check_episodes=0"
            )
        if self.per_robot and int(getattr(self.model, "n_agents", 0)) < 1:
            raise ValueError("per_robot=True needs a multi-agent model (model.n_agents); set per_robot=False")
        return q_net

    def _check_eval_env(self) -> None:
        """The evaluation world must speak the model's language: equal observation and action spaces."""
        try:
            env = make_eval_env(self.eval_env_id, self.eval_env_kwargs)
        except TypeError as error:
            raise ValueError(
                f"eval_env_kwargs {self.eval_env_kwargs} do not fit {self.eval_env_id!r}: {error}"
            ) from None
        spec_limit = env.spec.max_episode_steps if env.spec is not None else None
        limit = getattr(env, "max_episode_steps", None) or getattr(env, "max_cycles", None) or spec_limit
        self._episode_limit = int(limit or 0)
        try:
            for kind in ("observation_space", "action_space"):
                ours, theirs = agent_space(env, kind), getattr(self.model, kind)
                if ours != theirs:
                    raise ValueError(
                        f"the {kind} of eval_env_id {self.eval_env_id!r} ({ours}) differs from the model's "
                        f"({theirs}): pick the evaluation world that matches the training env "
                        "(envs.eps_env_id_for(training env id))"
                    )
            problem = sharing_problem(self.model, env) if self.share_experience else None
            if problem is not None:
                raise ValueError(f"{problem}; or set share_experience=False")
            if self.share_experience and self.train_on_shared_rows:
                shared_gradient_steps(self.model, 0)  # a train_freq in episodes: the error says what to set
        finally:
            env.close()


class _OnlineGreedy:
    """A policy's greedy actions from its online network: ``predict`` for :func:`evaluate_team`, whatever network
    the model's own ``predict(deterministic=True)`` takes (``q_net_average`` when the policy keeps one). The
    package's policies and SB3's ``DQNPolicy`` both take the online network's argmax with ``deterministic=False``
    (exploration is the algorithm's)."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        return self.policy.predict(observation, state, episode_start, deterministic=False)


def visited_mask(replay_buffer: Any, robot: int | None = None) -> np.ndarray:
    """``(rows, agents)`` bool: True where the replay buffer holds a real visited observation (an alive agent).

    :param replay_buffer: the model's replay buffer (ours records ``alive``; in SB3's every stored row is real)
    :param robot: keep only this agent's column of the joint rows; None for every agent
    """
    size = int(replay_buffer.size())
    alive = getattr(replay_buffer, "alive", None)
    mask = np.ones(replay_buffer.observations.shape[1:2], dtype=bool)[None].repeat(size, 0)
    if alive is not None:
        mask = np.asarray(alive[:size]) > 0
    return mask if robot is None else mask[:, robot : robot + 1]


def sample_visited_observations(
    model: Any, batch_size: int, rng: np.random.Generator, robot: int | None = None
) -> th.Tensor | None:
    """Sample up to ``batch_size`` distinct visited observations (alive agents' entries) from a model's replay
    buffer: the batch ``b`` of Eq. 6, of the calibration and of the diagnostics.

    :param model: an off-policy model with ``replay_buffer`` and ``policy.q_net``
    :param batch_size: the most observations returned
    :param rng: the generator that picks them
    :param robot: restrict to this agent's column of the joint rows; None for every agent
    :return: ``(batch, obs_dim)`` on the network's device, or None when nothing was visited yet
    """
    mask = visited_mask(model.replay_buffer, robot)
    candidates = np.flatnonzero(mask.reshape(-1))
    if candidates.size == 0:
        return None
    chosen = np.sort(rng.choice(candidates, size=min(batch_size, candidates.size), replace=False))
    observations = model.replay_buffer.observations[: mask.shape[0]]
    if robot is not None:
        observations = observations[:, robot : robot + 1]
    flat = np.asarray(observations).reshape(-1, observations.shape[-1])
    device = next(model.policy.q_net.parameters()).device
    return th.as_tensor(flat[chosen], dtype=th.float32, device=device)


def _warn_disqualified(population: Parameters, valid: np.ndarray) -> None:
    """Warn about individuals whose weights (after mutation) or Q-values were not finite; they cannot win."""
    weights_ok = finite_individuals({name: stacked.detach().cpu() for name, stacked in population.items()})
    bad_weights = np.flatnonzero(~weights_ok).tolist()
    bad_outputs = np.flatnonzero(weights_ok & ~np.asarray(valid, dtype=bool)).tolist()
    parts = [f"individuals {bad_weights} have non-finite weights"] if bad_weights else []
    parts += [f"individuals {bad_outputs} gave non-finite Q-values"] if bad_outputs else []
    warnings.warn(
        f"EPS round: {' and '.join(parts)}; they are disqualified and never written into the network",
        RuntimeWarning,
        stacklevel=3,
    )


def _check_arguments(**values: Any) -> None:
    """Constructor checks, each a ``ValueError`` that says what to change."""
    if not isinstance(values["population_size"], int) or values["population_size"] < 1:
        raise ValueError(
            f"population_size (mutants per round) must be an int >= 1, got {values['population_size']!r}"
        )
    if not isinstance(values["period"], int) or values["period"] < 1:
        raise ValueError(f"period must be an int >= 1, got {values['period']!r}")
    if values["period_unit"] not in PERIOD_UNITS:
        raise ValueError(f"period_unit must be one of {PERIOD_UNITS}, got {values['period_unit']!r}")
    if values["sigma"] is not None and not values["sigma"] > 0:
        raise ValueError(f"sigma (noise scale) must be > 0, got {values['sigma']!r}")
    if not 0.0 <= values["alpha"] <= 1.0:
        raise ValueError(
            f"alpha (crossover share of the best individual, Eq. 5) must be in [0, 1], got {values['alpha']!r}"
        )
    if not isinstance(values["n_eval_episodes"], int) or values["n_eval_episodes"] < 1:
        raise ValueError(f"n_eval_episodes must be an int >= 1, got {values['n_eval_episodes']!r}")
    if values["mutation"] not in MUTATIONS:
        raise ValueError(f"unknown mutation {values['mutation']!r}; use one of {MUTATIONS}")
    if not isinstance(values["sensitivity_batch_size"], int) or values["sensitivity_batch_size"] < 1:
        raise ValueError(
            f"sensitivity_batch_size must be an int >= 1, got {values['sensitivity_batch_size']!r}"
        )
    if not values["sensitivity_floor"] > 0:
        raise ValueError(f"sensitivity_floor must be > 0, got {values['sensitivity_floor']!r}")
    if not values["max_step"] > 0:
        raise ValueError(f"max_step must be > 0 (float('inf') disables the clip), got {values['max_step']!r}")
    if values["n_workers"] is not None and (
        not isinstance(values["n_workers"], int) or values["n_workers"] < 0
    ):
        raise ValueError(
            f"n_workers must be None or an int >= 0 (0: in the main process), got {values['n_workers']!r}"
        )
    if not values["eval_timeout"] > 0:
        raise ValueError(f"eval_timeout must be > 0 seconds, got {values['eval_timeout']!r}")
    if values["per_robot"] and values["mutation"] != "safe":
        raise ValueError("per_robot=True chooses each mutant's sensitivity: it needs mutation='safe'")
    if values["alpha_schedule"] not in ALPHA_SCHEDULES:
        raise ValueError(f"alpha_schedule must be one of {ALPHA_SCHEDULES}, got {values['alpha_schedule']!r}")
    share = values["target_flip_share"]
    if share is not None and not 0.0 < share < 1.0:
        raise ValueError(
            f"target_flip_share (share of greedy actions a mutant changes) must be in (0, 1) or None, got {share!r}"
        )
    groups = values["frozen_groups"]
    if groups is not None and (
        isinstance(groups, str) or not all(isinstance(group, str) for group in groups)
    ):
        raise ValueError(
            f"frozen_groups must be a list of parameter-group names (e.g. ['value_stream']) or None, got {groups!r}"
        )
    if values["fitness"] not in FITNESS_KINDS:
        raise ValueError(f"unknown fitness {values['fitness']!r}; use one of {FITNESS_KINDS}")
    if not np.isfinite(values["min_gain"]) or values["min_gain"] < 0:
        raise ValueError(f"min_gain must be a finite number >= 0, got {values['min_gain']!r}")
    max_share = values["max_eps_share"]
    if max_share is not None and not max_share > 0:
        raise ValueError(f"max_eps_share must be > 0 or None (no budget), got {max_share!r}")
    if not isinstance(values["n_reevaluation_episodes"], int) or values["n_reevaluation_episodes"] < 0:
        raise ValueError(
            f"n_reevaluation_episodes must be an int >= 0 (0: no reevaluation), got {values['n_reevaluation_episodes']!r}"
        )
    if not isinstance(values["n_team_check_episodes"], int) or values["n_team_check_episodes"] < 0:
        raise ValueError(
            f"n_team_check_episodes must be an int >= 0, got {values['n_team_check_episodes']!r}"
        )


def gain_accepted(gain: float, min_gain: float) -> bool:
    """The acceptance rule: a finite fitness gain over copy 0 strictly above ``min_gain``.

    :param gain: winner's fitness minus copy 0's (NaN when copy 0 was disqualified)
    :param min_gain: the margin (>= 0)
    """
    return bool(np.isfinite(gain) and gain > min_gain)


def scheduled_alpha(alpha: float, schedule: str, progress_remaining: float) -> float:
    """Eq. 5's alpha at a point of training.

    :param alpha: the base share of the best individual
    :param schedule: ``"constant"`` or ``"linear"`` (``alpha`` times the share of training still to come, so it
        reaches 0 at the end)
    :param progress_remaining: SB3's ``_current_progress_remaining``: 1 at the start, 0 at the end
    """
    if schedule not in ALPHA_SCHEDULES:
        raise ValueError(f"alpha_schedule must be one of {ALPHA_SCHEDULES}, got {schedule!r}")
    if schedule == "constant":
        return alpha
    return alpha * float(np.clip(progress_remaining, 0.0, 1.0))
