"""Single-agent Cooperative Navigation (``CooperativeNavigationSingle-v0``): the EPS world of the MPE benchmark.

EPS (Marchesini & Farinelli, ICRA 2022) evaluates mutated copies of the multi-agent policy in a world with one
agent, where the navigation skill can be improved without teammates moving around. This env keeps everything the
policy sees identical to ``CooperativeNavigation-v0`` so that a policy moves between the two unchanged: the same
mpe2 world and physics (``simple_spread`` scenario, 0.1 s ticks, damping, contact forces), the same 18-float
observation layout for N=3 and the same Discrete(5) actions.

How the absent teammates are encoded: the world still holds the N-1 other agents, but they are **parked**
(immovable, silent) exactly on N-1 of the landmarks, chosen at random each episode; the remaining landmark is the
learner's. The observation is therefore mpe2's observation of agent 0 with no special values:
``[own velocity (2), own position (2), landmark i - own position (2 N), parked teammate j - own position
(2 (N-1)), communication (2 (N-1), always 0)]``. This is exactly the last stretch of a good multi-agent episode
(teammates sitting on their landmarks, one landmark left to cover), so what is learnt here transfers; a fixed
"far away" or zero encoding would put the policy off the multi-agent observation distribution instead.

The parked teammates collide like in the multi-agent world: the learner bounces off them and is penalised, so
they play the part of the static obstacles of the robots' EPS world.

Reward per tick: ``(1 - local_ratio) * (-d) + local_ratio * (-c)`` with ``d`` the learner's distance to its
landmark and ``c`` the number of parked teammates it overlaps. With the teammates on their landmarks this is the
multi-agent reward of the same configuration (mpe2's global term is minus the sum of the landmarks' distances to
their nearest agent), so returns are on the multi-agent scale.

Episodes are truncated after ``max_cycles`` ticks; ``info["team"]`` has the same keys as in the multi-agent env,
computed as if the parked teammates were the rest of the team; ``info["is_success"]`` on the last tick.

Version history:

- v0: first version (mpe2 1.1 ``simple_spread_v3`` world).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from mpe2 import simple_spread_v3

from envs.mpe._common import CAPTURE_RADIUS, N_ACTIONS, RENDER_MODES, team_metrics
from envs.seeding import check_seed

# mpe2's discrete action -> unit force direction (no_action, left, right, down, up), scaled by the
# sensitivity mpe2 uses for agents without their own ``accel``.
_MOVES = np.array([[0.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
_SENSITIVITY = 5.0
# Parked teammates are drawn lighter than the learner.
_PARKED_COLOR = np.array([0.65, 0.65, 0.85])
# Rejection sampling of the learner's start (it must not overlap a parked teammate) gives up after this many
# draws; with 2 parked discs of radius 0.3 in a 2 x 2 square one draw succeeds with probability > 0.8.
_MAX_START_DRAWS = 1000


class CooperativeNavigationSingleEnv(gymnasium.Env):
    """Gymnasium env: one agent navigates to its landmark among parked teammates (see the module docstring).

    :param n_agents: team size whose observation layout is reproduced (N landmarks, N-1 parked teammates)
    :param local_ratio: weight of the collision penalty, as in the multi-agent env
    :param max_cycles: ticks per episode; the episode is truncated after them
    :param render_mode: None, ``"rgb_array"`` or ``"human"`` (mpe2's pygame drawing)
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": 10}

    def __init__(
        self,
        n_agents: int = 3,
        local_ratio: float = 0.5,
        max_cycles: int = 25,
        render_mode: str | None = None,
    ) -> None:
        if isinstance(n_agents, bool) or not isinstance(n_agents, int) or n_agents < 2:
            raise ValueError(f"n_agents must be an int >= 2, got {n_agents!r}")
        if not 0.0 <= local_ratio <= 1.0:
            raise ValueError(f"local_ratio must lie in [0, 1], got {local_ratio!r}")
        if isinstance(max_cycles, bool) or not isinstance(max_cycles, int) or max_cycles < 1:
            raise ValueError(f"max_cycles must be an int >= 1, got {max_cycles!r}")
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be None or one of {RENDER_MODES}, got {render_mode!r}")
        # The mpe2 env supplies the world, the scenario's observation function and the renderer; its own AEC
        # stepping is not used (it would step the parked teammates as agents).
        self._sim = simple_spread_v3.raw_env(
            N=n_agents, local_ratio=local_ratio, max_cycles=max_cycles, render_mode=render_mode
        )
        self._world = self._sim.world
        self._agent = self._world.agents[0]
        self._teammates = self._world.agents[1:]
        for mate in self._teammates:
            mate.movable = False
        self.n_agents = n_agents
        self.local_ratio = local_ratio
        self.max_cycles = max_cycles
        self.render_mode = render_mode
        obs_dim = 6 * n_agents
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self._target = 0
        self._ticks = 0
        self._team_return = 0.0
        self._n_collisions = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode: new landmarks, teammates parked on all but the learner's, a free start.

        :param seed: reseeds ``self.np_random`` when given (non-negative int)
        :param options: ignored
        :return: the observation and ``{"team": ...}``
        """
        super().reset(seed=check_seed(seed))
        self._sim.scenario.reset_world(self._world, self.np_random)
        landmarks = self._world.landmarks
        self._target = int(self.np_random.integers(len(landmarks)))
        others = [lm for i, lm in enumerate(landmarks) if i != self._target]
        for mate, landmark in zip(self._teammates, others):
            mate.state.p_pos = landmark.state.p_pos.copy()
            mate.color = _PARKED_COLOR
        for _ in range(_MAX_START_DRAWS):
            if self._n_overlaps() == 0:
                break
            self._agent.state.p_pos = self.np_random.uniform(-1, 1, self._world.dim_p)
        for agent in self._world.agents:
            agent.action.u = np.zeros(self._world.dim_p)
            agent.action.c = np.zeros(self._world.dim_c)
        # mpe2's renderer scales the picture by the extent of the first frame.
        self._sim.original_cam_range = np.max(np.abs([e.state.p_pos for e in self._world.entities]))
        self._ticks = 0
        self._team_return = 0.0
        self._n_collisions = 0
        return self._observation(), {"team": self._metrics(self._distance())}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply one Discrete(5) action for one tick.

        :param action: 0 no-op, 1 left, 2 right, 3 down, 4 up
        :return: observation, reward, terminated (always False), truncated (after ``max_cycles``), info
        """
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is outside the action space {self.action_space}")
        self._agent.action.u = _MOVES[int(action)] * _SENSITIVITY
        self._world.step()
        self._ticks += 1
        distance = self._distance()
        n_overlaps = self._n_overlaps()
        reward = (1.0 - self.local_ratio) * -distance + self.local_ratio * -float(n_overlaps)
        self._n_collisions += n_overlaps
        self._team_return += reward
        truncated = self._ticks >= self.max_cycles
        info: dict[str, Any] = {"team": self._metrics(distance)}
        if truncated:
            info["is_success"] = info["team"]["success"]
        if self.render_mode == "human":
            self.render()
        return self._observation(), reward, False, truncated, info

    def render(self) -> np.ndarray | None:
        """Draw the world with mpe2's renderer (an RGB array in ``"rgb_array"`` mode)."""
        return self._sim.render()

    def close(self) -> None:
        """Release the renderer."""
        self._sim.close()

    def _observation(self) -> np.ndarray:
        return self._sim.scenario.observation(self._agent, self._world).astype(np.float32)

    def _distance(self) -> float:
        target = self._world.landmarks[self._target]
        return math.dist(self._agent.state.p_pos.tolist(), target.state.p_pos.tolist())

    def _n_overlaps(self) -> int:
        # mpe2's is_collision: centre distance < sum of the sizes.
        position = self._agent.state.p_pos.tolist()
        return sum(math.dist(position, mate.state.p_pos.tolist()) < self._agent.size + mate.size for mate in self._teammates)

    def _metrics(self, distance: float) -> dict[str, Any]:
        # The parked teammates sit on their landmarks: they count as occupied, at distance 0.
        n_landmarks = len(self._world.landmarks)
        return team_metrics(
            n_landmarks=n_landmarks,
            min_dist_sum=distance,
            occupied_landmarks=n_landmarks - 1 + int(distance < CAPTURE_RADIUS),
            n_collisions=self._n_collisions,
            team_return=self._team_return,
            ticks=self._ticks,
        )
