"""Hyper-parameter search with Optuna (``python -m sb3_eps.train -optimize``; ``docs/usage.md``, "Tuning"): each
trial trains with sampled hyper-parameters (:func:`sample_hyperparams`), reports every evaluation's
:func:`objective_score` to the pruner, and the best trial is written as a config entry, ``best_params.yml``."""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger

from sb3_eps.common.evaluation import world_of
from sb3_eps.gdq import GDQ
from sb3_eps.zoo.callbacks import EVAL_SEED_OFFSET, TeamEvalCallback, TickBudgetCallback
from sb3_eps.zoo.checkpoint import write_text_atomic
from sb3_eps.zoo.cli import NamespaceOptions, TrainOptions
from sb3_eps.zoo.config import ResolvedConfig, apply_overrides, build_env, check_env_id, entry_yaml, resolve_config
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.exp_manager import build_model, prepare_run
from sb3_eps.zoo.run_folder import ARGS_NAME, CONFIG_NAME, create_run_folder
from sb3_eps.zoo.schema import (
    CALLBACK_KEY,
    EVOLUTION_CALLBACK,
    POLICY_KWARGS_KEY,
    AlgorithmSpec,
    build_callbacks,
    check_complete,
    entry_trainer,
)

BEST_PARAMS_NAME = "best_params.yml"
TRIALS_NAME = "trials.csv"
STUDY_DB_NAME = "study.db"

_NET_ARCHS = {"small": [64, 64], "medium": [128, 64], "large": [256, 128]}
_GLOBAL_NET_ARCHS = {"small": [32, 32], "medium": [64, 64], "large": [128, 128]}


@dataclass
class TuningOptions(NamespaceOptions):
    """The tuning flags of ``python -m sb3_eps.train -optimize``."""

    n_trials: int = 20
    n_jobs: int = 1
    sampler: Literal["tpe", "random"] = "tpe"
    pruner: Literal["median", "halving", "none"] = "median"
    n_startup_trials: int = 5
    n_evaluations: int = 4
    storage: str | None = None
    study_name: str | None = None
    sampler_seed: int | None = None
    n_seeds_per_trial: int = 1
    eps_only: bool = False


# ---------------------------------------------------------------------------------------------- search spaces
def sample_hyperparams(
    trial: Any, spec: AlgorithmSpec, n_timesteps: int, env_id: str | None = None, eps_only: bool = False
) -> dict[str, Any]:
    """Sample the overrides of one trial (canonical entry keys; ``policy_kwargs`` and the EPS arguments as
    partial mappings merged over the base entry by :func:`merge_overrides`).

    The algorithm's search space is the first of :data:`SEARCH_SPACES` that its class (or a base class) has,
    :func:`sample_common` for those without one. The ``eps_*`` algorithms add the EPS arguments (:func:`sample_eps`).

    :param trial: an ``optuna.Trial``
    :param spec: the algorithm
    :param n_timesteps: the trial budget (bounds ``learning_starts``)
    :param env_id: the training env id: EPS may then also search its team world (None: its default world only)
    :param eps_only: sample the EPS arguments alone (``--eps-only``, an ``eps_*`` algorithm's): the base algorithm
        keeps the entry's settings
    """
    space = next((SEARCH_SPACES[cls] for cls in spec.algorithm_class.__mro__ if cls in SEARCH_SPACES), sample_common)
    params = {} if eps_only else space(trial, spec, n_timesteps)
    if spec.eps:
        params[CALLBACK_KEY] = [{EVOLUTION_CALLBACK: sample_eps(trial, env_id)}]
    return params


def sample_eps(trial: Any, env_id: str | None = None) -> dict[str, Any]:
    """The ``EvolutionCallback`` arguments of a trial, around its defaults (``docs/modules/eps.md``; alpha < 0.4,
    which the paper found harmful above); with ``env_id``, also the training team world."""
    arguments: dict[str, Any] = {
        "target_flip_share": trial.suggest_categorical("eps_target_flip_share", [0.02, 0.05, 0.1, 0.2]),
        "alpha": trial.suggest_float("eps_alpha", 0.05, 0.39),
        "alpha_schedule": trial.suggest_categorical("eps_alpha_schedule", ["linear", "constant"]),
        "period": trial.suggest_categorical("eps_period", [5_000, 10_000, 20_000]),
        "period_unit": "ticks",
        "max_eps_share": trial.suggest_categorical("eps_max_eps_share", [0.05, 0.1, 0.2]),
        "population_size": trial.suggest_int("eps_population_size", 2, 10),
        "n_eval_episodes": trial.suggest_categorical("eps_n_eval_episodes", [2, 4, 8]),
        "n_reevaluation_episodes": trial.suggest_categorical("eps_n_reevaluation_episodes", [0, 4, 8]),
        "min_gain": trial.suggest_categorical("eps_min_gain", [0.0, 0.05, 0.1]),
    }
    if env_id is not None and trial.suggest_categorical("eps_world", ["single", "team"]) == "team":
        arguments.update(eval_env_id=env_id)
    return arguments


def sample_common(trial: Any, spec: AlgorithmSpec, n_timesteps: int) -> dict[str, Any]:
    """The search space of algorithms without their own, wide as RL Zoo's DQN space (QMIX's mixer sizes too; a head
    of a plug-in's own keeps its defaults)."""
    params: dict[str, Any] = {
        "learning_rate": trial.suggest_float("learning_rate", 1e-5, 3e-3, log=True),
        "batch_size": trial.suggest_categorical("batch_size", [32, 64, 128, 256]),
        "buffer_size": trial.suggest_categorical("buffer_size", [10_000, 50_000, 100_000, 300_000]),
        "gamma": trial.suggest_categorical("gamma", [0.95, 0.98, 0.99, 0.995]),
        "tau": trial.suggest_categorical("tau", [0.005, 0.01, 0.05]),
        "n_steps": trial.suggest_categorical("n_steps", [1, 3, 5]),
        "train_freq": trial.suggest_categorical("train_freq", [1, 2, 4, 8]),
        "gradient_steps": trial.suggest_categorical("gradient_steps", [1, 2]),
        "exploration_fraction": trial.suggest_float("exploration_fraction", 0.05, 0.5),
        "exploration_final_eps": trial.suggest_float("exploration_final_eps", 0.0, 0.1),
        "prioritized_replay": trial.suggest_categorical("prioritized_replay", [True, False]),
    }
    learning_starts = trial.suggest_categorical("learning_starts", [1_000, 5_000, 20_000])
    params["learning_starts"] = min(learning_starts, max(n_timesteps // 4, 1))
    policy_kwargs: dict[str, Any] = {
        "net_arch": _NET_ARCHS[trial.suggest_categorical("net_arch", list(_NET_ARCHS))],
        "activation_fn": trial.suggest_categorical("activation_fn", ["nn.ReLU", "nn.Tanh", "nn.ELU"]),
    }
    if "mixing_embed_dim" in spec.policy_params:
        policy_kwargs["mixing_embed_dim"] = trial.suggest_categorical("mixing_embed_dim", [16, 32, 64])
        policy_kwargs["hypernet_hidden_dim"] = trial.suggest_categorical("hypernet_hidden_dim", [32, 64, 128])
    params[POLICY_KWARGS_KEY] = policy_kwargs
    return params


def sample_gdq(trial: Any, spec: AlgorithmSpec, n_timesteps: int) -> dict[str, Any]:
    """GDQ's search space: what ``docs/results/gdq_tuning.md`` left open (``global_bootstrap`` near 0.1, short and
    long returns, decaying learning rates); what it settled stays at the package defaults."""
    params: dict[str, Any] = {
        "learning_rate": trial.suggest_categorical("learning_rate", ["lin_1e-4", "lin_3e-4", "lin_6e-4", "lin_1e-3"]),
        "global_bootstrap": trial.suggest_categorical("global_bootstrap", [0.05, 0.1, 0.2]),
        "n_steps": trial.suggest_categorical("n_steps", [3, 5, 10, 30]),
        "batch_size": trial.suggest_categorical("batch_size", [64, 128, 256]),
        "buffer_size": trial.suggest_categorical("buffer_size", [50_000, 100_000, 200_000]),
        "gamma": trial.suggest_categorical("gamma", [0.98, 0.99, 0.995]),
        "tau": trial.suggest_categorical("tau", [0.005, 0.01, 0.02]),
        "exploration_fraction": trial.suggest_categorical("exploration_fraction", [0.02, 0.05, 0.1, 0.2]),
        "exploration_final_eps": trial.suggest_categorical("exploration_final_eps", [0.01, 0.02, 0.05]),
        "prioritized_replay": trial.suggest_categorical("prioritized_replay", [True, False]),
    }
    learning_starts = trial.suggest_categorical("learning_starts", [1_000, 2_000, 5_000])
    params["learning_starts"] = min(learning_starts, max(n_timesteps // 4, 1))
    params[POLICY_KWARGS_KEY] = {
        "net_arch": _NET_ARCHS[trial.suggest_categorical("net_arch", list(_NET_ARCHS))],
        "global_net_arch": _GLOBAL_NET_ARCHS[trial.suggest_categorical("global_net_arch", ["small", "medium"])],
    }
    return params


#: Search spaces by algorithm class (a subclass uses its closest base's); plug-ins add theirs, as RL Zoo's
#: ``HYPERPARAMS_SAMPLER``. Each returns the overrides of one trial: ``(trial, spec, n_timesteps) -> dict``.
SEARCH_SPACES: dict[type, Callable[[Any, AlgorithmSpec, int], dict[str, Any]]] = {GDQ: sample_gdq}


def merge_overrides(base: dict[str, Any], overrides: dict[str, Any], spec: AlgorithmSpec) -> dict[str, Any]:
    """The base entry updated with a trial's overrides (``policy_kwargs`` and the callback's arguments merged per key,
    as ``--hyperparams`` does: :func:`~sb3_eps.zoo.config.apply_overrides`).

    :return: the canonical entry
    :raises ConfigError: when the result is not a valid entry
    """
    pairs: list[tuple[tuple[str, ...], Any]] = []
    for key, value in overrides.items():
        if key == POLICY_KWARGS_KEY:
            pairs += [((key, name), item) for name, item in value.items()]
        elif key == CALLBACK_KEY:  # sample_hyperparams's [{EvolutionCallback: arguments}]
            pairs += [((key, name), item) for name, item in value[0][EVOLUTION_CALLBACK].items()]
        else:
            pairs.append(((key,), value))
    return apply_overrides(base, pairs, spec, "sampled hyper-parameters")


def objective_score(summary: dict[str, Any], n_eval_episodes: int) -> float:
    """The trial score: team success rate, team return as tie-break.

    ``score = success_rate + tie / (4 n)`` with ``tie = R / (1 + |R|)`` in (-1, 1) for the mean team return ``R``
    and ``n`` evaluation episodes: success rates differ by at least ``1/n``, so the return only orders trials of
    equal success. Worlds without a success flag are scored by their team return alone.

    :param summary: an evaluation summary (:func:`~sb3_eps.evaluate_team`)
    :param n_eval_episodes: episodes per evaluation
    """
    team_return = float(summary["team_return_mean"])
    if "success_rate" not in summary:
        return team_return
    tie = team_return / (1.0 + abs(team_return))
    return float(summary["success_rate"]) + tie / (4.0 * max(n_eval_episodes, 1))


# ---------------------------------------------------------------------------------------------- study
def _import_optuna() -> Any:
    try:
        import optuna
    except ImportError:
        raise ConfigError("-optimize needs Optuna: pip install 'sb3-eps[tune]'") from None
    return optuna


def make_sampler(name: str, n_startup_trials: int, seed: int | None) -> Any:
    """:return: the Optuna sampler ``tpe`` or ``random``."""
    samplers = _import_optuna().samplers
    if name == "random":
        return samplers.RandomSampler(seed=seed)
    return samplers.TPESampler(n_startup_trials=n_startup_trials, seed=seed, multivariate=True)


def make_pruner(name: str, n_startup_trials: int, n_evaluations: int) -> Any:
    """:return: the Optuna pruner ``median``, ``halving`` or ``none``."""
    pruners = _import_optuna().pruners
    return {
        "median": lambda: pruners.MedianPruner(n_startup_trials=n_startup_trials, n_warmup_steps=n_evaluations // 3),
        "halving": lambda: pruners.SuccessiveHalvingPruner(min_resource=1, reduction_factor=4),
        "none": pruners.NopPruner,
    }[name]()


def make_storage(url: str | None, folder: Path) -> Any:
    """The study's storage: ``url`` (``sqlite:///file.db``, ``postgresql://...``, or a plain ``*.db`` path),
    by default a SQLite file in the tuning folder, whose connections wait up to a minute for a lock."""
    optuna = _import_optuna()
    if url is None:
        url = f"sqlite:///{(folder / STUDY_DB_NAME).resolve()}"
    elif "://" not in url:
        url = f"sqlite:///{Path(url).resolve()}"
    engine_kwargs = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else {}
    attempts = 5
    for attempt in range(attempts):
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=engine_kwargs)
        except Exception as error:  # SQLAlchemy raises many kinds for a bad URL
            # Processes that create a new database at the same moment race on its schema: the loser retries.
            if attempt == attempts - 1:
                raise ConfigError(f"--storage: cannot open {url}: {error}") from None
            time.sleep(0.5 * (attempt + 1))
    raise AssertionError("unreachable")


class _Objective:
    """Trains and evaluates one trial (see the module docstring)."""

    def __init__(self, options: TrainOptions, tuning: TuningOptions, config: ResolvedConfig) -> None:
        self.options = options
        self.tuning = tuning
        self.config = config

    def __call__(self, trial: Any) -> float:
        spec = self.config.spec
        n_timesteps = int(self.config.entry["n_timesteps"])
        overrides = sample_hyperparams(trial, spec, n_timesteps, self.config.env_id, self.tuning.eps_only)
        entry = merge_overrides(self.config.entry, overrides, spec)
        trial.set_user_attr("hyperparams", overrides)
        if self.tuning.n_jobs > 1:
            # Trials run as threads: EPS evaluates in-process rather than forking workers from a threaded process.
            for item in entry.get(CALLBACK_KEY, []):
                for name, kwargs in item.items():
                    if name == EVOLUTION_CALLBACK and kwargs.get("n_workers") is None:
                        kwargs["n_workers"] = 0
        config = ResolvedConfig(self.config.algo, self.config.env_id, entry, f"trial {trial.number}")
        summaries = [
            self._run_seed(trial, config, int(self.options.seed) + index, index * self.tuning.n_evaluations)  # type: ignore[arg-type]
            for index in range(self.tuning.n_seeds_per_trial)
        ]
        scores = [objective_score(summary, self.options.eval_episodes) for summary in summaries]
        # What each seed spent and, with EPS, how often it acted.
        for key in PER_SEED_COLUMNS:
            if all(key in summary for summary in summaries):
                trial.set_user_attr(key, [int(summary[key]) for summary in summaries])
        for key in ("success_rate", "collision_rate", "team_return_mean", "length_mean"):
            if all(key in summary for summary in summaries):
                trial.set_user_attr(key, float(sum(float(summary[key]) for summary in summaries) / len(summaries)))
        if len(scores) > 1:
            trial.set_user_attr("seed_scores", scores)
        trial.set_user_attr("world", world_of(summaries[0]))  # what the scores were measured on
        return float(sum(scores) / len(scores))

    def _run_seed(self, trial: Any, config: ResolvedConfig, seed: int, first_step: int) -> dict[str, Any]:
        """Train one seed of the trial, reporting every evaluation (steps after ``first_step``) for pruning.

        :return: the final evaluation's summary
        :raises optuna.TrialPruned: when the pruner stops the trial
        """
        optuna = _import_optuna()
        n_timesteps = int(config.entry["n_timesteps"])
        env = build_env(config, seed)
        eval_env = build_env(config, seed + EVAL_SEED_OFFSET, self.options.eval_env, self.options.n_eval_envs)
        pruned = False

        def report(summary: dict[str, Any]) -> bool:
            nonlocal pruned
            step = first_step + len(evaluation.records["timesteps"])
            trial.report(objective_score(summary, self.options.eval_episodes), step)
            pruned = trial.should_prune()
            return not pruned

        try:
            model = build_model(config, env, seed, self.options.device, verbose=0)
            model.set_logger(Logger(folder=None, output_formats=[]))
            user_callbacks = [callback for _, callback in build_callbacks(config.entry, config.env_id, 0, config.source)]
            # EPS pays its ticks from the trial's budget: a setting is scored at the ticks it used.
            eps_callbacks = [callback for callback in user_callbacks if hasattr(callback, "eps_ticks")]
            evaluation = TeamEvalCallback(
                eval_env, max(n_timesteps // self.tuning.n_evaluations, 1), self.options.eval_episodes,
                seed + EVAL_SEED_OFFSET, eps_callbacks=eps_callbacks, on_evaluation=report,
                count_eps_ticks=bool(eps_callbacks),
            )  # fmt: skip
            callbacks: list[BaseCallback] = [evaluation, *user_callbacks]
            if eps_callbacks:
                callbacks.append(TickBudgetCallback(n_timesteps, eps_callbacks))
            model.learn(n_timesteps, callback=CallbackList(callbacks))
            if pruned:
                raise optuna.TrialPruned()
            summary = evaluation.last_summary
            if summary is None or summary["timesteps"] != model.num_timesteps:
                summary = evaluation.evaluate()
            if eps_callbacks:
                summary = {
                    **summary,
                    "eps_rounds": sum(int(getattr(callback, "n_rounds", 0)) for callback in eps_callbacks),
                    "eps_crossovers": sum(int(getattr(callback, "n_crossovers", 0)) for callback in eps_callbacks),
                }
        finally:
            env.close()
            eval_env.close()
        return summary


def tune(options: TrainOptions, tuning: TuningOptions) -> Path:
    """Run (or join) a study and write ``best_params.yml`` (``-optimize``).

    :return: the tuning folder ``<folder>/<algo>/<env id>_<n>``
    :raises ConfigError: for any mistake, before anything is written
    """
    optuna = _import_optuna()
    tuning.check_fields()
    options.check()
    check_env_id(options.env)
    hyperparams = [*options.hyperparams, *(f"env_kwargs.{item}" for item in options.env_kwargs)]
    config = resolve_config(options.algo, options.env, options.conf_file, hyperparams, options.n_timesteps)
    if "ladder" in config.entry:
        raise ConfigError(f"-optimize tunes on one world; {config.source} has a ladder: tune its last rung's world")
    trainer = entry_trainer(config.entry)
    if trainer is not None:
        raise ConfigError(f"-optimize tunes one model; {config.source} has a {trainer.key}: tune without it, then add it")
    if tuning.eps_only and not config.spec.eps:
        raise ConfigError(f"--eps-only searches the EPS arguments: {options.algo} has none; use eps_{options.algo}")
    if options.eval_freq <= 0:
        options.eval_freq = 1  # evaluation is the objective: it cannot be turned off here
    prepare_run(options, config).close()  # builds everything once: mistakes surface before any file exists
    # Processes joining one study need their own sampler seeds, or their random startup trials coincide.
    sampler_seed = options.seed if tuning.sampler_seed is None else tuning.sampler_seed
    sampler = make_sampler(tuning.sampler, tuning.n_startup_trials, sampler_seed)
    pruner = make_pruner(tuning.pruner, tuning.n_startup_trials, tuning.n_evaluations)
    # A given storage is opened before the folder exists, so a bad URL leaves nothing behind.
    storage = make_storage(tuning.storage, Path(options.folder)) if tuning.storage is not None else None
    folder = create_run_folder(options.folder, options.algo, config.env_id)
    study_name = tuning.study_name or f"{options.algo}-{config.env_id}"
    record = {**vars(options), "tuning": vars(tuning), "study_name": study_name, "run_dir": str(folder)}
    write_text_atomic(folder / ARGS_NAME, yaml.safe_dump(record, sort_keys=False))
    write_text_atomic(folder / CONFIG_NAME, entry_yaml(config.env_id, config.entry, f"base of the study {study_name}"))
    if storage is None:
        storage = make_storage(None, folder)
    optuna.logging.set_verbosity(optuna.logging.INFO if options.verbose >= 1 else optuna.logging.WARNING)
    study = optuna.create_study(
        study_name=study_name, storage=storage, sampler=sampler, pruner=pruner, direction="maximize",
        load_if_exists=True,
    )  # fmt: skip
    start = time.time()
    study.optimize(
        _Objective(options, tuning, config),
        n_trials=tuning.n_trials,
        n_jobs=tuning.n_jobs,
        gc_after_trial=True,
    )
    write_results(study, config, folder, time.time() - start, options, tuning.n_seeds_per_trial)
    return folder


#: ``trials.csv`` columns with one value per seed of a trial (``/``-joined): ticks spent, and EPS's rounds.
PER_SEED_COLUMNS = ("ticks", "eps_ticks", "eps_rounds", "eps_crossovers")


def write_trials_csv(study: Any, path: Path) -> None:
    """One row per trial: number, state, value, duration, :data:`PER_SEED_COLUMNS` (``/``-joined) and every sampled
    parameter (``params_<name>``)."""
    names = sorted({name for trial in study.trials for name in trial.params})
    rows = [
        [trial.number, trial.state.name, trial.value, trial.duration.total_seconds() if trial.duration is not None else None,
         *("/".join(map(str, trial.user_attrs.get(key, []))) for key in PER_SEED_COLUMNS),
         *(trial.params.get(name) for name in names)]
        for trial in study.trials
    ]  # fmt: skip
    text = io.StringIO()
    csv.writer(text).writerows([["number", "state", "value", "duration_s", *PER_SEED_COLUMNS,
                                 *(f"params_{name}" for name in names)], *rows])  # fmt: skip
    write_text_atomic(path, text.getvalue())


def write_results(
    study: Any, config: ResolvedConfig, folder: Path, seconds: float, options: TrainOptions, n_seeds: int = 1
) -> None:
    """Write ``trials.csv`` and ``best_params.yml`` (the best trial as a config entry) and print a summary."""
    optuna = _import_optuna()
    write_trials_csv(study, folder / TRIALS_NAME)
    complete = [trial for trial in study.trials if trial.state == optuna.trial.TrialState.COMPLETE]
    n_pruned = sum(trial.state == optuna.trial.TrialState.PRUNED for trial in study.trials)
    print(
        f"Study {study.study_name}: {len(study.trials)} trials ({len(complete)} complete, {n_pruned} pruned) in {seconds / 60:.1f} min"
    )
    if not complete:
        print("No trial completed: no best parameters to write")
        return
    best = study.best_trial
    entry = merge_overrides(config.entry, best.user_attrs["hyperparams"], config.spec)
    success = best.user_attrs.get("success_rate")
    first, last = int(options.seed), int(options.seed) + n_seeds - 1  # type: ignore[arg-type]
    entry = {
        "tuned": True,
        "notes": (
            f"optuna study {study.study_name}, trial {best.number}: score {best.value:.4f}"
            + (f" (success {100 * success:.0f} %)" if success is not None else "")
            + f", {entry['n_timesteps']} timesteps, "
            + (f"seed {first}" if n_seeds == 1 else f"seeds {first}-{last}")
            + f", {time.strftime('%Y-%m-%d')}"
        ),
        **{key: value for key, value in entry.items() if key not in ("tuned", "notes")},
    }
    check_complete(entry, config.spec, "best parameters")
    header = (
        f"Best trial of the Optuna study {study.study_name} ({folder}).\n"
        f"Use it with: python -m sb3_eps.train --algo {config.algo} --env {config.env_id} -conf {folder / BEST_PARAMS_NAME}\n"
        f"or paste the entry into zoo_configs/{config.algo}.yml."
    )
    write_text_atomic(folder / BEST_PARAMS_NAME, entry_yaml(config.env_id, entry, header))
    print(f"Best trial {best.number}: score {best.value:.4f}; parameters in {folder / BEST_PARAMS_NAME}")
    if math.isnan(best.value):
        print("warning: the best score is NaN")
