"""The ``--gym-packages`` plug-in hook (RL Zoo's flag): a user module, written here into tmp_path, registers its own
world, algorithm and callback, and is trained, resumed and evaluated from the command line without any edit of the
package. The commands run in subprocesses, as a user would run them (and so the registrations stay out of this
process's registries)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from sb3_eps import train
from sb3_eps.zoo.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
USER_PACKAGE = '''
"""A user's package: a world (the one of docs/bring_your_own_world.md's test), an algorithm with options of its
own, a callback."""
import functools
import json
from typing import Literal

import pettingzoo
from stable_baselines3.common.callbacks import BaseCallback

import envs
from sb3_eps import IQL
from sb3_eps.zoo import register_algorithm, register_callback
from tests.test_bring_your_own_world import LineWorld


class ScaledIQL(IQL):
    """IQL whose loss is scaled: an option of its own, typed, which the config may set."""

    def __init__(self, *args, loss_scale: float = 1.0, reduction: Literal["plain", "scaled"] = "plain", **kwargs):
        self.loss_scale = loss_scale
        self.reduction = reduction
        super().__init__(*args, **kwargs)

    def _compute_loss(self, batch):
        loss, priorities, logs = super()._compute_loss(batch)
        return self.loss_scale * loss, priorities, {**logs, "loss_scale": self.loss_scale}


class StepCounter(BaseCallback):
    """Counts steps; writes the count at the end of training (so the test sees it ran, with its argument)."""

    def __init__(self, path: str, every: int = 1, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.path, self.every, self.count = path, every, 0

    def _on_step(self) -> bool:
        self.count += self.n_calls % self.every == 0
        return True

    def _on_training_end(self) -> None:
        with open(self.path, "w") as file:
            json.dump({"count": self.count, "every": self.every, "algo": type(self.model).__name__}, file)

    def state_dict(self):
        return {"count": self.count}

    def load_state_dict(self, state):
        self.count = state["count"]


envs.register("LineWorld-2-v0", LineWorld, fixed_kwargs={"n_agents": 2})
# A world registered with PettingZoo's own registry only.
pettingzoo.register("parallel", "LineWorldPZ-v0", entry_point=functools.partial(LineWorld, n_agents=2))
register_algorithm("scaled_iql", ScaledIQL, label="Scaled IL")
register_callback(StepCounter, "userpkg.StepCounter")
'''


def _config(tmp_path: Path) -> Path:
    path = tmp_path / "scaled_iql.yml"
    counter = tmp_path / "counter.json"
    path.write_text(
        textwrap.dedent(
            f"""\
            LineWorld-2-v0:
              n_timesteps: 1200
              n_envs: 2
              learning_starts: 100
              batch_size: 16
              buffer_size: 1000
              loss_scale: 0.5
              reduction: scaled
              policy_kwargs: "dict(net_arch=[16], stream_arch=[16])"
              callback:
                - userpkg.StepCounter:
                    path: {counter}
                    every: 2
            """
        )
    )
    return path


def _run(module: str, *arguments: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    paths = [str(cwd), str(ROOT), os.environ.get("PYTHONPATH", "")]  # the package, and tests/ for its world
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
    return subprocess.run(
        [sys.executable, "-m", module, *arguments], cwd=cwd, env=environment, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip


def test_a_user_package_is_trained_resumed_and_evaluated_from_the_command_line(tmp_path) -> None:
    (tmp_path / "userpkg.py").write_text(USER_PACKAGE)
    conf = _config(tmp_path)
    logs = tmp_path / "logs"
    result = _run(
        "sb3_eps.train", "--gym-packages", "userpkg", "--algo", "scaled_iql", "--env", "LineWorld-2-v0",
        "-conf", str(conf), "--seed", "0", "-f", str(logs), "--verbose", "0", "--eval-freq", "600",
        "--eval-episodes", "2", "--n-eval-envs", "1", "--save-freq", "600", "--keep-checkpoint",
        cwd=tmp_path,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    run_dir = logs / "scaled_iql" / "LineWorld-2-v0_1"
    assert (run_dir / "LineWorld-2-v0.zip").is_file() and (run_dir / "evaluations.npz").is_file()
    args = yaml.safe_load((run_dir / "LineWorld-2-v0" / "args.yml").read_text())
    assert args["gym_packages"] == ["userpkg"]
    config = yaml.safe_load((run_dir / "LineWorld-2-v0" / "config.yml").read_text())["LineWorld-2-v0"]
    assert config["loss_scale"] == 0.5 and config["reduction"] == "scaled"  # the algorithm's own options
    assert config["n_steps"] == 3 and config["policy_kwargs"]["net_arch"] == [16]  # the base's defaults filled in
    counter = yaml.safe_load((tmp_path / "counter.json").read_text())
    assert counter == {
        "count": 1200 // 2 // 2 // 2,
        "every": 2,
        "algo": "ScaledIQL",
    }  # 300 vector steps, every 2nd
    assert "train/loss_scale" in (run_dir / "progress.csv").read_text().splitlines()[0]
    # A finished run resumes as "already complete" once its recorded package is imported again.
    resumed = _run("sb3_eps.train", "--resume", str(run_dir), cwd=tmp_path)
    assert resumed.returncode == 0 and "finished already" in resumed.stdout, resumed.stderr
    # evaluate imports the run's recorded packages itself; the PettingZoo-registered id is a world too.
    output = tmp_path / "eval.json"
    evaluated = _run(
        "sb3_eps.evaluate", "--run", str(run_dir), "--eval-env", "LineWorldPZ-v0", "-n", "2", "--n-envs", "1",
        "--output", str(output), cwd=tmp_path,
    )  # fmt: skip
    assert evaluated.returncode == 0, evaluated.stderr
    assert yaml.safe_load(output.read_text())["n_episodes"] == 2


def test_a_config_setting_an_unknown_option_of_the_plugin_algorithm_is_refused(tmp_path) -> None:
    (tmp_path / "userpkg.py").write_text(USER_PACKAGE)
    conf = _config(tmp_path)
    conf.write_text(conf.read_text().replace("reduction: scaled", "reduction: squared"))
    result = _run(
        "sb3_eps.train", "--gym-packages", "userpkg", "--algo", "scaled_iql", "--env", "LineWorld-2-v0",
        "-conf", str(conf), "-f", str(tmp_path / "logs"), cwd=tmp_path,
    )  # fmt: skip
    assert result.returncode == 2
    assert "reduction must be one of plain, scaled, got 'squared'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not (tmp_path / "logs").exists()


def test_a_missing_package_is_one_line(tmp_path) -> None:
    with pytest.raises(ConfigError, match=r"--gym-packages: cannot import 'no_such_user_package'.*PYTHONPATH"):
        train.main(["--gym-packages", "no_such_user_package", "--algo", "gdq", "-f", str(tmp_path)])
    assert not any(tmp_path.iterdir())
