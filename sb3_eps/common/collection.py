"""Collection of :class:`~sb3_eps.common.off_policy.MultiAgentOffPolicyAlgorithm`: it steps the vector env with
per-agent epsilon-greedy actions, turns the per-agent stream into joint rows through the model's n-step collector,
counts episodes per world, and with ``overlap_training`` runs the due gradient steps while the worlds step.
"""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple, cast

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import RolloutReturn, TrainFreq
from stable_baselines3.common.utils import should_collect_more_steps
from stable_baselines3.common.vec_env import VecEnv

from sb3_eps.common.buffers import JointTick
from sb3_eps.common.utils import epsilon_greedy


def collect_rollouts(
    model: Any,
    env: VecEnv,
    callback: BaseCallback,
    train_freq: TrainFreq,
    learning_starts: int = 0,
    log_interval: int | None = None,
) -> RolloutReturn:
    """Step every world ``train_freq`` times, store joint rows, count episodes per world (not agent)."""
    model.policy.set_training_mode(False)
    model._trained_ahead = False
    n_collected_steps, n_collected_episodes = 0, 0
    callback.on_rollout_start()
    while should_collect_more_steps(train_freq, n_collected_steps, n_collected_episodes):
        actions = sample_actions(model, learning_starts, env.num_envs)
        env.step_async(actions)
        if model.overlap_training and n_collected_steps + 1 >= train_freq.frequency:
            _train_ahead(model, env.num_envs, n_collected_steps + 1)
        new_obs, rewards, dones, infos = env.step_wait()
        model.num_timesteps += env.num_envs
        n_collected_steps += 1
        callback.update_locals(locals())
        if not callback.on_step():
            return RolloutReturn(n_collected_steps * env.num_envs, n_collected_episodes, continue_training=False)
        model._update_info_buffer(infos, dones)
        n_ended = store_joint_transition(model, actions, cast(np.ndarray, new_obs), rewards, dones, infos)
        model._update_current_progress_remaining(model.num_timesteps, model._total_timesteps)
        model._on_step()
        for _ in range(n_ended):
            n_collected_episodes += 1
            model._episode_num += 1
            if log_interval is not None and model._episode_num % log_interval == 0:
                model.dump_logs()
    callback.on_rollout_end()
    return RolloutReturn(n_collected_steps * env.num_envs, n_collected_episodes, continue_training=True)


def sample_actions(model: Any, learning_starts: int, n_envs: int) -> np.ndarray:
    """Uniformly random actions before ``learning_starts``, then the online network's with one epsilon coin per
    agent (SB3's DQN draws one for the whole batch, so all agents would explore on the same steps)."""
    n_actions = int(model.action_space.n)
    if model.num_timesteps < learning_starts:
        return np.random.randint(n_actions, size=n_envs)
    # ``model.predict`` without SB3's generic input checks, which cost as much as the network itself here.
    assert model._last_obs is not None
    model.policy.set_training_mode(False)
    with th.no_grad():
        observation = th.as_tensor(model._last_obs, device=model.device)
        actions = model.policy._predict(observation, deterministic=False).cpu().numpy()
    if model.exploration_rate > 0:
        actions, _ = epsilon_greedy(actions, model.exploration_rate, n_actions)
    return actions


def _train_ahead(model: Any, n_envs: int, n_steps: int) -> None:
    """``overlap_training``: the gradient steps that SB3's ``learn`` runs after this collection, run now while the
    worlds step; its own call to ``train`` then does nothing (the same condition decides both)."""
    if model.num_timesteps + n_envs <= model.learning_starts:
        return
    gradient_steps = model.gradient_steps if model.gradient_steps >= 0 else n_steps * n_envs
    if gradient_steps > 0:
        model.train(gradient_steps, model.batch_size)
        model._trained_ahead = True
        model.policy.set_training_mode(False)


def store_joint_transition(
    model: Any,
    actions: np.ndarray,
    new_obs: np.ndarray,
    rewards: np.ndarray,
    dones: np.ndarray,
    infos: list[dict[str, Any]],
) -> int:
    """Feed the agents' transitions, grouped by world, to the model's n-step collector; :return: the worlds whose
    episode ended."""
    collector, last_state = model._collector, model._last_state
    assert collector is not None and last_state is not None and model._last_obs is not None
    shape = (model.n_worlds, model.n_agents)
    step = _read_step(new_obs, dones, infos, shape)
    new_state = model._global_state()
    last_obs = np.asarray(model._last_obs, dtype=np.float32).reshape((*shape, -1))
    next_obs = step.next_observations.reshape((*shape, -1))
    rewards = np.asarray(rewards, dtype=np.float32).reshape(shape)
    actions = np.asarray(actions, dtype=np.int64).reshape(shape)
    refused = _non_finite_worlds(last_obs, next_obs, rewards)
    for world in range(model.n_worlds):
        if world in refused:  # never stored; windows across the bad tick are dropped too
            collector.pending[world].clear()
            warnings.warn(f"{refused[world]}: the tick is not stored", RuntimeWarning, stacklevel=3)
            continue
        next_state = new_state[world]
        if step.world_ended[world] and model.uses_global_state:
            next_state = infos[world * model.n_agents].get("terminal_state", next_state)
        collector.add(
            world,
            JointTick(
                observations=last_obs[world],
                actions=actions[world],
                rewards=rewards[world],
                next_observations=next_obs[world],
                ended=step.ended[world],
                truncated=step.truncated[world],
                alive=step.alive[world],
                state=last_state[world],
                next_state=np.asarray(next_state, dtype=np.float32),
                world_ended=bool(step.world_ended[world]),
            ),
        )
    model._last_obs = new_obs
    model._last_state = new_state
    return int(step.world_ended.sum())


class _Step(NamedTuple):
    """What one vector step says of each agent, as ``(n_worlds, n_agents)`` arrays (observations flat)."""

    next_observations: np.ndarray  # (n_worlds * n_agents, obs): terminal observations where an episode ended
    alive: np.ndarray  # the agent acted at this tick
    truncated: np.ndarray  # its episode was cut by the time limit
    ended: np.ndarray  # its episode (its life) ended at this tick
    world_ended: np.ndarray  # (n_worlds,): every agent of the world is done


def _read_step(new_obs: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]], shape: tuple[int, int]) -> _Step:
    """Read the bridge's flags from a step's infos; patch in the terminal observations SB3 moved to the infos."""
    next_obs = np.array(new_obs, dtype=np.float32, copy=True)
    for index in np.flatnonzero(dones):
        next_obs[index] = infos[index]["terminal_observation"]
    alive = np.fromiter((info.get("alive", True) for info in infos), dtype=bool, count=len(infos))
    truncated = np.fromiter((info.get("TimeLimit.truncated", False) for info in infos), dtype=bool, count=len(infos))
    dones = np.asarray(dones, dtype=bool)
    ended = dones & alive
    return _Step(
        next_observations=next_obs,
        alive=alive.reshape(shape),
        truncated=truncated.reshape(shape),
        ended=ended.reshape(shape),
        world_ended=np.asarray(dones.reshape(shape).all(axis=1)),
    )


def _non_finite_worlds(observations: np.ndarray, next_observations: np.ndarray, rewards: np.ndarray) -> dict[int, str]:
    """:return: world -> what was not finite in its tick (``(worlds, agents, ...)`` arrays; empty when all are)."""
    parts = {"observation": observations, "next observation": next_observations, "reward": rewards}
    found: dict[int, str] = {}
    if all(np.isfinite(array).all() for array in parts.values()):  # the hot path: one check per array
        return found
    for name, array in parts.items():
        bad = ~np.isfinite(array.reshape(array.shape[0], array.shape[1], -1)).all(axis=2)
        for world in np.flatnonzero(bad.any(axis=1)):
            agents = np.flatnonzero(bad[world]).tolist()
            found.setdefault(int(world), f"non-finite {name} from the env (world {world}, agents {agents})")
    return found
