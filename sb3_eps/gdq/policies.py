"""GDQ policy: the shared dueling agent network plus the global value head V_G and its target."""

from __future__ import annotations

from typing import Any

import torch as th
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn

from sb3_eps.common.policies import MultiAgentQPolicy

DEFAULT_GLOBAL_NET_ARCH = [64, 64]


class GlobalValueNetwork(nn.Module):
    """Joint state-value ``V_G(v)`` over the agents' state-values ``v = [V_1(s_1), ..., V_n(s_n)]`` of one
    world (GDQ, Marchesini & Farinelli IROS 2021): Dense 64 ReLU -> Dense 64 ReLU -> linear scalar.

    :param n_agents: agents per world (the input size)
    :param net_arch: hidden sizes (default ``[64, 64]``)
    :param activation_fn: activation function
    """

    def __init__(self, n_agents: int, net_arch: list[int] | None = None, activation_fn: type[nn.Module] = nn.ReLU):
        super().__init__()
        self.n_agents = n_agents
        self.net = nn.Sequential(*create_mlp(n_agents, 1, list(net_arch or DEFAULT_GLOBAL_NET_ARCH), activation_fn))

    def forward(self, agent_values: th.Tensor) -> th.Tensor:
        """:param agent_values: ``(B, n_agents)``; :return: ``V_G`` as ``(B,)``."""
        if agent_values.dim() != 2 or agent_values.shape[1] != self.n_agents:
            raise ValueError(f"V_G expects (batch, {self.n_agents}) state-values, got {tuple(agent_values.shape)}")
        return self.net(agent_values).squeeze(-1)


class GDQPolicy(MultiAgentQPolicy):
    """:class:`~sb3_eps.common.policies.MultiAgentQPolicy` with ``global_value_net`` and its target.

    :param global_net_arch: hidden sizes of the global value head (default ``[64, 64]``)
    :param kwargs: as :class:`~sb3_eps.common.policies.MultiAgentQPolicy`
    """

    global_value_net: GlobalValueNetwork
    global_value_net_target: GlobalValueNetwork

    def __init__(self, *args: Any, global_net_arch: list[int] | None = None, **kwargs: Any) -> None:
        self.global_net_arch = list(global_net_arch or DEFAULT_GLOBAL_NET_ARCH)
        super().__init__(*args, **kwargs)

    def _build_joint_modules(self) -> None:
        self.global_value_net = GlobalValueNetwork(self.n_agents, self.global_net_arch, self.activation_fn)
        self.global_value_net_target = GlobalValueNetwork(self.n_agents, self.global_net_arch, self.activation_fn)
        self.global_value_net_target.load_state_dict(self.global_value_net.state_dict())
        self.global_value_net_target.train(False)
        self.global_value_net.to(self.device)
        self.global_value_net_target.to(self.device)

    def joint_module_names(self) -> list[str]:
        return ["global_value_net"]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(global_net_arch=self.global_net_arch)
        return data


MlpPolicy = GDQPolicy
