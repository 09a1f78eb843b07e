"""The bridge with its worlds in worker processes: :class:`SubprocMultiAgentVecEnv` (``vec_env_cls="subproc"``).

Each block of worlds is an in-process :class:`~sb3_eps.common.multi_agent_vec_env.MultiAgentVecEnv`, so a seeded run
gives the same numbers as in-process; pickling (a checkpoint) snapshots every block mid-episode.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import pickle
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper, VecEnvStepReturn

from sb3_eps.common.multi_agent_vec_env import MultiAgentVecEnv
from sb3_eps.common.snapshots import snapshot_dumps
from sb3_eps.common.utils import check_arguments
from sb3_eps.common.workers import START_TIMEOUT, Served, WorkerBlocks, WorkerError, default_start_method

#: Seconds a process polls its pipe without sleeping before it sleeps, where every process of the vec env has a
#: core of its own: waking a sleeping process costs about as much as stepping a world, and 10 ms covers the learning
#: between two training steps (``docs/benchmarks.md``, scale-out, measured 0, 0.5, 2 and 10 ms).
DEFAULT_SPIN_S = 0.01

_DOING = {
    "step": "stepping its worlds",
    "reset": "resetting its worlds",
    "get_state": "reading the global state",
    "snapshot": "taking a snapshot of its worlds (checkpoint)",
}
_RESUME_HINT = (
    "; its worlds are lost. A training run keeps its last checkpoint: continue it with python -m sb3_eps.train "
    "--resume <run folder>"
)
# What a pickled vec env leaves out: the live processes and the main block's worlds (snapshotted).
_PROCESS_LOCAL = ("_workers", "_slices", "_main_slice", "_step_in_flight")


class VecEnvWorkerError(WorkerError):
    """A worker process of a :class:`SubprocMultiAgentVecEnv` died, or one of its worlds raised."""


def available_cores() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def default_layout(n_worlds: int, cores: int | None = None) -> tuple[int, int]:
    """The default ``(main_worlds, n_workers)``: on ``C`` cores, the main process steps the first of ``min(C,
    n_worlds)`` blocks itself while ``C - 1`` workers step the others (``docs/benchmarks.md``, scale-out); on one
    core, or with one world, every world goes to one worker."""
    cores = available_cores() if cores is None else cores
    steppers = min(cores, n_worlds)
    if steppers < 2:
        return 0, 1
    return len(split_worlds(n_worlds, steppers)[0]), steppers - 1


def overlap_layout(n_worlds: int, cores: int | None = None) -> dict[str, int]:
    """The ``vec_env_kwargs`` for ``overlap_training``: every world in workers, one per core but the main process's."""
    cores = available_cores() if cores is None else cores
    return {"main_worlds": 0, "n_workers": max(1, min(n_worlds, cores - 1))}


def split_worlds(n_worlds: int, n_workers: int) -> list[range]:
    """:return: the contiguous block of worlds of each worker, sizes differing by at most one."""
    base, extra = divmod(n_worlds, n_workers)
    return [range(i * base + min(i, extra), (i + 1) * base + min(i + 1, extra)) for i in range(n_workers)]


# ---------------------------------------------------------------------------------------------- step messages
# The step, every tick, goes as raw bytes (pickling its small arrays cost more than the rest of the protocol).
_STEP, _STEP_WITH_STATE, _STEP_REPLY = b"s", b"S", b"R"
_HEADER = 8  # a message's first byte says what it is; arrays start 8-byte aligned


def _pack_step(command: str, data: Any) -> bytes | None:
    """:return: the step command as bytes, or None for another command or actions that need the pickled command."""
    if command != "step":
        return None
    actions, want_state = data
    if actions.dtype != np.int64 or actions.ndim != 1:
        return None
    return (_STEP_WITH_STATE if want_state else _STEP).ljust(_HEADER, b"\0") + actions.tobytes()


def _unpack_step(message: bytes) -> tuple[np.ndarray, bool]:
    return np.frombuffer(message, dtype=np.int64, offset=_HEADER), message[:1] == _STEP_WITH_STATE


def _pack_step_reply(reply: tuple[Any, ...]) -> bytes | None:
    """A step's reply: its arrays as raw bytes, the rest pickled; None where an array holds Python objects."""
    obs, rewards, dones, infos, alive, state, reset_infos = reply
    arrays = [np.ascontiguousarray(array) for array in (obs, rewards, dones, alive)]
    if state is not None:
        arrays.append(np.ascontiguousarray(state))
    if any(array.dtype.hasobject for array in arrays):
        return None
    meta = pickle.dumps(
        ([(array.dtype.str, array.shape) for array in arrays], infos, reset_infos),
        protocol=pickle.HIGHEST_PROTOCOL,
    )
    parts = [_STEP_REPLY.ljust(4, b"\0"), len(meta).to_bytes(4, "little"), meta]
    parts.append(b"\0" * (-len(meta) % 8))
    for array in arrays:
        data = array.tobytes()
        parts.extend((data, b"\0" * (-len(data) % 8)))
    return b"".join(parts)


def _unpack_step_reply(message: bytes) -> tuple[Any, ...]:
    size = int.from_bytes(message[4:8], "little")
    specs, infos, reset_infos = pickle.loads(memoryview(message)[_HEADER : _HEADER + size])
    offset = _HEADER + size + (-size % 8)
    arrays = []
    for dtype_str, shape in specs:
        dtype = np.dtype(dtype_str)
        count = int(np.prod(shape))
        arrays.append(np.frombuffer(message, dtype=dtype, count=count, offset=offset).reshape(shape))
        offset += count * dtype.itemsize
        offset += -offset % 8
    obs, rewards, dones, alive = arrays[:4]
    return obs, rewards, dones, infos, alive, arrays[4] if len(arrays) > 4 else None, reset_infos


# ---------------------------------------------------------------------------------------------- worker side
class _Worlds(Served):
    """A block of worlds, in a worker or in the main process; a worker's steps travel as raw bytes."""

    def __init__(self, payload: tuple[str, Any, float]) -> None:
        kind, value, t_start = payload
        if kind == "snapshot":
            self.venv = pickle.loads(value)  # written by SubprocMultiAgentVecEnv.__getstate__ in this run
        else:
            env_fns, env_id = value.var
            self.venv = MultiAgentVecEnv(env_fns, env_id=env_id)
            self.venv._t_start = t_start  # episode "t" counts from the main process's vec env

    def hello(self) -> tuple[Any, ...]:
        venv = self.venv
        return venv.possible_agents, venv.observation_space, venv.action_space, venv.state_space, venv.ticks_per_step

    def handle(self, command: str, data: Any) -> Any:
        venv = self.venv
        if command == "step":
            actions, want_state = data
            obs, rewards, dones, infos = venv.step(actions)
            reset_infos = venv.reset_infos if dones.any() else None
            return (
                obs,
                rewards,
                dones,
                infos,
                venv.alive,
                venv.get_state() if want_state else None,
                reset_infos,
            )
        if command == "reset":
            seed, options, want_state = data
            if seed is not None:
                venv.seed(seed)
            venv.set_options(options)
            obs = venv.reset()
            return obs, venv.reset_infos, venv.get_state() if want_state else None
        if command == "get_state":
            return venv.get_state()
        if command == "call":
            return venv._world_call(*data)
        if command == "snapshot":
            return snapshot_dumps(venv)  # the checkpoint's pickler: envs continue mid-episode
        return super().handle(command, data)

    def unpack(self, message: bytes) -> tuple[str, Any]:
        return "step", _unpack_step(message)

    def pack(self, command: str, reply: Any) -> bytes | None:
        return _pack_step_reply(reply) if command == "step" else None

    def close(self) -> None:
        self.venv.close()


# ---------------------------------------------------------------------------------------------- main side
class SubprocMultiAgentVecEnv(MultiAgentVecEnv):
    """A :class:`~sb3_eps.common.multi_agent_vec_env.MultiAgentVecEnv` whose worlds run in worker processes.

    :param env_fns: one constructor per world, sent to the workers with cloudpickle (lambdas and closures work)
    :param n_workers: worker processes, each holding a contiguous block of worlds (None: see ``main_worlds``)
    :param start_method: multiprocessing start method (None: ``"fork"`` where available, else ``"spawn"``)
    :param main_worlds: worlds the main process steps itself, side by side with the workers (the first ones).
        None: :func:`default_layout` with ``n_workers`` None, else 0. Given with ``n_workers`` None: the other
        worlds go to one worker per remaining core
    :param spin_s: seconds a waiting process polls its pipe before it sleeps. None: :data:`DEFAULT_SPIN_S` where
        the main process and the workers have a core each, else 0. Use 0 on a machine shared with other jobs
    """

    def __init__(
        self,
        env_fns: Sequence[Callable[[], ParallelEnv | gymnasium.Env]],
        env_id: str | None = None,
        n_workers: int | None = None,
        start_method: str | None = None,
        main_worlds: int | None = None,
        spin_s: float | None = None,
    ):
        n_worlds = len(env_fns)
        values = {"n_workers": n_workers, "main_worlds": main_worlds, "spin_s": spin_s}
        # At least one world in a worker (DummyVecEnv keeps them all in this process).
        ranges = {"n_workers": "[1, inf)", "main_worlds": f"[0, {n_worlds - 1}]", "spin_s": "[0, inf)"}
        check_arguments(SubprocMultiAgentVecEnv.__init__, values, ranges)
        if start_method is not None and start_method not in mp.get_all_start_methods():
            raise ValueError(f"start_method {start_method!r} is not available here; use one of {mp.get_all_start_methods()}")
        if main_worlds is None:
            if n_workers is None:
                main_worlds, n_workers = default_layout(n_worlds)
            else:
                main_worlds = 0
        elif n_workers is None:
            n_workers = max(1, available_cores() - (1 if main_worlds else 0))
        main_worlds = int(main_worlds)
        self.env_id = env_id
        self.n_worlds = n_worlds
        self.start_method = start_method or default_start_method()
        self._main_block = range(0, main_worlds)
        self._blocks = [
            range(block.start + main_worlds, block.stop + main_worlds)
            for block in split_worlds(n_worlds - main_worlds, min(int(n_workers), n_worlds - main_worlds))
        ]
        if spin_s is None:
            spin_s = DEFAULT_SPIN_S if len(self._blocks) + 1 <= available_cores() else 0.0
        self.spin_s = float(spin_s)
        self._t_start = time.time()
        main_payload, *payloads = (
            ("fns", CloudpickleWrapper(([env_fns[w] for w in block], env_id))) for block in [self._main_block, *self._blocks]
        )
        self._start_workers(payloads, main_payload if main_worlds else None)

    # -------------------------------------------------------------------------------- workers
    @property
    def n_workers(self) -> int:
        """Number of worker processes."""
        return len(self._blocks)

    @property
    def main_worlds(self) -> int:
        """Number of worlds the main process steps itself (worlds ``0 .. main_worlds - 1``)."""
        return len(self._main_block)

    @property
    def worker_pids(self) -> list[int]:
        """Process id of each worker (world block ``i`` lives in ``worker_pids[i]``)."""
        return self._workers.pool.pids

    def _start_workers(self, payloads: list[tuple[str, Any]], main_payload: tuple[str, Any] | None) -> None:
        self._step_in_flight = False
        t_start = self._t_start
        self._workers = WorkerBlocks(
            _Worlds,
            [(*payload, t_start) for payload in payloads],
            None if main_payload is None else lambda: _Worlds((*main_payload, t_start)),
            start_method=self.start_method,
            describe=self._describe,
            error=VecEnvWorkerError,
            hint=_RESUME_HINT,
            spin_s=self.spin_s,
            unpack=_unpack_step_reply,
            pack=_pack_step,
        )
        try:
            layouts = self._workers.hellos("building its worlds", time.monotonic() + START_TIMEOUT)
        except BaseException:
            self._workers.pool.terminate()
            raise
        possible_agents, observation_space, action_space, state_space, ticks_per_step = layouts[0]
        if any(layout[0] != possible_agents for layout in layouts[1:]):
            self.close()
            raise ValueError("all worlds must have the same possible_agents")
        self._set_layout(possible_agents, observation_space, action_space, state_space, ticks_per_step)
        self._main_slice = slice(0, len(self._main_block) * self.n_agents)
        self._slices = [slice(block.start * self.n_agents, block.stop * self.n_agents) for block in self._blocks]
        self._want_state = False

    def _describe(self, i: int) -> str:
        block = self._blocks[i]
        worlds = f"world {block.start}" if len(block) == 1 else f"worlds {block.start}-{block.stop - 1}"
        return f"{worlds} of {self.env_id}" if self.env_id else worlds

    def _ask_all(
        self, command: str, data: Sequence[Any] | None = None, local: Any = None, doing: str | None = None
    ) -> list[Any]:
        """:meth:`~sb3_eps.common.workers.WorkerBlocks.ask` once no step is in flight."""
        doing = self._no_step_in_flight(doing or _DOING.get(command, command))
        return self._workers.ask(command, data, local, doing)

    def _no_step_in_flight(self, doing: str) -> str:
        if self._step_in_flight:
            raise RuntimeError(
                f"a step is in flight: call step_wait() after step_async() before {doing.replace('its', 'the')}"
            )
        return doing

    # -------------------------------------------------------------------------------- VecEnv
    def reset(self) -> np.ndarray:
        """Reset every world (world ``w`` with ``seed + w`` after :meth:`seed`) and return all observations."""
        data = [
            (None if self._seed is None else self._seed + block.start, self._options[part], self._want_state)
            for block, part in zip(self._blocks, self._slices)
        ]
        local = (self._seed, self._options[self._main_slice], self._want_state)
        replies = self._ask_all("reset", data, local)
        obs = self._join([reply[0] for reply in replies])
        self.reset_infos = [info for reply in replies for info in reply[1]]
        self._state = self._join_states([reply[2] for reply in replies])
        self._seed = None
        self._reset_seeds()
        self._reset_options()
        self.alive = np.ones(self.num_envs, dtype=bool)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Send each worker its block's actions: the workers step their worlds from now on, while the caller does
        other work (an algorithm with ``overlap_training`` learns meanwhile) until :meth:`step_wait`."""
        super().step_async(actions)
        actions, want_state = self._actions, self._want_state
        self._workers.send(
            "step", [(actions[part], want_state) for part in self._slices], self._no_step_in_flight(_DOING["step"])
        )
        self._step_in_flight = True

    def step_wait(self) -> VecEnvStepReturn:
        """Step the main process's block (the workers step theirs meanwhile), then return all agents' results."""
        if not self._step_in_flight:
            raise RuntimeError("step_wait() needs a step_async() before it")
        self._step_in_flight = False
        replies = self._workers.finish("step", (self._actions[self._main_slice], self._want_state), _DOING["step"])
        obs, rewards, dones, alive = (self._join([reply[i] for reply in replies]) for i in (0, 1, 2, 4))
        infos = [info for reply in replies for info in reply[3]]
        self.alive = alive
        self._state = self._join_states([reply[5] for reply in replies])
        parts = self._slices if self._workers.local is None else [self._main_slice, *self._slices]
        for part, reply in zip(parts, replies):
            if reply[6] is not None:
                self.reset_infos[part] = reply[6]
        self._n_steps += 1
        return obs, rewards, dones, infos

    def get_state(self) -> np.ndarray:
        """The current global state of each world, ``(n_worlds, state_dim)`` float32 (see the in-process bridge).
        After the first call, every step brings the state back with the observations."""
        if self._state is None:
            self._want_state = True
            self._state = self._join_states(self._ask_all("get_state"))
        assert self._state is not None
        return self._state

    def close(self) -> None:
        """Close every world and stop the workers (idempotent)."""
        if self._workers.closed:
            return
        if self._step_in_flight:  # the workers' step replies come before their answers to "close"
            self._step_in_flight = False
            with contextlib.suppress(VecEnvWorkerError):
                self._workers.pool.gather(range(self.n_workers), _DOING["step"])
        self._workers.close()

    def _world_call(
        self,
        worlds: Iterable[int],
        kind: str,
        name: str | None = None,
        args: tuple[Any, ...] = (),
        kwargs: dict[str, Any] | None = None,
    ) -> dict[int, Any]:
        wanted = set(worlds)

        def request(block: range) -> tuple[Any, ...]:  # the block's wanted worlds by their index in the block
            return [w - block.start for w in block if w in wanted], kind, name, args, kwargs

        local = request(self._main_block) if self._workers.local is not None else None
        doing = f"running {kind} {name or ''}".strip()
        replies = self._ask_all("call", [request(block) for block in self._blocks], local, doing)
        blocks = self._blocks if self._workers.local is None else [self._main_block, *self._blocks]
        return {block.start + w: value for block, reply in zip(blocks, replies) for w, value in reply.items()}

    def _join(self, parts: list[np.ndarray]) -> np.ndarray:
        if len(parts) > 1:
            return np.concatenate(parts)
        # a step reply's arrays are read-only
        return parts[0] if parts[0].flags.writeable else parts[0].copy()

    def _join_states(self, parts: list[np.ndarray | None]) -> np.ndarray | None:
        return None if any(part is None for part in parts) else self._join(parts)  # type: ignore[arg-type]

    # -------------------------------------------------------------------------------- pickling
    def __getstate__(self) -> dict[str, Any]:
        """The main process's bookkeeping plus a snapshot of every block's worlds (mid-episode)."""
        snapshots = self._ask_all("snapshot")
        state = {key: value for key, value in super().__getstate__().items() if key not in _PROCESS_LOCAL}
        if self._workers.local is not None:
            state["_main_snapshot"], snapshots = snapshots[0], snapshots[1:]
        state["_snapshots"] = snapshots
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        snapshots = state.pop("_snapshots")
        main_snapshot = state.pop("_main_snapshot", None)
        bookkeeping: dict[str, Any] = {
            key: state[key]
            for key in ("alive", "_seed", "_seeds", "_options", "_n_steps", "_want_state", "reset_infos")
            if key in state
        }
        super().__setstate__(state)
        self._start_workers(
            [("snapshot", snapshot) for snapshot in snapshots],
            None if main_snapshot is None else ("snapshot", main_snapshot),
        )
        self.__dict__.update(bookkeeping)
        self._state = None
