"""The varied unseen room (``placement_jitter``, ``MultiRobotNavUnseen-4-varied-v0``): every episode a new problem,
every pose valid, seeding reproducible, the fixed room unchanged, and the arena's spaces so any 4-robot model runs."""

from __future__ import annotations

import numpy as np
import pytest

import envs
from envs.turtlebot3 import MultiRobotNavEnv, SingleRobotNavEnv
from envs.turtlebot3.layouts import (
    HEADING_JITTER,
    MIN_START_TARGET,
    START_CLEARANCE,
    START_SPACING,
    TARGET_CLEARANCE,
    TARGET_SPACING,
    TARGET_START_SPACING,
    UNSEEN_STARTS,
    UNSEEN_TARGET_SETS,
    clearance,
    jitter_starts,
    jitter_targets,
    unseen_layout,
)
from envs.turtlebot3.robot import ROBOT_RADIUS, TARGET_RADIUS
from sb3_eps import GDQ
from sb3_eps.common.evaluation import evaluate_team
from tests.test_algorithms import tiny_model
from tests.test_turtlebot3_physics import reachable

VARIED = "MultiRobotNavUnseen-4-varied-v0"
JITTER = 0.3  # the id's placement_jitter
N_SETS = len(UNSEEN_TARGET_SETS)


def episodes(env: MultiRobotNavEnv, seed: int, n_episodes: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Start poses and targets of ``n_episodes`` resets after one seeded reset."""
    problems = []
    for episode in range(n_episodes):
        env.reset(seed=seed if episode == 0 else None)
        problems.append((np.column_stack([env.world.xy, env.world.theta]), env._targets.copy()))
    return problems


def pairwise_min(points: np.ndarray) -> float:
    gaps = np.linalg.norm(points[:, None] - points[None], axis=-1)
    return float(gaps[np.triu_indices(len(points), k=1)].min())


def test_the_id_fixes_the_unseen_room_with_a_jitter() -> None:
    env = envs.make_parallel_env(VARIED)
    assert (env.scenario, env.n_robots, env.placement_jitter) == ("unseen", 4, JITTER)
    env.close()
    with pytest.raises(ValueError, match=r"fixes placement_jitter=0\.3"):
        envs.make_parallel_env(VARIED, placement_jitter=0.0)


def test_every_episode_is_another_problem() -> None:
    env = envs.make_parallel_env(VARIED)
    problems = episodes(env, seed=0, n_episodes=100)
    env.close()
    starts = np.array([start[:, :2].ravel() for start, _ in problems])
    targets = np.array([target.ravel() for _, target in problems])
    for poses in (starts, targets):
        assert pairwise_min(poses) > 1e-3  # no two of the 100 episodes share their poses
    # Each episode stays a neighbour of its fixed problem: the five sets cycle, offsets within the jitter.
    for episode, (start, target) in enumerate(problems):
        assert np.linalg.norm(start[:, :2] - UNSEEN_STARTS[:, :2], axis=1).max() <= JITTER + 1e-9
        assert np.linalg.norm(target - UNSEEN_TARGET_SETS[episode % N_SETS], axis=1).max() <= JITTER + 1e-9
        turn = np.angle(np.exp(1j * (start[:, 2] - UNSEEN_STARTS[:, 2])))
        assert np.abs(turn).max() <= HEADING_JITTER + 1e-9
    # The offsets use the disc, not a corner of it: some are large, and they point every way.
    offsets = targets.reshape(-1, 2) - np.tile(UNSEEN_TARGET_SETS, (20, 1, 1)).reshape(-1, 2)
    assert np.linalg.norm(offsets, axis=1).max() > 0.25
    assert (offsets > 0.1).any(axis=0).all() and (offsets < -0.1).any(axis=0).all()


def assert_valid(xy: np.ndarray, target: np.ndarray, boxes: np.ndarray, half: float) -> None:
    """The placement rules of the varied room, checked from scratch."""
    assert clearance(xy, boxes).min() >= START_CLEARANCE
    assert clearance(target, boxes).min() >= TARGET_CLEARANCE
    assert np.abs(np.concatenate([xy, target])).max() < half - TARGET_CLEARANCE + 1e-9
    assert pairwise_min(xy) >= START_SPACING
    assert pairwise_min(target) >= TARGET_SPACING
    gaps = np.linalg.norm(target[:, None] - xy[None], axis=-1)
    assert gaps.min() >= TARGET_START_SPACING
    assert np.diag(gaps).min() >= MIN_START_TARGET


@pytest.mark.parametrize("jitter", [JITTER, 0.5])
def test_thousands_of_draws_keep_the_placement_rules(jitter: float) -> None:
    # Unchecked offsets break them often: a swap target (0.7 m from a neighbour's start) lands within 0.5 m of it,
    # and at 0.5 m a corner target comes within 2 m of its own start.
    layout, rng = unseen_layout(), np.random.default_rng(0)
    for draw in range(2000):
        starts = jitter_starts(rng, layout, UNSEEN_STARTS, jitter)
        targets = jitter_targets(rng, layout, UNSEEN_TARGET_SETS[draw % N_SETS], starts[:, :2], jitter)
        assert_valid(starts[:, :2], targets, layout.boxes, layout.width / 2)


def test_every_start_and_target_is_valid_in_the_world() -> None:
    env = envs.make_parallel_env(VARIED)
    boxes, half = env.layout.boxes, env.layout.width / 2
    for seed in range(3):
        for start, target in episodes(env, seed=seed, n_episodes=N_SETS * 8):
            xy = start[:, :2]
            gaps = np.linalg.norm(target[:, None] - xy[None], axis=-1)
            assert_valid(xy, target, boxes, half)
            # The physics agrees: nothing touches at the start, nobody stands on its target.
            assert not env.world.map_collisions().any() and not env.world.robot_collisions().any()
            assert pairwise_min(xy) > 2 * ROBOT_RADIUS and np.diag(gaps).min() > TARGET_RADIUS
            for robot in range(4):
                assert reachable(boxes, half, xy[robot], target[robot])
    env.close()


def test_a_seed_reproduces_the_episodes_and_another_seed_does_not() -> None:
    first, second = envs.make_parallel_env(VARIED), envs.make_parallel_env(VARIED)
    again = episodes(first, seed=11, n_episodes=7)
    for (start_a, target_a), (start_b, target_b) in zip(again, episodes(second, seed=11, n_episodes=7)):
        np.testing.assert_array_equal(start_a, start_b)
        np.testing.assert_array_equal(target_a, target_b)
    other = episodes(second, seed=12, n_episodes=7)
    for (start_a, target_a), (start_b, target_b) in zip(again, other):
        assert not np.allclose(start_a, start_b) and not np.allclose(target_a, target_b)
    # Many ticks of the same actions stay identical too.
    rng = np.random.default_rng(0)
    first.reset(seed=5)
    second.reset(seed=5)
    for _ in range(200):
        if not first.agents:
            first.reset()
            second.reset()
        actions = {agent: int(rng.integers(20)) for agent in first.agents}
        obs_a, rewards_a, *_ = first.step(actions)
        obs_b, rewards_b, *_ = second.step(actions)
        assert rewards_a == rewards_b
        for agent in obs_a:
            np.testing.assert_array_equal(obs_a[agent], obs_b[agent])
    first.close()
    second.close()


def test_the_fixed_room_is_unchanged() -> None:
    env = envs.make_parallel_env("MultiRobotNavUnseen-4-v0")
    assert env.placement_jitter == 0.0
    for seed in (0, 3):
        for episode, (start, target) in enumerate(episodes(env, seed=seed, n_episodes=N_SETS + 1)):
            np.testing.assert_array_equal(start, UNSEEN_STARTS)
            np.testing.assert_array_equal(target, UNSEEN_TARGET_SETS[episode % N_SETS])
    env.close()


def test_spaces_are_the_arena_s_and_an_arena_model_runs_there() -> None:
    arena, varied = envs.make_parallel_env("MultiRobotNav-4-v0"), envs.make_parallel_env(VARIED)
    assert varied.possible_agents == arena.possible_agents
    for agent in arena.possible_agents:
        assert varied.observation_space(agent) == arena.observation_space(agent)
        assert varied.action_space(agent) == arena.action_space(agent)
    arena.close()
    varied.close()
    model = tiny_model(GDQ, env_id="MultiRobotNav-4-v0", n_envs=1)
    result = evaluate_team(model, VARIED, 2, n_envs=1, seed=0, env_kwargs={"max_episode_steps": 20})
    assert result["n_episodes"] == 2


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"scenario": "arena", "placement_jitter": 0.3}, "draws its poses at random"),
        ({"scenario": "unseen", "placement_jitter": -0.1}, r"in \[0, 0.5\]"),
        ({"scenario": "unseen", "placement_jitter": 0.8}, r"in \[0, 0.5\]"),
        ({"scenario": "unseen", "placement_jitter": "0.3"}, r"in \[0, 0.5\]"),
        ({"scenario": "unseen", "placement_jitter": float("nan")}, r"in \[0, 0.5\]"),
    ],
)
def test_bad_placement_jitter_is_refused_in_one_line(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message) as error:
        MultiRobotNavEnv(n_robots=4, **kwargs)
    assert "\n" not in str(error.value)


def test_the_single_robot_view_of_the_room_takes_the_jitter_too() -> None:
    fixed, varied = SingleRobotNavEnv("unseen"), SingleRobotNavEnv("unseen", placement_jitter=JITTER)
    fixed_obs, _ = fixed.reset(seed=0)
    varied_obs, _ = varied.reset(seed=0)
    assert varied.observation_space == fixed.observation_space
    assert not np.allclose(fixed_obs, varied_obs)
    np.testing.assert_array_equal(fixed.multi_env.world.xy[0], UNSEEN_STARTS[0, :2])
    offset = np.linalg.norm(varied.multi_env.world.xy[0] - UNSEEN_STARTS[0, :2])
    assert 0 < offset <= JITTER
    fixed.close()
    varied.close()
