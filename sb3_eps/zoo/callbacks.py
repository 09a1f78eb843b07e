"""The callbacks of a training run: :class:`TeamMonitor` (``monitor.csv``, the learning curves),
:class:`TeamEvalCallback` (greedy team evaluations, ``evaluations.npz``, ``best_model.zip``),
:class:`TickBudgetCallback` (training plus EPS within one budget) and :class:`TrainingStateCallback` (checkpoints,
also on SIGINT / SIGTERM)."""

from __future__ import annotations

import csv
import io
import json
import signal
import sys
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import CSVOutputFormat, HumanOutputFormat, KVWriter, Logger, TensorBoardOutputFormat

from sb3_eps.common.evaluation import evaluate_team, vec_env_world
from sb3_eps.common.snapshots import set_rng_states
from sb3_eps.common.vec_env import MultiAgentVecEnv
from sb3_eps.eps import EvolutionCallback
from sb3_eps.zoo import run_folder
from sb3_eps.zoo.checkpoint import Checkpoint, save_checkpoint, save_model_atomic, write_bytes_atomic
from sb3_eps.zoo.cli import TrainOptions

#: The evaluation worlds are seeded ``seed + EVAL_SEED_OFFSET``: other worlds than the training ones.
EVAL_SEED_OFFSET = 10_000
#: Columns every monitor row has; the env's team metrics (``success``, ``collision``...) follow.
MONITOR_COLUMNS = ("r", "l", "t", "ticks", "eps_ticks", "world")


class TrainingInterrupted(Exception):
    """Raised from a callback to leave ``learn()`` after a signal, once the checkpoint is written."""


def eps_ticks_of(callbacks: Sequence[BaseCallback]) -> int:
    """:return: the ticks simulated by EPS so far (the ``eps_ticks`` of the EvolutionCallbacks among ``callbacks``)."""
    return sum(callback.eps_ticks for callback in callbacks if isinstance(callback, EvolutionCallback))


def eps_timesteps(model: Any, callbacks: Sequence[BaseCallback]) -> int:
    """:return: the EPS ticks of ``callbacks`` in timesteps: one per agent of a world, as training counts them."""
    return eps_ticks_of(callbacks) * int(model.n_agents)


def team_score(summary: dict[str, Any]) -> tuple[float, float]:
    """:return: ``(success rate, mean team return)``, compared lexicographically (return breaks ties)."""
    return float(summary.get("success_rate", 0.0)), float(summary["team_return_mean"])


def final_against_best(records: dict[str, list[Any]], run_dir: str | Path, drop: float = 0.1) -> str | None:
    """One line comparing a run's last evaluation with its best (:func:`team_score`), or None without evaluations;
    a warning that names ``best_model.zip`` when the last success rate is ``drop`` or more below the best."""
    if not records.get("timesteps"):
        return None
    scores = [  # team_score of each evaluation
        (float(np.nanmean(successes)) if len(successes) else 0.0, float(np.mean(results)))
        for successes, results in zip(records["successes"], records["results"], strict=True)
    ]
    best = max(range(len(scores)), key=scores.__getitem__)
    (last, last_return), top = scores[-1], scores[best][0]
    line = (
        f"last evaluation: success {last:.0%}, team return {last_return:.2f} at tick "
        f"{records['ticks'][-1]}; best: success {top:.0%} at tick {records['ticks'][best]}"
    )
    if top - last >= drop - 1e-9:
        line += (
            f". WARNING: learning fell after its best evaluation; the best model is {Path(run_dir) / run_folder.BEST_MODEL_NAME}: "
            f"python -m sb3_eps.evaluate --run {run_dir} --load-best"
        )
    return line


def write_final_report(records: dict[str, list[Any]] | None, run_dir: str | Path, verbose: int) -> None:
    """Write :func:`final_against_best`'s line to ``final_vs_best.txt`` (none without evaluations); print it when
    ``verbose`` or when it warns."""
    report = None if records is None else final_against_best(records, run_dir)
    if report is not None:
        (Path(run_dir) / run_folder.FINAL_REPORT_NAME).write_text(report + "\n")
        if verbose >= 1 or "WARNING" in report:
            print(report, flush=True)


# ---------------------------------------------------------------------------------------------- monitor
class TeamMonitor(BaseCallback):
    """One CSV row per world (team) episode: ``r`` team return, ``l`` ticks, ``t`` seconds, the model's ``ticks`` and
    ``eps_ticks`` at its end, ``world`` and the env's team metrics, under a ``#`` JSON header as SB3's ``Monitor``
    writes it (so SB3's ``load_results`` reads the file).

    :param path: the CSV file; an existing one is continued (after :meth:`truncate_after` when resuming)
    :param header: what the first line records
    :param eps_callbacks: callbacks whose ``eps_ticks`` count towards the curves (EPS)
    """

    def __init__(self, path: str | Path, header: dict[str, Any], eps_callbacks: Sequence[BaseCallback] = ()) -> None:
        super().__init__()
        self.path = Path(path)
        self.header = {"t_start": time.time(), **header}
        self.eps_callbacks = list(eps_callbacks)
        self.columns: list[str] | None = None
        if self.path.exists():
            with self.path.open() as file:
                file.readline()
                names = file.readline().strip()
            self.columns = names.split(",") if names else None
        self._file: Any = None
        self._start = time.time()

    @staticmethod
    def truncate_after(path: str | Path, ticks: int) -> None:
        """Drop the rows of episodes that ended after ``ticks`` (written after the checkpoint being resumed)."""
        path = Path(path)
        if not path.exists():
            return
        lines = path.read_text().splitlines(keepends=True)
        if len(lines) < 2:
            return
        index = lines[1].strip().split(",").index("ticks")
        kept = lines[:2] + [line for line in lines[2:] if int(float(line.split(",")[index])) <= ticks]
        write_bytes_atomic(path, "".join(kept).encode())

    def _on_step(self) -> bool:
        infos = self.locals["infos"]
        n_agents = int(self.model.n_agents)  # type: ignore[attr-defined]
        for world in range(len(infos) // n_agents):
            episode = infos[world * n_agents].get("episode")
            if episode is not None:
                self._write(episode, world)
        return True

    def _write(self, episode: dict[str, Any], world: int) -> None:
        row = {
            **{key: value for key, value in episode.items() if isinstance(value, _SCALARS)},
            "ticks": int(self.model.ticks),  # type: ignore[attr-defined]
            "eps_ticks": eps_ticks_of(self.eps_callbacks),
            "world": world,
        }
        if self.columns is None:
            extra = sorted(key for key in row if key not in MONITOR_COLUMNS)
            self.columns = [*MONITOR_COLUMNS, *extra]
            with self.path.open("w") as file:
                file.write("#" + json.dumps(self.header) + "\n" + ",".join(self.columns) + "\n")
        if self._file is None:
            self._file = self.path.open("a", newline="")
        values = [row.get(column, "") for column in self.columns]
        csv.writer(self._file, lineterminator="\n").writerow(
            [int(value) if isinstance(value, bool) else value for value in values]
        )
        self._file.flush()

    def _on_training_end(self) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (it is reopened on the next episode)."""
        if self._file is not None:
            self._file.close()
            self._file = None


_SCALARS = (bool, int, float, str, np.integer, np.floating, np.bool_)


# ---------------------------------------------------------------------------------------------- evaluation
class TeamEvalCallback(BaseCallback):
    """Greedy team evaluation on separate evaluation worlds every ``eval_freq`` timesteps: the same seeded episodes
    each time, SB3's ``EvalCallback`` keys per world episode plus ``eval/success_rate``, ``eval/collision_rate``,
    ``eval/ticks`` and ``eval/eps_ticks``; ``best_model.zip`` when :func:`team_score` improves.

    :param eval_env: the evaluation worlds (not the training ones)
    :param eval_freq: timesteps (agent-steps) between evaluations; 0 disables
    :param n_eval_episodes: world episodes per evaluation
    :param seed: seed of the evaluation worlds
    :param folder: where ``evaluations.npz`` and ``best_model.zip`` go (None: nowhere)
    :param eps_callbacks: callbacks whose ``eps_ticks`` are recorded with each evaluation
    :param count_eps_ticks: count ``eval_freq`` in timesteps of training plus EPS (an EPS tick is one timestep per
        agent of a world), not of training alone
    :param on_evaluation: called with each evaluation's summary; returning False stops training (pruning)
    :param verbose: 1 prints one line per evaluation
    """

    def __init__(
        self,
        eval_env: MultiAgentVecEnv,
        eval_freq: int,
        n_eval_episodes: int,
        seed: int,
        folder: str | Path | None = None,
        eps_callbacks: Sequence[BaseCallback] = (),
        on_evaluation: Callable[[dict[str, Any]], bool] | None = None,
        verbose: int = 0,
        count_eps_ticks: bool = False,
    ) -> None:
        super().__init__(verbose=verbose)
        self.eval_env = eval_env
        self.eval_freq = int(eval_freq)
        self.n_eval_episodes = int(n_eval_episodes)
        self.eval_seed = int(seed)
        self.folder = Path(folder) if folder is not None else None
        self.eps_callbacks = list(eps_callbacks)
        self.count_eps_ticks = count_eps_ticks
        self.on_evaluation = on_evaluation
        self.next_eval = self.eval_freq
        self.records: dict[str, list[Any]] = {key: [] for key in _RECORD_KEYS}
        self.best_score: tuple[float, float] | None = None
        self.last_summary: dict[str, Any] | None = None

    def state_dict(self) -> dict[str, Any]:
        """:return: what a checkpoint keeps of this callback."""
        return {"next_eval": self.next_eval, "records": self.records, "best_score": self.best_score}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`."""
        self.next_eval = state["next_eval"]
        self.records = state["records"]
        self.best_score = state["best_score"]
        self._write_records()  # drops evaluations made after the checkpoint by a process that died

    def _on_step(self) -> bool:
        progress = self.num_timesteps
        if self.count_eps_ticks:
            progress += eps_timesteps(self.model, self.eps_callbacks)
        if self.eval_freq <= 0 or progress < self.next_eval:
            return True
        self.next_eval = (progress // self.eval_freq + 1) * self.eval_freq  # a round can pass several points
        summary = self.evaluate()
        return True if self.on_evaluation is None else bool(self.on_evaluation(summary))

    def evaluate(self) -> dict[str, Any]:
        """Evaluate now; record, log and save. :return: the summary of :func:`~sb3_eps.evaluate_team`."""
        summary = evaluate_team(self.model, self.eval_env, self.n_eval_episodes, seed=self.eval_seed)
        episodes = summary.pop("episodes")
        ticks = int(self.model.ticks)  # type: ignore[attr-defined]
        eps_ticks = eps_ticks_of(self.eps_callbacks)
        summary.update(timesteps=self.num_timesteps, ticks=ticks, eps_ticks=eps_ticks)
        self.last_summary = summary
        self._record(summary, episodes)
        self._log(summary)
        score = team_score(summary)
        if self.best_score is None or score > self.best_score:
            self.best_score = score
            if self.folder is not None:
                save_model_atomic(self.model, self.folder / run_folder.BEST_MODEL_NAME)
        return summary

    def _record(self, summary: dict[str, Any], episodes: list[dict[str, Any]]) -> None:
        records = self.records
        records["timesteps"].append(summary["timesteps"])
        records["ticks"].append(summary["ticks"])
        records["eps_ticks"].append(summary["eps_ticks"])
        records["results"].append([float(episode["r"]) for episode in episodes])
        records["ep_lengths"].append([int(episode["l"]) for episode in episodes])
        for key, name in (("success", "successes"), ("collision", "collisions")):
            records[name].append([float(episode.get(key, np.nan)) for episode in episodes])
        self._write_records()

    def _write_records(self) -> None:
        if self.folder is not None and self.records["timesteps"]:
            arrays = {key: np.array(value) for key, value in self.records.items()}
            world = vec_env_world(self.eval_env, self.n_eval_episodes)
            if world is not None:  # as JSON text: np.load reads it without pickles
                arrays[run_folder.EVALUATIONS_WORLD_KEY] = np.array(json.dumps(world))
            buffer = io.BytesIO()
            np.savez(buffer, **arrays)  # type: ignore[arg-type]
            write_bytes_atomic(self.folder / run_folder.EVALUATIONS_NAME, buffer.getvalue())

    def _log(self, summary: dict[str, Any]) -> None:
        logger = self.logger
        # SB3's EvalCallback keys (per world episode: the team return and the ticks), then the team extras.
        logger.record("eval/mean_reward", summary["team_return_mean"])
        logger.record("eval/mean_ep_length", summary["length_mean"])
        logger.record("eval/std_reward", summary["team_return_std"])
        for key in ("success_rate", "collision_rate"):
            if key in summary:
                logger.record(f"eval/{key}", summary[key])
        logger.record("eval/ticks", summary["ticks"])
        logger.record("eval/eps_ticks", summary["eps_ticks"])
        logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        logger.dump(self.num_timesteps)
        if self.verbose >= 1:
            success = f"success {100 * summary['success_rate']:.0f} %, " if "success_rate" in summary else ""
            print(
                f"Eval at {self.num_timesteps} timesteps ({summary['ticks']} ticks): {success}team return "
                f"{summary['team_return_mean']:.2f} +/- {summary['team_return_std']:.2f}, length "
                f"{summary['length_mean']:.0f} ticks",
                flush=True,
            )


class TickBudgetCallback(BaseCallback):
    """Ends ``learn()`` once training and EPS together reach ``budget`` timesteps, an EPS tick counting as one
    timestep per agent of a world (the equal-ticks budget of the EPS comparisons): EPS's ticks are paid from
    training.

    :param budget: timesteps (agent-steps) of training plus EPS, counted from 0 (``model.num_timesteps``)
    :param eps_callbacks: callbacks whose ``eps_ticks`` count
    :param schedules_follow: end the schedules (learning rate, exploration, PER's beta, EPS's alpha) with the
        budget, by lowering the model's ``_total_timesteps`` as EPS spends ticks; False: over the whole budget
    """

    def __init__(self, budget: int, eps_callbacks: Sequence[BaseCallback], schedules_follow: bool = True) -> None:
        super().__init__()
        self.budget = int(budget)
        self.eps_callbacks = list(eps_callbacks)
        self.schedules_follow = bool(schedules_follow)

    def _on_step(self) -> bool:
        spent = eps_timesteps(self.model, self.eps_callbacks)
        if self.schedules_follow and spent:
            self.model._total_timesteps = max(self.budget - spent, 1)
        return self.num_timesteps + spent < self.budget


_RECORD_KEYS = ("timesteps", "ticks", "eps_ticks", "results", "ep_lengths", "successes", "collisions")


# ---------------------------------------------------------------------------------------------- checkpoints
class TrainingStateCallback(BaseCallback):
    """Writes the full training state every ``save_freq`` timesteps, and the model alone beside it (RL Zoo's
    ``rl_model_<timesteps>_steps.zip``), at rollout starts (where every piece of state can be restored exactly), and
    after SIGINT / SIGTERM (:func:`stop_on_signals`), then raises :class:`TrainingInterrupted`.

    :param path: the checkpoint file
    :param save_freq: timesteps between checkpoints; 0 saves only on a signal
    :param total_timesteps: the run's total, recorded in the checkpoint
    :param stateful_callbacks: name -> callback whose state goes into the checkpoint
    :param restore: when resuming, the checkpoint: its callback states, random states and ``next_save`` are
        applied at the start of training, after every callback's initialisation
    :param verbose: 1 prints a line per checkpoint
    :param extra_meta: returns more facts for ``meta.json`` at each checkpoint (a ladder's rung and its progress)
    """

    def __init__(
        self,
        path: str | Path,
        save_freq: int,
        total_timesteps: int,
        stateful_callbacks: dict[str, BaseCallback],
        restore: Checkpoint | None = None,
        verbose: int = 0,
        extra_meta: Callable[[], dict[str, Any]] | None = None,
    ) -> None:
        super().__init__(verbose=verbose)
        self.extra_meta = extra_meta
        self.path = Path(path)
        self.save_freq = int(save_freq)
        self.total_timesteps = int(total_timesteps)
        self.stateful_callbacks = stateful_callbacks
        self.restore = restore
        self.next_save = self.save_freq
        self.stop_requested: str | None = None
        self.saved_at: int | None = None

    def _on_training_start(self) -> None:
        if self.restore is None:
            return
        for name, state in self.restore.callbacks.items():
            self.stateful_callbacks[name].load_state_dict(state)  # type: ignore[attr-defined]
        self.next_save = self.restore.meta["next_save"]
        set_rng_states(self.restore.rng)
        self.restore = None

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        due = self.save_freq > 0 and self.num_timesteps >= self.next_save
        if not (due or self.stop_requested):
            return
        if self.save_freq > 0:
            self.next_save = (self.num_timesteps // self.save_freq + 1) * self.save_freq
        if self.save() and due:
            save_model_atomic(self.model, self.path.parent / run_folder.snapshot_name(self.model.num_timesteps))
        if self.stop_requested:
            raise TrainingInterrupted(self.stop_requested)

    def save(self, complete: bool = False) -> bool:
        """Write the checkpoint now (between two iterations of ``learn``, or after it); refused with a warning, the
        previous one kept, when the weights are not finite or the file cannot be written.

        :return: whether a checkpoint was written
        """
        refused = f"checkpoint at {self.model.num_timesteps} timesteps %s; the previous checkpoint is kept"
        tensors = [*self.model.policy.named_parameters(), *self.model.policy.named_buffers()]
        broken = [name for name, tensor in tensors if tensor.is_floating_point() and not th.isfinite(tensor).all()]
        if broken:
            warnings.warn(refused % f"refused: non-finite values in {', '.join(broken)}", RuntimeWarning, stacklevel=2)
            return False
        states = {name: callback.state_dict() for name, callback in self.stateful_callbacks.items()}  # type: ignore[attr-defined]
        meta = {
            "num_timesteps": int(self.model.num_timesteps),
            "ticks": int(self.model.ticks),  # type: ignore[attr-defined]
            "total_timesteps": self.total_timesteps,
            "next_save": self.next_save,
            "complete": complete,
            "algorithm": type(self.model).__name__,
            "time": time.strftime("%Y-%m-%d %H:%M:%S"),
            **(self.extra_meta() if self.extra_meta is not None else {}),
        }
        try:
            save_checkpoint(self.path, self.model, states, meta)  # type: ignore[arg-type]
        except OSError as error:
            warnings.warn(refused % f"not written ({error})", RuntimeWarning, stacklevel=2)
            return False
        self.saved_at = int(self.model.num_timesteps)
        if self.verbose >= 1:
            print(f"Checkpoint at {self.saved_at} timesteps: {self.path}", flush=True)
        return True


@contextmanager
def stop_on_signals(callback: TrainingStateCallback) -> Iterator[None]:
    """While the block runs, SIGINT and SIGTERM ask ``callback`` to checkpoint and stop at the next rollout start;
    a second signal stops at once (``KeyboardInterrupt``). Handlers are put back afterwards.
    """

    def handler(signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if callback.stop_requested:
            raise KeyboardInterrupt(f"second {name}: stopping without a checkpoint")
        callback.stop_requested = name
        print(f"\n{name} received: writing a checkpoint at the next rollout start, then stopping", flush=True)

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


# ---------------------------------------------------------------------------------------------- logs
class ResumableCSVOutputFormat(CSVOutputFormat):
    """SB3's CSV log that continues an existing file: the rows logged after ``max_timesteps`` (after the checkpoint
    being resumed) are dropped, the others kept as they were written.

    :param filename: the CSV file
    :param max_timesteps: keep rows whose ``time/total_timesteps`` is at most this; None starts a new file
    """

    def __init__(self, filename: str | Path, max_timesteps: int | None = None) -> None:
        path = Path(filename)
        resumed = max_timesteps is not None and path.is_file()
        lines = path.read_text().splitlines(keepends=True) if resumed else []
        super().__init__(str(path))
        if lines:
            self.keys = lines[0].rstrip("\n").split(self.separator)  # SB3 writes the keys unquoted
            column = self.keys.index("time/total_timesteps")
            kept = [line for line in lines[1:] if float(next(csv.reader([line]))[column] or -1) <= max_timesteps]  # type: ignore[operator]
            self.file.writelines([lines[0], *kept])
            self.file.flush()


def make_logger(options: TrainOptions, run_dir: Path, resume_timesteps: int | None) -> Logger:
    """SB3 logger writing ``progress.csv`` (continued when resuming), if verbose stdout, and with
    ``--tensorboard-log`` TensorBoard in ``<tensorboard_log>/<algo>/<run folder name>``."""
    formats: list[KVWriter] = [ResumableCSVOutputFormat(run_dir / run_folder.PROGRESS_NAME, resume_timesteps)]
    if options.verbose >= 1:
        formats.insert(0, HumanOutputFormat(sys.stdout))
    if options.tensorboard_log is not None:
        formats.append(TensorBoardOutputFormat(str(Path(options.tensorboard_log) / options.algo / run_dir.name)))
    return Logger(folder=str(run_dir), output_formats=formats)
