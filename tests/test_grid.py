"""python -m sb3_eps.grid: skip the finished runs, resume the interrupted ones, gather every run folder in one log
folder; on the local backend and on a local Ray instance."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from sb3_eps import grid as grid_module
from sb3_eps.zoo.checkpoint import verify_checkpoint
from sb3_eps.zoo.errors import ConfigError

ENV_ID = "Corridor-2-v0"
# A tiny grid: 2 robots in a corridor, 3,000 agent-steps a run, a checkpoint every 300.
TINY = [
    "--algos",
    "gdq",
    "--envs",
    ENV_ID,
    "-n",
    "3000",
    "--train-args",
    "--eval-freq 0 --save-freq 300 --verbose 0",
]


def grid_command(folder: Path, *seeds: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "sb3_eps.grid",
        *TINY,
        "--seeds",
        *seeds,
        "-f",
        str(folder),
        "--n-jobs",
        "2",
    ]


def summary(folder: Path) -> dict[int, dict]:
    return {run["seed"]: run for run in yaml.safe_load((folder / "grid.yml").read_text())["runs"]}


def wait_for(condition, what: str, process: subprocess.Popen | None = None, timeout: float = 120) -> None:
    deadline = time.time() + timeout
    while not condition():
        assert process is None or process.poll() is None, f"the grid ended before {what}"
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_local_grid_skips_resumes_and_gathers(tmp_path) -> None:
    folder = tmp_path / "grid"
    # 1. Stop the grid (SIGTERM) once a run has written a checkpoint: its runs checkpoint and stop.
    process = subprocess.Popen(grid_command(folder, "0", "1"))
    wait_for(lambda: list(folder.glob("gdq/*/checkpoint.zip")), "a checkpoint", process)
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=120) == 0
    first = summary(folder)
    assert {run["status"] for run in first.values()} <= {"interrupted", "complete", "new", "incomplete"}
    interrupted = [seed for seed, run in first.items() if run["status"] == "interrupted"]
    assert interrupted, first
    stopped_at = {
        seed: verify_checkpoint(folder / "gdq" / f"{ENV_ID}_seed{seed}" / "checkpoint.zip")["num_timesteps"]
        for seed in interrupted
    }
    assert all(0 < timesteps < 3000 for timesteps in stopped_at.values())
    # A run that died before its first checkpoint: nothing to resume, it is moved aside and started again.
    stale = folder / "gdq" / f"{ENV_ID}_seed2"
    stale.mkdir(parents=True)
    (stale / "args.yml").write_text("algo: gdq\n")

    # 2. The same grid with one more seed: interrupted runs resume, the stale one starts again.
    assert subprocess.run(grid_command(folder, "0", "1", "2"), timeout=300).returncode == 0
    second = summary(folder)
    for seed in interrupted:
        assert second[seed]["action"] == "resumed" and second[seed]["status"] == "complete"
        log = (folder / "gdq" / f"{ENV_ID}_seed{seed}.log").read_text()
        assert "--resume" in log
        lines = (folder / "gdq" / f"{ENV_ID}_seed{seed}" / "progress.csv").read_text().splitlines()
        column = lines[0].split(",").index("time/total_timesteps")
        assert int(lines[-1].split(",")[column]) > stopped_at[seed]  # it went on from its checkpoint
    assert second[2]["before"] == "incomplete" and second[2]["status"] == "complete"
    assert (folder / "gdq" / f"{ENV_ID}_seed2.incomplete-1" / "args.yml").is_file()
    # Gathered: every run folder in the one log folder, each with its final model.
    for seed in (0, 1, 2):
        assert (folder / "gdq" / f"{ENV_ID}_seed{seed}" / f"{ENV_ID}.zip").is_file()
        assert not (folder / "gdq" / f"{ENV_ID}_seed{seed}" / "checkpoint.zip").exists()

    # 3. Once more: nothing left to do.
    start = time.time()
    assert subprocess.run(grid_command(folder, "0", "1", "2"), timeout=120).returncode == 0
    assert {run["action"] for run in summary(folder).values()} == {"skipped"}
    assert time.time() - start < 30


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--envs", ENV_ID], "no algorithms"),
        (["--algos", "dqn"], "unknown algorithm 'dqn'"),
        (["--algos", "gdq", "--envs", "Nope-v0"], "unknown env id 'Nope-v0'"),
        (["--algos", "gdq", "--envs", ENV_ID, "--seeds", "-1"], "seeds must be a list, each an int >= 0"),
        (["--algos", "gdq", "--envs", ENV_ID, "--train-args", "--seed 3"], "train_args may not hold --seed"),
        (["--algos", "gdq", "--envs", ENV_ID, "--train-args=--no-such-flag"], "not flags of"),
        (["--algos", "gdq", "--envs", ENV_ID, "--hyperparams", "gamma:7"], "gamma"),
        (["--algos", "gdq", "--envs", ENV_ID, "--n-jobs", "0"], "--n-jobs must be >= 1"),
    ],
)
def test_grid_mistakes_are_one_line_before_any_run(tmp_path, argv, message) -> None:
    with pytest.raises(ConfigError, match=message):
        grid_module.main([*argv, "-f", str(tmp_path / "grid")])
    assert not (tmp_path / "grid" / "gdq").exists()


def test_grid_file_keys_are_checked(tmp_path) -> None:
    path = tmp_path / "grid.yml"
    path.write_text("algos: [gdq]\nenvironments: [Corridor-2-v0]\n")
    with pytest.raises(ConfigError, match=r"unknown key.*environments"):
        grid_module.main(["--grid", str(path), "-f", str(tmp_path / "grid")])
    path.write_text("algos: [gdq]\nenvs: [Corridor-2-v0]\nseeds: 3\nn_timesteps: 100\n")
    runs = grid_module.grid_runs(grid_module.make_grid(grid_module.load_grid_file(path)))
    assert [(run.algo, run.env, run.seed) for run in runs] == [("gdq", ENV_ID, s) for s in range(3)]
    assert runs[0].name == f"{ENV_ID}_seed0" and "-n" in runs[0].flags


# --- Ray ------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ray_instance():
    """A local Ray instance of 2 CPUs (these tests run in ``make test-ray``, which installs the ray extra)."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def tiny_grid(*seeds: int) -> grid_module.Grid:
    return grid_module.Grid(
        algos=["gdq"], envs=[ENV_ID], seeds=list(seeds), n_timesteps=3000,
        train_args=["--eval-freq", "0", "--save-freq", "300", "--verbose", "0"],
    )  # fmt: skip


def train_process_of(run_name: str) -> tuple[int, int] | None:
    """(pid, parent pid) of the training process of a run, from /proc."""
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if f"--run-name\0{run_name}\0".encode() in cmdline.read_bytes() + b"\0":
                status = (cmdline.parent / "status").read_text()
                ppid = int(next(line.split()[1] for line in status.splitlines() if line.startswith("PPid:")))
                return int(cmdline.parent.name), ppid
        except (OSError, StopIteration):
            continue
    return None


@pytest.mark.ray
def test_ray_grid_retries_a_lost_task_from_its_checkpoint(ray_instance, tmp_path) -> None:
    """Shared-folder mode: the Ray worker running a run is killed (as when its node is lost); Ray retries the task,
    which resumes the run from its last checkpoint. A second grid run skips both runs."""
    shared = tmp_path / "shared"
    results: list = []
    thread = threading.Thread(
        target=lambda: results.extend(
            grid_module.run_grid(tiny_grid(0, 1), tmp_path / "unused", backend="ray", shared_folder=str(shared))
        )
    )
    thread.start()
    checkpoint = shared / "gdq" / f"{ENV_ID}_seed0" / "checkpoint.zip"
    wait_for(checkpoint.is_file, "a checkpoint of seed 0")
    found = train_process_of(f"{ENV_ID}_seed0")
    assert found is not None, "the run's training process"
    train_pid, ray_worker_pid = found
    os.kill(ray_worker_pid, signal.SIGKILL)  # the task's worker is lost, and its run with it
    thread.join(timeout=240)
    assert not thread.is_alive()
    by_seed = {run["seed"]: run for run in results}
    assert by_seed[0]["action"] == "resumed" and by_seed[0]["status"] == "complete", by_seed[0]
    assert by_seed[1]["status"] == "complete"
    assert not Path(f"/proc/{train_pid}").exists()  # the lost task's run did not train on behind the retry
    assert (shared / "gdq" / f"{ENV_ID}_seed0.log").read_text().count("--resume") == 1
    again = grid_module.run_grid(tiny_grid(0, 1), tmp_path / "unused", backend="ray", shared_folder=str(shared))
    assert {run["action"] for run in again} == {"skipped"}


@pytest.mark.ray
def test_ray_grid_sends_runs_back_without_a_shared_folder(ray_instance, tmp_path) -> None:
    folder = tmp_path / "gathered"
    results = grid_module.run_grid(tiny_grid(0), folder, backend="ray")
    assert results[0]["status"] == "complete"
    run = folder / "gdq" / f"{ENV_ID}_seed0"
    assert (run / f"{ENV_ID}.zip").is_file() and (run / "progress.csv").is_file()
    assert (folder / "grid.yml").is_file()
    again = grid_module.run_grid(tiny_grid(0), folder, backend="ray")
    assert again[0]["action"] == "skipped"
