from sb3_eps.iql.iql import IQL, MlpPolicy

__all__ = ["IQL", "MlpPolicy"]
