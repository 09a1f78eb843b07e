"""Reference controllers of ``CooperativeNavigation-v0``, the yardsticks of Table I (``docs/results/mpe.md``).

Each has the ``predict(observations, deterministic=True)`` of a trained model over a batch of agent observations
``(n, 18)`` (mpe2's layout, ``docs/envs_mpe.md``), so ``sb3_eps.evaluate_team`` plays it as it plays a model:

- :class:`HandController`: every agent, from its own observation alone, assigns the team to the landmarks by the
  cheapest permutation (sum of agent-landmark distances), then brakes onto its landmark;
- :class:`RandomController`: uniform actions from a seeded generator;
- :class:`NoOpController`: action 0 always (the agents stay where they spawned).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from envs.mpe._common import N_ACTIONS

# mpe2's discrete actions along x then y: (negative, positive) = (left, right), (down, up).
_AXIS_ACTIONS = np.array([[1, 2], [3, 4]])


class HandController:
    """Assign each agent a landmark by the cheapest permutation, then brake onto it (decentralised: the relative
    positions in one agent's observation are enough, and every agent finds the same assignment).

    :param n_agents: agents and landmarks of the world (3 in ``CooperativeNavigation-v0``)
    :param lookahead: the agent steers towards ``landmark - lookahead x velocity`` (seconds), which brakes it
    :param deadband: no action while that error is below this on both axes
    """

    def __init__(self, n_agents: int = 3, lookahead: float = 0.5, deadband: float = 0.03) -> None:
        self.n_agents = n_agents
        self.lookahead = lookahead
        self.deadband = deadband
        self._permutations = np.array(list(itertools.permutations(range(n_agents))))

    def act(self, observation: np.ndarray) -> int:
        """:return: the action of the agent that sees ``observation``"""
        n = self.n_agents
        velocity = observation[0:2]
        landmarks = observation[4 : 4 + 2 * n].reshape(n, 2)
        mates = observation[4 + 2 * n : 4 + 2 * n + 2 * (n - 1)].reshape(n - 1, 2)
        team = np.vstack([np.zeros(2), mates])  # this agent first, at the origin of its own frame
        distances = np.linalg.norm(team[:, None, :] - landmarks[None, :, :], axis=-1)  # (agent, landmark)
        costs = distances[np.arange(n), self._permutations].sum(axis=1)
        target = landmarks[self._permutations[int(np.argmin(costs))][0]]
        error = target - self.lookahead * velocity
        if np.abs(error).max() < self.deadband:
            return 0
        axis = int(np.argmax(np.abs(error)))
        return int(_AXIS_ACTIONS[axis][int(error[axis] > 0)])

    def predict(self, observations: np.ndarray, deterministic: bool = True, **_: Any) -> tuple[np.ndarray, None]:
        """:return: one action per observation of the batch, as a model's ``predict``"""
        return np.array([self.act(observation) for observation in np.asarray(observations)]), None


class RandomController:
    """Uniform random actions.

    :param seed: seed of the action generator
    """

    def __init__(self, seed: int = 0) -> None:
        self._rng = np.random.default_rng(seed)

    def predict(self, observations: np.ndarray, deterministic: bool = True, **_: Any) -> tuple[np.ndarray, None]:
        """:return: one uniform action per observation"""
        return self._rng.integers(N_ACTIONS, size=len(observations)), None


class NoOpController:
    """Action 0 (no force) for every agent."""

    def predict(self, observations: np.ndarray, deterministic: bool = True, **_: Any) -> tuple[np.ndarray, None]:
        """:return: zeros, one per observation"""
        return np.zeros(len(observations), dtype=np.int64), None
