"""The EPS beyond Algorithm 1 (issue 10): mutation-size calibration, frozen parameter groups, outcome fitness, the
acceptance rule with reevaluation, the alpha schedule, the tick budget, the per-round diagnostics record, the team
check and the pillars world. Algorithm 1 itself is tested in test_eps.py."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.logger import Logger, configure

import envs
from research.eps_inspection import team_check_changes
from research.eps_variants import ResearchEvolutionCallback
from sb3_eps.eps import EvolutionCallback
from sb3_eps.eps import round as round_module
from sb3_eps.eps.evaluation import (
    InProcessEnvPool,
    PopulationResult,
    episode_outcome,
    evaluate_population,
    population_fitness,
)
from sb3_eps.eps.mutations import (
    calibrate_scale,
    evolved_parameter_names,
    mutate_population,
    mutation_directions,
    network_parameters,
    output_sensitivity,
    policy_change,
    polyak_crossover_,
    population_from_directions,
    population_outputs,
)
from sb3_eps.eps.round import gain_accepted, scheduled_alpha
from sb3_eps.eps.round_log import RoundLog, read_round_log, round_counts
from sb3_eps.eps.settings import PAPER_SETTINGS, EPSSettings
from sb3_eps.gdq import GDQ
from sb3_eps.iql import IQL
from tests.test_eps import MPE_EPISODE, MPE_SINGLE, tiny_model

ROBOT_OBS = 30


def new_callback(callback_class: type[EvolutionCallback] = EvolutionCallback, **kwargs) -> EvolutionCallback:
    """The new defaults, sized for tests: no budget unless asked, one worker-free pool."""
    defaults = {
        "eval_env_id": MPE_SINGLE,
        "population_size": 3,
        "period": 50,
        "n_eval_episodes": 2,
        "n_reevaluation_episodes": 2,
        "max_eps_share": None,
        "n_workers": 0,
        "seed": 0,
    }
    defaults.update(kwargs)
    return callback_class(**defaults)


# ---------------------------------------------------------------------- calibration
def test_calibrate_scale_finds_the_target_share_from_far_away() -> None:
    def share(scale: float) -> float:  # a smooth increasing share, known inverse
        return 1.0 - np.exp(-scale / 0.01)

    exact = -0.01 * np.log(1 - 0.1)
    for initial in (1e-7, 1e-3, 10.0):
        scale, found = calibrate_scale(share, 0.1, initial, tolerance=0.05)
        assert abs(found - 0.1) <= 0.005 and scale == pytest.approx(exact, rel=0.06)
    # A target out of reach: the closest share tried, at the bound, and no endless search.
    calls: list[float] = []
    scale, found = calibrate_scale(lambda s: calls.append(s) or min(0.05, s), 0.1, 1e-3, bounds=(1e-6, 1.0))
    assert found == 0.05 and scale >= 0.05 and len(calls) <= 24  # the first scale that reached the plateau
    with pytest.raises(ValueError, match="target"):
        calibrate_scale(share, 1.5, 1e-3)


def test_calibrated_mutants_flip_the_target_share_and_leave_the_value_stream_alone() -> None:
    q_net = tiny_model(GDQ).policy.q_net
    observations = th.randn(64, 18, generator=th.Generator().manual_seed(0))
    theta = network_parameters(q_net)
    names = evolved_parameter_names(q_net, ["value_stream"])
    assert names and not any(name.startswith("value_stream") for name in names)
    assert len(names) < len(theta)
    omega = output_sensitivity(q_net, observations)
    directions = mutation_directions(theta, 8, th.Generator().manual_seed(1), [omega], 0.01, names)
    assert set(directions) == set(names)

    def share_at(scale: float) -> float:
        population = population_from_directions(theta, directions, scale, 0.2)
        return float(policy_change(population_outputs(q_net, population, observations))[0][1:].mean())

    scale, share = calibrate_scale(share_at, 0.2, 1e-3)
    assert abs(share - 0.2) <= 0.2 * 0.2 + 1e-9
    population = population_from_directions(theta, directions, scale, 0.2)
    flips, _ = policy_change(population_outputs(q_net, population, observations))
    assert flips[0] == 0 and flips[1:].mean() == pytest.approx(share)
    for name, stacked in population.items():
        assert th.equal(stacked[0], theta[name])
        if name.startswith("value_stream"):
            assert all(th.equal(row, theta[name]) for row in stacked)
        else:
            assert float((stacked[1:] - theta[name]).abs().max()) <= 0.2 + 1e-7  # the clip


def test_directions_give_the_population_of_mutate_population() -> None:
    q_net = tiny_model(IQL).policy.q_net
    theta = network_parameters(q_net)
    omega = output_sensitivity(q_net, th.randn(16, 18))
    for sensitivities, max_step in (([omega], 0.05), (None, 0.05)):
        direct = mutate_population(theta, 3, 0.01, th.Generator().manual_seed(4), sensitivities, 0.01, max_step)
        directions = mutation_directions(theta, 3, th.Generator().manual_seed(4), sensitivities, 0.01)
        # The clip belongs to the safe step only: Gaussian noise stays unclipped.
        clip = max_step if sensitivities is not None else float("inf")
        built = population_from_directions(theta, directions, 0.01, clip)
        for name in theta:
            th.testing.assert_close(direct[name], built[name])


def test_policy_change_against_a_hand_computation() -> None:
    outputs = th.tensor(
        [
            [[1.0, 0.0], [0.0, 1.0], [2.0, 1.0]],  # copy 0: greedy 0, 1, 0
            [[1.0, 0.5], [1.0, 0.0], [2.0, 1.0]],  # greedy 0, 0, 0: one of three changed
            [[0.0, 1.0], [1.0, 0.0], [float("nan"), 0.0]],  # all changed (NaN counts as changed)
        ]
    )
    flips, dq = policy_change(outputs[:2])
    np.testing.assert_allclose(flips, [0.0, 1 / 3])
    np.testing.assert_allclose(dq, [0.0, (0.5 + 1.0 + 1.0) / 6])
    assert policy_change(outputs)[0][2] == 1.0


def test_frozen_groups_must_name_parameters_and_crossover_respects_them() -> None:
    q_net = tiny_model(IQL).policy.q_net
    with pytest.raises(ValueError, match=r"names no parameter.*groups are"):
        evolved_parameter_names(q_net, ["value_strem"])
    with pytest.raises(ValueError, match="leave no parameter"):
        evolved_parameter_names(q_net, ["trunk", "value_stream", "advantage_stream"])
    before = network_parameters(q_net)
    best = {name: value + 1.0 for name, value in before.items()}
    names = evolved_parameter_names(q_net, ["value_stream"])
    polyak_crossover_(q_net, best, 0.5, names)
    for name, param in q_net.named_parameters():
        expected = before[name] + 0.5 if name in names else before[name]
        th.testing.assert_close(param.detach(), expected)


# ---------------------------------------------------------------------- fitness
def test_outcome_fitness_ranks_success_first_and_waiting_above_crashing() -> None:
    # individual 0 waits to the time limit (-3.0), 1 crashes (-1.5), 2 reaches once (+0.2) and crashes once.
    returns = np.array([[-3.0, -3.0], [-1.5, -1.5], [0.2, -2.5]])
    outcomes = np.array([[0, 0], [-1, -1], [1, -1]])
    valid = np.array([True, True, True])
    paper = population_fitness(returns, outcomes, valid, "return")
    np.testing.assert_allclose(paper, [-3.0, -1.5, -1.15])
    assert np.argmax(paper) == 2 and paper[1] > paper[0]  # the paper's fitness prefers crashing to waiting
    outcome = population_fitness(returns, outcomes, valid, "outcome")
    np.testing.assert_allclose(outcome, [0.0 - 0.03, -1.0 - 0.015, 0.0 - 0.0115])
    assert outcome[0] > outcome[1]  # waiting beats crashing
    more_success = population_fitness(np.array([[-2.0, -2.0], [1.9, 1.9]]), np.array([[1, 1], [1, 0]]), valid[:2], "outcome")
    assert more_success[0] > more_success[1]  # two arrivals beat one, whatever the returns
    assert np.isneginf(population_fitness(returns, outcomes, np.array([True, False, True]), "outcome")[1])
    with pytest.raises(ValueError, match="unknown fitness"):
        population_fitness(returns, outcomes, valid, "speed")
    assert episode_outcome(True, {"is_success": True}) == 1
    assert episode_outcome(True, {"is_success": False}) == -1
    assert episode_outcome(False, {}) == 0


def test_the_evaluation_records_how_robot_episodes_end() -> None:
    # A network whose greedy action is always 0 (stand still, turn): every episode runs to the time limit.
    q_net = tiny_model(GDQ, env_id="MultiRobotNav-2-v0", n_envs=1).policy.q_net
    with th.no_grad():
        for name, param in q_net.named_parameters():
            param.zero_()
            if name.startswith("advantage_stream") and name.endswith("bias"):
                param[0] = 1.0
    population = {name: value.unsqueeze(0).repeat(2, *[1] * value.dim()) for name, value in network_parameters(q_net).items()}
    kwargs = {"scenario": "eps_pillars", "max_episode_steps": 30}
    pool = InProcessEnvPool("SingleRobotNav-v0", kwargs, 2, 2, q_net)
    try:
        result = evaluate_population(pool, population, [1, 2], 60, "outcome")
    finally:
        pool.close()
    assert (result.outcomes == 0).all() and (result.lengths == 30).all()
    np.testing.assert_allclose(result.fitness, 0.01 * result.returns.mean(axis=1))
    np.testing.assert_allclose(result.returns, -0.005 * 30)  # the step cost only: it never moved


# ---------------------------------------------------------------------- acceptance, schedule, budget
def test_gain_accepted_and_scheduled_alpha_by_hand() -> None:
    assert gain_accepted(0.06, 0.05) and not gain_accepted(0.05, 0.05) and not gain_accepted(float("nan"), 0.0)
    assert gain_accepted(1e-9, 0.0) and not gain_accepted(0.0, 0.0)
    assert scheduled_alpha(0.3, "constant", 0.2) == 0.3
    assert scheduled_alpha(0.3, "linear", 1.0) == 0.3
    assert scheduled_alpha(0.3, "linear", 0.25) == pytest.approx(0.075)
    assert scheduled_alpha(0.3, "linear", -0.1) == 0.0
    with pytest.raises(ValueError, match="alpha_schedule must be one of"):
        EPSSettings(alpha_schedule="cosine")


def _scripted(monkeypatch, selection: list[float], fresh: list[float], calls: list) -> None:
    """Selection rounds score ``selection``; reevaluations (two individuals active) score ``fresh`` (copy 0, winner)."""

    def fake_evaluate(pool, population, seeds, timeout, kind="return", active=None):
        n = next(iter(population.values())).shape[0]
        values = np.full(n, -np.inf)
        if active is None:
            values[:] = selection
        else:
            values[np.flatnonzero(active)] = fresh
        calls.append(active)
        lengths = np.full((n, len(seeds)), MPE_EPISODE)
        if active is not None:
            lengths[~np.asarray(active)] = 0
        returns = np.repeat(np.where(np.isfinite(values), values, 0)[:, None], len(seeds), 1)
        outcomes = np.zeros_like(lengths)
        fitness = population_fitness(returns, outcomes, np.isfinite(values), kind)
        return PopulationResult(returns, lengths, np.isfinite(values), fitness, outcomes)

    monkeypatch.setattr(round_module, "evaluate_population", fake_evaluate)


@pytest.mark.parametrize(("fresh", "crossed"), [([1.0, 1.0], False), ([1.0, 30.0], True)])
def test_reevaluation_decides_the_crossover(monkeypatch, fresh, crossed) -> None:
    model = tiny_model(IQL, learning_starts=10**6, n_steps=1)  # IQL: a target network too
    before = network_parameters(model.policy.q_net)
    target_before = network_parameters(model.policy.q_net_target)
    calls: list = []
    _scripted(monkeypatch, [0.0, 20.0, 1.0, 2.0], fresh, calls)  # individual 1 wins the selection by 0.2
    callback = new_callback(period=1, fitness="outcome", alpha=0.5, alpha_schedule="constant")
    model.learn(2 * 3 * 2, callback=callback)
    record = callback.history[0]
    assert record["winner"] == 1 and record["gain"] == pytest.approx(0.2)
    assert record["reevaluation"]["fitness"] == pytest.approx([0.01 * f for f in fresh])
    assert len(record["reevaluation"]["episode_seeds"]) == 2 and record["accepted"] is crossed
    assert callback.n_crossovers == sum(bool(r.get("accepted")) for r in callback.history if not r.get("skipped"))
    assert callback.n_crossovers >= int(crossed)
    assert sum(active is not None for active in calls) == 1  # one batch of 2 fresh episodes
    changed = {name for name, param in model.policy.q_net.named_parameters() if not th.equal(param.detach(), before[name])}
    target_changed = {
        name
        for name, param in model.policy.q_net_target.named_parameters()
        if not th.equal(param.detach(), target_before[name])
    }
    if crossed:
        assert changed == target_changed == set(callback.evolved_parameters) and record["mean_abs_delta"] > 0
        assert not any(name.startswith("value_stream") for name in changed)
    else:
        assert changed == target_changed == set() and record["mean_abs_delta"] == 0.0
    # The reevaluation's ticks (copy 0 and the winner, 2 episodes each) are EPS ticks.
    assert callback.eps_ticks == 4 * 2 * MPE_EPISODE + 2 * 2 * MPE_EPISODE == record["ticks_spent"]


def test_a_gain_below_min_gain_is_not_even_reevaluated(monkeypatch) -> None:
    model = tiny_model(IQL, learning_starts=10**6, n_steps=1)
    calls: list = []
    _scripted(monkeypatch, [0.0, 3.0, 1.0, 2.0], [0.0, 100.0], calls)  # a gain of 0.03 in outcome units
    callback = new_callback(period=1, min_gain=0.05)
    model.learn(2 * 3 * 2, callback=callback)
    assert callback.history[0]["accepted"] is False and all(active is None for active in calls)


def test_the_alpha_schedule_decays_over_training_and_the_budget_holds() -> None:
    model = tiny_model(GDQ)
    callback = new_callback(period=20, max_eps_share=1.0, alpha=0.4, min_gain=0.0, target_flip_share=0.3)
    model.learn(3 * 1500, callback=callback)
    records = [record for record in callback.history if not record["skipped"]]
    assert len(records) >= 3
    alphas = [record["alpha"] for record in records]
    assert 0 < alphas[0] < 0.4 and all(0 <= a < 0.4 for a in alphas)  # 0 for a round at the very end
    assert alphas == sorted(alphas, reverse=True)
    n_played = (4 + 2 * 1) * 2  # copy 0 and 3 mutants, then copy 0 and the winner again: 2 episodes each
    for previous, record in itertools.pairwise(records):
        lengths = np.concatenate(
            [np.ravel(previous["episode_lengths"]), np.ravel(previous.get("reevaluation", {}).get("episode_lengths", []))]
        )
        expected = lengths[lengths > 0].mean() * n_played  # every episode it may play, at the last round's lengths
        assert record["eps_ticks"] - record["ticks_spent"] + expected <= 1.0 * record["model_ticks"] + 1e-9
        assert record["ticks_spent"] <= n_played * lengths.max()
    # The first round waited until half its most cost fitted: (4 + 2 * 1) x 2 episodes x 25 ticks / 2 = 150.
    assert records[0]["model_ticks"] >= 150
    assert callback.eps_ticks <= 1.0 * model.ticks + max(r["ticks_spent"] for r in records)


# ---------------------------------------------------------------------- diagnostics
def test_every_round_is_a_json_line_in_the_run_folder_and_logged_under_eps(tmp_path) -> None:
    model = tiny_model(GDQ)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    callback = new_callback(min_gain=0.0)
    model.learn(900, callback=callback, log_interval=1)
    assert callback.n_rounds >= 2
    lines = (tmp_path / "eps_rounds.jsonl").read_text().splitlines()
    records = [json.loads(line, parse_constant=lambda name: pytest.fail(f"{name} in the JSON"))
               for line in lines]  # fmt: skip
    assert len(records) == len(callback.history) == callback.n_rounds
    for record in records:
        assert np.array(record["returns"]).shape == (4, 2) and np.array(record["successes"]).shape == (4, 2)
        assert np.array(record["outcomes"]).shape == (4, 2) and len(record["episode_seeds"]) == 2
        assert len(record["flip_share"]) == 3 and len(record["mean_abs_dq"]) == 3
        assert 0 <= np.mean(record["flip_share"]) <= 1 and record["scale"] > 0
        for key in (
            "winner",
            "gain",
            "runner_up_margin",
            "accepted",
            "crossovers",
            "alpha",
            "mean_abs_delta",
            "ticks_spent",
        ):
            assert key in record, key
        if record["winner"] != 0 and record["gain"] > 0:
            assert "reevaluation" in record and len(record["reevaluation"]["returns"]) == 2
    # Each record counts the run's crossovers so far; the last one says how many rounds of the run crossed over.
    running = np.cumsum([record["accepted"] for record in records])
    assert [record["crossovers"] for record in records] == running.tolist()
    assert round_counts(records) == {"rounds": callback.n_rounds, "crossovers": int(running[-1]), "skipped": 0}
    assert callback.n_crossovers == records[-1]["crossovers"]
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in (
        "eps/flip_share", "eps/mean_abs_dq", "eps/mutation_scale", "eps/accepted", "eps/alpha", "eps/success_0",
        "eps/runner_up_margin", "eps/round_ticks", "eps/tick_share", "eps/reevaluation_gain", "eps/crossovers",
    ):  # fmt: skip
        assert key in header, key
    assert read_round_log(tmp_path / "eps_rounds.jsonl")[0]["round"] == 1


def test_the_round_log_follows_the_history_on_resume(tmp_path) -> None:
    path = tmp_path / "deep" / "rounds.jsonl"
    log = RoundLog(path)
    for index in range(3):
        log.append({"round": index + 1, "fitness": [float("-inf"), np.float32(0.5)]}, n_before=index)
    assert [r["fitness"] for r in read_round_log(path)] == [[None, 0.5]] * 3  # -inf: null, valid JSON
    RoundLog(path).append({"round": 2}, n_before=1)  # a run resumed from a checkpoint holding 1 round
    assert [r["round"] for r in read_round_log(path)] == [1, 2]
    RoundLog(path).append({"round": 1}, n_before=0)  # a fresh run in the same folder
    assert [r["round"] for r in read_round_log(path)] == [1]


def test_diagnostics_path_choices(tmp_path) -> None:
    chosen = tmp_path / "mine.jsonl"
    for path, expected in ((str(chosen), chosen), ("", None)):
        model = tiny_model(IQL)
        model.set_logger(configure(str(tmp_path / "run"), ["csv"]))
        callback = new_callback(diagnostics_path=path)
        model.learn(300, callback=callback)
        assert callback.n_rounds >= 1
        if expected is not None:
            assert len(read_round_log(expected)) == callback.n_rounds
    assert not (tmp_path / "run" / "eps_rounds.jsonl").exists()
    model = tiny_model(IQL)
    model.set_logger(Logger(None, []))  # no folder: history only
    callback = new_callback()
    model.learn(300, callback=callback)
    assert callback.n_rounds >= 1 and callback.records.file is None


def test_the_team_check_plays_the_training_env_before_and_after_the_crossover(monkeypatch) -> None:
    import research.eps_variants as evaluation  # the team check is research (research/eps_variants.py)

    model = tiny_model(GDQ, learning_starts=10**6, n_steps=1)
    assert model.policy.q_net_average is not None  # GDQ's default: greedy actions from a weight average
    _scripted(monkeypatch, [0.0, 20.0, 1.0, 2.0], [0.0, 30.0], [])
    played = []
    real_evaluate_team = evaluation.evaluate_team

    def recording_evaluate_team(policy, *args, **kwargs):
        played.append((policy, kwargs.get("deterministic", True)))
        return real_evaluate_team(policy, *args, **kwargs)

    monkeypatch.setattr(evaluation, "evaluate_team", recording_evaluate_team)
    callback = new_callback(ResearchEvolutionCallback, period=1, n_team_check_episodes=2, alpha_schedule="constant")
    model.learn(2 * 3 * 2, callback=callback)
    # The checks play the online network (the one the crossover changed), not the model's weight average.
    assert len(played) == 2
    observations = np.random.default_rng(2).uniform(-2, 2, (64, 18)).astype(np.float32)
    with th.no_grad():
        online = model.policy.q_net(th.as_tensor(observations)).argmax(dim=1).numpy()
        average = model.policy.q_net_average(th.as_tensor(observations)).argmax(dim=1).numpy()
    assert (online != average).any()  # the crossover moved the online network away from the average
    policy, deterministic = played[1]
    np.testing.assert_array_equal(policy.predict(observations, deterministic=deterministic)[0], online)
    record = callback.history[0]
    assert record["accepted"] and record["team_check_ticks"] == 2 * 2 * MPE_EPISODE
    assert {"team_success_before", "team_success_after", "team_return_before", "team_return_after"} <= set(record)
    assert callback.eps_ticks == record["ticks_spent"] == (4 * 2 + 2 * 2 + 2 * 2) * MPE_EPISODE
    # the summary that benchmarks/crossover_effects.py prints: one paired change per checked crossover
    skipped, rejected = {"round": 0, "skipped": True}, {**record, "round": 9, "accepted": False}
    for key in ("team_success_before", "team_success_after", "team_return_before", "team_return_after"):
        rejected.pop(key)
    (change,) = team_check_changes([skipped, record, rejected])
    assert change["round"] == record["round"] and change["alpha"] == record["alpha"]
    assert change["success_change"] == record["team_success_after"] - record["team_success_before"]
    assert change["return_change"] == pytest.approx(record["team_return_after"] - record["team_return_before"])


# ---------------------------------------------------------------------- settings and the world
def test_paper_settings_and_the_default_world() -> None:
    paper = EvolutionCallback.paper(eval_env_id=MPE_SINGLE, alpha=0.2, verbose=1)
    assert paper.verbose == 1 and paper.settings == EPSSettings.paper(eval_env_id=MPE_SINGLE, alpha=0.2)
    for name, value in PAPER_SETTINGS.items():
        assert getattr(paper.settings, name) == (0.2 if name == "alpha" else value), name
    default = EvolutionCallback().settings
    assert default == EPSSettings() and default.eval_env_kwargs == {"scenario": "eps_pillars", "max_episode_steps": 400}
    assert EvolutionCallback.paper().settings.eval_env_kwargs == {}  # the bars world of Fig. 3
    assert EvolutionCallback(eval_env_id=MPE_SINGLE).settings.eval_env_kwargs == {}
    assert EvolutionCallback(eval_env_kwargs={"scenario": "eps"}).settings.eval_env_kwargs == {"scenario": "eps"}
    assert EvolutionCallback(EPSSettings(alpha=0.1)).settings.alpha == 0.1
    with pytest.raises(ValueError, match="either settings or keyword arguments"):
        EvolutionCallback(EPSSettings(), alpha=0.1)


def test_the_pillars_world_has_robot_sized_obstacles_and_the_training_spaces() -> None:
    from envs.turtlebot3.layouts import make_layout

    layout = make_layout("eps_pillars", 1)
    assert layout.width == make_layout("arena", 4).width and len(layout.obstacles) == 3
    np.testing.assert_allclose(layout.obstacles[:, 2:], 0.1)
    env = envs.make_single_env("SingleRobotNav-v0", scenario="eps_pillars")
    multi = envs.make_parallel_env("MultiRobotNav-4-v0")
    try:
        assert env.observation_space == multi.observation_space("robot_0") and env.max_episode_steps == 600
        assert env.observation_space.shape == (ROBOT_OBS,)
    finally:
        env.close()
        multi.close()
    with pytest.raises(ValueError, match="eps_pillars"):
        make_layout("pillars", 1)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"target_flip_share": 1.0}, "target_flip_share"),
        ({"fitness": "speed"}, "fitness must be one of"),
        ({"min_gain": -0.1}, "min_gain"),
        ({"n_reevaluation_episodes": -1}, "n_reevaluation_episodes"),
        ({"frozen_groups": "value_stream"}, "frozen_groups"),
        ({"alpha_schedule": "cosine"}, "alpha_schedule"),
        ({"max_eps_share": 0.0}, "max_eps_share"),
        ({"rounds_until": 0}, "rounds_until"),
        ({"rounds_until": 2.5}, "rounds_until"),
    ],
)
def test_bad_new_arguments_raise_value_errors(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        new_callback(**kwargs)


def test_an_unknown_frozen_group_or_an_unknown_team_env_fails_before_training() -> None:
    with pytest.raises(ValueError, match="names no parameter"):
        tiny_model(IQL).learn(30, callback=new_callback(frozen_groups=["value"]))
    from stable_baselines3 import DQN

    dqn = DQN("MlpPolicy", envs.make_single_env(MPE_SINGLE), policy_kwargs={"net_arch": [16]})
    with pytest.raises(ValueError, match="n_team_check_episodes"):
        dqn.learn(30, callback=new_callback(ResearchEvolutionCallback, n_team_check_episodes=1))


def test_state_dict_round_trip() -> None:
    model = tiny_model(GDQ)
    callback = new_callback()
    model.learn(600, callback=callback)
    state = callback.state_dict()
    restored = new_callback()
    restored.init_callback(tiny_model(GDQ))
    restored.load_state_dict(state)
    assert restored.history == callback.history and restored.n_rounds == callback.n_rounds
    assert restored.round.scale == callback.round.scale and restored.eps_ticks == callback.eps_ticks
    assert th.equal(restored.round.generator.get_state(), callback.round.generator.get_state())
    assert restored.round.rng.random() == callback.round.rng.random()
    assert restored.budget.last_round_mark == callback.budget.last_round_mark
    restored._on_training_end()
    # A state loaded before init_callback (a checkpoint's, at the start of learn()) waits for it.
    early = new_callback()
    early.load_state_dict(state)
    early.init_callback(tiny_model(GDQ))
    assert early.eps_ticks == callback.eps_ticks and early.round.scale == callback.round.scale
    assert th.equal(early.round.generator.get_state(), callback.round.generator.get_state())
    early._on_training_end()


def test_a_run_whose_budget_allows_no_round_warns_once() -> None:
    """A round of ``new_callback`` may cost (4 + 2) x 2 episodes of 25 ticks, half of it expected before the first
    round: 150 ticks, more than 10 % of the 100 ticks of 300 timesteps of three agents."""
    import warnings

    model = tiny_model(IQL)
    callback = new_callback(max_eps_share=0.1, period=2)
    with pytest.warns(
        UserWarning, match=r"no EPS round in this run: a round is expected to cost 150 ticks.*raise max_eps_share"
    ):
        model.learn(300, callback=callback)
    assert callback.n_rounds == 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model.learn(300, callback=callback, reset_num_timesteps=False)
    assert not [warning for warning in caught if "no EPS round" in str(warning.message)]  # once per callback
    with pytest.warns(UserWarning, match=r"period=1000000 ticks is longer than this run's 100 training ticks"):
        tiny_model(IQL).learn(300, callback=new_callback(period=10**6))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        budgeted = new_callback(max_eps_share=0.1, period=2)
        tiny_model(IQL).learn(6000, callback=budgeted)  # 2,000 ticks: a round fits after 1,500
    assert budgeted.n_rounds >= 1 and not [warning for warning in caught if "no EPS round" in str(warning.message)]


def test_rounds_until_keeps_rounds_early() -> None:
    """Rounds every 50 ticks; with ``rounds_until=150`` none starts after 150 training ticks, and a run continued
    past it plays none and says so once."""
    model = tiny_model(IQL)
    early = new_callback(period=50, rounds_until=150)
    model.learn(1200, callback=early)  # 400 ticks of three agents
    assert early.n_rounds >= 1
    assert all(record["model_ticks"] <= 150 + 25 for record in early.history)  # a round starts at a rollout end
    unbounded = new_callback(period=50)
    tiny_model(IQL).learn(1200, callback=unbounded)
    assert max(record["model_ticks"] for record in unbounded.history) > 175
    with pytest.warns(UserWarning, match=r"rounds_until=150 ticks is not after this run's start"):
        model.learn(300, callback=early, reset_num_timesteps=False)


# ---------------------------------------------------------------------- fitness
def test_the_fitness_setting_from_python_decides_what_a_round_ranks() -> None:
    """``fitness="return"`` (the paper's; the MPE entries') ranks by the mean return, ``"outcome"`` by the outcomes
    plus 0.01 x the return; a round's records show which one it used."""
    for fitness, min_gain in (("return", 0.2), ("outcome", 0.05)):
        callback = new_callback(fitness=fitness, min_gain=min_gain)
        assert (callback.settings.fitness, callback.settings.min_gain) == (fitness, min_gain)
        tiny_model(IQL).learn(300, callback=callback)
        record = callback.history[0]
        returns, outcomes = np.array(record["returns"]), np.array(record["outcomes"])
        expected = returns.mean(axis=1) + (outcomes.mean(axis=1) - 0.99 * returns.mean(axis=1)) * (fitness == "outcome")
        np.testing.assert_allclose(record["fitness"], expected, rtol=1e-6)
    assert EPSSettings.paper().fitness == "return"
    with pytest.raises(ValueError, match="fitness"):
        new_callback(fitness="reward")
