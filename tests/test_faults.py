"""Reliability (issue 13): crashes at any point, corrupt checkpoints, EPS worker faults, NaN/inf, bad input, plain
installs, no code execution, determinism. Each fault is injected into a real run (real worlds, SB3, files)."""

from __future__ import annotations

import json
import os
import pickle
import signal
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.logger import configure
from stable_baselines3.common.save_util import load_from_zip_file
from test_zoo_resume import ARGV, ENV_ID, N_TIMESTEPS, assert_equal_runs, run_folder, without_wall_time

import envs
from sb3_eps import GDQ, IQL, QMIX, EvolutionCallback, export_policy, make_vec_env, train
from sb3_eps import evaluate as evaluate_command
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.vec_env import MultiAgentVecEnv
from sb3_eps.eps import SubprocessEnvPool
from sb3_eps.eps import round as round_module
from sb3_eps.zoo import checkpoint as checkpoint_module
from sb3_eps.zoo.callbacks import TrainingStateCallback
from sb3_eps.zoo.checkpoint import (
    CHECKPOINT_NAME,
    PREVIOUS_CHECKPOINT_NAME,
    CorruptCheckpoint,
    verify_checkpoint,
)
from sb3_eps.zoo.errors import run_command

ROOT = Path(__file__).resolve().parents[1]
TINY = {"net_arch": [16], "stream_arch": [16]}
MPE = "CooperativeNavigation-v0"


class SimulatedCrash(BaseException):
    """The process dies here: no handler catches it (only ``finally`` blocks run, as on a real crash)."""


def crash_on_call(monkeypatch: pytest.MonkeyPatch, owner: Any, name: str, call: int, when=None) -> None:
    """Make ``owner.name`` raise :class:`SimulatedCrash` on its ``call``-th call (counting calls where ``when``)."""
    original = getattr(owner, name)
    calls = {"n": 0}

    def crashing(*args: Any, **kwargs: Any) -> Any:
        if when is None or when(*args, **kwargs):
            calls["n"] += 1
            if calls["n"] == call:
                raise SimulatedCrash(f"{name}, call {call}")
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, crashing)


def assert_same_run(run: Path, expected: Path) -> None:
    """The resumed run equals the uninterrupted one, and left no checkpoint or temporary file behind."""
    assert_equal_runs(run, expected)
    assert not list(run.glob("*checkpoint*")) and not list(run.glob(".*.tmp"))


def files_of(folder: Path) -> dict[str, tuple[int, int]]:
    """:return: relative path -> (size, mtime_ns) of every file under ``folder``."""
    return {
        str(path.relative_to(folder)): (path.stat().st_size, path.stat().st_mtime_ns)
        for path in sorted(folder.rglob("*"))
        if path.is_file()
    }


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("uninterrupted")
    assert train.main([*ARGV, "-f", str(folder)]) == 0
    return run_folder(folder)


def crashed_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str) -> Path:
    """Train ``ARGV`` until the injected crash at ``where``; :return: the run folder left behind."""
    with monkeypatch.context() as patch:
        if where == "rollout":  # while a world's tick is being stored
            crash_on_call(patch, GDQ, "_store_joint_transition", 350)
        elif where == "gradient step":  # inside train(), between the loss and the optimiser step
            crash_on_call(patch, GDQ, "_compute_loss", 90)
        elif where == "eps round":  # while the population is being evaluated
            crash_on_call(patch, round_module, "evaluate_population", 4)
        elif where == "checkpoint write":  # half-way through writing the third checkpoint
            crash_on_call(
                patch, zipfile.ZipFile, "writestr", 3,
                when=lambda archive, name, *_: ".checkpoint.zip." in str(archive.filename) and name == "rng.pkl",
            )  # fmt: skip
        with pytest.raises(SimulatedCrash):
            train.main([*ARGV, "-f", str(tmp_path)])
    run = run_folder(tmp_path)
    assert not (run / f"{ENV_ID}.zip").exists()
    return run


# ---------------------------------------------------------------------------------------------- 1. interruptions
@pytest.mark.parametrize("where", ["rollout", "gradient step", "eps round", "checkpoint write"])
def test_a_crash_at_any_point_resumes_to_the_uninterrupted_run(uninterrupted, tmp_path, monkeypatch, where) -> None:
    run = crashed_run(tmp_path, monkeypatch, where)
    meta = verify_checkpoint(run / CHECKPOINT_NAME)
    assert 0 < meta["num_timesteps"] < N_TIMESTEPS
    if where == "checkpoint write":  # the interrupted third write (at 1800 timesteps) replaced nothing
        previous = verify_checkpoint(run / PREVIOUS_CHECKPOINT_NAME)["num_timesteps"]
        assert 600 <= previous < 1200 <= meta["num_timesteps"] < 1800
        assert not list(run.glob(".*.tmp"))
    assert train.main(["--resume", str(run), "--verbose", "0"]) == 0
    assert_same_run(run, uninterrupted)


@pytest.mark.parametrize("damage", ["truncated", "bit flip", "empty"])
def test_a_corrupt_checkpoint_is_reported_in_one_line_and_the_previous_one_is_used(
    uninterrupted, tmp_path, monkeypatch, capsys, damage
) -> None:
    run = crashed_run(tmp_path, monkeypatch, "rollout")
    latest = verify_checkpoint(run / CHECKPOINT_NAME)["num_timesteps"]
    previous = verify_checkpoint(run / PREVIOUS_CHECKPOINT_NAME)["num_timesteps"]
    assert previous < latest
    data = (run / CHECKPOINT_NAME).read_bytes()
    if damage == "truncated":  # a copy cut short
        data = data[: len(data) // 2]
    elif damage == "bit flip":  # a byte gone bad inside the replay buffer's member
        middle = len(data) // 2
        data = data[:middle] + bytes([data[middle] ^ 0xFF]) + data[middle + 1 :]
    else:  # a full disk
        data = b""
    (run / CHECKPOINT_NAME).write_bytes(data)
    (run / ".checkpoint.zip.abc123.tmp").write_bytes(b"PK\x03\x04 half a checkpoint")  # a writer killed mid-way
    capsys.readouterr()
    assert train.main(["--resume", str(run), "--verbose", "0"]) == 0
    warning_lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert len(warning_lines) == 1, warning_lines
    assert CHECKPOINT_NAME in warning_lines[0] and f"{PREVIOUS_CHECKPOINT_NAME} at {previous} timesteps" in warning_lines[0]
    assert_same_run(run, uninterrupted)


def test_when_every_checkpoint_is_corrupt_resume_says_so_and_changes_nothing(tmp_path, monkeypatch, capsys) -> None:
    run = crashed_run(tmp_path, monkeypatch, "rollout")
    for name in (CHECKPOINT_NAME, PREVIOUS_CHECKPOINT_NAME):
        path = run / name
        path.write_bytes(path.read_bytes()[:1000])
    before = files_of(run)
    status, stderr = run_cli(train.PROG, train.main, ["--resume", str(run)], capsys)
    assert status == 2 and len(stderr.splitlines()) == 1
    assert "no usable checkpoint" in stderr and CHECKPOINT_NAME in stderr and PREVIOUS_CHECKPOINT_NAME in stderr
    assert files_of(run) == before


def test_every_truncation_of_a_checkpoint_is_detected(tmp_path, monkeypatch) -> None:
    run = crashed_run(tmp_path, monkeypatch, "rollout")
    data = (run / CHECKPOINT_NAME).read_bytes()
    verify_checkpoint(run / CHECKPOINT_NAME)  # the intact file passes
    cut = tmp_path / "cut.zip"
    for fraction in np.linspace(0.0, 0.999, 25):
        cut.write_bytes(data[: int(len(data) * fraction)])
        with pytest.raises(CorruptCheckpoint):
            verify_checkpoint(cut)


def test_a_failed_checkpoint_write_keeps_the_previous_one_and_training_completes(tmp_path, monkeypatch) -> None:
    """A full disk while the second checkpoint is written: a warning, the first one stays, training goes on."""
    written: list[int] = []
    original = checkpoint_module.save_checkpoint

    def disk_full_once(path, model, states, meta):
        written.append(meta["num_timesteps"])
        if len(written) == 2:
            raise OSError(28, "No space left on device")
        return original(path, model, states, meta)

    monkeypatch.setattr("sb3_eps.zoo.callbacks.save_checkpoint", disk_full_once)
    with pytest.warns(RuntimeWarning, match="not written .*No space left on device.*previous checkpoint is kept"):
        assert train.main([*ARGV, "-f", str(tmp_path), "--keep-checkpoint"]) == 0
    run = run_folder(tmp_path)
    assert (run / f"{ENV_ID}.zip").is_file() and len(written) >= 4
    assert verify_checkpoint(run / CHECKPOINT_NAME)["complete"]


# ---------------------------------------------------------------------------------------------- 2. EPS workers
def robot_model(**kwargs: Any) -> GDQ:
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=0)
    defaults = {"learning_starts": 100, "batch_size": 16, "buffer_size": 2_000, "train_freq": 4, "seed": 0}
    return GDQ("MlpPolicy", venv, policy_kwargs={**TINY, "global_net_arch": [16]}, **{**defaults, **kwargs})


def robot_callback(**kwargs: Any) -> EvolutionCallback:
    defaults = {
        "eval_env_id": "SingleRobotNav-v0",
        "population_size": 2,
        "period": 60,
        "period_unit": "ticks",
        "max_eps_share": None,  # a round at every period: the tests need rounds, not the default's budget
    }
    return EvolutionCallback(**{**defaults, "n_eval_episodes": 1, "seed": 0, **kwargs})


@pytest.mark.parametrize("n_workers", [1, 0], ids=["worker", "in-process"])
def test_a_disconnected_pybullet_client_skips_the_round_and_the_workers_restart(tmp_path, monkeypatch, n_workers) -> None:
    """The EPS world's PyBullet client disconnects in the middle of a round (a crashed physics server)."""
    from envs.turtlebot3.single_robot_nav import SingleRobotNavEnv

    marker = tmp_path / "disconnected"
    original = SingleRobotNavEnv.step

    def disconnect_once(self, action):
        if not marker.exists():  # once, in whichever process plays first (the file is seen across processes)
            marker.touch()
            world = self.multi_env.world
            world_module = sys.modules[type(world).__module__]
            world_module.p.disconnect(physicsClientId=world.client)
        return original(self, action)

    monkeypatch.setattr(SingleRobotNavEnv, "step", disconnect_once)
    model = robot_model()
    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    callback = robot_callback(n_workers=n_workers)
    first_pids: list[list[int]] = []
    original_skip = callback._skip_round

    def remember_pids(error, wall_time, *record):
        first_pids.append(callback.worker_pids)
        original_skip(error, wall_time, *record)

    monkeypatch.setattr(callback, "_skip_round", remember_pids)
    with pytest.warns(RuntimeWarning, match="EPS round skipped"):
        model.learn(600, callback=callback, log_interval=1)
    assert marker.exists() and callback.n_skipped_rounds == 1 and callback.history[0]["skipped"]
    assert "Not connected" in callback.history[0]["reason"] or "not connected" in callback.history[0]["reason"]
    assert callback.n_rounds >= 1 and not callback.history[-1]["skipped"]  # the restarted envs serve
    if n_workers:
        assert first_pids[0] and not callback.worker_pids  # closed at the end; restarted in between
    # SB3 writes a log row when an episode ends; whether one ends after the skipped round depends on the run's
    # random draws (GDQ's default replay changed them), so write the rows still pending as a run's end would.
    model.logger.dump(model.num_timesteps)
    logged = (tmp_path / "log" / "progress.csv").read_text().splitlines()
    column = logged[0].split(",").index("eps/skipped_rounds")
    assert "1" in {line.split(",")[column] for line in logged[1:]}
    assert model.num_timesteps >= 600


def test_a_killed_worker_through_the_command_line_run_completes(tmp_path, monkeypatch) -> None:
    """The command line's EPS-GDQ run with worker processes: one worker killed, the run still finishes."""
    original = round_module.evaluate_population
    killed: list[int] = []

    def evaluate_after_a_kill(pool, *args, **kwargs):  # the first round finds its worker dead
        if not killed:
            assert isinstance(pool, SubprocessEnvPool)
            killed.append(pool.pids[0])
            os.kill(pool.pids[0], signal.SIGKILL)
        return original(pool, *args, **kwargs)

    monkeypatch.setattr(round_module, "evaluate_population", evaluate_after_a_kill)
    argv = [*ARGV, "callback.n_workers:1", "--save-freq", "0", "--eval-freq", "0", "-f", str(tmp_path)]
    with pytest.warns(RuntimeWarning, match="EPS round skipped"):
        assert train.main(argv) == 0
    run = run_folder(tmp_path)
    assert killed and (run / f"{ENV_ID}.zip").is_file()
    logged = (run / "progress.csv").read_text().splitlines()
    column = logged[0].split(",").index("eps/skipped_rounds")
    assert logged[-1].split(",")[column] == "1"


# ---------------------------------------------------------------------------------------------- 3. NaN / inf
def mpe_model(algorithm=IQL, **kwargs: Any) -> MultiAgentOffPolicyAlgorithm:
    venv = make_vec_env(MPE, n_envs=2, seed=0)
    defaults = {"learning_starts": 60, "batch_size": 16, "buffer_size": 2_000, "train_freq": 2, "seed": 0}
    extra = {"global_net_arch": [16]} if algorithm is GDQ else {}
    return algorithm("MlpPolicy", venv, policy_kwargs={**TINY, **extra}, **{**defaults, **kwargs})


def weights_and_moments(model: MultiAgentOffPolicyAlgorithm) -> dict[str, th.Tensor]:
    state = {f"w:{k}": v.clone() for k, v in model.policy.state_dict().items()}
    for index, moments in model.policy.optimizer.state_dict()["state"].items():
        state.update({f"o:{index}:{k}": v.clone() for k, v in moments.items() if isinstance(v, th.Tensor)})
    return state


@pytest.mark.parametrize("field", ["observation", "reward"])
def test_a_non_finite_observation_or_reward_from_the_env_is_never_stored(monkeypatch, field) -> None:
    original = MultiAgentVecEnv.step_wait
    calls = {"n": 0}

    def poisoned(self):
        obs, rewards, dones, infos = original(self)
        calls["n"] += 1
        if calls["n"] in (40, 41, 90):
            if field == "observation":
                obs[4, 1] = np.nan
            else:
                rewards[4] = np.inf
        return obs, rewards, dones, infos

    monkeypatch.setattr(MultiAgentVecEnv, "step_wait", poisoned)
    model = mpe_model()
    with pytest.warns(RuntimeWarning, match=rf"non-finite {field} from the env \(world 1, agents \[1\]\)"):
        model.learn(900)
    buffer = model.replay_buffer
    size = buffer.size()
    for name in ("observations", "next_observations", "rewards"):
        assert np.isfinite(getattr(buffer, name)[:size]).all(), name
    assert not non_finite(model) and model.n_refused_updates == 0 and model._n_updates > 0


def non_finite(model: MultiAgentOffPolicyAlgorithm) -> list[str]:
    return [name for name, value in model.policy.state_dict().items() if not th.isfinite(value).all()]


@pytest.mark.parametrize(
    ("poison", "source"),
    [
        ("batch reward", "replay batch rewards"),
        ("batch observation", "replay batch observations"),
        ("target network", "target network q_net_target"),
        ("overflowing reward", "the loss itself"),
    ],
)
def test_a_non_finite_loss_or_target_is_refused_and_the_source_named(poison, source) -> None:
    model = mpe_model()
    model.learn(300)  # fills the buffer, a few real updates
    buffer = model.replay_buffer
    size = buffer.size()
    if poison == "batch reward":
        buffer.rewards[:size] = np.nan
    elif poison == "batch observation":
        buffer.observations[:size, 0, 3] = np.inf
    elif poison == "target network":
        with th.no_grad():
            next(model.policy.q_net_target.parameters()).fill_(np.nan)
    else:
        buffer.rewards[:size] = 3e38  # finite, but its square is not
    online_before = {k: v.clone() for k, v in model.policy.q_net.state_dict().items()}
    before = weights_and_moments(model)
    priorities = buffer.priorities[:size].copy() if hasattr(buffer, "priorities") else None
    updates = model._n_updates
    with pytest.warns(RuntimeWarning, match=rf"gradient step refused: .*{source}"):
        model.train(gradient_steps=3, batch_size=16)
    assert model.n_refused_updates == 3 and model._n_updates == updates
    after = weights_and_moments(model)
    for key, value in before.items():  # weights, Adam moments and step counts all untouched
        assert th.equal(after[key], value) or (th.isnan(value).all() and th.isnan(after[key]).all()), key
    for key, value in online_before.items():
        assert th.isfinite(model.policy.q_net.state_dict()[key]).all() and th.equal(
            model.policy.q_net.state_dict()[key], value
        )
    if priorities is not None:
        np.testing.assert_array_equal(buffer.priorities[:size], priorities)


def test_a_checkpoint_of_non_finite_weights_is_refused(tmp_path) -> None:
    model = mpe_model()
    model.learn(120)
    checkpoint = TrainingStateCallback(tmp_path / CHECKPOINT_NAME, 0, 1000, {})
    checkpoint.init_callback(model)
    assert checkpoint.save() and (tmp_path / CHECKPOINT_NAME).is_file()
    good = (tmp_path / CHECKPOINT_NAME).read_bytes()
    with th.no_grad():
        next(model.policy.q_net.parameters())[0, 0] = float("inf")
    with pytest.warns(RuntimeWarning, match=r"checkpoint at \d+ timesteps refused: non-finite values in q_net\."):
        assert not checkpoint.save()
    assert (tmp_path / CHECKPOINT_NAME).read_bytes() == good
    assert not (tmp_path / PREVIOUS_CHECKPOINT_NAME).exists()


def test_a_non_finite_mutant_is_disqualified_with_a_warning(monkeypatch) -> None:
    original = round_module.population_from_directions  # the callback builds its population with it

    def with_nan_mutant(*args, **kwargs):
        population = original(*args, **kwargs)
        next(iter(population.values()))[2].fill_(np.nan)
        return population

    monkeypatch.setattr(round_module, "population_from_directions", with_nan_mutant)
    model = mpe_model(GDQ)
    callback = EvolutionCallback(
        eval_env_id="CooperativeNavigationSingle-v0",
        population_size=3,
        period=2,
        n_workers=0,
        seed=0,
        period_unit="episodes",
        max_eps_share=None,
        target_flip_share=None,
    )
    with pytest.warns(RuntimeWarning, match=r"individuals \[2\] have non-finite weights; they are disqualified"):
        model.learn(600, callback=callback)
    rounds = [record for record in callback.history if not record["skipped"]]
    assert rounds and all(record["winner"] != 2 and record["fitness"][2] == -np.inf for record in rounds)
    assert not non_finite(model)


# ---------------------------------------------------------------------------------------------- 4. bad input
def run_cli(prog: str, main: Any, argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        run_command(prog, lambda: main(argv))
    return int(exit_info.value.code or 0), capsys.readouterr().err


GOOD = f"{MPE}:\n  n_timesteps: 100\n  n_envs: 1\n"
EPS_ENTRY = GOOD + "  callback:\n    - sb3_eps.EvolutionCallback: {eval_env_id: SingleRobotNav-v0, n_workers: 0}\n"


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> Path:
    """Saved models for the bad-input cases: GDQ and QMIX on MPE, GDQ on the robots, a text file named .zip."""
    folder = tmp_path_factory.mktemp("models")
    mpe_model(GDQ).save(folder / "gdq_mpe.zip")
    venv = make_vec_env(MPE, n_envs=1, seed=0)
    QMIX("MlpPolicy", venv, policy_kwargs=TINY, seed=0).save(folder / "qmix_mpe.zip")
    robot_model().save(folder / "gdq_robot.zip")
    (folder / "text.zip").write_text("not a zip file")
    return folder


# (case, YAML of -conf or None, flags, words the one error line must contain); {models} is the models folder
TRAIN_CASES = [
    ("empty-yaml", "", [], ["bad.yml", "must map env ids"]),
    ("comments-only-yaml", "# nothing here\n", [], ["bad.yml", "must map env ids"]),
    ("binary-yaml", b"\x00\x01\xff\xfe\x89PNG\r\n", [], ["bad.yml", "not a text file"]),
    ("float-budget", GOOD.replace("100", "1.5"), [], ["n_timesteps", "an int >= 1", "1.5"]),
    ("negative-learning-rate", GOOD + "  learning_rate: -0.001\n", [], ["learning_rate", "> 0"]),
    ("epsilon-above-one", GOOD + "  exploration_final_eps: 2\n", [], ["exploration_final_eps", "in [0, 1]"]),
    ("negative-layer", GOOD + '  policy_kwargs: "dict(net_arch=[-4])"\n', [], ["net_arch", "each an int >= 1"]),
    ("empty-buffer", GOOD + "  buffer_size: 0\n", [], ["buffer_size", ">= 1"]),
    ("eps-world-of-other-spaces", EPS_ENTRY, ["--algo", "eps_gdq"], ["eval_env_id SingleRobotNav-v0", "Box(30,)", "Box(18,)", "CooperativeNavigationSingle-v0"]),
    ("eps-sigma-not-a-number", GOOD + "  callback:\n    - sb3_eps.EvolutionCallback: {sigma: big}\n", ["--algo", "eps_gdq"], ["sigma", "a number"]),
    ("device-unknown", None, ["--device", "bogus"], ["--device", "bogus", "not a torch device"]),
    ("threads-negative", None, ["--num-threads", "-2"], ["--num-threads", ">= 0"]),
    ("eval-env-unknown", None, ["--eval-env", "Foo-v0"], ["--eval-env", "Foo-v0", "allowed"]),
    ("env-kwarg-unknown", None, ["--env-kwargs", "foo:1"], ["env_kwargs", "foo"]),
    ("env-kwarg-type", None, ["--env", "MultiRobotNav-2-v0", "--env-kwargs", "lidar_noise_std:abc"], ["lidar_noise_std", "a finite number"]),
    ("init-from-not-a-zip", None, ["--init-from", "{models}/text.zip"], ["--init-from", "text.zip"]),
    ("init-from-other-observations", None, ["--init-from", "{models}/gdq_robot.zip"], ["--init-from", "Box(30,)", "Box(18,)"]),
    ("init-from-other-network", None, ["--init-from", "{models}/gdq_mpe.zip", "-params", "policy_kwargs:dict(net_arch=[32], stream_arch=[16], global_net_arch=[16])"], ["--init-from", "does not fit", "net_arch"]),
    ("init-from-other-algorithm", None, ["--init-from", "{models}/qmix_mpe.zip", "-params", "policy_kwargs:dict(net_arch=[32], stream_arch=[16], global_net_arch=[16])"], ["--init-from", "does not fit"]),
    ("resume-a-file", None, ["--resume", "{models}/text.zip"], ["--resume", "not a run folder"]),
]  # fmt: skip


@pytest.mark.parametrize(("case", "conf", "flags", "words"), TRAIN_CASES, ids=[case[0] for case in TRAIN_CASES])
def test_bad_train_input_is_one_line_and_writes_nothing(case, conf, flags, words, models, tmp_path, capsys) -> None:
    argv = ["--algo", "gdq", "--env", MPE, "-f", str(tmp_path / "logs"), "--seed", "0", "-n", "100"]
    if conf is not None:
        path = tmp_path / "bad.yml"
        path.write_bytes(conf if isinstance(conf, bytes) else conf.encode())
        argv += ["-conf", str(path)]
    argv += [flag.replace("{models}", str(models)) for flag in flags]
    status, stderr = run_cli(train.PROG, train.main, argv, capsys)
    assert status == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{train.PROG}: error: "), stderr
    for word in words:
        assert word in lines[0], f"{word!r} missing from: {lines[0]}"
    assert not (tmp_path / "logs").exists()


def make_foreign_run(folder: Path, kind: str, models: Path) -> None:
    """A run folder that is not (or no longer) one of ours."""
    folder.mkdir()
    args = f"algo: gdq\nenv: {MPE}\nn_timesteps: 100\nseed: 0\n"
    config = f"{MPE}:\n  n_timesteps: 100\n"
    if kind == "args-a-list":
        args = "- a\n- list\n"
    elif kind == "unknown-algorithm":
        args = args.replace("algo: gdq", "algo: dqn")
    elif kind == "unknown-env":
        args = args.replace(f"env: {MPE}", "env: Foo-v0")
    elif kind == "seed-not-an-int":
        args = args.replace("seed: 0", "seed: abc")
    (folder / "args.yml").write_text(args)
    if kind == "binary-args":
        (folder / "args.yml").write_bytes(b"\x89PNG\xff\xfe\x00")
    (folder / "config.yml").write_text(config)
    if kind == "checkpoint-of-another-algorithm":
        meta = {"num_timesteps": 10, "ticks": 3, "complete": False, "algorithm": "QMIX", "next_save": 0}
        members = {
            "model.zip": b"",
            "training.pkl": b"",
            "rng.pkl": b"",
            "callbacks.pkl": b"",
            "meta.json": json.dumps(meta).encode(),
        }
        with zipfile.ZipFile(folder / CHECKPOINT_NAME, "w") as archive:
            for name, data in members.items():
                archive.writestr(name, data)
    elif kind == "checkpoint-not-ours":
        with zipfile.ZipFile(folder / CHECKPOINT_NAME, "w") as archive:
            archive.writestr("hello.txt", "a zip, but not a checkpoint")


RESUME_CASES = [
    ("args-a-list", ["not a mapping of options"]),
    ("unknown-algorithm", ["unknown algorithm 'dqn'"]),
    ("unknown-env", ["Foo-v0", "allowed"]),
    ("seed-not-an-int", ["seed", "'abc'", "not a run of sb3_eps.train"]),
    ("binary-args", ["args.yml", "not a text file"]),
    ("no-checkpoint", ["no checkpoint.zip"]),
    ("checkpoint-of-another-algorithm", ["holds a QMIX model", "--algo gdq"]),
    ("checkpoint-not-ours", ["no usable checkpoint", "lacks"]),
]  # fmt: skip


@pytest.mark.parametrize(("kind", "words"), RESUME_CASES, ids=[case[0] for case in RESUME_CASES])
def test_resume_of_a_foreign_run_folder_is_one_line_and_changes_nothing(kind, words, models, tmp_path, capsys) -> None:
    run = tmp_path / "run"
    make_foreign_run(run, kind, models)
    before = files_of(run)
    status, stderr = run_cli(train.PROG, train.main, ["--resume", str(run)], capsys)
    lines = stderr.strip().splitlines()
    assert status == 2 and len(lines) == 1, stderr
    for word in words:
        assert word in lines[0], f"{word!r} missing from: {lines[0]}"
    assert files_of(run) == before


def test_bad_evaluate_input_is_one_line(models, tmp_path, capsys) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "args.yml").write_text(f"algo: gdq\nenv: {MPE}\n")
    (run / f"{MPE}.zip").write_bytes((models / "gdq_mpe.zip").read_bytes())
    (tmp_path / "a_file").write_text("")
    cases = [
        (["--device", "bogus"], ["--device", "not a torch device"]),
        (["--gif", str(tmp_path / "a_file" / "x.gif")], ["--gif", "not writable"]),
        (["--eval-env", "MultiRobotNav-2-v0"], ["Box(30,)", "Box(18,)"]),
        (["-n", "0"], ["-n", ">= 1"]),
    ]
    for flags, words in cases:
        status, stderr = run_cli(evaluate_command.PROG, evaluate_command.main, ["--run", str(run), *flags], capsys)
        lines = stderr.strip().splitlines()
        assert status == 2 and len(lines) == 1, (flags, stderr)
        assert all(word in lines[0] for word in words), (words, lines[0])
    assert sorted(path.name for path in run.iterdir()) == ["CooperativeNavigation-v0.zip", "args.yml"]


API_CASES = [
    ("learning-rate-string", lambda venv: GDQ("MlpPolicy", venv, learning_rate="fast"), "learning_rate must be a number > 0"),
    ("batch-size-zero", lambda venv: GDQ("MlpPolicy", venv, batch_size=0), "batch_size must be an int >= 1"),
    ("buffer-size-string", lambda venv: GDQ("MlpPolicy", venv, buffer_size="big"), "buffer_size must be an int >= 1"),
    ("epsilon-above-one", lambda venv: IQL("MlpPolicy", venv, exploration_final_eps=1.5), r"exploration_final_eps must be a number in \[0, 1\]"),
    ("exploration-fraction-negative", lambda venv: IQL("MlpPolicy", venv, exploration_fraction=-1), "exploration_fraction"),
    ("learn-negative", lambda venv: GDQ("MlpPolicy", venv, policy_kwargs=TINY).learn(-5), "total_timesteps must be an int >= 0"),
    ("env-id-instead-of-env", lambda venv: GDQ("MlpPolicy", MPE), "pass a vector env"),
    ("single-agent-env", lambda venv: GDQ("MlpPolicy", envs.make_single_env("CooperativeNavigationSingle-v0")), "not a multi-agent vector env"),
    ("n-envs-string", lambda venv: make_vec_env(MPE, n_envs="2"), "n_envs"),
    ("unknown-env-id", lambda venv: make_vec_env("Foo-v0"), "unknown env id 'Foo-v0'"),
    ("noise-not-a-number", lambda venv: envs.make_parallel_env("MultiRobotNav-2-v0", lidar_noise_std="x"), "lidar_noise_std must be a finite number"),
    ("noise-negative", lambda venv: envs.make_single_env("SingleRobotNav-v0", lidar_noise_std=-0.1), "lidar_noise_std"),
    ("robots-fixed-by-id", lambda venv: envs.make_parallel_env("MultiRobotNav-4-v0", n_robots=3), "fixes n_robots=4"),
    ("episode-length-zero", lambda venv: envs.make_parallel_env("MultiRobotNav-2-v0", max_episode_steps=0), "max_episode_steps"),
    ("render-mode-unknown", lambda venv: envs.make_parallel_env("MultiRobotNav-2-v0", render_mode="video"), "render_mode"),
    ("eps-timeout-zero", lambda venv: EvolutionCallback(eval_timeout=0), "eval_timeout"),
]  # fmt: skip


@pytest.mark.parametrize(("case", "build", "message"), API_CASES, ids=[case[0] for case in API_CASES])
def test_bad_python_api_input_is_one_clear_line(case, build, message) -> None:
    venv = make_vec_env(MPE, n_envs=1, seed=0)
    with pytest.raises(ValueError, match=message) as error:
        build(venv)
    assert len(str(error.value).splitlines()) == 1


def test_a_model_file_of_another_algorithm_or_observation_size_is_one_clear_line(models) -> None:
    with pytest.raises(ValueError, match=r"qmix_mpe\.zip holds a model of another algorithm \(policy QMIXPolicy\)") as error:
        GDQ.load(models / "qmix_mpe.zip")
    assert len(str(error.value).splitlines()) == 1
    venv = make_vec_env(MPE, n_envs=1, seed=0)
    with pytest.raises(ValueError, match=r"observation_space Box\(30,\), the env has Box\(18,\)") as error:
        GDQ.load(models / "gdq_robot.zip", env=venv)
    assert len(str(error.value).splitlines()) == 1


def test_a_real_process_with_a_robot_world_prints_one_line(tmp_path) -> None:
    """pybullet writes a banner on stderr at import; the command line's error must still be its only line."""
    import subprocess

    command = [
        sys.executable,
        "-m",
        "sb3_eps.train",
        "--algo",
        "gdq",
        "--env",
        "MultiRobotNav-2-v0",
        "-n",
        "100",
    ]
    command += ["--env-kwargs", "lidar_noise_std:-1", "-f", str(tmp_path / "logs")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "lidar_noise_std" in result.stderr and not (tmp_path / "logs").exists()


# ---------------------------------------------------------------------------------------------- 5. plain installs
def test_the_base_install_has_progress_bars_and_tensorboard() -> None:
    text = (ROOT / "setup.cfg").read_text()
    base = text.split("install_requires =")[1].split("[options.packages.find]")[0]
    for name in ("tensorboard", "tqdm", "rich"):
        assert f"\n    {name}" in base, name


@pytest.mark.parametrize(
    ("missing", "flags", "words"),
    [(("optuna",), ["-optimize", "--n-trials", "1"], ["-optimize needs Optuna", "sb3-eps[tune]"])],
    ids=["optuna"],
)
def test_a_feature_whose_package_is_missing_fails_before_anything_is_written(
    missing, flags, words, tmp_path, monkeypatch, capsys
) -> None:
    for name in missing:
        monkeypatch.setitem(sys.modules, name, None)  # import (and find_spec) now fail as without the package
    monkeypatch.chdir(tmp_path)
    argv = ["--algo", "gdq", "--env", MPE, "-n", "100", "-f", "logs", *flags]
    status, stderr = run_cli(train.PROG, train.main, argv, capsys)
    lines = stderr.strip().splitlines()
    assert status == 2 and len(lines) == 1, stderr
    assert all(word in lines[0] for word in words), lines[0]
    assert not any(tmp_path.iterdir())


def test_export_without_onnx_names_the_extra_and_writes_nothing(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "onnx", None)
    with pytest.raises(ImportError, match=r"sb3-eps\[export\]"):
        export_policy(mpe_model(), tmp_path / "out" / "policy")
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------------------------- 6. code execution
def test_the_exported_policy_loads_without_pickle(tmp_path, monkeypatch) -> None:
    onnxruntime = pytest.importorskip("onnxruntime")
    model = mpe_model(GDQ)
    onnx_path, json_path = export_policy(model, tmp_path / "policy")

    def refuse(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("pickle used while loading the exported policy")

    for name in ("load", "loads", "Unpickler"):
        monkeypatch.setattr(pickle, name, refuse)
    monkeypatch.setattr(th, "load", refuse)
    description = json.loads(Path(json_path).read_text())
    session = onnxruntime.InferenceSession(str(tmp_path / description["onnx_file"]), providers=["CPUExecutionProvider"])
    observations = np.random.default_rng(0).uniform(-1, 1, (8, description["input"]["shape"][1])).astype(np.float32)
    (q_values,) = session.run([description["output"]["name"]], {description["input"]["name"]: observations})
    monkeypatch.undo()
    with th.no_grad():
        expected = model.policy.q_net(th.as_tensor(observations)).numpy()
    np.testing.assert_allclose(q_values, expected, rtol=1e-5, atol=1e-5)
    assert Path(onnx_path).read_bytes()[:2] != b"\x80\x04"  # not a pickle stream


def test_the_readme_says_model_zips_and_checkpoints_are_pickles() -> None:
    text = " ".join((ROOT / "README.md").read_text().split())
    assert "model zips and checkpoints are pickles" in text.lower()
    assert "trusted" in text.lower()


# ---------------------------------------------------------------------------------------------- 8. determinism
DETERMINISM_ARGV = [
    "--env", "MultiRobotNav-2-v0", "-n", "20000", "--seed", "7", "--verbose", "0", "--device", "cpu",
    "--eval-freq", "10000", "--eval-episodes", "2", "--n-eval-envs", "1", "--save-freq", "0",
    "--hyperparams", "policy_kwargs:dict(net_arch=[32], stream_arch=[16], global_net_arch=[16])", "n_envs:4",
    "learning_starts:1000", "batch_size:32", "buffer_size:5000", "train_freq:4", "learning_rate:lin_3e-4",
]  # fmt: skip


def curves(run: Path) -> tuple[list[list[str]], list[list[str]]]:
    """The learning curves of a run without wall-clock columns: monitor rows and progress rows."""
    lines = (run / "progress.csv").read_text().splitlines()
    keys = lines[0].split(",")
    keep = [index for index, key in enumerate(keys) if not key.startswith("time/") or key == "time/total_timesteps"]
    keep = [index for index in keep if keys[index] not in ("eps/round_time", "eps/time_share")]
    progress = [[row.split(",")[index] for index in keep] for row in lines]
    return without_wall_time(run / "monitor.csv"), progress


@pytest.mark.parametrize("algo", ["gdq", "eps_gdq"])
def test_two_runs_with_the_same_seed_give_identical_learning_curves(algo, tmp_path) -> None:
    extra = [
        "callback.n_workers:1", "callback.period_unit:ticks", "callback.period:2500", "callback.population_size:3",
        "callback.n_eval_episodes:1", "callback.max_eps_share:1.0",
    ] if algo == "eps_gdq" else []  # fmt: skip
    runs = []
    for name in ("first", "second"):
        assert train.main(["--algo", algo, *DETERMINISM_ARGV, *extra, "-f", str(tmp_path / name)]) == 0
        (run,) = (tmp_path / name / algo).iterdir()
        runs.append(run)
    first, second = curves(runs[0]), curves(runs[1])
    assert len(first[0]) > 10 and len(first[1]) > 3
    assert first == second
    if algo == "eps_gdq":
        rounds = [row for row in first[1][1:] if row[first[1][0].index("eps/round")] not in ("", "0")]
        assert rounds, "no EPS round ran"
    _, expected, _ = load_from_zip_file(runs[0] / "MultiRobotNav-2-v0.zip")
    _, actual, _ = load_from_zip_file(runs[1] / "MultiRobotNav-2-v0.zip")
    for key, value in expected["policy"].items():
        assert th.equal(actual["policy"][key], value), key
