"""Two Python-API training runs side by side against one alone, with the package's thread setting and with torch's.

Each run is the README's Python path (``GDQ("MlpPolicy", make_vec_env("MultiRobotNav-2-v0", n_envs=4))``, package
defaults) in its own process: a warm-up of ``--warmup`` agent-steps, then ``--steps`` timed agent-steps. The
processes are started the way a user's script starts: ``package`` leaves the thread count to the model (one thread,
``set_torch_threads`` in ``sb3_eps/common/off_policy.py``); ``torch-default`` sets torch back to one thread per core
after the model is built, as torch has it when nothing sets the threads (the package before 2026-12-03).
Prints agent-steps/s of one run alone and of each of two runs at once, and their ratio, for both settings, measured
in one invocation (run it on a quiet machine).

    python benchmarks/threads_side_by_side.py
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = """
import json, sys, time
import torch as th
import envs
from sb3_eps import GDQ, make_vec_env
model = GDQ("MlpPolicy", make_vec_env("MultiRobotNav-2-v0", n_envs=4, seed=0), seed=0, learning_starts=500)
if {torch_default}:  # after the model: what a run gets where nothing sets the threads (torch's one per core)
    th.set_num_threads({cores})
model.learn({warmup})
start = time.perf_counter()
model.learn({steps}, reset_num_timesteps=False)
print(json.dumps({{"steps_per_s": {steps} / (time.perf_counter() - start), "threads": th.get_num_threads()}}))
"""


def run(n_parallel: int, torch_default: bool, warmup: int, steps: int) -> list[dict[str, float]]:
    """Start ``n_parallel`` runs at once and return what each printed."""
    code = CHILD.format(torch_default=torch_default, cores=os.cpu_count() or 1, warmup=warmup, steps=steps)
    environ = {key: value for key, value in os.environ.items() if key != "OMP_NUM_THREADS"}
    processes = [
        subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=environ)
        for _ in range(n_parallel)
    ]
    return [json.loads(process.communicate()[0].strip().splitlines()[-1]) for process in processes]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--warmup", type=int, default=2_000)
    parser.add_argument("--steps", type=int, default=8_000)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    print(f"{os.cpu_count()} cores; {args.steps} timed agent-steps per run after {args.warmup}")
    for torch_default in (False, True):
        alone, pair = [], []
        for _ in range(args.repeats):  # alternated, so drifts of the machine fall on both
            alone += [r["steps_per_s"] for r in run(1, torch_default, args.warmup, args.steps)]
            pair += [r["steps_per_s"] for r in run(2, torch_default, args.warmup, args.steps)]
        one, two = sorted(alone)[len(alone) // 2], sorted(pair)[len(pair) // 2]
        name = "torch-default" if torch_default else "package"
        print(
            f"{name:14s} one alone {one:7.0f} agent-steps/s; two at once {two:7.0f} each; ratio {two / one:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
