"""Torch's intra-op threads, set on purpose when a model is built.

The package's networks are small (two layers of 64 units): one thread trains a GDQ model as fast as torch's default
of one thread per core, and two runs side by side on 2 cores, each with torch's default threads, train 5.4x slower
than one run alone, while with one thread each they keep their speed (``benchmarks/threads_side_by_side.py``,
``docs/benchmarks.md``). So a model built through the Python API sets torch to one thread, as the command line does,
unless the user chose otherwise: with ``OMP_NUM_THREADS`` in the environment, or by calling
``torch.set_num_threads`` before building the model, the user's choice is kept.
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
    set, or ``torch.set_num_threads`` called since the package was imported).

    :return: the thread count in effect
    """
    if "OMP_NUM_THREADS" not in os.environ and th.get_num_threads() == _THREADS_AT_IMPORT:
        th.set_num_threads(DEFAULT_TORCH_THREADS)
    return th.get_num_threads()
