"""QMIX (Rashid et al., ICML 2018) and VDN (Sunehag et al., AAMAS 2018) on the shared multi-agent base."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import torch as th

from sb3_eps.common.buffers import JointReplayBufferSamples
from sb3_eps.common.losses import weighted_huber
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import input_gain, td_target
from sb3_eps.qmix.policies import QMIXPolicy, VDNPolicy


class QMIX(MultiAgentOffPolicyAlgorithm):
    """QMIX: the team's ``Q_tot = mixer(Q_1(s_1, a_1), ..., Q_n(s_n, a_n); s)`` is trained by TD on the team
    reward, ``y = r_team + gamma^k (1 - done) mixer_target(Q_i'(s'_i, a*_i); s')``; agents act greedily on
    their own ``Q_i`` (monotonicity makes that the joint arg max). Agents that are not acting (a robot that
    arrived) enter the mixer with ``Q = 0``. Needs the env's global state (``state()``).
    All arguments are those of :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm`;
    ``policy_kwargs=dict(mixing_embed_dim=32, hypernet_hidden_dim=64)`` size the mixer.
    """

    policy: QMIXPolicy
    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": QMIXPolicy}
    requires_fixed_n_agents: ClassVar[bool] = True
    uses_global_state: ClassVar[bool] = True

    def _compute_loss(self, batch: JointReplayBufferSamples) -> tuple[th.Tensor, np.ndarray, dict[str, float]]:
        terms = self._td_terms(batch)
        q_total = self.policy.mixer(terms.q_taken * batch.alive, batch.states)
        with th.no_grad():
            next_q = (terms.next_values + terms.next_advantage_term) * batch.next_alive
            next_total = self.policy.mixer_target(next_q, batch.next_states)
            targets = td_target(batch.team_rewards, batch.team_discounts, batch.team_dones, next_total)
        loss = weighted_huber(q_total, targets, batch.weights)
        priorities = (q_total - targets).detach().abs()
        q_total_detached = q_total.detach()
        logs = {
            "q_total_mean": float(q_total_detached.mean()),
            "q_total_min": float(q_total_detached.min()),
            "q_total_max": float(q_total_detached.max()),
            "target_mean": float(targets.mean()),
        }
        if self._n_updates % self.diagnostics_interval == 0:
            gain = input_gain(self.policy.mixer, terms.q_taken * batch.alive, batch.states)
            logs.update(
                mixer_gain_sum=float(gain.sum(dim=1).mean()),
                mixer_gain_std=float(gain[batch.alive > 0].std()),
                agent_q_mean=float(terms.q_taken.detach().mean()),
                agent_q_max=float(terms.q_taken.detach().abs().max()),
            )
        return loss, priorities.cpu().numpy(), logs


class VDN(QMIX):
    """VDN: as :class:`QMIX` with the additive mixer ``Q_tot = sum_i Q_i`` (no state needed)."""

    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": VDNPolicy}
    uses_global_state: ClassVar[bool] = False
