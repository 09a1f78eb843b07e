"""GDQ policy: the shared dueling agent network plus the global value head V_G and its target."""

from __future__ import annotations

import typing
from typing import Any, Literal

import torch as th
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn

from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import check_arguments

DEFAULT_GLOBAL_NET_ARCH = [64, 64]
#: GDQ greedy-acts from a weight average of its agent network by default (docs/results/gdq_weight_average.md).
DEFAULT_WEIGHT_AVERAGE_TAU = 2e-4
GlobalInit = Literal["random", "sum", "mean"]
GLOBAL_INITS: tuple[str, ...] = typing.get_args(GlobalInit)
#: ``"mlp"``: the paper's head over a fixed number of agents; ``"pooled"``: a Deep Sets head over any number.
GlobalHead = Literal["mlp", "pooled"]
DEFAULT_GLOBAL_HEAD: GlobalHead = "mlp"


@th.no_grad()
def _init_as_linear_sum(linears: list[nn.Linear], n_agents: int, scale: float) -> None:
    """Set the weights of a ReLU MLP so that it computes ``scale * sum(v)`` exactly, through ``2 n`` carrier
    units per hidden layer (``relu(v_i)`` and ``relu(-v_i)``). The other units keep their random input
    weights; their output weights start at 0, so they contribute nothing until the TD loss trains them."""
    width = 2 * n_agents
    eye = th.eye(n_agents)
    first, *hidden, last = linears
    first.weight[:width] = th.cat([eye, -eye])
    first.bias[:width] = 0.0
    for layer in hidden:
        layer.weight[:width] = 0.0
        layer.weight[:width, :width] = th.eye(width)
        layer.bias[:width] = 0.0
    last.weight.zero_()
    last.weight[0, :n_agents] = scale
    last.weight[0, n_agents:width] = -scale
    last.bias.zero_()


def _checked_arch(net_arch: list[int] | None, activation_fn: type[nn.Module], init: str, carriers: int) -> list[int]:
    """:return: the hidden sizes of a global head, after checking that ``init`` can be built on them: the exact
    ``"sum"`` / ``"mean"`` initialisations need ReLU and ``2 carriers`` units per hidden layer
    (:func:`_init_as_linear_sum`; ``carriers`` is the number of values the first layer reads)"""
    arch = list(DEFAULT_GLOBAL_NET_ARCH if net_arch is None else net_arch)
    if init not in GLOBAL_INITS:
        raise ValueError(f"global_init must be one of {GLOBAL_INITS}, got {init!r}")
    if init != "random":
        if activation_fn is not nn.ReLU:
            raise ValueError(f"global_init={init!r} needs activation_fn=nn.ReLU, got {activation_fn.__name__}")
        if not arch or min(arch) < 2 * carriers:
            raise ValueError(
                f"global_init={init!r} needs hidden layers of at least 2 * n_agents = {2 * carriers} units, "
                f"got global_net_arch={arch}; widen it or use global_init='random'"
            )
    return arch


class GlobalValueNetwork(nn.Module):
    """Joint state-value ``V_G(v)`` over the agents' state-values ``v = [V_1(s_1), ..., V_n(s_n)]`` of one
    world (GDQ, Marchesini & Farinelli IROS 2021): Dense 64 ReLU -> Dense 64 ReLU -> linear scalar.

    :param n_agents: agents per world (the input size)
    :param net_arch: hidden sizes (default ``[64, 64]``)
    :param activation_fn: activation function
    :param init: ``"random"`` (PyTorch's default initialisation), ``"sum"`` or ``"mean"``: the same architecture
        initialised to compute exactly ``sum(v)`` or ``mean(v)`` at step 0 (needs ReLU and hidden layers of at
        least ``2 n_agents`` units). The papers do not give the head's initialisation; ``docs/modules/gdq.md``
        says what each did (``"sum"`` is part of the setting that learns the 2-robot world).
    """

    def __init__(
        self,
        n_agents: int,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        init: GlobalInit = "random",
    ):
        super().__init__()
        arch = _checked_arch(net_arch, activation_fn, init, n_agents)
        self.n_agents = n_agents
        self.net = nn.Sequential(*create_mlp(n_agents, 1, arch, activation_fn))
        if init != "random":
            linears = [module for module in self.net if isinstance(module, nn.Linear)]
            _init_as_linear_sum(linears, n_agents, 1.0 if init == "sum" else 1.0 / n_agents)

    def forward(self, agent_values: th.Tensor) -> th.Tensor:
        """:param agent_values: ``(B, n_agents)``; :return: ``V_G`` as ``(B,)``."""
        if agent_values.dim() != 2 or agent_values.shape[1] != self.n_agents:
            raise ValueError(f"V_G expects (batch, {self.n_agents}) state-values, got {tuple(agent_values.shape)}")
        return self.net(agent_values).squeeze(-1)


class PooledGlobalValueNetwork(nn.Module):
    """Joint state-value ``V_G(v) = rho(mean_i phi(v_i))`` over any number of agents (a Deep Sets head, Zaheer et
    al., NeurIPS 2017): ``phi`` maps each agent's state-value to features (Dense ReLU layers), their mean over the
    agents goes through a linear ``rho``. The same weights read 2, 4 or 12 agents, so a model trained on one team
    size continues on another (``docs/results/many_robots.md``, "Team-size transfer"); the paper's head
    (:class:`GlobalValueNetwork`) reads a fixed ``n``. With the team reward a mean over the agents (GDQ's default
    ``team_reward_mode``) a mean-pooled head keeps one scale for every team size.

    :param n_agents: agents per world when built (only the ``"sum"`` initialisation reads it)
    :param net_arch: hidden sizes of ``phi`` (default ``[64, 64]``)
    :param activation_fn: activation function
    :param init: ``"random"``, or ``"mean"`` / ``"sum"``: ``V_G`` computes exactly ``mean(v)`` (or ``n_agents``
        times it) at step 0, through carrier units ``relu(v_i)`` and ``relu(-v_i)`` (needs ReLU and hidden layers of
        at least 2 units); the other units start with output weight 0
    """

    def __init__(
        self,
        n_agents: int,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        init: GlobalInit = "random",
    ):
        super().__init__()
        arch = _checked_arch(net_arch, activation_fn, init, carriers=1)  # phi reads one value at a time
        if not arch:
            raise ValueError("the pooled global head needs at least one hidden layer (global_net_arch)")
        self.n_agents = n_agents
        self.phi = nn.Sequential(*create_mlp(1, arch[-1], arch[:-1], activation_fn), activation_fn())
        self.rho = nn.Linear(arch[-1], 1)
        if init != "random":
            linears = [module for module in self.phi if isinstance(module, nn.Linear)]
            _init_as_linear_sum([*linears, self.rho], 1, 1.0 if init == "mean" else float(n_agents))

    def forward(self, agent_values: th.Tensor) -> th.Tensor:
        """:param agent_values: ``(B, n)`` for any ``n >= 1``; :return: ``V_G`` as ``(B,)``."""
        if agent_values.dim() != 2 or agent_values.shape[1] < 1:
            raise ValueError(f"V_G expects (batch, agents) state-values, got {tuple(agent_values.shape)}")
        features = self.phi(agent_values.unsqueeze(-1))  # (B, n, h)
        return self.rho(features.mean(dim=1)).squeeze(-1)


class GDQPolicy(MultiAgentQPolicy):
    """:class:`~sb3_eps.common.policies.MultiAgentQPolicy` with ``global_value_net`` and its target.

    :param global_net_arch: hidden sizes of the global value head (default ``[64, 64]``)
    :param global_init: initialisation of the global value head, see :class:`GlobalValueNetwork`
    :param global_head: ``"mlp"`` (the default, the paper's ``V_G`` over exactly ``n`` agents,
        :class:`GlobalValueNetwork`) or ``"pooled"`` (:class:`PooledGlobalValueNetwork`, any number of agents: the
        model can be loaded on, or ``set_env`` to, a world with another team size and keep training)
    :param weight_average_tau: as :class:`~sb3_eps.common.policies.MultiAgentQPolicy`, but ``2e-4`` by default for
        GDQ (``docs/results/gdq_weight_average.md``); ``None`` takes the greedy actions from the online network.
    :param kwargs: as :class:`~sb3_eps.common.policies.MultiAgentQPolicy`

    GDQ's learning options (``global_values``, ``global_bootstrap``) are arguments of :class:`~sb3_eps.gdq.GDQ`.
    """

    global_value_net: GlobalValueNetwork
    global_value_net_target: GlobalValueNetwork

    def __init__(
        self,
        *args: Any,
        global_net_arch: list[int] | None = None,
        global_init: GlobalInit = "mean",
        global_head: GlobalHead = DEFAULT_GLOBAL_HEAD,
        weight_average_tau: float | None = DEFAULT_WEIGHT_AVERAGE_TAU,
        **kwargs: Any,
    ) -> None:
        self.global_net_arch = list(global_net_arch or DEFAULT_GLOBAL_NET_ARCH)
        self.global_init = global_init
        check_arguments(GDQPolicy.__init__, {"global_head": global_head}, {})
        self.global_head = global_head
        kwargs["weight_average_tau"] = weight_average_tau
        super().__init__(*args, **kwargs)

    def _build_joint_modules(self) -> None:
        # Dense ReLU layers as the paper's V_G, whatever the agent network's activation (the sum/mean
        # initialisations are exact only with ReLU).
        args = (self.n_agents, self.global_net_arch, nn.ReLU, self.global_init)
        head = PooledGlobalValueNetwork if self.global_head == "pooled" else GlobalValueNetwork
        self.global_value_net, self.global_value_net_target = self.with_target(lambda: head(*args))

    def joint_module_names(self) -> list[str]:
        return ["global_value_net"]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            global_net_arch=self.global_net_arch,
            global_init=self.global_init,
            global_head=self.global_head,
        )
        return data


MlpPolicy = GDQPolicy
