"""Physics and task rules of the TurtleBot3 worlds: motion, lidar, collisions, arrival, targets, layouts."""

from __future__ import annotations

from collections import deque

import numpy as np
import pybullet as p
import pytest

from envs.turtlebot3 import MultiRobotNavEnv
from envs.turtlebot3.layouts import (
    TARGET_CLEARANCE,
    TARGET_SPACING,
    UNSEEN_STARTS,
    UNSEEN_TARGET_SETS,
    arena_side,
    clearance,
    eps_layout,
    unseen_layout,
)
from envs.turtlebot3.robot import (
    ACTION_ANGULAR,
    ACTION_LINEAR,
    BEAM_ANGLES,
    RANGE_MAX,
    ROBOT_RADIUS,
    STEP_PENALTY,
    integrate_unicycle,
    wrap_angle,
)

STRAIGHT_FULL = 17  # 0.21 m/s, 0 deg/s
STAND_STILL = 2


def bullet_pose(env: MultiRobotNavEnv, robot: int) -> tuple[np.ndarray, float]:
    """The robot's pose as PyBullet holds it (not our numpy mirror)."""
    position, orientation = p.getBasePositionAndOrientation(env.world.robot_ids[robot], physicsClientId=env.world.client)
    yaw = p.getEulerFromQuaternion(orientation)[2]
    return np.array(position[:2]), yaw


def placed_env(starts: list[list[float]], targets: list[list[float]], **kwargs: object) -> MultiRobotNavEnv:
    env = MultiRobotNavEnv(n_robots=len(starts), **kwargs)  # type: ignore[arg-type]
    env.reset(seed=0, options={"start_poses": starts, "targets": targets})
    return env


# --- kinematics ----------------------------------------------------------------------------------------


def test_closed_form_matches_textbook_arc() -> None:
    rng = np.random.default_rng(0)
    x, y, theta = rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), rng.uniform(-np.pi, np.pi, 50)
    v, w = rng.uniform(0, 0.21, 50), rng.uniform(-1.6, 1.6, 50)
    new_x, new_y, new_theta = integrate_unicycle(x, y, theta, v, w, 0.05)
    np.testing.assert_allclose(new_x, x + v / w * (np.sin(theta + 0.05 * w) - np.sin(theta)), atol=1e-12)
    np.testing.assert_allclose(new_y, y - v / w * (np.cos(theta + 0.05 * w) - np.cos(theta)), atol=1e-12)
    np.testing.assert_allclose(np.cos(new_theta), np.cos(theta + 0.05 * w), atol=1e-12)
    straight_x, straight_y, _ = integrate_unicycle(x, y, theta, v, np.zeros(50), 0.05)
    np.testing.assert_allclose(straight_x, x + 0.05 * v * np.cos(theta), atol=1e-12)
    np.testing.assert_allclose(straight_y, y + 0.05 * v * np.sin(theta), atol=1e-12)


@pytest.mark.parametrize("action", [STRAIGHT_FULL, 16, 19, 10, 7, 0, 4])
def test_command_held_one_second_comes_out_true(action: int) -> None:
    """20 decisions of 0.05 s: distance and heading change within 2 % of v * 1 s and w * 1 s."""
    env = placed_env([[-0.5, -0.5, 0.3]], [[1.2, 1.2]])
    v, w = ACTION_LINEAR[action], ACTION_ANGULAR[action]
    previous, _ = bullet_pose(env, 0)
    path, turned = 0.0, 0.0
    _, yaw_before = bullet_pose(env, 0)
    for _ in range(20):
        env.step({"robot_0": action})
        position, yaw = bullet_pose(env, 0)
        path += float(np.linalg.norm(position - previous))
        turned += float(wrap_angle(np.array(yaw - yaw_before)))
        previous, yaw_before = position, yaw
    assert path == pytest.approx(v * 1.0, rel=0.02, abs=1e-9)
    assert turned == pytest.approx(w * 1.0, rel=0.02, abs=1e-9)
    assert env.state()[4] == pytest.approx(v) and env.state()[5] == pytest.approx(w)
    # The world's mirror and PyBullet agree.
    np.testing.assert_allclose(env.world.xy[0], previous, atol=1e-9)
    env.close()


def test_distance_travelled_counts_every_robot() -> None:
    env = placed_env([[-0.8, -0.8, 0.0], [-0.8, 0.8, 0.0]], [[1.0, -1.0], [1.0, 1.0]])
    for _ in range(10):
        _, _, _, _, infos = env.step({"robot_0": STRAIGHT_FULL, "robot_1": 12})
    assert infos["robot_0"]["team"]["distance_travelled"] == pytest.approx(10 * 0.05 * (0.21 + 0.14))
    assert infos["robot_1"]["team"]["ticks"] == 10
    env.close()


# --- lidar ---------------------------------------------------------------------------------------------


def room_ranges(x: float, y: float, theta: float, half: float) -> np.ndarray:
    """Exact beam lengths from (x, y) to the walls of the square room [-half, half]^2, capped at 3.5 m."""
    angles = theta + BEAM_ANGLES
    cos, sin = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(cos > 0, (half - x) / cos, np.where(cos < 0, (-half - x) / cos, np.inf))
        ty = np.where(sin > 0, (half - y) / sin, np.where(sin < 0, (-half - y) / sin, np.inf))
    return np.minimum(np.minimum(tx, ty), RANGE_MAX)


@pytest.mark.parametrize(("x", "y", "theta"), [(0.0, 0.0, 0.0), (1.0, -0.4, 2.0), (-1.3, 1.2, -2.5)])
def test_lidar_reads_walls_within_1cm(x: float, y: float, theta: float) -> None:
    env = MultiRobotNavEnv(n_robots=1)
    obs, _ = env.reset(seed=0, options={"start_poses": [[x, y, theta]], "targets": [[0.5, 0.5]]})
    expected = room_ranges(x, y, theta, arena_side(1) / 2)
    np.testing.assert_allclose(obs["robot_0"][:28] * RANGE_MAX, expected, atol=0.01)
    env.close()


@pytest.mark.parametrize("distance", [0.3, 1.0, 2.5])
def test_beam_facing_a_wall_reads_its_distance(distance: float) -> None:
    """Beam 13 turned to face +x exactly reads the distance to the east wall (within 1 cm)."""
    half = arena_side(1) / 2
    env = MultiRobotNavEnv(n_robots=1)
    heading = -BEAM_ANGLES[13]
    obs, _ = env.reset(options={"start_poses": [[half - distance, 0.0, heading]], "targets": [[0.0, 1.0]]})
    assert obs["robot_0"][13] * RANGE_MAX == pytest.approx(distance, abs=0.01)
    env.close()


def test_lidar_sees_other_robots_and_max_range() -> None:
    # 12-robot arena (6 m): robot 0 near the west wall looks east along beam 13 at robot 1, 1.5 m away.
    starts = [[-2.8, 0.0, -BEAM_ANGLES[13]], [-1.3, 0.0, 0.0]] + [[-2.0 + 0.5 * i, 2.5, 0.0] for i in range(10)]
    targets = [[2.5, -2.5 + 0.5 * i] for i in range(12)]
    env = MultiRobotNavEnv(n_robots=12)
    obs, _ = env.reset(options={"start_poses": starts, "targets": targets})
    assert obs["robot_0"][13] * RANGE_MAX == pytest.approx(1.5 - ROBOT_RADIUS, abs=0.01)
    # Robot 1 looks east across the empty room (4.3 m to the wall): beyond the 3.5 m range.
    assert obs["robot_1"][13] == pytest.approx(1.0)
    env.close()


def test_observation_target_distance_and_heading() -> None:
    env = MultiRobotNavEnv(n_robots=1)
    obs, _ = env.reset(options={"start_poses": [[0.0, 0.0, 0.0]], "targets": [[0.0, 1.0]]})
    assert obs["robot_0"][28] == pytest.approx(0.1)  # 1 m / 10 m
    assert obs["robot_0"][29] == pytest.approx(0.5)  # target 90 deg to the left: +pi/2 / pi
    obs, _ = env.reset(options={"start_poses": [[0.0, 0.0, np.pi / 2]], "targets": [[1.0, 0.0]]})
    assert obs["robot_0"][29] == pytest.approx(-0.5)
    env.close()


# --- arrival, parking, collisions ------------------------------------------------------------------------


def test_driving_onto_the_target_arrives_and_parks() -> None:
    env = placed_env([[-1.0, 0.0, 0.0], [0.0, 1.2, 0.0]], [[0.0, 0.0], [1.2, -1.2]])
    ticks = 0
    while True:
        ticks += 1
        obs, rewards, terminations, truncations, infos = env.step({"robot_0": STRAIGHT_FULL, "robot_1": STAND_STILL})
        if terminations["robot_0"]:
            break
        # Eq. 7 dense term: 0.0105 m of progress per tick minus the step penalty.
        assert rewards["robot_0"] == pytest.approx(0.21 * 0.05 - STEP_PENALTY)
        assert rewards["robot_1"] == pytest.approx(-STEP_PENALTY)
    assert ticks == 86  # (1 m - 0.1 m) / 0.0105 m per tick = 85.7
    assert rewards["robot_0"] == 1.0 and infos["robot_0"]["arrived"] and not truncations["robot_0"]
    assert not terminations["robot_1"]
    assert env.agents == ["robot_1"]
    assert infos["robot_1"]["team"]["n_arrived"] == 1 and not infos["robot_1"]["team"]["success"]
    parked = env.world.xy[0].copy()
    # The others keep going; the parked robot stays put and only the live robot gets results.
    obs, rewards, terminations, truncations, infos = env.step({"robot_1": 15})  # 0.21 m/s, turning right
    assert set(obs) == {"robot_1"}
    np.testing.assert_array_equal(env.world.xy[0], parked)
    assert env.state()[8] == 1.0  # arrived flag of robot 0
    env.close()


TURN_LEFT_ON_THE_SPOT = 4  # 0 m/s, +90 deg/s
TURN_RIGHT_ON_THE_SPOT = 0  # 0 m/s, -90 deg/s


def test_all_arrived_is_success() -> None:
    env = placed_env([[-1.0, 0.0, 0.0]], [[-0.5, 0.0]])
    for _ in range(60):
        _, rewards, terminations, _, infos = env.step({"robot_0": STRAIGHT_FULL})
        if terminations["robot_0"]:
            break
    assert rewards["robot_0"] == 1.0 and infos["robot_0"]["team"]["success"]
    assert env.agents == []
    assert env.step({}) == ({}, {}, {}, {}, {})
    env.close()


def test_driving_into_a_parked_robot_ends_the_episode() -> None:
    env = placed_env([[-1.0, 0.0, 0.0], [-1.0, -0.6, 0.0]], [[-0.5, 0.0], [1.2, 0.0]])
    while "robot_0" in env.agents:
        env.step({agent: STRAIGHT_FULL if agent == "robot_0" else STAND_STILL for agent in env.agents})
    # Robot 1 turns to face the parked robot 0 (at about (-0.6, 0)) and drives into it.
    env.world.set_poses(np.array([[*env.world.xy[0], 0.0], [-0.6, -0.5, np.pi / 2]]))
    for _ in range(40):
        _, rewards, terminations, _, infos = env.step({"robot_1": STRAIGHT_FULL})
        if terminations["robot_1"]:
            break
    assert rewards["robot_1"] == -1.0 and infos["robot_1"]["collided"]
    assert infos["robot_1"]["team"]["collision"] and env.agents == []
    env.close()


def test_wall_collision_ends_the_episode_for_everyone() -> None:
    half = arena_side(2) / 2
    env = placed_env([[half - 0.2, 0.0, 0.0], [-0.5, 0.5, 0.0]], [[0.0, -1.0], [1.0, 1.0]])
    ticks, terminations = 0, {"robot_0": False}
    while not any(terminations.values()) and ticks < 30:
        ticks += 1
        _, rewards, terminations, truncations, infos = env.step({"robot_0": STRAIGHT_FULL, "robot_1": STRAIGHT_FULL})
    assert ticks == 10  # 0.095 m of gap at 0.0105 m per tick
    assert rewards["robot_0"] == -1.0 and infos["robot_0"]["collided"]
    # Robot 1 did not collide: it gets its dense reward, yet its episode ends too.
    assert -0.0105 - STEP_PENALTY <= rewards["robot_1"] <= 0.0105 - STEP_PENALTY
    assert not infos["robot_1"]["collided"]
    assert terminations == {"robot_0": True, "robot_1": True}
    assert not any(truncations.values())
    assert env.agents == [] and infos["robot_1"]["team"]["collision"]
    env.close()


def test_collision_reward_sets_the_penalty_of_a_crash_only() -> None:
    """The training option ``collision_reward`` changes the crash's reward, nothing else of the episode."""
    half = arena_side(2) / 2
    starts, targets = [[half - 0.2, 0.0, 0.0], [-0.5, 0.5, 0.0]], [[0.0, -1.0], [1.0, 1.0]]
    outcomes = []
    for collision_reward in (-1.0, -5.0):
        env = placed_env(starts, targets, collision_reward=collision_reward)
        trace, terminations = [], {"robot_0": False}
        while not any(terminations.values()):
            _, rewards, terminations, _, infos = env.step({"robot_0": STRAIGHT_FULL, "robot_1": STRAIGHT_FULL})
            trace.append((rewards["robot_0"], rewards["robot_1"]))
        outcomes.append((trace, infos["robot_0"]["collided"]))
        env.close()
    (paper, crashed_paper), (harsh, crashed_harsh) = outcomes
    assert crashed_paper and crashed_harsh and len(paper) == len(harsh) == 10
    assert paper[:-1] == harsh[:-1] and paper[-1][1] == harsh[-1][1]  # the same episode up to the crash
    assert paper[-1][0] == -1.0 and harsh[-1][0] == -5.0
    for bad in (-0.5, True, "x"):
        with pytest.raises(ValueError, match=r"collision_reward must be a number <= -1\.0"):
            MultiRobotNavEnv(n_robots=2, collision_reward=bad)  # type: ignore[arg-type]


def test_robot_robot_collision_penalises_both() -> None:
    env = placed_env([[-0.2, 0.0, 0.0], [0.2, 0.0, np.pi], [0.0, 1.0, 0.0]], [[1.0, -1.0], [-1.0, -1.0], [1.0, 1.0]])
    ticks, terminations = 0, {"robot_0": False}
    while not any(terminations.values()) and ticks < 30:
        ticks += 1
        _, rewards, terminations, _, _ = env.step({"robot_0": STRAIGHT_FULL, "robot_1": STRAIGHT_FULL, "robot_2": STAND_STILL})
    assert ticks == 10  # gap 0.4 - 0.21 = 0.19 m closing at 0.021 m per tick
    assert rewards["robot_0"] == rewards["robot_1"] == -1.0
    assert rewards["robot_2"] == pytest.approx(-STEP_PENALTY) and terminations["robot_2"]
    env.close()


def test_pybullet_contacts_match_exact_geometry() -> None:
    """The PyBullet contact query flags exactly the robots closer than their radius to a wall or bar."""
    env = MultiRobotNavEnv(n_robots=4, scenario="eps")
    env.reset(seed=0)
    boxes = env.layout.boxes
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(400):
        xy = rng.uniform(-2.0, 2.0, size=(4, 2))
        gap = clearance(xy, boxes) - ROBOT_RADIUS
        if np.any(np.abs(gap) < 2e-3):
            continue  # too close to the threshold to call
        env.world.set_poses(np.column_stack([xy, rng.uniform(-np.pi, np.pi, 4)]))
        np.testing.assert_array_equal(env.world.map_collisions(), gap < 0)
        checked += 1
    assert checked > 300
    env.close()


def test_no_phantom_collision_after_a_teleport() -> None:
    """A robot that sank into the north wall and is then placed straight south of that spot is clear."""
    half = arena_side(1) / 2
    env = placed_env([[0.3, half - 0.11, np.pi / 2]], [[0.0, -1.0]])
    _, rewards, _, _, _ = env.step({"robot_0": STRAIGHT_FULL})
    assert rewards["robot_0"] == -1.0
    env.reset(options={"start_poses": [[0.3, -1.0, np.pi / 2]], "targets": [[-1.0, 1.0]]})
    _, rewards, terminations, _, _ = env.step({"robot_0": STAND_STILL})
    assert not terminations["robot_0"] and rewards["robot_0"] == pytest.approx(-STEP_PENALTY)
    env.close()


@pytest.mark.parametrize(("gap", "collides"), [(0.002, False), (-0.002, True)])
def test_wall_contact_threshold(gap: float, collides: bool) -> None:
    half = arena_side(1) / 2
    env = placed_env([[half - ROBOT_RADIUS - gap, 0.0, 0.0]], [[0.0, 0.0]])
    _, rewards, terminations, _, _ = env.step({"robot_0": STAND_STILL})
    assert terminations["robot_0"] is collides
    assert (rewards["robot_0"] == -1.0) is collides
    env.close()


def test_time_limit_truncates_every_live_robot() -> None:
    env = MultiRobotNavEnv(n_robots=3, max_episode_steps=5)
    env.reset(seed=0)
    for _ in range(5):
        _, _, terminations, truncations, infos = env.step(dict.fromkeys(env.agents, STAND_STILL))
    assert all(truncations.values()) and not any(terminations.values())
    assert env.agents == [] and infos["robot_0"]["team"]["ticks"] == 5
    env.close()


def test_default_time_limit_follows_the_room() -> None:
    assert MultiRobotNavEnv(4).max_episode_steps == 600
    assert MultiRobotNavEnv(12).max_episode_steps == 900
    assert MultiRobotNavEnv(4, scenario="unseen").max_episode_steps == 900


def test_state_layout() -> None:
    env = placed_env([[-1.0, 0.5, 0.3], [0.7, -0.2, -1.0]], [[1.0, 1.0], [-1.0, -1.0]])
    env.step({"robot_0": 19, "robot_1": STAND_STILL})
    state = env.state().reshape(2, 9)
    np.testing.assert_allclose(state[:, :2], env.world.xy, atol=1e-6)
    np.testing.assert_allclose(state[:, 2], np.cos(env.world.theta), atol=1e-6)
    np.testing.assert_allclose(state[:, 3], np.sin(env.world.theta), atol=1e-6)
    np.testing.assert_allclose(state[0, 4:6], [0.21, np.pi / 2], atol=1e-6)
    np.testing.assert_allclose(state[1, 4:6], [0.0, 0.0])
    np.testing.assert_allclose(state[:, 6:8], [[1.0, 1.0], [-1.0, -1.0]])
    np.testing.assert_array_equal(state[:, 8], [0.0, 0.0])
    assert env.state_space.contains(env.state())
    env.close()


# --- targets and layouts -----------------------------------------------------------------------------


@pytest.mark.parametrize(("n_robots", "scenario"), [(12, "arena"), (4, "arena"), (1, "eps"), (4, "eps")])
def test_random_starts_and_targets_follow_the_rules(n_robots: int, scenario: str) -> None:
    env = MultiRobotNavEnv(n_robots=n_robots, scenario=scenario)
    boxes = env.layout.boxes
    env.reset(seed=123)
    upper = np.triu_indices(n_robots, k=1)
    for _ in range(1000 if n_robots == 12 else 300):
        starts, targets = env.world.xy, env._targets
        assert clearance(targets, boxes).min() >= TARGET_CLEARANCE
        assert clearance(starts, boxes).min() >= 0.3
        if n_robots > 1:
            assert np.linalg.norm(targets[:, None] - targets[None], axis=-1)[upper].min() >= TARGET_SPACING
            assert np.linalg.norm(starts[:, None] - starts[None], axis=-1)[upper].min() >= 0.5
        assert np.linalg.norm(targets[:, None] - starts[None], axis=-1).min() >= 0.5
        env.reset()
    env.close()


def test_unseen_world_cycles_its_fixed_target_sequence() -> None:
    env = MultiRobotNavEnv(n_robots=4, scenario="unseen")
    env.reset(seed=7)
    seen = [env._targets.copy()]
    for _ in range(len(UNSEEN_TARGET_SETS)):
        env.reset()
        seen.append(env._targets.copy())
        np.testing.assert_array_equal(env.world.xy, UNSEEN_STARTS[:, :2])
    for episode, targets in enumerate(seen):
        np.testing.assert_array_equal(targets, UNSEEN_TARGET_SETS[episode % len(UNSEEN_TARGET_SETS)])
    env.reset(seed=7)  # a seed restarts the sequence
    np.testing.assert_array_equal(env._targets, UNSEEN_TARGET_SETS[0])
    env.reset(options={"target_set": 3})
    np.testing.assert_array_equal(env._targets, UNSEEN_TARGET_SETS[3])
    env.close()


def reachable(layout_boxes: np.ndarray, half: float, start: np.ndarray, goal: np.ndarray) -> bool:
    """Breadth-first search on a 5 cm grid of the positions where the robot's body fits (radius + 2 cm)."""
    cell = 0.05
    coords = np.arange(-half + cell / 2, half, cell)
    grid_x, grid_y = np.meshgrid(coords, coords, indexing="ij")
    points = np.column_stack([grid_x.ravel(), grid_y.ravel()])
    free = (clearance(points, layout_boxes) >= ROBOT_RADIUS + 0.02).reshape(grid_x.shape)

    def to_cell(xy: np.ndarray) -> tuple[int, int]:
        i, j = np.floor((xy + half) / cell).astype(int)
        return int(i), int(j)

    begin, end = to_cell(start), to_cell(goal)
    assert free[begin] and free[end]
    queue, visited = deque([begin]), {begin}
    while queue:
        i, j = queue.popleft()
        if (i, j) == end:
            return True
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            nxt = (i + di, j + dj)
            if 0 <= nxt[0] < free.shape[0] and 0 <= nxt[1] < free.shape[1] and free[nxt] and nxt not in visited:
                visited.add(nxt)
                queue.append(nxt)
    return False


def test_unseen_targets_are_valid_and_reachable() -> None:
    layout = unseen_layout()
    boxes, half = layout.boxes, layout.width / 2
    starts = UNSEEN_STARTS[:, :2]
    assert clearance(starts, boxes).min() >= 0.3
    for targets in UNSEEN_TARGET_SETS:
        assert clearance(targets, boxes).min() >= TARGET_CLEARANCE
        assert np.all(np.abs(targets) < half)
        gaps = np.linalg.norm(targets[:, None] - targets[None], axis=-1)
        assert gaps[np.triu_indices(4, k=1)].min() >= TARGET_SPACING
        assert np.linalg.norm(targets[:, None] - starts[None], axis=-1).min() >= 0.5
        for robot in range(4):
            assert reachable(boxes, half, starts[robot], targets[robot])


def test_eps_world_bars_leave_the_room_connected() -> None:
    layout = eps_layout()
    corners = np.array([[-1.6, -1.6], [1.6, 1.6], [-1.6, 1.6], [1.6, -1.6], [0.0, 0.0], [1.5, 0.5]])
    for goal in corners[1:]:
        assert reachable(layout.boxes, layout.width / 2, corners[0], goal)
