"""A safety layer on the lidar for a deployed navigation policy (rule N13 of ``docs/results/navigator/rules.md``).

At every decision, each of the 20 actions is checked against what the robot's own lidar sees now: the robot's centre is
swept along the action's arc (the command held ``action_repeat`` ticks, for ``horizon`` decisions) and the action is
*safe* when the body stays more than ``margin`` metres clear of every lidar hit point (ranges below the view's cap).
The layer plays the policy's best safe action (by its advantage, the greedy order); when no action is safe, the action
that keeps the most clearance. The geometry is the ONNX runner's (``OnnxPolicy.act(obs, safety_margin=...)`` on a
robot): this script runs it on a torch model inside the evaluation worlds. It reads nothing but the robot's observation and the world's ``action_repeat`` and
``lidar_range``, so it runs wherever the policy runs. Other robots are seen as lidar points frozen at this instant;
the margin is what covers their motion.

Evaluate a run with the layer (the record stores the world and the layer's options)::

    python research/lidar_shield.py --run RUN_DIR --eval-env MultiRobotNavRooms-8-validation-v0 -n 100 \
        --seed 40000 --margin 0.03 --horizon 1 --output shielded.json
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from envs.turtlebot3.robot import (
    ACTION_ANGULAR,
    ACTION_LINEAR,
    BEAM_ANGLES,
    DT,
    N_BEAMS,
    ROBOT_RADIUS,
)
from sb3_eps.deploy.onnx_runner import lidar_clearance, swept_arcs
from sb3_eps.zoo.evaluation import evaluate_run, load_run, save_summary


def sweep(action_repeat: int, horizon: int) -> np.ndarray:
    """:return: ``(n_actions, horizon * ARC_POINTS, 2)``: the robot centre's positions along each action's arc, in
    the robot's frame at the decision (x ahead, y to the left), the start excluded (the runner's :func:`swept_arcs`)."""
    return swept_arcs(ACTION_LINEAR, ACTION_ANGULAR, action_repeat * DT, horizon)


class LidarShield:
    """A policy with the safety layer: ``predict`` as the model's, over a batch of robot observations.

    :param model: a trained sb3-eps value-based model (its greedy network's advantage orders the actions)
    :param lidar_range: the world's view [m] (the observation's ranges are divided by it)
    :param action_repeat: the world's ticks per decision
    :param margin: clearance [m] kept between the body and every lidar hit point along the checked arc
    :param horizon: decisions of the same command that the check covers
    """

    def __init__(self, model: Any, lidar_range: float, action_repeat: int, margin: float, horizon: int = 1) -> None:
        if margin < 0 or horizon < 1:
            raise ValueError(f"margin must be >= 0 and horizon >= 1, got {margin} and {horizon}")
        self.model, self.lidar_range, self.margin = model, float(lidar_range), float(margin)
        self.path = sweep(int(action_repeat), int(horizon))
        self.n_decisions = 0
        self.n_changed = 0
        self.n_unsafe = 0

    @property
    def observation_space(self) -> Any:
        return self.model.observation_space

    @property
    def action_space(self) -> Any:
        return self.model.action_space

    def clearance(self, observations: np.ndarray) -> np.ndarray:
        """:return: ``(n_robots, n_actions)``: the least distance [m] from the swept centre to a lidar hit point,
        minus the robot's radius (inf where the lidar sees nothing within its view)."""
        return lidar_clearance(observations[:, :N_BEAMS], self.lidar_range, BEAM_ANGLES, self.path, ROBOT_RADIUS)

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        observations = np.asarray(observation, dtype=np.float32)
        net = self.model.policy.greedy_net()
        with th.no_grad():
            advantage = net.advantage(th.as_tensor(observations, device=self.model.device)).cpu().numpy()
        clearance = self.clearance(observations)
        safe = clearance > self.margin
        any_safe = safe.any(axis=1)
        scores = np.where(safe, advantage, -np.inf)
        actions = np.where(any_safe, scores.argmax(axis=1), clearance.argmax(axis=1))
        greedy = advantage.argmax(axis=1)
        self.n_decisions += len(actions)
        self.n_changed += int((actions != greedy).sum())
        self.n_unsafe += int((~any_safe).sum())
        return actions, state


def evaluate_shielded(
    run_dir: str,
    env_id: str,
    n_episodes: int,
    seed: int,
    margin: float,
    horizon: int,
    shield: bool = True,
    env_kwargs: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Play a run's final model (with the layer unless ``shield`` is False: then the network alone, a mask built into
    the model taken out too) on ``env_id`` with the run's own world
    options updated by ``env_kwargs``, through :func:`sb3_eps.zoo.evaluation.evaluate_run` as ``python -m
    sb3_eps.evaluate`` does. :return: the evaluation summary plus
    the layer's record."""
    run = load_run(run_dir, "final", "cpu")
    if not shield:  # the network's own arg max: a mask built into the model (policy_kwargs.safety_margin) is taken out
        run.model.policy.safety_mask = None
    options = {**run.env_kwargs, **(env_kwargs or {})}
    lidar_range = float(options.get("lidar_range", 3.5))
    action_repeat = int(options.get("action_repeat", 1))
    policy = LidarShield(run.model, lidar_range, action_repeat, margin, horizon) if shield else run.model
    summary = evaluate_run(replace(run, model=policy), env_id, n_episodes, seed=seed, env_kwargs=env_kwargs)
    # The model's own mask (None: it has none) and whether it played: off with ``shield`` False.
    layer: dict[str, Any] = {"on": shield, "model_safety_margin": run.model.policy.safety_margin, "model_mask_used": shield}
    if shield:
        layer.update(
            margin=margin, horizon=horizon, lidar_range=lidar_range, action_repeat=action_repeat,
            changed_share=policy.n_changed / max(policy.n_decisions, 1),
            none_safe_share=policy.n_unsafe / max(policy.n_decisions, 1),
        )  # fmt: skip
    timeouts = [e for e in summary["episodes"] if not e.get("success") and not e.get("collision")]
    summary.update(shield=layer, timeout_rate=len(timeouts) / len(summary["episodes"]))
    return summary


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="run folder of a trained model")
    parser.add_argument("--eval-env", required=True, help="env id to play")
    parser.add_argument("-n", "--n-episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0, help="evaluation seed")
    parser.add_argument("--margin", type=float, default=0.03, help="clearance kept [m]")
    parser.add_argument("--horizon", type=int, default=1, help="decisions the check covers")
    parser.add_argument(
        "--no-shield", action="store_true", help="play the network alone, without this layer or a mask built into the model"
    )
    parser.add_argument("--env-kwargs", type=json.loads, default={}, help="world options added to the run's, as JSON")
    parser.add_argument("--output", required=True, help="JSON record to write")
    args = parser.parse_args(argv)
    summary = evaluate_shielded(
        args.run, args.eval_env, args.n_episodes, args.seed, args.margin, args.horizon, not args.no_shield, args.env_kwargs
    )
    save_summary(summary, Path(args.output))
    print(json.dumps({k: summary[k] for k in ("env_id", "success_rate", "collision_rate", "timeout_rate", "shield")}))


if __name__ == "__main__":
    main()
