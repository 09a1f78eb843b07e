"""Research instrumentation of the learners, outside the installed package: what explains GDQ's and QMIX's learning,
logged under ``train/`` every ``diagnostics_interval`` gradient steps (``docs/modules/gdq.md``, ``qmix.md``).

It plugs into the base's probe (``MultiAgentOffPolicyAlgorithm.diagnostics``), from Python::

    from research.diagnostics import attach
    attach(model)                      # GDQ: global_gain, action_margin...; QMIX / VDN: mixer_gain_sum...

or as a callback of a config entry (``callback: research.diagnostics.TrainDiagnostics``) with
``python -m sb3_eps.train --gym-packages research.diagnostics ...``. The probe reads the batch of a gradient step
before that step and changes nothing of the training.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_eps.common.buffers import JointReplayBufferSamples
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.gdq import GDQ
from sb3_eps.qmix import QMIX
from sb3_eps.zoo import register_callback

Probe = Callable[[Any, JointReplayBufferSamples], dict[str, float]]


def input_gain(head: Callable[..., th.Tensor], inputs: th.Tensor, *args: Any) -> th.Tensor:
    """``d head(inputs, *args).sum() / d inputs`` without touching any gradient of the head's parameters: the
    gain of a joint head (GDQ's ``V_G``, QMIX's mixer) with respect to each agent's value, per row."""
    probe = inputs.detach().clone().requires_grad_(True)
    with th.enable_grad():
        return th.autograd.grad(head(probe, *args).sum(), probe)[0]


def gdq_diagnostics(model: GDQ, batch: JointReplayBufferSamples) -> dict[str, float]:
    """What explains GDQ's learning (``docs/results/gdq_target.md``): the gain ``g_i = dV_G/dv_i`` of the global
    head, the greedy action's margin ``A(s, a*) - A(s, a_2nd)``, and the spread of the agents' values."""
    with th.no_grad():
        values = model._td_terms(batch).values
    gain = input_gain(model.policy.global_value_net, values * batch.alive)
    alive = batch.alive.bool()
    with th.no_grad():
        obs = batch.observations.reshape(-1, batch.observations.shape[-1])
        top2 = model.policy.q_net.advantage(obs).topk(2, dim=1).values
        margin = (top2[:, 0] - top2[:, 1]).reshape(alive.shape)[alive]
    values = values[alive]
    return {
        "global_gain": float(gain[alive].mean()),
        "global_gain_sum": float(gain.sum(dim=1).mean()),
        "action_margin": float(margin.mean()),
        "action_margin_small": float((margin < 0.01).float().mean()),
        "agent_value_mean": float(values.mean()),
        "agent_value_std": float(values.std()),
    }


def qmix_diagnostics(model: QMIX, batch: JointReplayBufferSamples) -> dict[str, float]:
    """The mixer's gain ``dQ_tot/dQ_i`` (sum over agents, spread across agents and rows), the agents' Q, and
    ``zero_input_gap``: ``mixer'(0; s') - mixer'(Q'; s')``, how far the target mixer moves with every agent at 0."""
    with th.no_grad():
        terms = model._td_terms(batch)
        agent_qs = terms.q_taken * batch.alive
        next_q = (terms.next_values + terms.next_advantage_term) * batch.alive * (1.0 - batch.dones)
        next_total = model.policy.mixer_target(next_q, batch.next_states)
        zero_total = model.policy.mixer_target(th.zeros_like(next_q), batch.next_states)
    gain = input_gain(model.policy.mixer, agent_qs, batch.states)
    return {
        "mixer_gain_sum": float(gain.sum(dim=1).mean()),
        "mixer_gain_std": float(gain[batch.alive > 0].std()),
        "agent_q_mean": float(agent_qs.sum() / batch.alive.sum().clamp(min=1)),
        "agent_q_max": float(agent_qs.abs().max()),
        "zero_input_gap": float((zero_total - next_total).mean()),
    }


def diagnostics_for(model: MultiAgentOffPolicyAlgorithm) -> Probe | None:
    """:return: the probe of the model's algorithm (GDQ's, QMIX's for QMIX and VDN), or None (IQL has none)."""
    if isinstance(model, GDQ):
        return gdq_diagnostics  # type: ignore[return-value]
    if isinstance(model, QMIX):
        return qmix_diagnostics  # type: ignore[return-value]
    return None


def attach(model: MultiAgentOffPolicyAlgorithm, interval: int = 250) -> MultiAgentOffPolicyAlgorithm:
    """Log the probe of the model's algorithm every ``interval`` gradient steps (from the first); :return: ``model``."""
    model.diagnostics = diagnostics_for(model)
    model.diagnostics_interval = int(interval)
    return model


class TrainDiagnostics(BaseCallback):
    """:func:`attach` as a callback, for config entries (``callback: research.diagnostics.TrainDiagnostics``).

    :param interval: gradient steps between two records
    """

    def __init__(self, interval: int = 250, verbose: int = 0) -> None:
        super().__init__(verbose=verbose)
        if not isinstance(interval, int) or interval < 1:
            raise ValueError(f"interval must be an int >= 1, got {interval!r}")
        self.interval = interval

    def _on_training_start(self) -> None:
        attach(self.model, self.interval)  # type: ignore[arg-type]

    def _on_step(self) -> bool:
        return True

    def state_dict(self) -> dict[str, Any]:
        """The callback keeps no state of its own (a resumed run attaches the probe again)."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Nothing to restore."""


register_callback(TrainDiagnostics, "research.diagnostics.TrainDiagnostics")
