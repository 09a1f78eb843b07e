"""Waypoints on a room's static map (``path_guidance``, ``envs/turtlebot3/paths.py``): path lengths round walls,
waypoints toward the doorway, and the world's observation and progress reward along the path."""

from __future__ import annotations

import numpy as np
import pytest

import envs
from envs.turtlebot3.layouts import Layout, walls_around
from envs.turtlebot3.paths import PathGuide
from envs.turtlebot3.robot import DISTANCE_SCALE, N_BEAMS, STEP_PENALTY


def walled_room() -> Layout:
    """A 5 m x 5 m room split at x = 0 by a wall from y = -2.5 to y = 1.0: the doorway is at y in (1.0, 2.5)."""
    inner = np.array([[0.0, -0.75, 0.05, 1.75]])  # centre (0, -0.75), half extents 0.05 x 1.75
    return Layout("walled", 5.0, 5.0, walls_around(5.0, 5.0), inner)


def test_in_an_open_room_the_path_is_the_straight_line() -> None:
    room = Layout("open", 5.0, 5.0, walls_around(5.0, 5.0))
    guide = PathGuide(room, np.array([[1.5, 0.5]]))
    length, waypoint = guide.query(np.array([[-1.5, -0.5]]), np.array([0]))
    straight = np.hypot(3.0, 1.0)
    assert straight <= length[0] <= 1.06 * straight  # grid paths are a little longer than the line
    heading = np.arctan2(*(waypoint[0] - [-1.5, -0.5])[::-1])
    assert abs(heading - np.arctan2(1.0, 3.0)) < 0.2
    assert np.linalg.norm(waypoint[0] - [-1.5, -0.5]) == pytest.approx(1.0, abs=0.15)  # 1 m ahead


def test_behind_a_wall_the_path_goes_through_the_doorway() -> None:
    guide = PathGuide(walled_room(), np.array([[1.0, -1.5]]))
    start = np.array([[-1.0, -1.5]])
    length, waypoint = guide.query(start, np.array([0]))
    # Up to the doorway at y > 1.0 and down again: at least 2 x hypot(1, 2.5), far more than the straight 2 m.
    assert length[0] > 2 * np.hypot(1.0, 2.5) > 2.0
    assert waypoint[0, 1] > start[0, 1] + 0.5 and waypoint[0, 0] < 0  # heading up the wall, still on its side
    # Following the waypoints leads through the doorway to the target.
    xy = start.copy()
    for _ in range(400):
        _, waypoint = guide.query(xy, np.array([0]))
        step = waypoint[0] - xy[0]
        xy[0] += 0.05 * step / max(np.linalg.norm(step), 1e-9)
        if np.linalg.norm(xy[0] - [1.0, -1.5]) < 0.1:
            break
    assert np.linalg.norm(xy[0] - [1.0, -1.5]) < 0.1
    # The path length is continuous in the position (the progress reward does not jump between cells).
    near = guide.query(start + np.array([[0.01, 0.0]]), np.array([0]))[0]
    assert abs(near[0] - length[0]) < 0.02


def test_the_world_observes_and_rewards_along_the_path() -> None:
    kwargs = {"level": 1, "action_repeat": 1, "lidar_range": 1.0}
    plain = envs.make_parallel_env("MultiRobotNavRooms-4-validation-v0", **kwargs)
    guided = envs.make_parallel_env("MultiRobotNavRooms-4-validation-v0", path_guidance=True, **kwargs)
    obs_plain, _ = plain.reset(seed=0)
    obs, _ = guided.reset(seed=0)
    assert np.array_equal(plain.world.xy, guided.world.xy)  # the same episode; only what the robots are told differs
    for k, agent in enumerate(guided.agents):
        assert obs[agent][N_BEAMS] == pytest.approx(min(guided._distance[k] / DISTANCE_SCALE, 1.0), rel=1e-5)
        assert obs[agent][N_BEAMS] >= obs_plain[agent][N_BEAMS] - 1e-6  # a path is never shorter than the line
        assert np.array_equal(obs[agent][:N_BEAMS], obs_plain[agent][:N_BEAMS])
    before = guided._distance.copy()
    _, rewards, _, _, _ = guided.step(dict.fromkeys(guided.agents, 17))
    for k, agent in enumerate(guided.possible_agents):
        if agent in rewards and abs(rewards[agent]) < 0.5:
            assert rewards[agent] == pytest.approx(before[k] - guided._distance[k] - STEP_PENALTY, abs=1e-9)
    for env in (plain, guided):
        env.close()
    with pytest.raises(ValueError, match="path_guidance must be True or False"):
        envs.make_parallel_env("MultiRobotNav-4-v0", path_guidance="yes")


def test_clearance_and_lookahead_are_world_options() -> None:
    kwargs = {"level": 1, "action_repeat": 1, "lidar_range": 1.0, "path_guidance": True}
    near = envs.make_parallel_env("MultiRobotNavRooms-4-validation-v0", **kwargs)
    wide = envs.make_parallel_env("MultiRobotNavRooms-4-validation-v0", path_clearance=0.25, path_lookahead=0.5, **kwargs)
    near.reset(seed=0)
    wide.reset(seed=0)
    assert wide._guide.free.sum() < near._guide.free.sum()  # a wider margin blocks more cells along the walls
    length, waypoint = wide._guide.query(wide.world.xy, np.arange(4))
    assert np.all(np.isfinite(length))
    ahead = np.linalg.norm(waypoint - wide.world.xy, axis=1)
    assert np.all(ahead <= 0.5 + 0.15)  # the waypoint lies at most the lookahead (plus a cell) away
    note = wide.deployment_description()["observation"]["goal_heading"]["note"]
    assert "0.5 m ahead" in note and "keeps 0.25 m" in note
    for bad in ({"path_clearance": 0.05}, {"path_clearance": 0.5}, {"path_lookahead": 0.0}, {"path_lookahead": "1"}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            envs.make_parallel_env("MultiRobotNavRooms-4-validation-v0", **bad)


def test_a_parked_robot_on_the_straight_line_is_planned_round() -> None:
    room = Layout("open", 5.0, 5.0, walls_around(5.0, 5.0))
    start, target = np.array([[-1.5, 0.0]]), np.array([[1.5, 0.0]])
    static = PathGuide(room, target)
    round_parked = PathGuide(room, target, parked=np.array([[0.0, 0.0]]), lookahead=0.3)
    length_static, _ = static.query(start, np.array([0]))
    length, _ = round_parked.query(start, np.array([0]))
    assert length[0] > length_static[0] + 0.05  # the detour round the parked robot's footprint
    # Walking the waypoints (0.3 m ahead: a waypoint 1 m ahead cuts the detour's corners, as it cuts walls') reaches
    # the target without touching the parked robot.
    xy, closest = start.copy(), np.inf
    for _ in range(200):
        _, waypoint = round_parked.query(xy, np.array([0]))
        step = waypoint[0] - xy[0]
        xy[0] += 0.05 * step / max(np.linalg.norm(step), 1e-9)
        closest = min(closest, float(np.linalg.norm(xy[0])))
        if np.linalg.norm(xy[0] - target[0]) < 0.1:
            break
    assert np.linalg.norm(xy[0] - target[0]) < 0.1
    assert closest > 2 * 0.105  # never within two radii of the parked robot's centre


def test_path_replan_plans_again_when_robots_park_and_earns_no_reward_for_it() -> None:
    kwargs = {"level": 1, "action_repeat": 1, "lidar_range": 1.0, "path_guidance": True}
    world = envs.make_parallel_env("MultiRobotNavRooms-4-validation-v0", path_replan=True, **kwargs)
    world.reset(seed=0)
    first = world._guide
    # Park robot 0 on its target by hand, then step: the planner plans again with it on the map.
    poses = np.column_stack([world.world.xy, world.world.theta])
    poses[0, :2] = world._targets[0]
    world.world.set_poses(poses)
    _, rewards, terminations, _, infos = world.step(dict.fromkeys(world.agents, 2))  # everyone stands still
    assert infos["robot_0"]["arrived"] and terminations["robot_0"]
    assert world._guide is not first and world._guide.free.sum() < first.free.sum()
    # Standing still after the replan earns the step penalty alone: the new path lengths start from here.
    _, rewards, _, _, _ = world.step(dict.fromkeys(world.agents, 2))
    assert all(r == pytest.approx(-STEP_PENALTY) for r in rewards.values())
    note = world.deployment_description()["observation"]["goal_heading"]["note"]
    assert "plans again" in note
    with pytest.raises(ValueError, match="path_replan"):
        envs.make_parallel_env("MultiRobotNavRooms-4-validation-v0", path_replan="yes")
