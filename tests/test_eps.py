"""EvolutionCallback: the math against hand computations, the round logic, safety, and runs on real models."""

from __future__ import annotations

import os
import signal
import time

import gymnasium
import numpy as np
import pettingzoo
import pytest
import torch as th
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.logger import Logger, configure
from stable_baselines3.common.utils import LinearSchedule
from torch import nn

import envs
from sb3_eps import make_vec_env
from sb3_eps.eps import (
    EPS_WORLDS,
    EvolutionCallback,
    InProcessEnvPool,
    SubprocessEnvPool,
    eps_env_id_for,
    evaluate_population,
    mutate_population,
    output_sensitivity,
    polyak_crossover_,
    safe_mutation_step,
    select_best,
)
from sb3_eps.eps import round as round_module
from sb3_eps.eps.evaluation import PopulationResult
from sb3_eps.eps.mutations import network_parameters
from sb3_eps.gdq import GDQ
from sb3_eps.iql import IQL
from sb3_eps.qmix import QMIX, VDN
from sb3_eps.zoo.callbacks import TickBudgetCallback

MPE, MPE_SINGLE = "CooperativeNavigation-v0", "CooperativeNavigationSingle-v0"
TINY = {"net_arch": [16], "stream_arch": [16]}
MPE_EPISODE = 25  # ticks of every Cooperative Navigation episode


def tiny_model(algorithm=GDQ, env_id=MPE, n_envs=2, seed=0, **kwargs):
    extra = {"mixing_embed_dim": 8, "hypernet_hidden_dim": 16} if algorithm in (QMIX, VDN) else {}
    if algorithm is GDQ:
        extra = {"global_net_arch": [16]}
    defaults = {"learning_starts": 60, "batch_size": 16, "buffer_size": 2_000, "train_freq": 2, "seed": seed}
    defaults.update(kwargs)
    venv = make_vec_env(env_id, n_envs=n_envs, seed=seed)
    return algorithm("MlpPolicy", venv, policy_kwargs={**TINY, **extra}, **defaults)


def tiny_callback(callback_class: type[EvolutionCallback] = EvolutionCallback, **kwargs) -> EvolutionCallback:
    # The tests written for Algorithm 1 as published build it with EvolutionCallback.paper (the defaults before
    # issue 10); the new pieces have tests of their own below, with the new defaults.
    defaults = {
        "eval_env_id": MPE_SINGLE,
        "population_size": 3,
        "period": 2,
        "n_eval_episodes": 2,
        "n_workers": 1,
        "seed": 0,
    }
    defaults.update(kwargs)
    return callback_class.paper(**defaults)


def small_network() -> nn.Module:
    th.manual_seed(0)
    return nn.Sequential(nn.Linear(3, 5), nn.Tanh(), nn.Linear(5, 4), nn.ReLU(), nn.Linear(4, 3))


# ---------------------------------------------------------------------- the math
def test_eps_evaluates_in_the_single_agent_world_of_the_training_world(monkeypatch) -> None:
    for env_id in envs.MULTI_AGENT_ENV_IDS:
        expected = "CooperativeNavigationSingle-v0" if env_id == "CooperativeNavigation-v0" else "SingleRobotNav-v0"
        assert eps_env_id_for(env_id) == expected
    for env_id in envs.SINGLE_AGENT_ENV_IDS:
        assert eps_env_id_for(env_id) == env_id
    with pytest.raises(ValueError, match="EPS has no single-agent world for 'Corridor-2-v0'"):
        eps_env_id_for("Corridor-2-v0")
    with pytest.raises(ValueError, match="unknown env id 'Nope-v0'"):
        eps_env_id_for("Nope-v0")
    monkeypatch.setitem(EPS_WORLDS, "Corridor-2-v0", "SingleRobotNav-v0")  # a plug-in names its world
    assert eps_env_id_for("Corridor-2-v0") == "SingleRobotNav-v0"


def test_a_registration_names_its_eps_world_and_options(monkeypatch) -> None:
    """The worlds' knowledge lives in their registrations (envs.EnvSpec's eps_world and eps_kwargs), read by id."""
    from sb3_eps.eps.settings import default_eval_env_kwargs

    assert envs.spec("MultiRobotNav-8-v0").eps_world == "SingleRobotNav-v0"
    assert default_eval_env_kwargs("SingleRobotNav-v0") == {"scenario": "eps_pillars", "max_episode_steps": 400}
    assert default_eval_env_kwargs("CooperativeNavigationSingle-v0") == {}
    monkeypatch.setattr(envs, "_MULTI_AGENT_SPECS", dict(envs._MULTI_AGENT_SPECS))
    monkeypatch.setattr(envs, "_SINGLE_AGENT_SPECS", dict(envs._SINGLE_AGENT_SPECS))
    monkeypatch.setattr(envs, "_PARALLEL_SPECS", dict(envs._PARALLEL_SPECS))
    try:
        envs.register("LineWorld-2-v0", "envs.debug:CorridorEnv", fixed_kwargs={"n_agents": 2}, eps_world="LineSolo-v0")
        envs.register("LineSolo-v0", "envs.debug:CorridorEnv", multi_agent=False, eps_kwargs={"length": 3})
        assert eps_env_id_for("LineWorld-2-v0") == "LineSolo-v0"
        assert default_eval_env_kwargs("LineSolo-v0") == {"length": 3}
    finally:  # out of PettingZoo's and gymnasium's registries again
        pettingzoo.parallel_registry.pop("LineWorld-2-v0", None)
        gymnasium.registry.pop("LineSolo-v0", None)


def test_sensitivity_equals_a_per_sample_autograd_loop() -> None:
    network = small_network()
    observations = th.randn(7, 3, generator=th.Generator().manual_seed(1))
    omega = output_sensitivity(network, observations, chunk_size=3)  # chunks of 3, 3, 1 samples
    expected = {name: th.zeros_like(param) for name, param in network.named_parameters()}
    for sample in observations:
        outputs = network(sample.unsqueeze(0)).reshape(-1)
        for output in outputs:
            grads = th.autograd.grad(output, list(network.parameters()), retain_graph=True)
            for (name, _), grad in zip(network.named_parameters(), grads, strict=True):
                expected[name] += grad.abs()
    for name, total in expected.items():
        # Eq. 6: batch mean of |dy/dw|, then mean over the 3 outputs.
        th.testing.assert_close(omega[name], total / (7 * 3), rtol=1e-5, atol=1e-7)


def test_sensitivity_of_the_dueling_network_has_its_parameter_shapes() -> None:
    model = tiny_model(IQL)
    q_net = model.policy.q_net
    omega = output_sensitivity(q_net, th.randn(5, 18))
    assert {name: value.shape for name, value in omega.items()} == {
        name: param.shape for name, param in q_net.named_parameters()
    }
    assert all(bool((value >= 0).all()) for value in omega.values())
    with pytest.raises(ValueError, match="batch, obs_dim"):
        output_sensitivity(q_net, th.randn(18))


def test_safe_step_floor_and_clip_hold() -> None:
    noise = th.tensor([0.05, 0.05, -0.05, 0.001, 0.5, -0.5, 0.02])
    omega = th.tensor([0.0, 1e-6, 1e-6, 0.5, 1.0, 2.0, 0.1])
    step = safe_mutation_step(noise, omega, floor=0.01, max_step=0.2)
    # omega 0 -> 1 (plain noise); 1e-6 -> floor 0.01 -> 5 -> clipped to +-0.2; 0.5 / 1.0 -> clipped; else G / omega.
    expected = th.tensor([0.05, 0.2, -0.2, 0.002, 0.2, -0.2, 0.2])
    th.testing.assert_close(step, expected)
    assert bool((step.abs() <= th.tensor(0.2)).all())  # float32 comparison
    unclipped = safe_mutation_step(noise, omega, floor=0.01, max_step=float("inf"))
    assert float(unclipped.abs().max()) == pytest.approx(5.0)  # |G| / floor at most
    with pytest.raises(ValueError, match="broadcast"):
        safe_mutation_step(noise, th.ones(3), floor=0.01, max_step=0.2)


def test_mutate_population_keeps_copy_0_and_uses_the_sensitivity() -> None:
    network = small_network()
    theta = network_parameters(network)
    omega = {name: th.full_like(param, 0.5) for name, param in theta.items()}
    population = mutate_population(theta, 4, 0.01, th.Generator().manual_seed(3), [omega], floor=0.01, max_step=1.0)
    plain = mutate_population(theta, 4, 0.01, th.Generator().manual_seed(3), None)
    for name, param in theta.items():
        assert population[name].shape == (5, *param.shape)
        assert th.equal(population[name][0], param) and th.equal(plain[name][0], param)
        # Same generator, same noise: the safe step is the Gaussian step divided by omega = 0.5.
        th.testing.assert_close(population[name][1:] - param, 2 * (plain[name][1:] - param))
    many = mutate_population({"w": th.zeros(200, 50)}, 10, 0.03, th.Generator().manual_seed(0), None)  # std of plain noise
    assert float(many["w"][1:].std()) == pytest.approx(0.03, rel=0.02)


def test_crossover_is_exactly_the_polyak_mean() -> None:
    network = small_network()
    current = network_parameters(network)
    best = {name: th.randn_like(param) for name, param in current.items()}
    change = polyak_crossover_(network, best, 0.3)
    for name, param in network.named_parameters():
        assert th.equal(param.detach(), 0.3 * best[name] + 0.7 * current[name])  # Eq. 5
    expected_change = np.mean(np.concatenate([(0.3 * (best[n] - current[n])).abs().flatten().numpy() for n in current]))
    assert change == pytest.approx(expected_change, rel=1e-5)
    with pytest.raises(ValueError, match="alpha"):
        polyak_crossover_(network, best, 1.5)


def test_select_best_never_picks_a_non_finite_individual_and_prefers_copy_0_on_ties() -> None:
    assert select_best(np.array([1.0, np.nan, 0.5])) == 0
    assert select_best(np.array([-3.0, np.inf, -1.0])) == 2  # inf fitness is as invalid as NaN
    assert select_best(np.array([-2.0, -2.0, -5.0])) == 0
    assert select_best(np.array([-np.inf, -np.inf])) == 0


# ---------------------------------------------------------------------- evaluation
def test_evaluation_uses_common_random_numbers_and_disqualifies_non_finite_individuals() -> None:
    network = tiny_model(IQL).policy.q_net
    theta = network_parameters(network)
    population = mutate_population(theta, 3, 0.05, th.Generator().manual_seed(0), None)
    population["advantage_stream.0.weight"][1, 0, 0] = float("nan")  # non-finite weights
    population["trunk.0.weight"][2] = 3e38  # finite weights, overflowing (inf/NaN) outputs
    population = {name: th.cat([stacked, stacked[:1]]) for name, stacked in population.items()}  # 4 = copy 0
    pool = InProcessEnvPool(MPE_SINGLE, None, 5, 2, network)
    try:
        result = evaluate_population(pool, population, [11, 12], timeout=60)
    finally:
        pool.close()
    assert result.valid.tolist() == [True, False, False, True, True]
    assert np.isneginf(result.fitness[[1, 2]]).all()
    assert result.lengths[1].sum() == 0 and result.lengths[0].tolist() == [MPE_EPISODE, MPE_EPISODE]
    # Same weights, same seeds: the same episodes, whatever their place in the population.
    np.testing.assert_array_equal(result.returns[4], result.returns[0])
    assert select_best(result.fitness) in (0, 3)


def test_worker_and_in_process_evaluation_agree() -> None:
    network = tiny_model(IQL).policy.q_net
    population = mutate_population(network_parameters(network), 4, 0.05, th.Generator().manual_seed(0), None)
    results = []
    for pool in (
        InProcessEnvPool(MPE_SINGLE, None, 5, 2, network),
        SubprocessEnvPool(MPE_SINGLE, None, 5, 2, network, n_workers=2),
    ):
        try:
            results.append(evaluate_population(pool, population, [3, 4], timeout=60))
        finally:
            pool.close()
    for result in results[1:]:
        np.testing.assert_allclose(result.returns, results[0].returns, rtol=1e-6)


# ---------------------------------------------------------------------- the round inside training
def _no_training(algorithm=IQL, **kwargs):
    # learning_starts beyond the budget: no gradient step, so the weights change only through EPS; one-step
    # rows reach the replay buffer after one tick, so the first rollout already has visited states for Eq. 6.
    return tiny_model(algorithm, learning_starts=10**6, n_steps=1, **kwargs)


def _scripted_evaluation(monkeypatch, fitness: list[float], record: dict) -> None:
    def fake_evaluate(pool, population, episode_seeds, timeout, kind="return", active=None):
        if "population" not in record:
            record["population"] = {name: value.clone() for name, value in population.items()}
        n = next(iter(population.values())).shape[0]
        lengths = np.full((n, len(episode_seeds)), MPE_EPISODE)
        values = np.asarray(fitness, dtype=float)
        return PopulationResult(
            np.repeat(values[:, None], len(episode_seeds), 1), lengths, np.ones(n, bool), values, 0 * lengths
        )

    monkeypatch.setattr(round_module, "evaluate_population", fake_evaluate)


def test_round_crossover_moves_online_and_target_nets_toward_the_winner(monkeypatch) -> None:
    model = _no_training(IQL)
    online_before = network_parameters(model.policy.q_net)
    target_before = network_parameters(model.policy.q_net_target)
    for name in target_before:  # make the target differ from the online net, to see each gets its own mix
        target_before[name] += 1.0
        model.policy.q_net_target.get_parameter(name).data.copy_(target_before[name])
    record: dict = {}
    _scripted_evaluation(monkeypatch, [-5.0, -4.0, -1.0, -3.0], record)
    callback = tiny_callback(period=1, period_unit="ticks", alpha=0.3)
    model.learn(2 * 3 * 2, callback=callback)  # one rollout (2 vector steps of 2 worlds x 3 agents): one round
    assert callback.n_rounds == 1 and callback.history[0]["winner"] == 2
    best = {name: stacked[2] for name, stacked in record["population"].items()}
    for name, param in model.policy.q_net.named_parameters():
        assert th.equal(param.detach(), 0.3 * best[name] + 0.7 * online_before[name])
    for name, param in model.policy.q_net_target.named_parameters():
        assert th.equal(param.detach(), 0.3 * best[name] + 0.7 * target_before[name])
    assert callback.history[0]["gain"] == pytest.approx(4.0)
    assert callback.history[0]["mean_abs_delta"] > 0


def test_nothing_changes_when_the_unmutated_copy_wins(monkeypatch) -> None:
    model = _no_training(GDQ)
    before = [param.detach().clone() for param in model.policy.parameters()]
    _scripted_evaluation(monkeypatch, [-1.0, -1.0, -2.0, float("nan")], {})  # a tie with copy 0, a NaN
    callback = tiny_callback(period=1, period_unit="ticks")
    model.learn(4 * 3 * 2, callback=callback)
    assert callback.n_rounds >= 2 and all(record["winner"] == 0 for record in callback.history)
    for old, new in zip(before, model.policy.parameters(), strict=True):
        assert th.equal(old, new)
    assert all(record["mean_abs_delta"] == 0.0 for record in callback.history)


def test_a_nan_mutant_never_wins_a_real_round(monkeypatch) -> None:
    original = round_module.population_from_directions  # the callback builds its population with it

    def poisoned(*args, **kwargs):
        population = original(*args, **kwargs)
        for stacked in population.values():
            stacked[1:] = float("nan")  # every mutant
        return population

    monkeypatch.setattr(round_module, "population_from_directions", poisoned)
    model = _no_training(IQL)
    before = network_parameters(model.policy.q_net)
    callback = tiny_callback(period=1, period_unit="ticks", n_workers=0)
    model.learn(2 * 3 * 2, callback=callback)
    record = callback.history[0]
    assert record["winner"] == 0 and np.isneginf(record["fitness"][1:]).all()
    for name, param in model.policy.q_net.named_parameters():
        assert th.equal(param.detach(), before[name])


def test_ticks_counter_adds_up_and_everything_is_logged(tmp_path) -> None:
    model = tiny_model(GDQ)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    callback = tiny_callback(population_size=3, n_eval_episodes=2)
    model.learn(900, callback=callback, log_interval=1)
    assert callback.n_rounds >= 2
    # rounds x individuals (m + 1) x episodes x 25 ticks
    assert callback.eps_ticks == callback.n_rounds * 4 * 2 * MPE_EPISODE
    assert [record["eps_ticks"] for record in callback.history] == [
        (i + 1) * 4 * 2 * MPE_EPISODE for i in range(callback.n_rounds)
    ]
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in (
        "eps/round", "eps/ticks", "eps/total_ticks", "eps/fitness_0", "eps/fitness_3", "eps/fitness_mean",
        "eps/fitness_max", "eps/fitness_min", "eps/winner", "eps/fitness_gain", "eps/mean_abs_delta",
        "eps/round_time", "eps/time_share", "eps/skipped_rounds",
    ):  # fmt: skip
        assert key in header, key
    assert callback.worker_pids == []  # closed at training end


def test_period_in_episodes_counts_world_episodes() -> None:
    model = tiny_model(IQL)
    callback = tiny_callback(period=4)
    model.learn(3 * 2 * 25 * 4, callback=callback)  # 2 worlds x 4 episodes each = 8 world episodes
    assert model._episode_num == 8
    assert callback.n_rounds == 2


def test_a_killed_worker_skips_the_round_and_training_goes_on(monkeypatch) -> None:
    original = SubprocessEnvPool.evaluate
    killed: list[int] = []

    def kill_then_evaluate(self, *args, **kwargs):
        if not killed:
            killed.append(self.pids[0])
            os.kill(self.pids[0], signal.SIGKILL)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(SubprocessEnvPool, "evaluate", kill_then_evaluate)
    model = tiny_model(GDQ)
    callback = tiny_callback(n_workers=2)
    with pytest.warns(RuntimeWarning, match="EPS round skipped"):
        model.learn(900, callback=callback)
    assert model.num_timesteps >= 900
    assert callback.n_skipped_rounds == 1 and callback.history[0]["skipped"]
    assert "died" in callback.history[0]["reason"] or "gone" in callback.history[0]["reason"]
    assert callback.n_rounds >= 1 and not callback.history[-1]["skipped"]  # the restarted workers serve


def test_a_hung_worker_times_out_and_the_round_is_skipped(monkeypatch) -> None:
    original = SubprocessEnvPool.evaluate
    stopped: list[int] = []

    def stop_then_evaluate(self, population, seeds, valid, deadline):
        if not stopped:
            stopped.append(self.pids[-1])
            os.kill(self.pids[-1], signal.SIGSTOP)
            return original(self, population, seeds, valid, deadline)  # the 1 s deadline: this round times out
        # Later rounds (restarted workers) get a deadline a loaded CI machine can meet: at 1 s a healthy round
        # once timed out too, beside two training runs on the 2 cores.
        return original(self, population, seeds, valid, time.monotonic() + 120.0)

    monkeypatch.setattr(SubprocessEnvPool, "evaluate", stop_then_evaluate)
    model = tiny_model(IQL)
    callback = tiny_callback(n_workers=2, eval_timeout=1.0)
    with pytest.warns(RuntimeWarning, match="did not answer"):
        model.learn(600, callback=callback)
    assert callback.n_skipped_rounds == 1 and callback.n_rounds >= 1
    with pytest.raises(ProcessLookupError):  # the stopped worker was killed and reaped, not left behind
        os.kill(stopped[0], 0)


# ---------------------------------------------------------------------- real models and worlds
@pytest.mark.parametrize("algorithm", [IQL, GDQ, QMIX, VDN], ids=lambda a: a.__name__)
def test_it_runs_with_every_algorithm_on_cooperative_navigation(algorithm) -> None:
    model = tiny_model(algorithm)
    callback = tiny_callback()
    model.learn(600, callback=callback)
    assert callback.n_rounds >= 1 and callback.n_skipped_rounds == 0
    assert all(np.isfinite(record["fitness"][0]) for record in callback.history)


@pytest.mark.parametrize("schedules_follow", [True, False])
def test_a_tick_budget_pays_the_eps_ticks_from_training_and_ends_the_schedules_with_it(schedules_follow) -> None:
    """TickBudgetCallback: training stops when its timesteps plus EPS's reach the budget. With ``schedules_follow``
    the schedules count the EPS ticks as spent, so a decaying learning rate has reached about 0 when training
    stops, as in a run without EPS; without it the schedule stops short by about EPS's share of the budget."""
    budget = 2_400  # timesteps: one round (600 timesteps) at about 1,000, then training to the budget
    model = tiny_model(GDQ, learning_rate=LinearSchedule(1e-3, 0.0, 1.0))
    callback = tiny_callback(n_workers=0, max_eps_share=0.3)
    model.learn(budget, callback=CallbackList([callback, TickBudgetCallback(budget, [callback], schedules_follow)]))
    spent, step = callback.eps_ticks * model.n_agents, model.get_env().num_envs
    assert callback.n_rounds >= 1 and spent >= 10 * step
    assert budget <= model.num_timesteps + spent < budget + step
    remaining = model._current_progress_remaining  # as the last gradient steps saw it (one step before the end)
    learning_rate = model.policy.optimizer.param_groups[0]["lr"]
    if schedules_follow:
        assert 0.0 <= remaining <= step / (budget - spent) + 1e-9
    else:
        assert remaining == pytest.approx(spent / budget, abs=step / budget + 1e-9)
    assert learning_rate == pytest.approx(1e-3 * remaining, abs=1e-3 * 2 * step / (budget - spent))  # train_freq 2


def test_gaussian_mutation_and_per_robot_sensitivity_run() -> None:
    from research.eps_variants import ResearchEvolutionCallback  # per_robot: research, outside the package

    for kwargs in ({"mutation": "gaussian"}, {"per_robot": True, "population_size": 3}):
        model = tiny_model(GDQ)
        callback = tiny_callback(ResearchEvolutionCallback, n_workers=0, **kwargs)
        model.learn(450, callback=callback)
        assert callback.n_rounds >= 1


def test_it_runs_with_gdq_on_the_robot_worlds() -> None:
    model = tiny_model(GDQ, env_id="MultiRobotNav-2-v0", n_envs=1, train_freq=4)
    # The default EPS (calibrated, outcome fitness, reevaluation), without the tick budget.
    callback = EvolutionCallback(
        eval_env_id=eps_env_id_for("MultiRobotNav-2-v0"),
        population_size=2,
        period=40,
        n_eval_episodes=1,
        max_eps_share=None,
        n_workers=1,
        eval_env_kwargs={"scenario": "eps_pillars", "max_episode_steps": 40},
        seed=0,
    )
    learn_and_check_the_tick_accounting(model, callback, max_episode_steps=40)


def learn_and_check_the_tick_accounting(model, callback: EvolutionCallback, max_episode_steps: int) -> None:
    """Train through at least two rounds; every episode stays within the time limit, and the EPS ticks are the
    rounds' ticks (at least their episodes' lengths)."""
    model.learn(2 * 100, callback=callback)
    assert callback.n_rounds >= 2
    lengths = np.array([record["episode_lengths"] for record in callback.history])
    assert 0 < lengths.max() <= max_episode_steps
    assert callback.eps_ticks == sum(record["ticks_spent"] for record in callback.history) >= lengths.sum()


def test_a_team_world_plays_every_robot_with_the_individual_and_counts_world_ticks() -> None:
    """eval_env_id a multi-agent id: each individual drives all robots of its world (as in training); the same
    numbers in process and in a worker; an episode's ticks are world ticks."""
    model = tiny_model(GDQ, env_id="MultiRobotNav-2-v0", n_envs=1, train_freq=4)
    network = model.policy.q_net
    population = mutate_population(network_parameters(network), 2, 0.05, th.Generator().manual_seed(0), None)
    results = []
    for pool in (
        InProcessEnvPool("MultiRobotNav-2-v0", {"max_episode_steps": 30}, 3, 2, network),
        SubprocessEnvPool("MultiRobotNav-2-v0", {"max_episode_steps": 30}, 3, 2, network, n_workers=2),
    ):
        try:
            results.append(evaluate_population(pool, population, [5, 6], timeout=60, fitness="outcome"))
        finally:
            pool.close()
    np.testing.assert_array_equal(results[0].returns, results[1].returns)
    np.testing.assert_array_equal(results[0].outcomes, results[1].outcomes)
    assert 0 < results[0].lengths.max() <= 30 and results[0].valid.all()

    callback = EvolutionCallback(
        eval_env_id="MultiRobotNav-2-v0", eval_env_kwargs={"max_episode_steps": 30}, population_size=2,
        period=40, n_eval_episodes=1, max_eps_share=None, n_workers=0, seed=0,
    )  # fmt: skip
    learn_and_check_the_tick_accounting(model, callback, max_episode_steps=30)


def test_a_team_world_must_speak_the_models_language() -> None:
    with pytest.raises(ValueError, match="observation_space"):
        tiny_model(IQL).learn(30, callback=tiny_callback(eval_env_id="MultiRobotNav-2-v0"))


def test_save_load_of_a_model_trained_with_eps(tmp_path) -> None:
    model = tiny_model(GDQ)
    callback = tiny_callback()
    model.learn(450, callback=callback)
    assert callback.n_rounds >= 1
    model.save(tmp_path / "eps_gdq")
    loaded = GDQ.load(tmp_path / "eps_gdq", env=make_vec_env(MPE, n_envs=2, seed=1))
    observations = np.random.default_rng(0).uniform(-1, 1, (32, 18)).astype(np.float32)
    np.testing.assert_array_equal(
        model.predict(observations, deterministic=True)[0],
        loaded.predict(observations, deterministic=True)[0],
    )
    loaded.learn(150, callback=tiny_callback())  # and training with EPS goes on


def test_two_seeded_runs_are_identical() -> None:
    parameters, histories = [], []
    for _ in range(2):
        model = tiny_model(GDQ, seed=5)
        callback = tiny_callback(seed=None)  # derived from the model's seed
        model.learn(600, callback=callback)
        parameters.append([param.detach().clone() for param in model.policy.parameters()])
        histories.append([(record["fitness"], record["winner"]) for record in callback.history])
    assert histories[0] == histories[1]
    for first, second in zip(*parameters, strict=True):
        assert th.equal(first, second)


def test_rounds_that_cross_nothing_over_leave_training_as_it_was_without_eps() -> None:
    """A round draws from its own generators and changes the model only by a crossover: with every round rejected
    (``min_gain`` out of reach), the trained network is bit for bit the one trained without the callback. So an
    EPS run and its base are the same run up to the first round, and, when the schedules run over the nominal
    training budget, up to the first crossover (docs/results/eps.md, "The pairs, seed by seed")."""
    parameters, callback = [], None
    for with_eps in (False, True):
        model = tiny_model(GDQ, seed=3)
        if with_eps:
            callback = EvolutionCallback(
                eval_env_id=MPE_SINGLE, population_size=3, period=200, n_eval_episodes=2, n_workers=0, seed=0,
                min_gain=1e9, max_eps_share=None,
            )  # fmt: skip
        model.learn(1_200, callback=callback if with_eps else None)
        parameters.append([param.detach().clone() for param in model.policy.parameters()])
    assert callback is not None and callback.n_rounds >= 2 and callback.n_crossovers == 0 and callback.eps_ticks > 0
    for plain, evolved in zip(*parameters, strict=True):
        assert th.equal(plain, evolved)


def test_sb3_dqn_works_too() -> None:
    model = DQN("MlpPolicy", envs.make_single_env(MPE_SINGLE), learning_starts=50, policy_kwargs={"net_arch": [16]})
    callback = tiny_callback(period=40, period_unit="ticks", n_workers=0)
    model.learn(200, callback=callback)
    assert callback.n_rounds >= 1


# ---------------------------------------------------------------------- construction errors
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"alpha": 1.5}, "alpha"),
        ({"alpha": -0.1}, "alpha"),
        ({"sigma": 0.0}, "sigma"),
        ({"population_size": 0}, "population_size"),
        ({"mutation": "cauchy"}, "mutation must be one of"),
        ({"eval_env_id": "NoSuchWorld-v0"}, "unknown eval_env_id"),
        ({"period_unit": "epochs"}, "period_unit"),
        ({"period": 0}, "period"),
        ({"n_eval_episodes": 0}, "n_eval_episodes"),
        ({"n_workers": -1}, "n_workers"),
        ({"sensitivity_floor": 0.0}, "sensitivity_floor"),
    ],
)
def test_bad_arguments_raise_value_errors(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        tiny_callback(**kwargs)


def test_the_research_options_are_checked_and_not_in_the_package() -> None:
    from research.eps_variants import ResearchEvolutionCallback

    with pytest.raises(ValueError, match="per_robot"):
        tiny_callback(ResearchEvolutionCallback, per_robot=True, mutation="gaussian")
    with pytest.raises(ValueError, match="n_team_check_episodes"):
        tiny_callback(ResearchEvolutionCallback, n_team_check_episodes=-2)
    with pytest.raises(TypeError, match="share_experience"):
        tiny_callback(share_experience=True)


def test_mismatched_spaces_and_models_fail_before_training() -> None:
    model = tiny_model(IQL)
    with pytest.raises(ValueError, match="observation_space"):
        model.learn(30, callback=tiny_callback(eval_env_id="SingleRobotNav-v0"))
    ppo = PPO("MlpPolicy", envs.make_single_env(MPE_SINGLE), n_steps=16, batch_size=16)
    with pytest.raises(ValueError, match="q_net"):
        ppo.learn(16, callback=tiny_callback())
    dqn = DQN("MlpPolicy", envs.make_single_env(MPE_SINGLE))
    dqn.replay_buffer = None
    dqn.set_logger(Logger(None, []))
    with pytest.raises(ValueError, match="replay buffer"):
        tiny_callback().init_callback(dqn)


def test_sigma_defaults_depend_on_the_mutation() -> None:
    assert tiny_callback().settings.sigma == 0.001
    assert tiny_callback(mutation="gaussian").settings.sigma == 0.03
    assert tiny_callback(mutation="gaussian", sigma=0.5).settings.sigma == 0.5
