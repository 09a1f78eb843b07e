"""Rooms generated from level seeds (``scenario="rooms"``, ``MultiRobotNavRooms-{4,8,12,24}-v0``) and the 24-robot
arena: the training / validation / test split and that no world can play another set's level, the generator's
determinism, free, apart and reachable starts and targets, the PettingZoo API, and records that name the level set."""

from __future__ import annotations

import hashlib
import pickle
import warnings

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import envs
from envs.turtlebot3 import MultiRobotNavEnv
from envs.turtlebot3 import multi_robot_nav as nav
from envs.turtlebot3.layouts import (
    BLOCK_GAP,
    ROOM_SCALE,
    START_CLEARANCE,
    START_SPACING,
    TARGET_CLEARANCE,
    TARGET_SPACING,
    TARGET_START_SPACING,
    arena_side,
    clearance,
    in_room,
)
from envs.turtlebot3.robot import DISTANCE_SCALE, ROBOT_RADIUS
from envs.turtlebot3.rooms import (
    CORRIDOR_WIDTH,
    DOORWAY_WIDTH,
    FEATURES,
    KEEP_OUT_MARGIN,
    LEVEL_COUNT,
    LEVEL_SETS,
    MAX_TARGET_DISTANCE,
    generate_room,
    level_set_of,
    levels_of,
    select_levels,
)
from sb3_eps import evaluate_team

ROOM_IDS = [f"MultiRobotNavRooms-{n}{suffix}-v0" for n in (4, 8, 12, 24) for suffix in ("", "-validation", "-test")]


class RandomPolicy:
    """Uniform random actions, whatever the robots see."""

    def __init__(self) -> None:
        self.rng = np.random.default_rng(0)

    def predict(self, observations: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self.rng.integers(0, 20, size=len(observations)), None


# --- the split -----------------------------------------------------------------------------------------------


def test_the_split_is_the_documented_hash_and_the_sets_are_disjoint() -> None:
    sets = {name: set(levels_of(name).tolist()) for name in LEVEL_SETS}
    assert set.union(*sets.values()) == set(range(LEVEL_COUNT))
    assert sum(len(levels) for levels in sets.values()) == LEVEL_COUNT  # disjoint
    for level in range(0, LEVEL_COUNT, 7):  # the rule of the docs, computed here on its own
        bucket = int.from_bytes(hashlib.sha256(f"sb3-eps rooms level {level}".encode()).digest()[:8], "big") % 10
        expected = "train" if bucket < 8 else "validation" if bucket == 8 else "test"
        assert level_set_of(level) == expected and level in sets[expected]
    assert 0.78 < len(sets["train"]) / LEVEL_COUNT < 0.82
    assert all(0.08 < len(sets[name]) / LEVEL_COUNT < 0.12 for name in ("validation", "test"))
    with pytest.raises(ValueError):
        levels_of("train")[0] = 1  # read-only


@pytest.mark.parametrize("level_set", LEVEL_SETS)
def test_a_world_draws_only_levels_of_its_own_set(level_set: str) -> None:
    env = MultiRobotNavEnv(4, scenario="rooms", level_set=level_set)
    played = set()
    for seed in range(3):  # whole resets: the level the episode plays and the one its info names
        _, infos = env.reset(seed=seed)
        for _ in range(30):
            assert infos["robot_0"]["team"]["level"] == env.level
            played.add(env.level)
            _, infos = env.reset()
    drawn = {env._draw_level({}) for _ in range(20_000)}  # the draw alone, many more times
    env.close()
    assert {level_set_of(level) for level in played | drawn} == {level_set}
    assert len(drawn) > 0.8 * len(levels_of(level_set))  # it draws across the whole set


@pytest.mark.parametrize("level_set", ["train", "validation"])
def test_the_single_robot_rooms_world_draws_only_its_own_set(level_set: str) -> None:
    """EPS's single-robot world among the rooms (``SingleRobotNav-v0``, ``scenario="rooms"``) keeps the split too."""
    env = envs.make_single_env("SingleRobotNav-v0", scenario="rooms", level_set=level_set)
    played = set()
    observation, _ = env.reset(seed=0)
    for _ in range(10):
        played.add(env.multi_env.level)
        observation, _ = env.reset()
    assert env.observation_space.contains(observation)
    drawn = {env.multi_env._draw_level({}) for _ in range(5_000)}
    env.close()
    assert {level_set_of(level) for level in played | drawn} == {level_set}


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"level_set": "train", "level": int(levels_of("test")[0])}, "is a test level; this world plays train levels"),
        ({"level_set": "validation", "level": int(levels_of("test")[0])}, "is a test level"),
        ({"level_set": "test", "level": int(levels_of("train")[0])}, "is a train level; this world plays test levels"),
        ({"level_set": "test", "levels": [int(levels_of("test")[0]), int(levels_of("validation")[0])]}, "validation"),
        ({"level_set": "holdout"}, "level_set must be one of"),
        ({"levels": 0}, "ask for 1 to"),
        ({"levels": [], "level_set": "test"}, "non-empty list"),
        ({"level": LEVEL_COUNT}, "a level is an int in"),
        ({"level": 0, "levels": 3}, "either levels or level"),
    ],
)
def test_a_level_outside_the_world_s_set_is_a_one_line_value_error(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message) as error:
        MultiRobotNavEnv(4, scenario="rooms", **kwargs)
    assert "\n" not in str(error.value)


def test_a_pinned_level_or_a_smaller_set_is_all_a_world_plays() -> None:
    first_three = levels_of("validation")[:3]
    np.testing.assert_array_equal(select_levels("validation", 3), first_three)
    env = MultiRobotNavEnv(4, scenario="rooms", level_set="validation", levels=3)
    for seed in range(20):
        env.reset(seed=seed)
        assert env.level in first_three
    env.reset(options={"level": int(first_three[1])})
    assert env.level == first_three[1]
    for level in (int(levels_of("test")[0]), int(levels_of("validation")[5])):  # another set, or not in `levels`
        with pytest.raises(ValueError, match="level"):
            env.reset(options={"level": level})
    env.close()
    pinned = MultiRobotNavEnv(4, scenario="rooms", level_set="test", level=int(levels_of("test")[7]))
    assert {pinned.reset(seed=seed) and pinned.level for seed in range(5)} == {levels_of("test")[7]}
    pinned.close()
    with pytest.raises(ValueError, match="scenario='rooms' only"):
        MultiRobotNavEnv(4, level_set="test")


# --- the generator -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_robots", [4, 24])
def test_a_level_seed_gives_the_same_room_starts_and_targets(n_robots: int) -> None:
    for level in (0, 1, 4_321, LEVEL_COUNT - 1):
        first, again = generate_room(level, n_robots), generate_room.__wrapped__(level, n_robots)  # cached, fresh
        assert first is not again and first.features == again.features
        for a, b in ((first.layout.boxes, again.layout.boxes), (first.starts, again.starts), (first.targets, again.targets)):
            np.testing.assert_array_equal(a, b)
    assert not np.array_equal(generate_room(0, n_robots).starts, generate_room(1, n_robots).starts)
    # In the world: two envs given the same level, and the same seed, play the same room and see the same.
    level = int(levels_of("train")[10])
    one, two = (MultiRobotNavEnv(n_robots, scenario="rooms", level=level) for _ in range(2))
    obs_one, _ = one.reset(seed=0)
    obs_two, _ = two.reset(seed=99)
    np.testing.assert_array_equal(np.stack(list(obs_one.values())), np.stack(list(obs_two.values())))
    np.testing.assert_array_equal(one.state(), two.state())
    one.close()
    two.close()


def test_a_seed_replays_its_levels_and_a_pickled_or_rebuilt_world_sees_the_same(monkeypatch) -> None:
    monkeypatch.setattr(nav, "MAP_SHAPES_MAX", 3)  # start afresh every few rooms, as a long run does every 100
    first, second = MultiRobotNavEnv(8, scenario="rooms"), MultiRobotNavEnv(8, scenario="rooms")
    for episode in range(8):
        obs_a, _ = first.reset(seed=21 if episode == 0 else None)
        obs_b, _ = second.reset(seed=21 if episode == 0 else None)
        assert first.level == second.level and first.world.n_map_shapes <= 3
        np.testing.assert_array_equal(np.stack(list(obs_a.values())), np.stack(list(obs_b.values())))
    fresh = MultiRobotNavEnv(8, scenario="rooms", level=first.level)
    fresh.reset()
    np.testing.assert_array_equal(fresh.world.scan(np.arange(8)), first.world.scan(np.arange(8)))
    fresh.world.gui = True  # the GUI's boxes of a new room, built in DIRECT mode (no display needed)
    fresh.world.set_map(generate_room(int(levels_of("train")[0]), 8).layout)
    assert len(fresh.world._map_visual_ids) == len(fresh.world.layout.boxes)
    fresh.world.gui = False
    for _ in range(10):
        first.step(dict.fromkeys(first.agents, 17))
    copy = pickle.loads(pickle.dumps(first))
    assert copy.level == first.level
    np.testing.assert_array_equal(copy.world.scan(np.arange(8)), first.world.scan(np.arange(8)))
    for env in (first, second, fresh, copy):
        env.close()


def _component(free: np.ndarray, seed_cell: tuple[int, int]) -> np.ndarray:
    """The 4-connected component of ``free`` that holds ``seed_cell`` (flood fill by dilation)."""
    reached = np.zeros_like(free)
    reached[seed_cell] = True
    while True:
        grown = reached.copy()
        grown[1:] |= reached[:-1]
        grown[:-1] |= reached[1:]
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown &= free
        if (grown == reached).all():
            return reached
        reached = grown


def _cells(layout, points: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    return tuple(np.floor((points + layout.half_extent) / cell).astype(int).T)


@pytest.mark.parametrize(("n_robots", "n_levels"), [(4, 150), (8, 60), (12, 40), (24, 15)])
def test_starts_and_targets_are_free_apart_and_reachable(n_robots: int, n_levels: int) -> None:
    cell = 0.05
    seen = set()
    side = arena_side(n_robots)
    for level in range(n_levels):
        room = generate_room(level, n_robots)
        layout, starts, targets = room.layout, room.starts[:, :2], room.targets
        seen.update(room.features)
        assert ROOM_SCALE[0] * side - 1e-9 <= min(layout.width, layout.height)
        assert max(layout.width, layout.height) <= ROOM_SCALE[1] * side + 1e-9
        for points, wall_clearance, spacing in (
            (starts, START_CLEARANCE, START_SPACING),
            (targets, TARGET_CLEARANCE, TARGET_SPACING),
        ):
            assert in_room(points, layout, wall_clearance - 1e-9).all()
            assert (clearance(points, layout.obstacles) >= wall_clearance - 1e-9).all()
            assert (clearance(points, room.keep_out) >= wall_clearance + KEEP_OUT_MARGIN - 1e-9).all()  # no doorway
            gaps = np.linalg.norm(points[:, None] - points[None], axis=-1) + np.eye(n_robots) * 1e9
            assert gaps.min() >= spacing - 1e-9
        assert np.linalg.norm(targets[:, None] - starts[None], axis=-1).min() >= TARGET_START_SPACING - 1e-9
        assert (np.linalg.norm(targets - starts, axis=1) <= MAX_TARGET_DISTANCE).all()
        # Every robot's body (radius + 2 cm) can drive from every start to every target: one free component.
        coords = [np.arange(-h + cell / 2, h, cell) for h in layout.half_extent]
        grid = np.stack(np.meshgrid(*coords, indexing="ij"), axis=-1).reshape(-1, 2)
        free = (clearance(grid, layout.boxes) >= ROBOT_RADIUS + 0.02).reshape(len(coords[0]), len(coords[1]))
        start_cells, target_cells = _cells(layout, starts, cell), _cells(layout, targets, cell)
        component = _component(free, (start_cells[0][0], start_cells[1][0]))
        assert component[start_cells].all() and component[target_cells].all(), f"level {level}: a robot is shut in"
    assert seen == set(FEATURES)


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    """Free gap between two boxes along the axis that separates them most (negative: they overlap)."""
    return float((np.abs(a[:2] - b[:2]) - a[2:] - b[2:]).max())


def test_obstacles_keep_their_gaps_and_doorways_and_corridors_stay_open() -> None:
    widths = []
    for level in range(150):
        room = generate_room(level, 8)
        half = room.layout.half_extent
        obstacles, keep_out = room.layout.obstacles, room.keep_out
        to_walls = half - np.abs(obstacles[:, :2]) - obstacles[:, 2:]  # free floor to the outer walls, per axis
        inner_wall = np.isclose(to_walls, 0.0, atol=1e-9).any(axis=1)  # inner walls join the outer walls
        assert (to_walls[~inner_wall] >= BLOCK_GAP - 1e-9).all()
        for i, box in enumerate(obstacles):  # every two obstacles: a passage between them
            assert all(_gap(box, other) >= BLOCK_GAP - 1e-9 for other in obstacles[:i])
        for opening in keep_out:  # a doorway or a corridor's inside: bounded by its walls, else nothing near it
            gaps = np.array([_gap(opening, box) for box in obstacles])
            assert ((np.abs(gaps) < 1e-9) | (gaps >= BLOCK_GAP - 1e-9)).all()
            thin = np.isclose(opening[2:].min(), 0.05)
            widths.append(2 * opening[2:].max() if thin else 2 * opening[2:].min())
    assert len(widths) > 50
    assert min(widths) >= min(DOORWAY_WIDTH[0], CORRIDOR_WIDTH[0]) - 1e-9


def test_every_start_is_clear_of_the_walls_in_the_world() -> None:
    env = MultiRobotNavEnv(12, scenario="rooms")
    for seed in range(25):
        env.reset(seed=seed)
        assert not env.world.map_collisions().any() and not env.world.robot_collisions().any()
        ranges = env.world.scan(np.arange(12))
        assert ranges.min() >= START_CLEARANCE - ROBOT_RADIUS - 0.01  # the lidar sees the obstacles, none closer
    env.close()


# --- the worlds ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("env_id", [*ROOM_IDS, "MultiRobotNav-24-v0", "MultiRobotNavMixed-4-v0"])
def test_the_new_ids_pass_the_parallel_api_test_with_the_arena_s_spaces(env_id: str) -> None:
    env = envs.make_parallel_env(env_id)
    arena = envs.make_parallel_env("MultiRobotNav-4-v0")
    assert env.observation_space("robot_0") == arena.observation_space("robot_0")
    assert env.action_space("robot_0") == arena.action_space("robot_0")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parallel_api_test(env, num_cycles=100)
    env.close()
    arena.close()


def test_the_mixed_world_plays_the_open_arena_or_a_training_level() -> None:
    """The navigator's training world: about ``arena_share`` of its episodes in the team's open arena (walls only,
    no level), the others in training levels; the same seed replays the same episodes."""
    arena_side_4 = nav.make_layout("arena", 4).width

    def played(seed: int) -> list[tuple[int | None, float]]:
        env = envs.make_parallel_env("MultiRobotNavMixed-4-v0")
        env.reset(seed=seed)
        episodes = []
        for _ in range(200):
            episodes.append((env.level, env.layout.width))
            env.reset()
        env.close()
        return episodes

    episodes = played(5)
    assert played(5) == episodes
    open_arena = [width for level, width in episodes if level is None]
    assert 0.4 < len(open_arena) / len(episodes) < 0.6
    assert set(open_arena) == {arena_side_4}
    assert {level_set_of(level) for level, _ in episodes if level is not None} == {"train"}
    with pytest.raises(ValueError, match="is a test level"):  # the id fixes the training levels
        envs.make_parallel_env("MultiRobotNavMixed-4-v0", level=int(levels_of("test")[0]))
    for kwargs, message in (({"arena_share": 1.0}, "probability in"), ({"scenario": "arena", "arena_share": 0.5}, "rooms")):
        with pytest.raises(ValueError, match=message):
            MultiRobotNavEnv(4, **kwargs)


def test_the_24_robot_arena_has_room_and_runs() -> None:
    env = envs.make_parallel_env("MultiRobotNav-24-v0")
    side = 3.0 + 0.25 * 24
    assert (env.layout.width, env.layout.height, env.max_episode_steps) == (side, side, 1350)
    assert side * side / 24 == pytest.approx(3.375)  # m^2 of floor per robot: 3.0 with 12 robots, 4.0 with 4
    rng = np.random.default_rng(0)
    for seed in range(30):
        env.reset(seed=seed)
        assert len(env.agents) == 24 and not env.world.robot_collisions().any()
        assert (np.linalg.norm(env._targets - env.world.xy, axis=1) <= DISTANCE_SCALE).all()
    ticks = 0
    while env.agents and ticks < 300:
        _, _, _, _, infos = env.step({a: int(rng.integers(20)) for a in env.agents})
        ticks += 1
    assert ticks > 0 and "level" not in next(iter(infos.values()))["team"]
    env.close()


def test_the_ids_default_to_training_levels_and_records_name_the_level_set() -> None:
    env = envs.make_parallel_env("MultiRobotNavRooms-8-v0")
    assert (env.level_set, env.n_robots, env.scenario) == ("train", 8, "rooms")
    env.close()
    test_env = envs.make_parallel_env("MultiRobotNavRooms-8-v0", level_set="test")
    assert test_env.level_set == "test"
    test_env.close()
    for level_set in ("validation", "test"):  # these ids fix their set
        env = envs.make_parallel_env(f"MultiRobotNavRooms-8-{level_set}-v0")
        assert env.level_set == level_set
        env.close()
        with pytest.raises(ValueError, match=f"fixes level_set='{level_set}'"):
            envs.make_parallel_env(f"MultiRobotNavRooms-8-{level_set}-v0", level_set="train")
    summary = evaluate_team(RandomPolicy(), "MultiRobotNavRooms-4-v0", 2, n_envs=1, env_kwargs={"level_set": "validation"})
    assert summary["level_set"] == "validation" and summary["env_id"] == "MultiRobotNavRooms-4-v0"
    assert all(level_set_of(episode["level"]) == "validation" for episode in summary["episodes"])
    assert evaluate_team(RandomPolicy(), "MultiRobotNavRooms-4-v0", 1, n_envs=1)["level_set"] == "train"
    summary = evaluate_team(RandomPolicy(), "MultiRobotNavRooms-4-test-v0", 2, n_envs=1)
    assert summary["level_set"] == "test" and summary["env_kwargs"] == {}
    assert all(level_set_of(episode["level"]) == "test" for episode in summary["episodes"])
