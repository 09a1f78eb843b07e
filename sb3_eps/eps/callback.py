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

from sb3_eps.eps.evaluation import (
    EnvPool,
    EvaluationFailed,
    InProcessEnvPool,
    PopulationResult,
    SubprocessEnvPool,
    check_eval_env_id,
    evaluate_population,
    make_eval_env,
)
from sb3_eps.eps.mutations import (
    Parameters,
    finite_individuals,
    individual,
    mutate_population,
    network_parameters,
    output_sensitivity,
    polyak_crossover_,
    select_best,
)

MUTATIONS = ("safe", "gaussian")
# Noise scales giving a mean |Q change| of about 5-10 % of |Q| on a mid-training GDQ robot network (measured).
DEFAULT_SIGMA = {"safe": 0.001, "gaussian": 0.03}
PERIOD_UNITS = ("episodes", "ticks")


class EvolutionCallback(BaseCallback):
    """Evolutionary Policy Search (EPS; Marchesini & Farinelli, "Enhancing Deep Reinforcement Learning
    Approaches for Multi-Robot Navigation via Single-Robot Evolutionary Policy Search", ICRA 2022, Algorithm 1).

    Every ``period`` episodes (or ticks) of multi-agent training, at the end of a rollout (before the gradient
    steps): copy the shared agent network ``model.policy.q_net`` ``population_size + 1`` times; mutate all copies
    but copy 0 with Gaussian noise normalised by the output-gradient sensitivity of Eq. 6 (computed on visited
    observations from the replay buffer); evaluate every copy greedily for ``n_eval_episodes`` episodes in
    independent single-agent worlds; pick the best mean return (Eq. 4) and move the agent network (and its target
    network, if any) toward it by Polyak averaging (Eq. 5). When the unmutated copy 0 wins nothing changes.
    See ``docs/modules/eps.md`` for Algorithm 1 line by line.

    The defaults are chosen so that EPS costs at most about 10 % of GDQ's time on ``MultiRobotNav-4-v0``
    (``benchmarks/eps_overhead.py``; figures in ``docs/benchmarks.md``).

    :param eval_env_id: the single-agent evaluation world (``"SingleRobotNav-v0"``, the robots' EPS world with
        static obstacles; ``"CooperativeNavigationSingle-v0"`` for Cooperative Navigation; see
        ``envs.eps_env_id_for``). Its observation and action spaces must equal the model's.
    :param population_size: ``m``, the number of mutated copies; ``m + 1`` individuals are evaluated (the paper
        adds the unmutated copy to the ``m`` mutants). Default 10, the population of the author's earlier
        evolutionary work (ALGORITHMS.md section 2).
    :param period: ``e_s`` of Algorithm 1, in ``period_unit``. Default 100 episodes of the multi-agent worlds
        (episodes of all ``n_envs`` worlds together). The paper does not report ``e_s``; a default round on the
        robot world costs about 4 CPU seconds (7-11k evaluation ticks), and 100 world episodes of
        ``MultiRobotNav-4-v0`` (16k ticks or more) keep that within 10 % of GDQ's time (measured,
        ``docs/benchmarks.md``). Lower it where evaluation is cheap (Cooperative Navigation) or cores are free.
    :param period_unit: ``"episodes"`` (world episodes, as the paper's epochs) or ``"ticks"`` (simulator steps of
        one world, summed over the worlds: ``model.ticks``). A round starts at the first rollout end after
        ``period`` units since the previous round.
    :param sigma: standard deviation of the Gaussian noise ``G ~ N(0, sigma)`` (Algorithm 1's baseline mutation).
        Default None: 0.001 for ``mutation="safe"``, 0.03 for ``"gaussian"``. Both move the Q-values of a
        mid-training GDQ robot network by about 5-10 % of their mean magnitude (measured, docs/modules/eps.md):
        dividing by the sensitivity enlarges the noise wherever ``omega < 1``, which is most weights, so equal
        sigmas would not compare the two operators at equal disruption. The paper reports no value.
    :param alpha: share of the best individual in the crossover, Eq. 5, in [0, 1]. Default 0.3: the paper found
        alpha >= 0.4 harmful and alpha < 0.4 helpful.
    :param n_eval_episodes: episodes per individual; fitness is their mean return (Eq. 4). Default 2: with
        common random numbers (every individual plays the same seeded episodes) two episodes already compare
        individuals fairly, and evaluation dominates the cost of a round.
    :param mutation: ``"safe"`` (Eq. 6-normalised noise, the paper's operator) or ``"gaussian"`` (plain noise,
        the ablation).
    :param sensitivity_batch_size: ``|b|``, visited observations (alive agents' entries) sampled from the replay
        buffer for Eq. 6. Default 128, about the 100 states of Lehman et al.'s safe mutations.
    :param sensitivity_floor: lower bound on the sensitivity ``omega`` (a sensitivity of exactly 0 counts as 1),
        so a step is at most ``|G| / floor``. Default 0.01, as in Lehman et al.'s reference implementation.
    :param max_step: per-weight clip on the safe mutation's step. Default 0.2, Lehman et al.'s value (their maze
        domain); ``float("inf")`` disables it. Not applied to ``mutation="gaussian"``.
    :param n_workers: evaluation worker processes, each evaluating a block of whole individuals; 0 evaluates in
        the main process. Default None: one per CPU core (at most one per individual), because training waits for
        the round. On a machine whose cores are busy with other jobs they bring nothing (measured).
    :param eval_timeout: seconds a whole evaluation round may take before its workers count as hung; the round
        is then skipped and the workers restarted. It also bounds the first round's wait for the workers to build
        their envs (they build them while training goes on). Default 120 (a default round takes a few seconds).
    :param batched_forward: compute the greedy actions of a block of individuals in one ``vmap``-ed
        ``functional_call`` over their stacked weights (default True; 0.9 ms instead of 2.1 ms per tick for 11
        individuals x 2 episodes of the robot network) instead of one forward pass per individual. Env steps
        dominate a round: it evaluates 10-15 % more ticks per second (measured, docs/benchmarks.md).
    :param per_robot: normalise mutant ``i`` by the sensitivity computed on robot ``i % n_agents``'s own visited
        observations instead of all robots' (paper III-B's "individual experiences"; with
        ``population_size = n_agents`` every robot gets one mutant). The weights stay shared: no algorithm of
        this package holds per-robot networks (see docs/modules/eps.md). Needs ``mutation="safe"``.
    :param eval_env_kwargs: constructor arguments of the evaluation env
    :param worker_start_method: multiprocessing start method of the workers; None: ``"fork"`` where available
    :param seed: seed of the noise, the buffer sampling and the evaluation episodes; None: derived from the
        model's seed (a seeded model gives a reproducible EPS), or random when the model has none.
    :param verbose: 0 silent, 1 one line per round, 2 also worker restarts
    """

    def __init__(
        self,
        eval_env_id: str = "SingleRobotNav-v0",
        population_size: int = 10,
        period: int = 100,
        period_unit: str = "episodes",
        sigma: float | None = None,
        alpha: float = 0.3,
        n_eval_episodes: int = 2,
        mutation: str = "safe",
        sensitivity_batch_size: int = 128,
        sensitivity_floor: float = 0.01,
        max_step: float = 0.2,
        n_workers: int | None = None,
        eval_timeout: float = 120.0,
        batched_forward: bool = True,
        per_robot: bool = False,
        eval_env_kwargs: dict[str, Any] | None = None,
        worker_start_method: str | None = None,
        seed: int | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose=verbose)
        _check_arguments(
            population_size=population_size, period=period, period_unit=period_unit, sigma=sigma, alpha=alpha,
            n_eval_episodes=n_eval_episodes, mutation=mutation, sensitivity_batch_size=sensitivity_batch_size,
            sensitivity_floor=sensitivity_floor, max_step=max_step, n_workers=n_workers, eval_timeout=eval_timeout,
            per_robot=per_robot,
        )  # fmt: skip
        check_eval_env_id(eval_env_id)
        self.eval_env_id = eval_env_id
        self.population_size = population_size
        self.period = period
        self.period_unit = period_unit
        self.sigma = DEFAULT_SIGMA[mutation] if sigma is None else sigma
        self.alpha = alpha
        self.n_eval_episodes = n_eval_episodes
        self.mutation = mutation
        self.sensitivity_batch_size = sensitivity_batch_size
        self.sensitivity_floor = sensitivity_floor
        self.max_step = max_step
        self.n_workers = n_workers
        self.eval_timeout = eval_timeout
        self.batched_forward = batched_forward
        self.per_robot = per_robot
        self.eval_env_kwargs = dict(eval_env_kwargs or {})
        self.worker_start_method = worker_start_method
        self.seed = seed
        # Public counters and records (they survive across learn() calls).
        self.eps_ticks = 0
        """Cumulative single-agent ticks simulated in EPS evaluation (add to the training ticks in plots)."""
        self.n_rounds = 0
        self.n_skipped_rounds = 0
        self.eps_time = 0.0
        self.history: list[dict[str, Any]] = []
        """One record per round: fitness of every individual, winner, gain, applied change, time, ticks."""
        self._rng: np.random.Generator | None = None
        self._generator: th.Generator | None = None
        self._pool: EnvPool | None = None
        self._pool_finalizer: weakref.finalize | None = None
        self._last_round_mark: int | None = None
        self._training_start = 0.0

    @property
    def n_individuals(self) -> int:
        """``m + 1``: the mutants plus the unmutated copy 0."""
        return self.population_size + 1

    @property
    def worker_pids(self) -> list[int]:
        """Process ids of the evaluation workers (empty when the envs run in the main process or are closed)."""
        return self._pool.pids if self._pool is not None else []

    # ------------------------------------------------------------------ SB3 hooks
    def _init_callback(self) -> None:
        q_net = self._check_model()
        self._check_eval_env()
        if self._rng is None:
            model_seed = getattr(self.model, "seed", None)
            self._rng = np.random.default_rng(self.seed if self.seed is not None else model_seed)
            device = next(q_net.parameters()).device
            self._generator = th.Generator(device=device)
            self._generator.manual_seed(int(self._rng.integers(2**62)))
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
        if self._progress() - self._last_round_mark < self.period:
            return
        if self.mutation == "safe" and not self._visited_mask(None).any():
            return  # nothing visited yet: Eq. 6 needs states; try again after the next rollout
        self._last_round_mark = self._progress()
        self._run_round()

    def _on_training_end(self) -> None:
        self._close_pool()

    # ------------------------------------------------------------------ one round (Algorithm 1, lines 3-13)
    def _run_round(self) -> None:
        start = time.perf_counter()
        q_net = self._q_net()
        theta = network_parameters(q_net)  # line 5: the copies of theta^e
        sensitivities = self._sensitivities(q_net) if self.mutation == "safe" else None  # lines 7-8
        assert self._generator is not None and self._rng is not None
        population = mutate_population(  # lines 6 and 9: G ~ N(0, sigma), theta_p = theta + G / omega
            theta, self.population_size, self.sigma, self._generator, sensitivities,
            self.sensitivity_floor, self.max_step,
        )  # fmt: skip
        episode_seeds = [int(seed) for seed in self._rng.integers(2**31 - 1, size=self.n_eval_episodes)]
        try:
            assert self._pool is not None
            result = evaluate_population(self._pool, population, episode_seeds, self.eval_timeout)  # line 10
        except EvaluationFailed as error:
            self._skip_round(error, time.perf_counter() - start)
            return
        if not result.valid.all():
            _warn_disqualified(population, result.valid)
        winner = select_best(result.fitness)  # line 11, Eq. 4 (never a disqualified individual)
        mean_change = 0.0
        if winner != 0:  # line 13, Eq. 5 (copy 0 winning would leave theta as it is)
            best = individual(population, winner)
            mean_change = polyak_crossover_(q_net, best, self.alpha)
            target = getattr(self.model.policy, "q_net_target", None)
            if isinstance(target, nn.Module):
                polyak_crossover_(target, best, self.alpha)
        self._record_round(result, winner, mean_change, time.perf_counter() - start)

    def _sensitivities(self, q_net: nn.Module) -> list[Parameters]:
        """Eq. 6 on a batch of visited observations: one for all mutants, or one per robot (``per_robot``)."""
        if not self.per_robot:
            return [self._sensitivity_of(q_net, None)]
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
        """``(rows, agents)`` bool: True where the replay buffer holds a real visited observation (an alive agent).

        :param robot: keep only this agent's column of the joint rows; None for every agent
        """
        buffer = self._model.replay_buffer
        size = int(buffer.size())
        alive = getattr(buffer, "alive", None)  # SB3's own buffers have none: every stored row is real
        mask = np.ones(buffer.observations.shape[1:2], dtype=bool)[None].repeat(size, 0)
        if alive is not None:
            mask = np.asarray(alive[:size]) > 0
        return mask if robot is None else mask[:, robot : robot + 1]

    def _visited_observations(self, robot: int | None, batch_size: int) -> th.Tensor | None:
        """Sample up to ``batch_size`` distinct visited observations (alive entries only) from the replay buffer.

        :param robot: restrict to this agent's column of the joint rows; None for every agent
        :return: ``(batch, obs_dim)`` on the network's device, or None when nothing was visited yet
        """
        mask = self._visited_mask(robot)
        candidates = np.flatnonzero(mask.reshape(-1))
        if candidates.size == 0:
            return None
        assert self._rng is not None
        chosen = np.sort(self._rng.choice(candidates, size=min(batch_size, candidates.size), replace=False))
        observations = self._model.replay_buffer.observations[: mask.shape[0]]
        if robot is not None:
            observations = observations[:, robot : robot + 1]
        flat = np.asarray(observations).reshape(-1, observations.shape[-1])
        device = next(self._q_net().parameters()).device
        return th.as_tensor(flat[chosen], dtype=th.float32, device=device)

    # ------------------------------------------------------------------ records
    def _record_round(
        self, result: PopulationResult, winner: int, mean_change: float, wall_time: float
    ) -> None:
        self.n_rounds += 1
        self.eps_ticks += int(result.lengths.sum())
        self.eps_time += wall_time
        fitness = result.fitness
        gain = float(fitness[winner] - fitness[0]) if np.isfinite(fitness[0]) else float("nan")
        finite = fitness[np.isfinite(fitness)]
        record = {
            "round": self.n_rounds,
            "model_ticks": self._model_ticks(),
            "eps_ticks": self.eps_ticks,
            "fitness": fitness.tolist(),
            "episode_lengths": result.lengths.tolist(),
            "winner": winner,
            "gain": gain,
            "mean_abs_delta": mean_change,
            "wall_time": wall_time,
            "skipped": False,
        }
        self.history.append(record)
        logger = self.logger
        logger.record("eps/round", self.n_rounds)
        logger.record("eps/ticks", self.eps_ticks)
        logger.record("eps/total_ticks", self._model_ticks() + self.eps_ticks)
        for index, value in enumerate(fitness):
            logger.record(f"eps/fitness_{index}", float(value))
        logger.record("eps/fitness_mean", float(finite.mean()) if finite.size else float("-inf"))
        logger.record("eps/fitness_max", float(fitness.max()))
        logger.record("eps/fitness_min", float(fitness.min()))
        logger.record("eps/n_invalid", int((~result.valid).sum()))
        logger.record("eps/winner", winner)
        logger.record("eps/fitness_gain", gain)
        logger.record("eps/mean_abs_delta", mean_change)
        logger.record("eps/round_time", wall_time)
        logger.record("eps/time_share", self._time_share())
        logger.record("eps/skipped_rounds", self.n_skipped_rounds)
        if self.verbose >= 1:
            print(
                f"EPS round {self.n_rounds}: copy 0 {fitness[0]:.3f}, best {fitness[winner]:.3f} (individual "
                f"{winner}), mean |dtheta| {mean_change:.2e}, {wall_time:.2f} s ({100 * self._time_share():.1f} % "
                f"of training), {self.eps_ticks} EPS ticks"
            )

    def _skip_round(self, error: EvaluationFailed, wall_time: float) -> None:
        self.n_skipped_rounds += 1
        self.eps_time += wall_time
        self.history.append(
            {"round": None, "model_ticks": self._model_ticks(), "skipped": True, "reason": str(error)}
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
        if n_workers == 0:
            self._pool = InProcessEnvPool(*arguments, batched=self.batched_forward)
        else:
            self._pool = SubprocessEnvPool(
                *arguments,
                batched=self.batched_forward,
                n_workers=n_workers,
                start_method=self.worker_start_method,
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
        if self.per_robot and int(getattr(self.model, "n_agents", 0)) < 1:
            raise ValueError("per_robot=True needs a multi-agent model (model.n_agents); set per_robot=False")
        return q_net

    def _check_eval_env(self) -> None:
        """The evaluation world must speak the model's language: equal observation and action spaces."""
        env = make_eval_env(self.eval_env_id, self.eval_env_kwargs)
        try:
            for kind in ("observation_space", "action_space"):
                ours, theirs = getattr(env, kind), getattr(self.model, kind)
                if ours != theirs:
                    raise ValueError(
                        f"the {kind} of eval_env_id {self.eval_env_id!r} ({ours}) differs from the model's "
                        f"({theirs}): pick the evaluation world that matches the training env "
                        "(envs.eps_env_id_for(training env id))"
                    )
        finally:
            env.close()


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
