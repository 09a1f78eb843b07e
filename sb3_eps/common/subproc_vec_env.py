"""The bridge with its worlds in worker processes: :class:`SubprocMultiAgentVecEnv`.

``make_vec_env(env_id, n_envs, vec_env_cls=SubprocVecEnv)`` (or ``"subproc"``) builds it. The worlds are split
into contiguous blocks. By default (:func:`default_layout`), on ``C`` cores the main process steps the first block
itself while ``C - 1`` worker processes step the others, side by side: the main process would otherwise wait idle
for its workers, and every worker is one more process to wake per step. With ``n_workers`` alone, every world
lives in those workers (the layout before ``main_worlds`` existed). Each worker runs an ordinary in-process
:class:`~sb3_eps.common.multi_agent_vec_env.MultiAgentVecEnv` over its block, with its own PyBullet clients, as
does the main process over its own block, and the main process concatenates the blocks. So every promise of the bridge
holds unchanged (each block's own bridge keeps them) and a seeded run gives the same numbers as in-process:
world ``w`` is still reset with ``seed + w``, and no state is shared between worlds.

A step goes to the workers as raw bytes (the actions) and comes back as raw bytes (observations, rewards, dones,
alive flags, the global state) plus the pickled infos; everything else is pickled. Where every process has a core
of its own, a process waiting for the next message polls its pipe for ``spin_s`` (10 ms) before it sleeps: waking
a sleeping process costs about as much as stepping a world (``docs/benchmarks.md``, scale-out).

The main process keeps what SB3 reads between steps (``alive``, ``reset_infos``, the tick counter, seeds and
reset options) and the global state of the last step: once :meth:`get_state` has been called, every step brings
the state back with the observations, so algorithms that read it every tick pay no extra round trip.

Pickling (the checkpoint of ``python -m sb3_eps.train``) asks every worker for a snapshot of its worlds,
mid-episode, and takes one of the main process's block; unpickling starts new workers from those snapshots, so a
resumed run continues exactly.

A worker that dies (killed, out of memory, a crash in PyBullet) raises :class:`VecEnvWorkerError` naming its
worlds; an exception inside a world of a worker is raised again in the main process as :class:`VecEnvWorkerError`
with the worker's traceback (one inside a world of the main process's block is raised as is, as in process).
Workers ignore SIGINT and SIGTERM: the main process decides when they stop (after writing its checkpoint), and a
worker whose main process is gone exits on its own.
"""

from __future__ import annotations

import atexit
import multiprocessing as mp
import os
import pickle
import select
import signal
import time
import traceback
import weakref
from collections.abc import Callable, Iterable, Sequence
from multiprocessing.connection import Connection
from multiprocessing.reduction import ForkingPickler
from typing import Any

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper, VecEnv, VecEnvStepReturn

from sb3_eps.common.multi_agent_vec_env import MultiAgentVecEnv
from sb3_eps.common.snapshots import snapshot_dumps

#: Seconds a worker gets to start (import, build its worlds) or to close before it is terminated.
START_TIMEOUT = 120.0
CLOSE_TIMEOUT = 10.0
#: Seconds a process polls its pipe without sleeping before it sleeps until the next message, where every process
#: of the vec env has a core of its own (``spin_s`` None). Waking a sleeping process costs 50-200 us on a VM (more
#: after milliseconds asleep), as much as stepping a world; a poll answers within microseconds. 10 ms covers the
#: learning between two training steps (2-6 ms for GDQ), so a worker stays awake through a run and sleeps only
#: through long pauses (evaluations, checkpoints): ``docs/benchmarks.md``, scale-out, measured 0, 0.5, 2 and 10 ms.
DEFAULT_SPIN_S = 0.01


# Vec envs with running workers. Their workers ignore SIGTERM, so multiprocessing's own exit handler (terminate,
# then join) would wait for them forever: this handler, registered later and so run first, closes them.
_OPEN: weakref.WeakSet[SubprocMultiAgentVecEnv] = weakref.WeakSet()


@atexit.register
def _close_open_vec_envs() -> None:
    for venv in list(_OPEN):
        venv.close()


_DOING = {
    "step": "stepping its worlds",
    "reset": "resetting its worlds",
    "get_state": "reading the global state",
    "snapshot": "taking a snapshot of its worlds (checkpoint)",
}


# What a pickled vec env leaves out: the live processes, their pipes, and the main block's worlds (snapshotted).
_PROCESS_LOCAL = ("_remotes", "_processes", "_ready", "_closed", "_slices", "_main_slice", "_local", "_step_in_flight")


class VecEnvWorkerError(RuntimeError):
    """A worker process of a :class:`SubprocMultiAgentVecEnv` died, or one of its worlds raised."""


def default_start_method() -> str:
    """``"fork"`` where available (workers start in milliseconds with everything imported), else ``"spawn"``."""
    return "fork" if "fork" in mp.get_all_start_methods() else "spawn"


def available_cores() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def default_n_workers(n_worlds: int) -> int:
    """One worker per core this process may use, at most one per world."""
    return max(1, min(n_worlds, available_cores()))


def default_layout(n_worlds: int, cores: int | None = None) -> tuple[int, int]:
    """The default split of ``n_worlds`` over the main process and workers: :return: ``(main_worlds, n_workers)``.

    With ``C`` cores and at least 2 worlds, the main process steps one block itself while ``C - 1`` workers step
    the others, side by side (``min(C, n_worlds)`` blocks of sizes differing by at most one; the main process
    takes the first). The main process would otherwise sit idle waiting for its workers, and a worker fewer is
    a process fewer to wake on every step (``docs/benchmarks.md``, scale-out). On one core, or with one world,
    every world goes to one worker.
    """
    cores = available_cores() if cores is None else cores
    steppers = min(cores, n_worlds)
    if steppers < 2:
        return 0, 1
    return len(split_worlds(n_worlds, steppers)[0]), steppers - 1


def overlap_layout(n_worlds: int, cores: int | None = None) -> dict[str, int]:
    """The layout for an algorithm with ``overlap_training``, as ``vec_env_kwargs``: every world in workers, one
    per core but the main process's (which learns while they step), at most one per world."""
    cores = available_cores() if cores is None else cores
    return {"main_worlds": 0, "n_workers": max(1, min(n_worlds, cores - 1))}


def split_worlds(n_worlds: int, n_workers: int) -> list[range]:
    """:return: the contiguous block of worlds of each worker, sizes differing by at most one."""
    base, extra = divmod(n_worlds, n_workers)
    blocks, start = [], 0
    for i in range(n_workers):
        size = base + (1 if i < extra else 0)
        blocks.append(range(start, start + size))
        start += size
    return blocks


_yield: Callable[[], Any] = getattr(os, "sched_yield", lambda: None)


def _poller(remote: Connection) -> Callable[[], Any]:
    """:return: a cheap "has ``remote`` a message (or is it closed)?" check: a ``poll(2)`` of its file descriptor
    (about 1 us; ``Connection.poll`` builds a selector on every call, about 10 us)."""
    if hasattr(select, "poll"):
        poller = select.poll()
        poller.register(remote.fileno(), select.POLLIN)
        return lambda: poller.poll(0)
    return remote.poll  # Windows


def _wait(ready: Callable[[], Any], spin_s: float) -> bool:
    """Return when ``ready()`` (a :func:`_poller`) is true, or after asking it for ``spin_s`` seconds without
    sleeping; the caller's ``recv`` then sleeps in the kernel until the message comes. Between two questions the
    process yields its core to any other runnable process there (on a busy machine, maybe the one it waits for).

    :return: whether the message came while polling
    """
    if spin_s <= 0:
        return False
    deadline = time.perf_counter() + spin_s
    while not ready():
        if time.perf_counter() > deadline:
            return False
        _yield()
    return True


# ---------------------------------------------------------------------------------------------- step messages
# The step, every tick, goes as raw bytes; everything else (and a step whose actions are not a 1-D int64 array)
# as a pickle, which starts with pickle's PROTO opcode. Pickling the few small arrays of a step (actions there,
# observations, rewards, dones and alive flags back) cost more than the rest of the protocol together.
_STEP, _STEP_WITH_STATE, _STEP_REPLY = b"s", b"S", b"R"
_HEADER = 8  # a message's first byte says what it is; arrays start 8-byte aligned


def _pack_step(actions: np.ndarray, want_state: bool) -> bytes | None:
    """:return: the step command as bytes, or None where the actions need the pickled command."""
    if actions.dtype != np.int64 or actions.ndim != 1:
        return None
    return (_STEP_WITH_STATE if want_state else _STEP).ljust(_HEADER, b"\0") + actions.tobytes()


def _unpack_step(message: bytes) -> tuple[np.ndarray, bool]:
    return np.frombuffer(message, dtype=np.int64, offset=_HEADER), message[:1] == _STEP_WITH_STATE


def _pack_step_reply(reply: tuple[Any, ...]) -> bytes | None:
    """The reply of :func:`_handle`'s step: its arrays as raw bytes, the rest (infos, reset infos) pickled.

    :return: None where an array holds Python objects (the pickled reply then)
    """
    obs, rewards, dones, infos, alive, state, reset_infos = reply
    arrays = [np.ascontiguousarray(array) for array in (obs, rewards, dones, alive)]
    if state is not None:
        arrays.append(np.ascontiguousarray(state))
    if any(array.dtype.hasobject for array in arrays):
        return None
    meta = pickle.dumps(
        ([(array.dtype.str, array.shape) for array in arrays], infos, reset_infos), protocol=pickle.HIGHEST_PROTOCOL
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
def _build_worker_env(payload: tuple[str, Any], t_start: float) -> MultiAgentVecEnv:
    kind, value = payload
    if kind == "snapshot":
        venv = pickle.loads(value)  # written by this class's __getstate__ in a process of this run
    else:
        env_fns, env_id = value.var
        venv = MultiAgentVecEnv(env_fns, env_id=env_id)
        venv._t_start = t_start  # episode "t" counts from the main process's vec env
    return venv


def _snapshot(venv: MultiAgentVecEnv) -> bytes:
    return snapshot_dumps(venv)  # the checkpoint's pickler: envs continue mid-episode


def _handle(venv: MultiAgentVecEnv, command: str, data: Any) -> Any:
    """Run one command of the main process on the worker's vec env; :return: the reply."""
    if command == "step":
        actions, want_state = data
        obs, rewards, dones, infos = venv.step(actions)
        reset_infos = venv.reset_infos if dones.any() else None
        return obs, rewards, dones, infos, venv.alive, venv.get_state() if want_state else None, reset_infos
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
        worlds, kind, name, args, kwargs = data
        return venv._world_call(worlds, kind, name, args, kwargs)
    if command == "snapshot":
        return _snapshot(venv)
    raise ValueError(f"unknown command {command!r}")


def _worker_main(
    remote: Connection, parent_remote: Connection, payload: tuple[str, Any], t_start: float, spin_s: float = 0.0
) -> None:
    # The main process decides when workers stop: a Ctrl-C or SIGTERM sent to the whole process group must not
    # kill the worlds before the main process has written its checkpoint (which asks them for a snapshot).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    parent_remote.close()
    venv: MultiAgentVecEnv | None = None
    ready = _poller(remote)
    try:
        venv = _build_worker_env(payload, t_start)
        remote.send(
            (
                "ok",
                (
                    venv.possible_agents,
                    venv.observation_space,
                    venv.action_space,
                    venv.state_space,
                ),
            )
        )
        poll = True
        while True:
            try:
                # Poll only where the last wait was short: after a long pause (an evaluation, a checkpoint) the
                # next one may be long too.
                idle_since = time.perf_counter()
                if poll:
                    _wait(ready, spin_s)
                message = remote.recv_bytes()
                poll = time.perf_counter() - idle_since <= spin_s
            except (EOFError, OSError):  # the main process is gone
                break
            if message[:1] in (_STEP, _STEP_WITH_STATE):
                command, data = "step", _unpack_step(message)
            else:
                command, data = ForkingPickler.loads(message)
            if command == "close":
                remote.send(("ok", None))
                break
            try:
                result = _handle(venv, command, data)
            except Exception as error:  # anything a world raises goes back to the main process
                remote.send(("error", f"{type(error).__name__}: {error}\n{traceback.format_exc()}"))
                continue
            packed = _pack_step_reply(result) if command == "step" else None
            if packed is not None:
                remote.send_bytes(packed)
            else:
                remote.send(("ok", result))
    except Exception as error:  # building the worlds failed
        try:
            remote.send(("error", f"{type(error).__name__}: {error}\n{traceback.format_exc()}"))
        except OSError:
            pass
    finally:
        if venv is not None:
            venv.close()
        remote.close()


# ---------------------------------------------------------------------------------------------- main side
class SubprocMultiAgentVecEnv(MultiAgentVecEnv):
    """A :class:`~sb3_eps.common.multi_agent_vec_env.MultiAgentVecEnv` whose worlds run in worker processes.

    Same attributes, step semantics and sub-env order as in-process (``docs/architecture.md``); world ``w`` lives
    in the worker whose block holds it, or in the main process's own block (the first ``main_worlds`` worlds),
    which the main process steps while the workers step theirs.

    :param env_fns: one constructor per world (PettingZoo ParallelEnv or gymnasium env); they are sent to the
        workers with cloudpickle, so lambdas and closures work
    :param env_id: the registered id the worlds were built from, for the record and error messages
    :param n_workers: worker processes, each holding a contiguous block of worlds (None: see ``main_worlds``)
    :param start_method: multiprocessing start method (None: ``"fork"`` where available, else ``"spawn"``)
    :param main_worlds: worlds the main process steps itself, side by side with the workers (the first ones).
        None: with ``n_workers`` None, :func:`default_layout` (on ``C`` cores, the main process holds one block and
        ``C - 1`` workers the others); with ``n_workers`` given, 0 (every world in a worker, as before this
        option). Given with ``n_workers`` None: the rest of the worlds go to one worker per remaining core.
    :param spin_s: seconds a worker waiting for its next command, and the main process waiting for a reply, poll
        their pipe without sleeping before they sleep (waking a sleeping process costs as much as stepping a
        world). None: :data:`DEFAULT_SPIN_S` where the main process and the workers have a core each (``n_workers
        + 1 <=`` cores, as in the default layout), else 0 (never poll: pollers would take the cores of the
        processes with work). A worker whose last wait for a command took longer than ``spin_s`` sleeps at once
        the next time (a long pause: an evaluation, a checkpoint). Polling keeps a core busy between steps: use 0
        on a machine shared with other jobs.
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
        if n_worlds < 1:
            raise ValueError("SubprocMultiAgentVecEnv needs at least one env constructor")
        if n_workers is not None and (
            isinstance(n_workers, bool) or not isinstance(n_workers, int | np.integer) or n_workers < 1
        ):
            raise ValueError(f"n_workers must be an int >= 1 (or None: one per core), got {n_workers!r}")
        if main_worlds is not None and (
            isinstance(main_worlds, bool)
            or not isinstance(main_worlds, int | np.integer)
            or not 0 <= main_worlds < n_worlds
        ):
            raise ValueError(
                f"main_worlds must be an int in [0, {n_worlds - 1}] (at least one of the {n_worlds} worlds in a "
                f"worker; DummyVecEnv keeps them all in this process), or None for the default; got {main_worlds!r}"
            )
        if start_method is not None and start_method not in mp.get_all_start_methods():
            raise ValueError(
                f"start_method {start_method!r} is not available here; use one of {mp.get_all_start_methods()}"
            )
        if spin_s is not None and (
            isinstance(spin_s, bool) or not isinstance(spin_s, int | float) or not 0 <= spin_s < float("inf")
        ):
            raise ValueError(f"spin_s must be a number of seconds >= 0 (or None for the default), got {spin_s!r}")
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
        payloads = [
            ("fns", CloudpickleWrapper(([env_fns[w] for w in block], env_id))) for block in self._blocks
        ]
        main_payload = (
            ("fns", CloudpickleWrapper(([env_fns[w] for w in self._main_block], env_id))) if main_worlds else None
        )
        self._start_workers(payloads, main_payload)

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
    def worker_pids(self) -> list[int | None]:
        """Process id of each worker (world block ``i`` lives in ``worker_pids[i]``)."""
        return [process.pid for process in self._processes]

    def _start_workers(self, payloads: list[tuple[str, Any]], main_payload: tuple[str, Any] | None) -> None:
        context: Any = mp.get_context(self.start_method)
        self._closed = False
        self._step_in_flight = False
        self._remotes: list[Connection] = []
        self._processes: list[Any] = []
        self._ready: list[Callable[[], Any]] = []
        self._local: MultiAgentVecEnv | None = None
        try:
            for payload in payloads:
                remote, child = context.Pipe()
                process = context.Process(
                    target=_worker_main, args=(child, remote, payload, self._t_start, self.spin_s), daemon=True
                )
                process.start()
                child.close()
                self._remotes.append(remote)
                self._processes.append(process)
                self._ready.append(_poller(remote))
            if main_payload is not None:  # built while the workers build theirs, after the forks
                self._local = _build_worker_env(main_payload, self._t_start)
            infos = [self._receive(i, "building its worlds", START_TIMEOUT) for i in range(len(payloads))]
        except BaseException:
            self._terminate()
            raise
        _OPEN.add(self)
        if self._local is not None:
            local = self._local
            infos.insert(
                0,
                (
                    local.possible_agents,
                    local.observation_space,
                    local.action_space,
                    local.state_space,
                ),
            )
        possible_agents, observation_space, action_space, state_space = infos[0]
        for info in infos[1:]:
            if info[0] != possible_agents:
                self._terminate()
                raise ValueError("all worlds must have the same possible_agents")
        self.possible_agents = list(possible_agents)
        self.n_agents = len(self.possible_agents)
        self.state_space = state_space
        self._main_slice = slice(0, len(self._main_block) * self.n_agents)
        self._slices = [
            slice(block.start * self.n_agents, block.stop * self.n_agents) for block in self._blocks
        ]
        VecEnv.__init__(self, self.n_worlds * self.n_agents, observation_space, action_space)
        self.alive = np.ones(self.num_envs, dtype=bool)
        self._actions = np.zeros(self.num_envs, dtype=np.int64)
        self._seed: int | None = None
        self._n_steps = 0
        self._state: np.ndarray | None = None
        self._want_state = False

    def _describe(self, i: int) -> str:
        block = self._blocks[i]
        worlds = f"world {block.start}" if len(block) == 1 else f"worlds {block.start}-{block.stop - 1}"
        name = f" of {self.env_id}" if self.env_id else ""
        return f"{worlds}{name} (worker {i}, pid {self._processes[i].pid})"

    def _died(self, i: int, doing: str) -> VecEnvWorkerError:
        process = self._processes[i]
        process.join(timeout=1.0)
        code = process.exitcode
        how = f"was killed by signal {-code}" if code is not None and code < 0 else f"exited ({code})"
        return VecEnvWorkerError(
            f"the worker process of {self._describe(i)} {how} while {doing}; its worlds are lost. A training "
            "run keeps its last checkpoint: continue it with python -m sb3_eps.train --resume <run folder>"
        )

    def _send(self, i: int, command: str, data: Any = None) -> None:
        try:
            self._remotes[i].send((command, data))
        except (BrokenPipeError, ConnectionResetError, EOFError, OSError):
            raise self._died(i, command) from None

    def _send_step(self, i: int, actions: np.ndarray, want_state: bool) -> None:
        message = _pack_step(actions, want_state)
        if message is None:
            self._send(i, "step", (actions, want_state))
            return
        try:
            self._remotes[i].send_bytes(message)
        except (BrokenPipeError, ConnectionResetError, EOFError, OSError):
            raise self._died(i, "step") from None

    def _receive(self, i: int, doing: str, timeout: float | None = None) -> Any:
        remote = self._remotes[i]
        try:
            if timeout is not None and not remote.poll(timeout):
                raise VecEnvWorkerError(
                    f"{self._describe(i)} did not answer within {timeout:.0f} s while {doing}"
                )
            _wait(self._ready[i], self.spin_s)
            message = remote.recv_bytes()
        except (EOFError, ConnectionResetError, BrokenPipeError, OSError):
            raise self._died(i, doing) from None
        if message[:1] == _STEP_REPLY:
            return _unpack_step_reply(message)
        status, value = ForkingPickler.loads(message)
        if status == "error":
            raise VecEnvWorkerError(f"{self._describe(i)} failed while {doing}: {value}")
        return value

    def _gather(self, workers: Iterable[int], doing: str) -> list[Any]:
        """Receive the reply of each of ``workers``, all of them even when one fails (so no reply stays in a pipe
        to answer the next command); then raise the first failure."""
        replies, failure = [], None
        for i in workers:
            try:
                replies.append(self._receive(i, doing))
            except VecEnvWorkerError as error:
                failure = failure or error
        if failure is not None:
            raise failure
        return replies

    def _ask_all(self, command: str, data: Sequence[Any] | None = None, local: Any = None) -> list[Any]:
        """Send ``command`` to every worker (``data[i]`` to worker ``i``), run it on the main process's block
        meanwhile (with ``local`` as its data), then gather the replies in order, the main block's first."""
        self._send_all(command, data)
        return self._finish_all(command, local)

    def _send_all(self, command: str, data: Sequence[Any] | None) -> None:
        if self._step_in_flight:
            raise RuntimeError(
                f"cannot {_DOING.get(command, command).replace('its', 'the')} while a step is in flight: call "
                "step_wait() after step_async() first"
            )
        for i in range(self.n_workers):
            if command == "step" and data is not None:
                self._send_step(i, *data[i])
            else:
                self._send(i, command, None if data is None else data[i])

    def _finish_all(self, command: str, local: Any) -> list[Any]:
        """The second half of :meth:`_ask_all`: the main block's share, then the workers' replies."""
        doing = _DOING.get(command, command)
        mine = self._while_workers_run(lambda venv: _handle(venv, command, local), doing)
        replies = self._gather(range(self.n_workers), doing)
        return replies if self._local is None else [mine, *replies]

    def _while_workers_run(self, work: Callable[[MultiAgentVecEnv], Any], doing: str) -> Any:
        """Run ``work`` on the main process's block while the workers run a command; if it raises, collect the
        workers' replies first (the error of the main block is the one raised, as in process)."""
        if self._local is None:
            return None
        try:
            return work(self._local)
        except BaseException:
            try:
                self._gather(range(self.n_workers), doing)
            except VecEnvWorkerError:
                pass
            raise

    # -------------------------------------------------------------------------------- VecEnv
    def reset(self) -> np.ndarray:
        """Reset every world (world ``w`` with ``seed + w`` after :meth:`seed`) and return all observations."""
        data = [
            (
                None if self._seed is None else self._seed + block.start,
                self._options[part],
                self._want_state,
            )
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
        self._send_all("step", [(actions[part], want_state) for part in self._slices])
        self._step_in_flight = True

    def step_wait(self) -> VecEnvStepReturn:
        """Step the main process's block (the workers step theirs meanwhile, since :meth:`step_async`), then
        return all agents' results."""
        if not self._step_in_flight:
            raise RuntimeError("step_wait() needs a step_async() before it")
        self._step_in_flight = False
        replies = self._finish_all("step", (self._actions[self._main_slice], self._want_state))
        obs, rewards, dones, alive = (self._join([reply[i] for reply in replies]) for i in (0, 1, 2, 4))
        infos = [info for reply in replies for info in reply[3]]
        self.alive = alive
        self._state = self._join_states([reply[5] for reply in replies])
        parts = self._slices if self._local is None else [self._main_slice, *self._slices]
        for part, reply in zip(parts, replies):
            if reply[6] is not None:
                self.reset_infos[part] = reply[6]
        self._n_steps += 1
        return obs, rewards, dones, infos

    def get_state(self) -> np.ndarray:
        """The current global state of each world, ``(n_worlds, state_dim)`` float32 (see the in-process bridge).

        After the first call, every step brings the state back with the observations.
        """
        if self._state is None:
            self._want_state = True
            self._state = self._join_states(self._ask_all("get_state"))
        assert self._state is not None
        return self._state

    def close(self) -> None:
        """Close every world and stop the workers (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._step_in_flight:  # the workers' step replies come before their answers to "close"
            self._step_in_flight = False
            try:
                self._gather(range(self.n_workers), _DOING["step"])
            except VecEnvWorkerError:
                pass
        for remote in self._remotes:
            try:
                remote.send(("close", None))
            except (EOFError, OSError):
                pass
        if self._local is not None:
            self._local.close()
        for remote in self._remotes:
            try:
                if remote.poll(CLOSE_TIMEOUT):
                    remote.recv()
            except (EOFError, OSError):
                pass
        self._terminate()

    def _terminate(self) -> None:
        self._closed = True
        _OPEN.discard(self)
        for process in self._processes:
            process.join(timeout=CLOSE_TIMEOUT)
            if process.is_alive():
                process.kill()  # it ignores SIGTERM
                process.join(timeout=1.0)
        for remote in self._remotes:
            remote.close()

    def _world_call(
        self,
        worlds: Iterable[int],
        kind: str,
        name: str | None = None,
        args: tuple[Any, ...] = (),
        kwargs: dict[str, Any] | None = None,
    ) -> dict[int, Any]:
        if self._step_in_flight:
            raise RuntimeError(f"cannot run {kind} {name or ''} while a step is in flight: call step_wait() first")
        wanted = set(worlds)
        asked = []
        for i, block in enumerate(self._blocks):
            local = [w - block.start for w in block if w in wanted]
            if local:
                self._send(i, "call", (local, kind, name, args, kwargs))
                asked.append(i)
        doing = f"running {kind} {name or ''}".strip()
        mine = [w for w in self._main_block if w in wanted]
        results: dict[int, Any] = {}
        if mine:  # the main block starts at world 0: its local indices are the global ones
            results.update(
                self._while_workers_run(lambda venv: venv._world_call(mine, kind, name, args, kwargs), doing)
            )
        for i, replies in zip(asked, self._gather(asked, doing)):
            start = self._blocks[i].start
            results.update((start + w, value) for w, value in replies.items())
        return results

    def _join(self, parts: list[np.ndarray]) -> np.ndarray:
        if len(parts) > 1:
            return np.concatenate(parts)
        return parts[0] if parts[0].flags.writeable else parts[0].copy()  # a step reply's arrays are read-only

    def _join_states(self, parts: list[np.ndarray | None]) -> np.ndarray | None:
        return None if any(part is None for part in parts) else self._join(parts)  # type: ignore[arg-type]

    # -------------------------------------------------------------------------------- pickling
    def __getstate__(self) -> dict[str, Any]:
        """The main process's bookkeeping plus a snapshot of every worker's worlds and of the main process's block
        (mid-episode)."""
        snapshots = self._ask_all("snapshot")
        state = {
            key: value
            for key, value in self.__dict__.items()
            if key not in _PROCESS_LOCAL
        }
        if self._local is not None:
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
        self.__dict__.update(state)
        self._start_workers(
            [("snapshot", snapshot) for snapshot in snapshots],
            None if main_snapshot is None else ("snapshot", main_snapshot),
        )
        self.__dict__.update(bookkeeping)
        self._state = None
