"""sb3-eps: multi-robot value-based RL (IQL, GDQ, QMIX, VDN) and Evolutionary Policy Search for SB3."""

from sb3_eps.version import __version__

__all__ = ["__version__"]
