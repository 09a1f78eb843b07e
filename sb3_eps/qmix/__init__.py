from sb3_eps.qmix.policies import QMixer, QMIXPolicy, SumMixer, VDNPolicy
from sb3_eps.qmix.qmix import QMIX, VDN

MlpPolicy = QMIXPolicy

__all__ = ["QMIX", "VDN", "MlpPolicy", "QMIXPolicy", "QMixer", "SumMixer", "VDNPolicy"]
