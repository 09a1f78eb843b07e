from sb3_eps.iql.iql import IQL
from sb3_eps.iql.policies import MlpPolicy

__all__ = ["IQL", "MlpPolicy"]
