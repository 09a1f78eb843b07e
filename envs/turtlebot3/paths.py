"""Waypoints along the shortest path on a room's static map: the ``path_guidance`` option of the TurtleBot3 worlds.

A robot that sees 1 m of lidar and only its target's distance and bearing cannot tell which way round an inner wall
leads to a target behind it: in generated rooms such robots loop or crash (``docs/results/navigator.md``). With
guidance the world does what a robot's global planner does on a known map (the global / local split of the ROS
navigation stack; PRM-RL, Faust et al., ICRA 2018, arXiv 1710.03937): it plans on the static map (walls, inner walls,
blocks; never the robots, which the lidar policy avoids) and gives the policy a waypoint about ``lookahead`` metres
ahead on that path instead of the target, and the path length to go instead of the straight distance. The
observation keeps its layout and meaning (a distance and a bearing to head for), so a policy, its export and the ONNX
runner are unchanged; on a robot, a planner must feed the waypoints.

How (:class:`PathGuide`): the room is rasterised on a grid of ``resolution`` metres; a cell is blocked when its
centre lies within ``clearance`` of a static box (the robot's radius plus a margin); Dijkstra over the free cells
(16 neighbours) from every robot's target gives each cell its path length to go; a robot's path length is the least
of ``length(cell) + |position - cell centre|`` over the free cells of the 5 x 5 window around it (continuous in the
position, so the progress reward does not jump from cell to cell), and its waypoint is reached by following the
steepest descent of the lengths ``lookahead / resolution`` cells from there (the target itself once the path left
is shorter). A robot whose window has no free cell (it grazes a wall) uses the nearest free cell; a target the grid
cannot reach (never seen in the generated rooms) falls back to the straight line. With ``parked`` robots (the worlds'
``path_replan`` option), the map also holds the robots that stand on their targets, as a costmap's obstacle layer
marks what the lidar sees standing still.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from envs.turtlebot3.layouts import Layout
from envs.turtlebot3.robot import ROBOT_RADIUS

RESOLUTION = 0.075  # [m] grid cell (34 ms a plan for 8 robots; no target of 60 training rooms unreachable at 5, 7.5 or 10 cm)
CLEARANCE = ROBOT_RADIUS + 0.045  # [m] a path keeps this far from every static box (the robot's body plus 4.5 cm)
LOOKAHEAD = 1.0  # [m] how far ahead on the path the waypoint lies (the 1 m view's reach)
CLEARANCE_MAX = 0.35  # [m] a wider clearance closes the narrowest doorways (0.7 m) on the grid
LOOKAHEAD_MAX = 3.0  # [m]
_WINDOW = np.array([(di, dj) for di in range(-2, 3) for dj in range(-2, 3)])  # the 5 x 5 cells around a position
# 16 neighbours (the 8 around and the knight's moves): grid paths then run within 3 % of the straight line in every
# direction (8 neighbours: up to 8 %). No blocked band is thinner than two cells, so no move jumps a wall.
_BACK = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (-2, -1), (-2, 1), (-1, -2), (-1, 2)]
_NEIGHBOURS = np.array([*_BACK, *((-di, -dj) for di, dj in _BACK)])  # the second half: each undirected edge once


class PathGuide:
    """Path lengths to go and waypoints for one episode's targets on one room's static map.

    :param layout: the room (its walls and obstacles are the static map)
    :param targets: ``(n, 2)`` the robots' targets
    :param resolution: grid cell [m]
    :param clearance: distance [m] the path keeps from every static box
    :param lookahead: how far ahead on the path the waypoint lies [m]
    :param parked: ``(p, 2)`` centres of robots standing still (parked on their targets), blocked like the boxes
    """

    def __init__(
        self,
        layout: Layout,
        targets: np.ndarray,
        resolution: float = RESOLUTION,
        clearance: float = CLEARANCE,
        lookahead: float = LOOKAHEAD,
        parked: np.ndarray | None = None,
    ) -> None:
        self.resolution = float(resolution)
        self.lookahead = float(lookahead)
        self.targets = np.asarray(targets, dtype=float).reshape(-1, 2)
        half = layout.half_extent
        self.origin = -half  # the lower left corner of cell (0, 0)
        self.shape = (int(np.ceil(2 * half[0] / resolution)), int(np.ceil(2 * half[1] / resolution)))
        xs = self.origin[0] + (np.arange(self.shape[0]) + 0.5) * resolution
        ys = self.origin[1] + (np.arange(self.shape[1]) + 0.5) * resolution
        self.centres = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1)  # (nx, ny, 2)
        blocked = np.zeros(self.shape, dtype=bool)
        for cx, cy, hx, hy in layout.boxes:
            dx = np.maximum(np.abs(xs - cx) - hx, 0.0)[:, None]
            dy = np.maximum(np.abs(ys - cy) - hy, 0.0)[None, :]
            blocked |= dx * dx + dy * dy < clearance * clearance
        reach = ROBOT_RADIUS + clearance  # a parked robot's footprint, grown as the boxes are
        for px, py in np.zeros((0, 2)) if parked is None else np.asarray(parked, dtype=float).reshape(-1, 2):
            blocked |= (xs[:, None] - px) ** 2 + (ys[None, :] - py) ** 2 < reach * reach
        self.free = ~blocked
        # The nearest free cell of every cell (itself when free), for positions that graze a wall.
        _, nearest = ndimage.distance_transform_edt(blocked, return_indices=True)
        self.nearest_free = np.ravel_multi_index((nearest[0], nearest[1]), self.shape)
        self.lengths = self._path_lengths()  # (n, cells): path length to go from each cell to each target
        self.next_cell = self._steepest_descent()  # (n, cells)

    def _cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.floor((xy - self.origin) / self.resolution).astype(int)
        return np.clip(ij[:, 0], 0, self.shape[0] - 1), np.clip(ij[:, 1], 0, self.shape[1] - 1)

    def _path_lengths(self) -> np.ndarray:
        nx, ny = self.shape
        index = np.arange(nx * ny).reshape(self.shape)
        rows, cols, weights = [], [], []
        for di, dj in _NEIGHBOURS[8:]:  # each undirected edge once
            x0, x1, y0, y1 = max(0, -di), nx - max(0, di), max(0, -dj), ny - max(0, dj)
            a, b = index[x0:x1, y0:y1], index[x0 + di : x1 + di, y0 + dj : y1 + dj]
            keep = self.free.ravel()[a.ravel()] & self.free.ravel()[b.ravel()]
            rows.append(a.ravel()[keep])
            cols.append(b.ravel()[keep])
            weights.append(np.full(int(keep.sum()), self.resolution * float(np.hypot(di, dj))))
        graph = sparse.coo_matrix(
            (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(nx * ny, nx * ny)
        ).tocsr()
        ti, tj = self._cell(self.targets)
        sources = self.nearest_free[ti, tj]
        lengths = csgraph.dijkstra(graph, directed=False, indices=sources)
        # From a target's cell to the target itself.
        lengths += np.linalg.norm(self.centres.reshape(-1, 2)[sources] - self.targets, axis=1)[:, None]
        return lengths

    def _steepest_descent(self) -> np.ndarray:
        nx, ny = self.shape
        padded = np.full((len(self.targets), nx + 4, ny + 4), np.inf)
        padded[:, 2:-2, 2:-2] = self.lengths.reshape(-1, nx, ny)
        index = np.pad(np.arange(nx * ny).reshape(self.shape), 2, constant_values=0)
        best = self.lengths.reshape(-1, nx, ny).copy()
        best_cell = np.broadcast_to(np.arange(nx * ny).reshape(self.shape), best.shape).copy()
        for di, dj in _NEIGHBOURS:
            candidate = padded[:, 2 + di : nx + 2 + di, 2 + dj : ny + 2 + dj]
            better = candidate < best
            best = np.where(better, candidate, best)
            best_cell = np.where(better, index[2 + di : nx + 2 + di, 2 + dj : ny + 2 + dj][None], best_cell)
        return best_cell.reshape(len(self.targets), -1)

    def query(self, xy: np.ndarray, robots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:param xy: ``(k, 2)`` robot positions
        :param robots: ``(k,)`` whose targets they drive to (row of :attr:`targets`)
        :return: the path lengths to go ``(k,)`` and the waypoints ``(k, 2)``"""
        length, cell = self.locate(xy, robots)
        return length, self.waypoints(xy, robots, length, cell)

    def locate(self, xy: np.ndarray, robots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The path lengths alone (what the reward needs every tick; :meth:`waypoints` only when a robot observes).

        :param xy: ``(k, 2)`` robot positions
        :param robots: ``(k,)`` whose targets they drive to (row of :attr:`targets`)
        :return: the path lengths to go ``(k,)`` (the straight distance where the grid cannot reach the target) and
            the free cells ``(k,)`` they are measured from"""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        robots = np.asarray(robots, dtype=int)
        i, j = self._cell(xy)
        wi = np.clip(i[:, None] + _WINDOW[None, :, 0], 0, self.shape[0] - 1)
        wj = np.clip(j[:, None] + _WINDOW[None, :, 1], 0, self.shape[1] - 1)
        cells = np.ravel_multi_index((wi, wj), self.shape)  # (k, 25)
        free = self.free.ravel()[cells]
        centres = self.centres.reshape(-1, 2)[cells]
        lengths = self.lengths[robots[:, None], cells] + np.linalg.norm(centres - xy[:, None, :], axis=2)
        lengths = np.where(free, lengths, np.inf)
        pick = np.argmin(lengths, axis=1)
        cell = cells[np.arange(len(xy)), pick]
        length = lengths[np.arange(len(xy)), pick]
        grazing = ~np.isfinite(length)  # no free cell around: the nearest free one
        if grazing.any():
            near = self.nearest_free[i[grazing], j[grazing]]
            cell[grazing] = near
            length[grazing] = self.lengths[robots[grazing], near] + np.linalg.norm(
                self.centres.reshape(-1, 2)[near] - xy[grazing], axis=1
            )
        unreachable = ~np.isfinite(length)  # the grid cannot reach the target: the straight line
        length[unreachable] = np.linalg.norm(self.targets[robots[unreachable]] - xy[unreachable], axis=1)
        return length, cell

    def waypoints(self, xy: np.ndarray, robots: np.ndarray, length: np.ndarray, cell: np.ndarray) -> np.ndarray:
        """:param xy: ``(k, 2)`` robot positions
        :param robots: ``(k,)`` whose targets they drive to
        :param length: ``(k,)`` and ``cell``: what :meth:`locate` returned for them
        :return: the waypoints ``(k, 2)``: ``lookahead`` down the path, the target once less is left (or where the grid
            cannot reach it)"""
        robots = np.asarray(robots, dtype=int)
        goal = length - self.lookahead  # walk down the path until this much of it is left
        for _ in range(round(self.lookahead / self.resolution) + 1):
            cell = np.where(self.lengths[robots, cell] > goal, self.next_cell[robots, cell], cell)
        target = self.targets[robots]
        straight = (length <= self.lookahead) | ~np.isfinite(self.lengths[robots, cell])
        return np.where(straight[:, None], target, self.centres.reshape(-1, 2)[cell])
