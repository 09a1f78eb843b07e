"""The safety layer on the lidar (``research/lidar_shield.py``, rule N13): the arcs it checks, and a robot driven
straight at a wall by its policy that stops short of it with the layer and hits it without."""

from __future__ import annotations

import numpy as np
import torch as th

from envs.turtlebot3.multi_robot_nav import MultiRobotNavEnv
from envs.turtlebot3.robot import N_ACTIONS, N_BEAMS, ROBOT_RADIUS
from research.lidar_shield import LidarShield, sweep

FULL_AHEAD, STAND_STILL = 17, 2


class AlwaysAhead:
    """A policy that ranks full speed straight ahead first and standing still last (the model under the layer)."""

    device = th.device("cpu")

    class _Net:
        def advantage(self, obs: th.Tensor) -> th.Tensor:
            scores = th.zeros((len(obs), N_ACTIONS))
            scores[:, FULL_AHEAD] = 1.0
            scores[:, STAND_STILL] = -1.0
            return scores

    class policy:  # lower case: the attribute name of an SB3 model
        @staticmethod
        def greedy_net() -> AlwaysAhead._Net:
            return AlwaysAhead._Net()

    def predict(self, observation: np.ndarray, state=None, episode_start=None, deterministic: bool = True):
        return np.full(len(observation), FULL_AHEAD), state


def test_the_arcs_follow_the_commands() -> None:
    path = sweep(action_repeat=4, horizon=2)
    assert path.shape == (N_ACTIONS, 16, 2)
    np.testing.assert_allclose(path[FULL_AHEAD, -1], [0.21 * 0.4, 0.0], atol=1e-9)  # 0.21 m/s for 2 x 0.2 s
    np.testing.assert_allclose(path[STAND_STILL], 0.0)
    assert path[19, -1, 1] > 0 > path[15, -1, 1]  # turning left ends left of the line, turning right to its right


def test_an_obstacle_ahead_blocks_only_the_actions_that_reach_it() -> None:
    shield = LidarShield(AlwaysAhead(), lidar_range=1.0, action_repeat=4, margin=0.03)
    clear = np.ones((1, N_BEAMS + 2), dtype=np.float32)
    assert shield.predict(clear)[0][0] == FULL_AHEAD  # nothing in view: the policy's action
    near = clear.copy()
    near[0, N_BEAMS // 2 - 1 : N_BEAMS // 2 + 1] = ROBOT_RADIUS + 0.06  # a post 6 cm past the body, straight ahead
    clearance = shield.clearance(near)[0]
    assert clearance[STAND_STILL] > 0.03 > clearance[FULL_AHEAD]
    action = shield.predict(near)[0][0]
    assert action != FULL_AHEAD and clearance[action] > 0.03
    assert shield.n_changed == 1 and shield.n_decisions == 2


def test_a_robot_driven_at_a_wall_stops_short_of_it_with_the_layer_and_hits_it_without() -> None:
    def drive(policy) -> tuple[bool, float]:
        world = MultiRobotNavEnv(n_robots=1, action_repeat=4, lidar_range=1.0)
        # Facing the east wall (x = 1.625) from 0.6 m, the target behind the robot: ahead is only the wall.
        obs, _ = world.reset(seed=0, options={"start_poses": np.array([[1.0, 0.0, 0.0]]), "targets": np.array([[-1.0, 0.0]])})
        collided = False
        for _ in range(40):  # 8 s: at 0.21 m/s the robot would reach the wall in under 3 s
            actions, _ = policy.predict(np.stack([obs[a] for a in world.agents]))
            obs, _, terminations, _, infos = world.step(dict(zip(world.agents, actions.tolist())))
            collided = infos["robot_0"]["collided"]
            if any(terminations.values()):
                break
        x = float(world.world.xy[0, 0])
        world.close()
        return collided, x

    assert drive(AlwaysAhead())[0]
    collided, x = drive(LidarShield(AlwaysAhead(), lidar_range=1.0, action_repeat=4, margin=0.03))
    assert not collided and x > 1.0 + 0.3  # it drove most of the way, then stopped short of the wall
