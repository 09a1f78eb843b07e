"""Crossover by Q-filtered distillation (Bodnar et al., "Proximal Distilled Evolutionary Reinforcement Learning",
AAAI 2020, Section 4.1), for Q-networks: a child network learns, state by state, the Q-values of the parent that
values its own greedy action higher.

Polyak averaging (:func:`~sb3_eps.eps.mutations.polyak_crossover_`, EPS Eq. 5) mixes weights, which is meaningful
only for networks that are small perturbations of one another; two separately trained learners' hidden units
need not line up, so the mean of their weights can act like neither. Distillation mixes behaviour instead: the
parents may even have different architectures from each other and from the child.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch as th
from torch import nn


@dataclass
class DistillationResult:
    """What a distillation did.

    :param teacher_share: per parent, the share of the states on which it was the teacher
    :param agreement: share of the states where the child's greedy action is its teacher's, after training
    :param loss: the last gradient step's mean squared error to the teachers' Q-values
    """

    teacher_share: list[float]
    agreement: float
    loss: float


def q_filter(parents: Sequence[nn.Module], observations: th.Tensor, critic: nn.Module | None = None) -> th.Tensor:
    """The Q-filter: per state, the parent whose greedy action is valued highest.

    :param parents: Q-networks mapping ``(B, obs_dim)`` to ``(B, n_actions)``
    :param observations: ``(B, obs_dim)``
    :param critic: judges every parent's greedy action with its own ``Q(s, a)``; None: each parent judges its own
        (``max_a Q_p(s, a)``)
    :return: ``(B,)`` index of each state's teacher
    """
    with th.no_grad():
        scores = []
        for parent in parents:
            q_values = parent(observations)
            if critic is None:
                scores.append(q_values.max(dim=1).values)
            else:
                greedy = q_values.argmax(dim=1, keepdim=True)
                scores.append(critic(observations).gather(1, greedy).squeeze(1))
        return th.stack(scores, dim=1).argmax(dim=1)


def q_filtered_distillation(
    child: nn.Module,
    parents: Sequence[nn.Module],
    observations: th.Tensor,
    n_steps: int = 300,
    batch_size: int = 64,
    learning_rate: float = 1e-3,
    critic: nn.Module | None = None,
    generator: th.Generator | None = None,
) -> DistillationResult:
    """Train ``child`` in place to imitate, on each state, its teacher's Q-values (the teacher is chosen by
    :func:`q_filter`): ``min E_s || Q_child(s) - Q_teacher(s)(s) ||^2`` by Adam on minibatches of ``observations``.
    PDERL regresses its actors' actions; regressing the whole Q-vector keeps the child a Q-network that temporal-
    difference learning can go on from.

    :param child: the network trained (usually starts as a copy of the fitter parent; any architecture with the
        parents' input and output sizes)
    :param parents: two or more Q-networks, left unchanged
    :param observations: ``(N, obs_dim)`` visited states (replay states of the parents)
    :param n_steps: gradient steps (>= 1)
    :param batch_size: states per step (>= 1; at most ``N`` are used)
    :param learning_rate: Adam's step size (> 0)
    :param critic: see :func:`q_filter`
    :param generator: torch generator of the minibatch draws (on the observations' device)
    :return: the teachers' shares, the child's agreement with its teachers and its last loss
    """
    if len(parents) < 2:
        raise ValueError(f"distillation needs at least 2 parents, got {len(parents)}")
    if observations.dim() != 2 or observations.shape[0] < 1:
        raise ValueError(f"observations must be a non-empty (N, obs_dim) tensor, got {tuple(observations.shape)}")
    if n_steps < 1 or batch_size < 1 or not learning_rate > 0:
        raise ValueError(
            f"n_steps and batch_size must be >= 1 and learning_rate > 0, got {n_steps}, {batch_size}, {learning_rate}"
        )
    observations = observations.detach()
    teacher = q_filter(parents, observations, critic)
    with th.no_grad():
        all_targets = th.stack([parent(observations) for parent in parents], dim=1)  # (N, P, n_actions)
        targets = all_targets[th.arange(observations.shape[0]), teacher]
    if targets.shape[1:] != child(observations[:1]).shape[1:]:
        raise ValueError(f"child outputs {tuple(child(observations[:1]).shape[1:])}, parents {tuple(targets.shape[1:])}")
    optimizer = th.optim.Adam(child.parameters(), lr=learning_rate)
    size = min(batch_size, observations.shape[0])
    loss = th.zeros(())
    for _ in range(n_steps):
        batch = th.randint(observations.shape[0], (size,), generator=generator, device=observations.device)
        loss = nn.functional.mse_loss(child(observations[batch]), targets[batch])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with th.no_grad():
        agreement = (child(observations).argmax(dim=1) == targets.argmax(dim=1)).float().mean()
    shares = th.bincount(teacher, minlength=len(parents)).float() / observations.shape[0]
    return DistillationResult(shares.tolist(), float(agreement), float(loss.detach()))
