"""``EvolutionCallback``: SB3's hooks of EPS. What a round does is :class:`~sb3_eps.eps.round.EPSRound`, when it may
start :class:`~sb3_eps.eps.budget.RoundBudget`, what it records :class:`~sb3_eps.eps.round_log.RoundRecords`."""

from __future__ import annotations

import copy
import os
import time
import warnings
import weakref
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from torch import nn

from sb3_eps.common.parallel_wrappers import ticks_per_step
from sb3_eps.eps.budget import RoundBudget, model_ticks
from sb3_eps.eps.evaluation import (
    EnvPool,
    EvaluationBlock,
    EvaluationFailed,
    agent_space,
    eval_env_geometry,
    make_eval_env,
)
from sb3_eps.eps.mutations import evolved_parameter_names
from sb3_eps.eps.round import EPSRound, sample_visited_observations, visited_mask
from sb3_eps.eps.round_log import RoundRecords
from sb3_eps.eps.settings import PAPER_SETTINGS, EPSSettings

__all__ = ["PAPER_SETTINGS", "EvolutionCallback", "sample_visited_observations"]

#: World options EPS's evaluation world takes from the training worlds (the vec env's ``env_kwargs``) when
#: ``eval_env_kwargs`` does not set them: what a robot sees must be the same in both (``docs/modules/eps.md``).
SHARED_WORLD_OPTIONS = (
    "lidar_range",
    "lidar_frames",
    "lidar_frame_ticks",
    "lidar_noise_std",
    "collision_reward",
    "path_guidance",
    "path_clearance",
    "path_lookahead",
)
#: The dueling network's state-value stream: greedy actions (hence fitness) never see it, GDQ feeds it to V_G'.
VALUE_STREAM = "value_stream"


class EvolutionCallback(BaseCallback):
    """Evolutionary Policy Search (EPS; Marchesini & Farinelli, "Enhancing Deep Reinforcement Learning
    Approaches for Multi-Robot Navigation via Single-Robot Evolutionary Policy Search", ICRA 2022, Algorithm 1).

    A round, at the end of a rollout (before the gradient steps): copy the shared agent network
    ``model.policy.q_net`` ``population_size + 1`` times; mutate all copies but copy 0 with Gaussian noise
    normalised by the output-gradient sensitivity of Eq. 6 (computed on visited observations from the replay
    buffer); evaluate every copy greedily for ``n_eval_episodes`` common-random-number episodes in independent
    single-agent worlds; pick the best (Eq. 4) and move the agent network (and its target network, if any) toward it
    by Polyak averaging (Eq. 5). When the unmutated copy 0 wins nothing changes. See ``docs/modules/eps.md``.

    Where it was measured (2 to 12 robots and the unseen room, with GDQ and IQL), EPS has not been found to help
    (``docs/modules/eps.md``, "Where EPS was tested, and what it did").

    Rounds come only while the tick budget (``max_eps_share``) allows them, the first near 80k training ticks; a
    shorter run plays none and warns once, saying what to change (``docs/modules/eps.md``, "Getting rounds in a short
    run, and early rounds").

    :param settings: the method's settings (:class:`~sb3_eps.eps.settings.EPSSettings`, every argument documented
        there; :meth:`paper` for Algorithm 1 as published). Default: built from ``settings_kwargs``
    :param verbose: 0 silent, 1 one line per round, 2 also worker restarts
    :param settings_kwargs: fields of :class:`~sb3_eps.eps.settings.EPSSettings` (as a config lists them), when
        ``settings`` is not given

    A subclass plugs in variants of the method: its own settings (``settings_class``, a subclass of
    :class:`~sb3_eps.eps.settings.EPSSettings`), rounds (``round_class``) and evaluation blocks (``block_class``);
    ``research/eps_variants.py`` is one.
    """

    model: Any  # the multi-agent attributes (n_agents, replay_buffer) are not on SB3's BaseAlgorithm type
    settings_class: type[EPSSettings] = EPSSettings
    round_class: type[EPSRound] = EPSRound
    block_class: type[EvaluationBlock] = EvaluationBlock

    def __init__(self, settings: EPSSettings | None = None, verbose: int = 0, **settings_kwargs: Any) -> None:
        super().__init__(verbose=verbose)
        name = self.settings_class.__name__
        if not isinstance(settings, self.settings_class | None):
            raise TypeError(f"settings must be an {name} or None, got {settings!r} (the world is eval_env_id=...)")
        if settings is not None and settings_kwargs:
            raise ValueError(f"give {type(self).__name__} either settings or keyword arguments of {name}, not both")
        self.settings = settings if settings is not None else self.settings_class(**settings_kwargs)
        self.budget = RoundBudget(self.settings)
        self.records = RoundRecords(verbose)
        self.round: EPSRound | None = None
        self._eps_ticks = 0  # before init_callback made the round
        self._pool_finalizer: weakref.finalize | None = None
        self._state: dict[str, Any] | None = None  # a state_dict loaded before init_callback
        self._training_start = 0.0
        self._warned_no_round = False

    @classmethod
    def paper(cls, **kwargs: Any) -> EvolutionCallback:
        """Algorithm 1 as published: :data:`~sb3_eps.eps.settings.PAPER_SETTINGS`, updated by ``kwargs``.

        :param kwargs: any field of :class:`~sb3_eps.eps.settings.EPSSettings` (``EvolutionCallback.paper(alpha=0.2)``),
            or ``verbose``
        """
        verbose = kwargs.pop("verbose", 0)
        return cls(cls.settings_class.paper(**kwargs), verbose=verbose)

    # ------------------------------------------------------------------ what a run reads
    @property
    def eps_ticks(self) -> int:
        """Cumulative ticks simulated in EPS evaluation (add to the training ticks in plots)."""
        return self.round.eps_ticks if self.round is not None else self._eps_ticks

    @property
    def history(self) -> list[dict[str, Any]]:
        """One record per round (see docs/modules/eps.md, "The round record"); also in ``diagnostics_path``."""
        return self.records.history

    @property
    def n_rounds(self) -> int:
        return self.records.n_rounds

    @property
    def n_skipped_rounds(self) -> int:
        return self.records.n_skipped_rounds

    @property
    def n_crossovers(self) -> int:
        """Rounds whose winner was crossed over into the model (of the ``n_rounds`` played)."""
        return self.records.n_crossovers

    @property
    def worker_pids(self) -> list[int]:
        """Process ids of the evaluation workers (empty when the envs run in the main process or are closed)."""
        pool = self.round.pool if self.round is not None else None
        return pool.pids if pool is not None else []

    @property
    def evolved_parameters(self) -> list[str]:
        """Names of the ``q_net`` parameters that EPS mutates and crosses over (known after ``init_callback``)."""
        return list(self.round.evolved) if self.round is not None else []

    def state_dict(self) -> dict[str, Any]:
        """The training state (counters, records, generators, calibrated scale), for checkpoints."""
        round_ = self.round
        return {
            "eps_ticks": self.eps_ticks,
            "n_rounds": self.records.n_rounds,
            "n_skipped_rounds": self.records.n_skipped_rounds,
            "eps_time": self.records.eps_time,
            "history": copy.deepcopy(self.records.history),
            "scale": round_.scale if round_ is not None else None,
            "rng": copy.deepcopy(round_.rng) if round_ is not None else None,
            "generator": round_.generator.get_state() if round_ is not None else None,
            "last_round_mark": self.budget.last_round_mark,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` (before or after ``init_callback``)."""
        self.records.n_rounds = int(state["n_rounds"])
        self.records.n_skipped_rounds = int(state["n_skipped_rounds"])
        self.records.eps_time = float(state["eps_time"])
        self.records.history = copy.deepcopy(state["history"])
        self.budget.last_round_mark = state["last_round_mark"]
        self._eps_ticks = int(state["eps_ticks"])
        self._state = state
        if self.round is not None:
            self._restore_round()

    def _restore_round(self) -> None:
        assert self.round is not None and self._state is not None
        state, self._state = self._state, None
        self.round.eps_ticks = int(state["eps_ticks"])
        self.round.scale = state["scale"]
        if state["rng"] is not None:
            self.round.rng = copy.deepcopy(state["rng"])
        if state["generator"] is not None:
            self.round.generator.set_state(state["generator"])

    # ------------------------------------------------------------------ SB3 hooks
    def _init_callback(self) -> None:
        q_net = self._check_model()
        self._check_eval_env()
        if self.round is None:
            frozen = self.settings.frozen_groups
            if frozen is None:  # the dueling value stream when there is one
                names = [name for name, _ in q_net.named_parameters()]
                frozen = [VALUE_STREAM] if any(name.startswith(f"{VALUE_STREAM}.") for name in names) else []
            seed = self.settings.seed if self.settings.seed is not None else getattr(self.model, "seed", None)
            rng = np.random.default_rng(seed)
            generator = th.Generator(device=next(q_net.parameters()).device)
            generator.manual_seed(int(rng.integers(2**62)))
            evolved = evolved_parameter_names(q_net, frozen)
            self.round = self.round_class(self.settings, self.model, evolved, rng, generator)
            self.round.eps_ticks = self._eps_ticks
        if self._state is not None:
            self._restore_round()
        self.records.open(self.settings.diagnostics_path, getattr(self.model, "_logger", None))
        self._start_pool()
        self.budget.start(self.model)
        self._training_start = time.perf_counter()

    def _on_training_start(self) -> None:
        total_timesteps = self.locals.get("total_timesteps")
        if total_timesteps is None or self._warned_no_round:
            return
        # A step moves every agent of a world and advances it ticks_per_step ticks (its action_repeat).
        agents, ticks = int(getattr(self.model, "n_agents", 1)), int(getattr(self.model, "ticks_per_step", 1))
        start, end = model_ticks(self.model), int(total_timesteps) // agents * ticks
        reason = self.budget.why_no_round(self.eps_ticks, start, end, self.history)
        if reason is not None:
            self._warned_no_round = True
            warnings.warn(f"EvolutionCallback will play no EPS round in this run: {reason}", UserWarning, stacklevel=2)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        # The rollout has been stored and the episodes counted; the gradient steps come next.
        if not self.budget.due(self.model):
            return
        if not self.budget.within(self.eps_ticks, model_ticks(self.model), self.history):
            return
        if not visited_mask(self.model.replay_buffer).any():
            return  # nothing visited yet: Eq. 6 and the calibration need states; try after the next rollout
        self.budget.mark(self.model)
        self._run_round()

    def _on_training_end(self) -> None:
        self._close_pool()

    # ------------------------------------------------------------------ one round
    def _run_round(self) -> None:
        assert self.round is not None
        start, ticks_before = time.perf_counter(), self.round.eps_ticks
        try:
            record = self.round.run()
        except EvaluationFailed as error:
            self._skip_round(error, time.perf_counter() - start, error.record or {})
            return
        wall_time, ticks_spent = time.perf_counter() - start, self.round.eps_ticks - ticks_before
        record = self.records.played(record, wall_time, ticks_spent, self._counters())
        elapsed = time.perf_counter() - self._training_start
        totals = {**self._counters(), "time_share": self.records.eps_time / elapsed if elapsed > 0 else 0.0}
        self.records.log(self.logger, record, totals)

    def _counters(self) -> dict[str, Any]:
        assert self.round is not None
        return {"model_ticks": model_ticks(self.model), "eps_ticks": self.round.eps_ticks}

    def _skip_round(self, error: EvaluationFailed, wall_time: float, record: dict[str, Any]) -> None:
        self.records.skipped(str(error), wall_time, record.get("round_ticks", 0), self._counters())
        warnings.warn(f"EPS round skipped, restarting the evaluation workers: {error}", RuntimeWarning, stacklevel=2)
        self.logger.record("eps/skipped_rounds", self.n_skipped_rounds)
        self._close_pool()
        self._start_pool()
        if self.verbose >= 2:
            print(f"EPS: evaluation workers restarted (pids {self.worker_pids})")

    # ------------------------------------------------------------------ the evaluation workers
    def _start_pool(self) -> None:
        assert self.round is not None
        settings = self.settings
        # The workers get the architecture only (a CPU copy); each round sends them the weights.
        template = copy.deepcopy(self.model.policy.q_net).to("cpu")
        arguments = (settings.eval_env_id, settings.eval_env_kwargs, settings.n_individuals, settings.n_eval_episodes)
        # A worker evaluates whole individuals, so more workers than individuals would idle.
        n_workers = (os.cpu_count() or 1) if settings.n_workers is None else settings.n_workers
        mask = getattr(self.model.policy, "safety_mask", None)  # mutants act through it, as the model does
        pool = EnvPool(
            *arguments,
            template,
            n_workers=min(n_workers, settings.n_individuals),
            block_class=self.block_class,
            safety_margin=None if mask is None else mask.margin,
        )
        self.round.pool = pool
        # Close the workers even when training dies with an exception (no _on_training_end then).
        self._pool_finalizer = weakref.finalize(self, pool.close)

    def _close_pool(self) -> None:
        if self._pool_finalizer is not None:
            self._pool_finalizer()  # calls pool.close() once
        self._pool_finalizer = None
        if self.round is not None:
            self.round.pool = None

    # ------------------------------------------------------------------ checks
    def _check_model(self) -> nn.Module:
        """The model needs a shared agent network and a replay buffer of visited observations."""
        policy = getattr(self.model, "policy", None)
        q_net = getattr(policy, "q_net", None)
        if not isinstance(q_net, nn.Module):
            raise ValueError(
                f"EvolutionCallback needs a model with a shared agent network at model.policy.q_net "
                f"(IQL, GDQ, QMIX, VDN or SB3's DQN); {type(self.model).__name__} has none"
            )
        buffer = getattr(self.model, "replay_buffer", None)
        if buffer is None or not hasattr(buffer, "observations") or not hasattr(buffer, "size"):
            raise ValueError(
                f"EvolutionCallback samples visited observations from model.replay_buffer; "
                f"{type(self.model).__name__} has no replay buffer: use an off-policy model (IQL, GDQ, QMIX, VDN)"
            )
        return q_net

    def _match_training_world(self) -> int:
        """Give the evaluation world the training worlds' decision rate and view: ``action_repeat`` (the model's
        ``ticks_per_step``) and the options of :data:`SHARED_WORLD_OPTIONS` the training vec env was made with,
        unless ``eval_env_kwargs`` sets them (a different value is an error: the mutants would be judged on another
        robot). :return: the ticks each decision is held"""
        ticks = int(getattr(self.model, "ticks_per_step", 1))
        training = dict(getattr(self.model.get_env(), "env_kwargs", None) or {})
        wanted = {key: training[key] for key in SHARED_WORLD_OPTIONS if key in training}
        if ticks != 1:
            wanted["action_repeat"] = ticks
        kwargs = self.settings.eval_env_kwargs
        assert kwargs is not None  # EPSSettings fills it in
        for key, value in wanted.items():
            if key in kwargs and kwargs[key] != value:
                raise ValueError(
                    f"eval_env_kwargs {key}={kwargs[key]!r} but the model's worlds have {key}={value!r}: EPS must "
                    f"evaluate the robots as they train; drop {key} from eval_env_kwargs or set it to {value!r}"
                )
            kwargs.setdefault(key, value)
        return ticks

    def _check_eval_env(self) -> None:
        """The evaluation world must speak the model's language: equal observation and action spaces
        (:meth:`_check_eval_world`)."""
        ticks = self._match_training_world()
        try:
            env = make_eval_env(self.settings.eval_env_id, self.settings.eval_env_kwargs)
        except TypeError as error:
            raise ValueError(
                f"eval_env_kwargs {self.settings.eval_env_kwargs} do not fit {self.settings.eval_env_id!r}: {error}"
            ) from None
        if ticks_per_step(env) != ticks:
            env.close()
            raise ValueError(
                f"the model's worlds hold each decision for {ticks} ticks but eval_env_id "
                f"{self.settings.eval_env_id!r} holds it for {ticks_per_step(env)}: give it action_repeat={ticks}"
            )
        spec_limit = env.spec.max_episode_steps if env.spec is not None else None
        limit = getattr(env, "max_episode_steps", None) or getattr(env, "max_cycles", None) or spec_limit
        self.budget.episode_limit = int(limit or 0)
        try:
            for kind in ("observation_space", "action_space"):
                ours, theirs = agent_space(env, kind), getattr(self.model, kind)
                if ours != theirs:
                    raise ValueError(
                        f"the {kind} of eval_env_id {self.settings.eval_env_id!r} ({ours}) differs from the model's "
                        f"({theirs}): pick the evaluation world that matches the training env "
                        "(sb3_eps.eps.eps_env_id_for(training env id))"
                    )
            self._check_safety_geometry(env)
            self._check_eval_world(env)
        finally:
            env.close()

    def _check_safety_geometry(self, env: Any) -> None:
        """A model with a lidar mask: the EPS world's lidar and actions must be the training worlds' (its mutants act
        through the same mask)."""
        policy = self.model.policy
        if getattr(policy, "safety_mask", None) is None:
            return
        geometry = eval_env_geometry(env, self.settings.eval_env_id)
        if geometry != policy.safety_geometry:
            differ = sorted(key for key in geometry if geometry[key] != policy.safety_geometry.get(key))
            raise ValueError(
                f"the lidar mask's geometry of eval_env_id {self.settings.eval_env_id!r} differs from the model's in "
                f"{', '.join(differ)}: give it the training worlds' lidar and decision options"
            )

    def _check_eval_world(self, env: Any) -> None:
        """A subclass's checks of the evaluation world (built with ``eval_env_kwargs``); raise ``ValueError``."""
