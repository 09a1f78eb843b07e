"""Seed validation shared by every env of the project and by the bridge (``sb3_eps.make_vec_env``)."""

from __future__ import annotations

from typing import Any

import numpy as np


def check_seed(seed: Any) -> int | None:
    """Return ``seed`` as a Python int (or None), or raise a ValueError saying what a seed may be.

    NumPy integers are accepted because SB3 and ``np.random`` hand them out; bools are refused because
    ``True`` as a seed is always a mistake.

    :param seed: the seed given to ``reset`` or ``make_vec_env``
    :return: the seed as a non-negative Python int, or None
    """
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise ValueError(f"seed must be None or a non-negative int, got {seed!r} of type {type(seed).__name__}")
    if seed < 0:
        raise ValueError(f"seed must be None or a non-negative int, got {seed}")
    return int(seed)
