"""Regenerate the pictures of ``docs/envs.md``: ``python -m envs.turtlebot3.pictures [out_dir]``."""

from __future__ import annotations

import sys
from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from envs.turtlebot3.multi_robot_nav import MultiRobotNavEnv
from envs.turtlebot3.single_robot_nav import SingleRobotNavEnv

FORWARD = 17  # 0.21 m/s straight ahead


def _picture(frame: np.ndarray | None) -> np.ndarray:
    assert frame is not None, "an rgb_array env returns a picture"
    return frame


def run(out_dir: str | Path = "docs/images", n_forward_ticks: int = 15) -> list[Path]:
    """Draw the 4-robot arena (with lidar), the EPS world, the unseen room, two rooms of the 4-robot blocks
    scenario and generated rooms (:func:`rooms_picture`), and save them as PNG.

    :param out_dir: folder for ``multi_robot_4.png``, ``single_robot.png``, ``unseen_4.png``, ``blocks_4.png`` and
        ``rooms.png``
    :param n_forward_ticks: ticks the arena robots drive straight before the picture
    :return: the files written
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []

    arena = MultiRobotNavEnv(4, render_mode="rgb_array", render_lidar=True)
    arena.reset(seed=3)
    for _ in range(n_forward_ticks):
        if arena.agents:
            arena.step(dict.fromkeys(arena.agents, FORWARD))
    written.append(out / "multi_robot_4.png")
    imageio.imwrite(written[-1], _picture(arena.render()))
    arena.close()

    single = SingleRobotNavEnv(render_mode="rgb_array", render_lidar=True)
    single.reset(seed=1)
    written.append(out / "single_robot.png")
    imageio.imwrite(written[-1], _picture(single.render()))
    single.close()

    unseen = MultiRobotNavEnv(4, scenario="unseen", render_mode="rgb_array")
    unseen.reset(seed=0)
    written.append(out / "unseen_4.png")
    imageio.imwrite(written[-1], _picture(unseen.render()))
    unseen.close()

    blocks = MultiRobotNavEnv(4, scenario="blocks", render_mode="rgb_array", render_lidar=True)
    rooms = []
    for seed in (0, 1):
        blocks.reset(seed=seed)
        rooms.append(_picture(blocks.render()))
    written.append(out / "blocks_4.png")
    gap = np.full((rooms[0].shape[0], 8, 3), 255, dtype=np.uint8)
    imageio.imwrite(written[-1], np.concatenate([rooms[0], gap, rooms[1]], axis=1))
    blocks.close()
    written.append(rooms_picture(out / "rooms.png"))
    return written


# (team size, training level) of each generated room in rooms.png, row by row; None: the open arena, for scale.
ROOMS_PICTURE = (((4, 0), (4, 3), (4, 4), (4, 2)), ((8, 2), (12, 0), (24, 0), (24, None)))


def rooms_picture(path: str | Path, shrink: int = 2) -> Path:
    """A grid of generated rooms (:data:`ROOMS_PICTURE`: training levels only), robots at their starts, targets as
    rings, every picture at half size; the last is the 24-robot arena.

    :param path: the PNG to write
    :param shrink: keep one pixel in ``shrink`` along each axis
    :return: ``path``
    """
    rows = []
    for row in ROOMS_PICTURE:
        pictures = []
        for n_robots, level in row:
            if level is None:
                env = MultiRobotNavEnv(n_robots, render_mode="rgb_array")
                env.reset(seed=0)
            else:
                env = MultiRobotNavEnv(n_robots, scenario="rooms", level=level, render_mode="rgb_array")
                env.reset()
            pictures.append(_picture(env.render())[::shrink, ::shrink])
            env.close()
        gap = np.full((pictures[0].shape[0], 8, 3), 255, dtype=np.uint8)
        rows.append(np.concatenate([part for picture in pictures for part in (picture, gap)][:-1], axis=1))
    band = np.full((8, rows[0].shape[1], 3), 255, dtype=np.uint8)
    imageio.imwrite(path, np.concatenate([rows[0], band, rows[1]], axis=0))
    return Path(path)


if __name__ == "__main__":
    for path in run(sys.argv[1] if len(sys.argv) > 1 else "docs/images"):
        print(path)
