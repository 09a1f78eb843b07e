"""sb3-eps: multi-robot value-based RL (IQL, GDQ, QMIX, VDN) and Evolutionary Policy Search for SB3."""

from __future__ import annotations

from typing import TYPE_CHECKING

from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.common.export import export_policy
from sb3_eps.common.ladder import learn_ladder
from sb3_eps.common.vec_env import MultiAgentVecEnv, make_vec_env
from sb3_eps.eps import EPSSettings, EvolutionCallback
from sb3_eps.gdq import GDQ
from sb3_eps.iql import IQL
from sb3_eps.qmix import QMIX, VDN
from sb3_eps.version import __version__

if TYPE_CHECKING:
    from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
    from sb3_eps.zoo.pretrained import ModelCard


def pretrained(algo: str, env_id: str, device: str = "auto") -> MultiAgentOffPolicyAlgorithm:
    """The shipped trained model of ``algo`` for ``env_id`` (``sb3_eps/trained_agents/``, RL Zoo's trained agents):
    ``model = sb3_eps.pretrained("gdq", "MultiRobotNav-12-v0")``. Its world options (a 1 m view, held decisions) are
    on its card, :func:`model_card`; ``python -m sb3_eps.enjoy`` plays it.

    :raises sb3_eps.zoo.ConfigError: when none is shipped (the message lists what is) or its file was changed
    """
    from sb3_eps.zoo.pretrained import load_pretrained

    return load_pretrained(algo, env_id, device)


def model_card(algo: str, env_id: str) -> ModelCard:
    """The card of the shipped model of ``algo`` for ``env_id``: training command, seed, world options
    (``card.env_kwargs``), code version, figures on 100 greedy team episodes, SHA-256."""
    from sb3_eps.zoo.pretrained import model_card as card

    return card(algo, env_id)


__all__ = [
    "GDQ",
    "IQL",
    "QMIX",
    "VDN",
    "EPSSettings",
    "EvolutionCallback",
    "MultiAgentVecEnv",
    "__version__",
    "evaluate_team",
    "export_policy",
    "learn_ladder",
    "make_vec_env",
    "model_card",
    "pretrained",
]
