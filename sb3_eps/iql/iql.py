"""IQL: parameter-shared independent dueling double DQN with n-step returns and prioritised replay.

The independent learners (IL) baseline of the EPS paper (Section IV, "based on Rainbow"): every agent learns
from its own transitions with its own reward; the network is shared.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import torch as th

from sb3_eps.common.buffers import JointReplayBufferSamples
from sb3_eps.common.losses import masked_huber, row_priority
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import td_target

#: IQL's policy: the shared dueling agent network and its target, no joint module.
MlpPolicy = MultiAgentQPolicy


class IQL(MultiAgentOffPolicyAlgorithm):
    """Independent Q-learning with a shared dueling network (Tan 1993; Rainbow components, Hessel et al. 2018).

    Target of agent i: ``y_i = G_i + gamma^k (1 - done_i) Q_target(s'_i, argmax_a Q(s'_i, a))``.
    The constructor is :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm`'s:

    :param policy: the policy class, or ``"MlpPolicy"`` for the algorithm's own
    :param env: the vector env from :func:`~sb3_eps.make_vec_env` (one sub-env per agent); None to set it later
    :param learning_rate: learning rate, or a schedule of the remaining progress (1 to 0)
    :param buffer_size: replay capacity, in joint rows (one world's tick, all its agents)
    :param learning_starts: agent-steps of uniformly random actions before learning starts
    :param batch_size: joint rows per gradient step
    :param tau: Polyak coefficient of the target networks (1: a hard copy)
    :param gamma: discount factor
    :param train_freq: ticks of every world between two trainings, or ``(n, "step" | "episode")``
    :param gradient_steps: gradient steps per training (-1: as many as agent-steps collected)
    :param replay_buffer_class: a :class:`~sb3_eps.common.buffers.JointReplayBuffer` class (None: by ``prioritized_replay``)
    :param replay_buffer_kwargs: the replay buffer's arguments beyond capacity, spaces and agents
    :param gradient_steps_per_target_update: gradient steps between two Polyak updates of the target networks
    :param n_steps: n of the n-step returns
    :param prioritized_replay: proportional prioritised replay (else uniform)
    :param prioritized_replay_alpha: priority exponent of the prioritised replay
    :param prioritized_replay_beta0: importance exponent at the start, annealed linearly to 1 over training
    :param double_q: choose the bootstrap action with the online network and value it with the target one
    :param exploration_fraction: fraction of training over which epsilon decays linearly
    :param exploration_initial_eps: epsilon at the start (one epsilon coin per agent)
    :param exploration_final_eps: epsilon at the end of the decay
    :param max_grad_norm: gradient norm clipping
    :param team_reward_mode: team reward of a tick: ``"sum"`` or ``"mean"`` of the alive agents' rewards
    :param overlap_training: learn while the last tick's worlds step (worlds in worker processes; ``train_freq`` in steps)
    :param stats_window_size: episodes (worlds, not agents) averaged in the rollout logs
    :param tensorboard_log: TensorBoard log folder (None: none)
    :param policy_kwargs: the policy's arguments (network sizes, target network, weight average)
    :param verbose: 0: no output, 1: training information, 2: debug
    :param seed: seed of the random generators
    :param device: torch device (``"auto"``: CUDA where available)
    :param _init_setup_model: build the networks and the buffer now (SB3's ``load`` builds them later)
    """

    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": MlpPolicy}

    def _compute_loss(self, batch: JointReplayBufferSamples) -> tuple[th.Tensor, np.ndarray, dict[str, float]]:
        terms = self._td_terms(batch)
        q_taken, next_values, next_advantages = terms.q_taken, terms.next_values, terms.next_advantage_term
        # Double-Q n-step target per agent (its own reward, its own bootstrap).
        targets = td_target(batch.rewards, batch.discounts, batch.dones, next_values + next_advantages)
        loss = masked_huber(q_taken, targets, batch.alive, batch.weights)
        priorities = row_priority(q_taken - targets, batch.alive)
        q_mean = float((q_taken.detach() * batch.alive).sum() / batch.alive.sum().clamp(min=1))
        return loss, priorities.cpu().numpy(), {"q_mean": q_mean}
