"""The experiment manager behind ``python -m sb3_eps.train``: config -> envs, model, callbacks -> run folder -> learn.
Everything is built and checked before anything is written; ``--resume`` continues a run from its checkpoint to the
result of the uninterrupted run."""

from __future__ import annotations

import random
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import torch as th
import yaml
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ProgressBarCallback
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_eps.common.ladder import Rung, learn_ladder, rung_at
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.subproc_vec_env import VecEnvWorkerError
from sb3_eps.common.vec_env import MultiAgentVecEnv
from sb3_eps.eps import EvolutionCallback, eps_env_id_for
from sb3_eps.eps.evaluation import agent_space, make_eval_env
from sb3_eps.version import __version__
from sb3_eps.zoo import run_folder
from sb3_eps.zoo.callbacks import (
    EVAL_SEED_OFFSET,
    TeamEvalCallback,
    TeamMonitor,
    TrainingInterrupted,
    TrainingStateCallback,
    make_logger,
    stop_on_signals,
    write_final_report,
)
from sb3_eps.zoo.checkpoint import (
    CHECKPOINT_NAME,
    Checkpoint,
    CorruptCheckpoint,
    latest_good_checkpoint,
    load_checkpoint,
    remove_checkpoints,
    restore_model,
    save_model_atomic,
    write_text_atomic,
)
from sb3_eps.zoo.cli import TrainOptions, TrainResult, import_gym_packages
from sb3_eps.zoo.config import (
    PreparedRun,
    ResolvedConfig,
    build_env,
    check_env_id,
    close_envs,
    entry_yaml,
    load_config_entries,
    load_yaml,
    merged_entry,
    resolve_config,
)
from sb3_eps.zoo.errors import ConfigError, RunFailed
from sb3_eps.zoo.evaluation import check_spaces
from sb3_eps.zoo.ladder import LADDER_KEY, build_rungs, check_ladder_run, check_rungs, ladder_progress
from sb3_eps.zoo.schema import algorithm_kwargs, algorithm_spec, build_callbacks, check_complete, entry_trainer


# ---------------------------------------------------------------------------------------------- building
def build_model(
    config: ResolvedConfig, env: MultiAgentVecEnv, seed: int | None, device: str, verbose: int
) -> MultiAgentOffPolicyAlgorithm:
    """Make the model of a config on ``env``.

    :raises ConfigError: when the algorithm refuses the config
    """
    cls = config.spec.algorithm_class
    try:
        return cls(
            config.entry.get("policy", "MlpPolicy"),
            env,
            seed=seed,
            device=device,
            verbose=verbose,
            **algorithm_kwargs(config.entry, config.spec),
        )
    except (TypeError, ValueError) as error:
        raise ConfigError(f"{config.source}: building {cls.__name__}: {error}") from None


def check_callback_worlds(callbacks: list[tuple[str, BaseCallback]], env: MultiAgentVecEnv, source: str) -> None:
    """Check that every callback's own evaluation world (EPS's ``eval_env_id``) shares the training world's
    observation and action spaces, before anything is written (the callback itself checks only when training
    starts).

    :raises ConfigError: naming the callback, both worlds and their spaces
    """
    for name, callback in callbacks:
        if isinstance(callback, EvolutionCallback):
            eval_env = make_eval_env(callback.settings.eval_env_id, callback.settings.eval_env_kwargs)
            kinds = ("observation_space", "action_space")
            spaces = SimpleNamespace(**{kind: agent_space(eval_env, kind) for kind in kinds})
            eval_env.close()
            whose = f"the training world {env.env_id} (its EPS world, the default, is {eps_env_id_for(str(env.env_id))})"
            check_spaces(env, spaces, callback.settings.eval_env_id, whose, f"{source}: callback {name}: eval_env_id ")


def load_agent_weights(model: MultiAgentOffPolicyAlgorithm, path: str | Path) -> None:
    """Warm start (paper Table III): copy the agent network (``q_net`` and its target) of a saved model into
    ``model``, e.g. from a single-robot model trained on ``SingleRobotNav-v0`` into a multi-robot one; a weight
    average (``weight_average_tau``) starts from the loaded network. The joint modules (GDQ's ``V_G``, mixers) and
    the optimizer state start fresh.

    :param model: the new model
    :param path: a model ``.zip`` with the same agent network architecture and spaces
    :raises ConfigError: when the file is unreadable or its network does not fit
    """
    try:
        data, params, _ = load_from_zip_file(path, device=model.device)
    except (OSError, ValueError, KeyError) as error:
        raise ConfigError(f"--init-from: cannot read {path}: {error}") from None
    if data is None or params is None or "policy" not in params:
        raise ConfigError(f"--init-from: {path} holds no policy weights")
    trained_on = SimpleNamespace(**{kind: data.get(kind) for kind in ("observation_space", "action_space")})
    check_spaces(model, trained_on, f"the model in {path}", "the new model", "--init-from: ")
    policy: dict[str, Any] = params["policy"]  # type: ignore[assignment]
    online = {key[len("q_net.") :]: value for key, value in policy.items() if key.startswith("q_net.")}
    target = {key[len("q_net_target.") :]: value for key, value in policy.items() if key.startswith("q_net_target.")}
    try:
        model.policy.q_net.load_state_dict(online)
        if model.policy.q_net_target is not None:
            model.policy.q_net_target.load_state_dict(target or online)
        model.policy.reset_weight_average()  # a kept weight average starts from the loaded network
    except RuntimeError as error:
        first = str(error).splitlines()[1:2] or [str(error)]
        raise ConfigError(
            f"--init-from: the agent network of {path} does not fit this model (use the same policy_kwargs "
            f"net_arch / stream_arch / activation_fn): {first[0].strip()}"
        ) from None


def prepare_run(options: TrainOptions, config: ResolvedConfig | None = None, build_model_now: bool = True) -> PreparedRun:
    """Resolve the config and build envs, model and callbacks; nothing is written.

    :param options: the run's options
    :param config: an already resolved config (resume), else resolved from the options
    :param build_model_now: False when the model comes from a checkpoint (resume)
    :raises ConfigError: for any mistake
    """
    options.check()
    if config is None:
        check_env_id(options.env)
        hyperparams = [*options.hyperparams, *(f"env_kwargs.{item}" for item in options.env_kwargs)]
        config = resolve_config(options.algo, options.env, options.conf_file, hyperparams, options.n_timesteps)
        if LADDER_KEY in config.entry:
            check_ladder_run(config.entry, config.env_id, options.n_timesteps, options.algo, config.source)
        trainer = entry_trainer(config.entry)
        if trainer is not None:
            trainer.check(config, options)
    eval_env_id = options.eval_env or config.env_id
    check_env_id(eval_env_id, "--eval-env")
    if options.seed is None:
        options.seed = random.SystemRandom().randrange(2**31 - 1)
    if options.num_threads > 0:
        th.set_num_threads(options.num_threads)
    ladder = config.entry.get(LADDER_KEY)
    env = build_env(config, options.seed, ladder[0]["env"] if ladder else None, vec_env=options.vec_env)
    model: Any = None
    eval_env = None
    rungs: list[Rung] = []
    try:
        if ladder:
            rungs = build_rungs(
                config.entry,
                env,
                options.seed,
                lambda env_id, seed: build_env(config, seed, env_id, vec_env=options.vec_env),
            )
        if build_model_now:
            model = build_model(config, env, options.seed, options.device, options.verbose)
            if options.init_from is not None:
                load_agent_weights(model, options.init_from)
            if ladder:
                config.entry["n_timesteps"] = check_rungs(model, rungs, config.source)
        if options.eval_freq > 0:
            eval_env = build_env(config, options.seed + EVAL_SEED_OFFSET, eval_env_id, options.n_eval_envs, options.vec_env)
            if model is not None:
                check_spaces(model, eval_env, eval_env_id, "the model", "--eval-env: ")
        user_callbacks = build_callbacks(config.entry, config.env_id, options.verbose, config.source)
        check_callback_worlds(user_callbacks, env, config.source)
    except BaseException:
        close_envs([env, eval_env, *(rung.env for rung in rungs)])
        raise
    return PreparedRun(options, config, env, eval_env, model, user_callbacks, rungs)


# ---------------------------------------------------------------------------------------------- training
def train(options: TrainOptions, extra_callbacks: Sequence[BaseCallback] = ()) -> TrainResult:
    """Build, create the run folder, train (``python -m sb3_eps.train``).

    :param options: the run's options
    :param extra_callbacks: more callbacks to run (not checkpointed; e.g. a probe of ``benchmarks/soak.py``)
    :raises ConfigError: for any mistake, before anything is written
    """
    prepared = prepare_run(options)
    try:
        env_id = prepared.config.env_id
        run_dir = run_folder.create_run_folder(options.folder, options.algo, env_id, options.run_name)
        options_record = {**vars(options), "version": __version__, "run_dir": str(run_dir)}
        options_record["n_timesteps"] = prepared.config.entry["n_timesteps"]
        params = run_dir / env_id  # RL Zoo's parameter folder
        params.mkdir()
        write_text_atomic(params / run_folder.ARGS_NAME, yaml.safe_dump(options_record, sort_keys=False))
        header = f"resolved from {prepared.config.source}\nrerun: python -m sb3_eps.train --algo {options.algo} -conf <this file> ..."
        write_text_atomic(params / run_folder.CONFIG_NAME, entry_yaml(env_id, prepared.config.entry, header))
        write_text_atomic(params / run_folder.COMMAND_NAME, (options.command or run_folder.command_line()) + "\n")
        trainer = entry_trainer(prepared.config.entry)
        if trainer is not None:
            return trainer.run(prepared, run_dir, None, extra_callbacks)
        return _run(prepared, run_dir, restore=None, extra_callbacks=extra_callbacks)
    finally:
        prepared.close()


def resume(run_dir: str | Path, progress: bool | None = None, verbose: int | None = None) -> TrainResult:
    """Continue an interrupted run from its checkpoint to its total (``--resume``).

    :param run_dir: the run folder, or its parameter folder ``<run>/<env id>/``
    :param progress: show a progress bar (None: as the run was started)
    :param verbose: verbosity (None: as the run was started)
    :raises ConfigError: when the folder holds no resumable run
    """
    run_dir = run_folder.run_dir_of(run_dir)
    args_path, config_path = (run_folder.run_file(run_dir, name) for name in (run_folder.ARGS_NAME, run_folder.CONFIG_NAME))
    for path in (args_path, config_path):
        if not path.is_file():
            raise ConfigError(f"--resume: {run_dir} is not a run folder of sb3_eps.train (no {path.name})")
    options = TrainOptions.from_record(load_yaml(args_path), f"--resume: {args_path}")
    # The run's plug-ins, before its algorithm and world are named.
    import_gym_packages([], options.gym_packages)
    spec = algorithm_spec(options.algo)
    check_env_id(options.env, f"--resume: {args_path}: env")
    options.init_from = None  # the warm-start weights are in the checkpoint already
    if progress is not None:
        options.progress = progress
    if verbose is not None:
        options.verbose = verbose
    final_model = run_dir / run_folder.final_model_name(options.env)
    try:
        checkpoint_path, meta, skipped = latest_good_checkpoint(run_dir / CHECKPOINT_NAME)
    except FileNotFoundError:
        if not final_model.is_file():
            raise ConfigError(
                f"--resume: {run_dir} has no {CHECKPOINT_NAME} (it stopped before its first checkpoint); start a new run"
            ) from None
        checkpoint_path, meta, skipped = final_model, {"complete": True}, []
    except CorruptCheckpoint as error:
        raise ConfigError(f"--resume: no usable checkpoint in {run_dir}: {error}; start a new run") from None
    for problem in skipped:
        print(
            f"warning: {problem}; resuming from {checkpoint_path.name} at {meta['num_timesteps']} timesteps", file=sys.stderr
        )
    if meta.get("complete"):
        print(f"{run_dir} has finished already: its final model is {final_model}")
        return TrainResult(run_dir, "already complete", int(options.n_timesteps or 0))
    entry = merged_entry(load_config_entries(config_path, options.algo), options.env, config_path)
    config = ResolvedConfig(options.algo, options.env, entry, f"{config_path}: entry {options.env!r}")
    check_complete(entry, spec, config.source)
    saved_algorithm = meta.get("algorithm", spec.algorithm_class.__name__)
    if saved_algorithm != spec.algorithm_class.__name__:
        raise ConfigError(
            f"--resume: {checkpoint_path} holds a {saved_algorithm} model, but {args_path} says "
            f"--algo {options.algo} ({spec.algorithm_class.__name__}): the run folder was mixed with another one"
        )
    prepared = prepare_run(options, config, build_model_now=False)
    try:
        trainer = entry_trainer(entry)
        if trainer is not None:
            return trainer.run(prepared, run_dir, checkpoint_path, ())
        checkpoint = load_checkpoint(checkpoint_path)
        # The training worlds come back from the checkpoint, mid-episode (a ladder's: those of its rung).
        rung = resumed_rung(prepared, checkpoint.meta, checkpoint_path)
        close_envs([prepared.rungs[rung].env if prepared.rungs else prepared.env])
        prepared.env = checkpoint.training["env"]
        if prepared.rungs:
            prepared.rungs[rung] = Rung(prepared.env, prepared.rungs[rung].ticks)
        prepared.model = restore_model(checkpoint, spec.algorithm_class, options.device)
        prepared.model.verbose = options.verbose
        if options.verbose >= 1:
            print(f"Resuming {run_dir} at {checkpoint.meta['num_timesteps']} of {options.n_timesteps} timesteps")
        return _run(prepared, run_dir, checkpoint)
    finally:
        prepared.close()


def resumed_rung(prepared: PreparedRun, meta: dict[str, Any], checkpoint_path: Path) -> int:
    """:return: the ladder rung a checkpoint was taken in (0 without a ladder).

    :raises ConfigError: when the run's ladder puts its ticks in another rung than the checkpoint records
    """
    if not prepared.rungs:
        return 0
    rung = rung_at(prepared.rungs, int(meta["ticks"]))
    if meta.get("rung") != rung:
        raise ConfigError(
            f"--resume: {checkpoint_path} was taken in ladder rung {meta.get('rung')}, but the run's config.yml puts "
            f"its {meta['ticks']} ticks in rung {rung}: the run folder was mixed with another one"
        )
    return rung


def _run(
    prepared: PreparedRun,
    run_dir: Path,
    restore: Checkpoint | None,
    extra_callbacks: Sequence[BaseCallback] = (),
) -> TrainResult:
    """Train a prepared run in its folder; write the final model. ``restore`` continues a checkpoint."""
    options, config, model = prepared.options, prepared.config, prepared.model
    total = int(config.entry["n_timesteps"])
    resume_timesteps = None if restore is None else int(restore.meta["num_timesteps"])
    if restore is not None:
        TeamMonitor.truncate_after(run_dir / run_folder.MONITOR_NAME, int(restore.meta["ticks"]))
    model.set_logger(make_logger(options, run_dir, resume_timesteps))
    eps_callbacks = [callback for _, callback in prepared.user_callbacks]
    header = {
        "env_id": config.env_id,
        "algo": options.algo,
        "n_agents": model.n_agents,
        "n_envs": model.n_worlds,
        "seed": options.seed,
    }
    callbacks: list[BaseCallback] = [TeamMonitor(run_dir / run_folder.MONITOR_NAME, header, eps_callbacks)]
    stateful: dict[str, BaseCallback] = {}
    eval_callback = None
    if prepared.eval_env is not None:
        eval_callback = TeamEvalCallback(
            prepared.eval_env, options.eval_freq, options.eval_episodes, options.seed + EVAL_SEED_OFFSET,  # type: ignore[operator]
            folder=run_dir, eps_callbacks=eps_callbacks, verbose=options.verbose,
        )  # fmt: skip
        callbacks.append(eval_callback)
        stateful["eval"] = eval_callback
    for index, (name, callback) in enumerate(prepared.user_callbacks):
        callbacks.append(callback)
        stateful[f"{index}:{name}"] = callback
    rungs = prepared.rungs
    checkpoint = TrainingStateCallback(
        run_dir / CHECKPOINT_NAME,
        options.save_freq,
        total,
        stateful,
        restore,
        options.verbose,
        extra_meta=(lambda: ladder_progress(rungs, model.ticks)) if rungs else None,
    )
    if options.progress:
        callbacks.append(ProgressBarCallback())
    callbacks.extend(extra_callbacks)
    callbacks.append(checkpoint)  # last: it restores states after every other callback is initialised
    callback_list = CallbackList(callbacks)
    start = time.time()
    if options.verbose >= 1 and restore is None:
        print(
            f"Training {options.algo} on {config.env_id} for {total} timesteps (seed {options.seed}); run folder {run_dir}",
            flush=True,
        )
    # The signal handlers stay until the final model is written: a signal after learn() only lets it finish.
    with stop_on_signals(checkpoint):
        try:
            log_interval = options.log_interval if options.log_interval > 0 else 4
            if rungs:
                learn_ladder(model, rungs, callback_list, log_interval, reset_num_timesteps=restore is None)
            else:
                model.learn(
                    total - model.num_timesteps,
                    callback=callback_list,
                    log_interval=log_interval,
                    reset_num_timesteps=restore is None,
                )
        except VecEnvWorkerError as error:
            kept = (
                f"its last checkpoint ({checkpoint.saved_at} timesteps) is kept: continue with "
                f"python -m sb3_eps.train --resume {run_dir}"
                if (run_dir / CHECKPOINT_NAME).is_file()
                else "it had no checkpoint yet: start it again"
            )
            reason = str(error).split("; its worlds are lost")[0]
            raise RunFailed(f"{run_dir}: {reason}; {kept}") from error
        except TrainingInterrupted as stop:
            callback_list.on_training_end()
            saved = (
                "" if checkpoint.saved_at == model.num_timesteps else ", without a new checkpoint (the last good one is kept)"
            )
            print(
                f"Stopped by {stop} at {model.num_timesteps} of {total} timesteps{saved}; checkpoint "
                f"{run_dir / CHECKPOINT_NAME}. Continue with: python -m sb3_eps.train --resume {run_dir}",
                flush=True,
            )
            return TrainResult(run_dir, "interrupted", int(model.num_timesteps))
        if eval_callback is not None and eval_callback.records["timesteps"][-1:] != [model.num_timesteps]:
            eval_callback.evaluate()
        save_model_atomic(model, run_dir / run_folder.final_model_name(config.env_id))
        if options.keep_checkpoint:
            checkpoint.save(complete=True)
        else:
            remove_checkpoints(run_dir / CHECKPOINT_NAME)
    write_final_report(None if eval_callback is None else eval_callback.records, run_dir, options.verbose)
    if options.verbose >= 1:
        minutes = (time.time() - start) / 60
        print(
            f"Done in {minutes:.1f} min: {model.num_timesteps} timesteps ({model.ticks} ticks); final model {run_dir / run_folder.final_model_name(config.env_id)}",
            flush=True,
        )
    return TrainResult(run_dir, "complete", int(model.num_timesteps))
