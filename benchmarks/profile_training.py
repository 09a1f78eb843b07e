"""Where a training tick's time goes, per world size: a cProfile of ``model.learn`` split into its parts.

Builds the algorithm with its package defaults on ``MultiRobotNav-<n>-v0`` (``n_envs`` worlds), trains a warm-up
(past ``learning_starts``), then profiles ``--ticks`` world ticks of training and prints, per part, the share of
the profiled wall time (cumulative time of the functions that make it up; the parts of ``train`` nest inside it):

- ``env step``: the worlds' step (physics, lidar, rewards) through the bridge (``step_wait``);
- ``action selection``: the epsilon-greedy forward pass (``_sample_actions``);
- ``buffer writes``: n-step folding and joint rows (``_store_joint_transition``);
- ``train``: the gradient steps, and inside it ``sampling`` (``sample``), ``loss`` (the forward passes and
  the TD targets: ``_compute_loss``), ``backward``, ``clip`` (``clip_grad_norm_``), ``optimizer`` (Adam's
  ``step``), ``weight average`` (``update_weight_average``), ``targets`` (``_update_targets``);
- ``logging``: ``dump_logs`` and the logger's ``record``.

``--config`` takes a configuration of ``benchmarks/time_to_solution.py`` (a preset name or a JSON dict); with
``overlap_training`` the worlds step in a worker while the main process learns, so ``env step`` is the main process's
wait for them. The shares are ratios inside one process, so a busy machine scales them all alike. Example::

    python benchmarks/profile_training.py --robots 4 8 12 --ticks 4000
    python benchmarks/profile_training.py --robots 4 --config overlap8-b128
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import torch as th
from time_to_solution import ALGORITHMS, build_model, configuration

#: part -> (function name, a piece of its file's path); the cumulative times of matching functions are summed.
PARTS: dict[str, list[tuple[str, str]]] = {
    "env step": [("step_wait", "sb3_eps")],
    "action selection": [("_sample_actions", "sb3_eps")],
    "buffer writes": [("_store_joint_transition", "sb3_eps")],
    "train": [("train", "off_policy")],
    "  sampling": [("sample", "buffers")],
    "  loss": [("_compute_loss", "sb3_eps")],
    "  backward": [("backward", "torch")],
    "  clip": [("clip_grad_norm_", "torch")],
    "  optimizer": [("step", "adam")],
    "  weight average": [("update_weight_average", "sb3_eps")],
    "  targets": [("_update_targets", "sb3_eps")],
    "logging": [("dump_logs", "sb3_eps"), ("record", "logger")],
}


def profile(algo: str, n_robots: int, config: str, ticks: int, warmup: int) -> tuple[dict[str, float], float]:
    """:return: each part's share of the profiled time, and the profiled ticks per second (under the profiler)"""
    model = build_model(algo, configuration(config)[1], f"MultiRobotNav-{n_robots}-v0", seed=0)
    venv = model.get_env()
    model.learn(warmup * venv.n_agents, log_interval=1_000_000)
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    model.learn(ticks * venv.n_agents, reset_num_timesteps=False, log_interval=1_000_000)
    profiler.disable()
    wall = time.perf_counter() - start
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    shares = {}
    for part, matches in PARTS.items():
        total = 0.0
        for (filename, _, name), (_, _, _, cumulative, _) in stats.items():
            if any(name == fn and piece in filename for fn, piece in matches):
                total += cumulative
        shares[part] = total / wall
    venv.close()
    return shares, ticks / wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), default="gdq")
    parser.add_argument("--robots", type=int, nargs="+", default=[4, 8, 12])
    parser.add_argument("--config", default="defaults-2026-12-03", help="a preset of time_to_solution.py or a JSON dict")
    parser.add_argument("--ticks", type=int, default=4_000)
    parser.add_argument("--warmup", type=int, default=2_500, help="ticks before the profile (past learning_starts)")
    args = parser.parse_args()
    th.set_num_threads(1)
    results = {n: profile(args.algo, n, args.config, args.ticks, args.warmup) for n in args.robots}
    print(f"{args.algo}, {args.config}, {args.ticks} profiled ticks after {args.warmup}; share of wall time")
    print("| part | " + " | ".join(f"{n} robots" for n in args.robots) + " |")
    print("|---|" + "---|" * len(args.robots))
    for part in PARTS:
        print(f"| {part} | " + " | ".join(f"{100 * results[n][0][part]:.0f} %" for n in args.robots) + " |")
    print("| ticks/s (profiled) | " + " | ".join(f"{results[n][1]:.0f}" for n in args.robots) + " |")


if __name__ == "__main__":
    main()
