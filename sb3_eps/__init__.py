"""sb3-eps: multi-robot value-based RL (IQL, GDQ, QMIX, VDN) and Evolutionary Policy Search for SB3."""

from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.common.export import export_policy
from sb3_eps.common.ladder import learn_ladder
from sb3_eps.common.vec_env import MultiAgentVecEnv, make_vec_env
from sb3_eps.eps import EPSSettings, EvolutionCallback
from sb3_eps.gdq import GDQ
from sb3_eps.iql import IQL
from sb3_eps.qmix import QMIX, VDN
from sb3_eps.version import __version__

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
]
