"""Optuna tuning: search spaces of every algorithm, a 3-trial 2-job study in SQLite, the best-parameters entry."""

from __future__ import annotations

import csv
import dataclasses

import optuna
import pytest

from sb3_eps import GDQ, train
from sb3_eps.zoo.config import load_config_entries, resolve_config
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.schema import ALGORITHMS, EVOLUTION_CALLBACK, build_callbacks
from sb3_eps.zoo.tuning import SEARCH_SPACES, merge_overrides, objective_score, sample_hyperparams

ENV_ID = "CooperativeNavigation-v0"


@pytest.mark.parametrize("algo", list(ALGORITHMS))
def test_search_space_gives_valid_entries(algo) -> None:
    spec = ALGORITHMS[algo]
    base = resolve_config(algo, ENV_ID).entry
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(25):
        trial = study.ask()
        entry = merge_overrides(base, sample_hyperparams(trial, spec, 2_000), spec)
        assert entry["learning_starts"] <= 500
        if spec.eps:
            (item,) = entry["callback"]
            arguments = item[EVOLUTION_CALLBACK]
            assert 0 < arguments["alpha"] < 0.4  # the paper: alpha >= 0.4 hurt
            assert {"sigma", "period", "population_size", "n_eval_episodes"} <= set(arguments)
            assert arguments["mutation"] == "safe"  # unsampled arguments keep the base entry's
        study.tell(trial, 0.0)


def test_objective_orders_by_success_then_return() -> None:
    n = 10
    better_success = objective_score({"success_rate": 0.2, "team_return_mean": -1e9}, n)
    worse_success = objective_score({"success_rate": 0.1, "team_return_mean": 1e9}, n)
    assert better_success > worse_success
    assert objective_score({"success_rate": 0.1, "team_return_mean": 5.0}, n) > objective_score(
        {"success_rate": 0.1, "team_return_mean": 4.0}, n
    )


def test_three_trials_two_jobs_write_a_sqlite_study_and_best_params(tmp_path, capsys) -> None:
    argv = ["--algo", "gdq", "--env", ENV_ID, "-n", "450", "--seed", "0", "-f", str(tmp_path), "--verbose", "0",
            "--eval-episodes", "2", "--n-eval-envs", "1", "-optimize", "--n-trials", "3", "--n-jobs", "2",
            "--sampler", "tpe", "--pruner", "median", "--n-evaluations", "2", "--hyperparams", "n_envs:1"]  # fmt: skip
    assert train.main(argv) == 0
    (folder,) = (tmp_path / "gdq").iterdir()
    database = folder / "study.db"
    assert database.is_file() and (folder / "trials.csv").is_file()
    study = optuna.load_study(study_name=f"gdq-{ENV_ID}", storage=f"sqlite:///{database}")
    assert len(study.trials) == 3
    finished = [t for t in study.trials if t.state in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)]
    assert len(finished) == 3
    assert all(len(t.intermediate_values) >= 1 for t in finished)  # reported for pruning
    # The best parameters are a ready-to-use entry: -conf reads it.
    best = load_config_entries(folder / "best_params.yml", "gdq")[ENV_ID]
    assert best["tuned"] is True and "optuna study" in best["notes"]
    assert best["learning_rate"] == study.best_trial.params["learning_rate"]
    assert "best_params.yml" in capsys.readouterr().out

    # Another process (here: another call) given the same storage and study name joins the study.
    join = argv[:]
    join[join.index("--n-trials") + 1] = "1"
    join[join.index("--n-jobs") + 1] = "1"
    join += ["--storage", f"sqlite:///{database}", "--study-name", f"gdq-{ENV_ID}"]
    assert train.main(join) == 0
    assert len(optuna.load_study(study_name=f"gdq-{ENV_ID}", storage=f"sqlite:///{database}").trials) == 4


@pytest.mark.parametrize("algo", ["gdq", "eps_gdq"])
def test_gdq_searches_its_own_space_around_the_measured_settings(algo) -> None:
    # GDQ's space stays near the measured GDQ-lambda 0.1 (the paper's global_bootstrap=1 cost 28 points on 4 robots,
    # docs/results/gdq_target.md), spans 3- and 30-step returns, decays the learning rate, and leaves the settled
    # choices (team reward, agent target) to the base entry.
    spec = ALGORITHMS[algo]
    base = resolve_config(algo, ENV_ID).entry
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=1))
    seen_bootstrap = set()
    for _ in range(25):
        trial = study.ask()
        entry = merge_overrides(base, sample_hyperparams(trial, spec, 600_000), spec)
        assert entry["n_steps"] in (3, 5, 10, 30) and str(entry["learning_rate"]).startswith("lin_")
        assert 0.0 < entry["global_bootstrap"] <= 0.2
        seen_bootstrap.add(entry["global_bootstrap"])
        assert entry["team_reward_mode"] == base["team_reward_mode"] == "mean"
        assert entry["policy_kwargs"]["agent_target"] is True and "agent_target" not in trial.params
        study.tell(trial, 0.0)
    assert len(seen_bootstrap) > 1
    # Other algorithms keep the wide space.
    trial = optuna.create_study().ask()
    assert sample_hyperparams(trial, ALGORITHMS["iql"], 600_000)["n_steps"] in (1, 3, 5)


def test_a_subclass_uses_its_closest_base_space(monkeypatch) -> None:
    class MyGDQ(GDQ):
        pass

    spec = dataclasses.replace(ALGORITHMS["gdq"], name="my_gdq", algorithm_class=MyGDQ)
    trial = optuna.create_study().ask()
    assert "global_bootstrap" in sample_hyperparams(trial, spec, 600_000)  # GDQ's own space, not the wide one
    monkeypatch.setitem(SEARCH_SPACES, MyGDQ, lambda trial, spec, n: {"n_steps": 7})
    assert sample_hyperparams(optuna.create_study().ask(), spec, 600_000) == {"n_steps": 7}


def test_eps_searches_its_rounds_and_world_and_the_entries_build() -> None:
    spec = ALGORITHMS["eps_gdq"]
    env_id = "MultiRobotNav-2-v0"
    base = resolve_config("eps_gdq", env_id).entry
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=2))
    worlds = set()
    for _ in range(20):
        trial = study.ask()
        entry = merge_overrides(base, sample_hyperparams(trial, spec, 400_000, env_id), spec)
        (item,) = entry["callback"]
        arguments = item[EVOLUTION_CALLBACK]
        assert arguments["period_unit"] == "ticks" and arguments["period"] >= 5_000  # not the paper's episodes
        assert arguments["fitness"] == base["callback"][0][EVOLUTION_CALLBACK]["fitness"]  # from the base entry
        team = arguments.get("eval_env_id") == env_id
        worlds.add(team)
        ((_, callback),) = build_callbacks(entry, env_id, 0, "a trial")
        assert (callback.settings.eval_env_id == env_id) is team
        assert callback.settings.max_eps_share == arguments["max_eps_share"]
        study.tell(trial, 0.0)
    assert worlds == {False, True}


def test_a_trial_can_train_several_seeds_and_scores_their_mean(tmp_path) -> None:
    # One seed per trial ranks noise on the robot worlds (docs/results/gdq_tuning.md, the 4-robot study): each trial
    # here trains seeds 5 and 6, reports 2 evaluations of each (4 pruning steps) and scores the mean of the seeds.
    argv = ["--algo", "gdq", "--env", ENV_ID, "-n", "300", "--seed", "5", "-f", str(tmp_path), "--verbose", "0",
            "--eval-episodes", "2", "--n-eval-envs", "1", "-optimize", "--n-trials", "2", "--pruner", "none",
            "--n-evaluations", "2", "--n-seeds-per-trial", "2", "--hyperparams", "n_envs:1"]  # fmt: skip
    assert train.main(argv) == 0
    (folder,) = (tmp_path / "gdq").iterdir()
    study = optuna.load_study(study_name=f"gdq-{ENV_ID}", storage=f"sqlite:///{folder / 'study.db'}")
    for trial in study.trials:
        assert sorted(trial.intermediate_values) == [1, 2, 3, 4]
        first, second = trial.user_attrs["seed_scores"]
        assert trial.value == pytest.approx((first + second) / 2)
        assert trial.intermediate_values[2] == pytest.approx(first) and trial.intermediate_values[4] == pytest.approx(second)
        assert trial.user_attrs["world"] == {"env_id": ENV_ID, "env_kwargs": {}, "level_set": None, "n_episodes": 2}
    assert "seeds 5-6" in load_config_entries(folder / "best_params.yml", "gdq")[ENV_ID]["notes"]
    with pytest.raises(ConfigError, match="--n-seeds-per-trial must be an int >= 1, got 0"):
        train.main([*argv, "--n-seeds-per-trial", "0"])


def test_an_eps_trial_pays_its_eps_ticks_from_the_budget(tmp_path, monkeypatch) -> None:
    # Issue 10: EPS settings are searched with their EPS ticks counted in the budget, or the search would favour
    # the settings that spend most. Rounds every 6 world episodes here (the space's 5-20k ticks exceed the budget).
    from sb3_eps.zoo import tuning

    rounds = {"period": 6, "period_unit": "episodes", "max_eps_share": 1.0, "population_size": 2,
              "n_eval_episodes": 1, "n_reevaluation_episodes": 1, "n_workers": 0, "sensitivity_batch_size": 16}  # fmt: skip
    monkeypatch.setattr(tuning, "sample_eps", lambda trial, env_id=None: dict(rounds))
    budget = 3_000  # timesteps: 1,000 ticks of the 3-agent world
    argv = ["--algo", "eps_gdq", "--env", ENV_ID, "-n", str(budget), "--seed", "5", "-f", str(tmp_path),
            "--verbose", "0", "--eval-episodes", "2", "--n-eval-envs", "1", "-optimize", "--n-trials", "1",
            "--pruner", "none", "--n-evaluations", "3", "--hyperparams", "n_envs:1", "learning_starts:300"]  # fmt: skip
    assert train.main(argv) == 0
    (folder,) = (tmp_path / "eps_gdq").iterdir()
    (trial,) = optuna.load_study(study_name=f"eps_gdq-{ENV_ID}", storage=f"sqlite:///{folder / 'study.db'}").trials
    (ticks,), (eps_ticks,) = trial.user_attrs["ticks"], trial.user_attrs["eps_ticks"]
    assert eps_ticks > 0 and ticks < budget // 3  # the training stopped early by what EPS spent...
    assert budget // 3 <= ticks + eps_ticks < budget // 3 + 200  # ...at the budget (a round is at most 3 x 25 ticks)
    # The evaluations fall every third of the budget of training plus EPS (counted on training alone, the third
    # point would never be reached), the last one at the step that ends the budget.
    assert sorted(trial.intermediate_values) == [1, 2, 3]
    row = next(csv.DictReader((folder / "trials.csv").open()))
    assert (int(row["ticks"]), int(row["eps_ticks"])) == (ticks, eps_ticks)
    # How often EPS acted: its rounds and crossovers (a trial without a crossover is its base algorithm).
    (n_rounds,), (n_crossovers,) = trial.user_attrs["eps_rounds"], trial.user_attrs["eps_crossovers"]
    assert n_rounds >= 1 and 0 <= n_crossovers <= n_rounds
    assert (int(row["eps_rounds"]), int(row["eps_crossovers"])) == (n_rounds, n_crossovers)


def test_eps_only_searches_the_eps_arguments_and_keeps_the_base_settings(tmp_path) -> None:
    # EPS is searched on top of its base algorithm's settings (the package defaults, or a tuned entry).
    spec, env_id = ALGORITHMS["eps_gdq"], "MultiRobotNav-4-v0"
    trial = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0)).ask()
    overrides = sample_hyperparams(trial, spec, 600_000, env_id, eps_only=True)
    assert list(overrides) == ["callback"] and "eps_target_flip_share" in trial.params
    assert not any(name in trial.params for name in ("n_steps", "learning_rate", "gamma"))
    with pytest.raises(ConfigError, match="--eps-only searches the EPS arguments: gdq has none; use eps_gdq"):
        train.main(["--algo", "gdq", "--env", ENV_ID, "-f", str(tmp_path), "-optimize", "--eps-only"])
    assert not any(tmp_path.iterdir())  # nothing written
