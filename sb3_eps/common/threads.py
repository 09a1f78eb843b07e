"""Torch's intra-op threads, set to one when a model is built unless the user chose a count.

The networks are small: one thread trains as fast as one per core, and runs side by side keep their speed
(``docs/benchmarks.md``, threads).
"""

from __future__ import annotations

import os

import torch as th

#: Threads a model sets when the user chose none.
DEFAULT_TORCH_THREADS = 1
#: Torch's thread count when the package was imported: a different count at model construction is the user's choice.
_THREADS_AT_IMPORT = th.get_num_threads()


def set_torch_threads() -> int:
    """Set torch's intra-op threads to :data:`DEFAULT_TORCH_THREADS` unless the user chose a count (``OMP_NUM_THREADS``
    or ``torch.set_num_threads`` since import); :return: the count in effect."""
    if "OMP_NUM_THREADS" not in os.environ and th.get_num_threads() == _THREADS_AT_IMPORT:
        th.set_num_threads(DEFAULT_TORCH_THREADS)
    return th.get_num_threads()
