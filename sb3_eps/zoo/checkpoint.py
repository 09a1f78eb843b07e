"""Checkpoints that lose nothing (``<run>/checkpoint.zip``: what they hold and why resuming is exact,
``docs/usage.md``, "Checkpoints and --resume"), and the helpers that write files atomically. Checkpoints are
pickles: load only the ones you wrote."""

from __future__ import annotations

import io
import json
import os
import pickle
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.snapshots import rng_states, snapshot_dumps
from sb3_eps.zoo.errors import ConfigError

CHECKPOINT_NAME = "checkpoint.zip"
#: The checkpoint before the newest one, kept until a newer one is written and verified.
PREVIOUS_CHECKPOINT_NAME = "checkpoint.prev.zip"


class CorruptCheckpoint(ConfigError):
    """A checkpoint file that cannot be read back: truncated, corrupt, or not written by ``sb3_eps.train`` (one line
    on the command line, as a configuration mistake)."""


def _file_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


# mkstemp makes private (0600) files; written files get the mode a plain open() would give them.
_FILE_MODE = _file_mode()
_MEMBERS = ("model.zip", "training.pkl", "rng.pkl", "callbacks.pkl", "meta.json")


# ---------------------------------------------------------------------------------------------- atomic files
@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; when the block succeeds it is renamed onto ``path`` (atomic on
    POSIX), when it fails it is removed, so ``path`` always holds a complete file or its previous version.

    :param path: the file to write
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(handle)
    try:
        yield Path(temporary)
        with open(temporary, "rb+") as file:  # on disk before the rename: a crash never leaves an empty file
            os.fsync(file.fileno())
        os.chmod(temporary, _FILE_MODE)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    with atomic_path(path) as temporary:
        temporary.write_bytes(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename."""
    with atomic_path(path) as temporary:
        temporary.write_text(text)


def save_model_atomic(model: Any, path: str | Path) -> None:
    """``model.save(path)`` through a temporary file and a rename (``path`` ends with ``.zip``)."""
    buffer = io.BytesIO()
    model.save(buffer)
    write_bytes_atomic(path, buffer.getvalue())


# ---------------------------------------------------------------------------------------------- checkpoints
@dataclass
class Checkpoint:
    """A loaded checkpoint: the ``model.save`` archive, the model's ``rollout_state()`` with its ``env``, the global
    random states, callback name -> state, and ``meta.json`` (``num_timesteps``, ``ticks``, ``complete``...)."""

    model_bytes: bytes
    training: dict[str, Any]
    rng: dict[str, Any]
    callbacks: dict[str, Any]
    meta: dict[str, Any]


def save_checkpoint(
    path: str | Path,
    model: MultiAgentOffPolicyAlgorithm,
    callback_states: dict[str, Any],
    meta: dict[str, Any],
) -> None:
    """Write a checkpoint of ``model`` (taken between two iterations of ``learn``) atomically.

    :param path: the checkpoint file
    :param model: the model being trained
    :param callback_states: callback name -> picklable state
    :param meta: JSON-able facts (timesteps, ticks, total...)
    """
    model_buffer = io.BytesIO()
    model.save(model_buffer)
    training = {**model.rollout_state(), "env": model.env}
    members = {
        "model.zip": model_buffer.getvalue(),
        "training.pkl": snapshot_dumps(training),  # one pickle: the collector keeps pointing at the buffer
        "rng.pkl": pickle.dumps(rng_states()),
        "callbacks.pkl": snapshot_dumps(callback_states),
        "meta.json": json.dumps(meta, indent=2).encode(),
    }
    write_checkpoint(path, members)


def write_checkpoint(path: str | Path, members: dict[str, bytes], start: Callable[[Path], None] | None = None) -> None:
    """Write a checkpoint file through a temporary one, verified before it replaces ``path`` (whose previous version is
    kept as ``checkpoint.prev.zip``).

    :param members: member name -> content
    :param start: writes an archive of its own to the temporary file first (a plug-in trainer's), ``members`` are added
    """
    path = Path(path)
    with atomic_path(path) as temporary:
        if start is not None:
            start(temporary)
        with zipfile.ZipFile(temporary, "w" if start is None else "a", zipfile.ZIP_STORED) as archive:
            for name, data in members.items():
                archive.writestr(name, data)
        verify_checkpoint(temporary)
        if path.is_file():  # the new one is good: the current one becomes the previous one
            os.replace(path, path.with_name(PREVIOUS_CHECKPOINT_NAME))


def remove_checkpoints(path: str | Path) -> None:
    """Delete a checkpoint, its previous one and temporary files a killed writer left beside it."""
    path = Path(path)
    for candidate in (path, path.with_name(PREVIOUS_CHECKPOINT_NAME), *path.parent.glob(f".{path.name}.*.tmp")):
        candidate.unlink(missing_ok=True)


def verify_checkpoint(path: str | Path) -> dict[str, Any]:
    """Check that a checkpoint file is complete: a zip archive holding every member with a correct CRC and a
    readable ``meta.json``.

    :return: its ``meta.json``
    :raises CorruptCheckpoint: naming what is wrong, in one line
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            missing = [name for name in _MEMBERS if name not in archive.namelist()]
            if missing:
                raise CorruptCheckpoint(f"{path.name} lacks {', '.join(missing)}")
            damaged = archive.testzip()  # reads every member and checks its CRC-32
            if damaged is not None:
                raise CorruptCheckpoint(f"{path.name}: member {damaged} fails its CRC check")
            meta = json.loads(archive.read("meta.json"))
    except CorruptCheckpoint:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, zlib.error) as error:
        reason = " ".join(str(error).split()) or type(error).__name__
        raise CorruptCheckpoint(f"{path.name} is truncated or corrupt ({reason})") from None
    if not isinstance(meta, dict) or "num_timesteps" not in meta:
        raise CorruptCheckpoint(f"{path.name} has no valid meta.json")
    return meta


def latest_good_checkpoint(path: str | Path) -> tuple[Path, dict[str, Any], list[str]]:
    """Find the newest checkpoint that verifies: ``path``, else the previous one.

    :param path: the run's checkpoint file (``<run>/checkpoint.zip``)
    :return: ``(file, its meta, one line per newer file that was skipped and why)``
    :raises FileNotFoundError: when neither file exists
    :raises CorruptCheckpoint: when every existing one is damaged (the message lists why)
    """
    problems: list[str] = []
    for candidate in (Path(path), Path(path).with_name(PREVIOUS_CHECKPOINT_NAME)):
        if not candidate.is_file():
            continue
        try:
            return candidate, verify_checkpoint(candidate), problems
        except CorruptCheckpoint as error:
            problems.append(str(error))
    if not problems:
        raise FileNotFoundError(path)
    raise CorruptCheckpoint("; ".join(problems))


def load_checkpoint(path: str | Path) -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint` (a pickle: only load your own).

    :raises CorruptCheckpoint: when the file is damaged or not such a checkpoint
    """
    verify_checkpoint(path)
    with zipfile.ZipFile(path) as archive:
        data = {name: archive.read(name) for name in _MEMBERS}
    try:
        return Checkpoint(
            model_bytes=data["model.zip"],
            training=pickle.loads(data["training.pkl"]),  # our own checkpoint
            rng=pickle.loads(data["rng.pkl"]),
            callbacks=pickle.loads(data["callbacks.pkl"]),
            meta=json.loads(data["meta.json"]),
        )
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError, ValueError) as error:
        reason = " ".join(str(error).split()) or type(error).__name__
        raise CorruptCheckpoint(f"{Path(path).name} is not a checkpoint this version of sb3_eps can read ({reason})") from None


def restore_model(
    checkpoint: Checkpoint, algorithm_class: type[MultiAgentOffPolicyAlgorithm], device: str = "auto"
) -> MultiAgentOffPolicyAlgorithm:
    """Rebuild the model of a checkpoint with its env, replay buffer and n-step windows, ready to
    ``learn(remaining, reset_num_timesteps=False)``. The global random states are restored separately
    (:func:`~sb3_eps.common.snapshots.set_rng_states`), right before training goes on, because loading re-seeds them.

    :param checkpoint: the loaded checkpoint
    :param algorithm_class: the model's class
    :param device: torch device
    """
    training = checkpoint.training
    model = algorithm_class.load(io.BytesIO(checkpoint.model_bytes), env=None, device=device)
    # set_env without a reset keeps the saved _last_obs; it does not re-seed the env (load with env= would).
    model.set_env(training["env"], force_reset=False)
    model.set_rollout_state(training)
    return model
