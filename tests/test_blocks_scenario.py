"""The ``"blocks"`` scenario: the arena with blocks drawn anew at every reset. Every draw keeps its gaps, every start
and target is clear and reachable, the physics (lidar, collisions) sees the blocks, a seed reproduces the rooms,
and a pickled or closed env comes back with its blocks."""

from __future__ import annotations

import itertools
import pickle

import numpy as np
import pytest

from envs.turtlebot3 import MultiRobotNavEnv
from envs.turtlebot3.layouts import (
    BLOCK_GAP,
    BLOCK_HALF_SIZES,
    BLOCK_HALF_STEP,
    START_CLEARANCE,
    TARGET_CLEARANCE,
    arena_side,
    clearance,
    sample_blocks,
)
from envs.turtlebot3.robot import RANGE_MAX
from tests.test_turtlebot3_physics import reachable


@pytest.mark.parametrize("n_robots", [4, 8, 12])
def test_every_draw_keeps_its_gaps_and_sizes(n_robots: int) -> None:
    side = arena_side(n_robots)
    rng = np.random.default_rng(0)
    counts = []
    for _ in range(300):
        blocks = sample_blocks(rng, side)
        counts.append(len(blocks))
        centres, half = blocks[:, :2], blocks[:, 2:]
        assert (half >= BLOCK_HALF_SIZES[0] - 1e-12).all() and (half <= BLOCK_HALF_SIZES[1] + 1e-12).all()
        np.testing.assert_allclose(half / BLOCK_HALF_STEP, np.round(half / BLOCK_HALF_STEP), atol=1e-9)
        assert (np.abs(centres) + half <= side / 2 - BLOCK_GAP + 1e-9).all()  # off the walls
        for i in range(len(blocks)):
            for j in range(i):
                apart = np.abs(centres[i] - centres[j]) - half[i] - half[j]
                assert apart.max() >= BLOCK_GAP - 1e-9  # a passage between any two
    assert np.mean(counts) >= 0.9 * round(side * side / 4.0)  # nearly every room gets its blocks


def test_every_episode_is_a_new_room_and_every_pose_is_clear_and_reachable() -> None:
    env = MultiRobotNavEnv(4, scenario="blocks")
    rooms = []
    for episode in range(40):
        env.reset(seed=3 if episode == 0 else None)
        blocks = env.layout.obstacles
        rooms.append(blocks.copy())
        assert len(blocks) >= 1
        assert (clearance(env.world.xy, blocks) >= START_CLEARANCE - 1e-9).all()
        assert (clearance(env._targets, blocks) >= TARGET_CLEARANCE - 1e-9).all()
        assert not env.world.map_collisions().any()
        for robot in range(4):
            assert reachable(env.layout.boxes, env.layout.width / 2, env.world.xy[robot], env._targets[robot])
    assert all(not np.array_equal(a, b) for a, b in itertools.pairwise(rooms))
    env.close()


def test_the_lidar_and_the_collisions_see_the_blocks() -> None:
    env = MultiRobotNavEnv(1, scenario="blocks")
    env.reset(seed=0)
    cx, cy, hx, hy = env.layout.obstacles[0]
    # In front of the block's west face, facing east: the middle beam reads the gap.
    start = np.array([[cx - hx - 0.3, cy, 0.0]])
    env.reset(seed=0, options={"start_poses": start, "targets": [[cx - hx - 1.2, cy]]})
    np.testing.assert_array_equal(env.layout.obstacles[0], [cx, cy, hx, hy])  # the same seed, the same room
    ranges = env.world.scan(np.array([0]))[0]
    assert abs(ranges.min() - 0.3) < 0.02 and ranges.min() < RANGE_MAX
    # A robot reaching into the block touches it.
    env.reset(seed=0, options={"start_poses": np.array([[cx - hx - 0.05, cy, 0.0]]), "targets": [[cx - hx - 1.2, cy]]})
    assert env.world.map_collisions().all()
    env.close()


def test_a_seed_reproduces_the_rooms_and_a_pickled_or_closed_env_keeps_its_blocks() -> None:
    first, second = MultiRobotNavEnv(8, scenario="blocks"), MultiRobotNavEnv(8, scenario="blocks")
    for episode in range(5):
        first.reset(seed=21 if episode == 0 else None)
        second.reset(seed=21 if episode == 0 else None)
        np.testing.assert_array_equal(first.layout.obstacles, second.layout.obstacles)
    second.reset(seed=22)
    assert not np.array_equal(first.layout.obstacles, second.layout.obstacles)
    copy = pickle.loads(pickle.dumps(first))
    np.testing.assert_array_equal(copy.world.scan(np.arange(8)), first.world.scan(np.arange(8)))
    first.close()
    first.reset(seed=21)  # a closed env starts a new client: the blocks of the new episode, none of the old ones
    second.reset(seed=21)
    np.testing.assert_array_equal(first.world.scan(np.arange(8)), second.world.scan(np.arange(8)))
    for env in (first, second, copy):
        env.close()
