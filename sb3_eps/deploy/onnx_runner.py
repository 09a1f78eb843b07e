"""Run a policy exported by ``sb3_eps.export_policy`` (``<name>.onnx`` + ``<name>.json``) without torch.

This file imports json, math, pathlib, numpy and onnxruntime only, and nothing of ``sb3_eps``: copy it alone onto the
robot beside the two exported files (``pip install numpy onnxruntime``), or import it from an installed package
(``from sb3_eps.deploy import OnnxPolicy``, which imports torch with the package).

>>> policy = OnnxPolicy.load("gdq_4")                        # gdq_4.json and gdq_4.onnx
>>> obs = policy.observation(ranges_m, goal_distance_m, goal_heading_rad)   # as the world builds it
>>> action = policy.act(obs)                                 # the policy's action (its lidar mask applied, if trained with one)
>>> action = policy.act(obs, safety_margin=0.03)            # the best action that keeps 3 cm from what the lidar sees
>>> linear, angular = policy.wheel_velocities(action)        # m/s, rad/s: hold for policy.decision_period_s

``observation`` and the wheel commands need a world that described itself at export (a TurtleBot3 world's
``deployment`` entry in the JSON); ``q_values`` and ``act`` work for every exported policy.
"""

from __future__ import annotations

import json
import math
import pathlib
from typing import Any

import numpy as np

try:
    import onnxruntime
except ImportError as _error:  # pragma: no cover - depends on the machine
    raise ImportError("onnx_runner needs onnxruntime: pip install onnxruntime") from _error

EXPORT_FORMAT = "sb3-eps-policy"
TURTLEBOT3 = "turtlebot3"

__all__ = ["OnnxPolicy", "lidar_clearance", "swept_arcs"]

#: Positions checked along each action's arc per decision (:func:`swept_arcs`).
ARC_POINTS = 8


def swept_arcs(linear: np.ndarray, angular: np.ndarray, period_s: float, horizon: int = 1) -> np.ndarray:
    """Where each command takes the robot's centre: ``(n_actions, horizon * ARC_POINTS, 2)`` positions in the robot's
    frame at the decision (x ahead, y to the left), along the unicycle's arc held ``horizon`` decisions, start excluded."""
    n_points = horizon * ARC_POINTS
    times = (period_s * horizon) * np.arange(1, n_points + 1) / n_points
    v = np.repeat(np.asarray(linear, dtype=float)[:, None], n_points, axis=1)
    w = np.repeat(np.asarray(angular, dtype=float)[:, None], n_points, axis=1)
    half_turn = (0.5 * times[None, :]) * w
    sinc = np.ones_like(half_turn)
    np.divide(np.sin(half_turn), half_turn, out=sinc, where=half_turn != 0.0)
    chord = (v * times[None, :]) * sinc  # exact arcs: the chord along the mean heading
    return np.stack([chord * np.cos(half_turn), chord * np.sin(half_turn)], axis=-1)


def lidar_clearance(
    scan: np.ndarray, lidar_range: float, angles: np.ndarray, arcs: np.ndarray, robot_radius: float
) -> np.ndarray:
    """How far [m] each action keeps the robot's body from the lidar's hit points of this instant.

    :param scan: ``(batch, n_beams)`` ranges as the observation holds them (divided by ``lidar_range``; 1 = no hit)
    :param angles: the beams' angles [rad] in the robot's frame
    :param arcs: :func:`swept_arcs`
    :return: ``(batch, n_actions)``: the least distance from the swept centre to a hit point, minus the robot's radius
        (inf where the lidar sees nothing in its view)
    """
    ranges = scan * lidar_range
    seen = scan < 0.999
    points = np.stack([ranges * np.cos(angles), ranges * np.sin(angles)], axis=-1)  # (batch, beams, 2)
    points = np.where(seen[..., None], points, np.inf)
    gaps = arcs[None, :, :, None, :] - points[:, None, None, :, :]  # (batch, actions, points, beams, 2)
    return np.sqrt((gaps * gaps).sum(axis=-1)).min(axis=(2, 3)) - robot_radius


class OnnxPolicy:
    """A greedy exported policy: Q-values by ONNX Runtime, the observation and the wheel commands from its JSON.

    :param session: the ONNX Runtime session of the ``.onnx`` file
    :param description: the parsed ``.json`` file
    """

    def __init__(self, session: onnxruntime.InferenceSession, description: dict[str, Any]) -> None:
        self.session = session
        self.description = description
        self.obs_dim = int(description["input"]["shape"][1])
        self.n_actions = int(description["n_actions"])
        self._input = description["input"]["name"]
        self._output = description["output"]["name"]
        deployment = description.get("deployment")
        self.deployment: dict[str, Any] | None = deployment if isinstance(deployment, dict) else None
        margin = description.get("safety_margin")
        #: The lidar mask the policy was trained with [m] (its ``policy_kwargs.safety_margin``), None without one.
        self.safety_margin: float | None = None if margin is None else float(margin)

    @classmethod
    def load(cls, path: str | pathlib.Path, threads: int | None = None) -> OnnxPolicy:
        """Load ``<path>.json`` and the ``.onnx`` file it names.

        :param path: ``<path>``, ``<path>.json`` or ``<path>.onnx`` as ``export_policy`` wrote them
        :param threads: ONNX Runtime's threads within an operator (None: its default, every core)
        :raises ValueError: for a missing or unreadable file, or a JSON that is not an exported policy's
        """
        json_path = pathlib.Path(path).with_suffix(".json")
        if not json_path.is_file():
            raise ValueError(f"no exported policy at {json_path}: export_policy writes <name>.json and <name>.onnx")
        try:
            description = json.loads(json_path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise ValueError(f"{json_path} is not readable JSON: {error}") from error
        if not isinstance(description, dict) or description.get("format") != EXPORT_FORMAT:
            raise ValueError(f"{json_path} is not an exported sb3-eps policy (its 'format' is not {EXPORT_FORMAT!r})")
        onnx_path = json_path.parent / str(description.get("onnx_file", ""))
        if not onnx_path.is_file():
            raise ValueError(f"{json_path} names the network {onnx_path}, which does not exist")
        options = onnxruntime.SessionOptions()
        if threads is not None:
            options.intra_op_num_threads = int(threads)
            options.inter_op_num_threads = 1
        try:
            session = onnxruntime.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
        except Exception as error:  # ONNX Runtime's own exception types
            raise ValueError(f"{onnx_path} is not a loadable ONNX network: {str(error).splitlines()[0]}") from error
        policy = cls(session, description)
        (graph_input,) = session.get_inputs()
        if graph_input.name != policy._input or graph_input.shape[-1] != policy.obs_dim:
            raise ValueError(
                f"{onnx_path} takes {graph_input.name} {graph_input.shape}, its JSON says "
                f"{policy._input} (batch, {policy.obs_dim}): the two files are not one export"
            )
        return policy

    # --- what the JSON says ------------------------------------------------------------------------------

    @property
    def env_id(self) -> str | None:
        """The registered id of the world the policy was exported for (None: not recorded)."""
        return self.description.get("env_id")

    @property
    def env_kwargs(self) -> dict[str, Any] | None:
        """The world options beyond the id's (None: not recorded)."""
        return self.description.get("env_kwargs")

    @property
    def action_repeat(self) -> int | None:
        """Ticks each decision is held (None: the world did not say)."""
        return None if self.deployment is None else int(self.deployment["action_repeat"])

    @property
    def decision_period_s(self) -> float | None:
        """Seconds each decision is held: ``action_repeat`` ticks of ``tick_s`` (None: the world did not say)."""
        return None if self.deployment is None else float(self.deployment["decision_period_s"])

    def __repr__(self) -> str:
        return (
            f"OnnxPolicy({self.description.get('algorithm')}, env_id={self.env_id!r}, obs_dim={self.obs_dim}, "
            f"n_actions={self.n_actions}, action_repeat={self.action_repeat})"
        )

    # --- acting ------------------------------------------------------------------------------------------

    def q_values(self, obs: Any) -> np.ndarray:
        """The Q-values of one observation ``(obs_dim,)`` -> ``(n_actions,)``, or of a batch ``(batch, obs_dim)`` ->
        ``(batch, n_actions)`` (float32).

        :raises ValueError: for another shape, or values that are not finite
        """
        batch = np.asarray(obs, dtype=np.float32)
        single = batch.ndim == 1
        if batch.ndim not in (1, 2) or batch.shape[-1] != self.obs_dim:
            raise ValueError(f"obs must have shape ({self.obs_dim},) or (batch, {self.obs_dim}), got {batch.shape}")
        if not np.isfinite(batch).all():
            raise ValueError("obs holds NaN or infinite values")
        (q_values,) = self.session.run([self._output], {self._input: batch.reshape(-1, self.obs_dim)})
        return q_values[0] if single else q_values

    def act(self, obs: Any, safety_margin: float | str | None = "trained") -> Any:
        """The greedy action (arg max of the Q-values): an int for one observation, an int64 array for a batch,
        and ``{agent: int}`` for a dict of observations (a PettingZoo world's, one network for every agent).

        :param safety_margin: ``"trained"`` (the default): the policy as trained, with its lidar mask when it has one
            (:attr:`safety_margin`); None: the network alone; or a number: a safety layer on the lidar (TurtleBot3
            worlds): the best action whose arc over the next decision keeps the body this many metres [m] clear of
            every lidar hit point of this observation, or the action with the most clearance when none does
            (:meth:`clearance`). 0.03 removed every collision on validation rooms (``docs/results/navigator.md``, rule
            N13); moving robots are seen where they are now, so the margin is what covers their motion
        """
        if isinstance(safety_margin, str):
            if safety_margin != "trained":
                raise ValueError(f"safety_margin must be 'trained', None or metres >= 0, got {safety_margin!r}")
            safety_margin = self.safety_margin
        if isinstance(obs, dict):
            agents = list(obs)
            if not agents:
                return {}
            stacked = np.stack([np.asarray(obs[agent], dtype=np.float32) for agent in agents])
            return dict(zip(agents, self.act(stacked, safety_margin).tolist()))
        q_values = self.q_values(obs)
        if safety_margin is not None:
            if not safety_margin >= 0:
                raise ValueError(f"safety_margin must be a number of metres >= 0, got {safety_margin!r}")
            clearance = self.clearance(obs)
            safe = clearance > safety_margin
            masked = np.where(safe, q_values, -np.inf)
            return _greedy(np.where(safe.any(axis=-1, keepdims=True), masked, clearance))
        return _greedy(q_values)

    def clearance(self, obs: Any, horizon: int = 1) -> np.ndarray:
        """How far [m] each action, held ``horizon`` decisions, keeps the robot's body from the lidar's hit points in
        ``obs`` (:func:`lidar_clearance`): ``(n_actions,)`` for one observation, ``(batch, n_actions)`` for a batch."""
        deployment = self._turtlebot3("clearance")
        lidar, actions = deployment["lidar"], deployment["actions"]
        batch = np.asarray(obs, dtype=np.float32)
        arcs = swept_arcs(actions["linear_m_s"], actions["angular_rad_s"], float(deployment["decision_period_s"]), horizon)
        n_beams = int(lidar["n_beams"])
        scan = batch.reshape(-1, batch.shape[-1])[:, :n_beams]
        angles = np.asarray(lidar["angles_rad"], dtype=float)
        clearance = lidar_clearance(scan, float(lidar["lidar_range_m"]), angles, arcs, float(deployment["robot_radius_m"]))
        return clearance[0] if batch.ndim == 1 else clearance

    # --- the robot's side (TurtleBot3 worlds) ------------------------------------------------------------

    def observation(self, ranges: Any, goal_distance: Any, goal_heading: Any, earlier_ranges: Any = None) -> np.ndarray:
        """The observation the world builds, from raw lidar ranges and the target's polar coordinates.

        One robot: ``ranges (n_beams,)`` and two numbers; several: ``ranges (batch, n_beams)`` and ``(batch,)``.
        Ranges are capped at ``lidar_range_m`` and divided by it (a beam without a return may read ``inf``), the
        distance divided by its scale and capped at 1, the heading wrapped to [-pi, pi) and divided by pi.

        :param ranges: lidar ranges [m], in the order of ``deployment["lidar"]["angles_rad"]``
        :param goal_distance: distance to the target [m]
        :param goal_heading: the target's bearing relative to the robot's heading [rad], counter-clockwise positive
        :param earlier_ranges: with stacked scans (``lidar.frames > 1``): the earlier scans, newest first,
            ``(frames - 1, n_beams)`` (or ``(batch, frames - 1, n_beams)``) [m]
        :return: float32 ``(obs_dim,)`` or ``(batch, obs_dim)``
        :raises ValueError: for shapes that do not fit, NaN, negative distances, or a world that did not describe
            its observation
        """
        deployment = self._turtlebot3("observation")
        lidar, layout = deployment["lidar"], deployment["observation"]
        n_beams, frames = int(lidar["n_beams"]), int(lidar["frames"])
        scan = self._scaled_ranges(ranges, lidar, "ranges", (n_beams,))
        batch_shape = scan.shape[:-1]
        distance = self._per_robot(goal_distance, batch_shape, "goal_distance")
        heading = self._per_robot(goal_heading, batch_shape, "goal_heading")
        if not np.isfinite(heading).all():
            raise ValueError("goal_heading must be finite")
        if (distance < 0).any():
            raise ValueError("goal_distance must be >= 0 metres")
        inside = np.abs(heading) <= math.pi  # the world's bearing is wrapped already: kept as it is, to the bit
        heading = np.where(inside, heading, (heading + math.pi) % (2.0 * math.pi) - math.pi)
        obs = np.empty((*batch_shape, int(layout["size"])), dtype=np.float32)
        obs[..., :n_beams] = scan
        goal = layout["goal_distance"]
        obs[..., int(goal["index"])] = np.minimum(distance * (1.0 / float(goal["scale_m"])), 1.0)
        obs[..., int(layout["goal_heading"]["index"])] = heading * (1.0 / np.pi)
        if frames > 1:
            if earlier_ranges is None:
                raise ValueError(f"this policy sees {frames} stacked scans: pass earlier_ranges ({frames - 1}, {n_beams})")
            earlier = self._scaled_ranges(earlier_ranges, lidar, "earlier_ranges", (frames - 1, n_beams))
            if earlier.shape[:-2] != batch_shape:
                raise ValueError(f"earlier_ranges must have shape {(*batch_shape, frames - 1, n_beams)}, got {earlier.shape}")
            start, stop = layout["earlier_ranges"]["slice"]
            obs[..., start:stop] = earlier.reshape(*batch_shape, -1)
        elif earlier_ranges is not None:
            raise ValueError("this policy sees one scan: earlier_ranges must be None")
        return obs

    def wheel_velocities(self, action: Any) -> tuple[Any, Any]:
        """The command of an action: linear [m/s] and angular [rad/s, counter-clockwise positive] velocity, floats
        for one action, arrays for several; held for ``decision_period_s``."""
        actions = self._check_actions(action)
        table = self._turtlebot3("wheel_velocities")["actions"]
        linear = np.asarray(table["linear_m_s"], dtype=float)[actions]
        angular = np.asarray(table["angular_rad_s"], dtype=float)[actions]
        if actions.ndim == 0:
            return float(linear), float(angular)
        return linear, angular

    def wheel_speeds(self, action: Any, unit: str = "m/s") -> tuple[Any, Any]:
        """Left and right wheel speeds of an action (differential drive, wheel separation from the JSON):
        ``v -+ w * separation / 2`` in m/s at the wheel's rim, or in rad/s with ``unit="rad/s"``."""
        if unit not in ("m/s", "rad/s"):
            raise ValueError(f"unit must be 'm/s' or 'rad/s', got {unit!r}")
        linear, angular = self.wheel_velocities(action)
        wheels = self._turtlebot3("wheel_speeds").get("wheels") or {}
        if "separation_m" not in wheels or (unit == "rad/s" and "radius_m" not in wheels):
            raise ValueError("the exported JSON does not give the wheels' separation and radius")
        half = 0.5 * float(wheels["separation_m"])
        left, right = linear - angular * half, linear + angular * half
        if unit == "rad/s":
            left, right = left / float(wheels["radius_m"]), right / float(wheels["radius_m"])
        return left, right

    # --- checks ------------------------------------------------------------------------------------------

    def _turtlebot3(self, what: str) -> dict[str, Any]:
        if self.deployment is None or self.deployment.get("kind") != TURTLEBOT3:
            raise ValueError(
                f"{what} needs a TurtleBot3 world's description in the JSON (env_id {self.env_id!r} has none): "
                "export with env=<the training env> in sb3-eps 0.1 or later"
            )
        return self.deployment

    @staticmethod
    def _scaled_ranges(ranges: Any, lidar: dict[str, Any], name: str, shape: tuple[int, ...]) -> np.ndarray:
        """Ranges [m] -> the observation's values: capped at ``lidar_range_m`` and divided by it, as the world."""
        array = np.asarray(ranges, dtype=float)
        if array.ndim not in (len(shape), len(shape) + 1) or array.shape[-len(shape) :] != shape:
            raise ValueError(f"{name} must have shape {shape} or (batch, {', '.join(map(str, shape))}), got {array.shape}")
        if np.isnan(array).any():
            raise ValueError(f"{name} holds NaN: pass inf for a beam without a return")
        reach = float(lidar["lidar_range_m"])
        return np.minimum(np.maximum(array, float(lidar["range_min_m"])), reach) * (1.0 / reach)

    @staticmethod
    def _per_robot(value: Any, batch_shape: tuple[int, ...], name: str) -> np.ndarray:
        array = np.asarray(value, dtype=float)
        if array.shape != batch_shape:
            raise ValueError(f"{name} must have shape {batch_shape} (one per scan), got {array.shape}")
        if np.isnan(array).any():
            raise ValueError(f"{name} holds NaN")
        return array

    def _check_actions(self, action: Any) -> np.ndarray:
        actions = np.asarray(action)
        if actions.dtype.kind not in "iu" or actions.ndim > 1 or (actions < 0).any() or (actions >= self.n_actions).any():
            raise ValueError(f"action must be an int in [0, {self.n_actions - 1}] or a 1-d array of them, got {action!r}")
        return actions.astype(np.int64)


def _greedy(scores: np.ndarray) -> Any:
    """:return: the arg max of ``(n_actions,)`` scores as an int, of ``(batch, n_actions)`` as int64s."""
    if scores.ndim == 1:
        return int(np.argmax(scores))
    return np.argmax(scores, axis=1).astype(np.int64)
