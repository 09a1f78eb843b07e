"""Joint replay buffers: one row is one world's tick for all of its agents (the joint heads and mixers need them
together), with ``alive`` (the agent acted at the row's first tick) and ``next_alive`` (it still acts in the bootstrap
observation) masks. :class:`NStepJointCollector` folds every world's ticks into n-step rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces

#: The team reward of a tick: the ``"sum"`` or the ``"mean"`` of the alive agents' rewards (``team_reward_mode``).
TeamRewardMode = Literal["sum", "mean"]


class JointReplayBufferSamples(NamedTuple):
    """A batch of ``B`` joint rows of ``n`` agents as torch tensors: per agent ``(B, n, ...)``, per team ``(B,)``,
    states ``(B, state_dim)``, importance ``weights`` and numpy row ``indices``."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    rewards: th.Tensor
    dones: th.Tensor
    discounts: th.Tensor
    alive: th.Tensor
    next_alive: th.Tensor
    team_rewards: th.Tensor
    team_dones: th.Tensor
    team_discounts: th.Tensor
    states: th.Tensor
    next_states: th.Tensor
    weights: th.Tensor
    indices: np.ndarray


class JointReplayBuffer:
    """Uniform replay buffer of joint rows.

    :param observation_space: one agent's observation space (a flat Box)
    :param state_dim: length of the global state vector (0: none stored)
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        n_agents: int,
        state_dim: int = 0,
        device: th.device | str = "cpu",
    ) -> None:
        obs_shape = observation_space.shape
        if obs_shape is None or len(obs_shape) != 1:
            raise ValueError(f"joint buffers need flat observations, got shape {obs_shape}")
        self.buffer_size = int(buffer_size)
        self.n_agents = int(n_agents)
        self.obs_dim = int(obs_shape[0])
        self.state_dim = int(state_dim)
        self.device = th.device(device)
        self.pos = 0
        self.full = False
        size, n = self.buffer_size, self.n_agents
        self.observations = np.zeros((size, n, self.obs_dim), dtype=np.float32)
        self.next_observations = np.zeros((size, n, self.obs_dim), dtype=np.float32)
        self.actions = np.zeros((size, n), dtype=np.int64)
        self.rewards = np.zeros((size, n), dtype=np.float32)
        self.dones = np.zeros((size, n), dtype=np.float32)
        self.discounts = np.zeros((size, n), dtype=np.float32)
        self.alive = np.zeros((size, n), dtype=np.float32)
        self.next_alive = np.zeros((size, n), dtype=np.float32)
        self.team_rewards = np.zeros(size, dtype=np.float32)
        self.team_dones = np.zeros(size, dtype=np.float32)
        self.team_discounts = np.zeros(size, dtype=np.float32)
        self.states = np.zeros((size, self.state_dim), dtype=np.float32)
        self.next_states = np.zeros((size, self.state_dim), dtype=np.float32)

    def size(self) -> int:
        """:return: the number of rows stored."""
        return self.buffer_size if self.full else self.pos

    def add_row(self, row: JointRow) -> int:
        """Store one joint row (:class:`NStepJointCollector`'s) and return its index."""
        index = self.pos
        self.observations[index] = row.observations
        self.next_observations[index] = row.next_observations
        self.actions[index] = row.actions
        self.rewards[index] = row.rewards
        self.dones[index] = row.dones
        self.discounts[index] = row.discounts
        self.alive[index] = row.alive
        self.next_alive[index] = row.next_alive
        self.team_rewards[index] = row.team_reward
        self.team_dones[index] = row.team_done
        self.team_discounts[index] = row.team_discount
        if self.state_dim:
            self.states[index] = row.state
            self.next_states[index] = row.next_state
        self.pos = (self.pos + 1) % self.buffer_size
        self.full = self.full or self.pos == 0
        return index

    def sample(self, batch_size: int, beta: float = 1.0) -> JointReplayBufferSamples:
        """Sample ``batch_size`` rows uniformly with replacement (``beta``: the prioritised variant's)."""
        indices = np.random.randint(0, self.size(), size=batch_size)
        return self._to_samples(indices, np.ones(batch_size, dtype=np.float32))

    def update_priorities(self, indices: np.ndarray, td_errors: np.ndarray) -> None:
        """No-op for uniform replay (the prioritised variant overrides it)."""

    def _to_samples(self, indices: np.ndarray, weights: np.ndarray) -> JointReplayBufferSamples:
        state_columns = ("states", "next_states")
        rows = {  # every column of the buffer: the samples' fields but weights and indices
            name: th.as_tensor(getattr(self, name)[indices], device=self.device)
            for name in JointReplayBufferSamples._fields[:-2]
            if self.state_dim or name not in state_columns
        }
        if not self.state_dim:  # nothing to gather without a global state
            rows.update(dict.fromkeys(state_columns, th.zeros((len(indices), 0), device=self.device)))
        return JointReplayBufferSamples(**rows, weights=th.as_tensor(weights, device=self.device), indices=indices)


class SumTree:
    """Binary sum tree over ``capacity`` leaves (a power of two inside), vectorised over batches of indices."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self.n_leaves = 1 << max(0, (self.capacity - 1).bit_length())
        self.tree = np.zeros(2 * self.n_leaves, dtype=np.float64)

    @property
    def total(self) -> float:
        """:return: the sum of all leaves."""
        return float(self.tree[1])

    def update(self, indices: np.ndarray, values: np.ndarray) -> None:
        """Set the leaves ``indices`` to ``values`` and refresh their ancestors."""
        nodes = np.asarray(indices, dtype=np.int64) + self.n_leaves
        self.tree[nodes] = values
        # Level by level to the root; a parent listed twice gets the same sum twice (cheaper than np.unique).
        for _ in range(self.n_leaves.bit_length() - 1):
            nodes = nodes // 2
            self.tree[nodes] = self.tree[2 * nodes] + self.tree[2 * nodes + 1]

    def set_one(self, index: int, value: float) -> None:
        """Set one leaf (the per-row insert path: plain Python integers beat NumPy here)."""
        tree = self.tree
        node = index + self.n_leaves
        tree[node] = value
        while node > 1:
            node //= 2
            tree[node] = tree[2 * node] + tree[2 * node + 1]

    def leaves(self, indices: np.ndarray) -> np.ndarray:
        """:return: the values of the leaves ``indices``."""
        return self.tree[np.asarray(indices, dtype=np.int64) + self.n_leaves]

    def find(self, prefix_sums: np.ndarray) -> np.ndarray:
        """:return: for each value u in [0, total), the leaf whose cumulative range holds u."""
        nodes = np.ones(len(prefix_sums), dtype=np.int64)
        remaining = np.array(prefix_sums, dtype=np.float64)
        while nodes[0] < self.n_leaves:
            left = self.tree[2 * nodes]
            go_right = remaining >= left
            remaining -= left * go_right
            nodes = 2 * nodes + go_right
        return np.minimum(nodes - self.n_leaves, self.capacity - 1)


class PrioritizedJointReplayBuffer(JointReplayBuffer):
    """Proportional prioritised replay (Schaul et al., 2016) over joint rows: priority ``(|delta| + eps) ** alpha``
    of the row's TD error, new rows at the maximum; importance weights ``(N * P(i)) ** -beta`` over the batch's
    largest."""

    def __init__(self, *args: Any, alpha: float = 0.6, priority_eps: float = 1e-6, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if alpha < 0:
            raise ValueError(f"PER alpha must be >= 0, got {alpha}")
        self.alpha = float(alpha)
        self.priority_eps = float(priority_eps)
        self.tree = SumTree(self.buffer_size)
        self.max_priority = 1.0

    def add_row(self, row: JointRow) -> int:
        index = super().add_row(row)
        self.tree.set_one(index, self.max_priority)
        return index

    def sample(self, batch_size: int, beta: float = 0.4) -> JointReplayBufferSamples:
        """Stratified proportional sampling: one draw in each of ``batch_size`` equal slices of the mass."""
        size = self.size()
        total = self.tree.total
        bounds = np.linspace(0.0, total, batch_size + 1)
        draws = np.random.uniform(bounds[:-1], bounds[1:])
        indices = np.minimum(self.tree.find(np.minimum(draws, np.nextafter(total, 0))), size - 1)
        probabilities = self.tree.leaves(indices) / total
        weights = (size * probabilities) ** (-beta)
        weights = (weights / weights.max()).astype(np.float32)
        return self._to_samples(indices, weights)

    def update_priorities(self, indices: np.ndarray, td_errors: np.ndarray) -> None:
        """Set the rows' priorities from their absolute TD errors."""
        priorities = (np.abs(td_errors) + self.priority_eps) ** self.alpha
        self.tree.update(indices, priorities)
        self.max_priority = max(self.max_priority, float(priorities.max()))


@dataclass
class JointRow:
    """One joint row before storage (numpy; ``n`` agents)."""

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_observations: np.ndarray
    dones: np.ndarray
    discounts: np.ndarray
    alive: np.ndarray
    next_alive: np.ndarray
    team_reward: float
    team_done: float
    team_discount: float
    state: np.ndarray
    next_state: np.ndarray


@dataclass
class JointTick:
    """One world's tick for the n-step collector, from what the bridge says of each agent (the rollout and EPS's
    experience sharing both store through it): ``alive`` the agents that acted, ``ended`` those whose life ended,
    ``truncated`` those ended by the time limit."""

    observations: np.ndarray  # (n, d)
    actions: np.ndarray  # (n,)
    rewards: np.ndarray  # (n,)
    next_observations: np.ndarray  # (n, d), terminal observations where an agent ended
    ended: np.ndarray  # (n,) bool: the agent's episode ended at this tick (terminated or truncated)
    truncated: np.ndarray  # (n,) bool: ... by the time limit
    alive: np.ndarray  # (n,) bool: the agent acted at this tick
    state: np.ndarray
    next_state: np.ndarray
    world_ended: bool
    # Derived once (every window containing this tick asks for them).
    terminated: np.ndarray = field(init=False)  # (n,) bool: the agent's episode ended by termination
    world_terminated: bool = field(init=False)  # every living agent reached a real end, not the time limit
    all_alive: bool = field(init=False)
    any_ended: bool = field(init=False)

    def __post_init__(self) -> None:
        self.terminated = self.ended & ~self.truncated
        self.world_terminated = bool(self.world_ended and not self.truncated[self.alive].any())
        self.all_alive = bool(self.alive.all())
        self.any_ended = bool(self.ended.any())


def n_step_row(ticks: list[JointTick], gamma: float, team_reward_mode: str = "sum") -> JointRow:
    """Fold the window ``t0 .. t0+K-1`` of one world (only the last tick may end it) into the n-step row of ``t0``.

    Agent i: ``G_i = sum_{k < K_i} gamma^k r_i(t0+k)``, ``K_i`` stopping where its own episode ended, bootstrapped
    with ``gamma^K_i`` unless it terminated inside the window. Team: the same over the whole window of the team reward
    (sum or mean of the alive agents'), bootstrapped unless the world terminated.
    """
    if all(tick.all_alive for tick in ticks) and not any(tick.any_ended for tick in ticks[:-1]):
        return _n_step_row_all_alive(ticks, gamma, team_reward_mode)
    return _n_step_row_general(ticks, gamma, team_reward_mode)


def _n_step_row_general(ticks: list[JointTick], gamma: float, team_reward_mode: str) -> JointRow:
    """:func:`n_step_row` for any window."""
    first, last = ticks[0], ticks[-1]
    n_ticks = len(ticks)
    rewards = np.stack([tick.rewards for tick in ticks])  # (K, n)
    alive_k = np.stack([tick.alive for tick in ticks])  # (K, n)
    ended = np.stack([tick.ended for tick in ticks])  # (K, n)
    terminated = np.stack([tick.terminated for tick in ticks])
    # in_window[k, i]: agent i's episode has not ended before tick k of the window.
    ended_before = np.zeros_like(ended)
    ended_before[1:] = np.cumsum(ended[:-1], axis=0) > 0
    in_window = ~ended_before
    discount_powers = gamma ** np.arange(n_ticks, dtype=np.float64)[:, None]
    individual = (discount_powers * rewards * in_window * alive_k).sum(axis=0)
    horizon = in_window.sum(axis=0)  # K_i
    dones = (terminated & in_window).any(axis=0)
    alive_rewards = rewards * alive_k
    if team_reward_mode == "sum":
        team_per_tick = alive_rewards.sum(axis=1)
    else:
        team_per_tick = alive_rewards.sum(axis=1) / np.maximum(alive_k.sum(axis=1), 1)
    team_reward = float((discount_powers[:, 0] * team_per_tick).sum())
    return JointRow(
        observations=first.observations,
        actions=first.actions,
        rewards=individual.astype(np.float32),
        next_observations=last.next_observations,
        dones=dones.astype(np.float32),
        discounts=(gamma**horizon).astype(np.float32),
        alive=first.alive.astype(np.float32),
        next_alive=(last.alive & ~last.ended).astype(np.float32),
        team_reward=team_reward,
        team_done=float(last.world_terminated),
        team_discount=float(gamma**n_ticks),
        state=first.state,
        next_state=last.next_state,
    )


def _n_step_row_all_alive(ticks: list[JointTick], gamma: float, team_reward_mode: str) -> JointRow:
    """:func:`n_step_row` where every agent is alive at every tick and none ends before the last: the general fold's
    result at a third of its cost (``tests/test_algorithm_math.py`` compares them)."""
    first, last = ticks[0], ticks[-1]
    individual = np.zeros_like(first.rewards, dtype=np.float64)
    team_reward = 0.0
    for k, tick in enumerate(ticks):
        power = gamma**k
        individual += np.float64(power) * tick.rewards  # float64 as in the general fold (NumPy 2 promotion)
        team_tick = float(tick.rewards.sum())
        team_reward += power * (team_tick if team_reward_mode == "sum" else team_tick / len(tick.rewards))
    n_agents = len(first.rewards)
    return JointRow(
        observations=first.observations,
        actions=first.actions,
        rewards=individual.astype(np.float32),
        next_observations=last.next_observations,
        dones=last.terminated.astype(np.float32),
        discounts=np.full(n_agents, gamma ** len(ticks), dtype=np.float32),
        alive=np.ones(n_agents, dtype=np.float32),
        next_alive=(~last.ended).astype(np.float32),
        team_reward=team_reward,
        team_done=float(last.world_terminated),
        team_discount=float(gamma ** len(ticks)),
        state=first.state,
        next_state=last.next_state,
    )


class NStepJointCollector:
    """Turns the per-tick stream of every world into n-step joint rows (:func:`n_step_row`) written to ``buffer``."""

    n_rows = 0  # rows written

    def __init__(
        self,
        buffer: JointReplayBuffer,
        n_worlds: int,
        n_steps: int = 1,
        gamma: float = 0.99,
        team_reward_mode: TeamRewardMode = "sum",
    ) -> None:
        self.buffer = buffer
        self.n_steps = int(n_steps)
        self.gamma = float(gamma)
        self.team_reward_mode = team_reward_mode
        self.pending: list[list[JointTick]] = [[] for _ in range(n_worlds)]

    def add(self, world: int, tick: JointTick) -> None:
        """Append one world's tick; write every complete window's row (none where no agent was alive)."""
        window = self.pending[world]
        window.append(tick)
        if tick.world_ended:
            while window:
                self._write(window)
                window.pop(0)
        elif len(window) == self.n_steps:
            self._write(window)
            window.pop(0)

    def _write(self, window: list[JointTick]) -> None:
        if window[0].alive.any():
            self.buffer.add_row(n_step_row(window, self.gamma, self.team_reward_mode))
            self.n_rows += 1
