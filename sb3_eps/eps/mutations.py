"""The math of one EPS round (Marchesini & Farinelli, ICRA 2022, Section III): the output-gradient sensitivity
(Eq. 6), the safe and the plain Gaussian mutation (Algorithm 1, line 9), the selection of the best individual
(Eq. 4) and the Polyak mean crossover (Eq. 5).

Weights travel as dictionaries ``{parameter name: tensor}`` (the names of ``network.named_parameters()``), so
that :func:`torch.func.functional_call` can run a network on any set of them. A *population* is such a
dictionary whose tensors carry a leading population axis ``(P, *parameter shape)``; individual 0 is always the
unmutated copy of the network.
"""

from __future__ import annotations

import numpy as np
import torch as th
from torch import nn
from torch.func import functional_call, jacrev, vmap

Parameters = dict[str, th.Tensor]

# Samples whose Jacobians are materialised at once in output_sensitivity: a (chunk, |y|, n_weights) float32
# block, about 56 MB for the default GDQ network (22k weights, 20 actions). The chunks bound memory; inside a
# chunk the per-sample gradients are batched by vmap.
SENSITIVITY_CHUNK_SIZE = 32


def network_parameters(network: nn.Module) -> Parameters:
    """:return: detached copies of the network's parameters, keyed by name."""
    return {name: param.detach().clone() for name, param in network.named_parameters()}


def output_sensitivity(
    network: nn.Module, observations: th.Tensor, chunk_size: int = SENSITIVITY_CHUNK_SIZE
) -> Parameters:
    """Per-weight sensitivity of the network's outputs, EPS paper Eq. 6:
    ``omega_w = (1 / |y|) * sum_y (1 / |b|) * sum_{s in b} |d y(s) / d w|``.

    The absolute value is taken per sample, before the batch mean, so gradients of opposite sign on different
    states do not cancel (Lehman et al.'s "gradient washout"). The per-sample Jacobians come from
    ``vmap(jacrev(...))`` over the batch, in chunks of ``chunk_size`` samples to bound memory.

    :param network: maps a batch of observations ``(B, obs_dim)`` to outputs ``(B, |y|)`` (the Q-values)
    :param observations: the batch ``b`` of visited observations, ``(|b|, obs_dim)``
    :param chunk_size: samples per vmapped Jacobian
    :return: ``omega`` with the network's parameter shapes
    """
    if observations.dim() != 2 or observations.shape[0] < 1:
        raise ValueError(
            f"observations must be a non-empty (batch, obs_dim) tensor, got {tuple(observations.shape)}"
        )
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
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
    """The safe mutation of Algorithm 1, line 9: ``delta = G / omega``, made safe as Lehman et al. do.

    A sensitivity of exactly 0 (a weight the batch never exercises, e.g. into a dead ReLU) is replaced by 1 so
    the weight gets plain Gaussian noise; smaller sensitivities are raised to ``floor`` so no step exceeds
    ``|G| / floor``; the step is then clipped to ``[-max_step, max_step]`` per weight.

    :param noise: Gaussian noise ``G ~ N(0, sigma)``, any shape
    :param sensitivity: ``omega`` of Eq. 6, broadcastable to ``noise``
    :param floor: lower bound on ``omega`` (> 0)
    :param max_step: bound on ``|delta|`` per weight (> 0; ``inf`` disables the clip)
    :return: the step ``delta`` with the shape of ``noise``
    """
    if floor <= 0 or max_step <= 0:
        raise ValueError(f"floor and max_step must be > 0, got {floor} and {max_step}")
    try:
        broadcast = th.broadcast_shapes(noise.shape, sensitivity.shape)
    except RuntimeError:
        broadcast = None
    if broadcast != noise.shape:
        raise ValueError(
            f"sensitivity {tuple(sensitivity.shape)} does not broadcast to noise {tuple(noise.shape)}"
        )
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
) -> Parameters:
    """The population of Algorithm 1, lines 5-9: ``n_mutants + 1`` copies of ``parameters``, every copy but
    copy 0 perturbed by ``G ~ N(0, sigma)`` per weight, normalised by the sensitivity when one is given.

    :param parameters: the network's weights ``theta``
    :param n_mutants: ``m``, the number of mutated copies (>= 1)
    :param sigma: standard deviation of ``G`` (> 0)
    :param generator: torch generator of the noise (on the parameters' device)
    :param sensitivities: None for the plain Gaussian mutation; else one ``omega`` (Eq. 6) shared by all
        mutants (a list of one) or one per mutant (a list of ``n_mutants``)
    :param floor: see :func:`safe_mutation_step`
    :param max_step: see :func:`safe_mutation_step`
    :return: the population, each tensor ``(n_mutants + 1, *shape)``; row 0 equals ``parameters``
    """
    if n_mutants < 1 or sigma <= 0:
        raise ValueError(f"n_mutants must be >= 1 and sigma > 0, got {n_mutants} and {sigma}")
    if sensitivities is not None and len(sensitivities) not in (1, n_mutants):
        raise ValueError(f"give 1 or {n_mutants} sensitivities, got {len(sensitivities)}")
    population: Parameters = {}
    for name, theta in parameters.items():
        noise = th.randn(
            (n_mutants, *theta.shape), generator=generator, device=theta.device, dtype=theta.dtype
        )
        noise = noise * sigma
        if sensitivities is None:
            steps = noise
        else:
            omega = th.stack([sensitivity[name] for sensitivity in sensitivities])
            steps = safe_mutation_step(noise, omega, floor, max_step)
        population[name] = th.cat([theta.unsqueeze(0), theta.unsqueeze(0) + steps])
    return population


def select_best(fitness: np.ndarray) -> int:
    """The best individual, EPS paper Eq. 4: ``theta* = argmax_p F_p``.

    Non-finite fitness (an individual with NaN/inf weights or outputs) counts as ``-inf`` and can never win;
    ties go to the lowest index, so the unmutated copy 0 wins unless a mutant is strictly better.

    :param fitness: ``(P,)`` average returns
    :return: the winner's index
    """
    fitness = np.asarray(fitness, dtype=np.float64)
    if fitness.ndim != 1 or fitness.size < 1:
        raise ValueError(f"fitness must be a non-empty 1-D array, got shape {fitness.shape}")
    safe = np.where(np.isfinite(fitness), fitness, -np.inf)
    return int(np.argmax(safe))


def polyak_crossover_(network: nn.Module, best: Parameters, alpha: float) -> float:
    """Mean crossover by Polyak averaging, EPS paper Eq. 5: ``theta = alpha * theta* + (1 - alpha) * theta``,
    in place on ``network``'s parameters.

    :param network: the network to move toward the best individual (the online or the target agent network)
    :param best: the best individual's weights ``theta*``
    :param alpha: share of the best individual, in [0, 1]
    :return: the mean ``|delta theta|`` over all weights
    """
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    total_change, n_weights = 0.0, 0
    with th.no_grad():
        for name, param in network.named_parameters():
            if best[name].shape != param.shape:
                raise ValueError(f"{name}: best {tuple(best[name].shape)} != network {tuple(param.shape)}")
            mixed = alpha * best[name] + (1.0 - alpha) * param  # Eq. 5
            total_change += float((mixed - param).abs().sum())
            n_weights += param.numel()
            param.copy_(mixed)
    return total_change / max(n_weights, 1)


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
