"""Multi-robot TurtleBot3 mapless navigation (Marchesini & Farinelli, ICRA 2022, Sec. IV-B), a PettingZoo
``ParallelEnv``.

Each robot drives to its own target from 28 lidar ranges and the target's distance and relative heading; the
reward is the paper's Eq. 7. The full reference (constants, layouts, pictures) is ``docs/envs.md``.

Version history (``metadata["name"]``; bump the suffix on any change of behaviour):

- ``multi_robot_nav_v0``: first version. Later options (``scenario="blocks"``, ``scenario="rooms"``, up to 24 robots in
  the arena) leave the earlier worlds, their seeds and their physics unchanged, so the suffix stays.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from envs.seeding import check_seed
from envs.turtlebot3.deployment import deployment_description
from envs.turtlebot3.layouts import (
    PLACEMENT_JITTER_MAX,
    Layout,
    blocks_layout,
    in_room,
    jitter_starts,
    jitter_targets,
    make_layout,
    sample_starts,
    sample_targets,
)
from envs.turtlebot3.paths import CLEARANCE, CLEARANCE_MAX, LOOKAHEAD, LOOKAHEAD_MAX, PathGuide
from envs.turtlebot3.render import Rasteriser
from envs.turtlebot3.robot import (
    ACTION_ANGULAR,
    ACTION_LINEAR,
    BEAM_ANGLES,
    DISTANCE_SCALE,
    DT,
    MAX_ANGULAR,
    MAX_LINEAR,
    N_ACTIONS,
    N_BEAMS,
    RANGE_MAX,
    RAY_START,
    REWARD_ARRIVAL,
    REWARD_COLLISION,
    ROBOT_RADIUS,
    STEP_PENALTY,
    TARGET_RADIUS,
    wrap_angle,
)
from envs.turtlebot3.rooms import generate_room, select_levels
from envs.turtlebot3.world import NavWorld

OBS_DIM = N_BEAMS + 2  # 28 ranges, target distance, target heading
LIDAR_FRAMES_MAX = 4
LIDAR_RANGE_MIN = 0.5  # [m] exclusive: a shorter view than the robot's own clearance (RAY_START) tells too little
LIDAR_FRAME_TICKS_MAX = 20
ACTION_REPEAT_MAX = 10
MAP_SHAPES_MAX = 100  # "rooms": room meshes a world keeps (about 0.15 MB each with 24 robots) before it starts afresh
STAND_STILL = 2  # the action (v, w) = (0, 0)
#: What ``step`` returns: observations, rewards, terminations, truncations and infos, keyed by robot.
StepResult = tuple[
    dict[str, np.ndarray],
    dict[str, float],
    dict[str, bool],
    dict[str, bool],
    dict[str, dict[str, Any]],
]


def observation_space(lidar_frames: int = 1) -> gymnasium.spaces.Box:
    """The observation box: 28 ranges / 3.5 m in [0, 1], distance / 10 m in [0, 1], heading / pi in [-1, 1), then
    28 earlier ranges / 3.5 m for every scan of ``lidar_frames`` after the first (30 floats with one scan)."""
    dim = OBS_DIM + (lidar_frames - 1) * N_BEAMS
    low = np.zeros(dim, dtype=np.float32)
    low[N_BEAMS + 1] = -1.0
    return gymnasium.spaces.Box(low=low, high=np.ones(dim, dtype=np.float32), dtype=np.float32)


def _is_number(value: Any) -> bool:
    """:return: whether ``value`` is a real number (not a bool)"""
    return not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))


class MultiRobotNavEnv(ParallelEnv):
    """TurtleBot3 Burgers navigating to their own targets in a PyBullet room (paper Sec. IV-B).

    - Observation (per robot, float32, 30): ``[0:28]`` lidar ranges / 3.5 m (beam 0 at -120 deg, beam 27 at
      +120 deg, counter-clockwise positive), ``[28]`` distance to the target / 10 m clipped to [0, 1],
      ``[29]`` target bearing relative to the heading / pi, in [-1, 1). With ``lidar_frames = k > 1``, the
      ``k - 1`` earlier scans follow, newest first: ``[30 + 28 j : 58 + 28 j]`` is the scan of
      ``(j + 1) * lidar_frame_ticks`` ticks ago (at the start of an episode, the first scan).
    - Action: Discrete(20), index ``5 * i_linear + i_angular`` over linear {0, 0.07, 0.14, 0.21} m/s and
      angular {-90, -45, 0, 45, 90} deg/s, held for one 0.05 s tick (20 Hz).
    - Reward (Eq. 7): -1 on collision; +1 on arriving within 0.1 m of the target; otherwise
      ``(d_prev - d_now) - 0.005``.
    - Episode: a collision (robot-robot, wall, obstacle, parked robot) terminates every live robot; a robot that
      arrives is terminated, parked in place (an obstacle for the others) and leaves ``agents``; every robot
      arrived = success; ``max_episode_steps`` ticks truncate the robots still driving.
    - ``state()``: 9 floats per robot, robot-major: x, y, cos(theta), sin(theta), v, w (last command), target
      x, target y, arrived flag (SI units).
    - infos: per robot ``{"arrived", "collided", "team": {"success", "collision", "n_arrived",
      "team_return", "distance_travelled", "ticks"}}`` (running team values; final at the episode's end).
    - ``reset(options=...)`` places robots deterministically: ``"start_poses"`` ``(n, 3)`` (x, y, heading),
      ``"targets"`` ``(n, 2)``, in the unseen world ``"target_set"`` (index into its fixed sequence), in the rooms
      ``"level"`` (one of the world's levels, for this episode); other keys are ignored.

    :param n_robots: number of robots (1-24 in ``"arena"`` and ``"rooms"``, 1-12 in ``"blocks"``, 1-4 in the ``"eps*"``
        worlds and ``"unseen"``)
    :param scenario: ``"arena"`` (walls only, side 3 m + 0.25 m per robot), ``"blocks"`` (the same arena with
        rectangular blocks drawn anew at every reset, a training option for unseen rooms), ``"rooms"`` (a room
        generated from a level seed at every reset: :mod:`envs.turtlebot3.rooms`), ``"eps"`` (the single-robot EPS
        world with bars), ``"eps_pillars"`` (the 4 m arena with three robot-sized pillars) or
        ``"unseen"`` (the evaluation room: fixed starts, fixed cycling target sequence)
    :param max_episode_steps: time limit in ticks; None = 150 ticks per metre of the room's side
        (600 = 30 s for the 4 m arena)
    :param render_mode: None, ``"rgb_array"`` (top-down picture) or ``"human"`` (PyBullet GUI; needs a display)
    :param lidar_noise_std: standard deviation of Gaussian noise added to every range [m] (0 = exact)
    :param render_lidar: draw the lidar beams in ``rgb_array`` pictures
    :param placement_jitter: in a room with fixed poses (``"unseen"``), the largest seeded offset [m] of every
        start and target at each reset (start headings turn by up to 30 degrees too), kept clear of walls,
        obstacles and the other robots, with each target at least 2 m from its robot's start; 0 (the default)
        keeps the fixed poses. Up to 0.5 m
    :param lidar_frames: scans in each observation (1-4): 1 (the default, the paper's observation) is the current
        scan; more add earlier scans, from which a policy can tell how the robots around it move (multi-robot lidar
        policies stack the last three scans: Long et al., ICRA 2018, arXiv 1709.10082). An option beside the paper's
        world, measured in ``docs/results/many_robots.md``
    :param lidar_frame_ticks: ticks between two stacked scans (1-20; 5 = 0.25 s); read only with ``lidar_frames > 1``
    :param action_repeat: ticks each action is held (1-10): 1 (the default) is the paper's decision at every tick
        (20 Hz); ``k`` makes ``step`` advance ``k`` ticks (20 / k decisions a second) and return each robot's reward
        summed over them; collisions, arrivals and the time limit are still resolved at every tick, and a robot that
        ends inside a step returns its observation, reward and flags from the tick it ended. An option beside the
        paper's world, measured in ``docs/results/many_robots.md``
    :param lidar_range: the ranges the policy sees [m], in (0.5, 3.5]: every range is capped at ``lidar_range`` and
        divided by it (3.5, the default, is the LDS-01's reach and the paper's observation). A shorter view hides the
        far walls and corridors, which differ from room to room, and the robots far away, and keeps what is near. An
        option beside the paper's world; with ``action_repeat=4`` it is the setting of the 8- and 12-robot GDQ zoo
        entries and of the arena-only models that solve the unseen room (``docs/results/many_robots.md``).
        Collisions and rewards do not depend on it
    :param collision_reward: the reward of a robot that collides (a number <= -1; -1, the default, is the paper's
        Eq. 7). With the paper's -1, a robot that would need more than 200 ticks (10 s) of detour without progress
        scores better by crashing (the step penalty is 0.005 a tick): in rooms whose targets lie behind walls the
        learners crash into walls. A training option beside the paper's world; success and collisions do not
        depend on it (``docs/results/navigator.md``)
    :param level_set: ``"rooms"`` only: the levels every reset draws from, ``"train"`` (the default), ``"validation"``
        (make every choice there) or ``"test"`` (report there only); a world never plays a level of another set
    :param levels: ``"rooms"`` only: None (the whole set), a count ``k`` (the set's ``k`` lowest levels) or level ids of
        the set
    :param level: ``"rooms"`` only: the one level of the set this world plays (not with ``levels``)
    :param arena_share: ``"rooms"`` only: the probability, in [0, 1), that an episode plays the open arena of the team
        size (walls only, random starts and targets, as ``scenario="arena"``) instead of a level; 0 (the default)
        plays levels only. A training option: a world that mixes the open arena and the rooms (the
        ``MultiRobotNavMixed-<n>-v0`` ids, the navigator's training worlds)
    :param path_guidance: False (the default, the paper's observation): the observation holds the target's straight
        distance and bearing. True: the world plans on the room's static map as a robot's global planner would, and
        the observation holds the path length to go and the bearing of a waypoint 1 m ahead on the shortest path;
        progress is rewarded along the path (:mod:`envs.turtlebot3.paths`). Arrival is still at the target. The
        observation's layout is unchanged; a deployed policy needs a planner to feed it the waypoints
    :param path_clearance: with ``path_guidance``: how far [m] the planned path keeps from every wall and block, from
        the robot's radius up to 0.35 (the default: the radius plus 4.5 cm, ``envs.turtlebot3.paths.CLEARANCE``)
    :param path_lookahead: with ``path_guidance``: how far ahead [m] on the path the waypoint lies, in (0, 3] (the
        default: 1 m, the 1 m view's reach, ``envs.turtlebot3.paths.LOOKAHEAD``)
    :param path_replan: with ``path_guidance``: False (the default) plans once per episode on the static map; True
        plans again each time robots park, with the parked robots on the map (a costmap's obstacle layer), so no
        path runs through a robot standing on its target (``docs/results/navigator.md``, rule N14)
    """

    metadata: dict[str, Any] = {
        "name": "multi_robot_nav_v0",
        "render_modes": ["rgb_array", "human"],
        "render_fps": 20,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        n_robots: int = 4,
        scenario: str = "arena",
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        lidar_noise_std: float = 0.0,
        render_lidar: bool = False,
        placement_jitter: float = 0.0,
        lidar_frames: int = 1,
        lidar_frame_ticks: int = 5,
        action_repeat: int = 1,
        lidar_range: float = RANGE_MAX,
        level_set: str | None = None,
        levels: int | Sequence[int] | None = None,
        level: int | None = None,
        collision_reward: float = REWARD_COLLISION,
        arena_share: float = 0.0,
        path_guidance: bool = False,
        path_clearance: float = CLEARANCE,
        path_lookahead: float = LOOKAHEAD,
        path_replan: bool = False,
    ) -> None:
        self.layout: Layout = make_layout(scenario, n_robots)
        self.scenario = scenario
        self.n_robots = int(n_robots)
        self.level_set, self.levels = self._check_levels(level_set, levels, level)
        self.level: int | None = None  # the level of the current episode ("rooms"; None when it plays the arena)
        self.arena_share = self._check_arena_share(arena_share)
        if not isinstance(path_guidance, (bool, np.bool_)):
            raise ValueError(f"path_guidance must be True or False, got {path_guidance!r}.")
        self.path_guidance = bool(path_guidance)
        if not isinstance(path_replan, (bool, np.bool_)):
            raise ValueError(f"path_replan must be True or False, got {path_replan!r}.")
        self.path_replan = bool(path_replan)
        if not _is_number(path_clearance) or not ROBOT_RADIUS <= path_clearance <= CLEARANCE_MAX:
            raise ValueError(
                f"path_clearance must be a number of metres in [{ROBOT_RADIUS}, {CLEARANCE_MAX}], got {path_clearance!r}."
            )
        if not _is_number(path_lookahead) or not 0 < path_lookahead <= LOOKAHEAD_MAX:
            raise ValueError(f"path_lookahead must be a number of metres in (0, {LOOKAHEAD_MAX}], got {path_lookahead!r}.")
        self.path_clearance = float(path_clearance)
        self.path_lookahead = float(path_lookahead)
        self._guide: PathGuide | None = None
        self._arena = make_layout("arena", self.n_robots) if self.arena_share > 0 else None
        # Every room of a "rooms" world is drawn on the canvas of its largest one, so all pictures share one size.
        self._canvas = self.layout.half_extent if scenario == "rooms" else None
        if max_episode_steps is None:
            max_episode_steps = self.layout.default_time_limit
        if isinstance(max_episode_steps, bool) or not isinstance(max_episode_steps, (int, np.integer)):
            raise ValueError(f"max_episode_steps must be a positive int or None, got {max_episode_steps!r}.")
        if max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be a positive int or None, got {max_episode_steps}.")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}.")
        if (
            not isinstance(lidar_noise_std, (int, float, np.integer, np.floating))
            or not np.isfinite(lidar_noise_std)
            or lidar_noise_std < 0
        ):
            raise ValueError(f"lidar_noise_std must be a finite number >= 0 (metres), got {lidar_noise_std!r}.")
        if not _is_number(lidar_range) or not LIDAR_RANGE_MIN < lidar_range <= RANGE_MAX:
            raise ValueError(
                f"lidar_range must be a number of metres in ({LIDAR_RANGE_MIN}, {RANGE_MAX}], got {lidar_range!r}."
            )
        self.lidar_range = float(lidar_range)
        if not _is_number(collision_reward) or not -1e6 <= collision_reward <= REWARD_COLLISION:
            raise ValueError(f"collision_reward must be a number <= {REWARD_COLLISION}, got {collision_reward!r}.")
        self.collision_reward = float(collision_reward)
        self.placement_jitter = self._check_placement_jitter(placement_jitter)
        for name, value, largest in (
            ("lidar_frames", lidar_frames, LIDAR_FRAMES_MAX),
            ("lidar_frame_ticks", lidar_frame_ticks, LIDAR_FRAME_TICKS_MAX),
            ("action_repeat", action_repeat, ACTION_REPEAT_MAX),
        ):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= largest:
                raise ValueError(f"{name} must be an int in [1, {largest}], got {value!r}.")
        self.lidar_frames = int(lidar_frames)
        self.lidar_frame_ticks = int(lidar_frame_ticks)
        self.action_repeat = int(action_repeat)
        self.max_episode_steps = int(max_episode_steps)
        self.render_mode = render_mode
        self.lidar_noise_std = float(lidar_noise_std)
        self.render_lidar = bool(render_lidar)

        self.possible_agents = [f"robot_{i}" for i in range(self.n_robots)]
        self.agents: list[str] = []
        self._agent_index = {agent: i for i, agent in enumerate(self.possible_agents)}
        # One space object shared by every robot, built once: never depends on reset().
        self._observation_space = observation_space(self.lidar_frames)
        self._action_space = gymnasium.spaces.Discrete(N_ACTIONS)
        self.observation_spaces = dict.fromkeys(self.possible_agents, self._observation_space)
        self.action_spaces = dict.fromkeys(self.possible_agents, self._action_space)
        self.state_space = self._make_state_space()

        self.world = self._new_world()
        self._rasteriser: Rasteriser | None = None
        self.np_random, self._np_random_seed = seeding.np_random(None)
        self._episode_index = 0
        n = self.n_robots
        self._targets = np.zeros((n, 2))
        self._distance = np.zeros(n)
        self._live = np.zeros(n, dtype=bool)
        self._arrived = np.zeros(n, dtype=bool)
        self._live_index = np.zeros(0, dtype=int)
        self._command = np.full(n, STAND_STILL)  # last action of each robot (parked: standing still)
        self._scan_ranges = np.full((n, N_BEAMS), RANGE_MAX)
        self._scanned = np.zeros(0, dtype=int)
        # Normalised scans of the last (lidar_frames - 1) * lidar_frame_ticks ticks, newest first (lidar_frames > 1).
        history = (self.lidar_frames - 1) * self.lidar_frame_ticks + 1 if self.lidar_frames > 1 else 0
        self._scan_history = np.zeros((n, history, N_BEAMS), dtype=np.float32)
        self._ticks = 0
        self._team_return = 0.0
        self._distance_travelled = 0.0
        self._collision = False
        self._last_render_time = 0.0

    def _new_world(self) -> NavWorld:
        """The PyBullet world of the room; in ``"blocks"`` the walls are its map and the episode's blocks bodies
        beside it (:meth:`NavWorld.set_blocks`), replaced at each reset."""
        if self.scenario != "blocks":
            return NavWorld(self.layout, self.n_robots, gui=self.render_mode == "human")
        world = NavWorld(blocks_layout(self.n_robots), self.n_robots, gui=self.render_mode == "human")
        world.set_blocks(self.layout.obstacles)
        return world

    def _check_levels(
        self, level_set: str | None, levels: int | Sequence[int] | None, level: int | None
    ) -> tuple[str | None, np.ndarray | None]:
        if self.scenario != "rooms":
            given = [
                name for name, value in (("level_set", level_set), ("levels", levels), ("level", level)) if value is not None
            ]
            if given:
                raise ValueError(f"{', '.join(given)}: an option of scenario='rooms' only, not of {self.scenario!r}.")
            return None, None
        level_set = "train" if level_set is None else level_set
        return level_set, select_levels(level_set, levels, level)

    def _check_arena_share(self, arena_share: float) -> float:
        if (
            isinstance(arena_share, bool)
            or not isinstance(arena_share, (int, float, np.integer, np.floating))
            or not 0.0 <= arena_share < 1.0
        ):
            raise ValueError(f"arena_share must be a probability in [0, 1), got {arena_share!r}.")
        if arena_share > 0 and self.scenario != "rooms":
            raise ValueError(f"arena_share: an option of scenario='rooms' only, not of {self.scenario!r}.")
        return float(arena_share)

    def _check_placement_jitter(self, placement_jitter: float) -> float:
        if (
            isinstance(placement_jitter, bool)
            or not isinstance(placement_jitter, (int, float, np.integer, np.floating))
            or not 0.0 <= placement_jitter <= PLACEMENT_JITTER_MAX
        ):
            raise ValueError(
                f"placement_jitter must be a number of metres in [0, {PLACEMENT_JITTER_MAX}], got {placement_jitter!r}."
            )
        if placement_jitter > 0 and self.layout.starts is None:
            raise ValueError(
                f"placement_jitter moves fixed poses, and scenario {self.scenario!r} draws its poses at random: "
                "use scenario='unseen' or placement_jitter=0."
            )
        return float(placement_jitter)

    # --- spaces ------------------------------------------------------------------------------------------

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        """The observation space of ``agent`` (the same object for every robot and every call)."""
        self._check_agent(agent)
        return self._observation_space

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        """The action space of ``agent`` (the same object for every robot and every call)."""
        self._check_agent(agent)
        return self._action_space

    def deployment_description(self) -> dict[str, Any]:
        """What a real robot needs to run a policy of this world (lidar beams, observation, action table, decision
        period), JSON-ready: ``sb3_eps.export_policy`` writes it into the exported policy's JSON."""
        return deployment_description(
            self.lidar_range,
            self.action_repeat,
            self.lidar_frames,
            self.lidar_frame_ticks,
            self.lidar_noise_std,
            self.path_guidance,
            self.path_clearance,
            self.path_lookahead,
            self.path_replan,
        )

    def _plan_round_parked(self) -> None:
        """Plan again with the parked robots on the map (``path_replan``); the robots still driving measure their
        progress from their new path lengths, so the replan itself earns no reward."""
        parked = self.world.xy[self._arrived & ~self._live]
        self._guide = PathGuide(
            self.layout, self._targets, clearance=self.path_clearance, lookahead=self.path_lookahead, parked=parked
        )
        rows = self.world.rows_of(self._live_index)
        self._distance[rows], _ = self._guide.locate(self.world.xy[rows], self._live_index)

    def _check_agent(self, agent: str) -> None:
        if agent not in self._agent_index:
            raise ValueError(f"Unknown agent {agent!r}: this env has {self.possible_agents}.")

    def _make_state_space(self) -> gymnasium.spaces.Box:
        hx, hy = self.layout.half_extent
        low_one = [-hx, -hy, -1.0, -1.0, 0.0, -MAX_ANGULAR, -hx, -hy, 0.0]
        high_one = [hx, hy, 1.0, 1.0, MAX_LINEAR, MAX_ANGULAR, hx, hy, 1.0]
        low = np.tile(np.asarray(low_one, dtype=np.float32), self.n_robots)
        high = np.tile(np.asarray(high_one, dtype=np.float32), self.n_robots)
        return gymnasium.spaces.Box(low=low, high=high, dtype=np.float32)

    # --- reset -------------------------------------------------------------------------------------------

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode: new start poses and targets (random, fixed or from ``options``).

        :param seed: re-seeds ``self.np_random`` (and restarts the unseen world's target sequence)
        :param options: ``"start_poses"`` ``(n, 3)``, ``"targets"`` ``(n, 2)``, ``"target_set"`` (unseen), ``"level"``
            (rooms: one of the world's levels; else the level is drawn from them)
        :return: observations and infos of every robot
        """
        check_seed(seed)
        if seed is not None:
            self.np_random, self._np_random_seed = seeding.np_random(int(seed))
            self._episode_index = 0
        options = options or {}
        if self.world.client is None:
            # close() released the PyBullet client; like gymnasium's envs, a later reset() starts afresh.
            self.world = self._new_world()
        if self.scenario == "blocks":  # new blocks every episode
            self.layout = blocks_layout(self.n_robots, self.np_random)
            self.world.set_blocks(self.layout.obstacles)
            self._rasteriser = None
        elif self.scenario == "rooms":  # a level of the world's set every episode: its room, starts and targets
            if self._arena is not None and "level" not in options and self.np_random.random() < self.arena_share:
                self.level, self.layout = None, self._arena
            else:
                self.level = self._draw_level(options)
                self.layout = generate_room(self.level, self.n_robots).layout
            if self.world.n_map_shapes < MAP_SHAPES_MAX:
                self.world.set_map(self.layout)
            else:  # free the earlier rooms' meshes with their client
                self.world.close()
                self.world = self._new_world()
            self._rasteriser = None
        starts = self._start_poses(options)
        self.world.set_poses(starts)
        self._targets = self._pick_targets(options, starts[:, :2])
        self.world.show_targets(self._targets)
        self._episode_index += 1

        n = self.n_robots
        self.agents = self.possible_agents[:]
        self._live[:] = True
        self._live_index = np.arange(n)
        self._arrived[:] = False
        self._command.fill(STAND_STILL)
        self._ticks = 0
        self._team_return = 0.0
        self._distance_travelled = 0.0
        self._collision = False
        offset = self._targets - self.world.xy
        self._distance = np.hypot(offset[:, 0], offset[:, 1])
        if self.path_guidance:
            self._guide = PathGuide(self.layout, self._targets, clearance=self.path_clearance, lookahead=self.path_lookahead)
            self._distance, waypoint = self._guide.query(self.world.xy, np.arange(n))
            offset = waypoint - self.world.xy
        bearing = self._bearing(self._live_index, offset)
        obs = self._observe(self._live_index, offset, self._distance, bearing, new_episode=True)
        team = self._team_info()
        observations = dict(zip(self.agents, obs))
        infos = {agent: {"arrived": False, "collided": False, "team": team} for agent in self.agents}
        return observations, infos

    def _draw_level(self, options: dict[str, Any]) -> int:
        """The episode's level: ``options["level"]`` if it is one of the world's levels, else one drawn uniformly from
        them with ``np_random`` (so ``reset(seed=...)`` replays the same levels)."""
        assert self.levels is not None
        if "level" in options:
            chosen = select_levels(str(self.level_set), level=options["level"])[0]
            if chosen not in self.levels:
                raise ValueError(f"options['level']={chosen} is not one of this world's {len(self.levels)} levels.")
            return int(chosen)
        return int(self.levels[self.np_random.integers(len(self.levels))])

    def _start_poses(self, options: dict[str, Any]) -> np.ndarray:
        n = self.n_robots
        if "start_poses" in options:
            poses = self._option_array(options, "start_poses", (n, 3))
            if not in_room(poses[:, :2], self.layout, 0.0).all():
                raise ValueError(
                    f"options['start_poses'] puts a robot outside the room "
                    f"(|x| <= {self.layout.width / 2}, |y| <= {self.layout.height / 2})."
                )
            return poses
        if self.layout.starts is not None:
            starts = self.layout.starts[:n].copy()
            if self.placement_jitter > 0:
                return jitter_starts(self.np_random, self.layout, starts, self.placement_jitter)
            return starts
        return sample_starts(self.np_random, self.layout, n)

    def _pick_targets(self, options: dict[str, Any], starts_xy: np.ndarray) -> np.ndarray:
        n = self.n_robots
        if "targets" in options:
            return self._option_array(options, "targets", (n, 2))
        if self.layout.target_sets is not None:
            n_sets = len(self.layout.target_sets)
            index = options.get("target_set", self._episode_index % n_sets)
            if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < n_sets:
                raise ValueError(f"options['target_set'] must be an int in [0, {n_sets - 1}], got {index!r}.")
            targets = self.layout.target_sets[index, :n].copy()
            if self.placement_jitter > 0:
                return jitter_targets(self.np_random, self.layout, targets, starts_xy, self.placement_jitter)
            return targets
        return sample_targets(self.np_random, self.layout, starts_xy, DISTANCE_SCALE)

    @staticmethod
    def _option_array(options: dict[str, Any], key: str, shape: tuple[int, int]) -> np.ndarray:
        try:
            array = np.array(options[key], dtype=float)
        except (TypeError, ValueError) as error:
            raise ValueError(f"options[{key!r}] must be a numeric array of shape {shape}.") from error
        if array.shape != shape or not np.isfinite(array).all():
            raise ValueError(f"options[{key!r}] must be a finite array of shape {shape}, got shape {array.shape}.")
        return array

    # --- step --------------------------------------------------------------------------------------------

    def step(self, actions: dict[str, Any]) -> StepResult:
        """Advance one tick (0.05 s), or ``action_repeat`` ticks: every live robot executes its action, then
        collisions, arrivals and the time limit are resolved (at every tick).

        :param actions: an action in [0, 19] for every robot in ``self.agents`` (others are ignored)
        :return: observations, rewards, terminations, truncations and infos of the robots that acted
        """
        acting = self.agents
        if not acting:
            return {}, {}, {}, {}, {}
        if self.world.client is None:
            raise RuntimeError("step() on a closed env: call reset() first.")
        action_array = self._parse_actions(actions, acting)
        if self.action_repeat == 1:
            return self._tick(acting, action_array)
        # The ticks inside a step scan only the robots that end there (stacked scans need every tick's scan).
        every_scan = self.lidar_frames > 1
        chosen = dict(zip(acting, action_array.tolist()))
        observations, rewards, terminations, truncations, infos = self._tick(acting, action_array, every_scan)
        for sub_tick in range(1, self.action_repeat):
            if not self.agents:
                break
            still = self.agents
            last = sub_tick == self.action_repeat - 1
            tick = self._tick(still, np.array([chosen[agent] for agent in still], dtype=np.int64), every_scan or last)
            observations.update(tick[0])
            for agent, reward in tick[1].items():
                rewards[agent] += reward
            terminations.update(tick[2])
            truncations.update(tick[3])
            infos.update(tick[4])
        team = self._team_info()
        for info in infos.values():
            info["team"] = team
        return observations, rewards, terminations, truncations, infos

    def _tick(self, acting: list[str], action_array: np.ndarray, observe_all: bool = True) -> StepResult:
        """One tick of the live robots ``acting`` with their checked actions (:meth:`step`); ``observe_all=False``
        scans and returns the observations of the robots whose episode ends in this tick only."""
        live = self._live_index
        rows = self.world.rows_of(live)
        v, w = ACTION_LINEAR[action_array], ACTION_ANGULAR[action_array]
        if len(live) < self.n_robots:
            self._command.fill(STAND_STILL)  # parked robots stand still
        self._command[rows] = action_array
        self.world.move(live, v, w)
        self._distance_travelled += DT * float(v.sum())  # arc length = v dt, as v >= 0
        self._ticks += 1

        collided = (self.world.map_collisions() | self.world.robot_collisions())[rows]
        offset = self._targets[rows] - self.world.xy[rows]
        distance = np.hypot(offset[:, 0], offset[:, 1])
        arrived = (distance <= TARGET_RADIUS) & ~collided
        if self._guide is not None:  # the path length to go: progress along the path
            distance, cells = self._guide.locate(self.world.xy[rows], np.arange(self.n_robots)[rows])
        # Paper Eq. 7, collision taking precedence over arrival.
        progress = (self._distance[rows] - distance) - STEP_PENALTY
        rewards = np.where(collided, self.collision_reward, np.where(arrived, REWARD_ARRIVAL, progress))
        self._distance[rows] = distance
        self._team_return += float(rewards.sum())

        if collided.any():
            self._collision = True
            terminated = np.ones(len(live), dtype=bool)
        else:
            terminated = arrived
        ended = terminated
        if self._ticks >= self.max_episode_steps:
            truncated = ~terminated
            ended = np.ones(len(live), dtype=bool)
        else:
            truncated = np.zeros(len(live), dtype=bool)
        observations: dict[str, np.ndarray] = {}
        if observe_all or ended.any():
            if self._guide is not None:  # heading for the waypoint, walked only for a tick that observes
                robots = np.arange(self.n_robots)[rows]
                offset = self._guide.waypoints(self.world.xy[rows], robots, distance, cells) - self.world.xy[rows]
            bearing = self._bearing(live, offset)
            if observe_all:
                observations = dict(zip(acting, self._observe(live, offset, distance, bearing)))
            else:
                obs = self._observe(live[ended], offset[ended], distance[ended], bearing[ended])
                observations = dict(zip((agent for agent, end in zip(acting, ended) if end), obs))
        arrived_list = arrived.tolist()
        if ended.any():
            self._arrived[live] |= arrived
            self._live[live[ended]] = False
            self._live_index = np.flatnonzero(self._live)
            self.agents = [self.possible_agents[i] for i in self._live_index]
            if self.path_replan and self._guide is not None and arrived.any() and len(self._live_index):
                self._plan_round_parked()

        team = self._team_info()
        infos = {
            agent: {"arrived": a, "collided": c, "team": team} for agent, a, c in zip(acting, arrived_list, collided.tolist())
        }
        result = (
            observations,
            dict(zip(acting, rewards.tolist())),
            dict(zip(acting, terminated.tolist())),
            dict(zip(acting, truncated.tolist())),
            infos,
        )
        if self.render_mode == "human":
            self.render()
        return result

    def _parse_actions(self, actions: dict[str, Any], acting: list[str]) -> np.ndarray:
        """Gather the acting robots' actions as an int array, raising ``ValueError`` on anything else."""
        try:
            raw = [actions[agent] for agent in acting]
        except (KeyError, TypeError) as error:
            missing = [agent for agent in acting if not isinstance(actions, dict) or agent not in actions]
            raise ValueError(f"step() needs a dict with an action for every live robot; missing {missing}.") from error
        try:
            array = np.asarray(raw)
        except ValueError:
            # Mixed shapes such as [array(3), array([4])]: fall back to one element at a time.
            array = np.asarray([np.asarray(a).reshape(-1)[0] if np.size(a) == 1 else None for a in raw])
        if array.shape != (len(acting),) and array.size == len(acting):
            array = array.reshape(len(acting))
        kind = array.dtype.kind
        integral = kind in "iu" or (kind == "f" and bool(np.all(array == np.round(array))))
        if array.shape != (len(acting),) or not integral or array.min() < 0 or array.max() >= N_ACTIONS:
            raise ValueError(
                f"Actions must be integers in [0, {N_ACTIONS - 1}] (Discrete({N_ACTIONS})), one per live robot; "
                f"got {dict(zip(acting, raw))}."
            )
        return array.astype(np.int64)

    # --- observations, state, infos ----------------------------------------------------------------------

    def _observe(
        self,
        indices: np.ndarray,
        offset: np.ndarray,
        distance: np.ndarray,
        bearing: np.ndarray,
        new_episode: bool = False,
    ) -> np.ndarray:
        """Scan and build the observations of the robots in ``indices`` (one ray batch).

        :param indices: robot indices
        :param offset: ``(k, 2)`` target minus robot position
        :param distance: ``(k,)`` norms of ``offset``
        :param bearing: ``(k,)`` the target bearings, ``self._bearing(indices, offset)``
        :param new_episode: the first scan of an episode, which fills the earlier scans of ``lidar_frames > 1``
        """
        ranges = self.world.scan(indices, self.lidar_noise_std, self.np_random)
        rows = self.world.rows_of(indices)
        self._scan_ranges[rows] = ranges
        self._scanned = indices
        obs = np.empty((len(indices), self._observation_space.shape[0]), dtype=np.float32)
        obs[:, :N_BEAMS] = np.minimum(ranges, self.lidar_range) * (1.0 / self.lidar_range)
        obs[:, N_BEAMS] = np.minimum(distance * (1.0 / DISTANCE_SCALE), 1.0)
        obs[:, N_BEAMS + 1] = bearing * (1.0 / np.pi)
        if self.lidar_frames > 1:
            history = self._scan_history
            if new_episode:
                history[indices] = obs[:, None, :N_BEAMS]
            else:
                history[indices, 1:] = history[indices, :-1]
                history[indices, 0] = obs[:, :N_BEAMS]
            earlier = history[indices, self.lidar_frame_ticks :: self.lidar_frame_ticks]  # (k, lidar_frames - 1, 28)
            obs[:, OBS_DIM:] = earlier.reshape(len(indices), -1)
        return obs

    def _bearing(self, indices: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """The target's bearing relative to each robot's heading, wrapped to [-pi, pi)."""
        return wrap_angle(np.arctan2(offset[:, 1], offset[:, 0]) - self.world.theta[self.world.rows_of(indices)])

    def _team_info(self) -> dict[str, Any]:
        n_arrived = int(self._arrived.sum())
        team: dict[str, Any] = {
            "success": n_arrived == self.n_robots,
            "collision": self._collision,
            "n_arrived": n_arrived,
            "team_return": self._team_return,
            "distance_travelled": self._distance_travelled,
            "ticks": self._ticks,
        }
        if self.scenario == "rooms":
            team["level"] = self.level
        return team

    def state(self) -> np.ndarray:
        """Global state for centralised critics: 9 floats per robot (see the class docstring).

        :return: ``(9 * n,)`` float32
        """
        theta = self.world.theta
        per_robot = np.column_stack(
            [
                self.world.xy,
                np.cos(theta),
                np.sin(theta),
                ACTION_LINEAR[self._command],
                ACTION_ANGULAR[self._command],
                self._targets,
                self._arrived,
            ]
        )
        state = per_robot.astype(np.float32).ravel()
        # A robot can sink up to one tick into a wall before the collision ends the episode: stay in the box.
        return np.clip(state, self.state_space.low, self.state_space.high)

    # --- rendering and lifetime --------------------------------------------------------------------------

    def render(self) -> np.ndarray | None:
        """Draw the current tick: a top-down ``(H, W, 3)`` uint8 picture, or pace the GUI in human mode."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() was called without a render_mode; pass render_mode='rgb_array'.")
            return None
        if self.render_mode == "human":
            # Keep the GUI at the decision rate so motion plays in real time.
            wait = 1.0 / self.metadata["render_fps"] - (time.perf_counter() - self._last_render_time)
            if wait > 0:
                time.sleep(wait)
            self._last_render_time = time.perf_counter()
            return None
        if self._rasteriser is None:
            self._rasteriser = Rasteriser(self.layout, half_extent=self._canvas)
        beams = self._beams() if self.render_lidar else None
        parked = self._arrived & ~self._live
        return self._rasteriser.draw(self.world.xy, self.world.theta, self._targets, parked, beams)

    def _beams(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Segments of the last scan: from the body edge to each range reading."""
        indices = self._scanned
        angles = self.world.theta[indices, None] + BEAM_ANGLES[None, :]
        directions = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
        centres = self.world.xy[indices, None, :]
        starts = centres + RAY_START * directions
        ends = centres + self._scan_ranges[indices, :, None] * directions
        owner = np.repeat(indices, N_BEAMS)
        return starts.reshape(-1, 2), ends.reshape(-1, 2), owner

    def close(self) -> None:
        """Release the PyBullet client (idempotent)."""
        self.world.close()

    # A PyBullet client cannot be pickled, yet SuperSuit and multiprocessing copy envs by pickling: the copy
    # gets a fresh client holding the same room and poses, so it continues the episode exactly.
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        world = state.pop("world")
        state["_rasteriser"] = None
        state["_world_pose"] = np.column_stack([world.xy, world.theta])
        state["_world_open"] = world.client is not None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        pose = state.pop("_world_pose")
        world_open = state.pop("_world_open")
        self.__dict__.update(state)
        self.world = self._new_world()
        self.world.set_poses(pose)
        self.world.show_targets(self._targets)
        if not world_open:
            self.world.close()
