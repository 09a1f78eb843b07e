"""The dueling Q-network shared by all agents and the policy that holds it with its target networks."""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor, create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_eps.common.safety import LidarSafetyMask
from sb3_eps.common.utils import dueling_aggregation, polyak_update_

DEFAULT_NET_ARCH = [128, 64]
DEFAULT_STREAM_ARCH = [64]


#: The warm-up of the weight average: polynomial-decay averaging (Shamir & Zhang, ICML 2013) with this eta.
WEIGHT_AVERAGE_WARMUP_ETA = 3


def weight_average_rate(tau: float, n_updates: int, eta: int = WEIGHT_AVERAGE_WARMUP_ETA) -> float:
    """:return: how far the ``n_updates``-th gradient step (from 1) moves the weight average toward the online
    weights: ``max(tau, (eta + 1) / (n + eta))``, a polynomial-decay average until its rate falls to ``tau``, then
    the exponential moving average (eta chosen in ``docs/results/gdq_weight_average.md``)."""
    return max(float(tau), (eta + 1.0) / (max(int(n_updates), 1) + eta))


class DuelingQNetwork(BasePolicy):
    """Dueling Q-network (Wang et al., 2016; EPS paper Eq. 2): a trunk, then a state-value stream and an
    advantage stream aggregated as ``Q = V + A - mean(A)``.

    :param net_arch: hidden sizes of the shared trunk (default ``[128, 64]``)
    :param stream_arch: hidden sizes of each of the two streams (default ``[64]``)
    """

    action_space: spaces.Discrete

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        features_extractor: BaseFeaturesExtractor,
        features_dim: int,
        net_arch: list[int] | None = None,
        stream_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        normalize_images: bool = True,
    ) -> None:
        super().__init__(
            observation_space,
            action_space,
            features_extractor=features_extractor,
            normalize_images=normalize_images,
        )
        self.net_arch = list(DEFAULT_NET_ARCH if net_arch is None else net_arch)
        self.stream_arch = list(DEFAULT_STREAM_ARCH if stream_arch is None else stream_arch)
        self.activation_fn = activation_fn
        self.features_dim = features_dim
        n_actions = int(self.action_space.n)
        trunk = create_mlp(features_dim, -1, self.net_arch, activation_fn, with_bias=True)
        self.trunk = nn.Sequential(*trunk)
        trunk_dim = self.net_arch[-1] if self.net_arch else features_dim
        self.value_stream = nn.Sequential(*create_mlp(trunk_dim, 1, self.stream_arch, activation_fn))
        self.advantage_stream = nn.Sequential(*create_mlp(trunk_dim, n_actions, self.stream_arch, activation_fn))

    def value_advantage(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor]:
        """:return: ``(V (batch, 1), A (batch, n_actions))`` for a batch of observations."""
        hidden = self.trunk(self.extract_features(obs, self.features_extractor))
        return self.value_stream(hidden), self.advantage_stream(hidden)

    def advantage(self, obs: PyTorchObs) -> th.Tensor:
        """:return: ``A (batch, n_actions)`` alone (the value stream is not run)."""
        return self.advantage_stream(self.trunk(self.extract_features(obs, self.features_extractor)))

    def forward(self, obs: PyTorchObs) -> th.Tensor:
        """:return: the Q-values ``(batch, n_actions)``."""
        return dueling_aggregation(*self.value_advantage(obs))

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        # arg max Q == arg max A (EPS paper Eq. 3): execution needs only the agent's own observation, and only the
        # advantage stream (the value stream is skipped: a third less work per action).
        return self.advantage(observation).argmax(dim=1).reshape(-1)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            net_arch=self.net_arch,
            stream_arch=self.stream_arch,
            features_dim=self.features_dim,
            activation_fn=self.activation_fn,
            features_extractor=self.features_extractor,
        )
        return data


class MultiAgentQPolicy(BasePolicy):
    """Holds the shared agent network ``q_net``, its optional target ``q_net_target`` and the joint modules
    an algorithm adds (GDQ's global value head, QMIX's mixer), with one optimizer over everything trainable.

    Subclasses override :meth:`_build_joint_modules` and :meth:`joint_module_names`. Arguments as SB3's
    ``DQNPolicy``, and:

    :param net_arch: hidden sizes of the agent trunk; ``stream_arch`` those of the value and advantage streams
    :param agent_target: whether the agent network has a target network
    :param weight_average_tau: keep ``q_net_average``, a moving average of the agent network's weights
        (:func:`weight_average_rate`), and take the greedy actions from it; training's exploring actions keep the
        online network. None: no average
    :param n_agents: agents per world; ``state_dim`` the length of the global state (for the joint modules)
    :param safety_margin: None (the network's greedy actions), or a lidar action mask built into the policy
        (:class:`sb3_eps.common.safety.LidarSafetyMask`, TurtleBot3 worlds): only actions whose arc over the next
        decision keeps the body this many metres [m] clear of the lidar's hit points are played, explored and used in
        the double-Q target. 0.03 removed every collision on validation rooms as a deployment layer (rule N13 of
        ``docs/results/navigator/rules.md``); the navigator trains with it (rule N16)
    :param safety_geometry: the world's lidar and action geometry for the mask
        (:func:`sb3_eps.common.safety.safety_geometry`); the algorithm fills it from its env, and the saved model
        keeps it
    """

    q_net: DuelingQNetwork
    q_net_target: DuelingQNetwork | None

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | None = None,
        stream_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        agent_target: bool = True,
        weight_average_tau: float | None = None,
        n_agents: int = 1,
        state_dim: int = 0,
        safety_margin: float | None = None,
        safety_geometry: dict[str, Any] | None = None,
    ) -> None:
        if weight_average_tau is not None and not 0.0 < float(weight_average_tau) <= 1.0:
            raise ValueError(f"weight_average_tau must be in (0, 1] or None, got {weight_average_tau!r}")
        self.weight_average_tau = None if weight_average_tau is None else float(weight_average_tau)
        super().__init__(
            observation_space,
            action_space,
            features_extractor_class,
            features_extractor_kwargs,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            normalize_images=normalize_images,
        )
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"value-based policies need a Discrete action space, got {action_space}")
        self.net_arch = list(DEFAULT_NET_ARCH if net_arch is None else net_arch)
        self.stream_arch = list(DEFAULT_STREAM_ARCH if stream_arch is None else stream_arch)
        self.activation_fn = activation_fn
        self.agent_target = agent_target
        self.n_agents = int(n_agents)
        self.state_dim = int(state_dim)
        self.safety_margin = None if safety_margin is None else float(safety_margin)
        self.safety_geometry = safety_geometry
        self.safety_mask: LidarSafetyMask | None = None
        if self.safety_margin is not None:
            if safety_geometry is None:
                raise ValueError("safety_margin needs safety_geometry (the algorithm reads it from its env)")
            self.safety_mask = LidarSafetyMask(self.safety_margin, safety_geometry)
        self._build(lr_schedule)

    def make_q_net(self) -> DuelingQNetwork:
        """:return: a new agent network with this policy's architecture (fresh features extractor)."""
        features_extractor = self.make_features_extractor()
        return DuelingQNetwork(
            self.observation_space,
            self.action_space,  # type: ignore[arg-type]
            features_extractor=features_extractor,
            features_dim=features_extractor.features_dim,
            net_arch=self.net_arch,
            stream_arch=self.stream_arch,
            activation_fn=self.activation_fn,
            normalize_images=self.normalize_images,
        ).to(self.device)

    def with_target(self, make: Callable[[], nn.Module]) -> tuple[Any, Any]:
        """:return: a new module and its target network (a second one, with the first's weights, in eval mode)."""
        online, target = make().to(self.device), make().to(self.device)
        target.load_state_dict(online.state_dict())
        return online, target.train(False)

    def _build(self, lr_schedule: Schedule) -> None:
        if self.agent_target:
            self.q_net, self.q_net_target = self.with_target(self.make_q_net)
        else:
            self.q_net, self.q_net_target = self.make_q_net(), None
        self._build_joint_modules()
        trainable = [self.q_net, *(getattr(self, name) for name in self.joint_module_names())]
        parameters = [param for module in trainable for param in module.parameters()]
        kwargs = dict(self.optimizer_kwargs)
        if self.optimizer_class in (th.optim.Adam, th.optim.AdamW) and not {"fused", "foreach"} & kwargs.keys():
            # The fused kernel updates every tensor in one call: about 0.4 ms less per gradient step on a CPU
            # for our small networks (benchmarks/train_throughput.py); pass fused=False to opt out.
            kwargs["fused"] = True
        self.optimizer = self.optimizer_class(parameters, lr=lr_schedule(1), **kwargs)  # type: ignore[call-arg]
        self.q_net_average: DuelingQNetwork | None = None
        if self.weight_average_tau is not None:  # built after the optimizer: never trained, only averaged
            # A copy, not make_q_net(): a fresh initialisation would draw from torch's generator and change
            # what training draws after it (the option would no longer leave training as it is).
            self.q_net_average = copy.deepcopy(self.q_net)
            self.q_net_average.requires_grad_(False)
            self.q_net_average.set_training_mode(False)

    def reset_weight_average(self) -> None:
        """Set ``q_net_average`` (when there is one) to the online network's weights (a warm start does this)."""
        if self.q_net_average is not None:
            self.q_net_average.load_state_dict(self.q_net.state_dict())

    def update_weight_average(self, n_updates: int) -> None:
        """One step of the weight average toward the online network, by :func:`weight_average_rate` of the
        ``n_updates`` so far; nothing without ``weight_average_tau``."""
        if self.q_net_average is not None:
            assert self.weight_average_tau is not None
            polyak_update_(self.q_net_average, self.q_net, weight_average_rate(self.weight_average_tau, n_updates))

    def greedy_net(self) -> DuelingQNetwork:
        """:return: the network the greedy actions come from: ``q_net_average`` when kept, else ``q_net``."""
        return self.q_net if self.q_net_average is None else self.q_net_average

    def _build_joint_modules(self) -> None:
        """Create the algorithm's joint modules and their targets (none for independent learners)."""

    def joint_module_names(self) -> list[str]:
        """:return: attribute names of the trainable joint modules; each has a ``<name>_target`` copy."""
        return []

    def target_pairs(self) -> list[tuple[nn.Module, nn.Module]]:
        """:return: ``(target, online)`` pairs that the target update moves together."""
        pairs: list[tuple[nn.Module, nn.Module]] = []
        if self.q_net_target is not None:
            pairs.append((self.q_net_target, self.q_net))
        for name in self.joint_module_names():
            target = getattr(self, f"{name}_target", None)
            if target is not None:
                pairs.append((target, getattr(self, name)))
        return pairs

    def forward(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self._predict(obs, deterministic=deterministic)

    def _predict(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        """Greedy actions: from :meth:`greedy_net` when ``deterministic``, else from the online network (the
        algorithm adds epsilon-greedy exploration on top of those)."""
        return self.greedy_and_allowed(obs, deterministic)[0]

    def greedy_and_allowed(self, obs: th.Tensor, deterministic: bool = True) -> tuple[th.Tensor, th.Tensor | None]:
        """:return: the greedy actions (as :meth:`_predict`) and the safety mask's allowed actions ``(batch,
        n_actions)`` they were chosen among (None without a mask), the mask computed once for both."""
        net = self.greedy_net() if deterministic else self.q_net
        if self.safety_mask is None:
            return net._predict(obs, deterministic=True), None
        allowed = self.safety_mask.allowed(obs)
        return net.advantage(obs).masked_fill(~allowed, float("-inf")).argmax(dim=1).reshape(-1), allowed

    def allowed_actions(self, obs: np.ndarray) -> np.ndarray | None:
        """:return: ``(batch, n_actions)`` booleans, the actions the safety mask lets the policy play (exploration draws
        among them), or None without a mask."""
        if self.safety_mask is None:
            return None
        with th.no_grad():
            return self.safety_mask.allowed(th.as_tensor(obs, dtype=th.float32, device=self.device)).cpu().numpy()

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            net_arch=self.net_arch,
            stream_arch=self.stream_arch,
            activation_fn=self.activation_fn,
            lr_schedule=self._dummy_schedule,
            optimizer_class=self.optimizer_class,
            optimizer_kwargs=self.optimizer_kwargs,
            features_extractor_class=self.features_extractor_class,
            features_extractor_kwargs=self.features_extractor_kwargs,
            agent_target=self.agent_target,
            weight_average_tau=self.weight_average_tau,
            n_agents=self.n_agents,
            state_dim=self.state_dim,
            safety_margin=self.safety_margin,
            safety_geometry=self.safety_geometry,
        )
        return data

    def set_training_mode(self, mode: bool) -> None:
        # Called before every action selection and every update: walking the module tree each time cost about
        # 10 % of a training step, so a call that changes nothing returns at once. ``nn.Module.train`` keeps
        # ``self.training`` in step too, so the flag cannot go stale.
        if mode == self.training and self.q_net.training == mode:
            return
        self.q_net.set_training_mode(mode)
        for name in self.joint_module_names():
            getattr(self, name).train(mode)
        self.training = mode
