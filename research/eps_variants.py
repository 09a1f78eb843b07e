"""EPS options that research measured and the package does not ship (``docs/modules/eps.md``, "Research variants"):
an :class:`~sb3_eps.eps.callback.EvolutionCallback` subclass that plugs them in through the callback's settings, round
and evaluation-block classes.

- ``share_experience``: every tick of every evaluation episode becomes a replay row of the learner, as in
  Evolutionary RL (Khadka & Tumer, NeurIPS 2018); needs a team world with the training worlds' agents. Measured
  -2.7 points against GDQ on 4 robots (``docs/results/eps.md``, "A team world for fitness and shared experience").
- ``n_team_check_episodes``: greedy episodes of the training world before and after every crossover, same seeds
  (a diagnostic of what a crossover does; ``benchmarks/crossover_effects.py`` reads it).
- ``per_robot``: mutant ``i`` normalised by robot ``i % n_agents``'s own sensitivity (paper III-B).

From Python, ``ResearchEvolutionCallback(eval_env_id="MultiRobotNav-4-v0", share_experience=True)``; in a config,
``callback: research.eps_variants.ResearchEvolutionCallback`` with
``python -m sb3_eps.train --algo eps_gdq --gym-packages research.eps_variants ...``
(``research/zoo_configs/eps_gdq_team_share.yml``).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from torch import nn

from sb3_eps.common.buffers import JointTick, NStepJointCollector
from sb3_eps.common.evaluation import evaluate_team
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.common.parallel_wrappers import TeamAsGymnasium, TeamTick
from sb3_eps.common.utils import check_arguments
from sb3_eps.eps.callback import SHARED_WORLD_OPTIONS, EvolutionCallback
from sb3_eps.eps.evaluation import EvaluationBlock, PopulationResult
from sb3_eps.eps.mutations import Parameters, output_sensitivity
from sb3_eps.eps.round import EPSRound
from sb3_eps.eps.settings import EPSSettings
from sb3_eps.zoo import register_callback

RANGES = {"n_team_check_episodes": "[0, inf)"}


@dataclass
class ResearchEPSSettings(EPSSettings):
    """:class:`~sb3_eps.eps.settings.EPSSettings` plus the research options.

    :param n_team_check_episodes: greedy episodes of the training world played before and after every crossover
        with the same seeds (counted as EPS ticks); 0: no check
    :param per_robot: normalise mutant ``i`` by robot ``i % n_agents``'s own sensitivity (paper III-B); needs
        ``mutation="safe"``
    :param share_experience: write every tick of every evaluation episode into the model's replay buffer
        (Evolutionary RL, Khadka & Tumer, NeurIPS 2018); needs a team world with the training world's agents
    """

    n_team_check_episodes: int = 0
    per_robot: bool = False
    share_experience: bool = False

    def __post_init__(self) -> None:
        own = {field.name: getattr(self, field.name) for field in dataclasses.fields(self) if field.name in OWN_FIELDS}
        check_arguments(ResearchEPSSettings, own, RANGES)
        if self.per_robot and self.mutation != "safe":
            raise ValueError("per_robot=True chooses each mutant's sensitivity: it needs mutation='safe'")
        super().__post_init__()

    @property
    def most_episodes_per_round(self) -> int:
        """Every episode a round may play: selection, reevaluation (both individuals) and team checks."""
        return super().most_episodes_per_round + 2 * self.n_team_check_episodes


OWN_FIELDS = ("n_team_check_episodes", "per_robot", "share_experience")


# ---------------------------------------------------------------------------------------------- experience sharing
@dataclass
class TeamEpisode:
    """Every tick of one team-world episode (``T`` ticks, ``n`` agents): observations and global states
    ``(T + 1, ...)`` (before every tick and after the last; states ``(T + 1, 0)`` when not recorded), the rest
    ``(T, n)`` as :class:`~sb3_eps.common.parallel_wrappers.TeamTick`."""

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    alive: np.ndarray
    states: np.ndarray


class _EpisodeRecorder:
    """Collects the ticks of one team-world episode as it is played (:class:`TeamEpisode`)."""

    def __init__(self, env: TeamAsGymnasium, first_obs: np.ndarray, record_states: bool) -> None:
        self.env, self.record_states = env, record_states
        self.observations = [first_obs]
        self.states = [env.state()] if record_states else []
        self.actions: list[np.ndarray] = []
        self.ticks: list[TeamTick] = []

    def add(self, action: np.ndarray, next_obs: np.ndarray) -> None:
        assert self.env.last_tick is not None
        self.actions.append(np.asarray(action, dtype=np.int64))
        self.ticks.append(self.env.last_tick)
        self.observations.append(np.array(next_obs, dtype=np.float32))
        if self.record_states:
            self.states.append(self.env.state())

    def episode(self) -> TeamEpisode:
        """The episode played (at least one tick: an individual that stops early records none)."""
        n_ticks = len(self.actions)
        states = np.stack(self.states) if self.record_states else np.zeros((n_ticks + 1, 0), dtype=np.float32)
        ticks = TeamTick(*(np.stack(column) for column in zip(*self.ticks)))
        return TeamEpisode(np.stack(self.observations), np.stack(self.actions), *ticks, states=states)


class RecordingBlock(EvaluationBlock):
    """An evaluation block that records every tick of its team-world episodes (:class:`TeamEpisode`)."""

    record_states = False
    recorders: list[_EpisodeRecorder]

    def start_recording(self, obs: np.ndarray, active: np.ndarray) -> None:
        self.recorders = [  # team worlds only (checked by the callback)
            _EpisodeRecorder(env, obs[index].copy(), self.record_states and bool(active[index]))  # type: ignore[arg-type]
            for index, env in enumerate(self.envs)
        ]

    def record_step(self, index: int, action: Any, next_obs: np.ndarray) -> None:
        self.recorders[index].add(np.asarray(action), next_obs)

    def recorded(self, valid: np.ndarray) -> list[Any] | None:
        # An individual stopped for non-finite outputs left unfinished episodes: none.
        played = np.repeat(valid, self.n_episodes)
        return [recorder.episode() if played[index] else None for index, recorder in enumerate(self.recorders)]


class StateRecordingBlock(RecordingBlock):
    """:class:`RecordingBlock` that also records the global states (for algorithms that store them: QMIX)."""

    record_states = True


def sharing_problem(model: Any, eval_env: Any) -> str | None:
    """Why the episodes of ``eval_env`` (:func:`~sb3_eps.eps.evaluation.make_eval_env`) cannot become ``model``'s
    replay rows, or None when they can."""
    if not isinstance(model, MultiAgentOffPolicyAlgorithm):
        return f"share_experience writes joint replay rows: it needs IQL, GDQ, QMIX or VDN, not {type(model).__name__}"
    team_size = int(getattr(eval_env, "team_size", 0))
    if not team_size:
        return (
            "share_experience needs a team world as eval_env_id (a multi-agent id such as 'MultiRobotNav-4-v0', "
            "whose robots act as in training); a single-agent world's ticks are no rows of the training worlds"
        )
    if team_size != model.n_agents:
        return (
            f"share_experience needs a team world with the training worlds' {model.n_agents} agents; the evaluation "
            f"world has {team_size}: use the training env id as eval_env_id"
        )
    state_dim = int(np.prod(eval_env.state_space.shape))
    if state_dim != model.state_dim:
        return (
            f"share_experience needs the training worlds' global state ({model.state_dim} entries); the evaluation "
            f"world's has {state_dim}: use the training env id (and its env_kwargs) for the evaluation world"
        )
    return None


def share_episodes(model: MultiAgentOffPolicyAlgorithm, episodes: Sequence[TeamEpisode | None]) -> int:
    """Write every tick of ``episodes`` (None entries skipped) into ``model.replay_buffer`` as the training rollout
    writes a world's ticks, non-finite ticks refused as in training. :return: the rows written"""
    played = [episode for episode in episodes if episode is not None and len(episode.actions)]
    if not played:
        return 0
    assert model.replay_buffer is not None
    n_rows = 0
    for episode in played:
        collector = NStepJointCollector(model.replay_buffer, 1, model.n_steps, model.gamma, model.team_reward_mode)
        for tick in range(len(episode.actions)):
            if not _finite_tick(episode, tick):
                collector.pending[0].clear()
                warnings.warn(
                    "EPS experience sharing: a team-world tick with a non-finite observation or reward is not stored",
                    RuntimeWarning,
                    stacklevel=2,
                )
                continue
            collector.add(0, _episode_tick(episode, tick))
        n_rows += collector.n_rows
    return n_rows


def _episode_tick(episode: TeamEpisode, tick: int) -> JointTick:
    """Tick ``tick`` of a team-world episode as the bridge would report it (``MultiAgentVecEnv.step_wait``)."""
    terminations, truncations, alive = (
        episode.terminations[tick],
        episode.truncations[tick],
        episode.alive[tick],
    )
    dones = terminations | truncations
    return JointTick(
        observations=episode.observations[tick],
        actions=episode.actions[tick],
        rewards=episode.rewards[tick],
        next_observations=episode.observations[tick + 1],
        ended=dones & alive,
        truncated=truncations & ~terminations,
        alive=alive,
        state=episode.states[tick],
        next_state=episode.states[tick + 1],
        world_ended=bool(dones.all()),
    )


def _finite_tick(episode: TeamEpisode, tick: int) -> bool:
    return bool(np.isfinite(episode.observations[tick : tick + 2]).all() and np.isfinite(episode.rewards[tick]).all())


# ---------------------------------------------------------------------------------------------- the round
class ResearchEPSRound(EPSRound):
    """:class:`~sb3_eps.eps.round.EPSRound` with the research options of :class:`ResearchEPSSettings`."""

    settings: ResearchEPSSettings

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.shared_rows = 0  # replay rows written from the evaluation episodes, all rounds together
        self.round_shared_rows = 0

    def run(self) -> dict[str, Any]:
        self.round_shared_rows = 0
        record = super().run()
        record["shared_rows"] = self.round_shared_rows
        return record

    def play(self, population: Parameters, active: np.ndarray | None = None) -> tuple[list[int], PopulationResult]:
        seeds, result = super().play(population, active)
        if self.settings.share_experience and result.episodes is not None:
            rows = share_episodes(self.model, result.episodes)  # before any crossover: the round's network
            self.round_shared_rows += rows
            self.shared_rows += rows
            result.episodes = None  # the arrays are in the buffer now
        return seeds, result

    def cross_over(self, best: Parameters, alpha: float, record: dict[str, Any]) -> float:
        self._team_check(record, "before")
        delta = super().cross_over(best, alpha, record)
        self._team_check(record, "after")
        return delta

    def _team_check(self, record: dict[str, Any], when: str) -> None:
        """Greedy episodes of the training env, same seeds before and after the crossover (optional)."""
        n_episodes = self.settings.n_team_check_episodes
        if n_episodes == 0:
            return
        env_id = self.model.get_env().env_id
        if when == "before":
            record["team_check_seed"] = int(self.rng.integers(2**31 - 1))
        # The online network, the one the crossover changed (a kept weight average, GDQ's default, follows it only
        # slowly): policies explore only through the algorithm, so their non-deterministic actions are its argmax.
        summary = evaluate_team(
            self.model.policy, env_id, n_episodes, n_envs=1, deterministic=False, seed=record["team_check_seed"]
        )
        ticks = int(sum(episode["l"] for episode in summary["episodes"]))
        self.eps_ticks += ticks
        record[f"team_success_{when}"] = summary.get("success_rate", float("nan"))
        record[f"team_return_{when}"] = summary["team_return_mean"]
        record["team_check_ticks"] = record.get("team_check_ticks", 0) + ticks

    def sensitivities(self, q_net: nn.Module, observations: th.Tensor) -> list[Parameters]:
        """Eq. 6 on a batch of visited observations: one for all mutants, or one per robot (``per_robot``)."""
        population_size = self.settings.population_size
        if not self.settings.per_robot:
            return super().sensitivities(q_net, observations)
        # Mutant i follows robot i % n: the paper's m = n when population_size = n_agents.
        n_agents = int(self.model.n_agents)
        robots = sorted({index % n_agents for index in range(population_size)})
        by_robot: dict[int, Parameters] = {}
        for robot in robots:  # a robot without an alive entry yet takes every robot's states
            robot_observations = self.visited_observations(robot)
            if robot_observations is None:
                robot_observations = self.visited_observations(None)
            assert robot_observations is not None
            by_robot[robot] = output_sensitivity(q_net, robot_observations)
        return [by_robot[index % n_agents] for index in range(population_size)]


# ---------------------------------------------------------------------------------------------- the callback
class ResearchEvolutionCallback(EvolutionCallback):
    """:class:`~sb3_eps.eps.callback.EvolutionCallback` with the research options (:class:`ResearchEPSSettings`).

    :param settings: the settings; default: built from ``settings_kwargs``
    :param verbose: as ``EvolutionCallback``
    :param settings_kwargs: fields of :class:`ResearchEPSSettings`, when ``settings`` is not given
    """

    settings: ResearchEPSSettings
    round: ResearchEPSRound | None
    settings_class = ResearchEPSSettings
    round_class = ResearchEPSRound

    def __init__(self, settings: ResearchEPSSettings | None = None, verbose: int = 0, **settings_kwargs: Any) -> None:
        super().__init__(settings, verbose, **settings_kwargs)

    @property
    def shared_rows(self) -> int:
        """Replay rows written from the evaluation episodes (``share_experience``), all rounds together."""
        return self.round.shared_rows if self.round is not None else 0

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "shared_rows": self.shared_rows}

    def _restore_round(self) -> None:
        assert self.round is not None and self._state is not None
        self.round.shared_rows = int(self._state.get("shared_rows", 0))
        super()._restore_round()

    def _init_callback(self) -> None:
        if self.settings.share_experience:
            self.block_class = StateRecordingBlock if self.model.uses_global_state else RecordingBlock
        super()._init_callback()

    def _check_model(self) -> nn.Module:
        q_net = super()._check_model()
        if self.settings.n_team_check_episodes > 0 and getattr(self.model.get_env(), "env_id", None) is None:
            raise ValueError(
                "n_team_check_episodes > 0 replays the training env, which needs a vec env made by "
                "sb3_eps.make_vec_env (it records its env_id); set n_team_check_episodes=0"
            )
        if self.settings.n_team_check_episodes > 0 and self._world_options():
            raise ValueError(
                f"the model's worlds have options {self._world_options()} and the team check replays the training "
                "env id with its default options: set n_team_check_episodes=0"
            )
        if self.settings.per_robot and int(getattr(self.model, "n_agents", 0)) < 1:
            raise ValueError("per_robot=True needs a multi-agent model (model.n_agents); set per_robot=False")
        return q_net

    def _world_options(self) -> dict[str, Any]:
        """The training worlds' options that the evaluation world takes from them (and ``action_repeat``)."""
        training = dict(getattr(self.model.get_env(), "env_kwargs", None) or {})
        wanted = {key: training[key] for key in SHARED_WORLD_OPTIONS if key in training}
        ticks = int(getattr(self.model, "ticks_per_step", 1))
        return {**wanted, "action_repeat": ticks} if ticks != 1 else wanted

    def _check_eval_world(self, env: Any) -> None:
        problem = sharing_problem(self.model, env) if self.settings.share_experience else None
        if problem is not None:
            raise ValueError(f"{problem}; or set share_experience=False")

    def _run_round(self) -> None:
        n_before = len(self.history)
        super()._run_round()
        record = self.history[-1] if len(self.history) > n_before else {}
        if record.get("skipped", True):
            return
        if self.settings.share_experience:
            self.logger.record("eps/shared_rows", record["shared_rows"])
            self.logger.record("eps/shared_rows_total", self.shared_rows)
        for when in ("before", "after"):
            if f"team_success_{when}" in record:
                self.logger.record(f"eps/team_success_{when}", record[f"team_success_{when}"])


register_callback(ResearchEvolutionCallback)
