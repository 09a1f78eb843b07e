"""A population of learners from a config entry (``population:``): the shipped YAML builds the trainer of its Python
one-liner, a run fills the run folder of any run and its final model evaluates, a run stopped by SIGTERM resumes to
the uninterrupted run, and bad settings are one line that leaves no run folder."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch as th

import envs  # noqa: F401
from research.population import PopulationTrainer
from research.population.zoo import check_population_run, population_kwargs
from sb3_eps import GDQ, evaluate, make_vec_env, train
from sb3_eps.zoo.checkpoint import verify_checkpoint
from sb3_eps.zoo.cli import TrainOptions
from sb3_eps.zoo.config import resolve_config
from sb3_eps.zoo.errors import run_command
from tests.test_zoo_resume import assert_equal_runs, stop_at_checkpoint

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "zoo_configs"
ENV_ID = "MultiRobotNav-2-v0"
# 2 learners of 2 robots, 30-tick episodes: a selection every 100 ticks of both from the second on (each learner
# needs 2 finished training episodes); fitness by team return (a tie of 0 % successes would skip every selection).
TINY = f"""\
{ENV_ID}:
  n_timesteps: 1600
  n_envs: 1
  env_kwargs: {{max_episode_steps: 30}}
  learning_starts: 100
  batch_size: 16
  buffer_size: 2000
  train_freq: 3
  policy_kwargs: {{net_arch: [16], stream_arch: [16], global_net_arch: [16]}}
  population:
    k: 2
    interval: 100
    turn_ticks: 50
    fitness: return
    fitness_episodes: 2
    share_buffer: true
    crossover: distill
    distillation_steps: 20
"""
# The population key is research/population's plug-in: the run names it, and --resume imports it again from args.yml.
FLAGS = [
    "--gym-packages",
    "research.population",
    "--eval-freq",
    "500",
    "--eval-episodes",
    "2",
    "--n-eval-envs",
    "1",
    "--save-freq",
    "400",
    "--verbose",
    "0",
]


def the_run(folder: Path) -> Path:
    (path,) = (folder / "gdq").iterdir()
    return path


def argv(tmp_path: Path, folder: Path, *extra: str) -> list[str]:
    conf = tmp_path / "population.yml"
    conf.write_text(TINY)
    return ["--algo", "gdq", "--env", ENV_ID, "-conf", str(conf), "--seed", "4", "-f", str(folder), *FLAGS, *extra]


# ---------------------------------------------------------------------------------------------- the YAML
@pytest.mark.parametrize(("override", "python"), [([], {}), (["population.crossover:distill"], {"crossover": "distill"})])
def test_the_yaml_builds_the_trainer_of_its_python_one_liner(override, python) -> None:
    """``research/zoo_configs/gdq_population.yml`` (and its distillation arm) against the header's one-liner
    ``PopulationTrainer(GDQ, "MultiRobotNav-8-v0", k=4, n_envs=4, share_buffer=True, interval=40_000, seed=0)``:
    the same settings, and learners of the same hyper-parameters and initial weights."""
    config = resolve_config("gdq", "MultiRobotNav-8-v0", ROOT / "research" / "zoo_configs" / "gdq_population.yml", override)
    assert config.entry["tuned"] is False and config.entry["n_timesteps"] == 8 * 300_000
    check_population_run(config, TrainOptions(algo="gdq", env="MultiRobotNav-8-v0", seed=0))
    from_yaml = PopulationTrainer(GDQ, None, seed=0, **population_kwargs(config))
    one_liner = PopulationTrainer(GDQ, None, k=4, n_envs=4, share_buffer=True, interval=40_000, seed=0, **python)
    learners = from_yaml.settings.pop("algorithm_kwargs")
    assert one_liner.settings.pop("algorithm_kwargs") == {}
    assert from_yaml.settings == one_liner.settings

    env = make_vec_env("MultiRobotNav-8-v0", n_envs=1, seed=0)
    try:
        built = GDQ("MlpPolicy", env, seed=0, **learners)
        default = GDQ("MlpPolicy", env, seed=0)
        for name in ("gamma", "tau", "batch_size", "buffer_size", "learning_starts", "train_freq", "gradient_steps",
                     "exploration_fraction", "exploration_final_eps", "prioritized_replay", "n_steps"):  # fmt: skip
            assert getattr(built, name) == getattr(default, name), name
        for progress in (1.0, 0.5, 0.0):
            assert built.lr_schedule(progress) == default.lr_schedule(progress)
        for key, value in default.policy.state_dict().items():
            assert th.equal(built.policy.state_dict()[key], value), key
    finally:
        env.close()


# ---------------------------------------------------------------------------------------------- a run
@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    tmp_path = tmp_path_factory.mktemp("uninterrupted")
    assert train.main(argv(tmp_path, tmp_path / "logs", "--keep-checkpoint")) == 0
    return the_run(tmp_path / "logs")


def test_a_population_run_fills_the_run_folder_and_its_model_evaluates(uninterrupted) -> None:
    run = uninterrupted
    names = {path.name for path in run.iterdir()}
    assert {
        ENV_ID, f"{ENV_ID}.zip", "best_model.zip", "evaluations.npz", "final_vs_best.txt", "monitor.csv",
        "progress.csv", "population.zip", "population_selections.jsonl", "checkpoint.zip",
    } <= names  # fmt: skip
    assert {path.name for path in (run / ENV_ID).iterdir()} == {"args.yml", "config.yml", "command.txt"}
    assert "population:" in (run / ENV_ID / "config.yml").read_text()
    assert verify_checkpoint(run / "checkpoint.zip")["complete"] is True

    population = PopulationTrainer.load(run / "population.zip")
    # n_timesteps counts agent-steps of both learners of 2 robots: 400 ticks each (a turn ends with a rollout of
    # train_freq 3 ticks, so it may run 2 ticks over)
    assert all(400 <= learner.ticks < 403 for learner in population.learners)
    selections = [json.loads(line) for line in (run / "population_selections.jsonl").read_text().splitlines()]
    assert selections == population.history and any("fittest" in record for record in selections)
    monitor = (run / "monitor.csv").read_text().splitlines()
    learner = monitor[1].split(",").index("learner")
    assert {row.split(",")[learner] for row in monitor[2:]} == {"0", "1"}

    final = GDQ.load(run / f"{ENV_ID}.zip")  # the fittest learner: a plain GDQ model
    fittest = population.best
    for key, value in fittest.policy.state_dict().items():
        assert th.equal(final.policy.state_dict()[key], value), key
    output = run / "evaluation.json"
    arguments = ["--run", str(run), "-n", "2", "--n-envs", "1", "--env-kwargs", "max_episode_steps:30"]
    assert evaluate.main([*arguments, "--output", str(output)]) == 0
    assert json.loads(output.read_text())["n_episodes"] == 2


def test_a_population_stopped_by_sigterm_resumes_to_the_uninterrupted_run(uninterrupted, tmp_path) -> None:
    folder = tmp_path / "logs"
    process = subprocess.Popen([sys.executable, "-m", "sb3_eps.train", *argv(tmp_path, folder, "--keep-checkpoint")], cwd=ROOT)
    # the second periodic checkpoint: after a copy and an evaluation, before the end
    stop_at_checkpoint(process, folder, lambda meta: meta.get("num_timesteps", 0) >= 800, 300, "it could be stopped")
    run = the_run(folder)
    meta = verify_checkpoint(run / "checkpoint.zip")
    assert 800 <= meta["num_timesteps"] < 1600 and meta["complete"] is False
    assert "fittest" in (run / "population_selections.jsonl").read_text()  # a copy before the stop
    with np.load(run / "evaluations.npz") as evaluations:
        assert list(evaluations["timesteps"]) and evaluations["timesteps"][-1] <= meta["num_timesteps"]
    assert not (run / f"{ENV_ID}.zip").exists()

    assert train.main(["--resume", str(run), "--verbose", "0"]) == 0
    assert_equal_runs(run, uninterrupted, ENV_ID)  # final weights, episodes, logged rows, evaluations
    selections = "population_selections.jsonl"
    assert (run / selections).read_text() == (uninterrupted / selections).read_text()  # each selection once
    resumed, expected = (PopulationTrainer.load(path / "population.zip") for path in (run, uninterrupted))
    for learner, reference in zip(resumed.learners, expected.learners, strict=True):
        assert learner.num_timesteps == reference.num_timesteps
        for key, value in reference.policy.state_dict().items():
            assert th.equal(learner.policy.state_dict()[key], value), key


# ---------------------------------------------------------------------------------------------- mistakes
# (case id, population lines or None to keep TINY's, extra flags, words the error line must contain)
ERROR_CASES = [
    ("k-1", "    k: 1\n", [], ["population", "k must be an int >= 2, got 1"]),
    ("unknown-setting", "    k: 2\n    size: 4\n", [], ["population: unknown key 'size'", "allowed keys"]),
    ("n-envs-inside", "    k: 2\n    n_envs: 2\n", [], ["population: unknown key 'n_envs'"]),
    ("crossover", "    k: 2\n    crossover: average\n", [], ["population", "crossover must be one of"]),
    ("type", "    k: two\n", [], ["population: k must be an int", "'two'"]),
    ("window", "    k: 2\n    fitness_episodes: 200\n", [], ["fitness_episodes (200) exceeds", "stats_window_size"]),
    ("ladder", None, ["--ladder", "MultiRobotNav-2-v0:60", f"{ENV_ID}:40"], ["population and ladder do not combine"]),
    ("eps", None, ["--algo", "eps_gdq", "--hyperparams", "callback:sb3_eps.EvolutionCallback"],
     ["population and callback sb3_eps.EvolutionCallback do not combine", "--algo gdq"]),
    ("init-from", None, ["--init-from", "POPULATION_YML"], ["population: --init-from", "drop --init-from"]),
    ("tuning", None, ["-optimize"], ["-optimize tunes one model", "population"]),
]  # fmt: skip


@pytest.mark.parametrize(("case", "lines", "flags", "words"), ERROR_CASES, ids=[case[0] for case in ERROR_CASES])
def test_bad_population_settings_give_one_line_and_no_run_folder(case, lines, flags, words, tmp_path, capsys) -> None:
    arguments = argv(tmp_path, tmp_path / "logs")
    conf = tmp_path / "population.yml"
    if lines is not None:
        conf.write_text(TINY.split("  population:\n")[0] + "  population:\n" + lines)
    if "--algo" in flags:  # the flags' algorithm replaces gdq
        arguments = arguments[2:]
    flags = [str(conf) if flag == "POPULATION_YML" else flag for flag in flags]
    with pytest.raises(SystemExit) as exit_info:
        run_command(train.PROG, lambda: train.main([*arguments, *flags]))
    errors = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(errors) == 1, errors
    assert all(word in errors[0] for word in words), errors[0]
    assert not (tmp_path / "logs").exists() or not list((tmp_path / "logs").rglob("*.*"))


def test_the_key_belongs_to_its_plug_in(monkeypatch, tmp_path, capsys) -> None:
    """Without ``research.population`` imported the key is unknown, and the line says how a plug-in's key is named;
    the zoo's trainer registry refuses keys of its own and keys taken by another trainer."""
    from sb3_eps.zoo import register_trainer
    from sb3_eps.zoo.schema import TRAINERS

    monkeypatch.delitem(TRAINERS, "population")
    arguments = [flag for flag in argv(tmp_path, tmp_path / "logs") if flag not in ("--gym-packages", "research.population")]
    with pytest.raises(SystemExit):
        run_command(train.PROG, lambda: train.main(arguments))
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "unknown key 'population'" in line and "--gym-packages MODULE" in line
    monkeypatch.undo()
    for key, words in (("Population", "lower case"), ("ladder", "a key of every entry"), ("population", "is taken")):
        with pytest.raises(ValueError, match=words):
            register_trainer(key, {}, lambda config, options: None, lambda *args: None)
