"""A policy's lidar action mask: the safety layer of ``docs/results/navigator.md`` built into the model.

At every decision each action is swept along its arc (the command held one decision, ``action_repeat`` ticks) against
the hit points of the robot's own lidar in this observation; the action is *safe* when the body stays more than
``margin`` metres clear of every point. The policy plays its best safe action (by the advantage, the greedy order);
exploration draws among the safe actions; double-Q targets take the arg max among the next state's safe actions, so the
values are those of the policy that is played. When no action is safe, the only allowed one is the action with the
most clearance. The geometry is the ONNX runner's (:func:`sb3_eps.deploy.onnx_runner.lidar_clearance`), computed
here in torch from the world's ``deployment_description()`` (TurtleBot3 worlds), so the mask needs nothing but the
robot's observation.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from torch import nn

#: Positions checked along each action's arc (as the ONNX runner's ``ARC_POINTS``).
ARC_POINTS = 8

#: A lidar value at or above this (of the view's cap, 1) is a beam that hit nothing.
_NO_HIT = 0.999

#: Where a beam without a hit is put [m].
_FAR = 1000.0

#: Observations per block of the distance computation.
_BLOCK = 128


def safety_geometry(description: dict[str, Any] | None, where: str = "the world") -> dict[str, Any]:
    """:return: what the mask needs of a world's ``deployment_description()``, as JSON numbers (stored in the model).

    :raises ValueError: for a world that does not describe a lidar robot (the mask needs TurtleBot3 worlds)
    """
    if not description or not {"lidar", "actions", "decision_period_s", "robot_radius_m"} <= description.keys():
        raise ValueError(
            f"safety_margin needs a world that describes its lidar and actions (a TurtleBot3 world); {where} does not: "
            "remove policy_kwargs.safety_margin"
        )
    lidar, actions = description["lidar"], description["actions"]
    return {
        "n_beams": int(lidar["n_beams"]),
        "angles_rad": [float(a) for a in lidar["angles_rad"]],
        "lidar_range_m": float(lidar["lidar_range_m"]),
        "linear_m_s": [float(v) for v in actions["linear_m_s"]],
        "angular_rad_s": [float(w) for w in actions["angular_rad_s"]],
        "decision_period_s": float(description["decision_period_s"]),
        "robot_radius_m": float(description["robot_radius_m"]),
    }


def arc_points(linear: np.ndarray, angular: np.ndarray, period_s: float) -> np.ndarray:
    """:return: ``(n_actions, ARC_POINTS, 2)``: where each command, held one decision, takes the robot's centre, in
    the robot's frame at the decision (x ahead, y to the left), the start excluded (exact unicycle arcs)."""
    times = period_s * np.arange(1, ARC_POINTS + 1) / ARC_POINTS
    v = np.asarray(linear, dtype=float)[:, None]
    half_turn = 0.5 * times[None, :] * np.asarray(angular, dtype=float)[:, None]
    sinc = np.ones_like(half_turn)
    np.divide(np.sin(half_turn), half_turn, out=sinc, where=half_turn != 0.0)
    chord = v * times[None, :] * sinc  # the chord along the mean heading
    return np.stack([chord * np.cos(half_turn), chord * np.sin(half_turn)], axis=-1)


class LidarSafetyMask(nn.Module):
    """Which actions keep the robot ``margin`` metres clear of what its lidar sees (the module docstring).

    :param margin: clearance [m] kept between the body and every lidar hit point along an action's arc
    :param geometry: :func:`safety_geometry` of the world the policy acts in
    """

    def __init__(self, margin: float, geometry: dict[str, Any]) -> None:
        super().__init__()
        if not float(margin) >= 0.0:
            raise ValueError(f"safety_margin must be a number of metres >= 0, got {margin!r}")
        self.margin = float(margin)
        self.n_beams = int(geometry["n_beams"])
        self.lidar_range = float(geometry["lidar_range_m"])
        self.robot_radius = float(geometry["robot_radius_m"])
        arcs = arc_points(geometry["linear_m_s"], geometry["angular_rad_s"], float(geometry["decision_period_s"]))
        angles = np.asarray(geometry["angles_rad"], dtype=float)
        if angles.shape != (self.n_beams,):
            raise ValueError(f"the geometry has {self.n_beams} beams but {angles.shape[0]} angles")
        directions = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
        points = arcs.reshape(-1, 2)  # (actions * arc points, 2)
        # |p - r u|^2 = |p|^2 - 2 r (p . u) + r^2 for an arc point p and a hit at range r along the beam's unit u.
        self.register_buffer("arc_norms", th.as_tensor((points * points).sum(-1)[:, None], dtype=th.float32), persistent=False)
        self.register_buffer("arc_dots", th.as_tensor(-2.0 * points @ directions.T, dtype=th.float32), persistent=False)
        self.n_actions = arcs.shape[0]

    def clearance(self, obs: th.Tensor) -> th.Tensor:
        """:return: ``(batch, n_actions)``: the least distance [m] from each action's swept centre to a lidar hit
        point, minus the robot's radius (about 1 km where the lidar sees nothing in its view)."""
        scan = obs[:, : self.n_beams]
        # A beam with no hit is put _FAR away: its r^2 term dominates every distance to the arcs.
        ranges = (scan * self.lidar_range).masked_fill(scan >= _NO_HIT, _FAR).unsqueeze(1)  # (batch, 1, beams)
        nearest = th.cat(
            [  # (rows, points, beams) in blocks of rows that stay in the cache (a training batch at once: 5x slower)
                th.addcmul(self.arc_norms + rows * rows, rows, self.arc_dots).view(len(rows), self.n_actions, -1).amin(2)
                for rows in ranges.split(_BLOCK)
            ]
        )
        return nearest.clamp_min(0.0).sqrt() - self.robot_radius

    def allowed(self, obs: th.Tensor) -> th.Tensor:
        """:return: ``(batch, n_actions)`` booleans: the safe actions, or the most clearing one where none is safe."""
        clearance = self.clearance(obs)
        safe = clearance > self.margin
        fallback = th.nn.functional.one_hot(clearance.argmax(dim=1), self.n_actions).bool()
        return th.where(safe.any(dim=1, keepdim=True), safe, fallback)

    def masked(self, obs: th.Tensor, scores: th.Tensor) -> th.Tensor:
        """:return: ``scores`` with the actions that are not allowed set to -inf (their arg max is the layer's)."""
        return scores.masked_fill(~self.allowed(obs), float("-inf"))
