"""Q-filtered distillation: the child learns each state's better parent, where averaging the parents' weights fails."""

from __future__ import annotations

import copy

import pytest
import torch as th
from torch import nn

from research.population.distillation import q_filter, q_filtered_distillation
from sb3_eps.eps.mutations import network_parameters, polyak_crossover_


def hand_made_parent(positive_half: list[float], negative_half: list[float]) -> nn.Module:
    """``Q(s) = relu(x) * positive_half + relu(-x) * negative_half`` for ``s = (x, y)``: a two-unit ReLU network whose
    hidden layer is the same for every parent, so the mean of two parents' weights is the mean of their Q-values."""
    network = nn.Sequential(nn.Linear(2, 2), nn.ReLU(), nn.Linear(2, 3))
    with th.no_grad():
        network[0].weight.copy_(th.tensor([[1.0, 0.0], [-1.0, 0.0]]))
        network[0].bias.zero_()
        network[2].weight.copy_(th.tensor([positive_half, negative_half]).T)
        network[2].bias.zero_()
    return network


# Parent A is confident (max Q 1) and right (action 0) where x > 0; parent B is confident (action 2) where x < 0. Each
# disagrees strongly with the other's choice, so the mean of their Q-values (Polyak averaging at alpha 0.5) picks
# neither parent's action on either half.
PARENT_A = ([1.0, 0.0, -2.0], [0.0, 0.2, -2.0])
PARENT_B = ([-2.0, 0.0, 0.2], [0.0, 0.0, 1.0])
RIGHT_ACTION = {"x > 0": 0, "x < 0": 2}


@pytest.fixture
def states() -> th.Tensor:
    generator = th.Generator().manual_seed(0)
    return th.rand((512, 2), generator=generator) * 2 - 1


def agreement_by_half(network: nn.Module, states: th.Tensor) -> dict[str, float]:
    with th.no_grad():
        greedy = network(states).argmax(dim=1)
    halves = {"x > 0": states[:, 0] > 0, "x < 0": states[:, 0] < 0}
    return {name: float((greedy[mask] == RIGHT_ACTION[name]).float().mean()) for name, mask in halves.items()}


def test_the_q_filter_picks_the_parent_that_values_its_greedy_action_highest(states) -> None:
    parents = [hand_made_parent(*PARENT_A), hand_made_parent(*PARENT_B)]
    teacher = q_filter(parents, states)
    assert th.equal(teacher, (states[:, 0] < 0).long())
    # A critic that values action 1 above all overrules the parents' own judgement: B's action 2 loses to A's 1.
    critic = hand_made_parent([0.0, 5.0, 0.0], [0.0, 5.0, 0.0])
    assert th.equal(
        q_filter(parents, states, critic)[states[:, 0] < 0],
        th.zeros(int((states[:, 0] < 0).sum()), dtype=th.long),
    )


def test_the_child_matches_each_halfs_better_parent_and_polyak_averaging_does_not(states) -> None:
    parents = [hand_made_parent(*PARENT_A), hand_made_parent(*PARENT_B)]
    before = [copy.deepcopy(network_parameters(parent)) for parent in parents]

    averaged = copy.deepcopy(parents[0])
    polyak_crossover_(averaged, network_parameters(parents[1]), alpha=0.5)
    for share in agreement_by_half(averaged, states).values():
        assert share < 0.05

    # A child of another architecture, started from scratch: distillation moves behaviour, not weights.
    th.manual_seed(0)
    child = nn.Sequential(nn.Linear(2, 32), nn.ReLU(), nn.Linear(32, 32), nn.ReLU(), nn.Linear(32, 3))
    result = q_filtered_distillation(
        child, parents, states, n_steps=400, learning_rate=3e-3, generator=th.Generator().manual_seed(1)
    )
    for share in agreement_by_half(child, states).values():
        assert share > 0.95
    assert result.agreement > 0.95
    assert result.teacher_share == pytest.approx(
        [float((states[:, 0] > 0).float().mean()), float((states[:, 0] < 0).float().mean())]
    )
    for parent, weights in zip(parents, before, strict=True):  # the parents are left as they were
        for name, value in network_parameters(parent).items():
            assert th.equal(value, weights[name])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_steps": 0}, "n_steps and batch_size must be >= 1"),
        ({"learning_rate": 0.0}, "learning_rate > 0"),
    ],
)
def test_bad_settings_are_one_line_errors(states, kwargs, message) -> None:
    parents = [hand_made_parent(*PARENT_A), hand_made_parent(*PARENT_B)]
    with pytest.raises(ValueError, match=message):
        q_filtered_distillation(copy.deepcopy(parents[0]), parents, states, **kwargs)
    with pytest.raises(ValueError, match="at least 2 parents"):
        q_filtered_distillation(copy.deepcopy(parents[0]), parents[:1], states)
    with pytest.raises(ValueError, match="child outputs"):
        q_filtered_distillation(nn.Linear(2, 4), parents, states)
