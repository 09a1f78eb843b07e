"""Drive a PettingZoo world with an exported policy through the torch-free runner (``sb3_eps/deploy/onnx_runner.py``).

Export once, where torch is (``docs/usage.md``, "Deploying the exported policy"):

    from sb3_eps import GDQ, export_policy
    export_policy(GDQ.load("gdq_4", env=venv), "gdq_4")     # gdq_4.onnx + gdq_4.json, the world described

then run, with numpy, onnxruntime and the worlds only (this script never imports torch or ``sb3_eps``: it takes the
runner as the one file a robot would take):

    python examples/onnx_runner_loop.py gdq_4 --episodes 3

Every robot of the world acts from its own observation through ``OnnxPolicy.act`` (one shared network, the paper's
decentralised execution); the world is the one the JSON names (``env_id``, ``env_kwargs``) unless ``--env`` says
another. On a real TurtleBot3 the observation comes from ``policy.observation(ranges_m, goal_distance_m,
goal_heading_rad)`` and the action goes out as ``policy.wheel_velocities(action)``, held ``policy.decision_period_s``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
from collections.abc import Callable, Sequence
from typing import Any

# The runner is one self-contained file: put its folder on the path, as on a robot that has the file alone.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "sb3_eps" / "deploy"))

from onnx_runner import OnnxPolicy

import envs  # registers the env ids; imports no torch


def run(
    policy_path: str | pathlib.Path,
    env_id: str | None = None,
    episodes: int = 1,
    seed: int = 0,
    max_steps: int | None = None,
    out: Callable[[str], Any] = print,
) -> dict[str, Any]:
    """Run ``episodes`` episodes of the world with the exported policy; :return: successes, episodes and steps."""
    policy = OnnxPolicy.load(policy_path)
    env_id = env_id or policy.env_id
    if env_id is None:
        raise ValueError(f"{policy_path}: the JSON names no world; pass --env")
    env = envs.make_parallel_env(env_id, **(policy.env_kwargs or {}))
    out(f"{policy} in {env_id}")
    successes = steps = 0
    try:
        for episode in range(episodes):
            observations, infos = env.reset(seed=seed + episode)
            ticks = 0
            while env.agents and (max_steps is None or ticks < max_steps):
                actions = policy.act(observations)  # {robot: action index}, each from its own observation
                if steps == 0 and policy.deployment is not None:
                    first = next(iter(actions))
                    linear, angular = policy.wheel_velocities(actions[first])
                    left, right = policy.wheel_speeds(actions[first])
                    out(
                        f"{first}: action {actions[first]} = {linear:.2f} m/s, {angular:+.2f} rad/s (wheels "
                        f"{left:.3f} / {right:.3f} m/s), held {policy.decision_period_s:.2f} s"
                    )
                observations, _, _, _, step_infos = env.step(actions)
                infos = step_infos or infos
                ticks += 1
                steps += 1
            team = next(iter(infos.values()), {}).get("team", {})
            success = bool(team.get("success", False))
            successes += success
            out(f"episode {episode}: success {success}, {team.get('n_arrived', '?')} arrived, {ticks} decisions")
    finally:
        env.close()
    out(f"success: {successes}/{episodes} episodes")
    return {"successes": successes, "episodes": episodes, "steps": steps}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python examples/onnx_runner_loop.py", description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="the exported policy: <name>, <name>.json or <name>.onnx")
    parser.add_argument("--env", default=None, help="env id (default: the one the JSON names)")
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, default=None, help="decisions per episode at most (default: the world's)")
    args = parser.parse_args(argv)
    try:
        run(args.policy, args.env, args.episodes, args.seed, args.max_steps)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
