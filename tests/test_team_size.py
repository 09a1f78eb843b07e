"""Team-size transfer: GDQ's pooled global head reads any number of agents."""

from __future__ import annotations

import pytest
import torch as th

from sb3_eps.gdq.policies import PooledGlobalValueNetwork


@pytest.mark.parametrize("n_agents", [2, 4, 12])
def test_the_pooled_head_starts_as_the_mean_of_any_number_of_values(n_agents):
    head = PooledGlobalValueNetwork(4, init="mean")
    values = th.randn(7, n_agents)
    assert th.allclose(head(values), values.mean(dim=1), atol=1e-5)


def test_the_pooled_head_sum_initialisation_scales_the_mean_by_the_team_it_was_built_for():
    head = PooledGlobalValueNetwork(4, init="sum")
    values = th.tensor([[1.0, 2.0, 3.0, 6.0]])
    assert th.allclose(head(values), th.tensor([12.0]), atol=1e-5)


def test_the_pooled_head_does_not_depend_on_the_agents_order():
    th.manual_seed(0)
    head = PooledGlobalValueNetwork(3, init="random")
    values = th.randn(5, 3)
    assert th.allclose(head(values), head(values[:, [2, 0, 1]]), atol=1e-6)


def test_the_pooled_head_refuses_what_is_not_a_batch_of_agent_values():
    with pytest.raises(ValueError, match="batch, agents"):
        PooledGlobalValueNetwork(2)(th.zeros(3))
