from sb3_eps.gdq.gdq import GDQ, gdq_agent_targets
from sb3_eps.gdq.policies import GDQPolicy, GlobalValueNetwork, MlpPolicy

__all__ = ["GDQ", "GDQPolicy", "GlobalValueNetwork", "MlpPolicy", "gdq_agent_targets"]
