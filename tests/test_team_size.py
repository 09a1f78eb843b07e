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


# --- a model trained on 2 robots keeps training on 4 -------------------------------------------------------------

import envs  # noqa: E402, F401
from sb3_eps import GDQ, IQL, QMIX, VDN, make_vec_env  # noqa: E402

SMALL = {"learning_starts": 50, "batch_size": 8, "buffer_size": 500, "policy_kwargs": {"net_arch": [16]}}


def two_then_four(algorithm, tmp_path, **kwargs):
    model = algorithm("MlpPolicy", make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=0), seed=0, **kwargs)
    model.learn(2 * 150)
    model.save(tmp_path / "two")
    four = make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=1)
    return model, algorithm.load(tmp_path / "two", env=four), four


@pytest.mark.parametrize(
    ("algorithm", "policy_kwargs"),
    [(GDQ, {"global_head": "pooled"}), (IQL, {}), (VDN, {})],
    ids=["gdq", "iql", "vdn"],
)
def test_a_model_trained_on_two_robots_loads_and_keeps_training_on_four(algorithm, policy_kwargs, tmp_path):
    kwargs = {**SMALL, "policy_kwargs": {**SMALL["policy_kwargs"], **policy_kwargs}}
    model, loaded, _ = two_then_four(algorithm, tmp_path, **kwargs)
    for name, value in model.policy.q_net.state_dict().items():  # the agent network came over as it was
        assert th.equal(loaded.policy.q_net.state_dict()[name], value)
    assert loaded.n_agents == 4 and loaded.replay_buffer.n_agents == 4
    assert loaded.ticks == 150  # the 2-robot ticks stay counted
    loaded.learn(4 * 100, reset_num_timesteps=False)
    assert loaded.ticks == 250 and loaded.num_timesteps == 2 * 150 + 4 * 100
    assert loaded.replay_buffer.size() > 0


def test_set_env_moves_a_pooled_gdq_to_another_team_size_and_back(tmp_path):
    kwargs = {**SMALL, "policy_kwargs": {"net_arch": [16], "global_head": "pooled"}}
    model = GDQ("MlpPolicy", make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=0), seed=0, **kwargs)
    model.learn(4 * 120)
    head = {k: v.clone() for k, v in model.policy.global_value_net.state_dict().items()}
    model.set_env(make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=1))
    assert all(th.equal(model.policy.global_value_net.state_dict()[k], v) for k, v in head.items())
    model.learn(2 * 100, reset_num_timesteps=False)
    assert model.n_agents == 2 and model.ticks == 220


@pytest.mark.parametrize(("algorithm", "fix"), [(GDQ, "global_head='pooled'"), (QMIX, "--init-from")], ids=["gdq", "qmix"])
def test_a_model_whose_joint_head_reads_a_fixed_team_is_refused_in_one_line(algorithm, fix, tmp_path):
    model = algorithm("MlpPolicy", make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=0), seed=0, **SMALL)
    model.save(tmp_path / "two")
    for other in ("MultiRobotNav-4-v0",):
        with pytest.raises(ValueError, match="trained with 2 agents per world") as error:
            algorithm.load(tmp_path / "two", env=make_vec_env(other, n_envs=1, seed=0))
        assert fix in str(error.value) and "\n" not in str(error.value)
        with pytest.raises(ValueError, match=fix.replace("(", r"\(")):
            model.set_env(make_vec_env(other, n_envs=1, seed=0))
