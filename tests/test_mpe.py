"""Cooperative Navigation envs: PettingZoo compliance, SB3 check_env, determinism, metrics, the single-agent layout."""

import os

# mpe2 draws with pygame; "human" mode needs a display unless SDL writes to a dummy one.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

import warnings

import gymnasium
import numpy as np
import pytest
from pettingzoo.test import max_cycles_test, parallel_api_test, render_test, state_test
from stable_baselines3.common.env_checker import check_env

import envs
from envs.mpe import CooperativeNavigationEnv, CooperativeNavigationSingleEnv
from envs.mpe import cooperative_navigation as coop_module
from envs.mpe.controllers import HandController, NoOpController, RandomController
from sb3_eps import evaluate_team
from sb3_eps.common.evaluation import summarize_episodes


def rollout(env: CooperativeNavigationEnv, seed: int, n_ticks: int, action_seed: int = 0) -> list:
    """Run ``n_ticks`` random ticks (resetting at the episode ends) and record everything the env returned."""
    rng = np.random.default_rng(action_seed)
    obs, infos = env.reset(seed=seed)
    record = [(obs, infos)]
    for _ in range(n_ticks):
        actions = {agent: int(rng.integers(5)) for agent in env.agents}
        record.append(env.step(actions))
        if not env.agents:
            record.append(env.reset())
    return record


def assert_same(a, b) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            assert_same(a[key], b[key])
    elif isinstance(a, list | tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same(x, y)
    else:
        np.testing.assert_array_equal(a, b)


# --- the multi-agent env -----------------------------------------------------------------------------------------


def test_parallel_api() -> None:
    parallel_api_test(CooperativeNavigationEnv(), num_cycles=60)


def test_state_and_max_cycles_and_render() -> None:
    with warnings.catch_warnings():
        # state_test warns that an MPE state space is unbounded, as it is for mpe2's own envs.
        warnings.simplefilter("ignore")
        state_test(coop_module.env(), coop_module.parallel_env())
    max_cycles_test(coop_module)
    render_test(coop_module.env)


def test_spaces_are_shared_and_fixed() -> None:
    env = CooperativeNavigationEnv()
    spaces = {id(env.observation_space(agent)) for agent in env.possible_agents}
    assert len(spaces) == 1 and len({id(env.action_space(agent)) for agent in env.possible_agents}) == 1
    assert env.observation_space("agent_0").shape == (18,)
    assert env.action_space("agent_0").n == 5
    env.reset(seed=0)
    assert env.state().shape == env.state_space.shape == (54,)
    assert env.state().dtype == np.float32


def test_seed_determinism_over_200_ticks() -> None:
    first = rollout(CooperativeNavigationEnv(), seed=3, n_ticks=200)
    again = rollout(CooperativeNavigationEnv(), seed=3, n_ticks=200)
    other = rollout(CooperativeNavigationEnv(), seed=4, n_ticks=200)
    assert_same(first, again)
    with pytest.raises(AssertionError):
        assert_same(first, other)


def test_episode_is_truncated_after_max_cycles() -> None:
    env = CooperativeNavigationEnv(max_cycles=7)
    env.reset(seed=0)
    for tick in range(1, 8):
        _, _, terminations, truncations, infos = env.step(dict.fromkeys(env.agents, 0))
        assert not any(terminations.values())
        assert all(truncations.values()) == (tick == 7)
    assert env.agents == [] and infos["agent_0"]["team"]["ticks"] == 7


def test_team_metrics_match_mpe2_benchmark_data() -> None:
    env = CooperativeNavigationEnv(benchmark_data=True)
    rng = np.random.default_rng(0)
    env.reset(seed=1)
    team_return = n_pairs = 0.0
    for _ in range(25):
        _, rewards, _, _, infos = env.step({agent: int(rng.integers(5)) for agent in env.agents})
        team = infos["agent_0"]["team"]
        assert all(infos[agent]["team"] is team for agent in infos)
        # mpe2's benchmark_data per agent: (reward, collisions of this agent, min distance sum, occupied).
        data = [infos[agent]["benchmark_data"] for agent in env.possible_agents]
        assert team["min_dist_sum"] == pytest.approx(data[0][2])
        assert team["occupied_landmarks"] == data[0][3]
        assert team["success"] == (data[0][3] == 3)
        n_pairs += sum(d[1] for d in data) / 2  # each colliding pair penalises both agents
        team_return += sum(rewards.values())
        assert team["n_collisions"] == n_pairs and team["collision"] == (n_pairs > 0)
        assert team["team_return"] == pytest.approx(team_return)


# A scripted episode: the world's physics replaced by positions set by hand, tick by tick. Landmarks at (-1, 0),
# (0, 0), (1, 0); agents collide below 0.3 between centres, occupy a landmark within 0.1.
LANDMARKS = [(-1.0, 0.0), (0.0, 0.0), (1.0, 0.0)]
SCRIPT = [
    [(0.0, 0.5), (0.1, 0.5), (1.0, -1.0)],  # reset: agents 0 and 1 spawn overlapping
    [(0.0, 0.5), (0.1, 0.5), (1.0, -1.0)],  # 1: still overlapping, the spawn overlap (all: 1, after spawn: 0)
    [(0.0, 0.5), (0.5, 0.5), (1.0, -1.0)],  # 2: separated
    [(0.0, 0.5), (0.1, 0.5), (1.0, -1.0)],  # 3: together again, a collision of the policy's (1 and 1)
    [(-1.0, 0.0), (0.0, 0.05), (1.0, 0.2)],  # 4: two landmarks occupied, the third 0.2 away
    [(-1.0, 0.0), (0.0, 0.05), (1.0, 0.0)],  # 5, the last: all three occupied, distance sum 0.05
]


def scripted_env() -> CooperativeNavigationEnv:
    """A 5-tick world whose agents and landmarks sit where :data:`SCRIPT` says, whatever the actions."""
    env = CooperativeNavigationEnv(max_cycles=len(SCRIPT) - 1)
    world, ticks = env._world, iter(SCRIPT[1:])

    def place(agent_pos) -> None:
        for entity, pos in zip(world.agents + world.landmarks, [*agent_pos, *LANDMARKS]):
            entity.state.p_pos = np.array(pos, dtype=float)
            entity.state.p_vel = np.zeros(2)

    scenario = env._env.unwrapped.scenario
    reset_world = scenario.reset_world
    scenario.reset_world = lambda world_, rng: (reset_world(world_, rng), place(SCRIPT[0]))
    world.step = lambda: place(next(ticks))
    return env


def test_scripted_episode_metrics() -> None:
    env = scripted_env()
    _, infos = env.reset(seed=0)
    assert infos["agent_0"]["team"]["n_collisions_after_spawn"] == 0
    team_return, per_tick = 0.0, []
    while env.agents:
        _, rewards, _, truncations, infos = env.step(dict.fromkeys(env.agents, 0))
        team = infos["agent_0"]["team"]
        per_tick.append((team["n_collisions"], team["n_collisions_after_spawn"], team["occupied_landmarks"]))
        team_return += sum(rewards.values())
    assert all(truncations.values())
    # Running counts: the spawn overlap of tick 1 counts in n_collisions only; the collision of tick 3 in both.
    assert per_tick == [(1, 0, 0), (1, 0, 0), (2, 1, 0), (2, 1, 2), (2, 1, 3)]
    assert team["collision"] and team["collision_after_spawn"]
    assert team["collisions_per_tick"] == pytest.approx(1 / 5)
    assert team["occupied_landmarks"] == 3 and team["success"]
    assert team["min_dist_sum"] == pytest.approx(0.05)
    # The team return is mpe2's reward summed over agents and ticks: 3 x 0.5 x (-distance sum) per tick, and 0.5 x
    # (-1) for each agent of a colliding pair (spawn overlaps included: the reward does not forgive them).
    distance_sums = [sum(min(np.hypot(lx - x, ly - y) for x, y in tick) for lx, ly in LANDMARKS) for tick in SCRIPT[1:]]
    expected = sum(-1.5 * d for d in distance_sums) - 0.5 * 2 * 2
    assert team["team_return"] == pytest.approx(team_return) == pytest.approx(expected)
    # The episode's dict reaches an evaluation: the summary averages the final tick's metrics.
    episode = {"r": team["team_return"], "l": team["ticks"], **team}
    summary = summarize_episodes([episode, {**episode, "success": False, "occupied_landmarks": 1}])
    assert summary["occupied_landmarks_mean"] == 2 and summary["success_rate"] == 0.5
    assert summary["collisions_per_tick_mean"] == pytest.approx(0.2) and summary["collision_after_spawn_rate"] == 1


def test_a_spawn_overlap_that_never_separates_is_never_counted() -> None:
    env = scripted_env()
    env._world.step = lambda: None  # the agents stay where they spawned
    env.reset(seed=0)
    while env.agents:
        _, _, _, _, infos = env.step(dict.fromkeys(env.agents, 0))
    team = infos["agent_0"]["team"]
    assert team["n_collisions"] == 5 and team["n_collisions_after_spawn"] == 0 and not team["collision_after_spawn"]
    assert team["collisions_per_tick"] == 0 and team["occupied_landmarks"] == 0 and not team["success"]


def test_hand_controller_beats_random_and_no_op() -> None:
    results = {
        name: evaluate_team(controller, "CooperativeNavigation-v0", n_eval_episodes=20, n_envs=2, seed=7)
        for name, controller in {"hand": HandController(), "random": RandomController(0), "no-op": NoOpController()}.items()
    }
    hand, random, no_op = results["hand"], results["random"], results["no-op"]
    assert hand["success_rate"] >= 0.4 and hand["occupied_landmarks_mean"] > 2
    assert random["success_rate"] == no_op["success_rate"] == 0
    assert hand["team_return_mean"] > max(random["team_return_mean"], no_op["team_return_mean"]) + 20
    assert hand["min_dist_sum_mean"] < 0.5 < no_op["min_dist_sum_mean"]
    assert no_op["collisions_per_tick_mean"] < random["collisions_per_tick_mean"]


def test_bad_arguments_raise_value_error() -> None:
    env = CooperativeNavigationEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="outside the action space"):
        env.step({"agent_0": 5, "agent_1": 0, "agent_2": 0})
    for seed in ("0", 1.5, -1, True):
        with pytest.raises(ValueError, match="seed must be None or a non-negative int"):
            env.reset(seed=seed)
    with pytest.raises(ValueError, match="render_mode"):
        CooperativeNavigationEnv(render_mode="ansi")


# --- the single-agent env ----------------------------------------------------------------------------------------


def test_single_passes_sb3_check_env() -> None:
    check_env(CooperativeNavigationSingleEnv())
    check_env(gymnasium.make("CooperativeNavigationSingle-v0").unwrapped)


def test_single_layout_matches_the_multi_agent_one() -> None:
    single, multi = CooperativeNavigationSingleEnv(), CooperativeNavigationEnv()
    assert single.observation_space.shape == multi.observation_space("agent_0").shape
    assert single.action_space == multi.action_space("agent_0")
    obs, info = single.reset(seed=0)
    landmarks, mates = obs[4:10].reshape(3, 2), obs[10:14].reshape(2, 2)
    # Each parked teammate sits on a landmark; one landmark is free: the learner's.
    parked = [int(np.argmin(np.abs(landmarks - mate).sum(axis=1))) for mate in mates]
    np.testing.assert_allclose(landmarks[parked], mates, atol=1e-6)
    free = ({0, 1, 2} - set(parked)).pop()
    assert np.all(obs[0:2] == 0) and np.all(obs[14:] == 0)
    distance = float(np.linalg.norm(landmarks[free]))
    assert info["team"]["min_dist_sum"] == pytest.approx(distance, abs=1e-6)
    assert info["team"]["occupied_landmarks"] == 2
    # No move: no collision at the start, so the reward is minus half the distance (local_ratio 0.5).
    _, reward, terminated, truncated, info = single.step(0)
    assert reward == pytest.approx(-0.5 * distance, abs=1e-6)
    assert not terminated and not truncated and info["team"]["ticks"] == 1


def greedy_action(obs: np.ndarray) -> int:
    """Head for the landmark no parked teammate sits on, braking ahead of it."""
    velocity, landmarks, mates = obs[0:2], obs[4:10].reshape(3, 2), obs[10:14].reshape(2, 2)
    free = next(lm for lm in landmarks if not any(np.allclose(lm, mate, atol=1e-5) for mate in mates))
    error = free - 0.5 * velocity
    if np.abs(error).max() < 0.03:
        return 0
    axis = int(np.argmax(np.abs(error)))
    return [[1, 2], [3, 4]][axis][int(error[axis] > 0)]


def test_single_rewards_navigation() -> None:
    env = CooperativeNavigationSingleEnv()
    results = {"greedy": [], "random": []}
    for name in results:
        env.action_space.seed(0)
        for episode in range(10):
            obs, _ = env.reset(seed=episode)
            for _ in range(25):
                action = greedy_action(obs) if name == "greedy" else env.action_space.sample()
                obs, _, _, truncated, info = env.step(action)
            assert truncated
            results[name].append((info["is_success"], info["team"]["team_return"]))
    greedy, random = np.array(results["greedy"]), np.array(results["random"])
    assert greedy[:, 0].mean() >= 0.5 > random[:, 0].mean()
    assert greedy[:, 1].mean() > random[:, 1].mean() + 3


def test_single_seed_determinism_and_errors() -> None:
    def run(seed: int) -> list:
        env = CooperativeNavigationSingleEnv()
        record = [env.reset(seed=seed)]
        record += [env.step(tick % 5) for tick in range(30)]
        return record

    assert_same(run(5), run(5))
    with pytest.raises(AssertionError):
        assert_same(run(5), run(6))
    env = CooperativeNavigationSingleEnv()
    env.reset(seed=0)
    for action in (5, -1, 1.5, "up"):
        with pytest.raises(ValueError, match="outside the action space"):
            env.step(action)
    for seed in ("0", 1.5, -1, False):
        with pytest.raises(ValueError, match="seed must be None or a non-negative int"):
            env.reset(seed=seed)


def test_single_renders() -> None:
    env = envs.make_single_env("CooperativeNavigationSingle-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    env.close()
