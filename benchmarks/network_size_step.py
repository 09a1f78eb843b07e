"""Does a smaller agent network make GDQ's training tick cheaper? The zoo's 4-robot layout with the default network and
with smaller ones, alternated.

Builds GDQ on ``MultiRobotNav-4-v0`` with the time-to-solution preset ``overlap8-b128`` (8 worlds in a worker, learning
while they step, batch 128) once per network (``--arch``: ``trunk/streams`` hidden sizes, e.g. ``64,64/32``), trains
``--warmup`` ticks, then ``--rounds`` times, network after network: ``--steps`` gradient steps of ``model.train``
alone (milliseconds per step) and ``--ticks`` ticks of ``model.learn`` (ticks per second). Prints each round and the
ratios of the medians against the first network. Example::

    python benchmarks/network_size_step.py --arch 128,64/64 64,64/32 64,64/64
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import torch as th
from time_to_solution import build_model, configuration


def parse_arch(text: str) -> dict[str, Any]:
    """``"128,64/64"`` -> ``{"net_arch": [128, 64], "stream_arch": [64]}``."""
    trunk, streams = text.split("/")
    return {"net_arch": [int(x) for x in trunk.split(",")], "stream_arch": [int(x) for x in streams.split(",")]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--arch", nargs="+", default=["128,64/64", "64,64/32"], help="the first is the reference")
    parser.add_argument("--warmup", type=int, default=3_000, help="ticks of training before timing")
    parser.add_argument("--steps", type=int, default=300, help="timed gradient steps per measurement")
    parser.add_argument("--ticks", type=int, default=4_000, help="timed ticks of learn() per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    th.set_num_threads(1)
    base = configuration("overlap8-b128")[1]
    models = {
        arch: build_model("gdq", {**base, "policy_kwargs": parse_arch(arch)}, "MultiRobotNav-4-v0", 0) for arch in args.arch
    }
    for model in models.values():
        model.learn(args.warmup * model.get_env().n_agents, log_interval=10**9)
    step_ms: dict[str, list[float]] = {arch: [] for arch in args.arch}
    rates: dict[str, list[float]] = {arch: [] for arch in args.arch}
    for round_ in range(args.rounds):
        for arch, model in models.items():
            start = time.perf_counter()
            model._trained_ahead = False  # a step trained during the worlds' last step would be skipped
            model.train(args.steps, model.batch_size)
            step_ms[arch].append((time.perf_counter() - start) / args.steps * 1e3)
            start = time.perf_counter()
            model.learn(args.ticks * model.get_env().n_agents, reset_num_timesteps=False, log_interval=10**9)
            rates[arch].append(args.ticks / (time.perf_counter() - start))
            print(f"round {round_}: {arch}: {step_ms[arch][-1]:.2f} ms per gradient step, {rates[arch][-1]:.0f} ticks/s")
    reference = args.arch[0]
    for arch in args.arch[1:]:
        step = statistics.median(step_ms[reference]) / statistics.median(step_ms[arch])
        tick = statistics.median(rates[arch]) / statistics.median(rates[reference])
        print(f"{arch} against {reference}: gradient step {step:.2f}x faster, ticks per second {tick:.2f}x")
    for model in models.values():
        model.get_env().close()


if __name__ == "__main__":
    main()
