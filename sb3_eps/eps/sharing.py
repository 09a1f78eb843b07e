"""EPS experience sharing: the population's team-world episodes become replay rows of the learner, as in
Evolutionary RL (Khadka & Tumer, NeurIPS 2018)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from sb3_eps.common.buffers import JointTick, NStepJointCollector
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm
from sb3_eps.eps.evaluation import TeamEpisode


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


def record_mode(model: MultiAgentOffPolicyAlgorithm) -> str:
    """What the evaluation workers must record for ``model``'s rows: the global states only where it stores them."""
    return "ticks+states" if model.uses_global_state else "ticks"


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
