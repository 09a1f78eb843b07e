"""The four SB3 test families for every algorithm: it runs, save/load, seeded determinism, it learns."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv

import envs
from sb3_eps import GDQ, IQL, QMIX, VDN, export_policy, make_vec_env
from sb3_eps.common.utils import epsilon_greedy

ALGORITHMS = [IQL, GDQ, QMIX, VDN]
TINY = {"net_arch": [16], "stream_arch": [16]}


def tiny_model(algorithm, env_id="CooperativeNavigation-v0", n_envs=2, seed=0, policy_extra=None, **kwargs):
    venv = make_vec_env(env_id, n_envs=n_envs, seed=seed)
    extra = {"mixing_embed_dim": 8, "hypernet_hidden_dim": 16} if algorithm in (QMIX, VDN) else {}
    if algorithm is GDQ:
        extra = {"global_net_arch": [16]}
    defaults = {"learning_starts": 60, "batch_size": 16, "buffer_size": 2_000, "train_freq": 2, "seed": seed}
    defaults.update(kwargs)
    return algorithm("MlpPolicy", venv, policy_kwargs={**TINY, **extra, **(policy_extra or {})}, **defaults)


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_it_runs_and_logs_team_metrics(algorithm, tmp_path) -> None:
    model = tiny_model(algorithm, tensorboard_log=None)
    from stable_baselines3.common.logger import configure

    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(600, log_interval=1)
    assert model.num_timesteps >= 600 and model.ticks == model.num_timesteps // 3
    assert model.replay_buffer.size() > 0
    # Episodes are counted per world (team), never per agent: 25-tick MPE episodes, 2 worlds.
    assert len(model.ep_info_buffer) == 2 * (model.ticks // 2 // 25)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in ("rollout/ep_rew_mean", "rollout/collision_rate", "rollout/success_rate", "time/ticks"):
        assert key in header
    assert "rollout/team_return" not in header  # it repeated rollout/ep_rew_mean
    assert "train/loss" in header


def test_tensorboard_runs_are_named_after_the_algorithm(tmp_path) -> None:
    """As SB3's own algorithms (``DQN_1``): ``GDQ_1``, then ``GDQ_2``; an explicit ``tb_log_name`` still wins."""
    model = tiny_model(GDQ, tensorboard_log=str(tmp_path))
    model.learn(90)
    model.learn(90)
    model.learn(90, tb_log_name="mine")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["GDQ_1", "GDQ_2", "mine_1"]


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_save_load_gives_identical_predictions(algorithm, tmp_path) -> None:
    model = tiny_model(algorithm)
    model.learn(300)
    model.save(tmp_path / "model")
    venv = make_vec_env("CooperativeNavigation-v0", n_envs=2, seed=1)
    loaded = algorithm.load(tmp_path / "model", env=venv)
    observations = np.random.default_rng(0).uniform(-1, 1, (32, 18)).astype(np.float32)
    expected, _ = model.predict(observations, deterministic=True)
    actual, _ = loaded.predict(observations, deterministic=True)
    np.testing.assert_array_equal(expected, actual)
    assert (model.policy.q_net_target is None) == (loaded.policy.q_net_target is None)
    names = ["q_net", *model.policy.joint_module_names()]
    names += ["q_net_target"] if model.policy.q_net_target is not None else []
    for name in names:
        for key, value in getattr(model.policy, name).state_dict().items():
            assert th.equal(value, getattr(loaded.policy, name).state_dict()[key]), f"{name}.{key}"
        target_name = f"{name}_target"
        if getattr(model.policy, target_name, None) is not None:
            for key, value in getattr(model.policy, target_name).state_dict().items():
                assert th.equal(value, getattr(loaded.policy, target_name).state_dict()[key])
    loaded.learn(100)  # training goes on after loading


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_same_seed_gives_identical_parameters(algorithm) -> None:
    parameters = []
    for _ in range(2):
        model = tiny_model(algorithm, seed=3)
        model.learn(1_000)
        parameters.append([param.detach().clone() for param in model.policy.parameters()])
    for first, second in zip(*parameters, strict=True):
        assert th.equal(first, second)
    other = tiny_model(algorithm, seed=4)
    other.learn(1_000)
    assert any(not th.equal(a, b) for a, b in zip(parameters[0], other.policy.parameters(), strict=True))


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_learns_the_corridor_optimum(algorithm) -> None:
    """Two agents on a 4-cell corridor: agent 1 arrives first and parks, agent 0 keeps walking."""
    model = _corridor_model(algorithm)
    model.learn(4_000)
    optimum = envs.make_parallel_env("Corridor-2-v0").optimal_team_return()
    assert _corridor_team_return(model) == pytest.approx(optimum)


def _corridor_model(algorithm, policy_kwargs=None, **options):
    venv = make_vec_env("Corridor-2-v0", n_envs=2, seed=0)
    return algorithm(
        "MlpPolicy",
        venv,
        policy_kwargs={"net_arch": [32], "stream_arch": [32], **(policy_kwargs or {})},
        learning_starts=200,
        batch_size=32,
        learning_rate=3e-3,
        exploration_fraction=0.5,
        train_freq=1,
        gamma=0.95,
        seed=0,
        **options,
    )


def _corridor_team_return(model) -> float:
    eval_env = envs.make_parallel_env("Corridor-2-v0")
    observations, _ = eval_env.reset(seed=1)
    team_return = 0.0
    while eval_env.agents:
        stacked = np.stack([observations[agent] for agent in eval_env.agents])
        actions, _ = model.predict(stacked, deterministic=True)
        observations, rewards, _, _, _ = eval_env.step(dict(zip(eval_env.agents, actions.tolist(), strict=True)))
        team_return += sum(rewards.values())
    return team_return


def test_exploration_coins_are_independent_per_agent() -> None:
    rng = np.random.default_rng(0)
    flags = np.stack([epsilon_greedy(np.zeros(2, dtype=np.int64), 0.5, 20, rng)[1] for _ in range(10_000)])
    rates = flags.mean(axis=0)
    assert rates == pytest.approx([0.5, 0.5], abs=0.02)
    # Independent coins: P(both) = 0.25 (one shared coin, as SB3's DQN, would give 0.5).
    assert (flags[:, 0] & flags[:, 1]).mean() == pytest.approx(0.25, abs=0.02)


def test_predict_explores_per_agent() -> None:
    model = tiny_model(IQL)
    model.exploration_rate = 1.0
    np.random.seed(0)
    observations = np.zeros((2, 18), dtype=np.float32)
    actions = np.stack([model.predict(observations)[0] for _ in range(300)])
    assert (actions[:, 0] != actions[:, 1]).mean() > 0.6  # uniform draws over 5 actions differ 80 % of the time


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_rejects_envs_that_are_not_multi_agent(algorithm) -> None:
    import gymnasium

    venv = DummyVecEnv([lambda: gymnasium.make("CartPole-v1")])
    with pytest.raises(ValueError, match="make_vec_env"):
        algorithm("MlpPolicy", venv)
    with pytest.raises(ValueError, match="make_vec_env"):
        algorithm("MlpPolicy", "CooperativeNavigation-v0")


@pytest.mark.parametrize("algorithm", [GDQ, QMIX], ids=lambda a: a.__name__)
def test_joint_models_refuse_another_number_of_agents(algorithm, tmp_path) -> None:
    model = tiny_model(algorithm, env_id="Corridor-2-v0")
    model.save(tmp_path / "model")
    with pytest.raises(ValueError, match="agents per world"):
        algorithm.load(tmp_path / "model", env=make_vec_env("Corridor-3-v0", n_envs=1))


def test_bad_hyperparameters_are_rejected() -> None:
    venv = make_vec_env("CooperativeNavigation-v0")
    with pytest.raises(ValueError, match="tau"):
        GDQ("MlpPolicy", venv, tau=0.0)
    with pytest.raises(ValueError, match="team_reward_mode"):
        GDQ("MlpPolicy", venv, team_reward_mode="max")
    with pytest.raises(ValueError, match="Policy CnnPolicy unknown"):
        GDQ("CnnPolicy", venv)


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_onnx_export_matches_torch(algorithm, tmp_path) -> None:
    import onnxruntime

    model = tiny_model(algorithm)
    onnx_path, json_path = export_policy(model, tmp_path / "policy")
    description = json.loads(open(json_path).read())
    assert description["n_actions"] == 5 and description["input"]["shape"] == ["batch", 18]
    observations = np.random.default_rng(1).uniform(-2, 2, (64, 18)).astype(np.float32)
    session = onnxruntime.InferenceSession(onnx_path, providers=["CPUExecutionProvider"])
    (onnx_q,) = session.run(["q_values"], {"obs": observations})
    with th.no_grad():
        torch_q = model.policy.q_net(th.as_tensor(observations)).numpy()
    np.testing.assert_allclose(onnx_q, torch_q, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_runs_on_the_robot_world(algorithm) -> None:
    model = tiny_model(algorithm, env_id="MultiRobotNav-2-v0", n_envs=1, learning_starts=100)
    model.learn(600)
    assert model.replay_buffer.size() > 0
    assert model.state_dim > 0
    # Only the state-conditioned mixer stores the global state; the others skip it (throughput).
    assert model.replay_buffer.states.shape[1] == (model.state_dim if algorithm.uses_global_state else 0)
    assert algorithm.uses_global_state == (algorithm is QMIX)
    actions, _ = model.predict(np.zeros((5, 30), dtype=np.float32), deterministic=True)
    assert actions.shape == (5,) and ((actions >= 0) & (actions < 20)).all()


GDQ_OPTIONS = ("global_values", "global_bootstrap")  # GDQ's own arguments; the others are policy_kwargs


def _gdq_with(tmp_path=None, **options):
    venv = make_vec_env("CooperativeNavigation-v0", n_envs=2, seed=0)
    kwargs = {"learning_starts": 60, "batch_size": 16, "buffer_size": 2_000, "train_freq": 2, "seed": 0}
    arguments = (*GDQ_OPTIONS, "n_steps")  # GDQ's arguments these tests set; the rest are policy_kwargs
    kwargs.update((key, value) for key, value in options.items() if key in arguments)
    policy_kwargs = {key: value for key, value in options.items() if key not in arguments}
    return GDQ("MlpPolicy", venv, policy_kwargs={**TINY, "global_net_arch": [16], **policy_kwargs}, **kwargs)


@pytest.mark.parametrize("bootstrap", [None, 1.0], ids=["package-defaults", "paper-target"])
def test_gdq_defaults_are_gdq_lambda_and_the_paper_target_is_one_argument(bootstrap, monkeypatch) -> None:
    """The package defaults train GDQ-lambda 0.1 with 3-step returns (docs/results/gdq_target.md);
    global_bootstrap=1.0 is the paper's target, which ignores the agents' own next values."""
    from sb3_eps.gdq import gdq as gdq_module

    lambdas = []
    original = gdq_module.gdq_agent_targets

    def spy(*args):
        lambdas.append(args[6])
        return original(*args)

    monkeypatch.setattr(gdq_module, "gdq_agent_targets", spy)
    model = _gdq_with() if bootstrap is None else _gdq_with(global_bootstrap=bootstrap, n_steps=30)
    if bootstrap is None:
        assert (model.global_bootstrap, model.n_steps) == (0.1, 3)
    model.learn(200)
    expected = 0.1 if bootstrap is None else 1.0
    assert lambdas and set(lambdas) == {expected}
    # The paper's target does not move with the agents' own next values; GDQ-lambda does.
    targets = [
        original(th.zeros(2, 3), th.ones(2, 3), th.zeros(2, 3), th.ones(2), th.zeros(2, 3), own, expected)
        for own in (th.zeros(2, 3), th.ones(2, 3))
    ]
    assert th.equal(targets[0], targets[1]) is (bootstrap == 1.0)


def test_gdq_target_values_are_the_default() -> None:
    model = _gdq_with()
    model.learn(200)
    assert model.global_values == "target" and model.policy.agent_target


@pytest.mark.parametrize(
    ("policy_kwargs", "match"),
    [
        ({"global_values": "cached"}, "global_values must be one of"),
        ({"global_bootstrap": 1.5}, r"global_bootstrap must be a number in \[0, 1\]"),
        ({"global_init": "zeros"}, "global_init must be one of"),
    ],
)
def test_gdq_rejects_bad_options(policy_kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        _gdq_with(**policy_kwargs)


@pytest.mark.parametrize(
    "policy_kwargs",
    [
        {"global_values": "recomputed"},
        {"global_bootstrap": 0.1, "agent_target": True},
        {"global_values": "target", "agent_target": True},
    ],
    ids=["recomputed-values", "gdq-lambda", "target-values"],
)
def test_gdq_variants_learn_the_corridor_optimum(policy_kwargs) -> None:
    options = {key: policy_kwargs.pop(key) for key in GDQ_OPTIONS if key in policy_kwargs}
    model = _corridor_model(GDQ, policy_kwargs, **options)
    model.learn(4_000)
    assert _corridor_team_return(model) == pytest.approx(envs.make_parallel_env("Corridor-2-v0").optimal_team_return())


def test_target_update_is_a_polyak_step_and_follows_set_parameters() -> None:
    model = tiny_model(IQL, tau=0.25)
    model.learn(100)
    online, target = model.policy.q_net, model.policy.q_net_target
    before = [p.detach().clone() for p in target.parameters()]
    model._update_targets()
    for old, new, source in zip(before, target.parameters(), online.parameters(), strict=True):
        assert th.allclose(new, 0.25 * source + 0.75 * old, atol=1e-6)
    # set_parameters loads in place, so the cached tensor lists keep pointing at the live weights.
    params = model.get_parameters()
    params["policy"] = {k: th.zeros_like(v) if k.startswith("q_net.") else v for k, v in params["policy"].items()}
    model.set_parameters(params)
    target_before = [p.detach().clone() for p in target.parameters()]
    model._update_targets()
    for old, new in zip(target_before, target.parameters(), strict=True):
        assert th.allclose(new, 0.75 * old, atol=1e-6)


def test_gdq_target_values_feed_the_global_target_head_from_the_agent_target_network() -> None:
    model = _gdq_with(global_values="target", agent_target=True)
    model.learn(300)
    batch = model.replay_buffer.sample(8)
    seen = []
    hook = model.policy.global_value_net_target.register_forward_hook(lambda module, args, out: seen.append(args[0]))
    with th.no_grad():
        # Move the online network far from its target: v' must not follow it.
        for parameter in model.policy.q_net.parameters():
            parameter.add_(1.0)
    model._compute_loss(batch)
    hook.remove()
    with th.no_grad():
        next_obs = batch.next_observations.reshape(-1, batch.next_observations.shape[-1])
        expected = model.policy.q_net_target.value_advantage(next_obs)[0].reshape(8, 3) * batch.next_alive
    th.testing.assert_close(seen[0], expected)


def test_gdq_target_values_need_an_agent_target_network() -> None:
    with pytest.raises(ValueError, match="reads v' from the agent target network: with agent_target=False"):
        _gdq_with(global_values="target", agent_target=False)


def _q_argmax(net, obs) -> np.ndarray:
    with th.no_grad():
        return net(th.as_tensor(obs)).argmax(dim=1).numpy()


@pytest.mark.parametrize("algorithm", ALGORITHMS, ids=lambda a: a.__name__)
def test_weight_average_is_an_ema_of_the_online_weights_and_leaves_training_unchanged(algorithm) -> None:
    """weight_average_tau keeps avg <- (1 - r) avg + r theta after the n-th gradient step, r = max(tau, 4 / (n + 3))
    (a polynomial-decay average, then the moving average); training (the online weights, the replay) is the same as
    without it, bit for bit."""
    tau = 0.2
    plain = tiny_model(algorithm, policy_extra={"weight_average_tau": None})  # GDQ keeps one by default
    plain.learn(400)  # before the second model is built: both seed the global generators
    averaged = tiny_model(algorithm, policy_extra={"weight_average_tau": tau})
    assert plain.policy.q_net_average is None and averaged.policy.weight_average_tau == tau
    expected = [p.detach().clone() for p in averaged.policy.q_net.parameters()]
    online_update = averaged.policy.update_weight_average
    n_calls = []

    def tracking_update(n_updates) -> None:
        n_calls.append(1)
        assert n_updates == len(n_calls)
        rate = max(tau, 4 / (len(n_calls) + 3))
        for e, p in zip(expected, averaged.policy.q_net.parameters(), strict=True):
            e.mul_(1 - rate).add_(p.detach(), alpha=rate)
        online_update(n_updates)

    averaged.policy.update_weight_average = tracking_update
    averaged.learn(400)
    assert len(n_calls) == averaged._n_updates > 4 / tau  # both the warm-up's steps and the moving average's
    for (name, p), q in zip(plain.policy.named_parameters(), averaged.policy.parameters(), strict=False):
        assert th.equal(p, q), name  # q_net_average is registered last: zip stops before it
    average, online = list(averaged.policy.q_net_average.parameters()), list(averaged.policy.q_net.parameters())
    for e, a in zip(expected, average, strict=True):
        th.testing.assert_close(a, e, rtol=1e-5, atol=1e-6)
    assert any(not th.equal(a, p) for a, p in zip(average, online, strict=True))
    assert all(not p.requires_grad for p in averaged.policy.q_net_average.parameters())


def test_greedy_actions_come_from_the_average_and_exploring_ones_from_the_online_network(tmp_path) -> None:
    model = tiny_model(GDQ, policy_extra={"weight_average_tau": 0.01})
    other = tiny_model(GDQ, seed=7)  # different weights for the average, so the two networks disagree
    model.policy.q_net_average.load_state_dict(other.policy.q_net.state_dict())
    obs = np.random.default_rng(4).uniform(-2, 2, (64, 18)).astype(np.float32)
    online, average = _q_argmax(model.policy.q_net, obs), _q_argmax(model.policy.q_net_average, obs)
    assert (online != average).any()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], average)
    model.exploration_rate = 0.0
    np.testing.assert_array_equal(model.predict(obs, deterministic=False)[0], online)
    model._last_obs = obs
    model.num_timesteps = model.learning_starts
    np.testing.assert_array_equal(model._sample_actions(model.learning_starts, 64), online)
    # The average is saved and loaded with the model; the greedy actions stay the same.
    model.save(tmp_path / "model")
    loaded = GDQ.load(tmp_path / "model")
    assert loaded.policy.weight_average_tau == 0.01
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], average)


def test_weight_average_export_and_bad_values(tmp_path) -> None:
    import onnxruntime

    model = tiny_model(VDN, policy_extra={"weight_average_tau": 0.5})
    model.policy.q_net_average.load_state_dict(tiny_model(VDN, seed=3).policy.q_net.state_dict())
    onnx_path, json_path = export_policy(model, tmp_path / "policy")
    description = json.loads(open(json_path).read())
    assert description["network"] == "q_net_average" and description["weight_average_tau"] == 0.5
    _, plain_json = export_policy(tiny_model(IQL), tmp_path / "plain")  # IQL keeps no average by default
    assert json.loads(open(plain_json).read())["network"] == "q_net"
    obs = np.random.default_rng(5).uniform(-2, 2, (32, 18)).astype(np.float32)
    (onnx_q,) = onnxruntime.InferenceSession(onnx_path, providers=["CPUExecutionProvider"]).run(["q_values"], {"obs": obs})
    with th.no_grad():
        expected = model.policy.q_net_average(th.as_tensor(obs)).numpy()
    np.testing.assert_allclose(onnx_q, expected, rtol=1e-5, atol=1e-5)
    venv = make_vec_env("CooperativeNavigation-v0", n_envs=1, seed=0)
    for bad in (0.0, -0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="weight_average_tau must be in"):
            IQL("MlpPolicy", venv, policy_kwargs={"weight_average_tau": bad})


def test_a_warm_start_sets_the_weight_average_to_the_loaded_network(tmp_path) -> None:
    from sb3_eps.zoo.exp_manager import load_agent_weights

    source = tiny_model(GDQ, seed=5)
    source.save(tmp_path / "source")
    model = tiny_model(GDQ, policy_extra={"weight_average_tau": 0.01})
    load_agent_weights(model, tmp_path / "source.zip")
    for a, p in zip(model.policy.q_net_average.parameters(), source.policy.q_net.parameters(), strict=True):
        assert th.equal(a, p)


def test_weight_average_defaults_and_a_policy_default_survive_save_load(tmp_path) -> None:
    """The package defaults: GDQ and VDN keep a 2e-4 average, IQL and QMIX none; a policy class whose default keeps
    an average builds it, and the saved model loads with it."""
    from sb3_eps.gdq.policies import GDQPolicy

    class AveragingPolicy(GDQPolicy):
        def __init__(self, *args, weight_average_tau=0.01, **kwargs) -> None:
            super().__init__(*args, weight_average_tau=weight_average_tau, **kwargs)

    venv = make_vec_env("CooperativeNavigation-v0", n_envs=1, seed=0)
    model = GDQ(AveragingPolicy, venv, seed=0)
    assert model.policy.weight_average_tau == 0.01 and model.policy.q_net_average is not None
    model.save(tmp_path / "averaging")
    assert GDQ.load(tmp_path / "averaging").policy.weight_average_tau == 0.01
    for averaging in (GDQ, VDN):
        assert averaging("MlpPolicy", venv, seed=0).policy.weight_average_tau == 2e-4
        assert averaging("MlpPolicy", venv, seed=0).policy.q_net_average is not None
    for other in (IQL, QMIX):
        assert other("MlpPolicy", venv, seed=0).policy.q_net_average is None
