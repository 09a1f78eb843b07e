"""``python -m sb3_eps.grid``: a grid of training runs (algorithms x env ids x seeds), locally or on Ray.

Examples::

    python -m sb3_eps.grid --algos gdq qmix --envs MultiRobotNav-2-v0 MultiRobotNav-4-v0 --seeds 0 1 2 -f logs/grid
    python -m sb3_eps.grid --grid my_grid.yml                       # the grid in a YAML file (keys: the fields of Grid)
    python -m sb3_eps.grid --grid my_grid.yml --backend ray --address auto --shared-folder /mnt/shared/grid

Every run is a ``python -m sb3_eps.train`` process with its folder in ``<folder>/<algo>/<env id>_seed<seed>/``.
Running the grid again skips the finished runs, resumes the interrupted ones and starts the others again; a
summary is written to ``<folder>/grid.yml``. The file's keys, the backends and what a lost run does:
``docs/usage.md``, "Scaling out". A mistake is one line and exit status 2 before any run starts; the grid exits 1
when a run failed.
"""

from __future__ import annotations

import argparse
import io
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
import typing
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from sb3_eps import train
from sb3_eps.zoo.checkpoint import CHECKPOINT_NAME, CorruptCheckpoint, verify_checkpoint, write_text_atomic
from sb3_eps.zoo.cli import OneLineArgumentParser
from sb3_eps.zoo.config import DEFAULT_KEY, config_file, load_config_entries, load_yaml, resolve_config
from sb3_eps.zoo.errors import ConfigError, run_command
from sb3_eps.zoo.run_folder import final_model_name
from sb3_eps.zoo.schema import algorithm_spec, normalize_value

PROG = "python -m sb3_eps.grid"
SUMMARY_NAME = "grid.yml"
#: Flags of ``sb3_eps.train`` that the grid sets itself for every run.
RESERVED_TRAIN_FLAGS = (
    "--algo", "--env", "--seed", "-f", "--log-folder", "--run-name", "--resume", "-n", "--n-timesteps",
    "-conf", "--conf-file", "-params", "--hyperparams", "-optimize", "--optimize-hyperparameters",
)  # fmt: skip


# ---------------------------------------------------------------------------------------------- the grid
@dataclass
class Grid:
    """A grid of runs and what every run gets (see the module docstring)."""

    algos: list[str]
    envs: list[str] | None = None
    seeds: list[int] = field(default_factory=lambda: [0])
    n_timesteps: int | None = None
    conf_file: str | None = None
    hyperparams: list[str] = field(default_factory=list)
    train_args: list[str] = field(default_factory=list)
    cpus_per_run: int = 1


@dataclass(frozen=True)
class RunSpec:
    """One run of a grid: its identity and its ``sb3_eps.train`` flags (without the log folder)."""

    algo: str
    env: str
    seed: int
    flags: tuple[str, ...]

    @property
    def name(self) -> str:
        """The run folder's name, ``<env id>_seed<seed>``."""
        return f"{self.env}_seed{self.seed}"


def load_grid_file(path: str | Path) -> dict[str, Any]:
    """:return: the keys of a grid YAML file (checked by :func:`make_grid`). :raises ConfigError: for an unreadable
    file or one that is not a mapping."""
    data = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a grid file maps keys ({', '.join(field.name for field in fields(Grid))}) to values")
    return data


def make_grid(values: dict[str, Any]) -> Grid:
    """Check the grid's keys (from a file and the command line) against the types of :class:`Grid` and return it.

    :raises ConfigError: naming the key and what is allowed
    """
    if not values.get("algos"):
        raise ConfigError("grid: no algorithms; give --algos (e.g. --algos gdq qmix) or algos: in the grid file")
    values = {key: [value] if isinstance(value, str) and key != "conf_file" else value
              for key, value in values.items() if value is not None}  # fmt: skip
    if isinstance(values.get("seeds"), int) and not isinstance(values["seeds"], bool):
        values["seeds"] = list(range(values["seeds"]))  # a count
    hints = typing.get_type_hints(Grid)
    unknown = sorted(set(values) - set(hints))
    if unknown:
        raise ConfigError(f"grid: unknown key(s) {unknown}; allowed: {', '.join(hints)}")
    grid = Grid(**{key: normalize_value(value, hints[key], f"grid: {key}", key) for key, value in values.items()})
    for algo in grid.algos:
        algorithm_spec(algo)  # an unknown name is refused with the allowed ones
    if not grid.seeds:
        raise ConfigError("grid: seeds is empty; give at least one seed (or a count)")
    for arg in grid.train_args:
        if arg.split("=")[0] in RESERVED_TRAIN_FLAGS:
            raise ConfigError(
                f"grid: train_args may not hold {arg.split('=')[0]}: the grid sets it (use the grid's algos, envs, "
                "seeds, n_timesteps, conf_file, hyperparams keys)"
            )
    grid.envs = grid.envs or None
    grid.seeds = list(dict.fromkeys(grid.seeds))
    return grid


def grid_runs(grid: Grid) -> list[RunSpec]:
    """Expand the grid into its runs, resolving every run's config first, so a mistake stops the grid before any
    run starts.

    :raises ConfigError: for an env id, config or override that a run would refuse
    """
    runs = []
    for algo in grid.algos:
        env_ids = grid.envs
        if env_ids is None:  # every env entry of the algorithm's config file
            path = config_file(algo, grid.conf_file)
            env_ids = [key for key in load_config_entries(path, algo) if key != DEFAULT_KEY]
            if not env_ids:
                raise ConfigError(f"grid: {path} has no env entries; give the env ids with --envs")
        for env_id in env_ids:
            resolve_config(algo, env_id, grid.conf_file, grid.hyperparams, grid.n_timesteps)
            for seed in grid.seeds:
                flags = ["--algo", algo, "--env", env_id, "--seed", str(seed)]
                if grid.n_timesteps is not None:
                    flags += ["-n", str(grid.n_timesteps)]
                if grid.conf_file is not None:
                    flags += ["-conf", grid.conf_file]
                if grid.hyperparams:
                    flags += ["--hyperparams", *grid.hyperparams]
                runs.append(RunSpec(algo, env_id, seed, (*flags, *grid.train_args)))
    try:  # the extra flags must parse as sb3_eps.train's
        train.make_parser().parse_args([*runs[0].flags, "--run-name", runs[0].name])
    except (SystemExit, ConfigError) as error:
        raise ConfigError(f"grid: train_args {grid.train_args} are not flags of python -m sb3_eps.train: {error}") from None
    return runs


# ---------------------------------------------------------------------------------------------- one run
def run_state(run_dir: Path, env_id: str) -> str:
    """:return: ``"new"`` (no folder), ``"complete"``, ``"interrupted"`` (a checkpoint to resume from) or
    ``"incomplete"`` (stopped before its first checkpoint: nothing to resume)."""
    if not run_dir.is_dir():
        return "new"
    checkpoint, final = run_dir / CHECKPOINT_NAME, run_dir / final_model_name(env_id)
    if checkpoint.is_file():
        try:
            complete = bool(verify_checkpoint(checkpoint).get("complete"))
        except CorruptCheckpoint:
            return "incomplete"
        return "complete" if complete and final.is_file() else "interrupted"
    return "complete" if final.is_file() else "incomplete"


def _kill_with_parent() -> None:
    """In the run's process (Linux): die when the process that started it dies, so a lost grid or Ray task never
    leaves a run training on behind the retried one."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def execute_run(
    spec: RunSpec, folder: str | Path, on_start: Callable[[subprocess.Popen], None] | None = None
) -> dict[str, Any]:
    """Bring one run of a grid to its end in ``<folder>/<algo>/<name>``: skip it when complete, resume it from its
    checkpoint when interrupted, else start it (moving an incomplete folder aside).

    :param spec: the run
    :param folder: the grid's log folder
    :param on_start: called with the run's process once it started (to forward signals)
    :return: the run's report: ``algo``, ``env``, ``seed``, ``run_dir``, ``before`` and ``status`` (run states),
        ``action`` (skipped, resumed, started), ``returncode``, ``seconds``, ``host``
    """
    folder = Path(folder)
    run_dir = folder / spec.algo / spec.name
    log_path = folder / spec.algo / f"{spec.name}.log"
    before = run_state(run_dir, spec.env)
    report = _skipped(spec, folder, before)
    if before == "complete":
        return report
    if before == "incomplete":
        number = 1
        while (aside := run_dir.with_name(f"{spec.name}.incomplete-{number}")).exists():
            number += 1
        run_dir.rename(aside)
    new = [*spec.flags, "-f", str(folder), "--run-name", spec.name]
    command = [sys.executable, "-m", "sb3_eps.train", *(["--resume", str(run_dir)] if before == "interrupted" else new)]
    log_path.parent.mkdir(parents=True, exist_ok=True)
    start = time.time()
    with open(log_path, "a") as log:
        log.write(f"# {time.strftime('%Y-%m-%d %H:%M:%S')} on {report['host']}: {' '.join(command)}\n")
        log.flush()
        process = subprocess.Popen(
            command,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # a Ctrl-C reaches the grid only; it forwards one SIGTERM
            preexec_fn=_kill_with_parent if sys.platform.startswith("linux") else None,
        )
        if on_start is not None:
            on_start(process)
        returncode = process.wait()
    return {
        **report,
        "action": "resumed" if before == "interrupted" else "started",
        "returncode": returncode,
        "seconds": round(time.time() - start, 2),
        # A run stopped by the grid's SIGTERM before its own handlers were set is not a failure: run it again.
        "status": run_state(run_dir, spec.env) if returncode in (0, -signal.SIGTERM) else "failed",
    }


# ---------------------------------------------------------------------------------------------- backends
class LocalBackend:
    """Runs side by side in processes of this machine, at most ``n_jobs`` at a time."""

    def __init__(self, n_jobs: int) -> None:
        self.n_jobs = n_jobs
        self._stopping = threading.Event()
        self._running: set[subprocess.Popen] = set()
        self._lock = threading.Lock()

    def stop(self) -> None:
        """Stop the grid: each running run gets one SIGTERM (it checkpoints), pending runs do not start."""
        self._stopping.set()
        with self._lock:
            for process in self._running:
                if process.poll() is None:
                    process.send_signal(signal.SIGTERM)

    def _one(self, spec: RunSpec, folder: Path) -> dict[str, Any] | None:
        if self._stopping.is_set():
            return None

        def register(process: subprocess.Popen) -> None:
            with self._lock:
                self._running.add(process)
                if self._stopping.is_set():
                    process.send_signal(signal.SIGTERM)

        return execute_run(spec, folder, on_start=register)

    def run(self, runs: Sequence[RunSpec], folder: Path, report: Callable[[dict[str, Any]], None]) -> None:
        """Run every run, calling ``report`` with each finished run's report."""
        with ThreadPoolExecutor(max_workers=self.n_jobs) as pool:
            futures = [pool.submit(self._one, spec, folder) for spec in runs]
            for future in futures:
                result = future.result()
                if result is not None:
                    report(result)


def _ray_task(spec: RunSpec, shared_folder: str | None) -> dict[str, Any]:
    """A Ray task: one run, in the shared folder, or in a temporary folder whose run is sent back (tar.gz)."""
    if shared_folder is not None:
        return execute_run(spec, shared_folder)
    with tempfile.TemporaryDirectory(prefix="sb3_eps_grid_") as scratch:
        result = execute_run(spec, scratch)
        archive = io.BytesIO()
        with tarfile.open(fileobj=archive, mode="w:gz") as tar:
            tar.add(Path(scratch) / spec.algo, arcname=spec.algo)
        result["archive"] = archive.getvalue()
        result["run_dir"] = f"{spec.algo}/{spec.name}"
        return result


class RayBackend:
    """One Ray task per run on a Ray cluster (see the module docstring)."""

    def __init__(
        self,
        address: str | None,
        cpus_per_run: int,
        shared_folder: str | None,
        max_retries: int = 3,
    ) -> None:
        try:
            import ray
        except ImportError:
            raise ConfigError("--backend ray needs Ray: pip install 'sb3-eps[ray]' (or pip install ray)") from None
        self.ray = ray
        self.address = address
        self.cpus_per_run = cpus_per_run
        self.shared_folder = shared_folder
        self.max_retries = max_retries

    def run(self, runs: Sequence[RunSpec], folder: Path, report: Callable[[dict[str, Any]], None]) -> None:
        """Submit one task per run, gather the results as they come (unpacking runs sent back into ``folder``)."""
        ray = self.ray
        started_here = not ray.is_initialized()
        if started_here:
            ray.init(address=self.address)
        try:
            task = ray.remote(num_cpus=self.cpus_per_run, max_retries=self.max_retries)(_ray_task)
            target = None if self.shared_folder is None else str(Path(self.shared_folder).resolve())
            pending = {}
            for spec in runs:
                if target is None and run_state(folder / spec.algo / spec.name, spec.env) == "complete":
                    report(_skipped(spec, folder))  # sent back earlier: nothing to send to a node
                    continue
                pending[task.remote(spec, target)] = spec
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                spec = pending.pop(done[0])
                try:
                    result = ray.get(done[0])
                except ray.exceptions.RayError as error:
                    result = {
                        **_skipped(spec, folder),
                        "action": "lost",
                        "status": "failed",
                        "error": str(error),
                    }
                if "archive" in result:
                    _unpack(result.pop("archive"), folder, spec)
                    result["run_dir"] = str(folder / result["run_dir"])
                report(result)
        finally:
            if started_here:
                ray.shutdown()


def _skipped(spec: RunSpec, folder: Path, before: str = "complete") -> dict[str, Any]:
    """:return: the report of a run left as it is (its ``action`` and ``status`` replaced when it runs)."""
    return {
        "algo": spec.algo, "env": spec.env, "seed": spec.seed, "run_dir": str(folder / spec.algo / spec.name),
        "before": before, "action": "skipped", "status": "complete", "returncode": None, "seconds": 0.0,
        "host": os.uname().nodename,
    }  # fmt: skip


def _unpack(archive: bytes, folder: Path, spec: RunSpec) -> None:
    """Unpack a run sent back by a Ray task into ``folder`` (replacing an older copy of the same run)."""
    target = folder / spec.algo / spec.name
    if target.exists():
        shutil.rmtree(target)
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        tar.extractall(folder, filter="data")


# ---------------------------------------------------------------------------------------------- the command
def run_grid(
    grid: Grid,
    folder: str | Path,
    backend: str = "local",
    n_jobs: int | None = None,
    address: str | None = None,
    shared_folder: str | None = None,
    max_retries: int = 3,
    verbose: int = 1,
) -> list[dict[str, Any]]:
    """Run a grid to its end (see the module docstring) and write ``<folder>/grid.yml``.

    :param grid: the grid
    :param folder: the log folder gathering every run folder (with ``shared_folder``, the shared one is used)
    :param backend: ``"local"`` or ``"ray"``
    :param n_jobs: local backend: runs side by side (None: cores // cpus_per_run, at least 1)
    :param address: ray backend: the cluster address (None: a local Ray instance)
    :param shared_folder: ray backend: a folder every node sees at the same path; the runs are written there
    :param max_retries: ray backend: retries of a task lost with its worker or node
    :param verbose: 0: silent; 1: one line per finished run and a summary
    :return: the report of every run, in grid order
    :raises ConfigError: for a mistake in the grid, before any run starts
    """
    runs = grid_runs(grid)
    if backend == "ray":
        runner: Any = RayBackend(address, grid.cpus_per_run, shared_folder, max_retries)
        if shared_folder is not None:
            folder = shared_folder
    elif backend == "local":
        if n_jobs is None:
            n_jobs = max(1, (os.cpu_count() or 1) // grid.cpus_per_run)
        if n_jobs < 1:
            raise ConfigError(f"--n-jobs must be >= 1, got {n_jobs}")
        runner = LocalBackend(n_jobs)
    else:
        raise ConfigError(f"--backend must be local or ray, got {backend!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    reports: dict[RunSpec, dict[str, Any]] = {}
    start = time.time()

    def report(result: dict[str, Any]) -> None:
        spec = next(s for s in runs if (s.algo, s.env, s.seed) == (result["algo"], result["env"], result["seed"]))
        reports[spec] = result
        if verbose >= 1:
            print(
                f"[{len(reports)}/{len(runs)}] {spec.algo} {spec.env} seed {spec.seed}: {result['action']} -> "
                f"{result['status']} ({result['seconds']:.0f} s) {result['run_dir']}",
                flush=True,
            )

    previous = {}
    if isinstance(runner, LocalBackend):
        previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
        for sig in previous:
            signal.signal(sig, lambda *_: runner.stop())
    try:
        runner.run(runs, folder, report)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    ordered = [reports.get(spec) or {**asdict(spec), "action": "not started", "status": "pending"} for spec in runs]
    for entry in ordered:
        entry.pop("flags", None)
    summary = {
        "backend": backend,
        "wall_seconds": round(time.time() - start, 2),
        "grid": asdict(grid),
        "runs": ordered,
    }
    write_text_atomic(folder / SUMMARY_NAME, yaml.safe_dump(summary, sort_keys=False))
    if verbose >= 1:
        counts = Counter(entry["status"] for entry in ordered)
        status = ", ".join(f"{n} {name}" for name, n in counts.items())
        print(f"Grid of {len(runs)} runs in {summary['wall_seconds']:.0f} s: {status}; summary {folder / SUMMARY_NAME}")
    return ordered


def make_parser() -> argparse.ArgumentParser:
    """:return: the parser of ``python -m sb3_eps.grid``."""
    parser = OneLineArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--grid", default=None, metavar="GRID.yml", help="the grid in a YAML file")
    parser.add_argument("--algos", nargs="+", default=None, help="algorithms (e.g. gdq qmix)")
    parser.add_argument("--envs", nargs="+", default=None, help="env ids (default: every entry of the configs)")
    parser.add_argument("--seeds", nargs="+", type=int, default=None, help="seeds (default 0)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="total timesteps of every run")
    parser.add_argument("-conf", "--conf-file", default=None, help="config file of every run")
    parser.add_argument("-params", "--hyperparams", nargs="+", default=None, metavar="KEY:VALUE")
    parser.add_argument(
        "--train-args",
        type=shlex.split,
        default=None,
        help='other flags of sb3_eps.train, one string: "--eval-freq 0 --vec-env subproc"',
    )
    parser.add_argument("-f", "--log-folder", dest="folder", default="logs/grid", help="the grid's log folder")
    parser.add_argument("--backend", choices=["local", "ray"], default="local")
    parser.add_argument("--n-jobs", type=int, default=None, help="local: runs side by side (default: one per core)")
    parser.add_argument("--cpus-per-run", type=int, default=None, help="cores each run reserves (default 1)")
    parser.add_argument("--address", default=None, help="ray: cluster address (auto, ray://head:10001)")
    parser.add_argument("--shared-folder", default=None, help="ray: a folder all nodes mount at the same path")
    parser.add_argument("--max-retries", type=int, default=3, help="ray: retries of a task lost with its node")
    parser.add_argument("--verbose", type=int, default=1)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line. :return: the exit status (1 when a run failed)."""
    args = make_parser().parse_args(argv)
    values: dict[str, Any] = load_grid_file(args.grid) if args.grid else {}
    flags = {field.name: getattr(args, field.name) for field in fields(Grid)}  # the flags override the file
    values.update((key, value) for key, value in flags.items() if value is not None)
    if args.max_retries < 0:
        raise ConfigError(f"--max-retries must be >= 0, got {args.max_retries}")
    results = run_grid(
        make_grid(values), args.folder, args.backend, args.n_jobs, args.address, args.shared_folder,
        args.max_retries, verbose=args.verbose,
    )  # fmt: skip
    return 1 if any(result["status"] == "failed" for result in results) else 0


def cli() -> None:
    """Console-script entry point: mistakes in the grid are one line on stderr and exit status 2."""
    run_command(PROG, main)


if __name__ == "__main__":
    cli()
