"""``benchmarks/failure_anatomy.py``: how a failed greedy episode is sorted, on the real PyBullet world."""

from __future__ import annotations

import importlib.util
import pathlib
import sys

import numpy as np
import pytest

import envs

ROOT = pathlib.Path(__file__).resolve().parents[1]
STAND_STILL = 2  # 5 * i_linear + i_angular: v = 0, w = 0
FULL_AHEAD = 17  # v = 0.21 m/s, w = 0


@pytest.fixture(scope="module")
def anatomy():
    spec = importlib.util.spec_from_file_location("failure_anatomy", ROOT / "benchmarks" / "failure_anatomy.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["failure_anatomy"] = module
    spec.loader.exec_module(module)
    return module


class Scripted:
    """A policy that always picks one action (stands in for a trained model: ``predict`` over a batch)."""

    def __init__(self, action: int) -> None:
        self.action = action

    def predict(self, observations: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return np.full(len(observations), self.action), None


def test_a_team_that_stands_still_times_out_standing(anatomy) -> None:
    env = envs.make_parallel_env("MultiRobotNav-2-v0", max_episode_steps=60)
    try:
        record = anatomy.run_episode(Scripted(STAND_STILL), env, seed=3, window=50)
    finally:
        env.close()
    assert record["outcome"] == "time-out" and record["ticks"] == 60 and record["n_arrived"] == 0
    assert [s["kind"] for s in record["stragglers"]] == ["standing still", "standing still"]
    assert [s["actions"] for s in record["stragglers"]] == [[(STAND_STILL, 50)], [(STAND_STILL, 50)]]
    assert all(s["driven"] == 0.0 and s["turned"] == 0.0 for s in record["stragglers"])
    assert all(s["nearest_parked"] is None for s in record["stragglers"])
    assert "what they did in the last window: standing still 2" in anatomy.summarize([record])


def test_a_team_that_drives_straight_ends_in_a_collision_that_is_named(anatomy) -> None:
    env = envs.make_parallel_env("MultiRobotNav-4-v0")
    try:
        records = [anatomy.run_episode(Scripted(FULL_AHEAD), env, seed=seed, window=50) for seed in range(3)]
    finally:
        env.close()
    collided = [record for record in records if record["outcome"] == "collision"]
    assert collided, "driving straight at full speed in a 4 m room must hit something within 600 ticks"
    for record in collided:
        assert record["collisions"] and set(record["collisions"]) <= {"robot", "parked robot", "wall"}


def test_the_time_out_kinds_follow_the_path(anatomy) -> None:
    target, parked = np.array([2.0, 0.0]), np.zeros((0, 2))
    observation = np.ones(30, dtype=np.float32)
    line = np.column_stack([np.linspace(0.0, 1.0, 50), np.zeros(50)])
    heading = np.zeros(50)
    assert anatomy.classify_timeout(line, heading, target, parked, observation)["kind"] == "slow"
    circle = np.column_stack([np.cos(np.linspace(0, 4 * np.pi, 50)), np.sin(np.linspace(0, 4 * np.pi, 50))])
    assert anatomy.classify_timeout(circle, heading, target, parked, observation)["kind"] == "looping"
    near = np.tile([1.7, 0.0], (50, 1))
    result = anatomy.classify_timeout(near, heading, target, np.array([[2.1, 0.1]]), observation)
    assert result["kind"] == "near target" and result["target_crowded"]
    spinning = np.tile([0.0, 0.0], (50, 1))
    result = anatomy.classify_timeout(spinning, np.linspace(0, 10, 50), target, parked, observation)
    assert result["kind"] == "turning in place" and result["turned"] == pytest.approx(10.0)


def test_epsilon_greedy_replays_are_seeded_and_leave_a_standing_team_moving(anatomy) -> None:
    env = envs.make_parallel_env("MultiRobotNav-2-v0", max_episode_steps=60)
    try:
        first = anatomy.run_episode(Scripted(STAND_STILL), env, seed=3, window=50, epsilon=0.5)
        again = anatomy.run_episode(Scripted(STAND_STILL), env, seed=3, window=50, epsilon=0.5)
    finally:
        env.close()
    assert first == again
    if first["outcome"] == "time-out":
        assert all(s["driven"] > 0 for s in first["stragglers"])


def test_a_collision_names_what_was_touched(anatomy) -> None:
    xy = np.array([[0.0, 0.0], [0.2, 0.0], [3.0, 3.0]])
    assert anatomy.classify_collision(xy, 0, live=np.array([True, True, True])) == "robot"
    assert anatomy.classify_collision(xy, 0, live=np.array([True, False, True])) == "parked robot"
    assert anatomy.classify_collision(xy, 2, live=np.array([True, True, True])) == "wall"
    half = np.array([2.0, 2.0])
    assert anatomy.classify_collision(np.array([[1.8, -1.75], [0.0, 0.0]]), 0, np.array([True, True]), half) == "corner"
    assert anatomy.classify_collision(np.array([[1.8, 0.0], [0.0, 0.0]]), 0, np.array([True, True]), half) == "wall"


def test_the_most_common_failure_is_animated(anatomy, tmp_path) -> None:
    env = envs.make_parallel_env("MultiRobotNav-2-v0")
    try:
        records = [anatomy.run_episode(Scripted(FULL_AHEAD), env, seed, window=50) for seed in (0, 1)]
    finally:
        env.close()
    args = type("Args", (), {"env": "MultiRobotNav-2-v0", "window": 50, "epsilon": 0.0, "animate": tmp_path / "f.gif"})
    anatomy.animate(Scripted(FULL_AHEAD), args, records)
    assert anatomy.failure_kind(records[0]).startswith("collision: ")
    assert (tmp_path / "f.gif").stat().st_size > 1000
