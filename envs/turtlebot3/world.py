"""The PyBullet world: static map, robot bodies, exact kinematics, lidar and collision queries.

All physics lives here; the envs only hold episode logic. Design choices, each measured on the 2-core VM
this project runs on (``docs/envs.md`` has the figures):

- Motion is kinematic: each decision integrates the unicycle model in closed form and sets the poses
  (``resetBasePositionAndOrientation``). No ``stepSimulation``: commanded motion comes out exact and a
  tick stays cheap.
- The walls and obstacles are ONE static triangle mesh: Bullet ray-casts a BVH mesh about 2x faster than
  separate boxes.
- A robot's collision shape is a sphere of the Burger's radius centred in the lidar scan plane. Every
  interaction happens in that plane (beams, wall contact, other robots), where the sphere's section is the
  same 0.105 m circle as the Burger's cylinder; Bullet casts rays at spheres analytically but at cylinders
  through GJK, which made a 12-robot scan 4x slower. The GUI still draws a cylinder.
- All robots' beams go in one ``rayTestBatch``; robot-map contacts come from one ``performCollisionDetection``
  plus one ``getContactPoints``; robot-robot contacts are centre distances below two radii (numpy).
"""

from __future__ import annotations

import operator
import os
import sys
from typing import Any

import numpy as np

from envs.turtlebot3.layouts import WALL_HEIGHT, Layout
from envs.turtlebot3.robot import (
    BEAM_ANGLES,
    DT,
    LIDAR_HEIGHT,
    N_BEAMS,
    RANGE_MAX,
    RANGE_MIN,
    RAY_START,
    ROBOT_HEIGHT,
    ROBOT_MASS,
    ROBOT_RADIUS,
    WHEEL_RADIUS,
    WHEEL_SEPARATION,
    integrate_unicycle,
)


def _import_pybullet_quietly() -> Any:
    """Import pybullet without the ``pybullet build time: ...`` line its C module writes on stderr at import: it
    would be a second line under the command lines' one-line error messages."""
    try:
        saved = os.dup(2)
    except OSError:  # no file descriptor 2: nothing to silence
        import pybullet

        return pybullet
    try:
        with open(os.devnull, "w") as devnull:
            sys.stderr.flush()
            os.dup2(devnull.fileno(), 2)
            import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return pybullet


p = _import_pybullet_quietly()

# Robot colours (RGB 0-255), shared with the rasteriser so the GUI and the pictures agree.
# Robot colours (RGB 0-255), 16 distinct hues shared by the GUI and the pictures; none is the map's blue.
ROBOT_COLOURS = np.array(
    [
        [228, 26, 28],  # red
        [55, 126, 184],  # steel blue
        [77, 175, 74],  # green
        [152, 78, 163],  # purple
        [255, 127, 0],  # orange
        [166, 86, 40],  # brown
        [247, 129, 191],  # pink
        [23, 190, 207],  # cyan
        [188, 189, 34],  # olive
        [110, 110, 110],  # grey
        [20, 20, 20],  # black
        [0, 128, 128],  # teal
        [128, 0, 0],  # maroon
        [150, 230, 60],  # lime
        [200, 0, 200],  # magenta
        [240, 200, 0],  # gold
    ],
    dtype=np.uint8,
)
MAP_COLOUR = (40, 80, 200)  # walls and obstacles are blue, as in the paper's Fig. 3
# Bullet's default filter of a dynamic body (group 1, mask all): collides with the map, and rays see it.
ROBOT_FILTER_GROUP, ROBOT_FILTER_MASK = 1, -1
# Distance from the robot's centre to where each beam starts and ends, shaped to broadcast over (2, k, 28).
RAY_REACH = np.array([RAY_START, RANGE_MAX])[:, None, None]
# A rayTestBatch hit is (body, link, hit fraction, position, normal); the fraction is 1 where nothing is hit.
_hit_fraction = operator.itemgetter(2)


def display_available() -> bool:
    """Whether a window can be opened (the PyBullet GUI needs one; without it PyBullet exits the process)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def box_mesh(boxes: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of the side and top faces of vertical boxes standing on the floor.

    :param boxes: ``(k, 4)`` boxes ``(cx, cy, hx, hy)``
    :param height: box height [m]
    :return: vertices ``(8k, 3)`` and triangle indices ``(30k,)``
    """
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    vertices, indices = [], []
    for k, (cx, cy, hx, hy) in enumerate(boxes):
        ring = np.array([cx, cy]) + corners * np.array([hx, hy])
        vertices.append(np.concatenate([np.c_[ring, np.zeros(4)], np.c_[ring, np.full(4, height)]]))
        base = 8 * k
        for i in range(4):
            j = (i + 1) % 4
            indices += [base + i, base + j, base + 4 + j, base + i, base + 4 + j, base + 4 + i]
        indices += [base + 4, base + 5, base + 6, base + 4, base + 6, base + 7]
    return np.concatenate(vertices), np.asarray(indices, dtype=int)


class NavWorld:
    """A PyBullet client holding one room and ``n_robots`` TurtleBot3 Burgers.

    The poses live in numpy (``xy``, ``theta``) and are mirrored into PyBullet whenever they change.

    :param layout: the room
    :param n_robots: number of robots
    :param gui: open the PyBullet GUI (needs a display) instead of the headless DIRECT mode
    """

    def __init__(self, layout: Layout, n_robots: int, gui: bool = False) -> None:
        if gui and not display_available():
            raise RuntimeError(
                'render_mode="human" opens the PyBullet GUI, which needs a display, and none was found '
                '(DISPLAY is not set). Use render_mode="rgb_array" on a headless machine.'
            )
        self.layout = layout
        self.n_robots = n_robots
        self.gui = gui
        self.client: int | None = p.connect(p.GUI if gui else p.DIRECT)
        cid = self.client
        if gui:
            p.configureDebugVisualizer(p.COV_ENABLE_GUI, 0, physicsClientId=cid)
            extent = max(layout.width, layout.height)
            p.resetDebugVisualizerCamera(extent * 1.1, 0.0, -89.9, [0.0, 0.0, 0.0], physicsClientId=cid)
        self._map_shapes: dict[bytes, int] = {}  # mesh shapes of set_map by their boxes: kept, as for set_blocks
        self.map_id = self._map_body(layout)
        self._block_ids: list[int] = []  # bodies of set_blocks, beside the map
        self._block_shapes: dict[tuple[int, int], int] = {}  # their collision shapes by half extents in 5 mm
        self._map_visual_ids: list[int] = []
        sphere = p.createCollisionShape(
            p.GEOM_SPHERE,
            radius=ROBOT_RADIUS,
            collisionFramePosition=[0, 0, LIDAR_HEIGHT],
            physicsClientId=cid,
        )
        self.robot_ids = [
            p.createMultiBody(ROBOT_MASS, sphere, self._robot_visual(i), [0.0, 0.0, 0.0], physicsClientId=cid)
            for i in range(n_robots)
        ]
        if gui:
            self._add_map_visuals()
        # Body id -> robot index, for reading contact lists without a Python search.
        self._robot_index = np.full(max(self.robot_ids) + 1, -1)
        self._robot_index[self.robot_ids] = np.arange(n_robots)
        self._target_ids: list[int] = []
        self.xy = np.zeros((n_robots, 2))
        self.theta = np.zeros(n_robots)
        self._rays = np.full((2, n_robots, N_BEAMS, 3), LIDAR_HEIGHT)

    def _map_body(self, layout: Layout) -> int:
        """The static body of the room's walls and obstacles, one triangle mesh; the mesh shape of the same boxes is
        built once per world and kept (PyBullet frees no shape that a body has used)."""
        cid = self.client
        key = np.asarray(layout.boxes, dtype=float).tobytes()
        if key not in self._map_shapes:
            vertices, indices = box_mesh(layout.boxes, WALL_HEIGHT)
            self._map_shapes[key] = p.createCollisionShape(
                p.GEOM_MESH, vertices=vertices.tolist(), indices=indices.tolist(), physicsClientId=cid
            )
        return p.createMultiBody(0.0, self._map_shapes[key], -1, [0.0, 0.0, 0.0], physicsClientId=cid)

    @property
    def n_map_shapes(self) -> int:
        """How many map meshes this world holds: one per room it has shown (:meth:`set_map`); PyBullet frees a used
        shape only with its client, so a world that shows many rooms is replaced now and then (``"rooms"``)."""
        return len(self._map_shapes)

    def set_map(self, layout: Layout) -> None:
        """Replace the map by the walls and obstacles of ``layout``, one mesh as at construction (a scenario whose room
        changes between episodes: ``"rooms"``; a mesh casts rays faster than bodies of its boxes). The robots stay.

        :param layout: the new room
        """
        p.removeBody(self.map_id, physicsClientId=self.client)
        self.layout = layout
        self.map_id = self._map_body(layout)
        if self.gui:
            self._add_map_visuals()

    def set_blocks(self, blocks: np.ndarray) -> None:
        """Put ``blocks`` (boxes ``(k, 4)``, half extents whole multiples of 5 mm) in the room as static bodies beside
        its map, replacing the previous call's (a scenario that draws its obstacles at every reset). Each size's
        collision shape is built once and kept: PyBullet cannot free a shape, so only bodies come and go."""
        cid = self.client
        blocks = np.asarray(blocks, dtype=float).reshape(-1, 4)
        for body in self._block_ids:
            p.removeBody(body, physicsClientId=cid)
        self._block_ids = []
        for cx, cy, hx, hy in blocks:
            size = (round(hx * 200), round(hy * 200))
            if size not in self._block_shapes:
                half = [size[0] / 200, size[1] / 200, WALL_HEIGHT / 2]
                self._block_shapes[size] = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid)
            position = [cx, cy, WALL_HEIGHT / 2]
            self._block_ids.append(p.createMultiBody(0.0, self._block_shapes[size], -1, position, physicsClientId=cid))
        if self.gui:
            self._add_map_visuals(blocks)

    # --- poses and motion ---------------------------------------------------------------------------------

    def set_poses(self, poses: np.ndarray) -> None:
        """Place every robot.

        :param poses: ``(n, 3)`` poses (x, y, heading)
        """
        self.xy = np.array(poses[:, :2], dtype=float)
        self.theta = np.array(poses[:, 2], dtype=float)
        self._push_poses(np.arange(self.n_robots))
        self._forget_contacts()

    def _forget_contacts(self) -> None:
        """Drop Bullet's cached contact points after a teleport.

        Bullet keeps contact points between frames and only refreshes them; a point of a robot that was
        sinking into a wall survives a teleport straight away from that wall with a large negative distance,
        a phantom collision (the geometry cross-check test caught it). Re-registering each robot with the
        collision world (which is what changing its filter does) discards its cached pairs. Continuous motion,
        at most 1 cm a tick, refreshes the points correctly and needs none of this.
        """
        for body in self.robot_ids:
            p.setCollisionFilterGroupMask(body, -1, ROBOT_FILTER_GROUP, ROBOT_FILTER_MASK, physicsClientId=self.client)

    def move(self, moving: np.ndarray, v: np.ndarray, w: np.ndarray) -> None:
        """Drive the robots in ``moving`` for one decision period (0.05 s) at constant (v, w), exactly.

        :param moving: indices of the robots that act this tick
        :param v: their linear velocities [m/s]
        :param w: their angular velocities [rad/s]
        """
        rows = self.rows_of(moving)
        x, y, theta = integrate_unicycle(self.xy[rows, 0], self.xy[rows, 1], self.theta[rows], v, w, DT)
        self.xy[rows, 0] = x
        self.xy[rows, 1] = y
        self.theta[rows] = theta
        self._push_poses(moving)

    def rows_of(self, indices: np.ndarray) -> np.ndarray | slice:
        """``indices`` (sorted, unique) as an index for numpy; a slice when it is every robot, which numpy
        reads and writes several times faster than a fancy index (the common case: nobody parked yet)."""
        return slice(None) if len(indices) == self.n_robots else indices

    def _push_poses(self, indices: np.ndarray) -> None:
        rows = self.rows_of(indices)
        half = 0.5 * self.theta[rows]
        sines, cosines = np.sin(half).tolist(), np.cos(half).tolist()
        client, bodies = self.client, self.robot_ids
        for i, (x, y), sz, cz in zip(indices.tolist(), self.xy[rows].tolist(), sines, cosines):
            p.resetBasePositionAndOrientation(bodies[i], (x, y, 0.0), (0.0, 0.0, sz, cz), physicsClientId=client)

    # --- sensing -----------------------------------------------------------------------------------------

    def beam_directions(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cosines and sines ``(k, 28)`` of the world-frame beam angles of the robots in ``indices``."""
        angles = self.theta[self.rows_of(indices), None] + BEAM_ANGLES
        return np.cos(angles), np.sin(angles)

    def scan(self, indices: np.ndarray, noise_std: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
        """Lidar ranges of the robots in ``indices``, all beams cast in one ``rayTestBatch``.

        :param indices: robot indices
        :param noise_std: standard deviation of additive Gaussian range noise [m] (0 = exact)
        :param rng: generator for the noise (required when ``noise_std > 0``)
        :return: ``(len(indices), 28)`` ranges in [0.12, 3.5] m; 3.5 where a beam hits nothing
        """
        n_robots = len(indices)
        n_rays = n_robots * N_BEAMS
        if n_rays == 0:
            return np.zeros((0, N_BEAMS))
        cos, sin = self.beam_directions(indices)
        rows = self.rows_of(indices)
        # A preallocated (2, n, 28, 3) buffer of ray starts [0] and ends [1] whose z already holds the scan
        # height: x and y of both are written in one broadcast each.
        rays = self._rays[:, :n_robots]
        rays[..., 0] = self.xy[rows, 0:1] + RAY_REACH * cos
        rays[..., 1] = self.xy[rows, 1:2] + RAY_REACH * sin
        starts, ends = rays[0].reshape(n_rays, 3), rays[1].reshape(n_rays, 3)
        hits = p.rayTestBatch(starts, ends, numThreads=1, physicsClientId=self.client)
        fractions = np.fromiter(map(_hit_fraction, hits), dtype=float, count=n_rays)
        ranges = (RANGE_MAX - RAY_START) * fractions.reshape(n_robots, N_BEAMS) + RAY_START
        if noise_std > 0.0:
            assert rng is not None, "lidar noise needs the env's generator"
            ranges = np.minimum(ranges + rng.normal(0.0, noise_std, size=ranges.shape), RANGE_MAX)
        # Beams start 0.107 m out, so a reading can fall under the LDS-01's 0.12 m only against a body
        # that already touches the robot; it reads the minimum range.
        return np.maximum(ranges, RANGE_MIN)

    # --- collisions --------------------------------------------------------------------------------------

    def map_collisions(self) -> np.ndarray:
        """Which robots penetrate a wall or an obstacle (PyBullet contact query, negative distance).

        :return: ``(n,)`` booleans
        """
        p.performCollisionDetection(physicsClientId=self.client)
        contacts = p.getContactPoints(bodyA=self.map_id, physicsClientId=self.client)
        for block in self._block_ids:
            contacts += p.getContactPoints(bodyA=block, physicsClientId=self.client)
        hit = np.zeros(self.n_robots, dtype=bool)
        touching = [contact[2] for contact in contacts if contact[8] < 0.0]
        if touching:
            hit[self._robot_index[touching]] = True
        return hit

    def robot_collisions(self) -> np.ndarray:
        """Which robots overlap another robot (moving or parked): centre distance below two radii.

        :return: ``(n,)`` booleans
        """
        gaps = self.xy[:, None, :] - self.xy[None, :, :]
        close = (gaps * gaps).sum(axis=2) < (2.0 * ROBOT_RADIUS) ** 2
        np.fill_diagonal(close, False)
        return close.any(axis=1)

    # --- GUI ---------------------------------------------------------------------------------------------

    def _robot_visual(self, index: int) -> int:
        if not self.gui:
            return -1
        rgba = [*(ROBOT_COLOURS[index % len(ROBOT_COLOURS)] / 255.0).tolist(), 1.0]
        wheel_y = WHEEL_SEPARATION / 2.0
        wheel_orn = [np.sin(np.pi / 4), 0.0, 0.0, np.cos(np.pi / 4)]  # wheel axles along y: roll by 90 deg
        return p.createVisualShapeArray(
            shapeTypes=[p.GEOM_CYLINDER, p.GEOM_CYLINDER, p.GEOM_CYLINDER, p.GEOM_BOX],
            radii=[ROBOT_RADIUS, WHEEL_RADIUS, WHEEL_RADIUS, 0.0],
            lengths=[ROBOT_HEIGHT - WHEEL_RADIUS, 0.018, 0.018, 0.0],
            halfExtents=[[0, 0, 0], [0, 0, 0], [0, 0, 0], [0.05, 0.01, 0.005]],
            rgbaColors=[rgba, [0.1, 0.1, 0.1, 1], [0.1, 0.1, 0.1, 1], [1, 1, 1, 1]],
            visualFramePositions=[
                [0, 0, WHEEL_RADIUS + (ROBOT_HEIGHT - WHEEL_RADIUS) / 2],
                [0, wheel_y, WHEEL_RADIUS],
                [0, -wheel_y, WHEEL_RADIUS],
                [0.05, 0, ROBOT_HEIGHT + 0.005],
            ],
            visualFrameOrientations=[[0, 0, 0, 1], wheel_orn, wheel_orn, [0, 0, 0, 1]],
            physicsClientId=self.client,
        )

    def _add_map_visuals(self, blocks: np.ndarray | None = None) -> None:
        """Draw the map's boxes (GUI only), with ``blocks`` beside them in place of the previous call's."""
        rgba = [*(np.array(MAP_COLOUR) / 255.0).tolist(), 1.0]
        for body in self._map_visual_ids:
            p.removeBody(body, physicsClientId=self.client)
        self._map_visual_ids = []
        for cx, cy, hx, hy in self.layout.boxes if blocks is None else np.concatenate([self.layout.boxes, blocks]):
            shape = p.createVisualShape(
                p.GEOM_BOX, halfExtents=[hx, hy, WALL_HEIGHT / 2], rgbaColor=rgba, physicsClientId=self.client
            )
            body = p.createMultiBody(0.0, -1, shape, [cx, cy, WALL_HEIGHT / 2], physicsClientId=self.client)
            self._map_visual_ids.append(body)

    def show_targets(self, targets: np.ndarray) -> None:
        """Draw the targets as coloured markers (GUI only; they have no collision shape).

        :param targets: ``(n, 2)`` target positions
        """
        if not self.gui:
            return
        for body in self._target_ids:
            p.removeBody(body, physicsClientId=self.client)
        self._target_ids = []
        for i, (tx, ty) in enumerate(targets):
            rgba = [*(ROBOT_COLOURS[i % len(ROBOT_COLOURS)] / 255.0).tolist(), 0.6]
            shape = p.createVisualShape(p.GEOM_CYLINDER, radius=0.1, length=0.005, rgbaColor=rgba, physicsClientId=self.client)
            self._target_ids.append(p.createMultiBody(0.0, -1, shape, [tx, ty, 0.003], physicsClientId=self.client))

    # --- lifetime ----------------------------------------------------------------------------------------

    def close(self) -> None:
        """Disconnect from PyBullet; safe to call more than once."""
        if self.client is not None:
            if p.isConnected(physicsClientId=self.client):
                p.disconnect(physicsClientId=self.client)
            self.client = None

    def __del__(self) -> None:
        # A forgotten env must not leak its PyBullet client (each holds a physics server).
        try:
            self.close()
        except Exception:
            pass
