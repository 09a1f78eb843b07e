"""Hand computations on tiny tensors for the math that can be wrong (STYLE.md point 4)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_eps.common.buffers import (
    JointReplayBuffer,
    JointTick,
    NStepJointCollector,
    PrioritizedJointReplayBuffer,
    SumTree,
    _n_step_row_all_alive,
    _n_step_row_general,
    n_step_row,
)
from sb3_eps.common.losses import masked_huber
from sb3_eps.common.utils import dueling_aggregation, td_target
from sb3_eps.gdq import GlobalValueNetwork, gdq_agent_targets
from sb3_eps.qmix import QMixer, SumMixer

GAMMA = 0.9


def test_dueling_aggregation_matches_hand_computation() -> None:
    values = th.tensor([[2.0], [-1.0]])
    advantages = th.tensor([[1.0, 2.0, 3.0], [0.0, 0.0, 6.0]])
    # Row 0: mean A = 2 -> Q = 2 + [-1, 0, 1]; row 1: mean A = 2 -> Q = -1 + [-2, -2, 4].
    expected = th.tensor([[1.0, 2.0, 3.0], [-3.0, -3.0, 3.0]])
    assert th.allclose(dueling_aggregation(values, advantages), expected)
    assert th.equal(dueling_aggregation(values, advantages).argmax(1), advantages.argmax(1))


def test_dueling_aggregation_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match="values"):
        dueling_aggregation(th.zeros(2, 3), th.zeros(2, 3))


def test_td_target_hand_computation() -> None:
    target = td_target(th.tensor([1.0, 1.0]), th.tensor([0.81, 0.81]), th.tensor([0.0, 1.0]), th.tensor([10.0, 10.0]))
    assert th.allclose(target, th.tensor([1.0 + 8.1, 1.0]))


def test_gdq_agent_target_uses_global_value_instead_of_own_value() -> None:
    rewards = th.tensor([[0.5, -1.0]])
    discounts = th.tensor([[GAMMA, GAMMA]])
    dones = th.tensor([[0.0, 1.0]])
    global_next = th.tensor([3.0])
    advantage_term = th.tensor([[0.2, 0.7]])
    targets = gdq_agent_targets(rewards, discounts, dones, global_next, advantage_term)
    # agent 0: 0.5 + 0.9 * (3.0 + 0.2); agent 1 terminated: -1.
    assert th.allclose(targets, th.tensor([[0.5 + 0.9 * 3.2, -1.0]]))


def test_gdq_lambda_target_blends_global_and_own_value() -> None:
    # lambda = 0.25: bootstrap value 0.25 * V_G' + 0.75 * V_i' = 0.25 * 2.0 + 0.75 * [1.0, -1.0] = [1.25, -0.25]
    target = gdq_agent_targets(
        th.tensor([[0.1, 0.2]]), th.full((1, 2), GAMMA), th.zeros(1, 2), th.tensor([2.0]),
        th.tensor([[0.5, 0.0]]), own_next_value=th.tensor([[1.0, -1.0]]), global_bootstrap=0.25,
    )  # fmt: skip
    assert th.allclose(target, th.tensor([[0.1 + GAMMA * 1.75, 0.2 + GAMMA * -0.25]]))
    with pytest.raises(ValueError, match="needs own_next_value"):
        gdq_agent_targets(th.zeros(1, 2), th.ones(1, 2), th.zeros(1, 2), th.zeros(1), th.zeros(1, 2), None, 0.5)


def test_global_value_target_hand_computation() -> None:
    # V_G target = r_team + gamma^k (1 - done) V_G'(v'), one-step: 0.3 + 0.9 * 2.0
    target = td_target(th.tensor([0.3]), th.tensor([GAMMA]), th.tensor([0.0]), th.tensor([2.0]))
    assert th.allclose(target, th.tensor([2.1]))


@pytest.mark.parametrize("n_agents", [2, 4, 12])
@pytest.mark.parametrize(("init", "scale"), [("sum", 1.0), ("mean", None)])
def test_global_head_init_computes_sum_or_mean_exactly(n_agents: int, init: str, scale: float | None) -> None:
    th.manual_seed(0)
    head = GlobalValueNetwork(n_agents, [64, 64], init=init)
    values = th.randn(32, n_agents) * 3.0
    expected = values.sum(dim=1) * (scale if scale is not None else 1.0 / n_agents)
    assert th.allclose(head(values), expected, atol=1e-5)
    # The free units stay trainable: the output weights see their (non-zero) activations in the gradient.
    head(values).sum().backward()
    last = [module for module in head.net if isinstance(module, th.nn.Linear)][-1]
    assert last.weight.grad is not None and last.weight.grad[0, 2 * n_agents :].abs().sum() > 0


def test_global_head_random_init_is_not_the_sum() -> None:
    th.manual_seed(0)
    head = GlobalValueNetwork(2, [64, 64], init="random")
    values = th.randn(32, 2)
    assert not th.allclose(head(values), values.sum(dim=1), atol=1e-2)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"init": "identity"}, "global_init must be one of"),
        ({"init": "sum", "net_arch": [64, 3]}, "at least 2 \\* n_agents = 4"),
        ({"init": "sum", "activation_fn": th.nn.Tanh}, "needs activation_fn=nn.ReLU"),
    ],
)
def test_global_head_init_rejects_what_it_cannot_build(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        GlobalValueNetwork(2, **kwargs)


def test_qmix_mixer_is_monotonic_in_every_agent_q() -> None:
    th.manual_seed(0)
    mixer = QMixer(n_agents=3, state_dim=5, embed_dim=8, hypernet_hidden_dim=16)
    agent_qs = th.randn(64, 3, requires_grad=True)
    states = th.randn(64, 5)
    mixer(agent_qs, states).sum().backward()
    assert agent_qs.grad is not None
    assert (agent_qs.grad >= 0).all()
    assert (agent_qs.grad > 0).any()


def test_qmix_mixer_rejects_wrong_shapes() -> None:
    mixer = QMixer(n_agents=2, state_dim=3)
    with pytest.raises(ValueError, match="QMixer expects"):
        mixer(th.zeros(4, 3), th.zeros(4, 3))


def test_vdn_mixer_is_the_sum() -> None:
    assert th.allclose(SumMixer()(th.tensor([[1.0, 2.0, -0.5]])), th.tensor([2.5]))


def test_masked_huber_ignores_dead_agents() -> None:
    prediction = th.tensor([[1.0, 100.0]])
    target = th.tensor([[0.5, 0.0]])
    loss = masked_huber(prediction, target, th.tensor([[1.0, 0.0]]), th.tensor([1.0]))
    assert th.isclose(loss, th.tensor(0.5 * 0.5**2))


def _tick(rewards, alive, ended=(False, False), terminated=(False, False), world_end=False, tag=0):
    n_agents = len(rewards)
    tick = JointTick(
        observations=np.full((n_agents, 1), tag, dtype=np.float32),
        actions=np.zeros(n_agents, dtype=np.int64),
        rewards=np.array(rewards, dtype=np.float32),
        next_observations=np.full((n_agents, 1), tag + 1, dtype=np.float32),
        ended=np.array(ended),
        truncated=np.array(ended) & ~np.array(terminated),
        alive=np.array(alive),
        state=np.array([tag], dtype=np.float32),
        next_state=np.array([tag + 1], dtype=np.float32),
        world_ended=world_end,
    )
    assert tick.terminated.tolist() == list(terminated)
    return tick


def test_n_step_return_across_an_agent_terminal() -> None:
    # Agent 0 arrives at tick 1 (terminal for it); agent 1 keeps going.
    window = [
        _tick([0.1, 0.2], [True, True], tag=0),
        _tick([1.0, 0.3], [True, True], ended=(True, False), terminated=(True, False), tag=1),
        _tick([0.0, 0.4], [False, True], tag=2),
    ]
    row = n_step_row(window, GAMMA)
    assert row.rewards[0] == pytest.approx(0.1 + GAMMA * 1.0)
    assert row.rewards[1] == pytest.approx(0.2 + GAMMA * 0.3 + GAMMA**2 * 0.4)
    assert row.dones.tolist() == [1.0, 0.0]
    assert row.discounts == pytest.approx([GAMMA**2, GAMMA**3])
    assert row.next_alive.tolist() == [0.0, 1.0]
    assert row.team_reward == pytest.approx(0.3 + GAMMA * 1.3 + GAMMA**2 * 0.4)
    assert row.team_done == 0.0 and row.team_discount == pytest.approx(GAMMA**3)
    assert row.next_observations[1, 0] == 3.0 and row.state[0] == 0.0 and row.next_state[0] == 3.0


@pytest.mark.parametrize("mode", ["sum", "mean"])
def test_n_step_fast_path_equals_the_general_fold(mode: str) -> None:
    rng = np.random.default_rng(0)
    for trial in range(300):
        n_ticks, n_agents = int(rng.integers(1, 6)), int(rng.integers(1, 5))
        last_ends = rng.random(n_agents) < 0.3
        window = [
            _tick(
                rng.normal(size=n_agents).astype(np.float32).tolist(), [True] * n_agents,
                ended=tuple(last_ends) if k == n_ticks - 1 else (False,) * n_agents,
                terminated=tuple(last_ends & (rng.random(n_agents) < 0.5)) if k == n_ticks - 1 else (False,) * n_agents,
                world_end=bool(k == n_ticks - 1 and last_ends.all()), tag=k,
            )
            for k in range(n_ticks)
        ]  # fmt: skip
        fast, general = _n_step_row_all_alive(window, 0.97, mode), _n_step_row_general(window, 0.97, mode)
        for field in dataclasses.fields(fast):
            name = field.name
            assert np.array_equal(np.asarray(getattr(fast, name)), np.asarray(getattr(general, name))), (trial, name)
        assert n_step_row(window, 0.97, mode) is not None


def test_n_step_return_across_a_truncation_bootstraps() -> None:
    window = [
        _tick([0.1, 0.1], [True, True], tag=0),
        _tick([0.2, 0.2], [True, True], ended=(True, True), world_end=True, tag=1),
    ]
    row = n_step_row(window, GAMMA)
    assert row.dones.tolist() == [0.0, 0.0]  # truncated: not terminal, bootstrap from the last observation
    assert row.discounts == pytest.approx([GAMMA**2, GAMMA**2])
    assert row.team_done == 0.0 and row.next_alive.tolist() == [0.0, 0.0]
    assert row.rewards == pytest.approx([0.1 + GAMMA * 0.2] * 2)


def test_collector_flushes_windows_at_world_end_and_drops_dead_rows() -> None:
    buffer = JointReplayBuffer(16, spaces.Box(-1, 1, (1,)), n_agents=2, state_dim=1)
    collector = NStepJointCollector(buffer, n_worlds=1, n_steps=3, gamma=GAMMA)
    collector.add(0, _tick([0.1, 0.1], [True, True], tag=0))
    collector.add(0, _tick([0.1, 0.1], [True, True], tag=1))
    assert buffer.size() == 0  # window not full yet
    collector.add(0, _tick([-1.0, 0.1], [True, True], (True, True), (True, True), True, tag=2))
    # The world ended: the rows of ticks 0, 1, 2 are all written, with shrinking windows.
    assert buffer.size() == 3
    assert buffer.team_dones[:3].tolist() == [1.0, 1.0, 1.0]
    assert buffer.rewards[2].tolist() == pytest.approx([-1.0, 0.1])
    assert buffer.discounts[1].tolist() == pytest.approx([GAMMA**2, GAMMA**2])
    collector.add(0, _tick([0.0, 0.0], [False, False], tag=5))
    collector.add(0, _tick([0.0, 0.0], [False, False], tag=6, world_end=True))
    assert buffer.size() == 3  # ticks with no acting agent never enter the buffer


def test_sum_tree_prefix_search() -> None:
    tree = SumTree(5)
    tree.update(np.arange(5), np.array([1.0, 2.0, 3.0, 0.0, 4.0]))
    assert tree.total == pytest.approx(10.0)
    found = tree.find(np.array([0.0, 0.99, 1.0, 2.99, 3.0, 5.99, 6.0, 9.99]))
    assert found.tolist() == [0, 0, 1, 1, 2, 2, 4, 4]


def test_per_sampling_probabilities_and_weights() -> None:
    np.random.seed(0)
    buffer = PrioritizedJointReplayBuffer(4, spaces.Box(-1, 1, (1,)), n_agents=1, state_dim=0, alpha=0.5)
    row = n_step_row([_tick([0.0], [True], (False,), (False,))], GAMMA)
    for _ in range(4):
        buffer.add_row(row)
    td_errors = np.array([1.0, 4.0, 9.0, 16.0])
    buffer.update_priorities(np.arange(4), td_errors - buffer.priority_eps)
    priorities = np.sqrt(td_errors)  # alpha = 0.5
    probabilities = priorities / priorities.sum()  # [0.1, 0.2, 0.3, 0.4]
    counts = np.zeros(4)
    for _ in range(500):
        counts += np.bincount(buffer.sample(20, beta=0.5).indices, minlength=4)
    assert counts / counts.sum() == pytest.approx(probabilities, abs=0.01)
    batch = buffer.sample(64, beta=0.5)
    expected = (4 * probabilities[batch.indices]) ** -0.5
    assert batch.weights.numpy() == pytest.approx(expected / expected.max(), rel=1e-5)


def test_sum_tree_totals_stay_exact_after_repeated_updates() -> None:
    rng = np.random.default_rng(0)
    tree = SumTree(37)
    leaves = np.zeros(37)
    for _ in range(50):
        indices = rng.integers(0, 37, size=8)  # duplicates included
        values = rng.uniform(0, 2, size=8)
        tree.update(indices, values)
        for index, value in zip(indices, values, strict=True):
            leaves[index] = value
        single = int(rng.integers(0, 37))
        tree.set_one(single, 0.5)
        leaves[single] = 0.5
        assert tree.total == pytest.approx(leaves.sum())
    assert tree.leaves(np.arange(37)) == pytest.approx(leaves)


def polyak_update_(target: th.nn.Module, source: th.nn.Module, tau: float) -> None:
    from sb3_eps.common.utils import polyak_update_tensors_

    lists = [list(part) for net in (target, source) for part in (net.parameters(), net.buffers())]
    polyak_update_tensors_(lists[0], lists[2], lists[1], lists[3], tau)


def test_polyak_update_hand_computation() -> None:
    target, source = th.nn.Linear(2, 1), th.nn.Linear(2, 1)
    with th.no_grad():
        target.weight.fill_(1.0), source.weight.fill_(3.0)
    polyak_update_(target, source, 0.25)
    assert th.allclose(target.weight, th.full((1, 2), 1.5))


def test_polyak_update_accepts_parameter_free_modules() -> None:
    polyak_update_(SumMixer(), SumMixer(), 0.5)
