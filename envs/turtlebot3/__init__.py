"""TurtleBot3 Burger navigation worlds in PyBullet (Marchesini & Farinelli, ICRA 2022, Sec. IV-B).

- :class:`MultiRobotNavEnv`: PettingZoo ``ParallelEnv``, n robots; scenarios ``"arena"`` (training),
  ``"blocks"`` (random blocks), ``"rooms"`` (rooms from level seeds, with training, validation and test levels:
  :mod:`envs.turtlebot3.rooms`), ``"eps"`` (walls plus bars), ``"eps_pillars"`` (an EPS world closer to training) and
  ``"unseen"`` (evaluation room with a fixed target sequence; ``placement_jitter`` varies its poses).
- :class:`SingleRobotNavEnv`: gymnasium ``Env``, one robot in the EPS world with static obstacles.
- :func:`save_gif`: write ``rgb_array`` frames to an animated GIF.

Reference: ``docs/envs.md``.
"""

from envs.turtlebot3.multi_robot_nav import MultiRobotNavEnv
from envs.turtlebot3.render import save_gif
from envs.turtlebot3.single_robot_nav import SingleRobotNavEnv

__all__ = ["MultiRobotNavEnv", "SingleRobotNavEnv", "save_gif"]
