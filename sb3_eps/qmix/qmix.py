"""QMIX (Rashid et al., ICML 2018) and VDN (Sunehag et al., AAMAS 2018) on the shared multi-agent base."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.utils import LinearSchedule

from sb3_eps.common.buffers import JointReplayBufferSamples
from sb3_eps.common.losses import weighted_huber
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import init_with_defaults, input_gain, td_target
from sb3_eps.qmix.policies import QMIXPolicy, VDNPolicy, apply_lr_scales

#: QMIX's and VDN's default learning rate: 3e-4 decaying linearly to 0 over the budget (RL Zoo's ``lin_3e-4``), as
#: GDQ's: the greedy policy stops churning as the budget ends (docs/results/baselines.md).
DEFAULT_LEARNING_RATE = LinearSchedule(3e-4, 0.0, 1.0)

#: VDN's default ``advantage_learning`` (rule T19, held-out seeds 200-205; QMIX's is 0).
DEFAULT_VDN_ADVANTAGE_LEARNING = 0.5

#: the base's ``__init__`` with QMIX's own default learning rate; QMIX's ``__init__`` adds ``advantage_learning``.
_base_init = init_with_defaults(MultiAgentOffPolicyAlgorithm.__init__, learning_rate=DEFAULT_LEARNING_RATE)


def _init_with_advantage_learning(default: float) -> Callable[..., None]:
    """:return: QMIX's ``__init__`` (VDN's too): the base's arguments, then ``advantage_learning`` with ``default``;
    its signature, which ``inspect`` and the config schema read, says so."""

    def __init__(self: QMIX, *args: Any, advantage_learning: float = default, **kwargs: Any) -> None:
        if not 0.0 <= advantage_learning < 1.0:
            raise ValueError(f"advantage_learning must be in [0, 1), got {advantage_learning}")
        self.advantage_learning = float(advantage_learning)
        _base_init(self, *args, **kwargs)

    signature = inspect.signature(_base_init)
    __init__.__signature__ = signature.replace(  # type: ignore[attr-defined]
        parameters=[
            *signature.parameters.values(),
            inspect.Parameter("advantage_learning", inspect.Parameter.KEYWORD_ONLY, default=default, annotation=float),
        ]
    )
    __init__.__doc__ = _base_init.__doc__
    return __init__


class QMIX(MultiAgentOffPolicyAlgorithm):
    """QMIX: the team's ``Q_tot = mixer(Q_1(s_1, a_1), ..., Q_n(s_n, a_n); s)`` is trained by TD on the team
    reward, ``y = r_team + gamma^k (1 - done) mixer_target(Q_i'(s'_i, a*_i); s')``; agents act greedily on
    their own ``Q_i`` (monotonicity makes that the joint arg max). Agents that are not acting (a robot that
    arrived) enter the mixer with ``Q = 0``. Needs the env's global state (``state()``).
    ``policy_kwargs=dict(mixing_embed_dim=32, hypernet_hidden_dim=64, mixer_init="sum", mixer_lr_scale=0.1)`` (the
    defaults) size the mixer, start it as VDN's sum and let it learn at a tenth of the agents' rate
    (:class:`~sb3_eps.qmix.policies.QMIXPolicy`; with one rate its gain ran away on the robot worlds).

    At a time-limit truncation the agents still driving enter the target mixer with their ``Q_i'(s'_i, a*_i)``: a time
    limit is not a terminal state (SB3's ``handle_timeout_termination``; IQL's per-agent targets do the same).
    Before, they entered as ``Q = 0``, as agents that arrived, and a truncated window's target was the mixer's
    state path alone, ``mixer'(0, ..., 0; s')``, a value no agent is trained towards (the class attribute
    ``handle_timeout_termination = False`` restores that for comparison; ``docs/results/baselines.md``).
    Arguments are those of :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm`, with the learning rate
    decaying linearly from 3e-4 to 0 over the budget by default, and one of QMIX's own:

    :param advantage_learning: ``alpha`` of advantage learning (Bellemare et al., "Increasing the Action Gap", AAAI
        2016) on the team's target: it is lowered by ``alpha (mixer'(max_b Q_i'(s_i, b); s) - mixer'(Q_i'(s_i, a_i);
        s))``, the gap between the joint greedy action and the joint action taken (the mixer is monotonic, so the
        joint greedy action is every agent's own; with VDN's sum it is the sum of the agents' gaps). The agent target
        network reads both. QMIX's default 0 is the plain target; VDN's default is 0.5 (rule T19)
    """

    policy: QMIXPolicy
    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": QMIXPolicy}
    requires_fixed_n_agents: ClassVar[bool] = True
    uses_global_state: ClassVar[bool] = True
    handle_timeout_termination: ClassVar[bool] = True

    # QMIX's and VDN's own default: the learning rate (lin_3e-4, as GDQ's; docs/results/baselines.md); their own
    # argument advantage_learning is off for QMIX (not screened; QMIX meets its target), 0.5 for VDN (below).
    __init__ = _init_with_advantage_learning(0.0)

    def _update_learning_rate(self, optimizers: list[th.optim.Optimizer] | th.optim.Optimizer) -> None:
        super()._update_learning_rate(optimizers)
        apply_lr_scales(self.policy.optimizer)  # the mixer's own rate (policy_kwargs mixer_lr_scale)

    def _bootstrap_mask(self, batch: JointReplayBufferSamples) -> th.Tensor:
        """``(B, n)``: 1 for the agents whose ``Q_i'`` enters the target mixer, 0 for those entering as ``Q = 0``
        (:meth:`~sb3_eps.common.buffers.JointReplayBufferSamples.bootstrap_alive`, through the time limit with
        ``handle_timeout_termination``)."""
        return batch.bootstrap_alive(self.handle_timeout_termination)

    def _compute_loss(self, batch: JointReplayBufferSamples) -> tuple[th.Tensor, np.ndarray, dict[str, float]]:
        terms = self._td_terms(batch)
        q_total = self.policy.mixer(terms.q_taken * batch.alive, batch.states)
        with th.no_grad():
            next_q = (terms.next_values + terms.next_advantage_term) * self._bootstrap_mask(batch)
            next_total = self.policy.mixer_target(next_q, batch.next_states)
            targets = td_target(batch.team_rewards, batch.team_discounts, batch.team_dones, next_total)
            if self.advantage_learning:
                targets = targets - self.advantage_learning * self._team_action_gap(batch)
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
            logs.update(self._diagnostics(terms.q_taken * batch.alive, next_q, next_total, batch))
        return loss, priorities.cpu().numpy(), logs

    def _team_action_gap(self, batch: JointReplayBufferSamples) -> th.Tensor:
        """``mixer'(max_b Q_i'(s_i, b); s) - mixer'(Q_i'(s_i, a_i); s)`` from the agent target network (the online
        one without it) and the target mixer: what advantage learning subtracts from the team's targets, times
        ``alpha``. Agents that are not acting enter both as ``Q = 0``.

        :return: ``(batch,)``, >= 0 (the mixer is monotonic)
        """
        network = self.policy.q_net_target if self.policy.q_net_target is not None else self.policy.q_net
        observations = batch.observations.reshape(-1, batch.observations.shape[-1])
        q_values = network(observations)
        shape = batch.actions.shape[:2]
        best = q_values.max(dim=1).values.reshape(shape) * batch.alive
        taken = q_values.gather(1, batch.actions.reshape(-1, 1)).reshape(shape) * batch.alive
        mixer = self.policy.mixer_target
        return mixer(best, batch.states) - mixer(taken, batch.states)

    def _diagnostics(
        self, agent_qs: th.Tensor, next_q: th.Tensor, next_total: th.Tensor, batch: JointReplayBufferSamples
    ) -> dict[str, float]:
        """The mixer's gain ``dQ_tot/dQ_i`` (sum over agents, spread across agents and rows), the agents' Q, and
        ``zero_input_gap``: how far the target mixer moves when every agent enters it as ``Q = 0`` (the bootstrap
        of a time-limit truncation without ``handle_timeout_termination``), ``mixer'(0; s') - mixer'(Q'; s')``."""
        gain = input_gain(self.policy.mixer, agent_qs, batch.states)
        with th.no_grad():
            zero_total = self.policy.mixer_target(th.zeros_like(next_q), batch.next_states)
        return {
            "mixer_gain_sum": float(gain.sum(dim=1).mean()),
            "mixer_gain_std": float(gain[batch.alive > 0].std()),
            "agent_q_mean": float(agent_qs.detach().sum() / batch.alive.sum().clamp(min=1)),
            "agent_q_max": float(agent_qs.detach().abs().max()),
            "zero_input_gap": float((zero_total - next_total).mean()),
        }


class VDN(QMIX):
    """VDN: as :class:`QMIX` with the additive mixer ``Q_tot = sum_i Q_i`` (no state needed), and its own defaults:
    ``advantage_learning=0.5`` and greedy actions from a 2e-4 weight average of the agent network's weights
    (``policy_kwargs=dict(weight_average_tau=2e-4)``, :class:`~sb3_eps.qmix.policies.VDNPolicy`), chosen together by
    the rule T19 (``docs/results/baselines.md``, "Seventeenth session")."""

    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": VDNPolicy}
    uses_global_state: ClassVar[bool] = False

    # VDN's own default: advantage learning 0.5, with greedy actions from a 2e-4 weight average (VDNPolicy's
    # default); rule T19, docs/results/baselines.md ("Seventeenth session").
    __init__ = _init_with_advantage_learning(DEFAULT_VDN_ADVANTAGE_LEARNING)
