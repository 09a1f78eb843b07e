"""SB3's constructor conventions: replay_buffer_class / replay_buffer_kwargs, and the target-update count renamed
gradient_steps_per_target_update (target_update_interval kept as a deprecated alias giving the same training)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_eps import GDQ, IQL
from sb3_eps.common.buffers import JointReplayBuffer, PrioritizedJointReplayBuffer
from sb3_eps.zoo.config import resolve_config
from sb3_eps.zoo.schema import algorithm_kwargs
from tests.test_algorithms import tiny_model


def _update_schedule(model, n_timesteps: int = 300) -> list[int]:
    """Train and return ``_n_updates`` at every target update."""
    schedule: list[int] = []
    update = model._update_targets

    def recording() -> None:
        schedule.append(model._n_updates)
        update()

    model._update_targets = recording
    model.learn(n_timesteps)
    return schedule


@pytest.mark.parametrize("algo", ["iql", "gdq", "eps_gdq", "qmix", "vdn", "eps_iql"])
def test_every_zoo_config_keeps_one_target_update_per_gradient_step(algo) -> None:
    """The shipped configs gave target_update_interval: 1 (gradient steps); they now say it under the new name."""
    entry = resolve_config(algo, "MultiRobotNav-4-v0").entry
    assert "target_update_interval" not in entry
    assert algorithm_kwargs(entry)["gradient_steps_per_target_update"] == 1


def test_the_old_name_gives_the_same_target_update_schedule_and_weights() -> None:
    with pytest.warns(DeprecationWarning, match="gradient_steps_per_target_update"):
        old = tiny_model(GDQ, target_update_interval=3, gradient_steps=2)
    old_schedule = _update_schedule(old)  # each model seeds the global RNGs: train one before building the next
    new = tiny_model(GDQ, gradient_steps_per_target_update=3, gradient_steps=2)
    new_schedule = _update_schedule(new)
    assert old_schedule == new_schedule and old_schedule[:3] == [3, 6, 9]
    assert len(old_schedule) == new._n_updates // 3
    for name, tensor in new.policy.state_dict().items():
        assert th.equal(tensor, old.policy.state_dict()[name]), name
    # The default: one Polyak step after every gradient step, none during the random warm-up.
    default = tiny_model(IQL)
    assert _update_schedule(default) == list(range(1, default._n_updates + 1))
    with pytest.warns(DeprecationWarning):
        assert old.target_update_interval == 3


def test_a_config_with_the_old_key_loads_with_a_warning(tmp_path) -> None:
    path = tmp_path / "iql.yml"
    path.write_text("default:\n  n_timesteps: 1000\n  target_update_interval: 4\n")
    with pytest.warns(DeprecationWarning, match="rename it gradient_steps_per_target_update"):
        entry = resolve_config("iql", "CooperativeNavigation-v0", conf_file=path).entry
    assert entry["gradient_steps_per_target_update"] == 4 and "target_update_interval" not in entry
    path.write_text("default:\n  n_timesteps: 1000\n  target_update_interval: 4\n  gradient_steps_per_target_update: 2\n")
    with pytest.raises(Exception, match="same setting"), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        resolve_config("iql", "CooperativeNavigation-v0", conf_file=path)


def test_a_model_saved_under_the_old_name_loads_with_its_value(tmp_path) -> None:
    model = tiny_model(IQL, gradient_steps_per_target_update=5)
    del model.__dict__["gradient_steps_per_target_update"]
    model.__dict__["target_update_interval"] = 5  # what the file of an older version holds
    model.save(tmp_path / "old.zip")
    loaded = IQL.load(tmp_path / "old.zip", env=model.get_env())
    assert loaded.gradient_steps_per_target_update == 5 and "target_update_interval" not in loaded.__dict__


# ---------------------------------------------------------------------------------------------- replay buffers
class CountingBuffer(PrioritizedJointReplayBuffer):
    """A user's buffer: SB3's convention lets a subclass in, with its own constructor argument."""

    def __init__(self, *args, tag: str = "", **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.tag = tag
        self.n_added = 0

    def add_row(self, row):
        self.n_added += 1
        return super().add_row(row)


def test_replay_buffer_class_and_kwargs_as_sb3() -> None:
    assert isinstance(tiny_model(IQL).replay_buffer, PrioritizedJointReplayBuffer)
    uniform = tiny_model(IQL, replay_buffer_class=JointReplayBuffer)
    assert type(uniform.replay_buffer) is JointReplayBuffer and not uniform.prioritized_replay
    alpha = tiny_model(IQL, replay_buffer_class=PrioritizedJointReplayBuffer, replay_buffer_kwargs={"alpha": 0.3})
    assert alpha.replay_buffer.alpha == 0.3 and alpha.prioritized_replay
    model = tiny_model(GDQ, replay_buffer_class=CountingBuffer, replay_buffer_kwargs={"tag": "mine"})
    model.learn(150)
    buffer = model.replay_buffer
    assert isinstance(buffer, CountingBuffer) and buffer.tag == "mine" and buffer.alpha == model.prioritized_replay_alpha
    assert buffer.n_added > 0 and buffer.size() > 0 and buffer.n_agents == model.n_agents


def test_gdq_replays_uniformly_by_default_and_the_others_prioritise() -> None:
    """GDQ's default is uniform replay (rule T24, docs/results/gdq_uniform_replay.md); IQL, QMIX and VDN keep PER."""
    from sb3_eps import QMIX, VDN

    gdq = tiny_model(GDQ)
    assert type(gdq.replay_buffer) is JointReplayBuffer and not gdq.prioritized_replay
    for algorithm in (IQL, QMIX, VDN):
        model = tiny_model(algorithm)
        assert isinstance(model.replay_buffer, PrioritizedJointReplayBuffer) and model.prioritized_replay
    per = tiny_model(GDQ, prioritized_replay=True)
    assert isinstance(per.replay_buffer, PrioritizedJointReplayBuffer) and per.replay_buffer.alpha == 0.6


def test_the_config_names_a_replay_buffer_class() -> None:
    entry = resolve_config(
        "iql", "CooperativeNavigation-v0", hyperparams=["replay_buffer_class:JointReplayBuffer"]
    ).entry
    assert algorithm_kwargs(entry)["replay_buffer_class"] is JointReplayBuffer
    with pytest.raises(Exception, match="replay_buffer_class must be one of"):
        resolve_config("iql", "CooperativeNavigation-v0", hyperparams=["replay_buffer_class:ReplayBuffer"])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"replay_buffer_class": ReplayBuffer}, "must be JointReplayBuffer, PrioritizedJointReplayBuffer or a subclass"),
        ({"replay_buffer_class": "JointReplayBuffer"}, "must be JointReplayBuffer"),
        ({"replay_buffer_kwargs": {"n_agents": 2}}, r"cannot set \['n_agents'\]"),
        ({"replay_buffer_class": JointReplayBuffer, "replay_buffer_kwargs": {"alpha": 0.5}}, "do not fit JointReplayBuffer"),
    ],
)
def test_an_incompatible_replay_buffer_is_one_clear_error(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        tiny_model(IQL, **kwargs)


def test_prioritised_and_uniform_buffers_learn_the_same_as_before() -> None:
    """No class given: prioritized_replay chooses, as before (the same weights as naming the class)."""
    implicit = tiny_model(IQL, prioritized_replay=False).learn(200)  # trained before the next one seeds the RNGs
    explicit = tiny_model(IQL, prioritized_replay=True, replay_buffer_class=JointReplayBuffer).learn(200)
    for name, tensor in implicit.policy.state_dict().items():
        assert np.array_equal(tensor.numpy(), explicit.policy.state_dict()[name].numpy()), name


# ---------------------------------------------------------------------------------------------- moved names
MOVED = [
    *[("sb3_eps.zoo.exp_manager", name, "sb3_eps.zoo.run_folder", name)
      for name in ("ARGS_NAME", "CONFIG_NAME", "FINAL_REPORT_NAME", "final_model_name", "create_run_folder")],
    *[("sb3_eps.zoo.callbacks", name, "sb3_eps.zoo.run_folder", name)
      for name in ("MONITOR_NAME", "EVALUATIONS_NAME", "BEST_MODEL_NAME", "PROGRESS_NAME", "read_monitor")],
    ("sb3_eps.zoo.callbacks", "CheckpointCallback", "sb3_eps.zoo.callbacks", "TrainingStateCallback"),
    ("sb3_eps.zoo.evaluation", "find_run", "sb3_eps.zoo.run_folder", "find_run"),
    ("sb3_eps.gdq.policies", "GLOBAL_VALUES", "sb3_eps.gdq.gdq", "GLOBAL_VALUES"),
    ("sb3_eps.gdq.policies", "DEFAULT_GLOBAL_VALUES", "sb3_eps.gdq.gdq", "DEFAULT_GLOBAL_VALUES"),
]  # fmt: skip


@pytest.mark.parametrize(("old_module", "old", "new_module", "new"), MOVED, ids=[f"{m}.{n}" for m, n, _, _ in MOVED])
def test_moved_names_keep_a_deprecated_alias(old_module, old, new_module, new) -> None:
    import importlib

    with pytest.warns(DeprecationWarning, match=f"{old_module}.{old} is now {new_module}.{new}"):
        value = getattr(importlib.import_module(old_module), old)
    assert value is getattr(importlib.import_module(new_module), new)
    with pytest.raises(AttributeError):
        importlib.import_module(old_module).no_such_name  # noqa: B018


def test_check_eval_env_is_a_deprecated_wrapper_of_check_spaces() -> None:
    from sb3_eps.zoo.errors import ConfigError
    from sb3_eps.zoo.exp_manager import check_eval_env

    model = tiny_model(IQL)
    from sb3_eps import make_vec_env

    other = make_vec_env("Corridor-2-v0", n_envs=1)
    with pytest.warns(DeprecationWarning, match="check_spaces"), pytest.raises(ConfigError, match="--eval-env: Corridor-2-v0 has observation_space"):
        check_eval_env(model, other)


def test_a_config_with_gdq_options_in_policy_kwargs_loads_with_a_warning(tmp_path) -> None:
    path = tmp_path / "gdq.yml"
    path.write_text(
        "default:\n  n_timesteps: 1000\n  policy_kwargs: \"dict(net_arch=[16], global_values='stored', "
        "global_bootstrap=0.5)\"\n"
    )
    with pytest.warns(DeprecationWarning, match="global_values, global_bootstrap in policy_kwargs is deprecated"):
        entry = resolve_config("gdq", "CooperativeNavigation-v0", conf_file=path).entry
    assert entry["global_values"] == "stored" and entry["global_bootstrap"] == 0.5
    assert entry["policy_kwargs"]["net_arch"] == [16] and not {"global_values", "global_bootstrap"} & set(entry["policy_kwargs"])
    with pytest.raises(Exception, match="global_values must be one of recomputed, stored, target"):
        resolve_config("gdq", "CooperativeNavigation-v0", hyperparams=["global_values:cached"])
