"""Scenario layouts (walls, obstacles, fixed poses) and the random placement of start poses and targets.

Every static body is an axis-aligned box ``(cx, cy, hx, hy)`` (centre and half extents in metres), so the
clearance of a point to the map is exact and cheap (:func:`clearance`); PyBullet gets the same boxes as one
triangle mesh (see ``world.py``). The room interior is ``[-width/2, width/2] x [-height/2, height/2]``.

Scenarios (see ``docs/envs.md`` for the pictures):

- ``"arena"``: the multi-robot training arena, walls only, a square of side :func:`arena_side` (n).
- ``"eps"``: the single-robot EPS world (paper Fig. 3 left): the 4-robot arena's walls plus static bars.
- ``"eps_pillars"``: an EPS world closer to the 4-robot training arena: its walls plus three robot-sized static
  pillars standing for the other three robots (no thin bars, which the training worlds never show).
- ``"blocks"``: the multi-robot arena with rectangular blocks drawn anew at every reset (:func:`sample_blocks`): a
  training option for rooms never seen in training (the unseen room's blocks and corridors), not the paper's world.
- ``"rooms"``: rooms generated from level seeds (:mod:`envs.turtlebot3.rooms`), a new room at every reset drawn from
  a training, validation or test set of levels; here only the empty bounds of the largest room a team size gets.
- ``"unseen"``: the 4-robot evaluation room (paper Fig. 5 analogue): a 6 m room whose four inner blocks
  leave a central cross and a ring corridor; fixed start poses and a fixed sequence of target sets. With a
  placement jitter (:func:`jitter_starts`, :func:`jitter_targets`) every episode moves those poses by a seeded
  offset, so no two episodes pose the same problem.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

WALL_THICKNESS = 0.1  # [m] outer walls stand outside the interior
WALL_HEIGHT = 0.3  # [m] taller than the Burger (0.192 m) so every beam that reaches a wall hits it
START_CLEARANCE = 0.3  # [m] start centre to any wall/obstacle surface (robot radius + ~0.2 m)
START_SPACING = 0.5  # [m] between start centres (0.29 m of free gap between two bodies)
TARGET_CLEARANCE = 0.3  # [m] target to any wall/obstacle surface: a robot parked there stays clear
TARGET_SPACING = 0.5  # [m] between targets (paper Sec. IV-B)
TARGET_START_SPACING = 0.5  # [m] target to every robot's start: "not on the initial positions"
TICKS_PER_METRE = 150  # default time limit per metre of the room's longer side (see default_time_limit)
ROOM_DETOUR = 1.5  # generated rooms: the time limit's allowance for the detours of inner walls and corridors
PLACEMENT_JITTER_MAX = 0.5  # [m] largest offset of a fixed start or target (keeps each problem recognisable)
HEADING_JITTER = np.pi / 6  # [rad] largest turn of a fixed start heading when the placement is jittered
MIN_START_TARGET = 2.0  # [m] a jittered target to its own robot's start (the fixed sets' shortest is 2.6 m)
SCENARIOS = ("arena", "blocks", "eps", "eps_pillars", "rooms", "unseen")
MAX_ROBOTS = {"arena": 24, "blocks": 12, "eps": 4, "eps_pillars": 4, "rooms": 24, "unseen": 4}
BLOCK_HALF_STEP = 0.05  # [m] a block's half extents are whole multiples of this (a bounded set of shapes to build)
BLOCK_HALF_SIZES = (0.05, 0.6)  # [m] range of a block's half extents, each axis drawn alone: bars to 1.2 m blocks
BLOCK_GAP = 0.5  # [m] least free gap between two blocks and between a block and a wall (robot diameter 0.21 m)
BLOCK_AREA = 4.0  # [m^2] of room per block: 4 blocks in the 4-robot arena, 6 with 8 robots, 9 with 12
ROOM_SCALE = (1.0, 1.3)  # a generated room's sides, each drawn alone, as multiples of the arena's side for its team


@dataclass(frozen=True)
class Layout:
    """A room: its walls and obstacles, and optionally fixed start poses and target sets.

    :param name: scenario name
    :param width: interior size along x [m]
    :param height: interior size along y [m]
    :param walls: boxes ``(k, 4)`` of the outer walls
    :param obstacles: boxes ``(m, 4)`` inside the room (inner walls, bars)
    :param starts: fixed start poses ``(n, 3)`` as (x, y, heading), or None for random starts
    :param target_sets: fixed targets ``(s, n, 2)``, one set per episode in sequence, or None for random
    :param time_limit: the default ``max_episode_steps``, or None for :attr:`default_time_limit`'s rule
    """

    name: str
    width: float
    height: float
    walls: np.ndarray
    obstacles: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    starts: np.ndarray | None = None
    target_sets: np.ndarray | None = None
    time_limit: int | None = None

    @property
    def boxes(self) -> np.ndarray:
        """All static boxes (walls then obstacles), shape ``(k, 4)``."""
        return np.concatenate([self.walls, self.obstacles], axis=0)

    @property
    def half_extent(self) -> np.ndarray:
        """Half the interior size ``(width / 2, height / 2)``."""
        return np.array([self.width / 2.0, self.height / 2.0])

    @property
    def default_time_limit(self) -> int:
        """Default ``max_episode_steps``: 150 ticks per metre of the longer side.

        At 0.21 m/s a tick covers 0.0105 m, so 150 ticks drive 1.58 m per metre of side: more than the
        room's diagonal (1.41 m per metre of side) plus the turns. A layout may set its own (``time_limit``).
        """
        if self.time_limit is not None:
            return self.time_limit
        return round(TICKS_PER_METRE * max(self.width, self.height))


def arena_side(n_robots: int) -> float:
    """Side of the square multi-robot arena: 3 m plus 0.25 m per robot.

    2 robots: 3.5 m, 4: 4 m, 8: 5 m, 12: 6 m. The free area per robot shrinks from 6.1 to 3 m^2 as n grows,
    so crowding, as in the paper, makes larger teams harder.

    :param n_robots: number of robots
    :return: side length [m]
    """
    return 3.0 + 0.25 * n_robots


def walls_around(width: float, height: float) -> np.ndarray:
    """Four wall boxes enclosing the interior ``[-width/2, width/2] x [-height/2, height/2]``.

    :param width: interior size along x [m]
    :param height: interior size along y [m]
    :return: boxes ``(4, 4)``
    """
    half_t = WALL_THICKNESS / 2.0
    hx, hy = width / 2.0, height / 2.0
    return np.array(
        [
            [0.0, hy + half_t, hx + WALL_THICKNESS, half_t],
            [0.0, -hy - half_t, hx + WALL_THICKNESS, half_t],
            [hx + half_t, 0.0, half_t, hy],
            [-hx - half_t, 0.0, half_t, hy],
        ]
    )


def arena_layout(n_robots: int) -> Layout:
    """The multi-robot training arena: walls only, square of side :func:`arena_side`.

    :param n_robots: number of robots
    :return: the layout
    """
    side = arena_side(n_robots)
    return Layout("arena", side, side, walls_around(side, side))


# The EPS world: the 4-robot arena (4 m) with three bars, 0.1 m thick, leaving passages of 0.7 m or more.
EPS_SIDE = 4.0
EPS_BARS = np.array(
    [
        [-0.9, 0.8, 0.6, 0.05],  # horizontal bar, upper left
        [0.9, 0.5, 0.05, 0.7],  # vertical bar, right
        [-0.1, -0.9, 0.7, 0.05],  # horizontal bar, lower middle
    ]
)


def eps_layout() -> Layout:
    """The single-robot EPS world (paper Fig. 3 left): the 4 m arena's walls plus static bars.

    :return: the layout
    """
    return Layout("eps", EPS_SIDE, EPS_SIDE, walls_around(EPS_SIDE, EPS_SIDE), EPS_BARS.copy())


# Robot-sized pillars (a 0.2 m square has about the area of the Burger's 0.105 m-radius disc, and at 28 beams over
# 240 degrees the lidar tells the two shapes apart only within a few centimetres), one per other robot of the
# 4-robot arena, spread so no passage is narrower than 0.9 m.
PILLAR_HALF_SIZE = 0.1
EPS_PILLARS = np.array([[x, y, PILLAR_HALF_SIZE, PILLAR_HALF_SIZE] for x, y in ((-0.8, 0.8), (0.9, 0.2), (-0.2, -0.9))])


def eps_pillars_layout() -> Layout:
    """An EPS world closer to the training arena: the 4 m arena's walls plus three robot-sized pillars.

    :return: the layout
    """
    return Layout("eps_pillars", EPS_SIDE, EPS_SIDE, walls_around(EPS_SIDE, EPS_SIDE), EPS_PILLARS.copy())


# The unseen room: 6 m x 6 m; four 1.4 m square blocks centred at (+-1.5, +-1.5) leave a central cross
# corridor 1.6 m wide and a ring corridor 0.8 m wide along the outer walls.
UNSEEN_SIDE = 6.0
UNSEEN_BLOCKS = np.array([[sx * 1.5, sy * 1.5, 0.7, 0.7] for sx in (1, -1) for sy in (1, -1)])
# Robot i starts at the end of one arm of the cross, facing the centre: north, east, south, west.
UNSEEN_STARTS = np.array(
    [
        [0.0, 2.5, -np.pi / 2],
        [2.5, 0.0, np.pi],
        [0.0, -2.5, np.pi / 2],
        [-2.5, 0.0, 0.0],
    ]
)
# The fixed target sequence, one row per episode (robot 0..3); episodes cycle through it.
UNSEEN_TARGET_SETS = np.array(
    [
        # 0 "swap": each robot to the far arm; all four cross the centre at once
        [[0.0, -1.8], [-1.8, 0.0], [0.0, 1.8], [1.8, 0.0]],
        # 1 "corners": each robot to the ring corner on its left
        [[2.6, 2.6], [2.6, -2.6], [-2.6, -2.6], [-2.6, 2.6]],
        # 2 "next arm": each robot to the arm on its right, through the centre
        [[-1.8, 0.0], [0.0, 1.8], [1.8, 0.0], [0.0, -1.8]],
        # 3 "ring": each robot into the ring corridor, beside a block, two arms away
        [[2.6, -1.5], [-1.5, -2.6], [-2.6, 1.5], [1.5, 2.6]],
        # 4 "side pockets": each robot to the side of a neighbouring arm, near the blocks
        [[1.5, -0.4], [-0.4, -1.5], [-1.5, 0.4], [0.4, 1.5]],
    ]
)


def unseen_layout() -> Layout:
    """The unseen 4-robot evaluation room with fixed starts and target sequence.

    :return: the layout
    """
    return Layout(
        "unseen",
        UNSEEN_SIDE,
        UNSEEN_SIDE,
        walls_around(UNSEEN_SIDE, UNSEEN_SIDE),
        UNSEEN_BLOCKS.copy(),
        UNSEEN_STARTS.copy(),
        UNSEEN_TARGET_SETS.copy(),
    )


def sample_blocks(rng: np.random.Generator, side: float, n_blocks: int | None = None) -> np.ndarray:
    """Random axis-aligned blocks in a square room of side ``side``: half extents uniform over the multiples of
    :data:`BLOCK_HALF_STEP` in :data:`BLOCK_HALF_SIZES` (each axis alone, so thin bars and squat blocks both occur),
    centres uniform, every block at least
    :data:`BLOCK_GAP` from the walls and from the others, so every passage admits a robot. Blocks that do not fit
    after a few draws are left out, so a crowded room may hold fewer than ``n_blocks``.

    :param rng: the env's generator
    :param side: interior side of the room [m]
    :param n_blocks: how many to place (default: one per :data:`BLOCK_AREA` of floor)
    :return: boxes ``(k, 4)``, ``k <= n_blocks``
    """
    if n_blocks is None:
        n_blocks = round(side * side / BLOCK_AREA)
    return drop_boxes(rng, np.array([side, side]) / 2.0, n_blocks, BLOCK_HALF_SIZES)


def drop_boxes(
    rng: np.random.Generator,
    half_extent: np.ndarray,
    n_boxes: int,
    half_sizes: tuple[float, float],
    others: np.ndarray | None = None,
    gap: float = BLOCK_GAP,
) -> np.ndarray:
    """Random axis-aligned boxes in the room ``[-half_extent, half_extent]``: each half extent a multiple of
    :data:`BLOCK_HALF_STEP` in ``half_sizes``, drawn per axis, the centre uniform, at least ``gap`` from the walls,
    from the boxes already placed and from ``others``; a box that does not fit after ``20 * n_boxes`` draws in all is
    left out (:func:`sample_blocks` and the generated rooms of :mod:`envs.turtlebot3.rooms`).

    :param rng: the generator
    :param half_extent: ``(2,)`` half the room's interior size [m]
    :param n_boxes: how many to place at most
    :param half_sizes: range of a half extent [m]
    :param others: boxes ``(m, 4)`` already in the room (not the outer walls) that the new ones keep ``gap`` from
    :param gap: least free gap [m]
    :return: boxes ``(k, 4)``, ``k <= n_boxes``
    """
    low, high = (round(size / BLOCK_HALF_STEP) for size in half_sizes)
    n_others = 0 if others is None else len(others)
    placed = np.empty((n_others + n_boxes, 4))
    placed[:n_others] = np.zeros((0, 4)) if others is None else others
    count = n_others
    for _ in range(20 * n_boxes):
        if count - n_others == n_boxes:
            break
        extent = rng.integers(low, high + 1, size=2) * BLOCK_HALF_STEP
        bound = half_extent - gap - extent
        if np.any(bound <= 0):
            continue
        centre = rng.uniform(-bound, bound)
        box = np.concatenate([centre, extent])
        if keeps_gap(box, placed[:count], gap):
            placed[count] = box
            count += 1
    return placed[n_others:count].copy()


def keeps_gap(box: np.ndarray, others: np.ndarray, gap: float) -> bool:
    """Whether the axis-aligned ``box`` leaves at least ``gap`` of free space to each of the boxes ``others``
    ``(m, 4)`` (along x or y)."""
    apart = np.abs(box[:2] - others[:, :2]) >= box[2:] + others[:, 2:] + gap
    return bool(apart.any(axis=1).all())


def blocks_layout(n_robots: int, rng: np.random.Generator | None = None) -> Layout:
    """The multi-robot arena (side :func:`arena_side`) with blocks from :func:`sample_blocks`; none without ``rng``
    (the env draws them at every reset).

    :param n_robots: number of robots
    :param rng: the env's generator, or None for the empty arena
    :return: the layout
    """
    side = arena_side(n_robots)
    obstacles = sample_blocks(rng, side) if rng is not None else np.zeros((0, 4))
    return Layout("blocks", side, side, walls_around(side, side), obstacles)


def make_layout(scenario: str, n_robots: int) -> Layout:
    """Build the layout of a scenario, checking ``n_robots`` against what it can place.

    :param scenario: one of :data:`SCENARIOS`
    :param n_robots: number of robots
    :return: the layout (``"blocks"``: the arena before its first reset draws the blocks)
    """
    if scenario not in SCENARIOS:
        raise ValueError(f"Unknown scenario {scenario!r}: choose one of {SCENARIOS}.")
    if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)):
        raise ValueError(f"n_robots must be an int, got {n_robots!r} ({type(n_robots).__name__}).")
    max_robots = MAX_ROBOTS[scenario]
    if not 1 <= n_robots <= max_robots:
        raise ValueError(f"n_robots={n_robots} is out of range for scenario {scenario!r}: allowed 1 to {max_robots}.")
    if scenario == "arena":
        return arena_layout(int(n_robots))
    if scenario == "blocks":
        return blocks_layout(int(n_robots))
    if scenario == "eps":
        return eps_layout()
    if scenario == "eps_pillars":
        return eps_pillars_layout()
    if scenario == "rooms":
        return rooms_bounds(int(n_robots))
    return unseen_layout()


def rooms_bounds(n_robots: int) -> Layout:
    """The largest room :mod:`envs.turtlebot3.rooms` generates for ``n_robots``, empty: every side
    :data:`ROOM_SCALE` ``[1]`` times the arena's; its time limit (150 ticks per metre of that side, times 1.5 for the
    detours through doorways and around corridors) is the rooms' default ``max_episode_steps``.

    :param n_robots: number of robots
    :return: the layout (no obstacles, no fixed poses)
    """
    side = round(ROOM_SCALE[1] * arena_side(n_robots), 1)
    limit = round(ROOM_DETOUR * TICKS_PER_METRE * side)
    return Layout("rooms", side, side, walls_around(side, side), time_limit=limit)


def clearance(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Exact distance from points to the nearest box surface (0 for a point inside a box).

    :param points: ``(m, 2)`` positions [m]
    :param boxes: ``(k, 4)`` boxes ``(cx, cy, hx, hy)``
    :return: ``(m,)`` distances [m]
    """
    if len(boxes) == 0:
        return np.full(len(points), np.inf)
    offset = np.abs(points[:, None, :] - boxes[None, :, :2]) - boxes[None, :, 2:]
    outside = np.linalg.norm(np.maximum(offset, 0.0), axis=-1)
    return outside.min(axis=1)


def in_room(points: np.ndarray, layout: Layout, margin: float) -> np.ndarray:
    """Whether points lie in the interior at least ``margin`` from the outer boundary.

    :param points: ``(m, 2)`` positions [m]
    :param layout: the room
    :param margin: distance to keep from the boundary [m]
    :return: ``(m,)`` booleans
    """
    return np.all(np.abs(points) <= layout.half_extent - margin, axis=1)


def _pick_spaced(
    rng: np.random.Generator,
    layout: Layout,
    n_points: int,
    wall_clearance: float,
    spacing: float,
    avoid: np.ndarray,
    avoid_spacing: float,
) -> np.ndarray:
    """Draw ``n_points`` uniform positions with wall clearance, pairwise spacing and distance to ``avoid``.

    Rejection sampling in vectorised batches; the accepted points are kept greedily in draw order, so the
    result depends only on the generator's state.
    """
    bound = layout.half_extent - wall_clearance
    chosen: list[np.ndarray] = []
    for _ in range(200):
        candidates = rng.uniform(-bound, bound, size=(max(4 * n_points, 16), 2))
        ok = clearance(candidates, layout.obstacles) >= wall_clearance
        if len(avoid):
            gaps = np.linalg.norm(candidates[:, None, :] - avoid[None, :, :], axis=-1)
            ok &= gaps.min(axis=1) >= avoid_spacing
        for point in candidates[ok]:
            if all(np.hypot(*(point - other)) >= spacing for other in chosen):
                chosen.append(point)
                if len(chosen) == n_points:
                    return np.array(chosen)
    raise RuntimeError(
        f"Could not place {n_points} points in the {layout.name!r} layout after 200 batches; "
        "use fewer robots or a larger room."
    )


def sample_starts(rng: np.random.Generator, layout: Layout, n_robots: int) -> np.ndarray:
    """Random start poses: clear of walls/obstacles, robots apart, uniform headings.

    :param rng: the env's generator
    :param layout: the room
    :param n_robots: number of robots
    :return: ``(n, 3)`` poses (x, y, heading)
    """
    xy = _pick_spaced(rng, layout, n_robots, START_CLEARANCE, START_SPACING, np.zeros((0, 2)), 0.0)
    heading = rng.uniform(-np.pi, np.pi, size=n_robots)
    return np.concatenate([xy, heading[:, None]], axis=1)


def sample_targets(
    rng: np.random.Generator, layout: Layout, starts_xy: np.ndarray, max_distance: float | None = None
) -> np.ndarray:
    """Random targets: obstacle-free with clearance, apart from each other and from every start.

    :param rng: the env's generator
    :param layout: the room
    :param starts_xy: ``(n, 2)`` start positions of all robots
    :param max_distance: if given, the whole set is drawn again until every target lies within it of its own robot's
        start (the observation's distance scale); a room whose diagonal is shorter never draws again, so its targets
        are those drawn without it
    :return: ``(n, 2)`` targets
    """
    for _ in range(100):
        targets = _pick_spaced(rng, layout, len(starts_xy), TARGET_CLEARANCE, TARGET_SPACING, starts_xy, TARGET_START_SPACING)
        if max_distance is None or (np.hypot(*(targets - starts_xy).T) <= max_distance).all():
            return targets
    raise RuntimeError(
        f"Could not place targets within {max_distance} m of their robots' starts in the {layout.name!r} layout."
    )


def jitter_starts(rng: np.random.Generator, layout: Layout, starts: np.ndarray, radius: float) -> np.ndarray:
    """Fixed start poses moved by seeded offsets: each position within ``radius`` of its own (uniform over the
    disc), clear of walls and obstacles and apart from the others as random starts are; each heading turned by up
    to :data:`HEADING_JITTER`.

    :param rng: the env's generator
    :param layout: the room
    :param starts: ``(n, 3)`` the fixed poses (x, y, heading)
    :param radius: largest offset [m]
    :return: ``(n, 3)`` poses
    """
    xy = _pick_near(rng, layout, starts[:, :2], radius, START_CLEARANCE, START_SPACING)
    turn = rng.uniform(-HEADING_JITTER, HEADING_JITTER, size=len(starts))
    heading = np.mod(starts[:, 2] + turn + np.pi, 2.0 * np.pi) - np.pi
    return np.concatenate([xy, heading[:, None]], axis=1)


def jitter_targets(
    rng: np.random.Generator, layout: Layout, targets: np.ndarray, starts_xy: np.ndarray, radius: float
) -> np.ndarray:
    """Fixed targets moved by seeded offsets within ``radius``: clear of walls and obstacles, apart from each other
    and from every start as random targets are, and at least :data:`MIN_START_TARGET` from the robot's own start.

    :param rng: the env's generator
    :param layout: the room
    :param targets: ``(n, 2)`` the fixed targets
    :param starts_xy: ``(n, 2)`` the episode's start positions
    :param radius: largest offset [m]
    :return: ``(n, 2)`` targets
    """
    return _pick_near(rng, layout, targets, radius, TARGET_CLEARANCE, TARGET_SPACING, starts_xy, TARGET_START_SPACING)


def _pick_near(
    rng: np.random.Generator,
    layout: Layout,
    centres: np.ndarray,
    radius: float,
    wall_clearance: float,
    spacing: float,
    starts_xy: np.ndarray | None = None,
    start_spacing: float = 0.0,
) -> np.ndarray:
    """One point per centre, uniform in the disc of ``radius`` around it, by rejection in batches of 32: the first
    candidate in draw order that keeps ``wall_clearance`` to every box, ``spacing`` to the points already chosen
    and, with ``starts_xy``, ``start_spacing`` to every start and :data:`MIN_START_TARGET` to its own."""
    chosen: list[np.ndarray] = []
    for i, centre in enumerate(centres):
        for _ in range(100):
            distance = radius * np.sqrt(rng.uniform(size=32))
            angle = rng.uniform(-np.pi, np.pi, size=32)
            candidates = centre + np.stack([distance * np.cos(angle), distance * np.sin(angle)], axis=1)
            ok = in_room(candidates, layout, 0.0) & (clearance(candidates, layout.boxes) >= wall_clearance)
            for other in chosen:
                ok &= np.hypot(*(candidates - other).T) >= spacing
            if starts_xy is not None:
                gaps = np.linalg.norm(candidates[:, None, :] - starts_xy[None, :, :], axis=-1)
                ok &= (gaps.min(axis=1) >= start_spacing) & (gaps[:, i] >= MIN_START_TARGET)
            if ok.any():
                chosen.append(candidates[np.argmax(ok)])
                break
        else:
            raise RuntimeError(
                f"Could not place point {i} within {radius} m of {centre.tolist()} in the {layout.name!r} layout "
                "after 100 batches; use a smaller placement_jitter."
            )
    return np.array(chosen)
