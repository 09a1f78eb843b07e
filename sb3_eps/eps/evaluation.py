"""Greedy evaluation of an EPS population (Algorithm 1, lines 4 and 10).

The individuals are split into contiguous blocks, one per worker process or one in the main process
(:class:`EnvPool`, on :class:`~sb3_eps.common.workers.WorkerBlocks` as the subprocess vec env); a block plays all its episodes in lockstep, episode ``j`` of every
individual from the same seed (common random numbers), and gets the weights once per round (``docs/modules/eps.md``).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np
import torch as th
from torch import nn
from torch.func import functional_call, vmap

from sb3_eps.common.export import deployment_description
from sb3_eps.common.parallel_wrappers import TeamAsGymnasium, ticks_per_step
from sb3_eps.common.safety import LidarSafetyMask, safety_geometry
from sb3_eps.common.workers import Served, WorkerBlocks, WorkerError
from sb3_eps.eps.mutations import Parameters, finite_individuals

#: Returns, lengths, outcomes ``(P, E)``, valid ``(P,)`` and what the blocks recorded of each episode
#: (individual-major; :meth:`EvaluationBlock.recorded`) or None.
PoolAnswer = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[Any] | None]


class EvaluationFailed(WorkerError):
    """An evaluation worker crashed, raised or did not answer in time; the round cannot be scored."""

    record: dict[str, Any] | None = None  # what the round measured before (set by the round)


def check_eval_env_id(env_id: str) -> None:
    """Raise ``ValueError`` unless ``env_id`` names an EPS world: a single-agent env or one of our team worlds."""
    from sb3_eps import worlds  # registers the project's ids

    if env_id in worlds.single_agent_ids() or env_id in worlds.multi_agent_ids():
        return
    if env_id not in gymnasium.registry:
        raise ValueError(
            f"unknown eval_env_id {env_id!r}; use one of {list(worlds.single_agent_ids())} (single-agent), "
            f"{list(worlds.multi_agent_ids())} (team worlds) or a registered gymnasium id"
        )


def make_eval_env(env_id: str, env_kwargs: dict[str, Any] | None = None) -> gymnasium.Env:
    """Build one evaluation env; a multi-agent id gives its world played by a team
    (:class:`~sb3_eps.common.parallel_wrappers.TeamAsGymnasium`)."""
    from sb3_eps import worlds

    if env_id in worlds.single_agent_ids():
        return worlds.make_single_env(env_id, **(env_kwargs or {}))
    if env_id in worlds.multi_agent_ids():
        return TeamAsGymnasium(worlds.make_parallel_env(env_id, **(env_kwargs or {})))
    return gymnasium.make(env_id, **(env_kwargs or {}))


def eval_env_geometry(env: gymnasium.Env, env_id: str) -> dict[str, Any]:
    """The lidar and action geometry (:func:`~sb3_eps.common.safety.safety_geometry`) of an EPS world, for a model
    with a lidar mask; :raises ValueError: for a world without a lidar (one line)."""
    return safety_geometry(deployment_description(env), f"the EPS world {env_id!r}")


def agent_space(env: gymnasium.Env, kind: str) -> gymnasium.Space:
    """The ``kind`` (``"observation_space"`` / ``"action_space"``) one agent of an EPS world sees: the env's own,
    or in a team world (:class:`~sb3_eps.common.parallel_wrappers.TeamAsGymnasium`) each robot's."""
    return getattr(env, f"agent_{kind}", getattr(env, kind))


class PopulationForward:
    """Outputs of a block of individuals, each on its own batch of observations: one ``vmap``-ed
    ``functional_call`` over the stacked weights.

    :param network: the agent network; only its architecture is used
    """

    def __init__(self, network: nn.Module) -> None:
        self.network = network
        self._buffers = dict(network.named_buffers())
        self._population: Parameters = {}
        self._vmapped = vmap(self._forward_one, in_dims=(0, 0))

    def _forward_one(self, weights: Parameters, obs: th.Tensor) -> th.Tensor:
        return functional_call(self.network, (weights, self._buffers), (obs,))

    def load(self, population: Parameters) -> None:
        """Take the weights to evaluate (each tensor ``(P, *shape)``)."""
        self._population = population

    def __call__(self, obs: th.Tensor) -> th.Tensor:
        """:param obs: ``(P, E, obs_dim)``; :return: outputs ``(P, E, n_outputs)``."""
        with th.no_grad():
            return self._vmapped(self._population, obs)


class EvaluationBlock(Served):
    """The envs of a block of individuals and the forward pass that drives them (in a worker or in process);
    env ``p * n_episodes + j`` plays episode ``j`` of individual ``p``. A worker's block answers ``evaluate`` with
    the numpy weights of its individuals. Episode lengths count world ticks: a world that holds each decision for
    ``action_repeat`` ticks adds that many per step (the last decision of an episode counted whole).

    A subclass records the episodes it plays (:meth:`start_recording`, :meth:`record_step`, :meth:`recorded`), e.g.
    to turn them into replay rows; the records travel back with the answer (:attr:`PopulationResult.episodes`).

    :param safety_margin: a model's lidar mask (``policy_kwargs.safety_margin``): each individual plays its best
        allowed action, as the model does, the mask built on this world's lidar and actions (None: the arg max)
    """

    def __init__(
        self,
        env_id: str,
        env_kwargs: dict[str, Any] | None,
        n_individuals: int,
        n_episodes: int,
        network: nn.Module,
        safety_margin: float | None = None,
    ) -> None:
        self.n_individuals, self.n_episodes = n_individuals, n_episodes
        self.envs = [make_eval_env(env_id, env_kwargs) for _ in range(n_individuals * n_episodes)]
        self.team_size = int(getattr(self.envs[0], "team_size", 0))  # 0: a single-agent env
        self.ticks_per_step = ticks_per_step(self.envs[0])
        self.forward = PopulationForward(network)
        self.safety_mask = None
        if safety_margin is not None:
            self.safety_mask = LidarSafetyMask(safety_margin, eval_env_geometry(self.envs[0], env_id))

    def evaluate(self, population: Parameters, seeds: Sequence[int], valid: np.ndarray) -> PoolAnswer:
        """Play every episode of every ``valid`` individual greedily, all envs in lockstep; an individual whose
        output is not finite becomes invalid. :return: :data:`PoolAnswer`"""
        shape = (self.n_individuals, self.n_episodes)
        valid = np.array(valid, dtype=bool)
        self.forward.load(population)
        returns, lengths = np.zeros(shape), np.zeros(shape, dtype=np.int64)
        outcomes = np.zeros(shape, dtype=np.int64)
        active = np.repeat(valid, self.n_episodes)
        agents = max(self.team_size, 1)  # observations per env: a team world's every agent acts
        obs_shape = self.envs[0].observation_space.shape or ()
        obs = np.zeros((len(self.envs), *obs_shape), dtype=np.float32)
        for index in np.flatnonzero(active):
            obs[index] = self.envs[index].reset(seed=int(seeds[int(index) % self.n_episodes]))[0]
        self.start_recording(obs, active)
        while active.any():
            outputs = self.forward(th.as_tensor(obs).reshape(self.n_individuals, self.n_episodes * agents, -1))
            outputs = outputs.reshape(len(self.envs), agents, -1)
            # A NaN/inf output disqualifies its individual at once: its envs stop, its fitness becomes -inf.
            finite = th.isfinite(outputs).all(dim=-1).all(dim=-1).numpy()
            broken = (~finite & active).reshape(shape).any(axis=1)
            if broken.any():
                valid &= ~broken
                active &= np.repeat(valid, self.n_episodes)
            if self.safety_mask is not None:  # the best allowed action, as the model's policy plays
                rows = th.as_tensor(obs).reshape(len(self.envs) * agents, -1)
                outputs = self.safety_mask.masked(rows, outputs.reshape(len(rows), -1)).reshape(outputs.shape)
            actions = outputs.argmax(dim=-1).numpy()
            for index in np.flatnonzero(active):
                action = actions[index] if self.team_size else int(actions[index, 0])
                next_obs, reward, terminated, truncated, info = self.envs[index].step(action)
                self.record_step(int(index), action, next_obs)
                obs[index] = next_obs
                returns.flat[index] += float(reward)
                lengths.flat[index] += self.ticks_per_step
                active[index] = not (terminated or truncated)
                if terminated or truncated:
                    outcomes.flat[index] = episode_outcome(bool(terminated), info)
        return returns, lengths, outcomes, valid, self.recorded(valid)

    def start_recording(self, obs: np.ndarray, active: np.ndarray) -> None:
        """Episodes start: ``obs`` the first observation of every env, ``active`` the envs that play."""

    def record_step(self, index: int, action: Any, next_obs: np.ndarray) -> None:
        """Env ``index`` took ``action`` and observes ``next_obs``."""

    def recorded(self, valid: np.ndarray) -> list[Any] | None:
        """:return: one record per env (``valid``: the individuals that played to the end), or None: nothing kept."""
        return None

    def handle(self, command: str, data: Any) -> Any:
        if command != "evaluate":
            return super().handle(command, data)
        population, seeds, valid = data
        return self.evaluate({name: th.from_numpy(array) for name, array in population.items()}, seeds, valid)

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _build_served_block(payload: tuple[type[EvaluationBlock], dict[str, Any]]) -> EvaluationBlock:
    th.set_num_threads(1)  # the forward passes are tiny; threads would fight over the cores with the envs
    block_class, block_kwargs = payload
    return block_class(**block_kwargs)


class EnvPool:
    """The evaluation envs of ``n_individuals`` x ``n_episodes`` episodes: the individuals split into contiguous
    blocks, one per worker process, or all in one block in the main process (``n_workers=0``: no start-up cost, no
    protection against a hanging env).

    :param env_id: an id :func:`check_eval_env_id` accepts, built with ``env_kwargs``
    :param n_individuals: individuals per round, each playing ``n_episodes`` episodes
    :param network: architecture template (CPU; copied into the workers)
    :param n_workers: number of worker processes (at most ``n_individuals``; 0: the main process)
    :param block_class: the blocks' class (a subclass records the episodes, :class:`EvaluationBlock`)
    :param safety_margin: the model's lidar mask, applied to every individual's actions (:class:`EvaluationBlock`)
    """

    def __init__(
        self,
        env_id: str,
        env_kwargs: dict[str, Any] | None,
        n_individuals: int,
        n_episodes: int,
        network: nn.Module,
        n_workers: int = 2,
        block_class: type[EvaluationBlock] = EvaluationBlock,
        safety_margin: float | None = None,
    ) -> None:
        n_blocks = max(1, min(n_workers, n_individuals))
        self.blocks = [block for block in np.array_split(np.arange(n_individuals), n_blocks) if len(block)]
        common = {"env_id": env_id, "env_kwargs": env_kwargs, "n_episodes": n_episodes, "network": network}
        if safety_margin is not None:  # only then: a block class of its own need not know the option
            common["safety_margin"] = safety_margin
        payloads = [(block_class, {**common, "n_individuals": len(block)}) for block in self.blocks]
        # The workers build their envs while the main process goes on training; the first evaluation waits for
        # their hellos within its own deadline.
        self._workers = WorkerBlocks(
            _build_served_block,
            payloads if n_workers else [],
            None if n_workers else lambda: block_class(**payloads[0][1]),
            describe=lambda i: f"evaluation block {i}",
            error=EvaluationFailed,
            close_timeout=1.0,
        )
        self._ready = False

    @property
    def pids(self) -> list[int]:
        """Process ids of the worker processes (empty in the main process or once closed)."""
        return [] if self._workers.closed else self._workers.pool.pids

    def evaluate(self, population: Parameters, seeds: Sequence[int], valid: np.ndarray, deadline: float) -> PoolAnswer:
        """Every episode of every ``valid`` individual (:meth:`EvaluationBlock.evaluate`) before ``deadline``
        (``time.monotonic()``; not enforced in the main process), else :class:`EvaluationFailed`."""
        if not self._ready:  # the workers' hellos: their envs are built
            self._workers.hellos("building its envs", deadline)
            self._ready = True
        data = [
            ({name: stacked[block].cpu().numpy() for name, stacked in population.items()}, list(seeds), valid[block])
            for block in self.blocks
        ]
        try:
            answers = self._workers.ask("evaluate", data, data[0], "evaluating", deadline)
        except EvaluationFailed:
            raise
        except Exception as error:  # an env that fails (e.g. its PyBullet client is gone): skip the round
            reason = " ".join(str(error).split()) or type(error).__name__
            raise EvaluationFailed(f"an evaluation env raised {type(error).__name__}: {reason}") from error
        returns, lengths, outcomes, valid_parts = (np.concatenate([answer[part] for answer in answers]) for part in range(4))
        episodes = None if answers[0][4] is None else [episode for answer in answers for episode in answer[4]]
        return returns, lengths, outcomes, valid_parts, episodes

    def close(self) -> None:
        self._workers.close()


#: The pool with its envs in worker processes (``n_workers``, 2 by default), and the one with them in this process.
SubprocessEnvPool, InProcessEnvPool = EnvPool, functools.partial(EnvPool, n_workers=0)


@dataclass
class PopulationResult:
    """What one evaluation round measured: returns, lengths and outcomes (:data:`OUTCOMES`) ``(P, E)``; valid
    ``(P,)`` (False where weights or outputs were not finite, or not run); Eq. 4's fitness ``(P,)`` (``-inf`` where
    not valid); what the blocks recorded of the episodes (:meth:`EvaluationBlock.recorded`) or None."""

    returns: np.ndarray
    lengths: np.ndarray
    valid: np.ndarray
    fitness: np.ndarray
    outcomes: np.ndarray
    episodes: list[Any] | None = None

    @property
    def successes(self) -> np.ndarray:
        return self.outcomes == OUTCOMES["success"]


#: How an episode ended: reached the target, stopped by the time limit (or not run), or terminated otherwise.
OUTCOMES = {"success": 1, "timeout": 0, "failure": -1}
FITNESS_KINDS = ("return", "outcome")
#: Weight of the mean return beside the mean outcome in ``fitness="outcome"``: one more success in up to 50 episodes
#: outranks any return difference of the robot worlds (|return| < 5), equal outcomes rank by return.
OUTCOME_RETURN_WEIGHT = 0.01


def episode_outcome(terminated: bool, info: dict[str, Any]) -> int:
    """:return: the :data:`OUTCOMES` code of an episode that just ended."""
    if info.get("is_success", False):
        return OUTCOMES["success"]
    return OUTCOMES["failure"] if terminated else OUTCOMES["timeout"]


def population_fitness(returns: np.ndarray, outcomes: np.ndarray, valid: np.ndarray, kind: str = "return") -> np.ndarray:
    """Eq. 4's fitness ``F`` ``(P,)`` of every individual from its episodes ``(P, E)``; ``-inf`` where not valid.

    ``"return"`` (the paper): the mean undiscounted return. ``"outcome"``: the mean outcome (+1 target, 0 timeout,
    -1 failure) plus :data:`OUTCOME_RETURN_WEIGHT` times the mean return, so waiting ranks above crashing
    (``docs/modules/eps.md``).
    """
    if kind not in FITNESS_KINDS:
        raise ValueError(f"unknown fitness {kind!r}; use one of {FITNESS_KINDS}")
    score = returns.mean(axis=1)
    if kind == "outcome":
        score = outcomes.mean(axis=1) + OUTCOME_RETURN_WEIGHT * score
    return np.where(valid, score, -np.inf)


def evaluate_population(
    pool: EnvPool,
    population: Parameters,
    episode_seeds: Sequence[int],
    timeout: float,
    fitness: str = "return",
    active: np.ndarray | None = None,
) -> PopulationResult:
    """Run every individual of ``population`` ``(P, *shape)`` greedily, episode ``j`` seeded with
    ``episode_seeds[j]`` for all (Algorithm 1, line 10), within ``timeout`` seconds; individuals not ``active``
    get no episode and ``-inf``. :raises EvaluationFailed: when a worker crashed, raised or timed out"""
    deadline = time.monotonic() + timeout
    cpu_population = {name: stacked.detach().cpu() for name, stacked in population.items()}
    valid = finite_individuals(cpu_population)
    if active is not None:
        valid &= np.asarray(active, dtype=bool)
    returns, lengths, outcomes, valid, episodes = pool.evaluate(cpu_population, list(episode_seeds), valid, deadline)
    scores = population_fitness(returns, outcomes, valid, fitness)
    return PopulationResult(
        returns=returns, lengths=lengths, valid=valid, fitness=scores, outcomes=outcomes, episodes=episodes
    )
