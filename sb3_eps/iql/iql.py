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
    All arguments are those of :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm`.
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
