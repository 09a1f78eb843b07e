"""The TurtleBot3 Burger, its LDS-01 lidar and its action set, as numbers and closed-form kinematics.

Sources: ROBOTIS TurtleBot3 Burger / LDS-01 specifications (e-Manual, "Specifications") and
Marchesini & Farinelli, ICRA 2022, Section IV-B (20 Hz decisions, 28 beams over [-120, 120] deg, the
Discrete(20) action set and the reward of Eq. 7).
"""

from __future__ import annotations

import numpy as np

# --- Robot body (ROBOTIS Burger) ---------------------------------------------------------------------
ROBOT_RADIUS = 0.105  # footprint radius [m]
ROBOT_HEIGHT = 0.192  # overall height [m]
ROBOT_MASS = 1.0  # about 1 kg
WHEEL_RADIUS = 0.033  # [m], drawn in the GUI only: motion is kinematic
WHEEL_SEPARATION = 0.160  # [m], idem

# --- LDS-01 lidar, as the paper samples it ---------------------------------------------------------
N_BEAMS = 28  # the paper's 28 beams ...
LIDAR_FOV_DEG = 120.0  # ... spread uniformly over [-120, 120] deg (endpoints included)
RANGE_MIN = 0.12  # [m] LDS-01 minimum range
RANGE_MAX = 3.5  # [m] LDS-01 maximum range; also the scale of the normalised ranges
LIDAR_HEIGHT = 0.172  # scan plane above the floor [m]: the LDS-01 sits on the Burger's top plate
# A beam starts this far from the robot's centre, just outside its own body, so it never hits it.
RAY_START = ROBOT_RADIUS + 0.002
# Beam angles in the robot frame, counter-clockwise positive, 0 = straight ahead; beam 0 is the
# rightmost (-120 deg), beam 27 the leftmost (+120 deg).
BEAM_ANGLES = np.deg2rad(np.linspace(-LIDAR_FOV_DEG, LIDAR_FOV_DEG, N_BEAMS))

# --- Decisions and actions (paper Sec. IV-B) ---------------------------------------------------------
DT = 0.05  # one decision is held 0.05 s: 20 Hz, the paper's decision rate
LINEAR_SPEEDS = (0.0, 0.07, 0.14, 0.21)  # [m/s]
ANGULAR_SPEEDS_DEG = (-90.0, -45.0, 0.0, 45.0, 90.0)  # [deg/s], positive = counter-clockwise (left)
N_ACTIONS = len(LINEAR_SPEEDS) * len(ANGULAR_SPEEDS_DEG)  # 20
# Action index a = 5 * i_linear + i_angular (linear-major): 0 = turn right on the spot, 2 = stand still,
# 17 = full speed straight ahead, 19 = full speed turning left.
ACTION_LINEAR = np.repeat(np.asarray(LINEAR_SPEEDS), len(ANGULAR_SPEEDS_DEG))
ACTION_ANGULAR = np.tile(np.deg2rad(np.asarray(ANGULAR_SPEEDS_DEG)), len(LINEAR_SPEEDS))
MAX_LINEAR = max(LINEAR_SPEEDS)
MAX_ANGULAR = float(np.deg2rad(max(abs(w) for w in ANGULAR_SPEEDS_DEG)))

# --- Task (paper Eq. 7) ------------------------------------------------------------------------------
TARGET_RADIUS = 0.1  # a robot within 0.1 m of its target has arrived
REWARD_COLLISION = -1.0
REWARD_ARRIVAL = 1.0
STEP_PENALTY = 0.005  # subtracted from the progress reward every tick
DISTANCE_SCALE = 10.0  # [m] observation scale of the target distance (covers every shipped world)


def integrate_unicycle(
    x: np.ndarray, y: np.ndarray, theta: np.ndarray, v: np.ndarray, w: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move unicycles exactly for ``dt`` seconds at constant (v, w): a circular arc, or a segment when w = 0.

    Closed form, so the commanded motion comes out true for any dt (no Euler drift).

    :param x: x positions [m]
    :param y: y positions [m]
    :param theta: headings [rad]
    :param v: linear velocities [m/s]
    :param w: angular velocities [rad/s]
    :param dt: duration [s]
    :return: new x, y and heading wrapped to [-pi, pi)
    """
    # Exact for any w, w = 0 included: the chord of the arc has length v dt sinc(w dt / 2) and points along
    # the mean heading theta + w dt / 2 (sinc(0) = 1).
    half_turn = (0.5 * dt) * w
    sinc = np.ones_like(half_turn)
    np.divide(np.sin(half_turn), half_turn, out=sinc, where=half_turn != 0.0)
    chord = (v * dt) * sinc
    mean_heading = theta + half_turn
    return x + chord * np.cos(mean_heading), y + chord * np.sin(mean_heading), wrap_angle(theta + w * dt)


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles to [-pi, pi).

    :param angle: angles [rad]
    :return: the same angles in [-pi, pi)
    """
    return (angle + np.pi) % (2.0 * np.pi) - np.pi
