"""QMIX and VDN policies: the shared dueling agent network plus a mixer (and its target)."""

from __future__ import annotations

from typing import Any, Literal, get_args

import torch as th
import torch.nn.functional as F
from stable_baselines3.common.type_aliases import Schedule
from torch import nn

from sb3_eps.common.policies import MultiAgentQPolicy
from sb3_eps.common.utils import check_arguments

#: VDN greedy-acts from a weight average of its agent network by default (docs/results/qmix_vdn.md; the
#: same rate as GDQ's).
VDN_WEIGHT_AVERAGE_TAU = 2e-4
#: QMIX's mixer learns at this fraction of the agents' rate (with one rate it diverged, docs/results/qmix_vdn.md).
MIXER_LR_SCALE = 0.1


class QMixer(nn.Module):
    """Monotonic mixing network of QMIX (Rashid et al., ICML 2018, Section 4).

    ``Q_tot = w2(s) . elu(w1(s)^T q + b1(s)) + b2(s)`` where the weights ``w1``, ``w2`` come from
    hypernetworks conditioned on the global state ``s`` and pass through ``abs`` so that
    ``dQ_tot / dQ_i >= 0`` (monotonicity, the paper's Eq. 5).

    :param n_agents: agents per world
    :param state_dim: global state length
    :param embed_dim: width of the mixing layer (32 in the QMIX paper)
    :param hypernet_hidden_dim: hidden width of the weight hypernetworks (64)
    :param init: ``"random"``: PyTorch's default initialisation (the QMIX paper's); ``"sum"``: the hypernetworks'
        output layers start so that ``Q_tot = sum_i Q_i`` (VDN's mixer, a gain of 1 per agent) wherever
        ``sum_i Q_i > -n_agents``, with state-dependent perturbations of 1/10 of the default scale that the TD loss
        then grows (see :func:`_init_mixer_as_sum`)
    """

    def __init__(
        self,
        n_agents: int,
        state_dim: int,
        embed_dim: int = 32,
        hypernet_hidden_dim: int = 64,
        init: str = "random",
    ) -> None:
        super().__init__()
        if state_dim < 1:
            raise ValueError("QMIX needs a global state: the env must provide state() (state_dim >= 1)")
        if init not in MIXER_INITS:
            raise ValueError(f"mixer_init must be one of {MIXER_INITS}, got {init!r}")
        self.n_agents, self.state_dim, self.embed_dim = n_agents, state_dim, embed_dim
        self.hyper_w1 = nn.Sequential(
            nn.Linear(state_dim, hypernet_hidden_dim),
            nn.ReLU(),
            nn.Linear(hypernet_hidden_dim, n_agents * embed_dim),
        )
        self.hyper_b1 = nn.Linear(state_dim, embed_dim)
        self.hyper_w2 = nn.Sequential(
            nn.Linear(state_dim, hypernet_hidden_dim), nn.ReLU(), nn.Linear(hypernet_hidden_dim, embed_dim)
        )
        self.hyper_b2 = nn.Sequential(nn.Linear(state_dim, embed_dim), nn.ReLU(), nn.Linear(embed_dim, 1))
        if init == "sum":
            _init_mixer_as_sum(self)

    def forward(self, agent_qs: th.Tensor, states: th.Tensor) -> th.Tensor:
        """:param agent_qs: ``(B, n_agents)``; :param states: ``(B, state_dim)``; :return: ``Q_tot (B,)``."""
        batch = agent_qs.shape[0]
        if agent_qs.shape != (batch, self.n_agents) or states.shape != (batch, self.state_dim):
            raise ValueError(
                f"QMixer expects q (B, {self.n_agents}) and state (B, {self.state_dim}), "
                f"got {tuple(agent_qs.shape)} and {tuple(states.shape)}"
            )
        w1 = self.hyper_w1(states).abs().view(batch, self.n_agents, self.embed_dim)
        b1 = self.hyper_b1(states).view(batch, 1, self.embed_dim)
        hidden = F.elu(th.bmm(agent_qs.view(batch, 1, self.n_agents), w1) + b1)
        w2 = self.hyper_w2(states).abs().view(batch, self.embed_dim, 1)
        b2 = self.hyper_b2(states).view(batch, 1, 1)
        return (th.bmm(hidden, w2) + b2).view(batch)


MixerInit = Literal["random", "sum"]
MIXER_INITS: tuple[str, ...] = get_args(MixerInit)
# Scale of the state-dependent part of the hypernetworks' output layers under ``init="sum"``: small enough that
# the mixer starts close to the sum, large enough to break the symmetry between the mixing units.
SUM_INIT_PERTURBATION = 0.1


@th.no_grad()
def _init_mixer_as_sum(mixer: QMixer) -> None:
    """Start ``mixer`` as ``Q_tot = sum_i Q_i`` on ``sum_i Q_i > -n``: ``|w1| = 1``, ``b1 = n``, ``|w2| = 1 / embed``,
    ``b2 = -n``, so every mixing unit is ``elu(sum_i Q_i + n)`` on the ELU's linear side. The output layers'
    random weights (the state dependence) are scaled by :data:`SUM_INIT_PERTURBATION` times the size of the
    weight they perturb (1 for ``w1``, ``b1`` and ``b2``, ``1 / embed`` for ``w2``)."""
    n_agents, embed_dim = mixer.n_agents, mixer.embed_dim
    outputs = [  # (output layer, its bias, the scale of its random weights)
        (mixer.hyper_w1[-1], 1.0, 1.0),
        (mixer.hyper_b1, float(n_agents), 1.0),
        (mixer.hyper_w2[-1], 1.0 / embed_dim, 1.0 / embed_dim),
        (mixer.hyper_b2[-1], -float(n_agents), 1.0),
    ]
    for layer, bias, scale in outputs:
        assert isinstance(layer, nn.Linear), f"a hypernetwork ends in {type(layer).__name__}, not a Linear layer"
        layer.weight.mul_(SUM_INIT_PERTURBATION * scale)
        layer.bias.fill_(bias)


def apply_lr_scales(optimizer: th.optim.Optimizer) -> None:
    """Multiply each parameter group's learning rate by its ``lr_scale`` (after SB3 has set them all to one rate)."""
    for group in optimizer.param_groups:
        group["lr"] = group["lr"] * group.get("lr_scale", 1.0)


class SumMixer(nn.Module):
    """VDN's mixer (Sunehag et al., AAMAS 2018): ``Q_tot = sum_i Q_i``; it has no parameters."""

    def forward(self, agent_qs: th.Tensor, states: th.Tensor | None = None) -> th.Tensor:
        """:param agent_qs: ``(B, n_agents)``; :return: ``(B,)``."""
        if agent_qs.dim() != 2:
            raise ValueError(f"SumMixer expects (B, n_agents), got {tuple(agent_qs.shape)}")
        return agent_qs.sum(dim=1)


class QMIXPolicy(MultiAgentQPolicy):
    """Agent network plus a :class:`QMixer` and its target.

    :param mixing_embed_dim: width of the mixing layer (32)
    :param hypernet_hidden_dim: hidden width of the hypernetworks (64)
    :param mixer_init: initialisation of the mixer, ``"sum"`` (default: it starts as VDN's sum) or ``"random"``
        (PyTorch's default initialisation, the QMIX paper's) (see :class:`QMixer`)
    :param kwargs: as :class:`~sb3_eps.common.policies.MultiAgentQPolicy`
    """

    mixer: nn.Module
    mixer_target: nn.Module

    def __init__(
        self,
        *args: Any,
        mixing_embed_dim: int = 32,
        hypernet_hidden_dim: int = 64,
        mixer_init: MixerInit = "sum",
        **kwargs: Any,
    ):
        check_arguments(QMIXPolicy.__init__, {"mixer_init": mixer_init}, {})
        self.mixing_embed_dim = mixing_embed_dim
        self.hypernet_hidden_dim = hypernet_hidden_dim
        self.mixer_init = mixer_init
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        if any(True for _ in self.mixer.parameters()):  # two rates (VDN's sum has no parameters): see apply_lr_scales
            groups = [
                {"params": list(self.q_net.parameters()), "lr_scale": 1.0},
                {"params": list(self.mixer.parameters()), "lr_scale": MIXER_LR_SCALE},
            ]
            defaults = {key: value for key, value in self.optimizer.defaults.items() if key != "lr"}
            self.optimizer = self.optimizer_class(groups, lr=lr_schedule(1), **defaults)  # type: ignore[call-arg]
            apply_lr_scales(self.optimizer)

    def _make_mixer(self) -> nn.Module:
        return QMixer(
            self.n_agents,
            self.state_dim,
            self.mixing_embed_dim,
            self.hypernet_hidden_dim,
            init=self.mixer_init,
        )

    def _build_joint_modules(self) -> None:
        self.mixer, self.mixer_target = self.with_target(self._make_mixer)

    def joint_module_names(self) -> list[str]:
        return ["mixer"]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            mixing_embed_dim=self.mixing_embed_dim,
            hypernet_hidden_dim=self.hypernet_hidden_dim,
            mixer_init=self.mixer_init,
        )
        return data


class VDNPolicy(QMIXPolicy):
    """Agent network plus a parameter-free :class:`SumMixer`.

    :param weight_average_tau: as :class:`~sb3_eps.common.policies.MultiAgentQPolicy`, but ``2e-4`` by default for VDN
        (``docs/results/qmix_vdn.md``); ``None`` takes the greedy actions from the online network.
    """

    def __init__(self, *args: Any, weight_average_tau: float | None = VDN_WEIGHT_AVERAGE_TAU, **kwargs: Any) -> None:
        super().__init__(*args, weight_average_tau=weight_average_tau, **kwargs)

    def _make_mixer(self) -> nn.Module:
        return SumMixer()
