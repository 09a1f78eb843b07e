"""Long-run soak test (``make soak``): memory growth, PyBullet clients and child processes over a long EPS-GDQ run.

One training run through the command line's own machinery (``sb3_eps.zoo.exp_manager.train``: run folder,
periodic checkpoints, team evaluations, EPS rounds in worker processes) of EPS-GDQ on ``MultiRobotNav-8-v0`` for
``--n-timesteps`` agent-steps (default 1,000,000) with an EPS round every ``--eps-period`` agent-steps (default
20,000, i.e. ``period_unit="ticks"``, ``period = 20,000 / 8`` ticks). Every ``--sample-freq`` agent-steps
(default 50,000) it records the resident memory of the training process, its child processes (the EPS workers)
and the PyBullet clients open in the training process, and the fill of the replay buffer.

Pass criteria (issue 13): once the replay buffer is full, resident memory grows by less than ``--max-growth-mb``
(default 50 MB) up to the end; the PyBullet clients and child processes after the run equal those before it.
The script prints a Markdown table and writes every sample to ``--out`` (JSON). Exit status 1 when a criterion
fails.

Usage::

    python benchmarks/soak.py [--n-timesteps 1000000] [--out logs/soak/soak.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from envs.turtlebot3.world import p  # pybullet, imported without its banner
from sb3_eps.version import __version__
from sb3_eps.zoo.cli import TrainOptions
from sb3_eps.zoo.exp_manager import train

ENV_ID = "MultiRobotNav-8-v0"
N_AGENTS = 8
#: PyBullet keeps its clients in a fixed table; ids are probed up to this bound.
MAX_PYBULLET_CLIENTS = 1024


def open_pybullet_clients() -> int:
    """:return: the PyBullet clients connected in this process."""
    return sum(bool(p.isConnected(physicsClientId=client)) for client in range(MAX_PYBULLET_CLIENTS))


def child_processes() -> list[int]:
    """:return: the process ids of this process's children (recursively)."""
    return [child.pid for child in psutil.Process().children(recursive=True)]


def resident_mb() -> float:
    """:return: the resident memory of this process in MB (10^6 bytes)."""
    return psutil.Process().memory_info().rss / 1e6


class SoakProbe(BaseCallback):
    """Records memory, children, PyBullet clients and buffer fill every ``sample_freq`` timesteps.

    :param sample_freq: timesteps (agent-steps) between samples
    """

    def __init__(self, sample_freq: int) -> None:
        super().__init__()
        self.sample_freq = sample_freq
        self.next_sample = 0
        self.samples: list[dict[str, Any]] = []
        self.eps_callbacks: list[Any] = []
        self._start = time.perf_counter()

    def _on_training_start(self) -> None:
        # learn()'s locals hold the CallbackList; the EPS callback is the one counting rounds.
        siblings = getattr(self.locals.get("callback"), "callbacks", [])
        self.eps_callbacks = [callback for callback in siblings if hasattr(callback, "n_rounds")]
        self._start = time.perf_counter()
        self._sample()

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next_sample:
            self._sample()
        return True

    def _on_training_end(self) -> None:
        self._sample()

    def _sample(self) -> None:
        self.next_sample = (self.num_timesteps // self.sample_freq + 1) * self.sample_freq
        model: Any = self.model
        buffer = model.replay_buffer
        eps = self.eps_callbacks
        record = {
            "timesteps": int(self.num_timesteps),
            "ticks": int(model.ticks),
            "seconds": round(time.perf_counter() - self._start, 1),
            "rss_mb": round(resident_mb(), 1),
            "children": len(child_processes()),
            "pybullet_clients": open_pybullet_clients(),
            "buffer_rows": int(buffer.size()),
            "buffer_full": bool(buffer.full),
            "eps_rounds": sum(int(callback.n_rounds) for callback in eps),
            "eps_skipped_rounds": sum(int(callback.n_skipped_rounds) for callback in eps),
        }
        self.samples.append(record)
        print("soak:", json.dumps(record), flush=True)


def git_commit() -> str:
    """:return: the commit of the checkout the script runs from ('unknown' outside a git checkout)."""
    try:
        output = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent
        )
    except OSError:
        return "unknown"
    return output.stdout.strip() or "unknown"


def summarise(samples: list[dict[str, Any]], before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """:return: the pass criteria measured on the samples.

    Growth is measured on the samples taken every ``--sample-freq`` timesteps during training (all at the same
    point of the loop): the largest of them after the buffer is full minus the first one with a full buffer. The
    extra sample taken when training ends (after the last EPS round, whose Eq. 6 per-sample gradients are a
    transient of about 50-100 MB of torch memory on this network) is reported as ``rss_at_training_end_mb``.
    """
    in_training = samples[:-1] if len(samples) > 1 else samples
    full = [sample for sample in in_training if sample["buffer_full"]]
    summary: dict[str, Any] = {
        "before": before,
        "after": after,
        "clients_equal": before["pybullet_clients"] == after["pybullet_clients"],
        "children_equal": before["children"] == after["children"],
    }
    if full:
        baseline = full[0]["rss_mb"]
        summary.update(
            buffer_full_at=full[0]["timesteps"],
            rss_at_buffer_full_mb=baseline,
            rss_max_after_full_mb=max(sample["rss_mb"] for sample in full),
            rss_end_mb=full[-1]["rss_mb"],
            growth_after_full_mb=round(max(sample["rss_mb"] for sample in full) - baseline, 1),
            rss_at_training_end_mb=samples[-1]["rss_mb"],
        )
    return summary


def markdown(samples: list[dict[str, Any]]) -> str:
    """:return: the samples as a Markdown table."""
    lines = [
        "| agent-steps | ticks | minutes | RSS MB | children | PyBullet clients | buffer rows | EPS rounds (skipped) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for sample in samples:
        lines.append(
            f"| {sample['timesteps']:,} | {sample['ticks']:,} | {sample['seconds'] / 60:.1f} | {sample['rss_mb']:.0f} "
            f"| {sample['children']} | {sample['pybullet_clients']} | {sample['buffer_rows']:,}"
            f"{' (full)' if sample['buffer_full'] else ''} | {sample['eps_rounds']} ({sample['eps_skipped_rounds']}) |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-n", "--n-timesteps", type=int, default=1_000_000, help="agent-steps")
    parser.add_argument("--eps-period", type=int, default=20_000, help="agent-steps between EPS rounds")
    parser.add_argument("--sample-freq", type=int, default=50_000, help="agent-steps between samples")
    parser.add_argument("--max-growth-mb", type=float, default=50.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-f", "--log-folder", default=None, help="run folder parent (default: a temporary one)")
    parser.add_argument("--out", default="logs/soak/soak.json", help="JSON record of every sample")
    parser.add_argument("--summarise", default=None, metavar="JSON", help="only summarise a recorded run")
    args = parser.parse_args()
    if args.summarise is not None:
        record = json.loads(Path(args.summarise).read_text())
        old = record["summary"]
        summary = {**old, **summarise(record["samples"], old["before"], old["after"])}
        summary["growth_ok"] = summary["growth_after_full_mb"] < args.max_growth_mb
        print(markdown(record["samples"]))
        print(json.dumps(summary, indent=2))
        return 0 if summary["growth_ok"] and summary["clients_equal"] and summary["children_equal"] else 1

    before = {"pybullet_clients": open_pybullet_clients(), "children": len(child_processes())}
    folder = args.log_folder or tempfile.mkdtemp(prefix="sb3_eps_soak_")
    options = TrainOptions(
        algo="eps_gdq", env=ENV_ID, n_timesteps=args.n_timesteps, seed=args.seed, folder=folder,
        eval_freq=250_000, eval_episodes=4, n_eval_envs=2, save_freq=100_000, device="cpu", verbose=0,
        # Every round runs (no EPS tick budget): the soak is about leaks over many rounds.
        hyperparams=[
            "callback.period_unit:ticks", f"callback.period:{args.eps_period // N_AGENTS}", "callback.max_eps_share:null"
        ],
    )  # fmt: skip
    probe = SoakProbe(args.sample_freq)
    start = time.perf_counter()
    result = train(options, extra_callbacks=[probe])
    wall = time.perf_counter() - start
    after = {"pybullet_clients": open_pybullet_clients(), "children": len(child_processes())}
    summary = summarise(probe.samples, before, after)
    growth_ok = summary.get("growth_after_full_mb", float("inf")) < args.max_growth_mb
    summary.update(
        growth_ok=growth_ok,
        max_growth_mb=args.max_growth_mb,
        wall_minutes=round(wall / 60, 1),
        run_dir=str(result.run_dir),
        status=result.status,
        n_timesteps=args.n_timesteps,
        eps_period_agent_steps=args.eps_period,
        sb3_eps_version=__version__,
        commit=git_commit(),
        torch=th.__version__,
        python=platform.python_version(),
        cpus=os.cpu_count(),
        load_average_at_end=os.getloadavg(),
    )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"summary": summary, "samples": probe.samples}, indent=2))
    print(markdown(probe.samples))
    print(json.dumps(summary, indent=2))
    passed = growth_ok and summary["clients_equal"] and summary["children_equal"]
    print(f"soak {'PASSED' if passed else 'FAILED'}; record: {out}", flush=True)
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
