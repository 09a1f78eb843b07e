"""Rooms generated from level seeds, split into training, validation and test levels (``scenario="rooms"``).

A *level* is an int in ``[0, LEVEL_COUNT)``. With a team size it deterministically gives a room (:func:`generate_room`):
its outer walls, its inner walls, blocks, corridors and clutter, and every robot's start pose and target; the same
level and team size give the same room on every machine with this numpy (the level's own generator,
``numpy.random.default_rng([ROOMS_SEED, level, n_robots])``, draws all of it; the env's generator only picks the
level). A level with another team size is another room, sized for that team.

The levels are split once and for all by a hash of the level (:func:`level_set_of`): SHA-256 of
``"sb3-eps rooms level <level>"``, its first 8 bytes as a big-endian int, modulo 10: 0-7 is a training level, 8 a
validation level, 9 a test level (about 80 / 10 / 10 % of the levels, interleaved over the whole range, so no range
of level ids is one set). Train on training levels, make every choice on validation levels, and report on test
levels only. :func:`select_levels` is the only way a world gets its levels, and it refuses any level outside the
world's set.

How a room is drawn (every range below is a module constant):

- outer walls: each side :data:`~envs.turtlebot3.layouts.ROOM_SCALE` (1 to 1.3) times the side of the
  ``n_robots`` arena (3 m + 0.25 m per robot), in 10 cm steps, drawn alone, so rooms are squares or oblongs;
- features, each on with probability 1/2 (at least one): ``"walls"`` (1 or 2 inner walls across the room's longer
  side, 0.1 m thick, each with 1 or 2 doorways of :data:`DOORWAY_WIDTH`, every sub-room at least
  :data:`SUBROOM_MIN` deep), ``"corridors"`` (two parallel walls :data:`CORRIDOR_WIDTH` apart and
  :data:`CORRIDOR_LENGTH` long, or one such wall along an outer wall, open at both ends), ``"blocks"`` (rectangles
  of half extents 0.05-0.6 m, :data:`BLOCK_DENSITY` per m^2 of floor) and ``"clutter"`` (small boxes of half
  extents 0.05-0.15 m, :data:`CLUTTER_DENSITY` per m^2); each density is drawn per level from its range;
- every obstacle leaves :data:`~envs.turtlebot3.layouts.BLOCK_GAP` (0.5 m) of free floor to every other one, to
  the outer walls (inner walls excepted: they join them) and to every doorway and corridor, so the free space stays
  connected for the robot's body (0.21 m) and no doorway or corridor is blocked;
- starts and targets follow the arena's rules (:func:`~envs.turtlebot3.layouts.sample_starts`,
  :func:`~envs.turtlebot3.layouts.sample_targets`: 0.3 m from every wall and obstacle, starts 0.5 m apart, targets
  0.5 m apart and from every start), and keep :data:`KEEP_OUT_MARGIN` plus that clearance away from doorways and
  corridor insides (a robot parked there would close them); each target lies within 10 m (the observation's distance
  scale) of its own robot's start.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from envs.turtlebot3.layouts import (
    BLOCK_GAP,
    BLOCK_HALF_SIZES,
    BLOCK_HALF_STEP,
    ROOM_SCALE,
    WALL_THICKNESS,
    Layout,
    arena_side,
    drop_boxes,
    keeps_gap,
    rooms_bounds,
    sample_starts,
    sample_targets,
    walls_around,
)

LEVEL_COUNT = 10_000  # level ids are 0 to 9,999
LEVEL_SETS = ("train", "validation", "test")
SPLIT_BUCKETS = 10  # hash mod 10: 0-7 train, 8 validation, 9 test
TRAIN_BUCKETS = 8
ROOMS_SEED = 53  # the first word of every level's seed sequence (the issue that asked for the rooms)
FEATURES = ("walls", "corridors", "blocks", "clutter")
FEATURE_PROBABILITY = 0.5
SIDE_STEP = 0.1  # [m] the outer sides are whole multiples of this
INNER_WALL_HALF = WALL_THICKNESS / 2.0  # inner walls are as thick as the outer ones
SUBROOM_MIN = 1.5  # [m] an inner wall to an outer wall or to the other inner wall
DOORWAY_WIDTH = (0.7, 1.2)  # [m] a doorway's opening
DOORWAY_STEP = 0.1  # [m] doorway widths are multiples of this and their centres of 5 cm, as the other sizes
WALL_PIECE_MIN = 0.3  # [m] the shortest piece of inner wall beside a doorway
CORRIDOR_WIDTH = (0.7, 1.1)  # [m] free width between a corridor's walls
CORRIDOR_LENGTH = (1.5, 3.0)  # [m]
CORRIDOR_AREA = 30.0  # [m^2] of floor per corridor (1 in the small rooms, up to 5 with 24 robots)
BLOCK_DENSITY = (0.1, 0.3)  # blocks per m^2 of floor (the "blocks" scenario has 0.25)
CLUTTER_DENSITY = (0.2, 0.5)  # small boxes per m^2 of floor
CLUTTER_HALF_SIZES = (0.05, 0.15)  # [m]
KEEP_OUT_MARGIN = 0.3  # [m] doorways and corridor insides grow by this for the placement of starts and targets
PLACEMENT_TRIES = 20  # rooms drawn for one level until its robots fit (a level seed gives the same sequence)
MAX_TARGET_DISTANCE = 10.0  # [m] = robot.DISTANCE_SCALE: a target's distance reading never saturates


@dataclass(frozen=True)
class Room:
    """One generated level for one team size.

    :param level: the level id
    :param layout: the room (outer walls, obstacles) with its starts ``(n, 3)`` and its targets as the one target set
        ``(1, n, 2)``
    :param keep_out: boxes ``(k, 4)`` that are free floor but where no obstacle, start or target may come: the
        doorways' openings and the corridors' insides
    :param features: the features the level drew (a subset of :data:`FEATURES`)
    """

    level: int
    layout: Layout
    keep_out: np.ndarray
    features: tuple[str, ...]

    @property
    def starts(self) -> np.ndarray:
        """``(n, 3)`` start poses (x, y, heading)."""
        assert self.layout.starts is not None
        return self.layout.starts

    @property
    def targets(self) -> np.ndarray:
        """``(n, 2)`` targets."""
        assert self.layout.target_sets is not None
        return self.layout.target_sets[0]


# --- the split -------------------------------------------------------------------------------------------------


def check_level(level: Any) -> int:
    """``level`` as an int, or a ``ValueError`` saying what a level is."""
    if isinstance(level, bool) or not isinstance(level, int | np.integer) or not 0 <= level < LEVEL_COUNT:
        raise ValueError(f"a level is an int in [0, {LEVEL_COUNT}), got {level!r}.")
    return int(level)


def level_set_of(level: int) -> str:
    """The set a level belongs to: ``"train"``, ``"validation"`` or ``"test"`` (module docstring)."""
    digest = hashlib.sha256(f"sb3-eps rooms level {check_level(level)}".encode()).digest()
    bucket = int.from_bytes(digest[:8], "big") % SPLIT_BUCKETS
    return "train" if bucket < TRAIN_BUCKETS else LEVEL_SETS[1 + bucket - TRAIN_BUCKETS]


@functools.cache
def _split() -> dict[str, np.ndarray]:
    owner = [level_set_of(level) for level in range(LEVEL_COUNT)]
    split = {}
    for name in LEVEL_SETS:
        levels = np.array([level for level in range(LEVEL_COUNT) if owner[level] == name], dtype=np.int64)
        levels.setflags(write=False)
        split[name] = levels
    return split


def levels_of(level_set: str) -> np.ndarray:
    """Every level of a set, in increasing order (a read-only array).

    :param level_set: ``"train"``, ``"validation"`` or ``"test"``
    """
    if level_set not in LEVEL_SETS:
        raise ValueError(f"level_set must be one of {LEVEL_SETS}, got {level_set!r}.")
    return _split()[level_set]


def select_levels(level_set: str, levels: int | Sequence[int] | None = None, level: int | None = None) -> np.ndarray:
    """The levels a world of ``level_set`` may play, checked: every one of them belongs to that set.

    :param level_set: ``"train"``, ``"validation"`` or ``"test"``
    :param levels: None (the whole set), an int ``k`` (the set's ``k`` lowest levels: a smaller training set), or
        level ids, each of the set
    :param level: one level of the set, the only one played (not with ``levels``)
    :return: the levels, increasing, without repeats (read-only)
    :raises ValueError: a level outside the set, an unknown set, a bad count
    """
    pool = levels_of(level_set)
    if level is not None and levels is not None:
        raise ValueError("give either levels or level, not both.")
    if level is not None:
        levels = [level]
    if levels is None:
        return pool
    if isinstance(levels, int | np.integer) and not isinstance(levels, bool):
        if not 1 <= levels <= len(pool):
            raise ValueError(f"levels={levels}: the {level_set!r} set has {len(pool)} levels; ask for 1 to {len(pool)}.")
        return pool[: int(levels)]
    if isinstance(levels, str | bytes) or not isinstance(levels, Sequence | np.ndarray) or len(levels) == 0:
        raise ValueError(f"levels must be None, a count or a non-empty list of level ids, got {levels!r}.")
    chosen = np.unique([check_level(one) for one in levels])
    for one in chosen:
        if level_set_of(int(one)) != level_set:
            raise ValueError(f"level {one} is a {level_set_of(int(one))} level; this world plays {level_set} levels only.")
    chosen.setflags(write=False)
    return chosen


# --- the generator -------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=512)
def generate_room(level: int, n_robots: int) -> Room:
    """The room, starts and targets of a level for ``n_robots`` robots (module docstring); the same arguments give
    the same room. Its arrays are read-only.

    :param level: a level id in ``[0, LEVEL_COUNT)`` of any set
    :param n_robots: 1 to 24 robots
    :return: the room
    """
    level = check_level(level)
    rng = np.random.default_rng([ROOMS_SEED, level, int(n_robots)])
    for _ in range(PLACEMENT_TRIES):
        width, height = _outer_sides(rng, n_robots)
        features = _draw_features(rng)
        obstacles, keep_out = _obstacles(rng, width, height, features)
        # Starts and targets keep their clearance to the doorways and corridor insides too, grown by a margin.
        grown = keep_out + np.array([0.0, 0.0, KEEP_OUT_MARGIN, KEEP_OUT_MARGIN])
        placing = Layout("rooms", width, height, walls_around(width, height), np.concatenate([obstacles, grown]))
        try:
            starts = sample_starts(rng, placing, n_robots)
            targets = sample_targets(rng, placing, starts[:, :2], MAX_TARGET_DISTANCE)
        except RuntimeError:  # too crowded for this team: draw the level's next room
            continue
        layout = Layout(
            "rooms",
            width,
            height,
            walls_around(width, height),
            obstacles,
            starts,
            targets[None],
            rooms_bounds(n_robots).time_limit,
        )
        for array in (layout.walls, layout.obstacles, starts, layout.target_sets, keep_out):
            array.setflags(write=False)
        return Room(level, layout, keep_out, features)
    raise RuntimeError(f"level {level}: no room of {PLACEMENT_TRIES} drawn holds {n_robots} robots.")


def _outer_sides(rng: np.random.Generator, n_robots: int) -> tuple[float, float]:
    side = arena_side(n_robots)
    low, high = (round(scale * side / SIDE_STEP) for scale in ROOM_SCALE)
    width, height = rng.integers(low, high + 1, size=2) * SIDE_STEP
    return round(float(width), 6), round(float(height), 6)


def _draw_features(rng: np.random.Generator) -> tuple[str, ...]:
    on = rng.random(len(FEATURES)) < FEATURE_PROBABILITY
    if not on.any():
        on[rng.integers(len(FEATURES))] = True
    return tuple(name for name, flag in zip(FEATURES, on) if flag)


def _rounded(rng: np.random.Generator, bounds: tuple[float, float], step: float = BLOCK_HALF_STEP) -> float:
    """A value uniform over the multiples of ``step`` in ``bounds``."""
    low, high = (round(bound / step) for bound in bounds)
    return float(rng.integers(low, high + 1) * step)


def _obstacles(
    rng: np.random.Generator, width: float, height: float, features: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The obstacles ``(m, 4)`` of a room and its keep-out boxes ``(k, 4)`` (doorways, corridor insides)."""
    half = np.array([width, height]) / 2.0
    area = width * height
    solid: list[np.ndarray] = []
    keep_out: list[np.ndarray] = []
    if "walls" in features:
        _inner_walls(rng, half, solid, keep_out)
    if "corridors" in features:
        for _ in range(max(1, round(area / CORRIDOR_AREA))):
            _corridor(rng, half, solid, keep_out)
    for name, density, sizes in (
        ("blocks", BLOCK_DENSITY, BLOCK_HALF_SIZES),
        ("clutter", CLUTTER_DENSITY, CLUTTER_HALF_SIZES),
    ):
        if name in features:
            count = round(area * rng.uniform(*density))
            others = np.array(solid + keep_out).reshape(-1, 4)
            solid.extend(drop_boxes(rng, half, count, sizes, others))
    return np.array(solid).reshape(-1, 4), np.array(keep_out).reshape(-1, 4)


def _inner_walls(rng: np.random.Generator, half: np.ndarray, solid: list[np.ndarray], keep_out: list[np.ndarray]) -> None:
    """One or two walls across the room's longer side (from outer wall to outer wall), each with one or two doorways.
    Boxes are ``(cx, cy, hx, hy)``; ``along`` is the axis the walls cross (the longer one), ``across`` the other."""
    along = 0 if half[0] >= half[1] else 1
    across = 1 - along
    length = 2.0 * half[along]
    n_walls = 2 if length >= 3 * SUBROOM_MIN and rng.random() < 0.5 else 1
    for _ in range(50):
        positions = np.sort(rng.uniform(-half[along] + SUBROOM_MIN, half[along] - SUBROOM_MIN, size=n_walls))
        if n_walls == 1 or positions[1] - positions[0] >= SUBROOM_MIN:
            break
    else:
        positions = positions[:1]
    span = 2.0 * half[across]
    for position in np.round(positions / BLOCK_HALF_STEP) * BLOCK_HALF_STEP:
        n_doors = 2 if span >= 3.0 and rng.random() < 0.5 else 1
        openings = _doorways(rng, half[across], n_doors)
        edges = [-half[across], *openings.ravel(), half[across]]
        for start, end in zip(edges[0::2], edges[1::2]):  # the wall's pieces between the doorways
            solid.append(_box(along, position, (start + end) / 2.0, INNER_WALL_HALF, (end - start) / 2.0))
        for start, end in openings:
            keep_out.append(_box(along, position, (start + end) / 2.0, INNER_WALL_HALF, (end - start) / 2.0))


def _doorways(rng: np.random.Generator, half_span: float, n_doors: int) -> np.ndarray:
    """``(n_doors, 2)`` openings (from, to) along a wall of ``[-half_span, half_span]``, in order, with wall pieces of
    at least :data:`WALL_PIECE_MIN` beside each (one door when two do not fit after a few draws)."""
    for attempt in range(50):
        doors = n_doors if attempt < 25 else 1
        widths = np.array([_rounded(rng, DOORWAY_WIDTH, DOORWAY_STEP) for _ in range(doors)])
        centres = np.sort(np.round(rng.uniform(-half_span, half_span, size=doors) / BLOCK_HALF_STEP) * BLOCK_HALF_STEP)
        openings = np.column_stack([centres - widths / 2.0, centres + widths / 2.0])
        edges = np.concatenate([[-half_span], openings.ravel(), [half_span]])
        if (np.diff(edges)[0::2] >= WALL_PIECE_MIN).all():
            return openings
    return np.array([[-DOORWAY_WIDTH[1] / 2.0, DOORWAY_WIDTH[1] / 2.0]])  # a wide doorway in the middle


def _corridor(rng: np.random.Generator, half: np.ndarray, solid: list[np.ndarray], keep_out: list[np.ndarray]) -> None:
    """A corridor open at both ends: two parallel walls, or one wall along an outer wall; its walls and its inside keep
    :data:`BLOCK_GAP` to everything placed before (its walls to the outer walls too). Left out after 30 draws."""
    for _ in range(30):
        along = int(rng.integers(2))  # the corridor runs along x (0) or y (1)
        across = 1 - along
        width = _rounded(rng, CORRIDOR_WIDTH)
        length = min(_rounded(rng, CORRIDOR_LENGTH), 2.0 * (half[along] - BLOCK_GAP))
        others = np.array(solid + keep_out).reshape(-1, 4)
        if rng.random() < 0.5:  # along an outer wall: the wall at `width` from it, the inside between the two
            side = 1.0 if rng.random() < 0.5 else -1.0
            wall_at = side * (half[across] - width - INNER_WALL_HALF)
            centre = rng.uniform(-half[along] + BLOCK_GAP + length / 2.0, half[along] - BLOCK_GAP - length / 2.0)
            walls = [_box(along, centre, wall_at, length / 2.0, INNER_WALL_HALF)]
            inside = _box(along, centre, side * (half[across] - width / 2.0), length / 2.0, width / 2.0)
        else:
            reach = half[across] - BLOCK_GAP - width / 2.0 - 2.0 * INNER_WALL_HALF
            if reach <= 0:
                continue
            centre = rng.uniform(-half[along] + BLOCK_GAP + length / 2.0, half[along] - BLOCK_GAP - length / 2.0)
            middle = rng.uniform(-reach, reach)
            offset = width / 2.0 + INNER_WALL_HALF
            walls = [_box(along, centre, middle + sign * offset, length / 2.0, INNER_WALL_HALF) for sign in (-1, 1)]
            inside = _box(along, centre, middle, length / 2.0, width / 2.0)
        if all(keeps_gap(box, others, BLOCK_GAP) for box in [*walls, inside]):
            solid.extend(walls)
            keep_out.append(inside)
            return


def _box(along: int, at_along: float, at_across: float, half_along: float, half_across: float) -> np.ndarray:
    """A box ``(cx, cy, hx, hy)`` given by its centre and half extents along the axis ``along`` and across it."""
    box = np.empty(4)
    box[along], box[1 - along] = at_along, at_across
    box[2 + along], box[3 - along] = half_along, half_across
    return box
