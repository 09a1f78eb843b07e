"""Training one model over a ladder of worlds, for example 2 robots, then 4, then 8.

A ladder is a list of rungs, each a multi-agent vector env and the world ticks to train on it. One model climbs it:
on each rung :meth:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm.set_env` moves it to the rung's world
(networks and optimizer carry over; the replay buffer starts empty when the team size changes, its rows hold one
team) and ``learn`` continues without resetting the counters. So ``model.ticks`` counts the world ticks of every
rung (the x axis of the curves) and ``model.num_timesteps`` the agent-steps beside them: a rung of 4 robots spends 4
agent-steps per tick, one of 8 spends 8. The schedules run once over the whole ladder (:class:`ScheduleHorizon`).

Only models whose joint modules read any number of agents can change team size (IQL, VDN, GDQ with
``global_head="pooled"``); :func:`check_ladder` refuses the others in one line before anything trains.

Example::

    model = GDQ("MlpPolicy", make_vec_env("MultiRobotNav-2-v0", n_envs=4, seed=0), seed=0,
                policy_kwargs=dict(global_head="pooled"))
    learn_ladder(model, [(model.get_env(), 20_000), (make_vec_env("MultiRobotNav-4-v0", n_envs=4, seed=1), 10_000)])
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence
from typing import Any, NamedTuple, TypeVar

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm, find_multi_agent_env, timesteps_for_ticks

SelfAlgorithm = TypeVar("SelfAlgorithm", bound=MultiAgentOffPolicyAlgorithm)


class Rung(NamedTuple):
    """One rung of a ladder.

    :param env: the rung's multi-agent vector env (``sb3_eps.make_vec_env``)
    :param ticks: world ticks to train on it (summed over its worlds, as ``model.ticks`` counts them)
    """

    env: VecEnv
    ticks: int


def as_rungs(rungs: Sequence[Rung | tuple[VecEnv, int]]) -> list[Rung]:
    """:return: the rungs checked: at least one, each a multi-agent vector env and a positive int of ticks.

    :raises ValueError: naming the rung that is wrong
    """
    if not rungs:
        raise ValueError("a ladder needs at least one rung (env, ticks)")
    checked = []
    for index, rung in enumerate(rungs):
        env, ticks = rung
        if isinstance(env, str):
            raise ValueError(
                f"ladder rung {index}: pass a vector env, not the id {env!r}: use sb3_eps.make_vec_env({env!r}, n_envs=...)"
            )
        if isinstance(ticks, bool) or not isinstance(ticks, int) or ticks < 1:
            raise ValueError(f"ladder rung {index}: ticks must be an int >= 1, got {ticks!r}")
        find_multi_agent_env(env)  # raises for an env that is not multi-agent
        checked.append(Rung(env, ticks))
    return checked


def rung_ends(rungs: Sequence[Rung]) -> list[int]:
    """:return: the total ticks at the end of each rung."""
    return list(itertools.accumulate(rung.ticks for rung in rungs))


def rung_at(rungs: Sequence[Rung], ticks: int) -> int:
    """:return: the index of the rung that the ticks so far are in (``len(rungs)`` once the ladder is done)."""
    return bisect.bisect_right(rung_ends(rungs), ticks)


def ladder_timesteps(rungs: Sequence[Rung]) -> int:
    """:return: the agent-steps of the whole ladder (each rung's ticks times its agents per world)."""
    layouts = [(rung.ticks, find_multi_agent_env(rung.env)) for rung in rungs]
    return sum(timesteps_for_ticks(ticks, env.n_agents, getattr(env, "ticks_per_step", 1)) for ticks, env in layouts)


def check_ladder(model: MultiAgentOffPolicyAlgorithm, rungs: Sequence[Rung]) -> None:
    """Check that ``model`` can train on every rung: the same spaces per agent, and another team size only when its
    joint modules read any number of agents.

    :raises ValueError: in one line, naming the rung and what to do
    """
    for index, rung in enumerate(rungs):
        layout = find_multi_agent_env(rung.env)
        name = getattr(layout, "env_id", None) or type(rung.env).__name__
        for kind in ("observation_space", "action_space"):
            if getattr(rung.env, kind) != getattr(model, kind):
                raise ValueError(
                    f"ladder rung {index} ({name}): its {kind} differs from the model's; every rung needs the same "
                    "observation and action per agent"
                )
        if int(layout.n_agents) != model.n_agents and model._fixed_team_size():
            raise ValueError(
                f"ladder rung {index} ({name}) has {layout.n_agents} agents per world, the model "
                f"{model.n_agents}, and this {type(model).__name__}'s joint networks are sized for its team. "
                f"{model._team_size_advice()}"
            )


class ScheduleHorizon(BaseCallback):
    """Points SB3's progress (``_total_timesteps``, which ``_current_progress_remaining`` counts down to) at
    ``total_timesteps`` instead of the ``learn`` call's own end, so the schedules (learning rate, exploration, PER)
    run once over a run made of several calls: a ladder's rungs, a learner's turns in a plug-in trainer."""

    def __init__(self, total_timesteps: int) -> None:
        super().__init__()
        self.total_timesteps = int(total_timesteps)

    def _on_training_start(self) -> None:
        self.model._total_timesteps = self.total_timesteps

    def _on_step(self) -> bool:
        return True


def learn_ladder(
    model: SelfAlgorithm,
    rungs: Sequence[Rung | tuple[VecEnv, int]],
    callback: MaybeCallback = None,
    log_interval: int = 4,
    reset_num_timesteps: bool = True,
    progress_bar: bool = False,
) -> SelfAlgorithm:
    """Train ``model`` on each rung in turn (the module docstring says what carries over).

    ``reset_num_timesteps=False`` continues a model part-way up the same ladder: training goes on in the rung that
    ``model.ticks`` is in, up to that rung's end, and a rung whose env is the model's own keeps its worlds where they
    are (a resumed checkpoint's worlds, mid-episode).

    :param model: the model; its env is replaced by each rung's
    :param rungs: ``(vector env, ticks)`` pairs, trained in this order
    :param callback: callback(s) called on every rung (``init_callback`` and ``on_training_start`` once per rung)
    :param log_interval: episodes between log dumps
    :param reset_num_timesteps: start counting from 0 (True) or continue the model's ticks (False)
    :param progress_bar: show a progress bar on each rung
    :return: the trained model
    :raises ValueError: for a bad rung or one the model cannot train on (:func:`check_ladder`)
    """
    checked = as_rungs(rungs)
    check_ladder(model, checked)
    ends = rung_ends(checked)
    schedules = ScheduleHorizon(ladder_timesteps(checked))
    callbacks: list[Any] = [
        schedules,
        *(callback if isinstance(callback, list) else [callback] if callback else []),
    ]
    start = 0 if reset_num_timesteps else rung_at(checked, model.ticks)
    for index in range(start, len(checked)):
        env = checked[index].env
        if env is not model.get_env():
            model.set_env(env)
        reset = reset_num_timesteps and index == start
        remaining = ends[index] - (0 if reset else model.ticks)
        if remaining <= 0:  # the previous rung ended past this one's end (a rollout longer than the rung)
            continue
        model.learn(
            model.timesteps_for_ticks(remaining),
            callback=callbacks,
            log_interval=log_interval,
            reset_num_timesteps=reset,
            progress_bar=progress_bar,
        )
    return model
