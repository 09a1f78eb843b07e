"""One EPS round (Algorithm 1, lines 3-13 of Marchesini & Farinelli, ICRA 2022): copy the shared agent network,
mutate the copies, evaluate them in the evaluation worlds, select the best, reevaluate it against copy 0 and cross it
over into the network."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import torch as th
from torch import nn

from sb3_eps.eps.evaluation import (
    EnvPool,
    EvaluationFailed,
    PopulationResult,
    evaluate_population,
    population_fitness,
)
from sb3_eps.eps.mutations import (
    Parameters,
    calibrate_scale,
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
from sb3_eps.eps.settings import EPSSettings


class EPSRound:
    """Plays the rounds of one model: holds the generators, the calibrated noise scale and the tick counters.

    A subclass (``EvolutionCallback.round_class``) may change how the mutants are normalised (:meth:`sensitivities`),
    what follows an evaluation (:meth:`play`) and what surrounds the crossover (:meth:`cross_over`).

    :param evolved: names of the ``q_net`` parameters mutated and crossed over
    :param rng: generator of the buffer sampling and the episode seeds; ``generator`` that of the mutation noise
    """

    def __init__(
        self,
        settings: EPSSettings,
        model: Any,
        evolved: list[str],
        rng: np.random.Generator,
        generator: th.Generator,
    ) -> None:
        self.settings, self.model, self.evolved = settings, model, evolved
        self.rng, self.generator = rng, generator
        self.pool: EnvPool | None = None
        self.scale: float | None = None  # the last calibrated noise scale: the next calibration starts there
        self.eps_ticks = 0  # ticks simulated by EPS, all rounds together

    def run(self) -> dict[str, Any]:
        """Play one round; :return: its record (``docs/modules/eps.md``, "The round record").

        :raises EvaluationFailed: with ``record`` set to what the round measured before
        """
        settings = self.settings
        q_net = self.model.policy.q_net
        theta = network_parameters(q_net)  # line 5: the copies of theta^e
        observations = self.visited_observations(None)
        assert observations is not None
        # lines 7-8
        sensitivities = self.sensitivities(q_net, observations) if settings.mutation == "safe" else None
        directions = mutation_directions(  # lines 6 and 9 at unit scale: G ~ N(0, 1), G / omega
            theta,
            settings.population_size,
            self.generator,
            sensitivities,
            settings.sensitivity_floor,
            self.evolved,
        )
        max_step = settings.max_step if settings.mutation == "safe" else float("inf")
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
            seeds, result = self.play(population)  # line 10
            record.update(round_ticks=int(result.lengths.sum()), **_episodes_record(seeds, result))
            if not result.valid.all():
                _warn_disqualified(population, result.valid)
            winner = select_best(result.fitness)  # line 11, Eq. 4 (never a disqualified individual)
            accepted = self._accept(population, result, winner, record)
        except EvaluationFailed as error:
            error.record = record
            raise
        remaining = float(getattr(self.model, "_current_progress_remaining", 1.0))
        alpha = scheduled_alpha(settings.alpha, settings.alpha_schedule, remaining)
        record.update(winner=winner, accepted=accepted, alpha=alpha, mean_abs_delta=0.0)
        if accepted and alpha > 0:  # line 13, Eq. 5 (copy 0 winning would leave theta as it is)
            record["mean_abs_delta"] = self.cross_over(individual(population, winner), alpha, record)
        return record

    def cross_over(self, best: Parameters, alpha: float, record: dict[str, Any]) -> float:
        """Eq. 5: move the agent network (and its target network, if any) toward ``best`` by ``alpha``.

        :param record: the round's record so far
        :return: the mean absolute change of the evolved weights
        """
        delta = polyak_crossover_(self.model.policy.q_net, best, alpha, self.evolved)
        target = getattr(self.model.policy, "q_net_target", None)
        if isinstance(target, nn.Module):
            polyak_crossover_(target, best, alpha, self.evolved)
        return delta

    def visited_observations(self, robot: int | None = None) -> th.Tensor | None:
        """``sensitivity_batch_size`` visited observations of one robot (None: of every robot), or None."""
        return sample_visited_observations(self.model, self.settings.sensitivity_batch_size, self.rng, robot)

    def _mutation_scale(
        self,
        q_net: nn.Module,
        theta: Parameters,
        directions: Parameters,
        observations: th.Tensor,
        max_step: float,
    ) -> float:
        """The noise scale of this round: ``sigma``, or calibrated to ``target_flip_share`` of greedy actions."""
        settings = self.settings
        if settings.target_flip_share is None:
            return float(settings.sigma)  # type: ignore[arg-type]  # set by EPSSettings

        def flip_share_at(scale: float) -> float:
            population = population_from_directions(theta, directions, scale, max_step)
            return float(policy_change(population_outputs(q_net, population, observations))[0][1:].mean())

        initial = self.scale if self.scale is not None else float(settings.sigma)  # type: ignore[arg-type]
        self.scale, _ = calibrate_scale(flip_share_at, settings.target_flip_share, initial)
        return self.scale

    def play(self, population: Parameters, active: np.ndarray | None = None) -> tuple[list[int], PopulationResult]:
        """Play the population on fresh common-random-number episodes and count their ticks."""
        settings = self.settings
        assert self.pool is not None
        seeds = [int(seed) for seed in self.rng.integers(2**31 - 1, size=settings.n_eval_episodes)]
        result = evaluate_population(self.pool, population, seeds, settings.eval_timeout, settings.fitness, active)
        self.eps_ticks += int(result.lengths.sum())
        return seeds, result

    def _accept(self, population: Parameters, result: PopulationResult, winner: int, record: dict[str, Any]) -> bool:
        """The acceptance rule: a gain over copy 0 beyond ``min_gain``, and again on fresh episodes."""
        fitness, min_gain = result.fitness, self.settings.min_gain
        gain = float(fitness[winner] - fitness[0]) if np.isfinite(fitness[0]) else float("nan")
        finite = np.sort(fitness[np.isfinite(fitness)])
        record["gain"] = gain
        record["runner_up_margin"] = float(finite[-1] - finite[-2]) if finite.size >= 2 else float("nan")
        accepted = winner != 0 and gain_accepted(gain, min_gain)
        if accepted and self.settings.n_reevaluation_episodes > 0:
            record["reevaluation"] = self._reevaluate(population, winner)
            record["reevaluation_gain"] = record["reevaluation"]["gain"]
            accepted = gain_accepted(record["reevaluation_gain"], min_gain)
        return accepted

    def _reevaluate(self, population: Parameters, winner: int) -> dict[str, Any]:
        """Copy 0 and the winner on ``n_reevaluation_episodes`` fresh episodes (in batches of the pool's size)."""
        active = np.zeros(self.settings.n_individuals, dtype=bool)
        active[[0, winner]] = True
        pair = [0, winner]
        seeds: list[int] = []
        results = []
        for _ in range(self.settings.n_reevaluation_batches):
            batch_seeds, result = self.play(population, active)
            seeds += batch_seeds
            results.append(result)
        returns, outcomes, lengths = (
            np.concatenate([getattr(result, name)[pair] for result in results], axis=1)
            for name in ("returns", "outcomes", "lengths")
        )
        fitness = population_fitness(returns, outcomes, results[-1].valid[pair], self.settings.fitness)
        record = _episodes_record(seeds, PopulationResult(returns, lengths, results[-1].valid[pair], fitness, outcomes))
        gain = float(fitness[1] - fitness[0]) if np.isfinite(fitness[0]) else float("nan")
        return {**record, "gain": gain, "ticks": int(lengths.sum())}

    def sensitivities(self, q_net: nn.Module, observations: th.Tensor) -> list[Parameters]:
        """Eq. 6 on a batch of visited observations, one for all mutants (a list of one, or one per mutant)."""
        return [output_sensitivity(q_net, observations)]


def visited_mask(replay_buffer: Any, robot: int | None = None) -> np.ndarray:
    """``(rows, agents)`` bool: True where the replay buffer holds a visited observation (an alive agent; in SB3's
    buffers every stored row); ``robot``: only this agent's column."""
    size = int(replay_buffer.size())
    alive = getattr(replay_buffer, "alive", None)
    mask = np.ones(replay_buffer.observations.shape[1:2], dtype=bool)[None].repeat(size, 0)
    if alive is not None:
        mask = np.asarray(alive[:size]) > 0
    return mask if robot is None else mask[:, robot : robot + 1]


def sample_visited_observations(
    model: Any, batch_size: int, rng: np.random.Generator, robot: int | None = None
) -> th.Tensor | None:
    """Up to ``batch_size`` distinct visited observations (:func:`visited_mask`) of a model's replay buffer, the
    batch ``b`` of Eq. 6: ``(batch, obs_dim)`` on the network's device, or None when nothing was visited yet."""
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


def _episodes_record(seeds: list[int], result: PopulationResult) -> dict[str, Any]:
    """What a round's record keeps of an evaluation's episodes (``docs/modules/eps.md``, "The round record")."""
    return {
        "episode_seeds": seeds,
        "returns": result.returns.tolist(),
        "successes": result.successes.astype(int).tolist(),
        "outcomes": result.outcomes.tolist(),
        "episode_lengths": result.lengths.tolist(),
        "fitness": result.fitness.tolist(),
    }


def gain_accepted(gain: float, min_gain: float) -> bool:
    """The acceptance rule: a finite fitness gain over copy 0 (NaN when it was disqualified) above ``min_gain``."""
    return bool(np.isfinite(gain) and gain > min_gain)


def scheduled_alpha(alpha: float, schedule: str, progress_remaining: float) -> float:
    """Eq. 5's alpha at a point of training (``progress_remaining``: 1 at the start, 0 at the end):
    ``"constant"``, or ``"linear"`` down to 0 at the end."""
    if schedule == "constant":
        return alpha
    return alpha * float(np.clip(progress_remaining, 0.0, 1.0))
