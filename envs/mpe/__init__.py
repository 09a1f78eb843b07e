"""Cooperative Navigation (mpe2 ``simple_spread``): the multi-agent env and its single-agent EPS variant."""

from envs.mpe.cooperative_navigation import CooperativeNavigationEnv
from envs.mpe.cooperative_navigation_single import CooperativeNavigationSingleEnv

__all__ = ["CooperativeNavigationEnv", "CooperativeNavigationSingleEnv"]
