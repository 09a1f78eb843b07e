"""QMIX (Rashid et al., ICML 2018) and VDN (Sunehag et al., AAMAS 2018) on the shared multi-agent base."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import LinearSchedule

from sb3_eps.common.buffers import JointReplayBuffer, JointReplayBufferSamples, TeamRewardMode
from sb3_eps.common.losses import weighted_huber
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import check_arguments, td_target
from sb3_eps.qmix.policies import QMIXPolicy, VDNPolicy, apply_lr_scales

#: QMIX's and VDN's default learning rate: 3e-4 decaying linearly to 0 over the budget (docs/results/qmix_vdn.md).
DEFAULT_LEARNING_RATE = LinearSchedule(3e-4, 0.0, 1.0)

#: VDN's default ``advantage_learning`` (held-out seeds 200-205, docs/results/qmix_vdn.md; QMIX's is 0).
DEFAULT_VDN_ADVANTAGE_LEARNING = 0.5


class QMIX(MultiAgentOffPolicyAlgorithm):
    """QMIX: the team's ``Q_tot = mixer(Q_1(s_1, a_1), ..., Q_n(s_n, a_n); s)`` is trained by TD on the team
    reward, ``y = r_team + gamma^k (1 - done) mixer_target(Q_i'(s'_i, a*_i); s')``; agents act greedily on
    their own ``Q_i`` (monotonicity makes that the joint arg max). Agents that are not acting (a robot that
    arrived) enter the mixer with ``Q = 0``. Needs the env's global state (``state()``). The mixer's size and
    initialisation are ``policy_kwargs`` (:class:`~sb3_eps.qmix.policies.QMIXPolicy`).

    :param policy: the policy class, or ``"MlpPolicy"`` for the algorithm's own
    :param env: the vector env from :func:`~sb3_eps.make_vec_env` (one sub-env per agent); None to set it later
    :param learning_rate: learning rate, or a schedule of the remaining progress (default: 3e-4 decaying linearly to 0)
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
    :param policy_kwargs: the policy's arguments (:class:`~sb3_eps.qmix.policies.QMIXPolicy`: mixer size, initialisation)
    :param verbose: 0: no output, 1: training information, 2: debug
    :param seed: seed of the random generators
    :param device: torch device (``"auto"``: CUDA where available)
    :param _init_setup_model: build the networks and the buffer now (SB3's ``load`` builds them later)
    :param advantage_learning: ``alpha`` of advantage learning (Bellemare et al., "Increasing the Action Gap", AAAI
        2016): the team's target is lowered by ``alpha (mixer'(max_b Q_i'(s_i, b); s) - mixer'(Q_i'(s_i, a_i); s))``,
        the gap between the joint greedy action and the joint action taken, read from the agent target network
    """

    policy: QMIXPolicy
    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": QMIXPolicy}
    requires_fixed_n_agents: ClassVar[bool] = True
    uses_global_state: ClassVar[bool] = True
    argument_ranges = {**MultiAgentOffPolicyAlgorithm.argument_ranges, "advantage_learning": "[0, 1)"}

    def __init__(
        self,
        policy: str | type[MultiAgentQPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = DEFAULT_LEARNING_RATE,
        buffer_size: int = 50_000,
        learning_starts: int = 2_000,
        batch_size: int = 64,
        tau: float = 0.01,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        replay_buffer_class: type[JointReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        gradient_steps_per_target_update: int = 1,
        n_steps: int = 3,
        prioritized_replay: bool = True,
        prioritized_replay_alpha: float = 0.6,
        prioritized_replay_beta0: float = 0.4,
        double_q: bool = True,
        exploration_fraction: float = 0.05,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.02,
        max_grad_norm: float = 10.0,
        team_reward_mode: TeamRewardMode = "sum",
        overlap_training: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        advantage_learning: float = 0.0,
    ) -> None:
        check_arguments(QMIX.__init__, {"advantage_learning": advantage_learning}, self.argument_ranges)
        self.advantage_learning = float(advantage_learning)
        # fmt: off
        super().__init__(
            policy=policy, env=env, learning_rate=learning_rate, buffer_size=buffer_size, learning_starts=learning_starts,
            batch_size=batch_size, tau=tau, gamma=gamma, train_freq=train_freq, gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class, replay_buffer_kwargs=replay_buffer_kwargs,
            gradient_steps_per_target_update=gradient_steps_per_target_update, n_steps=n_steps,
            prioritized_replay=prioritized_replay, prioritized_replay_alpha=prioritized_replay_alpha,
            prioritized_replay_beta0=prioritized_replay_beta0, double_q=double_q, exploration_fraction=exploration_fraction,
            exploration_initial_eps=exploration_initial_eps, exploration_final_eps=exploration_final_eps,
            max_grad_norm=max_grad_norm, team_reward_mode=team_reward_mode, overlap_training=overlap_training,
            stats_window_size=stats_window_size, tensorboard_log=tensorboard_log, policy_kwargs=policy_kwargs, verbose=verbose,
            seed=seed, device=device, _init_setup_model=_init_setup_model,
        )
        # fmt: on

    def _update_learning_rate(self, optimizers: list[th.optim.Optimizer] | th.optim.Optimizer) -> None:
        super()._update_learning_rate(optimizers)
        apply_lr_scales(self.policy.optimizer)  # the mixer's own rate (MIXER_LR_SCALE)

    def _compute_loss(self, batch: JointReplayBufferSamples) -> tuple[th.Tensor, np.ndarray, dict[str, float]]:
        terms = self._td_terms(batch)
        q_total = self.policy.mixer(terms.q_taken * batch.alive, batch.states)
        with th.no_grad():
            # The agents whose window did not terminate enter with Q_i'(s'_i, a*_i), those cut by the time limit
            # too (a time limit is not a terminal state); the others enter as Q = 0.
            next_q = (terms.next_values + terms.next_advantage_term) * batch.alive * (1.0 - batch.dones)
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


class VDN(QMIX):
    """VDN: as :class:`QMIX` with the additive mixer ``Q_tot = sum_i Q_i`` (no state needed), and its own defaults:
    ``advantage_learning=0.5`` and greedy actions from a 2e-4 weight average of the agent network's weights
    (``policy_kwargs=dict(weight_average_tau=2e-4)``, :class:`~sb3_eps.qmix.policies.VDNPolicy`), chosen together on
    held-out seeds (``docs/results/qmix_vdn.md``).

    :param policy: the policy class, or ``"MlpPolicy"`` for the algorithm's own
    :param env: the vector env from :func:`~sb3_eps.make_vec_env` (one sub-env per agent); None to set it later
    :param learning_rate: learning rate, or a schedule of the remaining progress (default: 3e-4 decaying linearly to 0)
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
    :param policy_kwargs: the policy's arguments (:class:`~sb3_eps.qmix.policies.VDNPolicy`: sizes, target, average)
    :param verbose: 0: no output, 1: training information, 2: debug
    :param seed: seed of the random generators
    :param device: torch device (``"auto"``: CUDA where available)
    :param _init_setup_model: build the networks and the buffer now (SB3's ``load`` builds them later)
    :param advantage_learning: ``alpha`` of advantage learning, as in :class:`QMIX` (default 0.5)
    """

    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": VDNPolicy}
    uses_global_state: ClassVar[bool] = False
    # The sum reads any number of agents: a VDN model moves between team sizes (QMIX's hypernetworks cannot).
    requires_fixed_n_agents: ClassVar[bool] = False

    def __init__(
        self,
        policy: str | type[MultiAgentQPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = DEFAULT_LEARNING_RATE,
        buffer_size: int = 50_000,
        learning_starts: int = 2_000,
        batch_size: int = 64,
        tau: float = 0.01,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        replay_buffer_class: type[JointReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        gradient_steps_per_target_update: int = 1,
        n_steps: int = 3,
        prioritized_replay: bool = True,
        prioritized_replay_alpha: float = 0.6,
        prioritized_replay_beta0: float = 0.4,
        double_q: bool = True,
        exploration_fraction: float = 0.05,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.02,
        max_grad_norm: float = 10.0,
        team_reward_mode: TeamRewardMode = "sum",
        overlap_training: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        advantage_learning: float = DEFAULT_VDN_ADVANTAGE_LEARNING,
    ) -> None:
        # fmt: off
        super().__init__(
            policy=policy, env=env, learning_rate=learning_rate, buffer_size=buffer_size, learning_starts=learning_starts,
            batch_size=batch_size, tau=tau, gamma=gamma, train_freq=train_freq, gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class, replay_buffer_kwargs=replay_buffer_kwargs,
            gradient_steps_per_target_update=gradient_steps_per_target_update, n_steps=n_steps,
            prioritized_replay=prioritized_replay, prioritized_replay_alpha=prioritized_replay_alpha,
            prioritized_replay_beta0=prioritized_replay_beta0, double_q=double_q, exploration_fraction=exploration_fraction,
            exploration_initial_eps=exploration_initial_eps, exploration_final_eps=exploration_final_eps,
            max_grad_norm=max_grad_norm, team_reward_mode=team_reward_mode, overlap_training=overlap_training,
            stats_window_size=stats_window_size, tensorboard_log=tensorboard_log, policy_kwargs=policy_kwargs, verbose=verbose,
            seed=seed, device=device, _init_setup_model=_init_setup_model,
            advantage_learning=advantage_learning,
        )
        # fmt: on
