"""The population of learners: selection copies deeply, perturbs as it says, costs no ticks, saves and resumes exactly."""

from __future__ import annotations

import json
import pathlib
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import VecEnvWrapper

import envs  # noqa: F401  # registers the worlds
from research.population import PopulationTrainer
from sb3_eps import GDQ, make_vec_env

ENV_ID = "CooperativeNavigation-v0"  # 3 agents, 25-tick episodes: fast
SMALL = {
    "learning_starts": 150,
    "batch_size": 16,
    "buffer_size": 2000,
    "train_freq": 3,
    "policy_kwargs": {"net_arch": [16], "stream_arch": [16], "global_net_arch": [16]},
}
# A run of four selections: 2 learners, turns of 50 ticks, a selection every 100 ticks of both.
RUN = {
    "k": 2,
    "interval": 100,
    "turn_ticks": 50,
    "fitness": "return",
    "fitness_episodes": 2,
    "seed": 0,
    **SMALL,
}


def trainer(**settings) -> PopulationTrainer:
    return PopulationTrainer(GDQ, ENV_ID, **{**RUN, **settings})


def state_of(learner) -> dict[str, th.Tensor]:
    return {key: value.clone() for key, value in learner.policy.state_dict().items()}


def optimizer_moments(learner) -> list[th.Tensor]:
    return [state["exp_avg"].clone() for state in learner.policy.optimizer.state.values()]


def assert_same_networks(first, second) -> None:
    for key, value in first.policy.state_dict().items():
        assert th.equal(value, second.policy.state_dict()[key]), key


def test_selection_copies_the_fittest_over_the_weakest_and_the_copy_is_deep() -> None:
    population = trainer(k=3, interval=10**9, mutation=None, perturb=())
    population.learn(3 * 90)  # gradient steps: the optimizers have moments to copy
    fittest, weakest, other = population.learners[1], population.learners[2], population.learners[0]
    fittest.learning_rate = 1e-3
    other_before = state_of(other)
    record = population.select(fitness=[0.2, 0.9, 0.1])

    assert (record["fittest"], record["weakest"]) == (1, 2)
    assert_same_networks(weakest, fittest)  # online, target and averaged networks
    for copied, source in zip(optimizer_moments(weakest), optimizer_moments(fittest), strict=True):
        assert th.equal(copied, source)
    assert weakest.learning_rate == 1e-3 and weakest.lr_schedule(0.5) == 1e-3
    assert weakest.replay_buffer is not fittest.replay_buffer  # the buffer stays the weakest's own
    assert len(weakest.ep_info_buffer) == 0  # its fitness starts afresh
    for key, value in other_before.items():
        assert th.equal(value, other.policy.state_dict()[key])

    with th.no_grad():  # a deep copy: changing the source in place leaves the copy as it was
        next(fittest.policy.q_net.parameters()).add_(1.0)
        for moment in fittest.policy.optimizer.state.values():
            moment["exp_avg"].add_(1.0)
    assert not th.equal(next(weakest.policy.q_net.parameters()), next(fittest.policy.q_net.parameters()))
    for copied, source in zip(optimizer_moments(weakest), optimizer_moments(fittest), strict=True):
        assert not th.equal(copied, source)

    assert "skipped" in population.select(fitness=[0.5, np.nan, 0.5])  # a tie, a learner sitting out: no copy
    with pytest.raises(ValueError, match=r"give one fitness per learner \(3\)"):
        population.select(fitness=[0.5, 0.1])


def test_the_perturbation_changes_what_it_says() -> None:
    population = trainer(mutation="safe", target_flip_share=0.1, perturb_factors=(2.0,))
    population.learn(2 * 90)
    fittest, weakest = population.learners
    record = population.select(fitness=[1.0, 0.0])
    assert record["learning_rate_factor"] == record["exploration_final_eps_factor"] == 2.0
    for progress in (1.0, 0.5, 0.1):
        assert weakest.lr_schedule(progress) == pytest.approx(2 * fittest.lr_schedule(progress))
    assert weakest.exploration_final_eps == pytest.approx(2 * fittest.exploration_final_eps)
    assert weakest.exploration_schedule(0.0) == pytest.approx(2 * fittest.exploration_schedule(0.0))
    assert 0.05 <= record["flip_share"] <= 0.2 and record["mutation_scale"] > 0
    online, target = weakest.policy.q_net, weakest.policy.q_net_target
    for (name, param), source, moved, source_target in zip(
        online.named_parameters(),
        fittest.policy.q_net.parameters(),
        target.parameters(),
        fittest.policy.q_net_target.parameters(),
        strict=True,
    ):
        step = param - source
        assert th.equal(step, th.zeros_like(step)) == name.startswith("value_stream."), name
        assert th.allclose(moved - source_target, step, atol=1e-6), name  # the target takes the same step


class CountedSteps(VecEnvWrapper):
    """Counts the vector steps of the worlds it wraps."""

    def __init__(self, venv) -> None:
        super().__init__(venv)
        self.n_steps = 0

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        self.n_steps += 1
        return self.venv.step_wait()


def test_fitness_costs_no_extra_ticks_and_comes_from_the_training_episodes() -> None:
    worlds = [CountedSteps(make_vec_env(ENV_ID, n_envs=2, seed=10 * index)) for index in range(2)]
    population = PopulationTrainer(GDQ, lambda index: worlds[index], **{**RUN, "share_buffer": True})
    assert population.learners[0].replay_buffer is population.learners[1].replay_buffer
    population.learn(400)
    selections = [record for record in population.history if "fittest" in record]
    assert selections
    assert population.ticks == sum(learner.ticks for learner in population.learners)
    assert population.ticks == sum(world.n_steps * 2 for world in worlds)  # every tick is a training tick
    measured, counts = population.fitness()
    for learner, value, count in zip(population.learners, measured, counts, strict=True):
        returns = [episode["r"] for episode in learner.ep_info_buffer][-2:]
        assert count == 2 and value == pytest.approx(np.mean(returns))
    population.settings["fitness"] = "success"
    successes, _ = population.fitness()
    for learner, value in zip(population.learners, successes, strict=True):
        assert value == np.mean([float(episode["success"]) for episode in learner.ep_info_buffer][-2:])
    for learner in population.learners:  # a world whose episodes carry no success flag
        learner.ep_info_buffer.extend([{"r": 1.0, "l": 25}] * 2)
    with pytest.raises(ValueError, match="use fitness='return'"):
        population.fitness()


def test_save_and_load_round_trip(tmp_path) -> None:
    population = trainer(crossover="distill")
    population.learn(400)
    assert any("distillation" in record for record in population.history)
    population.save(tmp_path / "population.zip")
    loaded = PopulationTrainer.load(tmp_path / "population.zip")
    assert loaded.history == json.loads(json.dumps(population.history))
    assert loaded.settings == population.settings
    shape = (3, *population.learners[0].observation_space.shape)
    observations = np.random.default_rng(0).normal(size=shape).astype(np.float32)
    for learner, original in zip(loaded.learners, population.learners, strict=True):
        assert_same_networks(learner, original)
        assert learner.env is None
        assert np.array_equal(
            learner.predict(observations, deterministic=True)[0],
            original.predict(observations, deterministic=True)[0],
        )
    assert isinstance(loaded.best, GDQ)
    loaded.best.save(tmp_path / "best.zip")
    with pytest.raises(ValueError, match="load the population with env"):
        loaded.learn(800)
    PopulationTrainer.load(tmp_path / "population.zip", env=ENV_ID).learn(460)  # new worlds: training goes on


SCRIPT = """
import sys
from sb3_eps import GDQ
from research.population import PopulationTrainer
population = PopulationTrainer(GDQ, {env!r}, log_path=sys.argv[1], **{settings!r})
population.learn({total}, checkpoint_path=sys.argv[2])
print("interrupted" if population.interrupted else "finished")
"""
RESUMED = {**RUN, "share_buffer": True, "crossover": "distill", "distillation_steps": 20}
TOTAL = 1_000


def test_a_run_stopped_by_sigterm_resumes_exactly(tmp_path) -> None:
    expected = PopulationTrainer(GDQ, ENV_ID, log_path=str(tmp_path / "expected.jsonl"), **RESUMED).learn(TOTAL)

    script = textwrap.dedent(SCRIPT.format(env=ENV_ID, settings=RESUMED, total=TOTAL))
    log, checkpoint = tmp_path / "selections.jsonl", tmp_path / "checkpoint.zip"
    # run from the repository's root, where research/ is importable
    root = pathlib.Path(__file__).resolve().parents[1]
    arguments = [sys.executable, "-c", script, str(log), str(checkpoint)]
    process = subprocess.Popen(arguments, stdout=subprocess.PIPE, text=True, cwd=root)
    deadline = time.time() + 120
    while not (log.exists() and log.read_text().count("\n") >= 1):  # a selection happened: stop it mid-run
        assert process.poll() is None and time.time() < deadline, "the run ended before it could be stopped"
        time.sleep(0.02)
    process.send_signal(signal.SIGTERM)
    output, _ = process.communicate(timeout=120)
    assert process.returncode == 0 and output.strip() == "interrupted"

    resumed = PopulationTrainer.load(checkpoint)
    assert 0 < resumed.ticks < TOTAL
    resumed.learn(TOTAL)
    assert resumed.history == expected.history
    assert log.read_text() == (tmp_path / "expected.jsonl").read_text()  # each selection once
    for learner, reference in zip(resumed.learners, expected.learners, strict=True):
        assert learner.num_timesteps == reference.num_timesteps
        assert_same_networks(learner, reference)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"k": 1}, r"k must be an int >= 2"),
        ({"crossover": "average"}, r"crossover must be one of \('copy', 'distill'\)"),
        ({"fitness": "speed"}, r"fitness must be one of"),
        ({"perturb": ["gamma"]}, r"perturb names \['gamma'\]"),
        ({"target_flip_share": 1.5}, r"target_flip_share must be in \(0, 1\)"),
        ({"perturb_factors": ()}, r"perturb_factors must be numbers > 0"),
        ({"share_buffer": "yes"}, r"share_buffer must be True or False"),
        ({"fitness_episodes": 20, "stats_window_size": 10}, r"fitness_episodes \(20\) exceeds the episodes"),
    ],
)
def test_bad_settings_are_one_line_errors(settings, message) -> None:
    with pytest.raises(ValueError, match=message) as error:
        PopulationTrainer(GDQ, None, **settings)
    assert "\n" not in str(error.value)


def test_bad_algorithm_and_budget_are_one_line_errors() -> None:
    with pytest.raises(ValueError, match="algorithm_class must be GDQ, IQL"):
        PopulationTrainer(dict, None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="total_ticks must be an int >= 0"):
        PopulationTrainer(GDQ, None).learn(-1)


def test_a_turn_keeps_the_schedules_of_the_whole_run(tmp_path) -> None:
    """A turn is a short ``learn`` call; the learning rate, exploration and PER schedules still run over the
    learner's whole share of the run (a stop after the first turn shows where they are)."""
    population = trainer(interval=10**9)
    population._request_stop(signal.SIGTERM, None)
    population.learn(4_000, checkpoint_path=tmp_path / "checkpoint.zip")
    assert population.interrupted and population.learners[1].ticks == 0
    first = population.learners[0]
    progress = 1 - first.ticks / 2_000
    assert first._current_progress_remaining == pytest.approx(progress)
    assert first.policy.optimizer.param_groups[0]["lr"] == pytest.approx(first.lr_schedule(progress), rel=1e-2)
    assert PopulationTrainer.load(tmp_path / "checkpoint.zip").learners[0].ticks == first.ticks
