"""A small numpy rasteriser for top-down pictures of the worlds, and GIF writing.

The static map is drawn once and copied, discs are cached stamps: a 480 px frame of 4 robots costs about
0.4 ms (3.5 ms with the 112 lidar beams), so recording every tick of an evaluation episode is affordable;
PyBullet's ``getCameraImage`` in DIRECT mode would run its software renderer instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from envs.turtlebot3.layouts import WALL_THICKNESS, Layout
from envs.turtlebot3.robot import ROBOT_RADIUS, TARGET_RADIUS
from envs.turtlebot3.world import MAP_COLOUR, ROBOT_COLOURS

FLOOR_COLOUR = (245, 245, 240)
OUTSIDE_COLOUR = (255, 255, 255)  # the canvas beyond a room smaller than the picture
GRID_COLOUR = (215, 215, 210)  # one line per metre
OUTLINE_COLOUR = (20, 20, 20)
MARGIN = 0.05  # [m] of floor drawn beyond the outer walls


class Rasteriser:
    """Draws one layout from above; y points up in the picture.

    :param layout: the room
    :param max_side_px: size in pixels of the picture's longer side
    :param half_extent: the interior half size the picture covers, at least the room's (a world whose rooms change
        draws them all on the canvas of its largest); None: the room's own
    """

    def __init__(self, layout: Layout, max_side_px: int = 480, half_extent: np.ndarray | None = None) -> None:
        canvas = layout.half_extent if half_extent is None else np.maximum(half_extent, layout.half_extent)
        self.extent = canvas + WALL_THICKNESS + MARGIN
        self._smaller_room = bool(np.any(canvas > layout.half_extent))
        self.scale = max_side_px / (2.0 * self.extent.max())  # pixels per metre
        self.width = round(2.0 * self.extent[0] * self.scale)
        self.height = round(2.0 * self.extent[1] * self.scale)
        self.background = self._draw_map(layout)
        self._stamps: dict[tuple[float, float], np.ndarray] = {}

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """World coordinates ``(..., 2)`` [m] to pixel coordinates ``(..., 2)`` as (column, row) floats."""
        col = (xy[..., 0] + self.extent[0]) * self.scale
        row = (self.extent[1] - xy[..., 1]) * self.scale
        return np.stack([col, row], axis=-1)

    def _draw_map(self, layout: Layout) -> np.ndarray:
        image = np.empty((self.height, self.width, 3), dtype=np.uint8)
        image[:] = FLOOR_COLOUR
        for metre in np.arange(-np.floor(self.extent.max()), np.floor(self.extent.max()) + 1):
            col, row = self.to_pixels(np.array([metre, metre]))
            if 0 <= col < self.width:
                image[:, int(col)] = GRID_COLOUR
            if 0 <= row < self.height:
                image[int(row), :] = GRID_COLOUR
        if self._smaller_room:  # nothing beyond the outer walls
            corners = np.array([[-1.0, 1.0], [1.0, -1.0]]) * (layout.half_extent + WALL_THICKNESS)
            (c0, r0), (c1, r1) = np.round(self.to_pixels(corners)).astype(int)
            image[:, :c0] = image[:, c1:] = OUTSIDE_COLOUR
            image[:r0] = image[r1:] = OUTSIDE_COLOUR
        for cx, cy, hx, hy in layout.boxes:
            (c0, r0), (c1, r1) = self.to_pixels(np.array([[cx - hx, cy + hy], [cx + hx, cy - hy]]))
            image[max(round(r0), 0) : round(r1), max(round(c0), 0) : round(c1)] = MAP_COLOUR
        return image

    def _stamp(self, radius: float, inner: float) -> np.ndarray:
        """Boolean mask of a disc (an annulus if ``inner > 0``) centred on a pixel, cached per size."""
        key = (radius, inner)
        if key not in self._stamps:
            half = int(np.ceil(radius * self.scale))
            offsets = np.arange(-half, half + 1)
            dist2 = offsets[:, None] ** 2 + offsets[None, :] ** 2
            r_px, inner_px = radius * self.scale, inner * self.scale
            self._stamps[key] = (dist2 <= r_px**2) & (dist2 >= inner_px**2)
        return self._stamps[key]

    def _disc(self, image: np.ndarray, col: int, row: int, stamp: np.ndarray, colour: Sequence[int]) -> None:
        """Paint ``stamp`` (see :meth:`_stamp`) centred on pixel (``col``, ``row``)."""
        half = stamp.shape[0] // 2
        r0, c0 = row - half, col - half
        # Clip the stamp where it leaves the picture.
        top, left = max(-r0, 0), max(-c0, 0)
        bottom = min(stamp.shape[0], self.height - r0)
        right = min(stamp.shape[1], self.width - c0)
        if top >= bottom or left >= right:
            return
        window = image[r0 + top : r0 + bottom, c0 + left : c0 + right]
        window[stamp[top:bottom, left:right]] = colour

    def _segments(self, image: np.ndarray, starts: np.ndarray, ends: np.ndarray, colours: np.ndarray) -> None:
        """Draw 1-pixel segments, all at once: about one sample per pixel along each, then colour the pixels."""
        if len(starts) == 0:
            return
        p0, p1 = self.to_pixels(starts), self.to_pixels(ends)
        n_samples = np.ceil(np.abs(p1 - p0).max(axis=1)).astype(int) + 1
        segment = np.repeat(np.arange(len(starts)), n_samples)
        first = np.cumsum(n_samples) - n_samples
        t = (np.arange(segment.size) - first[segment]) / np.maximum(n_samples[segment] - 1, 1)
        points = (p0[segment] + t[:, None] * (p1 - p0)[segment]).astype(int)
        cols = np.clip(points[:, 0], 0, self.width - 1)
        rows = np.clip(points[:, 1], 0, self.height - 1)
        image[rows, cols] = colours[segment]

    def draw(
        self,
        xy: np.ndarray,
        theta: np.ndarray,
        targets: np.ndarray,
        parked: np.ndarray,
        beams: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Draw one frame.

        :param xy: ``(n, 2)`` robot positions
        :param theta: ``(n,)`` robot headings
        :param targets: ``(n, 2)`` targets
        :param parked: ``(n,)`` booleans, robots parked on their target (drawn with a white centre)
        :param beams: optional lidar beams as (starts ``(m, 2)``, ends ``(m, 2)``, robot index ``(m,)``)
        :return: ``(H, W, 3)`` uint8 picture
        """
        image = self.background.copy()
        colours = ROBOT_COLOURS[np.arange(len(xy)) % len(ROBOT_COLOURS)]
        if beams is not None:
            starts, ends, owner = beams
            # Beams in a paler shade of their robot's colour, under everything else.
            pale = (0.45 * colours[owner] + 0.55 * 255).astype(np.uint8)
            self._segments(image, starts, ends, pale)
        ring = self._stamp(TARGET_RADIUS, TARGET_RADIUS - 0.025)
        dot = self._stamp(0.025, 0.0)
        body = self._stamp(ROBOT_RADIUS - 0.015, 0.0)
        outline = self._stamp(ROBOT_RADIUS, 0.0)
        parked_mark = self._stamp(0.04, 0.0)
        white = np.full((len(xy), 3), 255, dtype=np.uint8)
        for i, (col, row) in enumerate(np.rint(self.to_pixels(targets)).astype(int).tolist()):
            # The ring is the 0.1 m arrival zone; the dot marks the exact target.
            self._disc(image, col, row, ring, colours[i])
            self._disc(image, col, row, dot, colours[i])
        for i, (col, row) in enumerate(np.rint(self.to_pixels(xy)).astype(int).tolist()):
            self._disc(image, col, row, outline, OUTLINE_COLOUR)
            self._disc(image, col, row, body, colours[i])
            if parked[i]:
                self._disc(image, col, row, parked_mark, white[i])
        heading = np.stack([np.cos(theta), np.sin(theta)], axis=1)
        nose = xy + 0.9 * ROBOT_RADIUS * heading
        self._segments(image, xy, nose, white)
        return image


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float = 20) -> Path:
    """Write ``rgb_array`` frames to an animated GIF that loops forever.

    :param frames: ``(H, W, 3)`` uint8 pictures, all of one size
    :param path: file to write (parent folders are created)
    :param fps: frames per second (the worlds decide at 20 Hz, so 20 plays in real time)
    :return: the path written
    """
    if len(frames) == 0:
        raise ValueError("save_gif needs at least one frame.")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}.")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The Pillow GIF writer takes the frame duration in milliseconds.
    imageio.mimsave(path, [np.asarray(frame, dtype=np.uint8) for frame in frames], duration=1000.0 / fps, loop=0)
    return path
