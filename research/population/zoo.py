"""The ``population`` key of a config entry: ``k`` learners of the entry's algorithm trained as one run by
:class:`~research.population.trainer.PopulationTrainer`, in the run folder of any run. Importing this module (as
``--gym-packages research.population`` does) registers the key with the zoo (:func:`sb3_eps.zoo.register_trainer`).

An entry's ``population`` holds the trainer's settings (``k``, ``interval``, ``share_buffer``, ``crossover``,
``mutation``, ``fitness``...: :data:`POPULATION_PARAMS`); the entry's other keys configure every
learner (its hyper-parameters are the learners' constructor arguments, ``n_envs`` the worlds of each learner,
``env_kwargs`` their worlds' arguments). ``n_timesteps`` (and ``-n``, ``--eval-freq``, ``--save-freq``) count
agent-steps of all learners together: the run's world ticks are ``n_timesteps / n_agents``, ``total_ticks`` of
:meth:`PopulationTrainer.learn <research.population.trainer.PopulationTrainer.learn>`, each learner getting ``1 / k``.
Learner ``i`` is seeded ``seed + i`` and its worlds ``seed + i * n_envs``, as the trainer seeds them.

The run folder is that of any run (:mod:`sb3_eps.zoo.run_folder`): the monitor holds every learner's training
episodes (its ``ticks`` are all learners' together, its ``learner`` column says whose); the evaluations, the best and
the final model are those of the fittest learner at the time (:attr:`PopulationTrainer.best
<research.population.trainer.PopulationTrainer.best>`), a model of the entry's algorithm; ``population_selections.jsonl``
holds the selection records and ``population.zip`` the whole population at the end (``PopulationTrainer.load``).
Checkpoints are taken between two turns, where every learner can be restored exactly; ``--resume`` continues one
to the result of the uninterrupted run.
"""

from __future__ import annotations

import io
import json
import pickle
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger

from research.population.trainer import PopulationTrainer
from sb3_eps.common.snapshots import snapshot_dumps
from sb3_eps.common.vec_env import MultiAgentVecEnv
from sb3_eps.zoo import run_folder
from sb3_eps.zoo.callbacks import (
    EVAL_SEED_OFFSET,
    TeamEvalCallback,
    TeamMonitor,
    make_logger,
    stop_on_signals,
    write_final_report,
)
from sb3_eps.zoo.checkpoint import (
    CHECKPOINT_NAME,
    remove_checkpoints,
    save_model_atomic,
    write_checkpoint,
    write_text_atomic,
)
from sb3_eps.zoo.cli import TrainOptions, TrainResult
from sb3_eps.zoo.config import PreparedRun, ResolvedConfig, build_env, close_envs
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.ladder import LADDER_KEY
from sb3_eps.zoo.schema import CALLBACK_KEY, algorithm_kwargs, params_from_signature, register_trainer

POPULATION_KEY = "population"
#: The ``PopulationTrainer`` settings an entry's ``population`` may set, read from its signature; the run sets the
#: others (the algorithm, worlds and ``n_envs`` from the entry, seed, records file, verbosity).
POPULATION_PARAMS: dict[str, Any] = params_from_signature(
    PopulationTrainer.__init__,
    ("algorithm_class", "env", "n_envs", "env_kwargs", "log_path", "seed", "verbose"),
    every=True,
)
#: The selection records of a population run (one JSON line per selection, ``PopulationTrainer.history``).
SELECTIONS_NAME = "population_selections.jsonl"
#: The whole population at the end of a run (``PopulationTrainer.load``).
POPULATION_NAME = "population.zip"


def population_kwargs(config: ResolvedConfig, device: str = "auto") -> dict[str, Any]:
    """:return: the :class:`~research.population.trainer.PopulationTrainer` keyword arguments of a config entry (its
    ``population`` settings, ``n_envs``, ``env_kwargs`` and the learners' constructor arguments), without the env,
    seed, records file and verbosity that the run gives."""
    entry = config.entry
    return {
        **entry[POPULATION_KEY],
        "n_envs": entry.get("n_envs", 1),
        "env_kwargs": dict(entry["env_kwargs"]) if entry.get("env_kwargs") else None,
        "device": device,
        **algorithm_kwargs(entry, config.spec),
    }


def check_population_run(config: ResolvedConfig, options: TrainOptions) -> None:
    """The checks of a population run, before anything is written: the trainer accepts its settings, and nothing
    that belongs to one model (a ladder, callbacks, ``--init-from``, ``--progress``) comes with it.

    :raises ConfigError: in one line, naming the key and what to change
    """
    where = f"{config.source}: population"
    names = [next(iter(item)) for item in config.entry.get(CALLBACK_KEY, [])]
    if names:
        base = f" --algo {options.algo[4:]}" if config.spec.eps else ""
        raise ConfigError(
            f"{where} and callback {', '.join(names)} do not combine: the population's selection replaces EPS's rounds "
            f"and the callbacks drive one model; train the population with{base} and no callback"
        )
    if LADDER_KEY in config.entry:
        raise ConfigError(f"{where} and ladder do not combine: a population trains on one world; remove one of the keys")
    for flag, given in (("--init-from", options.init_from is not None), ("--progress", options.progress)):
        if given:
            raise ConfigError(f"{where}: {flag} works on one model, not a population of learners; drop {flag}")
    try:
        PopulationTrainer(config.spec.algorithm_class, None, **population_kwargs(config, options.device))
    except (TypeError, ValueError) as error:
        raise ConfigError(f"{where}: {error}") from None


def build_population(
    config: ResolvedConfig,
    options: TrainOptions,
    first_env: MultiAgentVecEnv,
    build_env: Callable[[int], MultiAgentVecEnv],
    log_path: Path,
) -> PopulationTrainer:
    """:return: the population of a checked config: learner 0 on ``first_env`` (the run's training worlds, seeded
    ``seed``), learner ``i`` on ``build_env(seed + i * n_envs)``."""
    n_envs = config.entry.get("n_envs", 1)

    def worlds(index: int) -> MultiAgentVecEnv:
        return first_env if index == 0 else build_env(int(options.seed) + index * n_envs)  # type: ignore[arg-type]

    kwargs = population_kwargs(config, options.device)
    return PopulationTrainer(
        config.spec.algorithm_class,
        worlds,
        log_path=str(log_path),
        seed=options.seed,
        verbose=options.verbose,
        **kwargs,
    )


class PopulationModel:
    """The population as the run's monitor and evaluations see a model: timesteps and ticks count all learners
    together; ``acting`` (the fittest learner when the last turn ended) predicts and is saved.

    :param trainer: the population
    :param logger: the run's logger (``progress.csv``)
    """

    def __init__(self, trainer: PopulationTrainer, logger: Logger) -> None:
        self.trainer = trainer
        self.logger = logger
        self.acting = trainer.best

    @property
    def num_timesteps(self) -> int:
        """Agent-steps of all learners together."""
        return sum(int(learner.num_timesteps) for learner in self.trainer.learners)

    @property
    def ticks(self) -> int:
        """World ticks of all learners together."""
        return self.trainer.ticks

    @property
    def n_agents(self) -> int:
        """Agents per world."""
        return int(self.trainer.learners[0].n_agents)

    @property
    def ticks_per_step(self) -> int:
        """World ticks per step of the learners' worlds (their ``action_repeat``)."""
        return int(self.trainer.learners[0].ticks_per_step)

    def get_env(self) -> None:
        """A population has no single training env."""
        return None

    def predict(self, *args: Any, **kwargs: Any) -> Any:
        """The acting learner's ``predict``."""
        return self.acting.predict(*args, **kwargs)

    def save(self, path: Any) -> None:
        """Save the acting learner (a model of the run's algorithm)."""
        self.acting.save(path)


class _LearnerEpisodes(BaseCallback):
    """Passes each step of a learner's turn to the run's :class:`~sb3_eps.zoo.callbacks.TeamMonitor`, the episodes
    marked with the learner's index (a copy: the learner's own episode records stay as they are)."""

    def __init__(self, monitor: TeamMonitor, trainer: PopulationTrainer) -> None:
        super().__init__()
        self.monitor = monitor
        self.trainer = trainer

    def _on_step(self) -> bool:
        learner = self.trainer.next_learner
        infos = [
            {**info, "episode": {**info["episode"], "learner": learner}} if "episode" in info else info
            for info in self.locals["infos"]
        ]
        self.monitor.update_locals({"infos": infos})
        return self.monitor.on_step()


@dataclass
class _StopRequest:
    """What :func:`~sb3_eps.zoo.callbacks.stop_on_signals` sets: the name of the signal received."""

    stop_requested: str | None = None


def save_population_checkpoint(
    path: Path, trainer: PopulationTrainer, callback_states: dict[str, Any], meta: dict[str, Any]
) -> None:
    """Write a population checkpoint atomically, the previous one kept as ``checkpoint.prev.zip``: the trainer's
    archive with its training state (:meth:`PopulationTrainer.save`), plus the members every checkpoint of a run
    has (:func:`~sb3_eps.zoo.checkpoint.verify_checkpoint`): ``model.zip`` (the fittest learner), ``callbacks.pkl``,
    ``meta.json``."""
    fittest = io.BytesIO()
    trainer.best.save(fittest)
    members = {"model.zip": fittest.getvalue(), "callbacks.pkl": snapshot_dumps(callback_states)}
    members["meta.json"] = json.dumps(meta, indent=2).encode()
    write_checkpoint(path, members, lambda temporary: trainer.save(temporary, include_training_state=True))


def run_population(
    prepared: PreparedRun,
    run_dir: Path,
    checkpoint_path: Path | None = None,
    extra_callbacks: Sequence[BaseCallback] = (),
) -> TrainResult:
    """Train the population of a prepared run in its folder (``checkpoint_path``: continue that checkpoint); write
    the final model (the fittest learner), the population and the report.

    :param prepared: the run, built and checked (its ``model``, one learner, is not used)
    :param run_dir: the run folder
    :param checkpoint_path: a population checkpoint of this run to continue, or None
    :param extra_callbacks: more SB3 callbacks, run in every learner's turns
    """
    options, config = prepared.options, prepared.config
    total = int(config.entry["n_timesteps"])
    log_path = run_dir / SELECTIONS_NAME
    meta: dict[str, Any] = {}
    callback_states: dict[str, Any] = {}
    if checkpoint_path is None:
        trainer = build_population(
            config, options, prepared.env, lambda seed: build_env(config, seed, vec_env=options.vec_env), log_path
        )
    else:
        with zipfile.ZipFile(checkpoint_path) as archive:
            meta = json.loads(archive.read("meta.json"))
            callback_states = pickle.loads(archive.read("callbacks.pkl"))  # our own checkpoint
        close_envs([prepared.env])  # the learners' worlds come back from the checkpoint, mid-episode
        trainer = PopulationTrainer.load(checkpoint_path, device=options.device)  # restores the random states last
        trainer.settings.update(log_path=str(log_path), verbose=options.verbose)
        # the records of selections made after the checkpoint by a process that died are dropped
        write_text_atomic(log_path, "".join(json.dumps(record) + "\n" for record in trainer.history))
        TeamMonitor.truncate_after(run_dir / run_folder.MONITOR_NAME, int(meta["ticks"]))
    prepared.env = trainer.learners[0].env  # type: ignore[assignment]
    try:
        return _train(prepared, run_dir, trainer, total, meta, callback_states, extra_callbacks)
    finally:
        close_envs([learner.env for learner in trainer.learners[1:]])


def _train(
    prepared: PreparedRun,
    run_dir: Path,
    trainer: PopulationTrainer,
    total: int,
    meta: dict[str, Any],
    callback_states: dict[str, Any],
    extra_callbacks: Sequence[BaseCallback],
) -> TrainResult:
    """The training of :func:`run_population`, from a new or a restored trainer (``meta`` and ``callback_states``
    of its checkpoint, empty for a new run)."""
    options, config = prepared.options, prepared.config
    resume_timesteps = int(meta["num_timesteps"]) if meta else None
    model = PopulationModel(trainer, make_logger(options, run_dir, resume_timesteps))
    header = {
        "env_id": config.env_id,
        "algo": options.algo,
        "n_agents": model.n_agents,
        "n_envs": trainer.settings["n_envs"],
        "population": trainer.settings["k"],
        "seed": options.seed,
    }
    monitor = TeamMonitor(run_dir / run_folder.MONITOR_NAME, header)
    monitor.init_callback(model)  # type: ignore[arg-type]
    evaluation = None
    if prepared.eval_env is not None:
        evaluation = TeamEvalCallback(
            prepared.eval_env, options.eval_freq, options.eval_episodes, int(options.seed) + EVAL_SEED_OFFSET,  # type: ignore[arg-type]
            folder=run_dir, verbose=options.verbose,
        )  # fmt: skip
        evaluation.init_callback(model)  # type: ignore[arg-type]
        if "eval" in callback_states:
            evaluation.load_state_dict(callback_states["eval"])
    save_freq = options.save_freq
    schedule = {"next_save": meta.get("next_save", save_freq)}
    stop = _StopRequest()
    checkpoint_path = run_dir / CHECKPOINT_NAME

    def checkpoint(complete: bool = False) -> None:
        states = {} if evaluation is None else {"eval": evaluation.state_dict()}
        facts = {
            "num_timesteps": model.num_timesteps,
            "ticks": model.ticks,
            "total_timesteps": total,
            "next_save": schedule["next_save"],
            "complete": complete,
            "algorithm": config.spec.algorithm_class.__name__,
            "population": trainer.settings["k"],
            "time": time.strftime("%Y-%m-%d %H:%M:%S"),
        }
        save_population_checkpoint(checkpoint_path, trainer, states, facts)

    def after_turn() -> bool:
        model.acting = trainer.best
        if evaluation is not None:
            evaluation.on_step()
        due = save_freq > 0 and model.num_timesteps >= schedule["next_save"]
        if due or stop.stop_requested:
            if save_freq > 0:
                schedule["next_save"] = (model.num_timesteps // save_freq + 1) * save_freq
            checkpoint()
            if due:
                save_model_atomic(model, run_dir / run_folder.snapshot_name(model.num_timesteps))
        return stop.stop_requested is None

    start = time.time()
    if options.verbose >= 1 and not meta:
        print(
            f"Training a population of {trainer.settings['k']} {options.algo} learners on {config.env_id} for {total} "
            f"timesteps, all learners together (seed {options.seed}); run folder {run_dir}",
            flush=True,
        )
    turn_callback = CallbackList([_LearnerEpisodes(monitor, trainer), *extra_callbacks])
    with stop_on_signals(stop):  # type: ignore[arg-type]
        trainer.learn(total // model.n_agents * model.ticks_per_step, callback=turn_callback, after_turn=after_turn)
        monitor.close()
        if stop.stop_requested:
            print(
                f"Stopped by {stop.stop_requested} at {model.num_timesteps} of {total} timesteps; checkpoint "
                f"{checkpoint_path}. Continue with: python -m sb3_eps.train --resume {run_dir}",
                flush=True,
            )
            return TrainResult(run_dir, "interrupted", model.num_timesteps)
        model.acting = trainer.best
        if evaluation is not None and evaluation.records["timesteps"][-1:] != [model.num_timesteps]:
            evaluation.evaluate()
        final_model = run_dir / run_folder.final_model_name(config.env_id)
        save_model_atomic(model, final_model)
        trainer.save(run_dir / POPULATION_NAME)
        if options.keep_checkpoint:
            checkpoint(complete=True)
        else:
            remove_checkpoints(checkpoint_path)
    write_final_report(None if evaluation is None else evaluation.records, run_dir, options.verbose)
    if options.verbose >= 1:
        print(
            f"Done in {(time.time() - start) / 60:.1f} min: {model.num_timesteps} timesteps ({model.ticks} ticks) of "
            f"{trainer.settings['k']} learners; final model (the fittest learner, {trainer.learners.index(model.acting)}) "
            f"{final_model}",
            flush=True,
        )
    return TrainResult(run_dir, "complete", model.num_timesteps)


register_trainer(POPULATION_KEY, POPULATION_PARAMS, check_population_run, run_population)
