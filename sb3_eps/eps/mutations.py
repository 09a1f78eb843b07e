"""The math of one EPS round (Marchesini & Farinelli, ICRA 2022, Section III: Eq. 4-6, Algorithm 1 line 9) and what
this package adds (``docs/modules/eps.md``, "Beyond Algorithm 1"). Weights travel as ``{parameter name: tensor}``; a
*population* stacks them on a leading axis ``(P, *shape)``, individual 0 the unmutated copy.
"""

from __future__ import annotations

from collections.abc import Callable, Collection

import numpy as np
import torch as th
from torch import nn
from torch.func import functional_call, jacrev, vmap

Parameters = dict[str, th.Tensor]

# Samples whose Jacobians output_sensitivity holds at once: (chunk, |y|, n_weights) float32, about 56 MB for GDQ.
SENSITIVITY_CHUNK_SIZE = 32


def network_parameters(network: nn.Module) -> Parameters:
    """:return: detached copies of the network's parameters, keyed by name."""
    return {name: param.detach().clone() for name, param in network.named_parameters()}


def output_sensitivity(network: nn.Module, observations: th.Tensor, chunk_size: int = SENSITIVITY_CHUNK_SIZE) -> Parameters:
    """Per-weight sensitivity of the network's outputs on the visited ``observations`` ``(|b|, obs_dim)``, EPS paper
    Eq. 6: ``omega_w = (1 / |y|) * sum_y (1 / |b|) * sum_{s in b} |d y(s) / d w|``. The absolute value is taken per
    sample, so gradients of opposite sign do not cancel (Lehman et al.'s "gradient washout").

    :return: ``omega`` with the network's parameter shapes
    """
    if observations.dim() != 2 or observations.shape[0] < 1:
        raise ValueError(f"observations must be a non-empty (batch, obs_dim) tensor, got {tuple(observations.shape)}")
    parameters = {name: param.detach() for name, param in network.named_parameters()}
    buffers = dict(network.named_buffers())

    def outputs_of_one(weights: Parameters, observation: th.Tensor) -> th.Tensor:
        return functional_call(network, (weights, buffers), (observation.unsqueeze(0),)).reshape(-1)

    per_sample_jacobian = vmap(jacrev(outputs_of_one), in_dims=(None, 0))
    totals = {name: th.zeros_like(param) for name, param in parameters.items()}
    n_outputs = 0
    for chunk in observations.detach().split(chunk_size):
        jacobian = per_sample_jacobian(parameters, chunk)  # name -> (chunk, |y|, *parameter shape)
        for name, block in jacobian.items():
            totals[name] += block.abs().sum(dim=(0, 1))
            n_outputs = block.shape[1]
    # Eq. 6: the batch mean of |grad|, then the mean over the |y| outputs.
    scale = 1.0 / (observations.shape[0] * n_outputs)
    return {name: total * scale for name, total in totals.items()}


def safe_mutation_step(noise: th.Tensor, sensitivity: th.Tensor, floor: float, max_step: float) -> th.Tensor:
    """The safe mutation of Algorithm 1, line 9: ``delta = G / omega``, made safe as Lehman et al. do: a sensitivity of
    exactly 0 (a weight never exercised) becomes 1, smaller ones are raised to ``floor``, and the step is clipped to
    ``[-max_step, max_step]`` per weight. ``sensitivity`` broadcasts to ``noise``."""
    try:
        broadcast = th.broadcast_shapes(noise.shape, sensitivity.shape)
    except RuntimeError:
        broadcast = None
    if broadcast != noise.shape:
        raise ValueError(f"sensitivity {tuple(sensitivity.shape)} does not broadcast to noise {tuple(noise.shape)}")
    omega = th.where(sensitivity == 0, th.ones_like(sensitivity), sensitivity).clamp_min(floor)
    return (noise / omega).clamp(-max_step, max_step)


def mutate_population(
    parameters: Parameters,
    n_mutants: int,
    sigma: float,
    generator: th.Generator,
    sensitivities: list[Parameters] | None = None,
    floor: float = 0.01,
    max_step: float = 0.2,
    names: Collection[str] | None = None,
) -> Parameters:
    """The population of Algorithm 1, lines 5-9: ``n_mutants + 1`` copies of ``parameters``, every copy but copy 0
    perturbed by ``G ~ N(0, sigma)`` per weight, normalised by the sensitivity when one is given.

    :param sensitivities: None for the plain Gaussian mutation; else one ``omega`` (Eq. 6) shared by all mutants
        or one per mutant (``floor``, ``max_step``: :func:`safe_mutation_step`)
    :param names: the parameters to mutate (None: all)
    :return: the population, each tensor ``(n_mutants + 1, *shape)``
    """
    directions = mutation_directions(parameters, n_mutants, generator, sensitivities, floor, names)
    # Lehman et al.'s clip belongs to the safe step; plain Gaussian noise is left unclipped.
    return population_from_directions(parameters, directions, sigma, max_step if sensitivities is not None else float("inf"))


def mutation_directions(
    parameters: Parameters,
    n_mutants: int,
    generator: th.Generator,
    sensitivities: list[Parameters] | None = None,
    floor: float = 0.01,
    names: Collection[str] | None = None,
) -> Parameters:
    """Unit-scale mutation steps ``G / omega`` with ``G ~ N(0, 1)`` (one ``randn`` per parameter, in order), which
    :func:`population_from_directions` scales, so the scale can be calibrated without drawing new noise.

    :return: ``{name: (n_mutants, *shape)}`` for the mutated parameters only (arguments as
        :func:`mutate_population`)
    """
    directions: Parameters = {}
    for name, theta in parameters.items():
        if names is not None and name not in names:
            continue
        noise = th.randn((n_mutants, *theta.shape), generator=generator, device=theta.device, dtype=theta.dtype)
        if sensitivities is not None:
            omega = th.stack([sensitivity[name] for sensitivity in sensitivities])
            noise = safe_mutation_step(noise, omega, floor, float("inf"))
        directions[name] = noise
    return directions


def population_from_directions(
    parameters: Parameters, directions: Parameters, scale: float, max_step: float = float("inf")
) -> Parameters:
    """``theta_p = theta + clip(scale * direction_p, -max_step, max_step)`` for every mutant ``p``; copy 0 and the
    parameters without a direction stay ``theta``. :return: each tensor ``(n_mutants + 1, *shape)``"""
    n_mutants = next(iter(directions.values())).shape[0]
    population: Parameters = {}
    for name, theta in parameters.items():
        copies = theta.unsqueeze(0).expand(n_mutants + 1, *theta.shape).clone()
        if name in directions:
            copies[1:] += (scale * directions[name]).clamp(-max_step, max_step)
        population[name] = copies
    return population


def population_outputs(network: nn.Module, population: Parameters, observations: th.Tensor) -> th.Tensor:
    """Outputs ``(P, B, n_outputs)`` of every individual on the same observations ``(B, obs_dim)``; parameters
    missing from the population are taken from ``network``."""
    buffers = dict(network.named_buffers())
    fixed = {name: param.detach() for name, param in network.named_parameters() if name not in population}

    def outputs_of(weights: Parameters) -> th.Tensor:
        return functional_call(network, ({**fixed, **weights}, buffers), (observations,))

    with th.no_grad():
        return vmap(outputs_of)(population)


def policy_change(outputs: th.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """How much each individual's greedy policy differs from individual 0's, from Q-values ``(P, B, n_actions)``.

    :return: per individual, the share of observations whose greedy action changed (NaN outputs count as changed)
        and the mean ``|Q_p - Q_0|``
    """
    if outputs.dim() != 3 or outputs.shape[0] < 1:
        raise ValueError(f"outputs must be (P, B, n_actions), got {tuple(outputs.shape)}")
    greedy = outputs.argmax(dim=-1)
    changed = (greedy != greedy[:1]) | ~th.isfinite(outputs).all(dim=-1)
    flip_share = changed.float().mean(dim=1)
    mean_abs_dq = (outputs - outputs[:1]).abs().mean(dim=(1, 2))
    return flip_share.cpu().numpy().astype(np.float64), mean_abs_dq.cpu().numpy().astype(np.float64)


def calibrate_scale(
    flip_share_at: Callable[[float], float],
    target: float,
    initial: float,
    tolerance: float = 0.2,
    max_evaluations: int = 24,
    bounds: tuple[float, float] = (1e-9, 1e3),
) -> tuple[float, float]:
    """Find a noise scale whose mutants change a ``target`` share of greedy actions (``docs/modules/eps.md``): scale
    by factors of 4 from ``initial`` until the target is bracketed, then bisect in log space until the share is
    within ``tolerance * target``.

    :param flip_share_at: the mean share of greedy actions changed by the mutants at a scale
    :return: the scale and its share (the closest tried, in log-ratio, when the tolerance was not met)
    """
    if not 0.0 < target < 1.0:
        raise ValueError(f"target flip share must be in (0, 1), got {target}")
    low_bound, high_bound = bounds
    scale = float(np.clip(initial, low_bound, high_bound))
    low: tuple[float, float] | None = None  # (scale, share) with share < target
    high: tuple[float, float] | None = None  # with share > target
    best = (scale, float("nan"))

    def closeness(share: float) -> float:
        return abs(np.log(max(share, 1e-6) / target))

    for _ in range(max_evaluations):
        share = float(flip_share_at(scale))
        if np.isnan(best[1]) or closeness(share) < closeness(best[1]):
            best = (scale, share)
        if abs(share - target) <= tolerance * target:
            return scale, share
        if share < target:
            low = (scale, share)
        else:
            high = (scale, share)
        if low is not None and high is not None:
            scale = float(np.sqrt(low[0] * high[0]))
        elif high is None:
            if scale >= high_bound:
                break
            scale = min(scale * 4.0, high_bound)
        else:
            if scale <= low_bound:
                break
            scale = max(scale / 4.0, low_bound)
    return best


def select_best(fitness: np.ndarray) -> int:
    """The best individual, EPS paper Eq. 4: ``theta* = argmax_p F_p``; non-finite fitness never wins, and ties go to
    the lowest index (copy 0 wins unless a mutant is strictly better)."""
    fitness = np.asarray(fitness, dtype=np.float64)
    if fitness.ndim != 1 or fitness.size < 1:
        raise ValueError(f"fitness must be a non-empty 1-D array, got shape {fitness.shape}")
    safe = np.where(np.isfinite(fitness), fitness, -np.inf)
    return int(np.argmax(safe))


def polyak_crossover_(network: nn.Module, best: Parameters, alpha: float, names: Collection[str] | None = None) -> float:
    """Mean crossover by Polyak averaging, EPS paper Eq. 5: ``theta = alpha * theta* + (1 - alpha) * theta``, in place
    on ``network``'s parameters ``names`` (None: all). :return: the mean ``|delta theta|``"""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    total_change, n_weights = 0.0, 0
    with th.no_grad():
        for name, param in network.named_parameters():
            if names is not None and name not in names:
                continue
            if best[name].shape != param.shape:
                raise ValueError(f"{name}: best {tuple(best[name].shape)} != network {tuple(param.shape)}")
            mixed = alpha * best[name] + (1.0 - alpha) * param  # Eq. 5
            total_change += float((mixed - param).abs().sum())
            n_weights += param.numel()
            param.copy_(mixed)
    return total_change / max(n_weights, 1)


def evolved_parameter_names(network: nn.Module, frozen_groups: Collection[str]) -> list[str]:
    """The parameters EPS mutates and crosses over, in order: all but those under a frozen group (module names such
    as ``"value_stream"``, or parameter names)."""
    names = [name for name, _ in network.named_parameters()]
    for group in frozen_groups:
        if not any(name == group or name.startswith(f"{group}.") for name in names):
            groups = sorted({name.split(".")[0] for name in names})
            raise ValueError(f"frozen_groups: {group!r} names no parameter of the agent network; its groups are {groups}")
    evolved = [name for name in names if not any(name == group or name.startswith(f"{group}.") for group in frozen_groups)]
    if not evolved:
        raise ValueError(f"frozen_groups {list(frozen_groups)} leave no parameter to evolve")
    return evolved


def individual(population: Parameters, index: int) -> Parameters:
    """:return: the weights of individual ``index`` of a population."""
    return {name: stacked[index] for name, stacked in population.items()}


def finite_individuals(population: Parameters) -> np.ndarray:
    """:return: ``(P,)`` bool, True where every weight of the individual is finite."""
    size = next(iter(population.values())).shape[0]
    finite = th.ones(size, dtype=th.bool)
    for stacked in population.values():
        finite &= th.isfinite(stacked.reshape(size, -1)).all(dim=1).cpu()
    return finite.numpy()
