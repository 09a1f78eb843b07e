"""QMIX's and VDN's own options: the mixer's initialisation, the bootstrap at time limits, the Q-range logs."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch as th

import envs  # noqa: F401
from research.diagnostics import input_gain
from sb3_eps import QMIX, VDN, make_vec_env
from sb3_eps.qmix import QMixer, QMIXPolicy

TINY = {"net_arch": [16], "stream_arch": [16], "mixing_embed_dim": 8, "hypernet_hidden_dim": 16}


def tiny_model(algorithm=QMIX, seed=0, **kwargs):
    """A small model on Cooperative Navigation, whose 25-tick episodes all end by the time limit."""
    venv = make_vec_env("CooperativeNavigation-v0", n_envs=2, seed=seed)
    defaults = {"learning_starts": 60, "batch_size": 16, "buffer_size": 2_000, "train_freq": 2, "seed": seed}
    defaults["policy_kwargs"] = dict(TINY)
    return algorithm("MlpPolicy", venv, **{**defaults, **kwargs})


def test_sum_init_starts_the_mixer_as_the_sum_of_the_agents_q() -> None:
    th.manual_seed(0)
    n_agents, state_dim = 4, 36
    agent_qs = th.randn(512, n_agents) * 0.5
    states = th.randn(512, state_dim)
    mixer = QMixer(n_agents, state_dim, init="sum")
    assert th.allclose(mixer(agent_qs, states), agent_qs.sum(dim=1), atol=0.2)
    gain = input_gain(mixer, agent_qs, states)
    assert gain.mean().item() == pytest.approx(1.0, abs=0.05)
    assert gain.std().item() < 0.05  # nearly the same credit for every agent in every state
    # The default (PyTorch's initialisation) is far from it: random, state-dependent credit.
    random_gain = input_gain(QMixer(n_agents, state_dim), agent_qs, states)
    assert random_gain.std().item() > 3 * gain.std().item()
    # Still a QMIX mixer: monotonic, and the state dependence is there for training to grow.
    assert (gain > 0).all()
    assert not th.allclose(gain[0], gain[1])


def test_mixer_init_is_checked_and_survives_save_load(tmp_path) -> None:
    with pytest.raises(ValueError, match="mixer_init must be one of"):
        QMixer(2, 3, init="identity")
    with pytest.raises(ValueError, match="mixer_init must be one of"):
        tiny_model(policy_kwargs={**TINY, "mixer_init": "vdn"})
    model = tiny_model(policy_kwargs={**TINY, "mixer_init": "sum"})
    assert isinstance(model.policy, QMIXPolicy) and model.policy.mixer_init == "sum"
    model.save(tmp_path / "model")
    loaded = QMIX.load(tmp_path / "model", env=make_vec_env("CooperativeNavigation-v0", n_envs=2, seed=1))
    assert loaded.policy.mixer_init == "sum"
    for key, value in model.policy.mixer.state_dict().items():
        assert th.equal(value, loaded.policy.mixer.state_dict()[key])


def _truncated_rows(model):
    """A batch of the rows whose window ends at the 25-tick time limit (every agent cut, none terminated)."""
    model.learn(400)
    buffer = model.replay_buffer
    rows = np.flatnonzero(
        (buffer.alive[: buffer.size()].min(axis=1) == 1)
        & (buffer.next_alive[: buffer.size()].max(axis=1) == 0)
        & (buffer.dones[: buffer.size()].max(axis=1) == 0)
    )
    assert len(rows) > 0, "Cooperative Navigation's episodes end at the time limit"
    return buffer._to_samples(rows, np.ones(len(rows), dtype=np.float32))


@pytest.mark.parametrize("algorithm", [QMIX, VDN], ids=lambda a: a.__name__)
def test_time_limit_windows_bootstrap_from_the_truncated_agents(algorithm, monkeypatch) -> None:
    """At the time limit every agent enters the target mixer with its Q_i'(s'_i, a*_i) (a time limit is not a
    terminal state): the target is mixer'(Q'; s'), not mixer'(0; s')."""
    import sb3_eps.qmix.qmix as qmix_module

    model = tiny_model(algorithm)
    batch = _truncated_rows(model)
    assert (batch.team_dones == 0).all()  # a time limit is not a terminal state
    seen = []
    original = qmix_module.weighted_huber

    def spy(prediction, target, weights):
        seen.append(target.clone())
        return original(prediction, target, weights)

    monkeypatch.setattr(qmix_module, "weighted_huber", spy)
    model._compute_loss(batch)
    with th.no_grad():
        terms = model._td_terms(batch)
        next_total = model.policy.mixer_target(terms.next_values + terms.next_advantage_term, batch.next_states)
    expected = batch.team_rewards + batch.team_discounts * next_total
    if model.advantage_learning:
        expected = expected - model.advantage_learning * model._team_action_gap(batch)
    th.testing.assert_close(seen[0], expected)


def test_q_range_is_logged(tmp_path) -> None:
    from stable_baselines3.common.logger import configure

    model = tiny_model(QMIX)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(600, log_interval=1)
    with (tmp_path / "progress.csv").open() as file:
        rows = [row for row in csv.DictReader(file) if row.get("train/q_total_min")]
    assert rows
    last = rows[-1]
    assert float(last["train/q_total_min"]) <= float(last["train/q_total_mean"]) <= float(last["train/q_total_max"])
    assert "train/mixer_gain_sum" not in last  # research instrumentation: research/diagnostics.py attaches it


def test_mixer_learns_at_its_fraction_of_the_agents_rate(tmp_path) -> None:
    model = tiny_model(QMIX, learning_rate=1e-3)
    assert model.policy.mixer_init == "sum"  # the package default
    groups = model.policy.optimizer.param_groups
    assert [group["lr"] for group in groups] == pytest.approx([1e-3, 1e-4])
    assert {id(p) for p in groups[1]["params"]} == {id(p) for p in model.policy.mixer.parameters()}
    model.learn(300)  # the schedule's updates keep the ratio (here a constant rate)
    assert [group["lr"] for group in model.policy.optimizer.param_groups] == pytest.approx([1e-3, 1e-4])
    decaying = tiny_model(QMIX)  # lin_3e-4, the default: both decay, the ratio stays
    decaying.learn(300)
    decaying._current_progress_remaining = 0.5
    decaying._update_learning_rate(decaying.policy.optimizer)
    assert [group["lr"] for group in decaying.policy.optimizer.param_groups] == pytest.approx([1.5e-4, 1.5e-5])
    model.save(tmp_path / "model")
    loaded = QMIX.load(tmp_path / "model", env=make_vec_env("CooperativeNavigation-v0", n_envs=2, seed=1))
    assert [group["lr"] for group in loaded.policy.optimizer.param_groups] == pytest.approx([1e-3, 1e-4])
    assert len(tiny_model(VDN).policy.optimizer.param_groups) == 1  # VDN's sum has no parameters


@pytest.mark.parametrize("algorithm", [QMIX, VDN], ids=lambda a: a.__name__)
def test_advantage_learning_lowers_the_team_target_by_alpha_times_the_joint_action_gap(
    algorithm, monkeypatch, tmp_path
) -> None:
    """y = (the plain team target) - alpha (mixer'(max_b Q_i'(s_i, b); s) - mixer'(Q_i'(s_i, a_i); s)); with VDN's sum
    the gap is the sum of the acting agents' own gaps, 0 only where every acting agent took its greedy action."""
    import sb3_eps.qmix.qmix as qmix_module

    model = tiny_model(algorithm, advantage_learning=0.5)
    model.learn(400)
    batch = model.replay_buffer.sample(32)
    seen = []
    original = qmix_module.weighted_huber

    def spy(prediction, target, weights):
        seen.append(target.clone())
        return original(prediction, target, weights)

    monkeypatch.setattr(qmix_module, "weighted_huber", spy)
    model._compute_loss(batch)
    model.advantage_learning = 0.0
    model._compute_loss(batch)
    with th.no_grad():
        gap = model._team_action_gap(batch)
        q_values = model.policy.q_net_target(batch.observations.reshape(-1, batch.observations.shape[-1]))
        own_gaps = (q_values.max(dim=1).values - q_values.gather(1, batch.actions.reshape(-1, 1)).squeeze(1)).reshape(
            batch.actions.shape[:2]
        ) * batch.alive
    assert gap.shape == seen[0].shape and (gap >= -1e-6).all() and (gap > 0).any()
    th.testing.assert_close(seen[0], seen[1] - 0.5 * gap)
    if algorithm is VDN:
        th.testing.assert_close(gap, own_gaps.sum(dim=1))
    all_greedy = (own_gaps == 0).all(dim=1)
    th.testing.assert_close(gap[all_greedy], th.zeros_like(gap[all_greedy]), atol=1e-5, rtol=0)
    model.advantage_learning = 0.5
    model.save(tmp_path / "al")
    assert algorithm.load(tmp_path / "al").advantage_learning == 0.5
    assert tiny_model(algorithm).advantage_learning == (0.5 if algorithm is VDN else 0.0)  # VDN's default
    with pytest.raises(ValueError, match=r"advantage_learning must be a number in \[0, 1\)"):
        tiny_model(algorithm, advantage_learning=1.0)
