"""Checkpoints lose nothing: a run stopped by SIGTERM and resumed equals the uninterrupted run with the same seed."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_eps import train
from sb3_eps.eps.round_log import read_round_log
from sb3_eps.zoo.checkpoint import CorruptCheckpoint, verify_checkpoint
from sb3_eps.zoo.errors import ConfigError

ENV_ID = "CooperativeNavigation-v0"
N_TIMESTEPS = 3_000
# EPS-GDQ with PER, 3-step returns, EPS rounds (in-process evaluation) and periodic team evaluations: every piece
# of state a checkpoint must carry. train_freq 3 so checkpoints fall mid-episode (episodes last 25 ticks).
ARGV = [
    "--algo", "eps_gdq", "--env", ENV_ID, "-n", str(N_TIMESTEPS), "--seed", "3", "--verbose", "0",
    "--eval-freq", "900", "--eval-episodes", "2", "--n-eval-envs", "1", "--save-freq", "600",
    "--hyperparams", "policy_kwargs:dict(net_arch=[16], stream_arch=[16], global_net_arch=[16])",
    "learning_starts:300", "prioritized_replay:True", "batch_size:16", "buffer_size:2000", "train_freq:3", "n_envs:2",
    "callback.population_size:2", "callback.n_workers:0", "callback.period:6", "callback.n_eval_episodes:1",
    "callback.sensitivity_batch_size:16",
    # A round every 6 world episodes as before issue 10's defaults (a round every 10k ticks within a 10 % budget).
    "callback.period_unit:episodes", "callback.max_eps_share:1.0", "callback.n_reevaluation_episodes:1",
]  # fmt: skip


def run_folder(folder: Path) -> Path:
    (path,) = (folder / "eps_gdq").iterdir()
    return path


def without_wall_time(monitor: Path) -> list[list[str]]:
    lines = monitor.read_text().splitlines()
    t = lines[1].split(",").index("t")
    return [[cell for index, cell in enumerate(line.split(",")) if index != t] for line in lines[1:]]


def max_monitor_ticks(monitor: Path) -> int:
    lines = monitor.read_text().splitlines()
    column = lines[1].split(",").index("ticks")
    return max((int(line.split(",")[column]) for line in lines[2:] if line.count(",") >= column), default=0)


def logged_timesteps(progress: Path) -> list[str]:
    lines = progress.read_text().splitlines()
    column = lines[0].split(",").index("time/total_timesteps")
    return [line.split(",")[column] for line in lines[1:]]


def worker_processes(parent_pid: int) -> list[int]:
    """Living processes started by ``parent_pid`` (Linux /proc; empty elsewhere)."""
    found = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines() if ":\t" in line)
        except OSError:
            continue
        if fields.get("PPid", "").strip() == str(parent_pid) and not fields.get("State", "").startswith("Z"):
            found.append(int(status.parent.name))
    return found


def stop_at_checkpoint(process: subprocess.Popen, folder: Path, ready, timeout: float, what: str) -> None:
    """SIGTERM the training ``process`` once the periodic checkpoint under ``folder`` has a meta for which ``ready(meta)``
    holds (a checkpoint replaced while being read counts as not ready); fails if training ends or ``timeout`` passes
    first, and when the process does not exit cleanly."""
    deadline = time.time() + timeout
    while True:
        found = list(folder.glob("gdq/*/checkpoint.zip"))
        try:
            meta = verify_checkpoint(found[0]) if found else {}
        except CorruptCheckpoint:
            meta = {}
        if meta and ready(meta):
            break
        assert process.poll() is None and time.time() < deadline, f"training ended before {what}"
        time.sleep(0.02)
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=300) == 0


def assert_equal_runs(run: Path, expected: Path, env_id: str = ENV_ID) -> None:
    """Two runs are equal: final weights, episodes (without wall time), logged rows, evaluations."""
    _, expected_params, _ = load_from_zip_file(expected / f"{env_id}.zip")
    _, params, _ = load_from_zip_file(run / f"{env_id}.zip")
    for key, value in expected_params["policy"].items():
        assert th.equal(params["policy"][key], value), key
    assert without_wall_time(run / "monitor.csv") == without_wall_time(expected / "monitor.csv")
    assert logged_timesteps(run / "progress.csv") == logged_timesteps(expected / "progress.csv")
    with np.load(expected / "evaluations.npz") as want, np.load(run / "evaluations.npz") as got:
        for key in want:
            np.testing.assert_array_equal(got[key], want[key], err_msg=key)


def stop_and_resume(argv: list[str], folder: Path, stop: signal.Signals, vec_env: str) -> Path:
    """Train ``argv`` into ``folder`` in a new process, stop it with ``stop`` after its first checkpoint (a SIGKILL
    once it has logged past the checkpoint), check what it left, resume it: :return: the run folder."""
    argv = [*argv, "-f", str(folder), "--vec-env", vec_env]
    process = subprocess.Popen([sys.executable, "-m", "sb3_eps.train", *argv])
    deadline = time.time() + 120
    while not list(folder.glob("eps_gdq/*/checkpoint.zip")):  # the first periodic checkpoint: training runs
        assert process.poll() is None and time.time() < deadline, "training ended before it could be stopped"
        time.sleep(0.02)
    if stop == signal.SIGKILL:  # let it log episodes past the checkpoint, which the resume must cut back
        checkpoint_ticks = verify_checkpoint(next(folder.glob("eps_gdq/*/checkpoint.zip")))["ticks"]
        while max_monitor_ticks(next(folder.glob("eps_gdq/*/monitor.csv"))) <= checkpoint_ticks:
            assert process.poll() is None and time.time() < deadline, "training ended before it could be stopped"
            time.sleep(0.02)
    workers = worker_processes(process.pid)
    # The default layout: training world 0 in the training process and world 1 in a worker (on 1 core both in
    # one worker), the evaluation world in its own worker.
    assert len(workers) == (2 if vec_env == "subproc" else 0)
    process.send_signal(stop)
    assert process.wait(timeout=120) == (0 if stop == signal.SIGTERM else -signal.SIGKILL)
    run = run_folder(folder)
    stopped_at = verify_checkpoint(run / "checkpoint.zip")["num_timesteps"]
    assert 0 < stopped_at < N_TIMESTEPS
    assert not (run / f"{ENV_ID}.zip").exists()
    deadline = time.time() + 10  # the world workers exit with their run, even a killed one
    while (alive := [pid for pid in workers if Path(f"/proc/{pid}").exists()]) and time.time() < deadline:
        time.sleep(0.05)
    assert not alive

    assert train.main(["--resume", str(run), "--verbose", "0"]) == 0
    return run


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("uninterrupted")
    assert train.main([*ARGV, "-f", str(folder)]) == 0
    return run_folder(folder)


@pytest.mark.parametrize(
    ("stop", "vec_env"),
    [
        (signal.SIGTERM, "dummy"),
        (signal.SIGKILL, "dummy"),
        (signal.SIGTERM, "subproc"),
        (signal.SIGKILL, "subproc"),
    ],
    ids=["sigterm", "crash", "sigterm-workers", "crash-workers"],
)
def test_resume_equals_the_uninterrupted_run(uninterrupted, tmp_path, stop, vec_env) -> None:
    """SIGTERM: a checkpoint at the next rollout start, exit 0. SIGKILL (a crash): resume from the last periodic
    checkpoint; what was logged after it is cut back and logged again. With ``--vec-env subproc`` the worlds run
    in worker processes (snapshotted into the checkpoint, rebuilt in new workers on resume), and the result still
    equals the uninterrupted in-process run."""
    folder = tmp_path / "interrupted"
    run = stop_and_resume(ARGV, folder, stop, vec_env)
    assert_equal_runs(run, uninterrupted)
    assert np.load(run / "evaluations.npz")["eps_ticks"][-1] > 0  # EPS rounds ran, before and after the stop
    # The EPS round log holds each round once, as the uninterrupted run's (wall times aside).
    rounds, expected_rounds = (read_round_log(folder / "eps_rounds.jsonl") for folder in (run, uninterrupted))
    assert len(rounds) == len(expected_rounds) >= 2
    for record, expected_record in zip(rounds, expected_rounds, strict=True):
        assert {**record, "wall_time": 0} == {**expected_record, "wall_time": 0}
    assert not (run / "checkpoint.zip").exists()

    # A finished run is not trained again.
    assert train.main(["--resume", str(run), "--verbose", "0"]) == 0


def test_resume_with_uniform_replay_equals_the_uninterrupted_run(tmp_path) -> None:
    """GDQ's default buffer (uniform replay since 2026-12-02; the runs above name PER) resumes exactly too."""
    uniform = [argument.replace("prioritized_replay:True", "prioritized_replay:False") for argument in ARGV]
    assert uniform != ARGV
    assert train.main([*uniform, "-f", str(tmp_path / "uninterrupted")]) == 0
    expected = run_folder(tmp_path / "uninterrupted")
    run = stop_and_resume(uniform, tmp_path / "interrupted", signal.SIGTERM, "dummy")
    assert_equal_runs(run, expected)


def test_overlap_training_with_workers_resumes_to_the_in_process_run(tmp_path) -> None:
    """``overlap_training`` (learning while the worlds step): every training world goes to a worker, a SIGTERM
    and ``--resume`` lose nothing, and the result equals the same config trained in process."""
    argv = [*ARGV, "overlap_training:True"]
    expected = tmp_path / "in_process"
    assert train.main([*argv, "-f", str(expected)]) == 0
    folder = tmp_path / "workers"
    process = subprocess.Popen([sys.executable, "-m", "sb3_eps.train", *argv, "-f", str(folder), "--vec-env", "subproc"])
    deadline = time.time() + 120
    while not list(folder.glob("eps_gdq/*/checkpoint.zip")):
        assert process.poll() is None and time.time() < deadline, "training ended before it could be stopped"
        time.sleep(0.02)
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=120) == 0
    run = run_folder(folder)
    assert 0 < verify_checkpoint(run / "checkpoint.zip")["num_timesteps"] < N_TIMESTEPS
    assert train.main(["--resume", str(run), "--verbose", "0"]) == 0
    assert_equal_runs(run, run_folder(expected))


def test_the_training_worlds_of_an_overlapping_config_all_go_to_workers() -> None:
    from sb3_eps.zoo.config import build_env, resolve_config

    config = resolve_config("gdq", ENV_ID, hyperparams=["n_envs:3", "overlap_training:True"])
    venv = build_env(config, seed=0, vec_env="subproc")
    try:
        assert venv.main_worlds == 0 and venv.n_workers >= 1
    finally:
        venv.close()
    eval_venv = build_env(config, seed=0, n_envs=2, vec_env="subproc")  # evaluation worlds: the default layout
    eval_venv.close()


def test_resume_needs_a_checkpoint(tmp_path) -> None:
    (tmp_path / "args.yml").write_text("algo: gdq\nenv: CooperativeNavigation-v0\nn_timesteps: 10\n")
    (tmp_path / "config.yml").write_text("CooperativeNavigation-v0:\n  n_timesteps: 10\n")
    with pytest.raises(ConfigError, match=r"no checkpoint\.zip"):
        train.main(["--resume", str(tmp_path)])


def test_resume_takes_the_parameter_folder_of_a_run(tmp_path, capsys) -> None:
    """RL Zoo's layout: ``<run>/<env id>/`` holds ``args.yml`` and ``config.yml``; ``--resume`` given that folder
    resumes the run above it (here a finished one, so nothing trains)."""
    run = tmp_path / f"{ENV_ID}_1"
    params = run / ENV_ID
    params.mkdir(parents=True)
    (params / "args.yml").write_text(f"algo: gdq\nenv: {ENV_ID}\nn_timesteps: 10\n")
    (params / "config.yml").write_text(f"{ENV_ID}:\n  n_timesteps: 10\n")
    with pytest.raises(ConfigError, match=rf"{run.name} has no checkpoint\.zip"):
        train.main(["--resume", str(params)])
    (run / f"{ENV_ID}.zip").write_bytes(b"")
    assert train.main(["--resume", str(params)]) == 0
    assert f"{run} has finished already" in capsys.readouterr().out


def test_resume_of_a_run_sharing_experience_equals_the_uninterrupted_run(tmp_path) -> None:
    """EPS experience sharing (a team world of the training env): the shared rows live in the replay buffer that the
    checkpoint carries, and the count in the callback's state; the resumed run equals the uninterrupted one. Sharing is
    research (``research/eps_variants.py``): the entries of ``zoo_configs/eps_gdq.yml`` with its callback."""
    configs = Path(__file__).resolve().parents[1] / "zoo_configs"
    research_callback = "research.eps_variants.ResearchEvolutionCallback"
    conf = tmp_path / "eps_gdq_sharing.yml"
    conf.write_text((configs / "eps_gdq.yml").read_text().replace("sb3_eps.EvolutionCallback:", f"{research_callback}:"))
    sharing = [*ARGV, "callback.eval_env_id:'CooperativeNavigation-v0'", "callback.share_experience:True"]
    sharing += ["-conf", str(conf), "--gym-packages", "research.eps_variants"]
    assert train.main([*sharing, "-f", str(tmp_path / "uninterrupted")]) == 0
    expected = run_folder(tmp_path / "uninterrupted")
    run = stop_and_resume(sharing, tmp_path / "interrupted", signal.SIGTERM, "dummy")
    assert_equal_runs(run, expected)
    rounds, expected_rounds = (read_round_log(folder / "eps_rounds.jsonl") for folder in (run, expected))
    assert [record["shared_rows"] for record in rounds] == [record["shared_rows"] for record in expected_rounds]
    assert sum(record["shared_rows"] for record in rounds) == sum(record["ticks_spent"] for record in rounds) > 0
