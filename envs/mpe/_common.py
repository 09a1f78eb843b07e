"""What the two Cooperative Navigation envs share: argument checks and the team metrics.

Both envs run mpe2's ``simple_spread`` world; the metrics are computed here from its entity positions, once per
tick and vectorised, rather than through mpe2's ``benchmark_data`` (a Python loop per agent and landmark).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces
from mpe2._mpe_utils.core import Entity

# An agent "occupies" a landmark within this distance (mpe2's simple_spread.Scenario.CAPTURE_RADIUS).
CAPTURE_RADIUS = 0.1

# mpe2's discrete movement actions: no_action, move_left, move_right, move_down, move_up.
N_ACTIONS = 5
_ACTION_SPACE = spaces.Discrete(N_ACTIONS)

# mpe2's pygame renderer.
RENDER_MODES = ["human", "rgb_array"]


def is_valid_action(action: Any) -> bool:
    """Whether ``action`` is one of the Discrete(5) actions (ints, NumPy ints and 0-d integer arrays).

    A fast path for the ints every rollout sends; anything else goes through gymnasium's check.

    :param action: the action to check
    :return: True when it lies in the action space
    """
    if isinstance(action, int | np.integer) and not isinstance(action, bool):
        return bool(0 <= action < N_ACTIONS)
    return bool(_ACTION_SPACE.contains(action))


# The worlds hold 3 agents and 3 landmarks: plain Python floats beat NumPy's per-call overhead on such tiny
# arrays (about 4 us instead of 17 us per tick for the metrics below).


def positions(entities: list[Any]) -> list[list[float]]:
    """The 2-D positions of mpe2 entities, as lists of floats.

    :param entities: mpe2 ``Agent`` or ``Landmark`` objects
    :return: their ``[x, y]`` positions
    """
    return [entity.state.p_pos.tolist() for entity in entities]


def landmark_coverage(agent_pos: list[list[float]], landmark_pos: list[list[float]]) -> tuple[float, int]:
    """How well the agents cover the landmarks, as mpe2's ``benchmark_data`` measures it.

    :param agent_pos: agent positions
    :param landmark_pos: landmark positions
    :return: the sum over landmarks of the distance to the nearest agent, and the number of landmarks
        with an agent within ``CAPTURE_RADIUS``
    """
    nearest = [min(math.dist(landmark, agent) for agent in agent_pos) for landmark in landmark_pos]
    return sum(nearest), sum(distance < CAPTURE_RADIUS for distance in nearest)


class CollisionCounter:
    """Counts the pairs of agents that overlap (mpe2's ``is_collision``: centre distance < sum of sizes), all of them
    and those that are not spawn overlaps.

    A pair counts once per tick, whereas mpe2's reward penalises both of its agents. A pair that overlaps at reset
    (mpe2 draws the starts without keeping agents apart: about 18 % of resets) is a *spawn overlap*: it is left out of
    the second count until it has separated once, since no policy chose it.

    :param agents: the mpe2 agents of the world (their sizes are read once)
    """

    def __init__(self, agents: list[Entity]) -> None:
        n_agents = len(agents)
        self._pairs = [(i, j, agents[i].size + agents[j].size) for i in range(n_agents) for j in range(i + 1, n_agents)]
        self._spawned_overlapping: set[tuple[int, int]] = set()

    def _overlapping(self, agent_pos: list[list[float]]) -> list[tuple[int, int]]:
        return [(i, j) for i, j, min_dist in self._pairs if math.dist(agent_pos[i], agent_pos[j]) < min_dist]

    def start(self, agent_pos: list[list[float]]) -> None:
        """Note the spawn overlaps of a new episode.

        :param agent_pos: the agents' positions at reset
        """
        self._spawned_overlapping = set(self._overlapping(agent_pos))

    def __call__(self, agent_pos: list[list[float]]) -> tuple[int, int]:
        """Count the colliding pairs now; a spawn overlap that has separated leaves the spawn set for good.

        :param agent_pos: the agents' positions
        :return: the number of colliding pairs, and of those that are not spawn overlaps still unseparated
        """
        overlapping = self._overlapping(agent_pos)
        self._spawned_overlapping.intersection_update(overlapping)
        return len(overlapping), sum(pair not in self._spawned_overlapping for pair in overlapping)


def team_metrics(
    n_landmarks: int,
    min_dist_sum: float,
    occupied_landmarks: int,
    n_collisions: int,
    team_return: float,
    ticks: int,
    n_collisions_after_spawn: int | None = None,
) -> dict[str, Any]:
    """Build the ``infos[agent]["team"]`` dict of the Cooperative Navigation envs (see ``docs/envs_mpe.md``).

    :param n_landmarks: number of landmarks in the world
    :param min_dist_sum: sum over landmarks of the distance to the nearest agent, now
    :param occupied_landmarks: landmarks with an agent within ``CAPTURE_RADIUS``, now
    :param n_collisions: colliding agent pairs summed over the ticks of the episode so far
    :param team_return: sum of all agents' rewards over the episode so far
    :param ticks: world steps in the episode so far
    :param n_collisions_after_spawn: the same without the spawn overlaps that have not separated yet
        (:class:`CollisionCounter`; None: ``n_collisions``, a world that never spawns agents overlapping)
    :return: the metrics dict
    """
    if n_collisions_after_spawn is None:
        n_collisions_after_spawn = n_collisions
    return {
        "success": occupied_landmarks == n_landmarks,
        "collision": n_collisions > 0,
        "n_collisions": n_collisions,
        "collision_after_spawn": n_collisions_after_spawn > 0,
        "n_collisions_after_spawn": n_collisions_after_spawn,
        "collisions_per_tick": n_collisions_after_spawn / ticks if ticks else 0.0,
        "min_dist_sum": min_dist_sum,
        "occupied_landmarks": occupied_landmarks,
        "team_return": team_return,
        "ticks": ticks,
    }
