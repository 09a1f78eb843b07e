"""Single-robot TurtleBot3 navigation among static obstacles: the EPS evaluation world (paper Fig. 3 left), a
gymnasium ``Env``.

Same robot, lidar, actions, observation layout and reward (Eq. 7) as :class:`MultiRobotNavEnv`, of which it is
a thin one-robot view, so a policy moves between the two worlds unchanged.

Version history (``metadata["name"]``; bump the suffix on any change of behaviour):

- ``single_robot_nav_v0``: first version. The ``eps_pillars`` scenario was added later as a new option; the
  default world is unchanged, so the suffix stays.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np

from envs.turtlebot3.multi_robot_nav import MultiRobotNavEnv
from envs.turtlebot3.paths import CLEARANCE, LOOKAHEAD
from envs.turtlebot3.robot import RANGE_MAX, REWARD_COLLISION

AGENT = "robot_0"


class SingleRobotNavEnv(gymnasium.Env):
    """One TurtleBot3 Burger driving to random targets in the EPS world (walls plus static bars).

    Observation, action, reward and time limit as in :class:`~envs.turtlebot3.MultiRobotNavEnv`. An episode
    terminates on arrival (reward +1, ``info["is_success"] = True``) or on a collision (-1), and is truncated
    after ``max_episode_steps`` ticks. ``info`` also carries ``"arrived"``, ``"collided"`` and ``"team"``.

    :param scenario: ``"eps"`` (default: the EPS world with bars, paper Fig. 3 left), ``"eps_pillars"`` (the
        4-robot arena's 4 m walls with three robot-sized static pillars in place of the other robots: what
        ``EvolutionCallback`` evaluates in by default), ``"arena"`` (the
        1-robot arena, 3.25 m, walls only), ``"unseen"`` (robot 0 of the unseen room) or ``"rooms"`` (a room generated
        from a level seed for one robot, 3.3-4.2 m a side: inner walls with doorways, corridors, blocks, clutter;
        ``envs/turtlebot3/rooms.py``), where a robot of a rooms-trained team fails alone
    :param max_episode_steps: time limit in ticks; None = 150 ticks per metre of the room's side (600 here)
    :param render_mode: None, ``"rgb_array"`` or ``"human"`` (PyBullet GUI; needs a display)
    :param lidar_noise_std: standard deviation of Gaussian range noise [m]
    :param render_lidar: draw the lidar beams in ``rgb_array`` pictures
    :param placement_jitter: in ``"unseen"``, the largest seeded offset [m] of robot 0's fixed start and targets
        (as in :class:`~envs.turtlebot3.MultiRobotNavEnv`); 0 keeps them fixed
    :param lidar_frames: scans in each observation, as in :class:`~envs.turtlebot3.MultiRobotNavEnv` (an EPS world
        for a model trained with stacked scans needs the same)
    :param lidar_frame_ticks: ticks between two stacked scans
    :param action_repeat: ticks each action is held, as in :class:`~envs.turtlebot3.MultiRobotNavEnv`
    :param lidar_range: the ranges the policy sees [m], as in :class:`~envs.turtlebot3.MultiRobotNavEnv`
    :param level_set: ``"rooms"`` only: the level set every reset draws from (``"train"``, the default,
        ``"validation"`` or ``"test"``), as in :class:`~envs.turtlebot3.MultiRobotNavEnv`
    :param levels: ``"rooms"`` only: None (the whole set), a count or level ids of the set
    :param level: ``"rooms"`` only: the one level of the set this world plays
    :param collision_reward: the reward of a collision, as in :class:`~envs.turtlebot3.MultiRobotNavEnv` (-1: the
        paper's)
    :param path_guidance: waypoints on the room's map, as in :class:`~envs.turtlebot3.MultiRobotNavEnv`
    :param path_clearance: the planned path's distance from walls, as in :class:`~envs.turtlebot3.MultiRobotNavEnv`
    :param path_lookahead: the waypoint's distance down the path, as in :class:`~envs.turtlebot3.MultiRobotNavEnv`
    """

    metadata: dict[str, Any] = {
        "name": "single_robot_nav_v0",
        "render_modes": ["rgb_array", "human"],
        "render_fps": 20,
    }

    def __init__(
        self,
        scenario: str = "eps",
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
        path_guidance: bool = False,
        path_clearance: float = CLEARANCE,
        path_lookahead: float = LOOKAHEAD,
    ) -> None:
        self.multi_env = MultiRobotNavEnv(
            n_robots=1,
            scenario=scenario,
            max_episode_steps=max_episode_steps,
            render_mode=render_mode,
            lidar_noise_std=lidar_noise_std,
            render_lidar=render_lidar,
            placement_jitter=placement_jitter,
            lidar_frames=lidar_frames,
            lidar_frame_ticks=lidar_frame_ticks,
            action_repeat=action_repeat,
            lidar_range=lidar_range,
            level_set=level_set,
            levels=levels,
            level=level,
            collision_reward=collision_reward,
            path_guidance=path_guidance,
            path_clearance=path_clearance,
            path_lookahead=path_lookahead,
        )
        self.observation_space = self.multi_env.observation_space(AGENT)
        self.action_space = self.multi_env.action_space(AGENT)
        self.render_mode = render_mode
        self.max_episode_steps = self.multi_env.max_episode_steps
        self.action_repeat = self.multi_env.action_repeat
        self._np_random = self.multi_env.np_random

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode with a new random start pose and target.

        :param seed: re-seeds the generator (a non-negative int)
        :param options: ``"start_poses"`` ``(1, 3)`` and/or ``"targets"`` ``(1, 2)`` to place the robot
        :return: observation and info
        """
        observations, infos = self.multi_env.reset(seed=seed, options=options)
        # One generator for both views, so env.np_random is the one the world draws from.
        self._np_random = self.multi_env.np_random
        self._np_random_seed = self.multi_env._np_random_seed
        return observations[AGENT], self._info(infos[AGENT])

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Advance one tick (0.05 s).

        :param action: an int in [0, 19]
        :return: observation, reward, terminated, truncated, info
        """
        if not self.multi_env.agents:
            raise RuntimeError("The episode is over: call reset() before step().")
        observations, rewards, terminations, truncations, infos = self.multi_env.step({AGENT: action})
        return (
            observations[AGENT],
            rewards[AGENT],
            terminations[AGENT],
            truncations[AGENT],
            self._info(infos[AGENT]),
        )

    def deployment_description(self) -> dict[str, Any]:
        """What a real robot needs to run a policy of this world, as :meth:`MultiRobotNavEnv.deployment_description`."""
        return self.multi_env.deployment_description()

    @staticmethod
    def _info(info: dict[str, Any]) -> dict[str, Any]:
        return {**info, "is_success": info["arrived"]}

    def render(self) -> np.ndarray | None:
        """Top-down ``(H, W, 3)`` uint8 picture (``rgb_array``), or pace the GUI (``human``)."""
        return self.multi_env.render()

    def close(self) -> None:
        """Release the PyBullet client (idempotent)."""
        self.multi_env.close()
