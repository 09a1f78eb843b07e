"""SB3's constructor conventions: replay_buffer_class / replay_buffer_kwargs, and the target-update count
gradient_steps_per_target_update (gradient steps, not SB3 DQN's env steps of target_update_interval)."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_eps import GDQ, IQL
from sb3_eps.common.buffers import JointReplayBuffer, PrioritizedJointReplayBuffer
from sb3_eps.zoo.config import resolve_config
from sb3_eps.zoo.schema import algorithm_kwargs, algorithm_spec
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
    assert algorithm_kwargs(entry, algorithm_spec(algo))["gradient_steps_per_target_update"] == 1


def test_gradient_steps_per_target_update_counts_gradient_steps() -> None:
    model = tiny_model(GDQ, gradient_steps_per_target_update=3, gradient_steps=2)
    schedule = _update_schedule(model)
    assert schedule[:3] == [3, 6, 9] and len(schedule) == model._n_updates // 3
    # The default: one Polyak step after every gradient step, none during the random warm-up.
    default = tiny_model(IQL)
    assert _update_schedule(default) == list(range(1, default._n_updates + 1))


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
    entry = resolve_config("iql", "CooperativeNavigation-v0", hyperparams=["replay_buffer_class:JointReplayBuffer"]).entry
    assert algorithm_kwargs(entry, algorithm_spec("iql"))["replay_buffer_class"] is JointReplayBuffer
    with pytest.raises(Exception, match="replay_buffer_class must be one of"):
        resolve_config("iql", "CooperativeNavigation-v0", hyperparams=["replay_buffer_class:ReplayBuffer"])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"replay_buffer_class": ReplayBuffer},
            "must be JointReplayBuffer, PrioritizedJointReplayBuffer or a subclass",
        ),
        ({"replay_buffer_class": "JointReplayBuffer"}, "must be JointReplayBuffer"),
        ({"replay_buffer_kwargs": {"n_agents": 2}}, r"cannot set \['n_agents'\]"),
        (
            {"replay_buffer_class": JointReplayBuffer, "replay_buffer_kwargs": {"alpha": 0.5}},
            "do not fit JointReplayBuffer",
        ),
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


def test_gdq_options_belong_to_the_entry_not_to_policy_kwargs(tmp_path) -> None:
    path = tmp_path / "gdq.yml"
    path.write_text("default:\n  n_timesteps: 1000\n  policy_kwargs: \"dict(net_arch=[16], global_values='stored')\"\n")
    with pytest.raises(Exception, match="policy_kwargs: unknown key 'global_values'"):
        resolve_config("gdq", "CooperativeNavigation-v0", conf_file=path)
    with pytest.raises(Exception, match="global_values must be one of recomputed, target"):
        resolve_config("gdq", "CooperativeNavigation-v0", hyperparams=["global_values:cached"])
