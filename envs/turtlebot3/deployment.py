"""What a real TurtleBot3 Burger needs to run a policy trained in these worlds, as JSON-ready numbers.

:func:`deployment_description` is read by ``sb3_eps.export_policy`` (through the env's
``deployment_description()``, so that the library never imports this package) and written into the exported
policy's JSON: the lidar beams, how the observation is built from raw ranges and the target's polar coordinates,
the action table and how long each decision is held. ``sb3_eps/deploy/onnx_runner.py`` rebuilds the observation and
the wheel commands from it, as :meth:`MultiRobotNavEnv._observe` and ``step`` do.
"""

from __future__ import annotations

from typing import Any

from envs.turtlebot3.paths import CLEARANCE, LOOKAHEAD
from envs.turtlebot3.robot import (
    ACTION_ANGULAR,
    ACTION_LINEAR,
    BEAM_ANGLES,
    DISTANCE_SCALE,
    DT,
    LIDAR_HEIGHT,
    N_ACTIONS,
    N_BEAMS,
    RANGE_MAX,
    RANGE_MIN,
    ROBOT_RADIUS,
    TARGET_RADIUS,
    WHEEL_RADIUS,
    WHEEL_SEPARATION,
)

#: The kind of world a description speaks of (the runner checks it before it builds an observation).
DEPLOYMENT_KIND = "turtlebot3"


def deployment_description(
    lidar_range: float = RANGE_MAX,
    action_repeat: int = 1,
    lidar_frames: int = 1,
    lidar_frame_ticks: int = 5,
    lidar_noise_std: float = 0.0,
    path_guidance: bool = False,
    path_clearance: float = CLEARANCE,
    path_lookahead: float = LOOKAHEAD,
    path_replan: bool = False,
) -> dict[str, Any]:
    """The robot-side description of a TurtleBot3 world with these options (the world's own values).

    :param lidar_range: the ranges the policy sees [m]: each is capped at it and divided by it
    :param action_repeat: ticks (0.05 s each) every decision is held
    :param lidar_frames: scans in an observation (the current one, then earlier ones)
    :param lidar_frame_ticks: ticks between two stacked scans
    :param lidar_noise_std: the range noise the policy was trained with [m] (for the record)
    :param path_guidance: the policy was trained with waypoints of a planner on the map (``envs.turtlebot3.paths``):
        the goal inputs then come from the path, not the straight line to the target
    :param path_clearance: with ``path_guidance``: how far [m] the planner's path keeps from every wall
    :param path_lookahead: with ``path_guidance``: how far ahead [m] on the path the waypoint lies
    :param path_replan: with ``path_guidance``: the planner plans again round robots parked on their targets
    :return: a dict of JSON types only
    """
    obs_size = N_BEAMS + 2 + (lidar_frames - 1) * N_BEAMS
    observation: dict[str, Any] = {
        "size": obs_size,
        "dtype": "float32",
        "ranges": {
            "slice": [0, N_BEAMS],
            "formula": "min(max(range_m, range_min_m), lidar_range_m) / lidar_range_m",
            "note": "one value per beam in the order of lidar.angles_rad; a beam that hits nothing reads lidar_range_m",
        },
        "goal_distance": {
            "index": N_BEAMS,
            "scale_m": DISTANCE_SCALE,
            "formula": "min(distance_m / scale_m, 1)",
            "note": "distance from the robot's centre to its target [m]",
        },
        "goal_heading": {
            "index": N_BEAMS + 1,
            "formula": "wrap(heading_rad) / pi, wrap to [-pi, pi)",
            "note": "bearing of the target minus the robot's heading, counter-clockwise positive, 0 straight ahead",
        },
    }
    if path_guidance:
        observation["goal_distance"]["note"] = (
            "length of the shortest path on the static map from the robot to its target [m] (a planner's)"
        )
        observation["goal_heading"]["note"] = (
            f"bearing of the waypoint {path_lookahead:g} m ahead on that path (the target itself when less is left) "
            "minus the robot's heading, counter-clockwise positive; the planner keeps "
            f"{path_clearance:g} m from every wall (envs/turtlebot3/paths.py)"
            + ("; it plans again round every robot parked on its target" if path_replan else "")
        )
    if lidar_frames > 1:
        observation["earlier_ranges"] = {
            "slice": [N_BEAMS + 2, obs_size],
            "formula": "as ranges, for the scans (j + 1) * frame_ticks ticks ago, j = 0 .. frames - 2, newest first",
            "note": "every scan is taken at every tick; at an episode's start the earlier scans repeat the first one",
        }
    return {
        "kind": DEPLOYMENT_KIND,
        "robot": "TurtleBot3 Burger",
        "tick_s": DT,
        "action_repeat": int(action_repeat),
        "decision_period_s": DT * int(action_repeat),
        "lidar": {
            "n_beams": N_BEAMS,
            "angles_rad": BEAM_ANGLES.tolist(),
            "angle_convention": "robot frame, counter-clockwise positive, 0 straight ahead: beam 0 at -120 deg (right)",
            "range_min_m": RANGE_MIN,
            "range_max_m": RANGE_MAX,
            "lidar_range_m": float(lidar_range),
            "height_m": LIDAR_HEIGHT,
            "frames": int(lidar_frames),
            "frame_ticks": int(lidar_frame_ticks),
            "noise_std_m": float(lidar_noise_std),
        },
        "observation": observation,
        "actions": {
            "n_actions": N_ACTIONS,
            "index": "5 * i_linear + i_angular",
            "linear_m_s": ACTION_LINEAR.tolist(),
            "angular_rad_s": ACTION_ANGULAR.tolist(),
            "note": "unicycle command held for action_repeat ticks; angular counter-clockwise positive",
        },
        "wheels": {"separation_m": WHEEL_SEPARATION, "radius_m": WHEEL_RADIUS},
        "robot_radius_m": ROBOT_RADIUS,
        "target_radius_m": TARGET_RADIUS,
        # The world options that shape what the policy sees and how often it decides (constructor arguments).
        "world_kwargs": {
            "lidar_range": float(lidar_range),
            "action_repeat": int(action_repeat),
            "lidar_frames": int(lidar_frames),
            "lidar_frame_ticks": int(lidar_frame_ticks),
            "lidar_noise_std": float(lidar_noise_std),
        },
    }
