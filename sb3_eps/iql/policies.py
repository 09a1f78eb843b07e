"""IQL policies: the shared dueling agent network and its target, no joint module."""

from sb3_eps.common.policies import MultiAgentQPolicy

MlpPolicy = MultiAgentQPolicy

__all__ = ["MlpPolicy"]
