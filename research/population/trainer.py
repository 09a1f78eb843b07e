"""A population of learners: Population Based Training (Jaderberg et al., arXiv 1711.09846) for this package's
algorithms, with EPS's calibrated safe mutation (Eq. 6) and a distillation crossover (PDERL, Bodnar et al. 2020).

``k`` learners of one algorithm train on worlds of their own, taking turns of ``turn_ticks`` world ticks each.
Every ``interval`` world ticks (all learners together) each learner's fitness is read from its own recent training
episodes, so selection costs no extra ticks; the fittest learner is copied over the weakest (weights, optimizer
state, target and averaged networks, hyper-parameters), which is then perturbed. See ``docs/modules/population.md``.
"""

from __future__ import annotations

import copy
import importlib
import io
import json
import os
import pickle
import signal
import tempfile
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import FloatSchedule, LinearSchedule
from stable_baselines3.common.vec_env import VecEnv

from research.population.distillation import q_filtered_distillation
from sb3_eps.common.ladder import ScheduleHorizon
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.snapshots import rng_states, set_rng_states, snapshot_dumps
from sb3_eps.eps.callback import VALUE_STREAM
from sb3_eps.eps.mutations import (
    calibrate_scale,
    evolved_parameter_names,
    individual,
    mutation_directions,
    network_parameters,
    output_sensitivity,
    policy_change,
    population_from_directions,
    population_outputs,
)
from sb3_eps.eps.round import sample_visited_observations
from sb3_eps.eps.settings import DEFAULT_SIGMA, EPSSettings

FITNESS_KINDS = ("success", "return")
CROSSOVERS = ("copy", "distill")
MUTATIONS = ("safe", None)
PERTURBABLE = ("learning_rate", "exploration_final_eps")
#: Visited states of Eq. 6 and of the mutation's calibration; replay states per parent of a distillation.
SENSITIVITY_BATCH_SIZE = 128
DISTILLATION_STATES = 512
#: The safe step of EPS's defaults (sensitivity floor, per-weight clip, the calibration's first scale).
_SAFE = EPSSettings()
INITIAL_SCALE = DEFAULT_SIGMA["safe"]


class ScaledSchedule:
    """A learning-rate schedule times a factor (a PBT perturbation of a schedule); picklable with the model."""

    def __init__(self, schedule: Callable[[float], float], factor: float) -> None:
        if isinstance(schedule, ScaledSchedule):  # one factor, however often it was perturbed
            factor *= schedule.factor
            schedule = schedule.schedule
        self.schedule: Callable[[float], float] = schedule
        self.factor: float = factor

    def __call__(self, progress_remaining: float) -> float:
        return self.factor * float(self.schedule(progress_remaining))

    def __repr__(self) -> str:
        return f"ScaledSchedule({self.schedule}, {self.factor:g})"


class PopulationTrainer:
    """``k`` learners of one algorithm, the fittest copied over the weakest every ``interval`` world ticks.

    :param algorithm_class: a :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm` (GDQ, IQL, VDN...)
    :param env: an env id (each learner gets ``make_vec_env(env, n_envs)`` of its own, learner ``i`` seeded
        ``seed + i * n_envs``) or a function of the learner's index that returns its vector env; None only to load
    :param k: learners (>= 2)
    :param n_envs: worlds per learner
    :param interval: world ticks, all learners together, between two selections (a selection is due at the end of
        the first round of turns that reaches it)
    :param turn_ticks: world ticks a learner trains before the next one takes its turn (a SIGTERM is answered at
        the end of a turn)
    :param share_buffer: one replay buffer for all learners (CERL) instead of one each
    :param fitness: ``"success"`` (mean team success) or ``"return"`` (mean team return) over a learner's last
        ``fitness_episodes`` finished training episodes; a learner with fewer since its last change sits a selection out
    :param fitness_episodes: episodes (worlds' episodes) per fitness
    :param crossover: ``"copy"`` (PBT's exploit) or ``"distill"``: the weakest becomes the Q-filtered distillation
        of the fittest and the second fittest (:func:`~research.population.distillation.q_filtered_distillation`), started
        from a copy of the fittest
    :param mutation: ``"safe"``: after the copy, a safe mutation (EPS Eq. 6) of the agent network, calibrated to
        change ``target_flip_share`` of its greedy actions on visited states; None: none
    :param target_flip_share: see ``mutation``, in (0, 1)
    :param perturb: hyper-parameters multiplied by a factor drawn from ``perturb_factors`` after a copy
        (``"learning_rate"``, ``"exploration_final_eps"``)
    :param perturb_factors: PBT's factors
    :param distillation_steps: gradient steps of a distillation
    :param log_path: JSON-lines file of the selection records (None: none)
    :param seed: seed of the learners, their worlds and the selection's random draws
    :param verbose: 1 prints a line per selection
    :param algorithm_kwargs: the learners' constructor arguments (``learning_rate``, ``policy_kwargs``...)
    """

    def __init__(
        self,
        algorithm_class: type[MultiAgentOffPolicyAlgorithm],
        env: str | Callable[[int], VecEnv] | None,
        k: int = 4,
        n_envs: int = 1,
        interval: int = 20_000,
        turn_ticks: int = 1_000,
        share_buffer: bool = False,
        fitness: str = "success",
        fitness_episodes: int = 10,
        crossover: str = "copy",
        mutation: str | None = "safe",
        target_flip_share: float = 0.05,
        perturb: Sequence[str] = PERTURBABLE,
        perturb_factors: Sequence[float] = (0.8, 1.2),
        distillation_steps: int = 300,
        env_kwargs: dict[str, Any] | None = None,
        log_path: str | None = None,
        seed: int | None = None,
        verbose: int = 0,
        **algorithm_kwargs: Any,
    ) -> None:
        self.algorithm_class, self.env = algorithm_class, env
        self.settings: dict[str, Any] = {
            "k": k,
            "n_envs": n_envs,
            "interval": interval,
            "turn_ticks": turn_ticks,
            "share_buffer": share_buffer,
            "fitness": fitness,
            "fitness_episodes": fitness_episodes,
            "crossover": crossover,
            "mutation": mutation,
            "target_flip_share": target_flip_share,
            "perturb": list(perturb),
            "perturb_factors": list(perturb_factors),
            "distillation_steps": distillation_steps,
            "env_kwargs": env_kwargs,
            "log_path": log_path,
            "seed": seed,
            "verbose": verbose,
            "algorithm_kwargs": algorithm_kwargs,
        }
        _check(algorithm_class, self.settings)
        self.rng = np.random.default_rng(seed)
        self.generator = th.Generator().manual_seed(int(self.rng.integers(2**62)))
        self.history: list[dict[str, Any]] = []
        self.last_selection_ticks = 0
        self.next_learner = 0
        # the last calibrated mutation scale: the next calibration starts there
        self.scale: float | None = None
        self.interrupted = False
        self._stop_requested = False
        self.learners: list[MultiAgentOffPolicyAlgorithm] = []
        if env is not None:
            self.learners = [
                algorithm_class("MlpPolicy", self._make_env(index), seed=_offset(seed, index), **algorithm_kwargs)
                for index in range(k)
            ]
            if share_buffer:
                for learner in self.learners[1:]:
                    learner.replay_buffer = self.learners[0].replay_buffer

    def _make_env(self, index: int) -> VecEnv:
        if callable(self.env):
            return self.env(index)
        if self.env is None:
            raise ValueError("the population has no env: give env= (an env id or a function of the learner's index)")
        import envs  # noqa: F401  # registers the package's worlds
        from sb3_eps.common.vec_env import make_vec_env

        n_envs = self.settings["n_envs"]
        return make_vec_env(self.env, n_envs, _offset(self.settings["seed"], index * n_envs), self.settings["env_kwargs"])

    # ------------------------------------------------------------------ training
    @property
    def ticks(self) -> int:
        """World ticks of all learners together."""
        return sum(learner.ticks for learner in self.learners)

    def learn(
        self,
        total_ticks: int,
        checkpoint_path: str | Path | None = None,
        callback: BaseCallback | None = None,
        after_turn: Callable[[], bool] | None = None,
    ) -> PopulationTrainer:
        """Train until every learner has its share (``total_ticks // k``) of the run's ``total_ticks`` world ticks (a
        loaded population goes on from where it was). The learners' schedules run over that share: give the run's
        whole total to one call (a call per evaluation mark would run them to their end at every mark).

        :param total_ticks: world ticks of the whole run, all learners together
        :param checkpoint_path: where a SIGTERM during training writes a checkpoint (at the end of the running
            turn; :meth:`load` resumes it exactly); training then returns with ``interrupted`` set
        :param callback: an SB3 callback run in every turn (each turn's ``learn`` initialises it with that turn's
            learner, ``learners[next_learner]``)
        :param after_turn: called after every turn and the selection it made due, where every learner is between two
            of its turns (where a checkpoint resumes exactly); returning False ends training there
        """
        if not isinstance(total_ticks, int | np.integer) or total_ticks < 0:
            raise ValueError(f"total_ticks must be an int >= 0 (world ticks, all learners), got {total_ticks!r}")
        if any(learner.env is None for learner in self.learners):
            raise ValueError("the learners have no env: load the population with env=... to train it")
        share = int(total_ticks) // self.settings["k"]
        previous = signal.signal(signal.SIGTERM, self._request_stop) if checkpoint_path is not None else None
        try:
            while any(learner.ticks < share for learner in self.learners):
                learner = self.learners[self.next_learner]
                remaining = share - learner.ticks
                if remaining > 0:
                    horizon = ScheduleHorizon(learner.timesteps_for_ticks(share))
                    turn = learner.timesteps_for_ticks(min(self.settings["turn_ticks"], remaining))
                    turn_callback = horizon if callback is None else CallbackList([horizon, callback])
                    learner.learn(turn, callback=turn_callback, reset_num_timesteps=False)
                self.next_learner = (self.next_learner + 1) % self.settings["k"]
                if self.next_learner == 0 and self.ticks - self.last_selection_ticks >= self.settings["interval"]:
                    self.select()
                if after_turn is not None and not after_turn():
                    break
                if self._stop_requested:
                    self.save(checkpoint_path, include_training_state=True)  # type: ignore[arg-type]
                    self.interrupted = True
                    break
        finally:
            if checkpoint_path is not None:
                signal.signal(signal.SIGTERM, previous)
        return self

    def _request_stop(self, signum: int, frame: Any) -> None:
        self._stop_requested = True

    # ------------------------------------------------------------------ selection
    def fitness(self) -> tuple[np.ndarray, list[int]]:
        """:return: each learner's fitness (NaN with fewer than ``fitness_episodes`` episodes since its last
        change) and its number of such episodes"""
        key = "success" if self.settings["fitness"] == "success" else "r"
        values, counts = [], []
        for learner in self.learners:
            episodes = list(learner.ep_info_buffer or [])[-self.settings["fitness_episodes"] :]
            if episodes and key not in episodes[0]:
                raise ValueError(
                    "fitness='success' needs episodes with a 'success' flag and this world's have none: use fitness='return'"
                )
            counts.append(len(episodes))
            enough = len(episodes) >= self.settings["fitness_episodes"]
            values.append(float(np.mean([float(episode[key]) for episode in episodes])) if enough else np.nan)
        return np.asarray(values), counts

    def select(self, fitness: Sequence[float] | None = None) -> dict[str, Any]:
        """One selection: copy the fittest learner over the weakest, then perturb the copy.

        :param fitness: the learners' fitnesses (NaN: sits out); None: measured by :meth:`fitness`
        :return: the record (also appended to ``history`` and ``log_path``)
        """
        values, counts = self.fitness() if fitness is None else (np.asarray(fitness, dtype=float), None)
        if values.shape != (len(self.learners),):
            raise ValueError(f"give one fitness per learner ({len(self.learners)}), got {list(values)}")
        record: dict[str, Any] = {
            "ticks": self.ticks,
            "learner_ticks": [learner.ticks for learner in self.learners],
            "fitness": [None if np.isnan(value) else float(value) for value in values],
            "n_episodes": counts,
        }
        ready = np.flatnonzero(np.isfinite(values))
        order = ready[np.argsort(-values[ready], kind="stable")]
        if order.size < 2 or values[order[0]] == values[order[-1]]:
            record["skipped"] = "fewer than 2 learners with fitness" if order.size < 2 else "the fitnesses tie"
        else:
            fittest, weakest = int(order[0]), int(order[-1])
            record.update(fittest=fittest, weakest=weakest, crossover=self.settings["crossover"])
            second = int(order[1])
            distill = self.settings["crossover"] == "distill"
            # The second parent as it is now: with two learners ready it is the weakest, overwritten by the copy.
            second_parent = copy.deepcopy(self.learners[second].policy.q_net) if distill else None
            self._copy(self.learners[fittest], self.learners[weakest])
            if second_parent is not None:
                record["second"] = second
                record["distillation"] = self._distill(weakest, fittest, second, second_parent)
            self._perturb(self.learners[weakest], record)
            if self.settings["mutation"] == "safe":
                record.update(self._mutate(self.learners[weakest]))
        self.last_selection_ticks = self.ticks
        self.history.append(record)
        if self.settings["log_path"]:
            with open(self.settings["log_path"], "a") as file:
                file.write(json.dumps(record) + "\n")
        if self.settings["verbose"]:
            print(f"population selection at {record['ticks']} ticks: {record}")
        return record

    @staticmethod
    def _copy(source: MultiAgentOffPolicyAlgorithm, target: MultiAgentOffPolicyAlgorithm) -> None:
        """Weights, optimizer state (deep copies: the optimizer would keep the source's tensors) and the hyper-
        parameters PBT perturbs; the target's fitness starts afresh from its next episodes."""
        target.set_parameters(copy.deepcopy(source.get_parameters()), exact_match=True)  # type: ignore[arg-type]
        _set_learning_rate(target, source.learning_rate)
        _set_exploration_final_eps(target, source.exploration_final_eps)
        if target.ep_info_buffer is not None:
            target.ep_info_buffer.clear()

    def _perturb(self, learner: MultiAgentOffPolicyAlgorithm, record: dict[str, Any]) -> None:
        """PBT's explore step: each hyper-parameter of ``perturb`` times a factor drawn from ``perturb_factors``."""
        for name in self.settings["perturb"]:
            factor = float(self.rng.choice(self.settings["perturb_factors"]))
            if name == "learning_rate":
                rate = learner.learning_rate
                _set_learning_rate(learner, ScaledSchedule(rate, factor) if callable(rate) else rate * factor)
            else:
                _set_exploration_final_eps(learner, float(np.clip(learner.exploration_final_eps * factor, 0.0, 1.0)))
            record[f"{name}_factor"] = factor

    def _mutate(self, learner: MultiAgentOffPolicyAlgorithm) -> dict[str, Any]:
        """The safe mutation (EPS Eq. 6) of the agent network, its scale calibrated to ``target_flip_share``; the
        target network takes the same step."""
        q_net = learner.policy.q_net
        observations = sample_visited_observations(learner, SENSITIVITY_BATCH_SIZE, self.rng)
        if observations is None:
            return {"mutation": "none: the replay buffer is empty"}
        theta = network_parameters(q_net)
        frozen = [VALUE_STREAM] if any(name.startswith(f"{VALUE_STREAM}.") for name in theta) else []
        sensitivity = output_sensitivity(q_net, observations)
        directions = mutation_directions(
            theta,
            1,
            self.generator,
            [sensitivity],
            _SAFE.sensitivity_floor,
            evolved_parameter_names(q_net, frozen),
        )

        def flip_share_at(scale: float) -> float:
            population = population_from_directions(theta, directions, scale, _SAFE.max_step)
            return float(policy_change(population_outputs(q_net, population, observations))[0][1])

        target_share = self.settings["target_flip_share"]
        self.scale, share = calibrate_scale(flip_share_at, target_share, self.scale or INITIAL_SCALE)
        mutant = individual(population_from_directions(theta, directions, self.scale, _SAFE.max_step), 1)
        target = learner.policy.q_net_target
        with th.no_grad():
            for name, param in q_net.named_parameters():
                param.copy_(mutant[name])
            if target is not None:
                for name, param in target.named_parameters():
                    param.add_(mutant[name] - theta[name])
        return {"mutation_scale": self.scale, "flip_share": share}

    def _distill(self, child: int, fittest: int, second: int, second_parent: th.nn.Module) -> dict[str, Any]:
        """The child (a copy of the fittest) distilled from the fittest and the second fittest (its network as it was
        before the copy) on both parents' replay states; its target and averaged networks restart from the result."""
        parents = [self.learners[fittest].policy.q_net, second_parent]
        sampled = [sample_visited_observations(self.learners[i], DISTILLATION_STATES, self.rng) for i in (fittest, second)]
        observations = th.cat([batch for batch in sampled if batch is not None])
        policy = self.learners[child].policy
        result = q_filtered_distillation(
            policy.q_net, parents, observations, self.settings["distillation_steps"], generator=self.generator
        )
        if policy.q_net_target is not None:
            policy.q_net_target.load_state_dict(policy.q_net.state_dict())
        policy.reset_weight_average()
        return {"teacher_share": result.teacher_share, "agreement": result.agreement, "loss": result.loss}

    @property
    def best(self) -> MultiAgentOffPolicyAlgorithm:
        """The learner of the highest fitness now (learner 0 while none has ``fitness_episodes`` episodes)."""
        values, _ = self.fitness()
        return self.learners[int(np.argmax(np.where(np.isfinite(values), values, -np.inf)))]

    # ------------------------------------------------------------------ saving
    def save(self, path: str | Path, include_training_state: bool = False) -> None:
        """Write the population to one zip archive, atomically: every learner's ``save``, the trainer's settings,
        schedule, generators and selection records; with ``include_training_state`` also the learners' replay
        buffers, n-step windows and worlds mid-episode, and the global random states (a checkpoint that
        :meth:`load` resumes exactly; a pickle: load only your own)."""
        algorithm = f"{self.algorithm_class.__module__}:{self.algorithm_class.__qualname__}"
        state = {
            "algorithm": algorithm,
            "settings": self.settings,
            "rng": self.rng,
            "generator": self.generator.get_state(),
            "last_selection_ticks": self.last_selection_ticks,
            "next_learner": self.next_learner,
            "scale": self.scale,
        }
        members = {"population.json": json.dumps({"algorithm": algorithm, "history": self.history}).encode()}
        members["trainer.pkl"] = pickle.dumps(state)
        for index, learner in enumerate(self.learners):
            buffer = io.BytesIO()
            learner.save(buffer)
            members[f"learner_{index}.zip"] = buffer.getvalue()
        if include_training_state:
            # One pickle: a shared buffer stays shared, and each n-step collector keeps pointing at its buffer.
            rollouts = [{**learner.rollout_state(), "env": learner.env} for learner in self.learners]
            members["training.pkl"] = snapshot_dumps(rollouts)
            members["rng.pkl"] = pickle.dumps(rng_states())
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        os.close(handle)
        try:
            with zipfile.ZipFile(temporary, "w") as archive:
                for name, data in members.items():
                    archive.writestr(name, data)
            os.replace(temporary, path)
        finally:
            if os.path.exists(temporary):
                os.remove(temporary)

    @classmethod
    def load(
        cls, path: str | Path, env: str | Callable[[int], VecEnv] | None = None, device: str = "auto"
    ) -> PopulationTrainer:
        """Read what :meth:`save` wrote. A checkpoint (``include_training_state``) comes back with its worlds and
        buffers, ready to go on with ``learn``; otherwise the learners get ``env`` (new worlds, empty buffers) or,
        with None, no env (``predict`` only)."""
        with zipfile.ZipFile(path) as archive:
            members = {name: archive.read(name) for name in archive.namelist()}
        state = pickle.loads(members["trainer.pkl"])
        module, name = state["algorithm"].split(":")
        algorithm_class = getattr(importlib.import_module(module), name)
        settings = dict(state["settings"])
        trainer = cls(algorithm_class, None, **{**settings.pop("algorithm_kwargs"), **settings})
        trainer.env = env
        trainer.rng, trainer.scale = state["rng"], state["scale"]
        trainer.generator.set_state(state["generator"])
        trainer.last_selection_ticks, trainer.next_learner = (
            state["last_selection_ticks"],
            state["next_learner"],
        )
        trainer.history = json.loads(members["population.json"])["history"]
        rollouts = pickle.loads(members["training.pkl"]) if "training.pkl" in members else None
        for index in range(settings["k"]):
            learner = algorithm_class.load(io.BytesIO(members[f"learner_{index}.zip"]), env=None, device=device)
            if rollouts is not None:  # set_env without a reset keeps the saved last observations
                learner.set_env(rollouts[index]["env"], force_reset=False)
                learner.set_rollout_state(rollouts[index])
            elif env is not None:
                learner.set_env(trainer._make_env(index))
            trainer.learners.append(learner)
        if "rng.pkl" in members:  # after the loads, which re-seed the global generators
            set_rng_states(pickle.loads(members["rng.pkl"]))
        return trainer


def _offset(seed: int | None, offset: int) -> int | None:
    return None if seed is None else seed + offset


def _set_learning_rate(learner: MultiAgentOffPolicyAlgorithm, rate: float | Callable[[float], float]) -> None:
    learner.learning_rate = rate
    learner.lr_schedule = FloatSchedule(rate)


def _set_exploration_final_eps(learner: MultiAgentOffPolicyAlgorithm, final_eps: float) -> None:
    learner.exploration_final_eps = final_eps
    learner.exploration_schedule = LinearSchedule(learner.exploration_initial_eps, final_eps, learner.exploration_fraction)


def _check(algorithm_class: Any, settings: dict[str, Any]) -> None:
    """Each a one-line ``ValueError`` that says what to change."""
    if not (isinstance(algorithm_class, type) and issubclass(algorithm_class, MultiAgentOffPolicyAlgorithm)):
        raise ValueError(
            f"algorithm_class must be GDQ, IQL, QMIX, VDN or another MultiAgentOffPolicyAlgorithm, got {algorithm_class!r}"
        )
    for name, low in (
        ("k", 2),
        ("n_envs", 1),
        ("interval", 1),
        ("turn_ticks", 1),
        ("fitness_episodes", 1),
        ("distillation_steps", 1),
    ):
        value = settings[name]
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < low:
            raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
    for name, allowed in (("fitness", FITNESS_KINDS), ("crossover", CROSSOVERS), ("mutation", MUTATIONS)):
        if settings[name] not in allowed:
            raise ValueError(f"{name} must be one of {allowed}, got {settings[name]!r}")
    if not isinstance(settings["share_buffer"], bool):
        raise ValueError(f"share_buffer must be True or False, got {settings['share_buffer']!r}")
    if not 0.0 < settings["target_flip_share"] < 1.0:
        raise ValueError(f"target_flip_share must be in (0, 1), got {settings['target_flip_share']!r}")
    window = settings["algorithm_kwargs"].get("stats_window_size", 100)
    if settings["fitness_episodes"] > window:
        raise ValueError(
            f"fitness_episodes ({settings['fitness_episodes']}) exceeds the episodes a learner keeps "
            f"(stats_window_size={window}): lower it or raise stats_window_size"
        )
    unknown = sorted(set(settings["perturb"]) - set(PERTURBABLE))
    if unknown:
        raise ValueError(f"perturb names {unknown}; the hyper-parameters it can perturb are {PERTURBABLE}")
    factors = settings["perturb_factors"]
    if not factors or not all(isinstance(factor, float | int) and factor > 0 for factor in factors):
        raise ValueError(f"perturb_factors must be numbers > 0, got {factors!r}")
