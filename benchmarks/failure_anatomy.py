"""What a trained team's failed greedy episodes are made of, on a TurtleBot3 world.

A greedy team episode fails by a collision (every robot ends) or by the time limit (the robots still driving are
truncated). Team success asks every robot to arrive, so one robot that never does fails the team. This script runs
a saved model greedily on fresh episodes of one world and sorts every failure by what the robots did:

- a collision: with a robot still driving, with a parked robot (one that has arrived and stands on its target) or
  with a wall;
- a time-out, per robot that had not arrived when the time ran out, by its last ``--window`` ticks:
  ``near target`` (it ended within 0.5 m of its target), ``standing still`` (it drove less than 0.1 m and turned
  less than 0.5 rad), ``turning in place`` (it drove less than 0.1 m and turned more), ``looping`` (it drove more
  than 3 times its net displacement), ``slow`` (anything else), the actions it took most in that window, and
  whether a parked robot stands within 0.4 m of its target (``target crowded``: arriving there means squeezing next
  to a parked robot).

``--epsilon`` replays the same episodes with training's epsilon-greedy actions instead, to tell a trap of the
deterministic policy (a state it never leaves) from a skill the policy lacks.

It prints the counts and writes one JSON line per episode with ``--out``. It selects nothing.

    python benchmarks/learning_check.py --algo gdq --env MultiRobotNav-4-v0 --ticks 150000 --seeds 154 \\
        --save-models --out runs/anatomy
    python benchmarks/failure_anatomy.py --algo gdq --model runs/anatomy/gdq_MultiRobotNav-4-v0_seed154.zip
"""

from __future__ import annotations

import argparse
import collections
import json
import pathlib
from typing import Any

import numpy as np
import torch as th

import envs
from envs.turtlebot3.robot import ACTION_ANGULAR, ACTION_LINEAR, N_BEAMS, RANGE_MAX, ROBOT_RADIUS
from sb3_eps.zoo.schema import ALGORITHMS, algorithm_spec

NEAR_TARGET_M = 0.5
STANDING_M = 0.1
LOOPING_RATIO = 3.0
CROWDED_M = 0.4
TURNING_RAD = 0.5
CORNER_M = 0.4  # a collision this close to two outer walls is a corner
CONTACT_M = 2 * ROBOT_RADIUS + 0.02  # two footprints touching, with the physics' margin


def classify_timeout(
    path: np.ndarray, heading: np.ndarray, target: np.ndarray, parked: np.ndarray, observation: np.ndarray
) -> dict[str, Any]:
    """:param path: ``(k, 2)`` the robot's positions over its last ticks
    :param heading: ``(k,)`` its headings over the same ticks [rad]
    :param target: ``(2,)`` its target
    :param parked: ``(p, 2)`` the parked robots' positions at the end
    :param observation: its last observation (28 lidar ranges / 3.5 m, target distance / 10 m, bearing / pi)
    :return: ``kind``, ``final_distance``, ``driven``, ``displacement``, ``turned`` (radians turned in the window),
        ``nearest_obstacle`` (the shortest lidar range at the end, m), ``bearing`` (the target's bearing at the end,
        degrees), ``target_crowded`` and ``nearest_parked`` (centre to centre, m; None without parked robots)
    """
    driven = float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0
    turned = float(np.abs(np.angle(np.exp(1j * np.diff(heading)))).sum()) if len(heading) > 1 else 0.0
    displacement = float(np.hypot(*(path[-1] - path[0])))
    final_distance = float(np.hypot(*(target - path[-1])))
    if final_distance < NEAR_TARGET_M:
        kind = "near target"
    elif driven < STANDING_M:
        kind = "standing still" if turned < TURNING_RAD else "turning in place"
    elif driven > LOOPING_RATIO * max(displacement, 1e-9):
        kind = "looping"
    else:
        kind = "slow"
    crowded = bool(len(parked) and np.hypot(*(parked - target).T).min() < CROWDED_M)
    nearest_parked = float(np.hypot(*(parked - path[-1]).T).min()) if len(parked) else None
    return {
        "kind": kind,
        "final_distance": final_distance,
        "driven": driven,
        "displacement": displacement,
        "turned": turned,
        "nearest_obstacle": float(observation[:N_BEAMS].min() * RANGE_MAX),
        "bearing": float(np.rad2deg(observation[N_BEAMS + 1] * np.pi)),
        "target_crowded": crowded,
        "nearest_parked": nearest_parked,
    }


def classify_collision(xy: np.ndarray, robot: int, live: np.ndarray, half_extent: np.ndarray | None = None) -> str:
    """:param xy: ``(n, 2)`` every robot's position at the collision
    :param robot: the robot that collided
    :param live: ``(n,)`` which robots were still driving
    :param half_extent: the room's half sizes ``(2,)``: a wall contact within ``CORNER_M`` of two outer walls is a
        ``"corner"``
    :return: ``"robot"``, ``"parked robot"``, ``"corner"`` or ``"wall"`` (an outer wall or an inner block)
    """
    distance = np.hypot(*(xy - xy[robot]).T)
    distance[robot] = np.inf
    touching = distance < CONTACT_M
    if (touching & live).any():
        return "robot"
    if (touching & ~live).any():
        return "parked robot"
    if half_extent is not None and (np.abs(xy[robot]) > np.asarray(half_extent) - CORNER_M).all():
        return "corner"
    return "wall"


def q_lead(model: Any, observation: np.ndarray) -> float | None:
    """:return: how far the greedy action's Q value leads the second best's at ``observation`` (None for a model
    without a ``policy.q_net``)."""
    network = getattr(getattr(model, "policy", None), "q_net", None)
    if network is None:
        return None
    with th.no_grad():
        q_values = network(th.as_tensor(observation[None], dtype=th.float32))[0]
    top = th.topk(q_values, 2).values
    return float(top[0] - top[1])


def run_episode(
    model: Any,
    env: Any,
    seed: int,
    window: int,
    epsilon: float = 0.0,
    frames: list[np.ndarray] | None = None,
    target_set: int | None = None,
) -> dict[str, Any]:
    """One team episode, greedy unless ``epsilon`` > 0 (then each robot takes a uniformly random action with that
    probability each tick, drawn from a generator seeded by ``seed``, as in training's epsilon-greedy rollouts).
    With ``frames`` (an env made with ``render_mode="rgb_array"``), every other tick's picture is appended to it.
    ``target_set`` picks one of the fixed target sets of a world that has them (the unseen room; a reset with a
    seed would restart its sequence at set 0 every episode).

    :return: its outcome and, for a failure, what each failing robot did
    """
    rng = np.random.default_rng(seed)
    observations, _ = env.reset(seed=seed, options=None if target_set is None else {"target_set": target_set})
    n = env.n_robots
    history: list[np.ndarray] = []  # (n, 3): x, y, heading after each tick
    last_observation: dict[str, np.ndarray] = {}
    arrived_at = [None] * n
    taken: dict[str, list[int]] = collections.defaultdict(list)
    collisions: list[str] = []
    while env.agents:
        agents = list(env.agents)
        live = np.array([agent in agents for agent in env.possible_agents])
        actions, _ = model.predict(np.stack([observations[a] for a in agents]), deterministic=True)
        actions = np.asarray(actions).reshape(-1)
        if epsilon > 0:
            explore = rng.random(len(agents)) < epsilon
            actions = np.where(explore, rng.integers(0, env.action_space(agents[0]).n, len(agents)), actions)
        for agent, action in zip(agents, actions.tolist()):
            taken[agent].append(int(action))
        observations, _, _, _, infos = env.step(dict(zip(agents, actions.tolist())))
        if frames is not None and len(history) % 2 == 0:
            frames.append(env.render())
        last_observation.update(observations)
        state = env.state().reshape(n, 9)
        history.append(np.column_stack([state[:, :2], np.arctan2(state[:, 3], state[:, 2])]))
        for agent in agents:
            index = env.possible_agents.index(agent)
            if infos[agent]["collided"]:
                collisions.append(classify_collision(state[:, :2], index, live, env.layout.half_extent))
            elif infos[agent]["arrived"]:
                arrived_at[index] = len(history)
    team = next(iter(infos.values()))["team"]
    state = env.state().reshape(n, 9)
    record: dict[str, Any] = {
        "seed": seed,
        "target_set": target_set,
        "ticks": team["ticks"],
        "n_arrived": team["n_arrived"],
        "arrived_at": arrived_at,
    }
    if team["success"]:
        record["outcome"] = "success"
    elif team["collision"]:
        record["outcome"] = "collision"
        record["collisions"] = collisions
    else:
        record["outcome"] = "time-out"
        poses = np.stack(history)[-window:]  # (ticks, n, 3)
        arrived = state[:, 8] > 0.5
        record["stragglers"] = []
        for i in np.flatnonzero(~arrived):
            agent = env.possible_agents[i]
            straggler = classify_timeout(
                poses[:, i, :2], poses[:, i, 2], state[i, 6:8], state[arrived, :2], last_observation[agent]
            )
            straggler["robot"] = int(i)
            straggler["q_lead"] = q_lead(model, last_observation[agent])
            straggler["actions"] = collections.Counter(taken[agent][-window:]).most_common(3)
            record["stragglers"].append(straggler)
    return record


def action_name(action: int) -> str:
    """:return: ``"<index> (v <m/s>, w <deg/s>)"`` for one of the 20 actions."""
    return f"{action} (v {ACTION_LINEAR[action]:g}, w {np.rad2deg(ACTION_ANGULAR[action]):g})"


def sum_actions(stragglers: list[dict[str, Any]]) -> collections.Counter:
    """:return: how often each action was taken in the stragglers' windows (their top 3 each)."""
    total: collections.Counter = collections.Counter()
    for straggler in stragglers:
        total.update({int(a): int(c) for a, c in straggler["actions"]})
    return total


def summarize(records: list[dict[str, Any]]) -> str:
    """:return: the printed table."""
    outcomes = collections.Counter(record["outcome"] for record in records)
    lines = [f"{len(records)} episodes: " + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))]
    collisions = collections.Counter(c for record in records for c in record.get("collisions", []))
    if collisions:
        lines.append("  collisions with: " + ", ".join(f"{k} {v}" for k, v in collisions.most_common()))
    stragglers = [s for record in records for s in record.get("stragglers", [])]
    if stragglers:
        per_episode = collections.Counter(len(record["stragglers"]) for record in records if "stragglers" in record)
        lines.append(
            "  robots short of their target per time-out: "
            + ", ".join(f"{k}: {v} episodes" for k, v in sorted(per_episode.items()))
        )
        kinds = collections.Counter(s["kind"] for s in stragglers)
        lines.append("  what they did in the last window: " + ", ".join(f"{k} {v}" for k, v in kinds.most_common()))
        for kind in kinds:
            group = [s for s in stragglers if s["kind"] == kind]
            lines.append(
                f"    {kind}: median turned {np.median([s['turned'] for s in group]):.1f} rad, "
                f"nearest obstacle {np.median([s['nearest_obstacle'] for s in group]):.2f} m, "
                f"|bearing| {np.median([abs(s['bearing']) for s in group]):.0f} deg, "
                f"distance {np.median([s['final_distance'] for s in group]):.2f} m, "
                + (
                    f"greedy Q lead {np.median([s['q_lead'] for s in group]):.4f}, "
                    if all(s.get("q_lead") is not None for s in group)
                    else ""
                )
                + "actions "
                + ", ".join(f"{action_name(a)} x{c}" for a, c in sum_actions(group).most_common(3))
            )
        crowded = sum(s["target_crowded"] for s in stragglers)
        blocked = sum(s["nearest_parked"] is not None and s["nearest_parked"] < CONTACT_M + 0.1 for s in stragglers)
        lines.append(f"  ending within 0.1 m of touching a parked robot: {blocked} of {len(stragglers)}")
        lines.append(
            f"  target crowded by a parked robot (< {CROWDED_M} m): {crowded} of {len(stragglers)}; "
            f"median final distance {np.median([s['final_distance'] for s in stragglers]):.2f} m"
        )
    return "\n".join(lines)


def failure_kind(record: dict[str, Any]) -> str | None:
    """:return: ``"collision: <with what>"`` or ``"time-out: <what the first straggler did>"``; None for a success"""
    if record["outcome"] == "collision":
        return f"collision: {record['collisions'][0] if record['collisions'] else 'unknown'}"
    if record["outcome"] == "time-out":
        return f"time-out: {record['stragglers'][0]['kind']}"
    return None


def animate(model: Any, args: argparse.Namespace, records: list[dict[str, Any]]) -> None:
    """Replay the first episode of the most common failure kind with pictures and write them as a GIF."""
    kinds = collections.Counter(kind for kind in map(failure_kind, records) if kind is not None)
    if not kinds:
        print("no failure to animate")
        return
    kind = kinds.most_common(1)[0][0]
    record = next(r for r in records if failure_kind(r) == kind)
    env = envs.make_parallel_env(args.env, render_mode="rgb_array")
    frames: list[np.ndarray] = []
    try:
        run_episode(model, env, record["seed"], args.window, args.epsilon, frames, record.get("target_set"))
    finally:
        env.close()
    from envs.turtlebot3 import save_gif

    path = save_gif(frames[::2], args.animate, fps=20)  # every 4th tick, played 5x faster than real time
    print(f"animation of a '{kind}' failure (episode seed {record['seed']}, {record['ticks']} ticks): {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), default="gdq")
    parser.add_argument("--model", help="a model saved by learning_check.py --save-models")
    parser.add_argument("--env", default="MultiRobotNav-4-v0")
    parser.add_argument(
        "--env-kwargs",
        type=json.loads,
        default={},
        help='world options as JSON, the model\'s own (e.g. \'{"action_repeat": 4, "lidar_range": 1.0}\')',
    )
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=20_000, help="episode k is reset with seed + k")
    parser.add_argument("--window", type=int, default=200, help="ticks read before a time-out")
    parser.add_argument(
        "--epsilon",
        type=float,
        default=0.0,
        help="random actions with this probability (0: greedy, the evaluation)",
    )
    parser.add_argument("--out", default=None, help="write one JSON line per episode here")
    parser.add_argument(
        "--animate",
        default=None,
        metavar="GIF",
        help="replay the first episode that failed in the most common way and write it as an animation here",
    )
    parser.add_argument("--from-records", default=None, help="print the table of a file written by --out; run nothing")
    args = parser.parse_args()
    if args.from_records:
        lines = pathlib.Path(args.from_records).read_text().splitlines()
        print(summarize([json.loads(line) for line in lines if line.strip()]))
        return
    if not args.model:
        parser.error("--model is needed (or --from-records)")
    if not args.env.startswith("MultiRobotNav"):
        parser.error(f"--env {args.env!r}: the anatomy reads TurtleBot3 worlds (MultiRobotNav-<n>-v0, ...)")
    model = algorithm_spec(args.algo).algorithm_class.load(args.model, env=None, device="cpu", buffer_size=1)
    env = envs.make_parallel_env(args.env, **args.env_kwargs)
    try:
        sets = env.layout.target_sets
        records = []
        for k in range(args.episodes):
            record = run_episode(
                model, env, args.seed + k, args.window, args.epsilon, target_set=None if sets is None else k % len(sets)
            )
            # Every record names its world: the env id, its options, the level set and the level played.
            record.update(env_id=args.env, env_kwargs=args.env_kwargs, level_set=env.level_set, level=env.level)
            records.append(record)
    finally:
        env.close()
    if args.out:
        pathlib.Path(args.out).write_text("".join(json.dumps(record) + "\n" for record in records))
    if args.animate:
        animate(model, args, records)
    print(f"{args.model} on {args.env}" + (f", epsilon {args.epsilon}" if args.epsilon else ", greedy"))
    print(summarize(records))


if __name__ == "__main__":
    main()
