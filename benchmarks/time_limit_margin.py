"""How much of the time limit the slowest robot of an episode needs at best, per team size.

For each of ``--episodes`` seeded resets of ``MultiRobotNav-<n>-v0`` it computes, per robot, the fewest ticks that
reach its target: the turn toward it at the top angular speed (90 deg/s) plus the straight drive at the top linear
speed (0.21 m/s) to within the 0.1 m arrival radius, ignoring every other robot; the episode needs the slowest
robot's. Prints the median and 90th percentile of that need against the time limit. If the need came close to the
limit, time-outs could come from the limit itself rather than from the policy.

    python benchmarks/time_limit_margin.py --robots 2 4 8 12 --episodes 300
"""

from __future__ import annotations

import argparse

import numpy as np

import envs
from envs.turtlebot3.robot import ACTION_ANGULAR, ACTION_LINEAR

TICK_S = 0.05


def slowest_robot_ticks(state: np.ndarray) -> float:
    """:param state: ``(n, 9)`` rows of the world's global state (x, y, cos, sin, ..., target x, target y, arrived)"""
    xy, target = state[:, :2], state[:, 6:8]
    heading = np.arctan2(state[:, 3], state[:, 2])
    distance = np.hypot(*(target - xy).T)
    bearing = np.abs((np.arctan2(*(target - xy).T[::-1]) - heading + np.pi) % (2 * np.pi) - np.pi)
    drive = np.maximum(distance - 0.1, 0.0) / (np.max(ACTION_LINEAR) * TICK_S)
    turn = bearing / (np.max(np.abs(ACTION_ANGULAR)) * TICK_S)
    return float((drive + turn).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robots", type=int, nargs="+", default=[2, 4, 8, 12])
    parser.add_argument("--episodes", type=int, default=300)
    args = parser.parse_args()
    print("| robots | time limit | slowest robot's need, median | 90th percentile | share above 0.8 of the limit |")
    print("|---|---|---|---|---|")
    for n in args.robots:
        env = envs.make_parallel_env(f"MultiRobotNav-{n}-v0")
        needs = []
        for seed in range(args.episodes):
            env.reset(seed=seed)
            needs.append(slowest_robot_ticks(env.state().reshape(n, 9)))
        limit = env.layout.default_time_limit
        env.close()
        need = np.array(needs)
        print(
            f"| {n} | {limit} | {np.median(need):.0f} | {np.percentile(need, 90):.0f} | "
            f"{100 * np.mean(need > 0.8 * limit):.1f} % |"
        )


if __name__ == "__main__":
    main()
