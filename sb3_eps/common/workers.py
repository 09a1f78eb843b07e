"""Worker processes that answer the main process's commands over pipes (:class:`WorkerPool`), and
:class:`WorkerBlocks`, the one mechanism of the blocks of work spread over them and the main process: the worlds of
:class:`~sb3_eps.common.subproc_vec_env.SubprocMultiAgentVecEnv` and EPS's evaluation envs
(:class:`~sb3_eps.eps.evaluation.EnvPool`).

A worker holds a :class:`Served` object and answers every ``(command, data)`` with ``("ok", reply)`` or ``("error",
traceback)``. Workers ignore SIGINT and SIGTERM (the main process stops them after its checkpoint) and exit with it.
"""

from __future__ import annotations

import atexit
import contextlib
import multiprocessing as mp
import os
import select
import signal
import time
import traceback
import weakref
from collections.abc import Callable, Iterable, Sequence
from multiprocessing.connection import Connection
from multiprocessing.reduction import ForkingPickler
from typing import Any

#: Seconds a worker gets to start (import, build its object) or to close before it is killed.
START_TIMEOUT = 120.0
CLOSE_TIMEOUT = 10.0
_PICKLE = b"\x80"  # pickle's PROTO opcode: the first byte of every pickled message

# Pools with running workers: multiprocessing's exit handler (terminate, then join) would wait forever for workers
# that ignore SIGTERM; this handler, registered later and so run first, closes them.
_OPEN: weakref.WeakSet[WorkerPool] = weakref.WeakSet()


@atexit.register
def _close_open_pools() -> None:
    for pool in list(_OPEN):
        pool.close()


class WorkerError(RuntimeError):
    """A worker process died, did not answer in time, or its object raised."""


def default_start_method() -> str:
    """``"fork"`` where available (workers start in milliseconds with everything imported), else ``"spawn"``."""
    return "fork" if "fork" in mp.get_all_start_methods() else "spawn"


_yield: Callable[[], Any] = getattr(os, "sched_yield", lambda: None)


def poller(remote: Connection) -> Callable[[], Any]:
    """:return: a cheap "has ``remote`` a message?" check (``poll(2)``: ``Connection.poll`` costs ten times more)."""
    if hasattr(select, "poll"):
        fd_poller = select.poll()
        fd_poller.register(remote.fileno(), select.POLLIN)
        return lambda: fd_poller.poll(0)
    return remote.poll  # Windows


def spin_wait(ready: Callable[[], Any], spin_s: float) -> None:
    """Return when ``ready()`` is true, or after asking it for ``spin_s`` seconds, yielding the core in between."""
    deadline = time.perf_counter() + spin_s
    while spin_s > 0 and not ready() and time.perf_counter() <= deadline:
        _yield()


class Served:
    """What a worker process holds; a subclass answers commands in :meth:`handle`."""

    def hello(self) -> Any:
        return None

    def handle(self, command: str, data: Any) -> Any:
        raise ValueError(f"unknown command {command!r}")

    def unpack(self, message: bytes) -> tuple[str, Any]:
        """Read a raw-byte command as ``(command, data)``."""
        raise ValueError("this worker takes pickled commands only")

    def pack(self, command: str, reply: Any) -> bytes | None:
        """:return: the reply as raw bytes (not starting with a pickle's first byte), or None to pickle it."""
        return None

    def close(self) -> None:
        pass


def _error_reply(error: BaseException) -> tuple[str, str]:
    return "error", f"{type(error).__name__}: {error}\n{traceback.format_exc()}"


def _worker_main(
    remote: Connection, parent_remote: Connection, build: Callable[[Any], Served], payload: Any, spin_s: float
) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    parent_remote.close()
    served: Served | None = None
    ready = poller(remote)
    try:
        served = build(payload)
        remote.send(("ok", served.hello()))
        poll = True
        while True:
            try:
                # Poll only where the last wait was short: after a long pause (an evaluation, a checkpoint) the
                # next one may be long too.
                idle_since = time.perf_counter()
                if poll:
                    spin_wait(ready, spin_s)
                message = remote.recv_bytes()
                poll = time.perf_counter() - idle_since <= spin_s
            except (EOFError, OSError):  # the main process is gone
                break
            command, data = ForkingPickler.loads(message) if message[:1] == _PICKLE else served.unpack(message)
            if command == "close":
                remote.send(("ok", None))
                break
            try:
                reply = served.handle(command, data)
            except Exception as error:  # anything the object raises goes back to the main process
                remote.send(_error_reply(error))
                continue
            packed = served.pack(command, reply)
            if packed is not None:
                remote.send_bytes(packed)
            else:
                remote.send(("ok", reply))
    except Exception as error:  # building the object failed
        with contextlib.suppress(OSError):
            remote.send(_error_reply(error))
    finally:
        if served is not None:
            served.close()
        remote.close()


class WorkerPool:
    """One worker process per payload, each holding ``build(payload)``; worker ``i`` answers only its own pipe.

    :param build: a module-level function (picklable for ``"spawn"``) that makes a worker's :class:`Served`
    :param describe: names what worker ``i`` holds, for errors (``"worlds 2-3 of Corridor-2-v0"``)
    :param error: the exception class raised for a worker that dies, hangs or raises; ``hint`` ends a death's message
    :param spin_s: seconds a process waiting for a message polls its pipe before it sleeps
    :param unpack: reads a reply that a worker sent as raw bytes (:meth:`Served.pack`)
    :param pack: ``(command, data)`` as raw bytes for :meth:`Served.unpack` (not starting with a pickle's first
        byte), or None to pickle it
    """

    def __init__(
        self,
        build: Callable[[Any], Served],
        payloads: Sequence[Any],
        start_method: str | None = None,
        describe: Callable[[int], str] = lambda i: "a worker",
        error: type[Exception] = WorkerError,
        hint: str = "",
        spin_s: float = 0.0,
        close_timeout: float = CLOSE_TIMEOUT,
        unpack: Callable[[bytes], Any] = bytes,
        pack: Callable[[str, Any], bytes | None] = lambda command, data: None,
    ) -> None:
        context: Any = mp.get_context(start_method or default_start_method())
        self.describe, self.error, self.hint = describe, error, hint
        self.spin_s, self.close_timeout, self.unpack, self.pack = spin_s, close_timeout, unpack, pack
        self.closed = False
        self._remotes: list[Connection] = []
        self._processes: list[Any] = []
        self._ready: list[Callable[[], Any]] = []
        try:
            for payload in payloads:
                remote, child = context.Pipe()
                process = context.Process(target=_worker_main, args=(child, remote, build, payload, spin_s), daemon=True)
                process.start()
                child.close()
                self._remotes.append(remote)
                self._processes.append(process)
                self._ready.append(poller(remote))
        except BaseException:
            self.terminate()
            raise
        _OPEN.add(self)

    @property
    def pids(self) -> list[int]:
        return [int(process.pid) for process in self._processes]

    def name(self, i: int) -> str:
        return f"{self.describe(i)} (worker {i}, pid {self._processes[i].pid})"

    def _died(self, i: int, doing: str) -> Exception:
        process = self._processes[i]
        process.join(timeout=1.0)
        code = process.exitcode
        how = f"was killed by signal {-code}" if code is not None and code < 0 else f"exited ({code})"
        return self.error(f"the worker process of {self.name(i)} died: it {how} while {doing}{self.hint}")

    def send(self, i: int, command: str, data: Any = None, doing: str = "") -> None:
        """Send ``(command, data)`` to worker ``i``, as ``pack`` makes it or pickled."""
        message = self.pack(command, data)
        self.send_bytes(i, ForkingPickler.dumps((command, data)) if message is None else message, doing or command)

    def send_bytes(self, i: int, message: Any, doing: str) -> None:
        try:
            self._remotes[i].send_bytes(message)
        except (BrokenPipeError, ConnectionResetError, EOFError, OSError):
            raise self._died(i, doing) from None

    def recv(self, i: int, doing: str, timeout: float | None = None) -> Any:
        """:return: worker ``i``'s reply, within ``timeout`` seconds (None: as long as it lives); ``doing`` names
        what it was doing, for errors."""
        remote = self._remotes[i]
        try:
            if timeout is not None and not remote.poll(timeout):
                raise self.error(f"{self.name(i)} did not answer within {timeout:.0f} s while {doing}")
            spin_wait(self._ready[i], self.spin_s)
            message = remote.recv_bytes()
        except (EOFError, ConnectionResetError, BrokenPipeError, OSError):
            raise self._died(i, doing) from None
        if message[:1] != _PICKLE:
            return self.unpack(message)
        status, value = ForkingPickler.loads(message)
        if status == "error":
            raise self.error(f"{self.name(i)} failed while {doing}: {value}")
        return value

    def gather(self, workers: Iterable[int], doing: str, deadline: float | None = None) -> list[Any]:
        """Receive the reply of each of ``workers``, all of them even when one fails (so no reply stays in a pipe),
        before ``deadline`` (``time.monotonic()``; None: none); then raise the first failure."""
        replies, failure = [], None
        for i in workers:
            timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                replies.append(self.recv(i, doing, timeout))
            except self.error as error:
                failure = failure or error
        if failure is not None:
            raise failure
        return replies

    def close(self) -> None:
        """Ask every worker to close, then stop those that do not (idempotent)."""
        if self.closed:
            return
        for remote in self._remotes:
            with contextlib.suppress(EOFError, OSError):
                remote.send(("close", None))
        for remote in self._remotes:
            with contextlib.suppress(EOFError, OSError):
                if remote.poll(self.close_timeout):
                    remote.recv()
        self.terminate()

    def terminate(self) -> None:
        """Stop every worker now: join, and kill those still alive (they ignore SIGTERM)."""
        self.closed = True
        _OPEN.discard(self)
        for process in self._processes:
            process.join(timeout=self.close_timeout)
            if process.is_alive():
                process.kill()
                process.join(timeout=1.0)
        for remote in self._remotes:
            remote.close()


class WorkerBlocks:
    """Blocks of work: one per worker process (a :class:`WorkerPool` of ``build(payload)``), and optionally one in
    the main process (``local()``, built after the forks while the workers build theirs). A command goes to every
    worker, runs on the local block meanwhile, and the replies come back in block order, the local block's first.

    :param local: makes the main process's block (None: every block in a worker)
    :param pool_options: the :class:`WorkerPool`'s
    """

    def __init__(
        self,
        build: Callable[[Any], Served],
        payloads: Sequence[Any],
        local: Callable[[], Served] | None = None,
        **pool_options: Any,
    ) -> None:
        self.pool = WorkerPool(build, payloads, **pool_options)
        try:
            self.local = None if local is None else local()
        except BaseException:
            self.pool.terminate()
            raise

    @property
    def n_workers(self) -> int:
        return len(self.pool.pids)

    @property
    def closed(self) -> bool:
        return self.pool.closed

    def hellos(self, doing: str, deadline: float | None = None) -> list[Any]:
        """:return: every block's :meth:`Served.hello` (a worker's once its object is built), before ``deadline``."""
        replies = self.pool.gather(range(self.n_workers), doing, deadline)
        return replies if self.local is None else [self.local.hello(), *replies]

    def send(self, command: str, data: Sequence[Any] | None, doing: str) -> None:
        """Send ``command`` to every worker, ``data[i]`` to worker ``i``."""
        for i in range(self.n_workers):
            self.pool.send(i, command, None if data is None else data[i], doing)

    def finish(self, command: str, local: Any, doing: str, deadline: float | None = None) -> list[Any]:
        """Run ``command`` on the local block (with ``local`` as its data) while the workers run theirs, then gather
        the replies; if the local block raises, the workers' replies are collected first (its error is raised)."""
        workers = range(self.n_workers)
        if self.local is None:
            return self.pool.gather(workers, doing, deadline)
        try:
            mine = self.local.handle(command, local)
        except BaseException:
            with contextlib.suppress(self.pool.error):
                self.pool.gather(workers, doing, deadline)
            raise
        return [mine, *self.pool.gather(workers, doing, deadline)]

    def ask(
        self, command: str, data: Sequence[Any] | None, local: Any, doing: str, deadline: float | None = None
    ) -> list[Any]:
        """:meth:`send`, then :meth:`finish`."""
        self.send(command, data, doing)
        return self.finish(command, local, doing, deadline)

    def close(self) -> None:
        if self.local is not None:
            self.local.close()
            self.local = None
        self.pool.close()
