"""Snapshots of live objects: envs pickled mid-episode (:func:`snapshot_dumps`, for checkpoints and the worker vec
env's pickling, so a resumed run continues exactly), and the global random states."""

from __future__ import annotations

import io
import pickle
import random
from typing import Any

import numpy as np
import torch as th
from gymnasium.utils import EzPickle


def _rebuild(cls: type, args: tuple[Any, ...], kwargs: dict[str, Any]) -> Any:
    return cls(*args, **kwargs)


def _update_dict(obj: Any, state: dict[str, Any]) -> None:
    obj.__dict__.update(state)


def _picklable(value: Any) -> bool:
    try:
        pickle.dumps(value)
    except Exception:  # any failure means: leave it to the constructor
        return False
    return True


class SnapshotPickler(pickle.Pickler):
    """A pickler that captures envs mid-episode: an ``EzPickle`` object (mpe2's envs), which pickles as its
    constructor arguments, is rebuilt by its constructor and then given back every attribute that pickles."""

    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, EzPickle) and not isinstance(obj, type):
            state = {
                key: value
                for key, value in obj.__dict__.items()
                if key not in ("_ezpickle_args", "_ezpickle_kwargs") and _picklable(value)
            }
            arguments = (type(obj), tuple(obj._ezpickle_args), dict(obj._ezpickle_kwargs))
            return _rebuild, arguments, state, None, None, _update_dict
        return NotImplemented


def snapshot_dumps(obj: Any) -> bytes:
    """:return: ``obj`` pickled with :class:`SnapshotPickler`."""
    buffer = io.BytesIO()
    SnapshotPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buffer.getvalue()


def rng_states() -> dict[str, Any]:
    """:return: the states of Python's, NumPy's and torch's global random generators."""
    states: dict[str, Any] = {
        "python": random.getstate(),
        "numpy": np.random.get_state(),
        "torch": th.get_rng_state(),
    }
    if th.cuda.is_available():
        states["cuda"] = th.cuda.get_rng_state_all()
    return states


def set_rng_states(states: dict[str, Any]) -> None:
    """Restore what :func:`rng_states` returned."""
    random.setstate(states["python"])
    np.random.set_state(states["numpy"])
    th.set_rng_state(states["torch"])
    if "cuda" in states and th.cuda.is_available():
        th.cuda.set_rng_state_all(states["cuda"])
