"""GDQ: Global Dueling Q-learning (Marchesini & Farinelli, IROS 2021; the EPS paper's baseline, Section II-B1)."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
import torch as th
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import LinearSchedule

from sb3_eps.common.buffers import JointReplayBuffer, JointReplayBufferSamples, TeamRewardMode
from sb3_eps.common.losses import masked_huber, row_priority, weighted_huber
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import check_arguments, td_target
from sb3_eps.gdq.policies import DEFAULT_GLOBAL_HEAD, GDQPolicy, MlpPolicy

#: Where ``v`` and ``v'`` (the inputs of ``V_G`` and ``V_G'``) come from (``GDQ(global_values=...)``).
GlobalValues = Literal["recomputed", "target"]


def gdq_agent_targets(
    rewards: th.Tensor,
    discounts: th.Tensor,
    dones: th.Tensor,
    global_next_value: th.Tensor,
    next_advantage_term: th.Tensor,
    own_next_value: th.Tensor | None = None,
    global_bootstrap: float = 1.0,
) -> th.Tensor:
    """Agent TD targets of GDQ: the joint value replaces each agent's own state-value in its bootstrap,
    ``y_i = r_i + gamma^k (1 - done_i) [V_G'(v') + A_i(s'_i, a*) - mean_a A_i(s'_i, a)]``.
    With ``global_bootstrap = lambda < 1`` (GDQ-lambda, not in the paper) the bootstrap value is
    ``lambda V_G'(v') + (1 - lambda) V_i(s'_i)``.

    :param rewards: ``(B, n)`` individual n-step returns
    :param discounts: ``(B, n)`` ``gamma ** k``
    :param dones: ``(B, n)`` terminal flags
    :param global_next_value: ``(B,)`` ``V_G'(v')`` of the target global head
    :param next_advantage_term: ``(B, n)`` ``A(s', a*) - mean A(s', .)``
    :param own_next_value: ``(B, n)`` ``V_i(s'_i)``, needed only when ``global_bootstrap < 1``
    :param global_bootstrap: ``lambda`` in ``[0, 1]``
    """
    if global_next_value.dim() != 1 or global_next_value.shape[0] != rewards.shape[0]:
        raise ValueError(f"global_next_value must be (B,), got {tuple(global_next_value.shape)}")
    value = global_next_value[:, None]
    if global_bootstrap != 1.0:
        if own_next_value is None or own_next_value.shape != rewards.shape:
            raise ValueError("global_bootstrap < 1 needs own_next_value of the rewards' shape (B, n)")
        value = global_bootstrap * value + (1.0 - global_bootstrap) * own_next_value
    return td_target(rewards, discounts, dones, value + next_advantage_term)


#: GDQ's default learning rate: 3e-4 decaying linearly to 0 over the budget (RL Zoo's ``lin_3e-4``).
DEFAULT_LEARNING_RATE = LinearSchedule(3e-4, 0.0, 1.0)


class GDQ(MultiAgentOffPolicyAlgorithm):
    """Global Dueling Q-learning on a parameter-shared dueling network.

    Each agent predicts ``Q_i(s_i, a_i) = V_i + A_i - mean A_i`` from its own observation; its TD target uses
    the joint state value ``V_G'(v')`` of the world instead of its own ``V_i(s'_i)``
    (:func:`gdq_agent_targets`). The global head ``V_G`` is trained by TD on the team reward,
    ``L = (r_team + gamma^k V_G'(v') - V_G(v))^2``, with ``v`` and ``v'`` entering as numbers (no gradient
    into the agents); agents that are no longer acting contribute 0. Action selection uses only ``A`` (Eq. 3), so
    execution stays decentralised.

    Where the package departs from the paper: ``global_bootstrap=0.1`` (``global_bootstrap=1.0, n_steps=30`` is the
    paper's target) and an agent target network (``docs/results/gdq_target.md``), ``team_reward_mode="mean"``,
    ``learning_rate`` 3e-4 decaying linearly to 0, uniform replay (``docs/results/gdq_uniform_replay.md``) and a
    weight average for the greedy actions (:class:`~sb3_eps.gdq.policies.GDQPolicy`).

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
    :param prioritized_replay: proportional prioritised replay (default False: uniform, ``docs/results/gdq_uniform_replay.md``)
    :param prioritized_replay_alpha: priority exponent of the prioritised replay
    :param prioritized_replay_beta0: importance exponent at the start, annealed linearly to 1 over training
    :param double_q: choose the bootstrap action with the online network and value it with the target one
    :param exploration_fraction: fraction of training over which epsilon decays linearly
    :param exploration_initial_eps: epsilon at the start (one epsilon coin per agent)
    :param exploration_final_eps: epsilon at the end of the decay
    :param max_grad_norm: gradient norm clipping
    :param team_reward_mode: team reward of a tick: ``"sum"`` or ``"mean"`` (the default) of the alive agents' rewards
    :param overlap_training: learn while the last tick's worlds step (worlds in worker processes; ``train_freq`` in steps)
    :param stats_window_size: episodes (worlds, not agents) averaged in the rollout logs
    :param tensorboard_log: TensorBoard log folder (None: none)
    :param policy_kwargs: the policy's arguments (:class:`~sb3_eps.gdq.policies.GDQPolicy`: global head, target, average)
    :param verbose: 0: no output, 1: training information, 2: debug
    :param seed: seed of the random generators
    :param device: torch device (``"auto"``: CUDA where available)
    :param _init_setup_model: build the networks and the buffer now (SB3's ``load`` builds them later)
    :param global_values: where ``v'`` comes from: ``"target"``, the agent target network (needs
        ``policy_kwargs=dict(agent_target=True)``, the default), so that every bootstrap input moves slowly;
        ``"recomputed"``, the current agent network at update time. ``v`` always comes from the current agent
        network on the stored observations
    :param global_bootstrap: ``lambda`` of the agents' bootstrap value ``lambda V_G'(v') + (1 - lambda) V_i(s'_i)``:
        1 is the paper's GDQ, 0 independent learning with a global head trained beside it. Default 0.1
        (``docs/results/gdq_target.md``)
    """

    policy: GDQPolicy
    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": MlpPolicy}
    argument_ranges = {**MultiAgentOffPolicyAlgorithm.argument_ranges, "global_bootstrap": "[0, 1]"}

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
        prioritized_replay: bool = False,
        prioritized_replay_alpha: float = 0.6,
        prioritized_replay_beta0: float = 0.4,
        double_q: bool = True,
        exploration_fraction: float = 0.05,
        exploration_initial_eps: float = 1.0,
        exploration_final_eps: float = 0.02,
        max_grad_norm: float = 10.0,
        team_reward_mode: TeamRewardMode = "mean",
        overlap_training: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        global_values: GlobalValues = "target",
        global_bootstrap: float = 0.1,
    ) -> None:
        check_arguments(
            GDQ.__init__,
            {"global_values": global_values, "global_bootstrap": global_bootstrap},
            self.argument_ranges,
        )
        self.global_values: GlobalValues = global_values
        self.global_bootstrap = float(global_bootstrap)
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

    def _fixed_team_size(self) -> bool:
        return self.policy_kwargs.get("global_head", DEFAULT_GLOBAL_HEAD) != "pooled"

    def _team_size_advice(self) -> str:
        return (
            "GDQ's paper head reads a fixed number of agents: build the model with "
            "policy_kwargs=dict(global_head='pooled') to move between team sizes, or warm-start a new model's "
            "agent network from this one (python -m sb3_eps.train --init-from)"
        )

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.global_values == "target" and self.policy.q_net_target is None:
            raise ValueError(
                "global_values='target' (the default) reads v' from the agent target network: with "
                "agent_target=False set global_values='recomputed'"
            )

    def _compute_loss(self, batch: JointReplayBufferSamples) -> tuple[th.Tensor, np.ndarray, dict[str, float]]:
        from_target = self.global_values == "target"
        terms = self._td_terms(batch, need_online_next_values=not from_target)
        q_taken = terms.q_taken
        with th.no_grad():
            # v': the agents' state-values of the next joint observation, from the agent target network like the rest
            # of the bootstrap ("target"), or from the current one in the bootstrap's forward pass ("recomputed").
            next_values = terms.next_values if from_target else terms.online_next_values
            assert next_values is not None
            # V_G' reads the agents still driving after the window; those that ended in it enter as 0.
            global_next = self.policy.global_value_net_target(next_values * batch.next_alive)
            agent_targets = gdq_agent_targets(
                batch.rewards,
                batch.discounts,
                batch.dones,
                global_next,
                terms.next_advantage_term,
                terms.next_values,
                self.global_bootstrap,
            )
            global_targets = td_target(batch.team_rewards, batch.team_discounts, batch.team_dones, global_next)
        agent_loss = masked_huber(q_taken, agent_targets, batch.alive, batch.weights)
        # V_G(v) with v detached: the global loss trains only the head.
        agent_values = terms.values.detach()
        global_values = self.policy.global_value_net(agent_values * batch.alive)
        global_loss = weighted_huber(global_values, global_targets, batch.weights)
        priorities = row_priority(q_taken - agent_targets, batch.alive)
        logs = {
            "agent_loss": agent_loss.item(),
            "global_value_loss": global_loss.item(),
            "global_value_mean": float(global_values.detach().mean()),
        }
        return agent_loss + global_loss, priorities.cpu().numpy(), logs
