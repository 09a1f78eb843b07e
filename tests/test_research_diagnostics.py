"""research/diagnostics.py: the probes of GDQ and QMIX plug into the base's ``diagnostics`` hook, log under
``train/``, come from a config's callback, and change nothing of the training (nor what a model saves)."""

from __future__ import annotations

import csv

import pytest
import torch as th
from stable_baselines3.common.logger import configure

import envs  # noqa: F401
from research.diagnostics import TrainDiagnostics, attach, gdq_diagnostics
from sb3_eps import GDQ, IQL, QMIX, VDN, make_vec_env
from sb3_eps.zoo.schema import build_callbacks, normalize_callbacks

TINY = {"net_arch": [16], "stream_arch": [16]}
EXTRA = {GDQ: {"global_net_arch": [16]}, QMIX: {"mixing_embed_dim": 8, "hypernet_hidden_dim": 16}, VDN: {}, IQL: {}}


def tiny_model(algorithm, **policy):
    venv = make_vec_env("CooperativeNavigation-v0", n_envs=2, seed=0)
    kwargs = {"learning_starts": 60, "batch_size": 16, "buffer_size": 2_000, "train_freq": 2, "seed": 0}
    return algorithm("MlpPolicy", venv, policy_kwargs={**TINY, **EXTRA[algorithm], **policy}, **kwargs)


@pytest.mark.parametrize(("init", "gain"), [("sum", 1.0), ("mean", 1.0 / 3.0)])
def test_gdq_diagnostics_measure_the_global_head_gain(init, gain) -> None:
    model = tiny_model(GDQ, global_init=init)
    model.learning_starts = 10_000
    model.learn(300)
    logs = gdq_diagnostics(model, model.replay_buffer.sample(16))
    # V_G starts as exactly sum(v) or mean(v), so dV_G/dv_i is 1 or 1/n for every agent.
    assert logs["global_gain"] == pytest.approx(gain, rel=1e-5)
    assert logs["global_gain_sum"] == pytest.approx(3 * gain, rel=1e-5)
    assert 0.0 <= logs["action_margin_small"] <= 1.0 and logs["action_margin"] >= 0.0
    assert logs["agent_value_std"] > 0.0


KEYS = {
    GDQ: ("global_gain", "global_gain_sum", "action_margin", "agent_value_std"),
    QMIX: ("mixer_gain_sum", "mixer_gain_std", "zero_input_gap", "agent_q_max"),
    VDN: ("mixer_gain_sum", "zero_input_gap"),
}


@pytest.mark.parametrize("algorithm", [GDQ, QMIX, VDN], ids=lambda a: a.__name__)
def test_the_probe_is_logged_and_changes_no_weight(algorithm, tmp_path) -> None:
    plain = tiny_model(algorithm)
    plain.learn(500)
    probed = attach(tiny_model(algorithm), interval=1)
    probed.set_logger(configure(str(tmp_path), ["csv"]))
    probed.learn(500, log_interval=1)
    for key, value in plain.policy.state_dict().items():
        assert th.equal(probed.policy.state_dict()[key], value), key
    with (tmp_path / "progress.csv").open() as file:
        rows = [row for row in csv.DictReader(file) if row.get("train/loss")]
    assert rows
    for key in KEYS[algorithm]:
        assert rows[-1][f"train/{key}"] != "", key
    probed.save(tmp_path / "model")
    assert algorithm.load(tmp_path / "model").diagnostics is None  # a probe is never saved


def test_a_config_names_the_probe_as_a_callback() -> None:
    entry = {"callback": normalize_callbacks([{"research.diagnostics.TrainDiagnostics": {"interval": 5}}], "test")}
    ((name, callback),) = build_callbacks(entry, "CooperativeNavigation-v0", 0, "test")
    assert name == "research.diagnostics.TrainDiagnostics" and isinstance(callback, TrainDiagnostics)
    model = tiny_model(IQL)
    model.learn(100, callback=callback)  # IQL has no probe: nothing attached, nothing logged
    assert model.diagnostics is None and model.diagnostics_interval == 5
    with pytest.raises(ValueError, match="interval must be an int >= 1"):
        TrainDiagnostics(interval=0)
