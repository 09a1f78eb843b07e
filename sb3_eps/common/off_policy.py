"""Multi-agent off-policy base: set-up, the optimisation step on joint rows, target updates, logging, saving.

An algorithm adds only its loss (:meth:`_compute_loss`) and its joint modules (in its policy); collection
(:meth:`~MultiAgentOffPolicyAlgorithm.collect_rollouts`) steps the worlds with per-agent epsilon-greedy actions,
turns the per-agent stream into joint rows through the n-step collector, counts episodes per world, and with
``overlap_training`` runs the due gradient steps while the worlds step. ``num_timesteps`` counts agent-steps, ``ticks`` simulator steps of one world.
"""

from __future__ import annotations

import io
import os
import pathlib
import warnings
from collections import defaultdict
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple, TypeVar, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.save_util import load_from_pkl, load_from_zip_file
from stable_baselines3.common.type_aliases import (
    GymEnv,
    MaybeCallback,
    RolloutReturn,
    Schedule,
    TrainFreq,
    TrainFrequencyUnit,
)
from stable_baselines3.common.utils import LinearSchedule, safe_mean, should_collect_more_steps
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_eps.common.buffers import (
    JointReplayBuffer,
    JointReplayBufferSamples,
    JointTick,
    NStepJointCollector,
    PrioritizedJointReplayBuffer,
    TeamRewardMode,
)
from sb3_eps.common.export import deployment_description
from sb3_eps.common.multi_agent_vec_env import MultiAgentVecEnv
from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.safety import safety_geometry
from sb3_eps.common.utils import check_arguments, describe_space, epsilon_greedy, polyak_update_

SelfMultiAgentOffPolicyAlgorithm = TypeVar("SelfMultiAgentOffPolicyAlgorithm", bound="MultiAgentOffPolicyAlgorithm")

#: Torch's intra-op threads a model sets when the user chose none: the networks are small, one thread trains as fast
#: as one per core and runs side by side keep their speed (``docs/benchmarks.md``, threads).
DEFAULT_TORCH_THREADS = 1
#: Torch's thread count when the package was imported: a different count at model construction is the user's choice.
_THREADS_AT_IMPORT = th.get_num_threads()


def set_torch_threads() -> int:
    """Set torch's intra-op threads to :data:`DEFAULT_TORCH_THREADS` unless the user chose a count (``OMP_NUM_THREADS``
    or ``torch.set_num_threads`` since import); :return: the count in effect."""
    if "OMP_NUM_THREADS" not in os.environ and th.get_num_threads() == _THREADS_AT_IMPORT:
        th.set_num_threads(DEFAULT_TORCH_THREADS)
    return th.get_num_threads()


class TDTerms(NamedTuple):
    """Agent-network terms of one batch (see :meth:`MultiAgentOffPolicyAlgorithm._td_terms`), each ``(B, n)``."""

    values: th.Tensor  # V(s), with gradient
    q_taken: th.Tensor  # Q(s, a) of the taken actions, with gradient
    next_values: th.Tensor  # V(s') of the evaluating network (target if any), no gradient
    next_advantage_term: th.Tensor  # A(s', a*) - mean A(s', .), no gradient
    online_next_values: th.Tensor | None  # online V(s') when asked for (GDQ's v'), no gradient


def find_multi_agent_env(env: VecEnv) -> Any:
    """Return the :class:`~sb3_eps.common.multi_agent_vec_env.MultiAgentVecEnv` inside ``env`` (through SB3 wrappers)."""
    current: Any = env
    while isinstance(current, VecEnvWrapper):
        current = current.venv
    if not isinstance(current, MultiAgentVecEnv):
        raise ValueError(
            f"{type(env).__name__} is not a multi-agent vector env: build the env with "
            "sb3_eps.make_vec_env(env_id, n_envs=...) so the algorithm knows which agents share a world"
        )
    return current


def timesteps_for_ticks(ticks: int, n_agents: int, ticks_per_step: int = 1) -> int:
    """:return: the agent-steps that advance ``ticks`` world ticks in worlds of ``n_agents`` agents that advance
    ``ticks_per_step`` ticks a step (rounded up to whole steps)."""
    return -(-int(ticks) // int(ticks_per_step)) * int(n_agents)


class MultiAgentOffPolicyAlgorithm(OffPolicyAlgorithm):
    """Base of the parameter-shared value-based multi-agent algorithms (IQL, GDQ, QMIX, VDN).

    Parameters as SB3's ``DQN`` where they share a name; ``buffer_size`` and ``batch_size`` count joint rows (one
    world's tick, all its agents), ``learning_starts`` agent-steps, ``train_freq`` ticks of every world.

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
    :param replay_buffer_class: a :class:`~sb3_eps.common.buffers.JointReplayBuffer` class (None: the prioritised one
        when ``prioritized_replay``); ``replay_buffer_kwargs`` are its arguments beyond capacity, spaces and agents
    :param replay_buffer_kwargs: the replay buffer's arguments beyond capacity, spaces and agents
    :param gradient_steps_per_target_update: gradient steps between two Polyak updates of the target networks
    :param n_steps: n of the n-step returns
    :param prioritized_replay: proportional prioritised replay, with exponent ``prioritized_replay_alpha`` and an
        importance exponent annealed from ``prioritized_replay_beta0`` to 1
    :param prioritized_replay_alpha: priority exponent of the prioritised replay
    :param prioritized_replay_beta0: importance exponent at the start, annealed linearly to 1 over training
    :param double_q: choose the bootstrap action with the online network and value it with the target one
        (only with an agent target network)
    :param exploration_fraction: fraction of training over which epsilon decays linearly
    :param exploration_initial_eps: epsilon at the start (one epsilon coin per agent)
    :param exploration_final_eps: epsilon at the end of the decay
    :param max_grad_norm: gradient norm clipping
    :param team_reward_mode: team reward of a tick: ``"sum"`` or ``"mean"`` of the alive agents' rewards
    :param overlap_training: run the gradient steps due after a collection while its last tick's worlds step (with
        worlds in worker processes, learning and simulation run side by side); a tick's own transition then joins
        the buffer after that tick's gradient steps. Needs ``train_freq`` in steps
    :param stats_window_size: episodes (worlds, not agents) averaged in the rollout logs
    :param tensorboard_log: TensorBoard log folder (None: none)
    :param policy_kwargs: the policy's arguments (network sizes, target network, weight average)
    :param verbose: 0: no output, 1: training information, 2: debug
    :param seed: seed of the random generators
    :param device: torch device (``"auto"``: CUDA where available)
    :param _init_setup_model: build the networks and the buffer now (SB3's ``load`` builds them later)
    """

    policy: MultiAgentQPolicy
    replay_buffer: JointReplayBuffer | None  # type: ignore[assignment]
    # Narrower than SB3's BasePolicy: every algorithm here builds a MultiAgentQPolicy.
    policy_aliases: ClassVar[dict[str, type[MultiAgentQPolicy]]] = {"MlpPolicy": MultiAgentQPolicy}  # type: ignore[assignment]
    requires_fixed_n_agents: ClassVar[bool] = False  # joint modules sized by the number of agents
    _tick_offset: int = 0  # ticks and agent-steps before the last change of team size or of ticks per step
    _step_offset: int = 0
    ticks_per_step: int = 1  # world ticks per step of the env (its worlds' action_repeat)
    default_agent_target: ClassVar[bool] = True
    uses_global_state: ClassVar[bool] = False  # only state-conditioned mixers (QMIX) read and store it
    #: A probe of the learning, ``diagnostics(model, batch) -> {name: value}``, logged under ``train/`` every
    #: ``diagnostics_interval`` gradient steps from the batch of that step, before the step (research instrumentation
    #: plugs in here; never saved with the model). None: none.
    diagnostics: Callable[[Any, JointReplayBufferSamples], dict[str, float]] | None = None
    diagnostics_interval: int = 250
    #: The intervals the constructor checks its numbers against (:func:`~sb3_eps.common.utils.check_arguments`).
    argument_ranges: ClassVar[dict[str, str]] = {
        "learning_rate": "(0, inf)", "buffer_size": "[1, inf)", "learning_starts": "[0, inf)",
        "batch_size": "[1, inf)", "tau": "(0, 1]", "gamma": "[0, 1]", "gradient_steps": "[-1, inf)",
        "gradient_steps_per_target_update": "[1, inf)", "n_steps": "[1, inf)", "prioritized_replay_alpha": "[0, inf)",
        "prioritized_replay_beta0": "[0, 1]", "exploration_fraction": "[0, 1]", "exploration_initial_eps": "[0, 1]",
        "exploration_final_eps": "[0, 1]", "max_grad_norm": "(0, inf]", "stats_window_size": "[1, inf)",
    }  # fmt: skip

    def __init__(
        self,
        policy: str | type[MultiAgentQPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 3e-4,
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
    ) -> None:
        if isinstance(env, str):
            raise ValueError(f"pass a vector env, not the id {env!r}: use sb3_eps.make_vec_env({env!r}, n_envs=...)")
        check_arguments(MultiAgentOffPolicyAlgorithm.__init__, locals(), self.argument_ranges)
        set_torch_threads()
        self.n_agents = 0
        self.n_worlds = 0
        self.state_dim = 0
        if env is not None:
            self._read_env_layout(env)  # type: ignore[arg-type]
        super().__init__(
            policy,
            env,  # type: ignore[arg-type]
            learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class,  # type: ignore[arg-type]
            replay_buffer_kwargs=replay_buffer_kwargs,
            n_steps=n_steps,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            support_multi_env=True,
            monitor_wrapper=False,
            seed=seed,
            sde_support=False,
            supported_action_spaces=(spaces.Discrete,),
        )
        self.gradient_steps_per_target_update = gradient_steps_per_target_update
        self.prioritized_replay = prioritized_replay
        self.prioritized_replay_alpha = prioritized_replay_alpha
        self.prioritized_replay_beta0 = prioritized_replay_beta0
        self.double_q = double_q
        self.exploration_fraction = exploration_fraction
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_rate = exploration_initial_eps
        self.max_grad_norm = max_grad_norm
        self.team_reward_mode = team_reward_mode
        self.overlap_training = bool(overlap_training)
        self._trained_ahead = False  # overlap_training ran this collection's gradient steps already
        self._collector: NStepJointCollector | None = None
        self._last_state: np.ndarray | None = None
        self.n_refused_updates = 0  # gradient steps refused for a non-finite loss or gradient
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up
    def _read_env_layout(self, env: VecEnv) -> None:
        """Read the agents-per-world layout from the bridge; check it against a loaded model's."""
        multi_agent_env = find_multi_agent_env(env)
        n_agents = int(multi_agent_env.n_agents)
        ticks_per_step = int(getattr(multi_agent_env, "ticks_per_step", 1))
        if self.n_agents and n_agents != self.n_agents and self._fixed_team_size():
            raise ValueError(
                f"this {type(self).__name__} model was trained with {self.n_agents} agents per world and its "
                f"joint networks are sized for them; the env has {n_agents}. {self._team_size_advice()}"
            )
        if self.n_agents and (n_agents, ticks_per_step) != (self.n_agents, self.ticks_per_step):
            # Another team size or ticks per step: the ticks so far stay counted (agent-steps per tick change).
            self._tick_offset, self._step_offset = self.ticks, self.num_timesteps
        self.n_agents = n_agents
        self.ticks_per_step = ticks_per_step
        self.n_worlds = int(multi_agent_env.n_worlds)
        state_space = getattr(multi_agent_env, "state_space", None)
        state_dim = int(np.prod(state_space.shape)) if state_space is not None else 0
        if self.state_dim and state_dim != self.state_dim and self.uses_global_state:
            raise ValueError(f"the model's global state has {self.state_dim} entries; the env's has {state_dim}")
        self.state_dim = state_dim

    @property
    def multi_agent_env(self) -> Any:
        """The bridge (:class:`~sb3_eps.common.multi_agent_vec_env.MultiAgentVecEnv`) under ``self.env``."""
        if self.env is None:
            raise ValueError("the model has no env: pass env= to load() or call set_env()")
        return find_multi_agent_env(self.env)

    def timesteps_for_ticks(self, ticks: int) -> int:
        """:return: the agent-steps (SB3 timesteps, what ``learn`` counts) that advance ``ticks`` world ticks, all
        worlds together, on the current env (rounded up to whole steps)."""
        return timesteps_for_ticks(ticks, self.n_agents, self.ticks_per_step)

    @property
    def ticks(self) -> int:
        """World ticks so far, all worlds together (agent-steps / agents per world x ticks per step: a world that holds
        each decision for ``action_repeat`` ticks advances that many per step), earlier team sizes included."""
        steps = (self.num_timesteps - self._step_offset) // max(self.n_agents, 1)
        return self._tick_offset + steps * self.ticks_per_step

    def _fixed_team_size(self) -> bool:
        """Whether the joint modules read exactly ``n_agents`` agents (QMIX's mixer; GDQ's paper head)."""
        return self.requires_fixed_n_agents

    def _team_size_advice(self) -> str:
        return (
            "Use an env with as many agents, or warm-start a new model's agent network from this one "
            "(python -m sb3_eps.train --init-from; decentralised prediction alone works on any env)"
        )

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """SB3's ``set_env``; another team size is accepted where the joint modules read any (the replay buffer
        then starts empty, the ticks so far stay counted)."""
        previous_team = self.n_agents
        vec_env = cast(VecEnv, env)  # _read_env_layout refuses an env that is not the bridge's
        self._read_env_layout(vec_env)
        if self.n_agents != previous_team and getattr(self, "policy", None) is not None:
            self.policy.n_agents = self.n_agents
            self.replay_buffer = self._make_replay_buffer()
            self.n_envs = vec_env.num_envs  # one SB3 sub-env per agent: SB3's check would refuse the new count
        super().set_env(env, force_reset=force_reset)
        self._collector = None
        self._last_state = None

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        if self.env is not None:
            # When loading, n_agents comes from the saved model: check the new env against it.
            self._read_env_layout(self.env)
        if self.n_agents < 1:
            raise ValueError("the model needs an env from sb3_eps.make_vec_env to know its agents")
        expected = self.policy_aliases["MlpPolicy"]
        if not (isinstance(self.policy_class, type) and issubclass(self.policy_class, expected)):
            raise ValueError(
                f"{type(self).__name__} needs a policy derived from {expected.__name__}, got {self.policy_class!r}"
            )
        self.replay_buffer = self._make_replay_buffer()
        if self.policy_kwargs.get("safety_margin") is not None and self.policy_kwargs.get("safety_geometry") is None:
            # Read once from the world and kept in policy_kwargs, so that the saved model loads without an env.
            world = getattr(self.env, "env_id", None) or "this env"
            description = deployment_description(self.env) if self.env is not None else None
            geometry = safety_geometry(description, repr(world))
            self.policy_kwargs = {**self.policy_kwargs, "safety_geometry": geometry}  # the caller's dict stays as it was
        kwargs = {"agent_target": self.default_agent_target, **self.policy_kwargs}
        kwargs.update(n_agents=self.n_agents, state_dim=self.state_dim)
        action_space = cast(spaces.Discrete, self.action_space)  # SB3 checked it against supported_action_spaces
        self.policy = self.policy_class(self.observation_space, action_space, self.lr_schedule, **kwargs).to(self.device)
        self.exploration_schedule = LinearSchedule(
            self.exploration_initial_eps, self.exploration_final_eps, self.exploration_fraction
        )
        self._convert_train_freq()
        if self.overlap_training and self.train_freq.unit != TrainFrequencyUnit.STEP:  # type: ignore[union-attr]
            raise ValueError(
                "overlap_training needs train_freq in steps (a collection of episodes ends only after its last "
                f"step, too late to overlap), got {self.train_freq!r}"
            )

    def _make_replay_buffer(self) -> JointReplayBuffer:
        default = PrioritizedJointReplayBuffer if self.prioritized_replay else JointReplayBuffer
        buffer_class: Any = self.replay_buffer_class or default
        if not (isinstance(buffer_class, type) and issubclass(buffer_class, JointReplayBuffer)):
            raise ValueError(
                f"replay_buffer_class must be JointReplayBuffer, PrioritizedJointReplayBuffer or a subclass "
                f"(sb3_eps.common.buffers: one row per world tick, all agents), got {buffer_class!r}"
            )
        self.prioritized_replay = issubclass(buffer_class, PrioritizedJointReplayBuffer)
        owned: dict[str, Any] = {
            "n_agents": self.n_agents,
            "state_dim": self.state_dim if self.uses_global_state else 0,
            "device": self.device,
        }
        clash = sorted(set(self.replay_buffer_kwargs) & {*owned, "buffer_size", "observation_space"})
        if clash:
            raise ValueError(f"replay_buffer_kwargs cannot set {clash}: the algorithm sets them (buffer_size, env)")
        defaults = {"alpha": self.prioritized_replay_alpha} if self.prioritized_replay else {}
        try:
            return buffer_class(self.buffer_size, self.observation_space, **owned, **{**defaults, **self.replay_buffer_kwargs})
        except TypeError as error:
            raise ValueError(f"replay_buffer_kwargs do not fit {buffer_class.__name__}: {error}") from None

    def learn(
        self: SelfMultiAgentOffPolicyAlgorithm,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfMultiAgentOffPolicyAlgorithm:
        """SB3's ``learn``; TensorBoard runs are named after the algorithm (``GDQ_1``) by default."""
        return super().learn(
            total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name or type(self).__name__,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        if not isinstance(total_timesteps, int | np.integer) or total_timesteps < 0:
            raise ValueError(f"total_timesteps must be an int >= 0 (agent-steps), got {total_timesteps!r}")
        if reset_num_timesteps:
            self._tick_offset = self._step_offset = 0
        env_is_reset = reset_num_timesteps or self._last_obs is None
        total_timesteps, callback = super()._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        if env_is_reset or self._collector is None or self._last_state is None:
            assert self.replay_buffer is not None
            self._collector = NStepJointCollector(
                self.replay_buffer, self.n_worlds, self.n_steps, self.gamma, self.team_reward_mode
            )
            self._last_state = self._global_state()
        return total_timesteps, callback

    def rollout_state(self) -> dict[str, Any]:
        """:return: what training needs beyond ``save`` to go on exactly (a checkpoint pickles it as one object)."""
        return {
            "replay_buffer": self.replay_buffer,
            "collector": self._collector,
            "last_state": self._last_state,
        }

    def set_rollout_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`rollout_state` returned (after ``set_env``, which forgets the collector)."""
        self.replay_buffer = state["replay_buffer"]
        self._collector = state["collector"]
        self._last_state = state["last_state"]

    def _global_state(self) -> np.ndarray:
        """:return: ``(n_worlds, state_dim)``, or ``(n_worlds, 0)`` for algorithms that do not use the state."""
        if self.uses_global_state:
            return self.multi_agent_env.get_state()
        return np.zeros((self.n_worlds, 0), dtype=np.float32)

    # ------------------------------------------------------------------ acting
    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """Decentralised action selection, one row per agent; exploration draws one epsilon coin per agent."""
        actions, state = self.policy.predict(observation, state, episode_start, deterministic=deterministic)
        if deterministic or self.exploration_rate <= 0:
            return actions, state
        n_actions = int(self.action_space.n)  # type: ignore[attr-defined]
        allowed = None
        if self.policy.safety_mask is not None and not isinstance(observation, dict):
            allowed = self.policy.allowed_actions(np.asarray(observation).reshape(-1, *self.observation_space.shape))
        flat, _ = epsilon_greedy(np.atleast_1d(actions), self.exploration_rate, n_actions, allowed=allowed)
        return flat.reshape(np.shape(actions)), state

    def _on_step(self) -> None:
        self.exploration_rate = self.exploration_schedule(self._current_progress_remaining)
        self.logger.record("rollout/exploration_rate", self.exploration_rate)

    def collect_rollouts(  # type: ignore[override]
        self,
        env: VecEnv,
        callback: BaseCallback,
        train_freq: TrainFreq,
        replay_buffer: JointReplayBuffer,
        action_noise: ActionNoise | None = None,
        learning_starts: int = 0,
        log_interval: int | None = None,
    ) -> RolloutReturn:
        """Step every world ``train_freq`` times, store joint rows, count episodes per world (not agent)."""
        self.policy.set_training_mode(False)
        self._trained_ahead = False
        n_collected_steps, n_collected_episodes = 0, 0
        callback.on_rollout_start()
        while should_collect_more_steps(train_freq, n_collected_steps, n_collected_episodes):
            actions = self._sample_actions(learning_starts, env.num_envs)
            env.step_async(actions)
            if self.overlap_training and n_collected_steps + 1 >= train_freq.frequency:
                self._train_ahead(env.num_envs, n_collected_steps + 1)
            new_obs, rewards, dones, infos = env.step_wait()
            self.num_timesteps += env.num_envs
            n_collected_steps += 1
            callback.update_locals(locals())
            if not callback.on_step():
                return RolloutReturn(n_collected_steps * env.num_envs, n_collected_episodes, continue_training=False)
            self._update_info_buffer(infos, dones)
            n_ended = self._store_joint_transition(actions, cast(np.ndarray, new_obs), rewards, dones, infos)
            self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
            self._on_step()
            for _ in range(n_ended):
                n_collected_episodes += 1
                self._episode_num += 1
                if log_interval is not None and self._episode_num % log_interval == 0:
                    self.dump_logs()
        callback.on_rollout_end()
        return RolloutReturn(n_collected_steps * env.num_envs, n_collected_episodes, continue_training=True)

    def _sample_actions(self, learning_starts: int, n_envs: int) -> np.ndarray:
        """Uniformly random actions before ``learning_starts``, then the online network's with one epsilon coin per
        agent (SB3's DQN draws one for the whole batch, so all agents would explore on the same steps)."""
        n_actions = int(self.action_space.n)  # type: ignore[attr-defined]
        if self.num_timesteps < learning_starts and self.policy.safety_mask is None:
            return np.random.randint(n_actions, size=n_envs)
        # ``predict`` without SB3's generic input checks, which cost as much as the network itself here.
        assert self._last_obs is not None
        self.policy.set_training_mode(False)
        with th.no_grad():
            observation = th.as_tensor(self._last_obs, device=self.device)
            greedy, allowed = self.policy.greedy_and_allowed(observation, deterministic=False)
        actions = greedy.cpu().numpy()
        # Before learning starts every action is a random one (among the allowed ones, with a safety mask).
        epsilon = 1.0 if self.num_timesteps < learning_starts else self.exploration_rate
        if epsilon > 0:
            actions, _ = epsilon_greedy(
                actions, epsilon, n_actions, allowed=None if allowed is None else allowed.cpu().numpy()
            )
        return actions

    def _train_ahead(self, n_envs: int, n_steps: int) -> None:
        """``overlap_training``: the gradient steps that SB3's ``learn`` runs after this collection, run now while the
        worlds step; its own call to ``train`` then does nothing (the same condition decides both)."""
        if self.num_timesteps + n_envs <= self.learning_starts:
            return
        gradient_steps = self.gradient_steps if self.gradient_steps >= 0 else n_steps * n_envs
        if gradient_steps > 0:
            self.train(gradient_steps, self.batch_size)
            self._trained_ahead = True
            self.policy.set_training_mode(False)

    def _store_joint_transition(
        self, actions: np.ndarray, new_obs: np.ndarray, rewards: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]
    ) -> int:
        """Feed the agents' transitions, grouped by world, to the n-step collector; :return: the worlds whose episode
        ended."""
        collector, last_state = self._collector, self._last_state
        assert collector is not None and last_state is not None and self._last_obs is not None
        shape = (self.n_worlds, self.n_agents)
        step = _read_step(new_obs, dones, infos, shape)
        new_state = self._global_state()
        last_obs = np.asarray(self._last_obs, dtype=np.float32).reshape((*shape, -1))
        next_obs = step.next_observations.reshape((*shape, -1))
        rewards = np.asarray(rewards, dtype=np.float32).reshape(shape)
        actions = np.asarray(actions, dtype=np.int64).reshape(shape)
        refused = _non_finite_worlds(last_obs, next_obs, rewards)
        for world in range(self.n_worlds):
            if world in refused:  # never stored; windows across the bad tick are dropped too
                collector.pending[world].clear()
                warnings.warn(f"{refused[world]}: the tick is not stored", RuntimeWarning, stacklevel=3)
                continue
            next_state = new_state[world]
            if step.world_ended[world] and self.uses_global_state:
                next_state = infos[world * self.n_agents].get("terminal_state", next_state)
            collector.add(
                world,
                JointTick(
                    observations=last_obs[world],
                    actions=actions[world],
                    rewards=rewards[world],
                    next_observations=next_obs[world],
                    ended=step.ended[world],
                    truncated=step.truncated[world],
                    alive=step.alive[world],
                    state=last_state[world],
                    next_state=np.asarray(next_state, dtype=np.float32),
                    world_ended=bool(step.world_ended[world]),
                ),
            )
        self._last_obs = new_obs
        self._last_state = new_state
        return int(step.world_ended.sum())

    # ------------------------------------------------------------------ learning
    def _compute_loss(self, batch: JointReplayBufferSamples) -> tuple[th.Tensor, np.ndarray, dict[str, float]]:
        """:return: ``(loss, per-row absolute TD error for the priorities, values to log under train/)``"""
        raise NotImplementedError(f"{type(self).__name__} must implement _compute_loss")

    def _td_terms(self, batch: JointReplayBufferSamples, need_online_next_values: bool = False) -> TDTerms:
        """Everything a value-based loss needs from the agent networks, in as few forward passes as possible: ``V(s)``
        and ``Q(s, a)`` with gradient; without, ``Q(s', a*) = V(s') + [A(s', a*) - mean A(s', .)]`` with ``a*`` the
        online greedy action under double-Q, values from the target network if any, and (``need_online_next_values``)
        the online ``V(s')``."""
        batch_size, n_agents, obs_dim = batch.observations.shape
        rows = batch_size * n_agents
        obs = batch.observations.reshape(rows, obs_dim)
        next_obs = batch.next_observations.reshape(rows, obs_dim)
        target = self.policy.q_net_target
        double = self.double_q and target is not None
        online_next_values: th.Tensor | None = None  # V(s') and A(s', .) of the online network, where needed
        online_next_advantages: th.Tensor | None = None
        values, advantages = self.policy.q_net.value_advantage(obs)
        with th.no_grad():
            if target is None or need_online_next_values:
                online_next_values, online_next_advantages = self.policy.q_net.value_advantage(next_obs)
            elif double:  # only the online arg max is needed: skip the value stream
                online_next_advantages = self.policy.q_net.advantage(next_obs)
        q_values = values + advantages - advantages.mean(dim=1, keepdim=True)
        taken = q_values.gather(1, batch.actions.reshape(-1, 1))
        with th.no_grad():
            if target is not None:
                next_values, next_advantages = target.value_advantage(next_obs)
            else:
                assert online_next_values is not None and online_next_advantages is not None
                next_values, next_advantages = online_next_values, online_next_advantages
            centred = next_advantages - next_advantages.mean(dim=1, keepdim=True)
            chooser = online_next_advantages if double else next_advantages
            assert chooser is not None
            if self.policy.safety_mask is not None:  # the next action is one the policy would play
                chooser = self.policy.safety_mask.masked(next_obs, chooser)
            advantage_term = centred.gather(1, chooser.argmax(dim=1, keepdim=True))
        shape = (batch_size, n_agents)
        return TDTerms(
            values=values.reshape(shape),
            q_taken=taken.reshape(shape),
            next_values=next_values.reshape(shape),
            next_advantage_term=advantage_term.reshape(shape),
            online_next_values=(
                online_next_values.reshape(shape) if need_online_next_values and online_next_values is not None else None
            ),
        )

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """Sample joint rows, minimise the algorithm's loss, update priorities and target networks."""
        if self._trained_ahead:  # done while the worlds stepped (overlap_training)
            self._trained_ahead = False
            return
        assert self.replay_buffer is not None
        if self.replay_buffer.size() == 0:
            return  # n-step rows appear n ticks after their first step: nothing to learn from yet
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        # The importance exponent, annealed from prioritized_replay_beta0 to 1 over training.
        beta = self.prioritized_replay_beta0 + (1.0 - self.prioritized_replay_beta0) * (1.0 - self._current_progress_remaining)
        parameters = [param for group in self.policy.optimizer.param_groups for param in group["params"]]
        logs: dict[str, list[float]] = defaultdict(list)
        for _ in range(gradient_steps):
            batch = self.replay_buffer.sample(batch_size, beta)
            loss, td_errors, info = self._compute_loss(batch)
            if self.diagnostics is not None and self._n_updates % self.diagnostics_interval == 0:
                info = {**info, **self.diagnostics(self, batch)}
            self.policy.optimizer.zero_grad()
            loss.backward()
            grad_norm = th.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)
            if not (th.isfinite(loss) and th.isfinite(grad_norm) and np.isfinite(td_errors).all()):
                self._refuse_update(batch)  # nothing of this step reaches the weights, moments or priorities
                continue
            self.policy.optimizer.step()
            self.policy.update_weight_average(self._n_updates + 1)
            self.replay_buffer.update_priorities(batch.indices, td_errors)
            self._n_updates += 1
            if self._n_updates % self.gradient_steps_per_target_update == 0:
                self._update_targets()
            logs["loss"].append(loss.item())
            for key, value in info.items():
                logs[key].append(value)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if getattr(self, "n_refused_updates", 0):
            self.logger.record("train/n_refused_updates", self.n_refused_updates)
        if self.prioritized_replay:
            self.logger.record("train/per_beta", beta)
        for key, values in logs.items():
            self.logger.record(f"train/{key}", float(np.mean(values)))

    def _refuse_update(self, batch: JointReplayBufferSamples) -> None:
        """Count and report a gradient step whose loss, gradient or TD errors were not finite, naming the source."""
        self.n_refused_updates = getattr(self, "n_refused_updates", 0) + 1
        inputs = {
            "observations": batch.observations,
            "next observations": batch.next_observations,
            "rewards": batch.rewards,
        }
        sources = [f"replay batch {name}" for name, tensor in inputs.items() if not th.isfinite(tensor).all()]
        broken = {name.split(".")[0] for name, param in self.policy.named_parameters() if not th.isfinite(param).all()}
        sources += [f"{'target network' if name.endswith('_target') else 'network'} {name}" for name in sorted(broken)]
        source = ", ".join(sources) or "the loss itself (TD target or prediction overflowed)"
        warnings.warn(
            f"gradient step refused: non-finite loss or gradient from {source} (count: train/n_refused_updates)",
            RuntimeWarning,
            stacklevel=3,
        )

    def _update_targets(self) -> None:
        """Polyak step of every target network toward its online network."""
        for target, online in self.policy.target_pairs():
            polyak_update_(target, online, self.tau)

    # ------------------------------------------------------------------ logging and saving
    def dump_logs(self) -> None:
        """SB3's logs, per world (``rollout/ep_rew_mean`` is the mean team return), plus the team rates."""
        episodes = list(self.ep_info_buffer or [])
        if episodes:
            if "collision" in episodes[0]:
                self.logger.record("rollout/collision_rate", safe_mean([float(e["collision"]) for e in episodes]))
            if "success" in episodes[0]:
                self.logger.record("rollout/success_rate", safe_mean([float(e["success"]) for e in episodes]))
        self.logger.record("time/ticks", self.ticks)
        super().dump_logs()

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "_collector",
            "_last_state",
            "_trained_ahead",
            "diagnostics",
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer"], []

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        buffer = load_from_pkl(path, self.verbose)
        if not isinstance(buffer, JointReplayBuffer) or buffer.n_agents != self.n_agents:
            raise ValueError(f"{path} does not hold a joint replay buffer for {self.n_agents} agents")
        self.replay_buffer = buffer
        self._collector = None

    @classmethod
    def load(  # type: ignore[override]
        cls: type[SelfMultiAgentOffPolicyAlgorithm],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        **kwargs: Any,
    ) -> SelfMultiAgentOffPolicyAlgorithm:
        """SB3's ``load``; a file of another algorithm, or an env of other spaces, is a one-line ``ValueError``."""
        try:
            model = super().load(path, env=env, device=device, **kwargs)
        except (RuntimeError, ValueError) as error:
            reason = _load_mismatch(cls, path, env)
            if reason is None:
                raise
            raise ValueError(reason) from error
        return model


def _load_mismatch(cls: type[MultiAgentOffPolicyAlgorithm], path: Any, env: GymEnv | None) -> str | None:
    """:return: why the model file at ``path`` does not load into ``cls`` on ``env``, or None if not known."""
    if hasattr(path, "seek"):
        path.seek(0)
    try:
        data, _, _ = load_from_zip_file(path, device="cpu")
    except Exception:  # unreadable: SB3's own error says more
        return None
    name = getattr(path, "name", path)
    saved_policy = data.get("policy_class") if data else None
    expected = cls.policy_aliases["MlpPolicy"]
    if isinstance(saved_policy, type) and not issubclass(saved_policy, expected):
        return (
            f"{name} holds a model of another algorithm (policy {saved_policy.__name__}); {cls.__name__} uses "
            f"{expected.__name__}: load it with the class that saved it"
        )
    for kind in ("observation_space", "action_space"):
        ours = getattr(env, kind, None)
        if env is not None and data and data.get(kind) != ours:
            return (
                f"{name} was trained with {kind} {describe_space(data.get(kind))}, the env has "
                f"{describe_space(ours)}: use an env of the same kind (robots with robots, MPE with MPE)"
            )
    return None


class _Step(NamedTuple):
    """What one vector step says of each agent, as ``(n_worlds, n_agents)`` arrays (observations flat)."""

    next_observations: np.ndarray  # (n_worlds * n_agents, obs): terminal observations where an episode ended
    alive: np.ndarray  # the agent acted at this tick
    truncated: np.ndarray  # its episode was cut by the time limit
    ended: np.ndarray  # its episode (its life) ended at this tick
    world_ended: np.ndarray  # (n_worlds,): every agent of the world is done


def _read_step(new_obs: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]], shape: tuple[int, int]) -> _Step:
    """Read the bridge's flags from a step's infos; patch in the terminal observations SB3 moved to the infos."""
    next_obs = np.array(new_obs, dtype=np.float32, copy=True)
    for index in np.flatnonzero(dones):
        next_obs[index] = infos[index]["terminal_observation"]
    alive = np.fromiter((info.get("alive", True) for info in infos), dtype=bool, count=len(infos))
    truncated = np.fromiter((info.get("TimeLimit.truncated", False) for info in infos), dtype=bool, count=len(infos))
    dones = np.asarray(dones, dtype=bool)
    ended = dones & alive
    return _Step(
        next_observations=next_obs,
        alive=alive.reshape(shape),
        truncated=truncated.reshape(shape),
        ended=ended.reshape(shape),
        world_ended=np.asarray(dones.reshape(shape).all(axis=1)),
    )


def _non_finite_worlds(observations: np.ndarray, next_observations: np.ndarray, rewards: np.ndarray) -> dict[int, str]:
    """:return: world -> what was not finite in its tick (``(worlds, agents, ...)`` arrays; empty when all are)."""
    parts = {"observation": observations, "next observation": next_observations, "reward": rewards}
    found: dict[int, str] = {}
    if all(np.isfinite(array).all() for array in parts.values()):  # the hot path: one check per array
        return found
    for name, array in parts.items():
        bad = ~np.isfinite(array.reshape(array.shape[0], array.shape[1], -1)).all(axis=2)
        for world in np.flatnonzero(bad.any(axis=1)):
            agents = np.flatnonzero(bad[world]).tolist()
            found.setdefault(int(world), f"non-finite {name} from the env (world {world}, agents {agents})")
    return found
