"""Worlds in worker processes (make_vec_env(..., vec_env_cls=SubprocVecEnv)): the same results as in process,
blocks of worlds per worker, snapshots mid-episode, training and EPS on top, and clear errors when a worker dies.

The bridge's contract tests (tests/test_vec_env.py) run in both modes as well."""

from __future__ import annotations

import os
import pickle
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

import envs  # noqa: F401  (registers the env ids: the tests run alone too)
from sb3_eps import EvolutionCallback, make_vec_env
from sb3_eps.common import subproc_vec_env
from sb3_eps.common.snapshots import snapshot_dumps
from sb3_eps.common.subproc_vec_env import (
    DEFAULT_SPIN_S,
    VecEnvWorkerError,
    _pack_step,
    _pack_step_reply,
    _unpack_step,
    _unpack_step_reply,
    default_layout,
    split_worlds,
)
from sb3_eps.gdq import GDQ

ROBOTS = "MultiRobotNav-4-v0"
# Short episodes, so worlds end (time limits, arrivals, collisions) and reset inside the compared stretch.
SHORT = {"max_episode_steps": 12}


def rollout(venv, n_steps: int, seed: int = 0) -> list:
    """Everything a step gives: observations, rewards, dones, alive flags, global states and the infos."""
    rng = np.random.default_rng(seed)
    record: list = [venv.reset(), [dict(info) for info in venv.reset_infos]]
    for _ in range(n_steps):
        obs, rewards, dones, infos = venv.step(rng.integers(venv.action_space.n, size=venv.num_envs))
        record.extend([obs, rewards, dones, venv.alive.copy(), venv.get_state().copy()])
        for info in infos:
            info = dict(info)
            if "episode" in info:
                info["episode"] = {k: v for k, v in info["episode"].items() if k != "t"}  # wall time
            record.append(info)
    return record


def assert_same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        if isinstance(x, dict):
            assert x.keys() == y.keys()
            for key in x:
                if isinstance(x[key], np.ndarray):
                    np.testing.assert_array_equal(x[key], y[key], err_msg=key)
                else:
                    assert x[key] == y[key], key
        else:
            np.testing.assert_array_equal(x, y)


@pytest.fixture
def closing():
    made = []
    yield made.append
    for venv in made:
        venv.close()


def subproc(closing, *args, **kwargs):
    venv = make_vec_env(*args, vec_env_cls=SubprocVecEnv, **kwargs)
    closing(venv)
    return venv


def test_worlds_are_split_into_contiguous_blocks() -> None:
    assert split_worlds(5, 2) == [range(0, 3), range(3, 5)]
    assert split_worlds(4, 4) == [range(i, i + 1) for i in range(4)]


def test_default_layout_main_process_and_one_worker_per_other_core() -> None:
    """(main_worlds, n_workers): the main process holds the first of min(cores, worlds) blocks."""
    assert default_layout(4, cores=2) == (2, 1)
    assert default_layout(3, cores=2) == (2, 1)
    assert default_layout(8, cores=4) == (2, 3)
    assert default_layout(2, cores=8) == (1, 1)
    assert default_layout(1, cores=2) == (0, 1)  # one world: in a worker
    assert default_layout(4, cores=1) == (0, 1)  # one core: one worker


@pytest.mark.parametrize("with_state", [False, True])
def test_a_step_travels_as_raw_bytes_and_comes_back_equal(with_state) -> None:
    """Actions out, observations, rewards, dones, alive flags and states back as bytes; infos pickled."""
    actions = np.array([4, 0, 2, 1], dtype=np.int64)
    assert _unpack_step(_pack_step("step", (actions, with_state))) == (pytest.approx(actions), with_state)
    assert _pack_step("step", (actions.astype(np.int32), False)) is None  # anything else: the pickled command
    assert _pack_step("step", (np.zeros((4, 2)), False)) is None
    assert _pack_step("reset", (actions, False)) is None
    rng = np.random.default_rng(0)
    reply = (
        rng.random((4, 7), dtype=np.float32),  # odd sizes: the arrays after them stay 8-byte aligned
        rng.random(4, dtype=np.float32),
        np.array([True, False, False, True]),
        [{"alive": True, "terminal_observation": np.ones(7)}, {}, {}, {"episode": {"r": 1.5}}],
        np.array([True, True, False, True]),
        rng.random((1, 5), dtype=np.float32) if with_state else None,
        [{"seed": 3}] * 4 if with_state else None,
    )
    back = _unpack_step_reply(_pack_step_reply(reply))
    for sent, got in zip(reply, back):
        if isinstance(sent, np.ndarray):
            assert got.dtype == sent.dtype and got.flags.aligned
            np.testing.assert_array_equal(got, sent)
        elif sent is None:
            assert got is None
    assert back[3][0]["terminal_observation"].tolist() == [1.0] * 7 and back[3][3] == {"episode": {"r": 1.5}}
    assert back[6] == reply[6]
    objects = (np.array([None] * 4), *reply[1:])
    assert _pack_step_reply(objects) is None  # arrays of Python objects: the pickled reply


@pytest.mark.parametrize(
    ("vec_env_kwargs", "main_worlds", "n_workers"),
    [
        ({"n_workers": 1}, 0, 1),  # one worker holds all worlds
        ({"n_workers": 2}, 0, 2),  # blocks of 2 + 1
        ({"n_workers": 3}, 0, 3),  # one world per worker
        ({"main_worlds": 1, "n_workers": 1}, 1, 1),  # the main process steps world 0, a worker worlds 1-2
        ({"main_worlds": 2, "n_workers": 1, "spin_s": 0}, 2, 1),  # worlds 0-1 here, no polling
        ({"main_worlds": 1, "n_workers": 2, "spin_s": 0.01}, 1, 2),  # world 0 here, one per worker
    ],
)
def test_same_seed_same_results_as_in_process(closing, vec_env_kwargs, main_worlds, n_workers) -> None:
    """3 worlds of 4 robots in every layout: all in workers, or a block in the main process beside them."""
    in_process = make_vec_env(ROBOTS, n_envs=3, seed=5, env_kwargs=SHORT, vec_env_cls=DummyVecEnv)
    closing(in_process)
    workers = subproc(closing, ROBOTS, n_envs=3, seed=5, env_kwargs=SHORT, vec_env_kwargs=vec_env_kwargs)
    assert (workers.main_worlds, workers.n_workers) == (main_worlds, n_workers)
    assert len(set(workers.worker_pids)) == n_workers
    assert os.getpid() not in workers.worker_pids
    expected = rollout(in_process, 40)
    assert any("episode" in item for item in expected if isinstance(item, dict))  # episodes ended and reset
    assert_same(rollout(workers, 40), expected)
    assert workers.total_ticks == in_process.total_ticks == 120


@pytest.mark.parametrize("vec_env_kwargs", [{"n_workers": 2}, {"main_worlds": 1}])
def test_a_snapshot_continues_mid_episode_in_new_workers(closing, vec_env_kwargs) -> None:
    venv = subproc(closing, ROBOTS, n_envs=2, seed=1, env_kwargs={"max_episode_steps": 30}, vec_env_kwargs=vec_env_kwargs)
    rollout(venv, 7)  # mid-episode
    copy = pickle.loads(snapshot_dumps(venv))  # what a checkpoint does
    closing(copy)
    assert set(copy.worker_pids).isdisjoint(venv.worker_pids)
    assert (copy.main_worlds, copy.n_workers, copy.spin_s) == (venv.main_worlds, venv.n_workers, venv.spin_s)
    assert copy.total_ticks == venv.total_ticks and copy.reset_infos == venv.reset_infos
    rng = np.random.default_rng(2)
    for _ in range(30):  # across the end of the episode
        actions = rng.integers(5, size=venv.num_envs)
        expected, got = venv.step(actions), copy.step(actions)
        for x, y in zip(expected[:3], got[:3]):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(copy.get_state(), venv.get_state())


@pytest.mark.parametrize("vec_env_cls", [DummyVecEnv, SubprocVecEnv])
def test_a_snapshot_counts_run_time_not_the_pause(closing, monkeypatch, vec_env_cls) -> None:
    """Episodes' ``t`` is run time: a checkpoint loaded 1000 s after it was written goes on from the seconds that
    had elapsed when it was written, so a stopped and resumed run does not count its pause."""
    venv = make_vec_env(ROBOTS, n_envs=1, seed=1, env_kwargs=SHORT, vec_env_cls=vec_env_cls)
    closing(venv)
    venv.reset()
    venv._t_start = time.time() - 100.0  # 100 s into the run
    payload = snapshot_dumps(venv)
    real_time = time.time
    monkeypatch.setattr(time, "time", lambda: real_time() + 1000.0)
    copy = pickle.loads(payload)
    closing(copy)
    assert 100.0 <= time.time() - copy._t_start < 130.0
    if vec_env_cls is DummyVecEnv:  # in this process, where the clock is patched: the episodes' t itself
        ended = []
        for _ in range(SHORT["max_episode_steps"] + 1):
            _, _, _, infos = copy.step(np.zeros(copy.num_envs, dtype=np.int64))
            ended += [info["episode"]["t"] for info in infos if "episode" in info]
        assert ended and all(100.0 <= t < 130.0 for t in ended)


def test_gdq_trains_the_same_with_workers() -> None:
    """A seeded GDQ run (PER, n-step returns, the global state every tick) gives the same network in both modes."""
    weights = []
    for vec_env_cls in (DummyVecEnv, SubprocVecEnv):
        venv = make_vec_env("MultiRobotNav-2-v0", n_envs=2, env_kwargs={"max_episode_steps": 30}, vec_env_cls=vec_env_cls)
        model = GDQ(
            "MlpPolicy", venv, seed=3, learning_starts=100, batch_size=16, buffer_size=2_000, train_freq=2,
            prioritized_replay=True, policy_kwargs={"net_arch": [16], "stream_arch": [16], "global_net_arch": [16]},
        )  # fmt: skip
        model.learn(800)
        weights.append({k: v.clone() for k, v in model.policy.state_dict().items()})
        assert len(model.ep_info_buffer) > 0
        venv.close()
    for key, value in weights[0].items():
        assert th.equal(weights[1][key], value), key


def _train_gdq(vec_env_cls, overlap_training: bool, **vec_env_kwargs) -> tuple[dict, int]:
    venv = make_vec_env(
        "MultiRobotNav-2-v0", n_envs=2, env_kwargs={"max_episode_steps": 30}, vec_env_cls=vec_env_cls,
        vec_env_kwargs=vec_env_kwargs or None,
    )  # fmt: skip
    try:
        model = GDQ(
            "MlpPolicy", venv, seed=3, learning_starts=100, batch_size=16, buffer_size=2_000, train_freq=2,
            gradient_steps=2, overlap_training=overlap_training,
            policy_kwargs={"net_arch": [16], "stream_arch": [16], "global_net_arch": [16]},
        )  # fmt: skip
        model.learn(800)
        return {k: v.clone() for k, v in model.policy.state_dict().items()}, model._n_updates
    finally:
        venv.close()


def test_overlap_training_learns_while_the_workers_step_and_gives_the_same_results_in_both_modes() -> None:
    """overlap_training runs the gradient steps between step_async and step_wait: the same network in process
    and with every world in a worker, and another network than without it (a tick's transition joins the buffer
    after its gradient steps). Gradient steps: as many as without it, less the one training call that found the
    buffer still empty (its first n-step row came with that very tick)."""
    in_process, n_in_process = _train_gdq(DummyVecEnv, True)
    workers, n_workers = _train_gdq(SubprocVecEnv, True, main_worlds=0, n_workers=1)
    plain, n_plain = _train_gdq(DummyVecEnv, False)
    assert n_in_process == n_workers > 0
    assert n_plain - n_in_process in (0, 2)  # gradient_steps=2 per call
    for key, value in in_process.items():
        assert th.equal(workers[key], value), key
    assert any(not th.equal(plain[key], value) for key, value in in_process.items())


def test_a_step_in_flight_refuses_other_commands_and_closes_cleanly(closing) -> None:
    venv = subproc(closing, ROBOTS, n_envs=2, vec_env_kwargs={"main_worlds": 0, "n_workers": 1})
    venv.reset()
    with pytest.raises(RuntimeError, match="step_async"):
        venv.step_wait()
    venv.step_async(np.zeros(venv.num_envs, dtype=np.int64))
    with pytest.raises(RuntimeError, match="in flight"):
        venv.reset()
    with pytest.raises(RuntimeError, match="in flight"):
        venv.get_attr("n_robots")
    obs, *_ = venv.step_wait()
    assert obs.shape[0] == venv.num_envs
    venv.step_async(np.zeros(venv.num_envs, dtype=np.int64))
    venv.close()  # drains the step's replies before it asks the workers to close
    assert all(not process.is_alive() for process in venv._workers.pool._processes)


def test_overlap_training_needs_train_freq_in_steps() -> None:
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=1)
    with pytest.raises(ValueError, match="overlap_training needs train_freq in steps"):
        GDQ("MlpPolicy", venv, train_freq=(1, "episode"), overlap_training=True)
    venv.close()


def test_eps_evaluation_workers_next_to_the_world_workers() -> None:
    """EPS forks its evaluation workers while the training worlds live in their own workers."""
    results = []
    for vec_env_cls in (DummyVecEnv, SubprocVecEnv):
        venv = make_vec_env("CooperativeNavigation-v0", n_envs=2, seed=0, vec_env_cls=vec_env_cls)
        model = GDQ(
            "MlpPolicy", venv, seed=0, learning_starts=60, batch_size=16, buffer_size=2_000, train_freq=2,
            policy_kwargs={"net_arch": [16], "stream_arch": [16], "global_net_arch": [16]},
        )  # fmt: skip
        callback = EvolutionCallback(
            eval_env_id="CooperativeNavigationSingle-v0", population_size=3, period=2, n_eval_episodes=2,
            n_workers=2, seed=0, period_unit="episodes", max_eps_share=None,
        )  # fmt: skip
        model.learn(600, callback=callback)
        assert callback.history and len(callback.worker_pids) == 0  # closed at the end of training
        assert not any(entry["skipped"] for entry in callback.history)
        results.append([entry["fitness"] for entry in callback.history])
        venv.close()
    assert results[0] == results[1]


# --- errors ---------------------------------------------------------------------------------------------------------


def test_the_default_layout_steps_a_block_in_the_main_process(closing, monkeypatch) -> None:
    """On 2 cores: worlds 0-1 here and 2-3 in one worker, both polling; where the processes outnumber the cores,
    nobody polls."""
    monkeypatch.setattr(subproc_vec_env, "available_cores", lambda: 2)
    venv = subproc(closing, "Corridor-2-v0", n_envs=4, seed=0)
    assert (venv.main_worlds, venv.n_workers, venv.spin_s) == (2, 1, DEFAULT_SPIN_S)
    assert subproc(closing, "Corridor-2-v0", n_envs=4, vec_env_kwargs={"n_workers": 2}).spin_s == 0.0
    assert subproc(closing, "Corridor-2-v0", n_envs=4, vec_env_kwargs={"main_worlds": 1}).n_workers == 1
    monkeypatch.setattr(subproc_vec_env, "available_cores", lambda: 1)
    venv = subproc(closing, "Corridor-2-v0", n_envs=4, seed=0)
    assert (venv.main_worlds, venv.n_workers, venv.spin_s) == (0, 1, 0.0)


def test_an_error_in_the_main_process_block_keeps_the_workers_in_step(closing) -> None:
    """An exception inside a world of the main process's block is raised as is (as in process), after the workers'
    replies to the same command have been collected: the next commands get their own replies."""
    in_process = make_vec_env(ROBOTS, n_envs=2, seed=4, env_kwargs=SHORT, vec_env_cls=DummyVecEnv)
    closing(in_process)
    venv = subproc(closing, ROBOTS, n_envs=2, seed=4, env_kwargs=SHORT, vec_env_kwargs={"main_worlds": 1})
    expected, got = rollout(in_process, 3), rollout(venv, 3)
    with pytest.raises(AttributeError, match="no_such_method"):
        venv.env_method("no_such_method")  # both worlds: the worker's reply is an error too
    assert venv.get_attr("max_episode_steps") == [12] * venv.num_envs
    rng = np.random.default_rng(1)
    for _ in range(15):
        actions = rng.integers(5, size=venv.num_envs)
        for x, y in zip(in_process.step(actions)[:3], venv.step(actions)[:3]):
            np.testing.assert_array_equal(x, y)
    assert_same(got, expected)


@pytest.mark.parametrize("vec_env_kwargs", [{"n_workers": 2}, {"main_worlds": 2, "n_workers": 1}])
def test_a_killed_worker_raises_a_clear_error_naming_its_worlds(closing, vec_env_kwargs) -> None:
    """Worlds 2-3 live in the last worker, whether worlds 0-1 are in another worker or in the main process."""
    venv = subproc(closing, "Corridor-2-v0", n_envs=4, seed=0, vec_env_kwargs=vec_env_kwargs)
    venv.reset()
    victim = venv.worker_pids[-1]
    os.kill(victim, signal.SIGKILL)
    with pytest.raises(VecEnvWorkerError) as caught:
        venv.step(np.zeros(venv.num_envs, dtype=np.int64))
    message = str(caught.value)
    assert "worlds 2-3 of Corridor-2-v0" in message and str(victim) in message
    assert "killed by signal 9" in message and "--resume" in message
    venv.close()  # closing after a death neither hangs nor raises


def test_an_error_inside_a_world_comes_back_with_its_traceback(closing) -> None:
    venv = subproc(closing, "Corridor-2-v0", n_envs=2, seed=0)
    venv.reset()
    with pytest.raises(VecEnvWorkerError, match=r"world 1 of Corridor-2-v0 .* no_such_method"):
        venv.env_method("no_such_method", indices=[2])
    venv.step(np.zeros(venv.num_envs, dtype=np.int64))  # the worker lives on


def test_workers_ignore_sigterm_until_the_main_process_closes_them(closing) -> None:
    venv = subproc(closing, "Corridor-2-v0", n_envs=2, seed=0)
    venv.reset()
    for pid in venv.worker_pids:
        os.kill(pid, signal.SIGTERM)  # as a process-group signal would: the run's checkpoint needs its worlds
    venv.step(np.zeros(venv.num_envs, dtype=np.int64))
    assert len(snapshot_dumps(venv)) > 0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"vec_env_cls": "threads"}, "vec_env_cls must be DummyVecEnv"),
        ({"vec_env_cls": dict}, "vec_env_cls must be DummyVecEnv"),
        ({"vec_env_cls": "subproc", "vec_env_kwargs": {"n_workers": 0}}, "n_workers must be an int >= 1"),
        (
            {"vec_env_cls": "subproc", "vec_env_kwargs": {"start_method": "teleport"}},
            "start_method 'teleport'",
        ),
        ({"vec_env_cls": "subproc", "vec_env_kwargs": {"workers": 2}}, r"vec_env_kwargs \['workers'\]"),
        (
            {"vec_env_cls": "subproc", "vec_env_kwargs": {"main_worlds": 2}},
            r"main_worlds must be an int in \[0, 1\]",
        ),
        ({"vec_env_cls": "subproc", "vec_env_kwargs": {"main_worlds": -1}}, "main_worlds must be"),
        ({"vec_env_cls": "subproc", "vec_env_kwargs": {"main_worlds": True}}, "main_worlds must be"),
        ({"vec_env_cls": "subproc", "vec_env_kwargs": {"spin_s": -0.1}}, "spin_s must be a number"),
        ({"vec_env_cls": "subproc", "vec_env_kwargs": {"spin_s": "long"}}, "spin_s must be a number"),
        ({"vec_env_cls": "dummy", "vec_env_kwargs": {"n_workers": 2}}, "not understood with 'dummy'"),
        ({"vec_env_cls": "subproc", "env_kwargs": {"max_episode_steps": -1}}, "max_episode_steps"),
    ],
)
def test_bad_switches_are_one_clear_error(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        make_vec_env("MultiRobotNav-2-v0", n_envs=2, **kwargs)


def test_a_run_whose_worker_dies_stops_with_one_line_and_keeps_its_checkpoint(tmp_path) -> None:
    """python -m sb3_eps.train --vec-env subproc: a killed world worker ends the run with exit status 1 and one line
    naming the worlds; the last checkpoint stays, and --resume finishes the run."""
    argv = [
        sys.executable, "-m", "sb3_eps.train", "--algo", "gdq", "--env", "Corridor-2-v0", "-n", "3000",
        "--seed", "0", "--eval-freq", "0", "--save-freq", "300", "--verbose", "0", "--vec-env", "subproc",
        "--hyperparams", "n_envs:2", "-f", str(tmp_path),
    ]  # fmt: skip
    process = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not list(tmp_path.glob("gdq/*/checkpoint.zip")):
        assert process.poll() is None and time.time() < deadline, "training ended before a checkpoint"
        time.sleep(0.02)
    workers = [int(path.parent.name) for path in Path("/proc").glob("[0-9]*/stat") if _parent_pid(path) == process.pid]
    assert len(workers) >= 1  # the default layout: world 0 in this process, world 1 in a worker (2 cores)
    os.kill(workers[-1], signal.SIGKILL)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 1
    (line,) = stderr.strip().splitlines()
    assert "error:" in line and re.search(r"worlds? (1|0-1) of Corridor-2-v0", line) and "killed by signal 9" in line
    assert "--resume" in line and "Traceback" not in stderr
    (run,) = tmp_path.glob("gdq/*")
    assert (run / "checkpoint.zip").is_file()
    resumed = subprocess.run([sys.executable, "-m", "sb3_eps.train", "--resume", str(run), "--verbose", "0"])
    assert resumed.returncode == 0 and (run / "Corridor-2-v0.zip").is_file()


def _parent_pid(stat: Path) -> int | None:
    try:
        return int(stat.read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None
