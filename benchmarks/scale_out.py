"""Scale-out, measured side by side in one run: worlds in worker processes against in process, and a grid of runs
on the local backend against the same runs one after another.

- **env**: ``MultiRobotNav-4-v0``, random actions drawn in advance, ``n`` worlds (4 and 8) in process
  (``DummyVecEnv``), with ``SubprocVecEnv``'s default layout (``subproc``: on ``C`` cores the main process steps
  one block of worlds itself while ``C - 1`` workers step the others, polling their pipes between steps) and with
  every world in workers (``workers``: one per core, no polling: the layout before the default changed),
  interleaved repeats, median wall time and the median of the repeats' ratios; robot-steps per second and the
  ratios to in-process.
- **parts**: where the time of a step of the default layout goes (sending the actions, the main process's own
  block, waiting for and reading the workers' replies, the rest), what a block of worlds costs alone and while
  another process steps worlds on the other core (the cores share hardware: contention).
- **train**: GDQ on the same worlds in process, in the default layout, and with every world in ``C - 1`` workers
  while the main process learns (``overlap_training=True``, ``main_worlds=0``), after a warm-up, the models
  training in turns of ``--train-steps / --train-slices`` agent-steps (a slow spell of the machine falls on
  all), torch on one thread in the main process, with the settings of ``benchmarks/train_throughput.py`` (package
  defaults, one gradient step every 4 vector steps) and with its ``zoo_configs/gdq.yml`` entry for
  ``MultiRobotNav-4-v0`` (one gradient step per vector step); ticks per second and the ratios. Without overlap,
  only the env part of a tick runs in the workers (Amdahl: the more learning per tick, the smaller the gain);
  with it, a tick costs about the larger of its learning and its env step.
- **projection**: from the measured cost of one world tick in process (``t_w``) and the measured cost per extra
  process of the default layout (``c``: a step of ``S`` processes, the main one and ``S - 1`` workers, holding
  ``n / S`` worlds each costs ``(n / S) t_w + (S - 1) c``), the ratio expected with ``K`` cores, for env stepping
  and for training (the rest of a training tick, measured in process, stays in the main process). ``c`` holds
  this machine's contention between its two cores, so the projection is a guess: measure there.
- **grid**: 4 GDQ runs (``MultiRobotNav-2-v0``, seeds 0-3) with ``python -m
  sb3_eps.grid`` on the local backend (one run per core) against the same 4 runs with ``--n-jobs 1`` (one after
  another); wall times and their ratio.

- **latency**: what one parallel round costs on this machine, without any env: 2 processes burning 0.5 ms each
  on command against 1 ms in one process, with and without a 0.3 ms gap between rounds.

Targets (issue 11, 2-core machine): env >= 1.5x with 4 worlds, GDQ training >= 1.2x per tick with 4 worlds,
grid <= 0.6x the time of its runs in sequence. Speed-ups need a quiet machine: the script prints the load
average before and after.

    python benchmarks/scale_out.py [--parts latency env parts train grid] [--worlds 4 8] [--repeats 3]
        [--train-steps 8000 --train-slices 8]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_eps import make_vec_env
from sb3_eps.common.subproc_vec_env import available_cores
from sb3_eps.grid import Grid, run_grid
from sb3_eps.zoo.config import resolve_config
from sb3_eps.zoo.schema import algorithm_kwargs

ENV_ID = "MultiRobotNav-4-v0"
#: in process; SubprocVecEnv's default layout; every world in a worker (one per core, the earlier default)
MODES = ("dummy", "subproc", "workers")
#: training: in process; the default layout; every world in workers while the main process learns (overlap_training)
TRAIN_MODES = ("dummy", "subproc", "overlap")


def make(mode: str, n_worlds: int, seed: int = 0) -> Any:
    if mode in ("workers", "overlap"):
        # overlap: the main process learns while the workers step, so it keeps no worlds and leaves them a core
        one_per_core = max(1, min(n_worlds, available_cores()))
        workers = one_per_core if mode == "workers" else max(1, one_per_core - 1)
        kwargs = {"n_workers": workers, "main_worlds": 0}
        return make_vec_env(ENV_ID, n_envs=n_worlds, seed=seed, vec_env_cls="subproc", vec_env_kwargs=kwargs)
    return make_vec_env(ENV_ID, n_envs=n_worlds, seed=seed, vec_env_cls=mode)


def load() -> str:
    return " ".join(f"{value:.2f}" for value in os.getloadavg())


def env_seconds(venv: Any, actions: np.ndarray) -> float:
    venv.reset()
    start = time.perf_counter()
    for action in actions:
        venv.step(action)
    return (time.perf_counter() - start) / len(actions)


#: GDQ settings of the train part: ``throughput`` is benchmarks/train_throughput.py's (package defaults, a batch of
#: 64 joint rows, one gradient step every 4 vector steps), ``zoo`` the zoo_configs/gdq.yml entry of the env (one
#: gradient step per vector step, 30-step returns, recomputed global values: far more learning per tick).
TRAIN_CONFIGS = ("throughput", "zoo")


def gdq_kwargs(config: str) -> dict[str, Any]:
    if config == "zoo":
        config = resolve_config("gdq", ENV_ID)
        return algorithm_kwargs(config.entry, config.spec)
    return {"batch_size": 64, "train_freq": 4, "gradient_steps": 1, "buffer_size": 50_000}


def train_models(n_worlds: int, warmup: int, config: str) -> dict[str, Any]:
    """One GDQ per mode on the same worlds and seed, after a warm-up (they train the same numbers)."""
    from sb3_eps.gdq import GDQ

    models = {}
    for mode in TRAIN_MODES:
        kwargs = gdq_kwargs(config)
        kwargs["learning_starts"] = warmup // 2
        kwargs["overlap_training"] = mode == "overlap"
        models[mode] = GDQ("MlpPolicy", make(mode, n_worlds), seed=0, **kwargs)
        models[mode].learn(warmup)
        _time_steps(models[mode].env)
    return models


def _time_steps(venv: Any) -> None:
    """Sum the wall time of ``venv``'s ``step_wait`` in ``venv.step_seconds`` (the env part of a training tick)."""
    inner = venv.step_wait
    venv.step_seconds = 0.0

    def timed() -> Any:
        start = time.perf_counter()
        result = inner()
        venv.step_seconds += time.perf_counter() - start
        return result

    venv.step_wait = timed


def env_part(args: argparse.Namespace, results: dict[str, Any]) -> None:
    for n_worlds in args.worlds:
        venvs = {mode: make(mode, n_worlds) for mode in MODES}
        actions = np.random.default_rng(0).integers(5, size=(args.env_steps, n_worlds * 4))
        for mode in MODES[1:]:
            env_seconds(venvs[mode], actions[:50])  # warm-up: the workers' first steps
        samples: dict[str, list[float]] = {mode: [] for mode in MODES}
        for _ in range(args.repeats):
            for mode in MODES:
                samples[mode].append(env_seconds(venvs[mode], actions))
        step = {mode: statistics.median(values) for mode, values in samples.items()}
        paired = {mode: statistics.median(d / w for d, w in zip(samples["dummy"], samples[mode])) for mode in MODES[1:]}
        default = venvs["subproc"]
        processes = default.n_workers + (1 if default.main_worlds else 0)
        t_w = step["dummy"] / n_worlds
        c = (step["subproc"] - n_worlds / processes * t_w) / max(processes - 1, 1)
        results[f"env{n_worlds}"] = {"step": step, "t_w": t_w, "c": c, "processes": processes}
        layout = f"main {default.main_worlds} + {default.n_workers} worker(s), spin {default.spin_s * 1e3:g} ms"
        for venv in venvs.values():
            venv.close()
        robots = n_worlds * 4
        print(
            f"env   {n_worlds} worlds: in process {robots / step['dummy']:8.0f} robot-steps/s; default layout "
            f"({layout}) {robots / step['subproc']:8.0f} -> {step['dummy'] / step['subproc']:.2f}x; "
            f"all in {venvs['workers'].n_workers} workers {robots / step['workers']:8.0f} -> "
            f"{step['dummy'] / step['workers']:.2f}x  (t_w {t_w * 1e6:.0f} us/world tick, c {c * 1e6:.0f} us)",
            flush=True,
        )
        print(
            f"      median of the {args.repeats} repeats' ratios: default layout {paired['subproc']:.2f}x, all in "
            f"workers {paired['workers']:.2f}x; us/step of each repeat: "
            + "; ".join(f"{mode} {[round(value * 1e6) for value in samples[mode]]}" for mode in MODES),
            flush=True,
        )


def _step_block_forever(n_worlds: int, stop: Any) -> None:
    venv = make_vec_env(ENV_ID, n_envs=n_worlds, seed=1)
    venv.reset()
    actions = np.zeros(venv.num_envs, dtype=np.int64)
    while not stop.is_set():
        venv.step(actions)


def parts_part(args: argparse.Namespace, results: dict[str, Any]) -> None:
    """Where a step of the default layout goes, and what the two cores cost each other."""
    import multiprocessing as mp

    n_worlds = args.worlds[0]
    venv = make("subproc", n_worlds)
    assert venv._local is not None, "the default layout holds a block in the main process (>= 2 cores)"
    actions = np.random.default_rng(0).integers(5, size=(args.env_steps, venv.num_envs))
    venv.reset()
    times: dict[str, list[float]] = {"send": [], "own block": [], "wait + read replies": [], "rest": []}
    for _ in range(min(args.repeats, 5)):
        for action in actions:
            t0 = time.perf_counter()
            venv.step_async(action)
            for i, part in enumerate(venv._slices):
                venv._send_step(i, action[part], False)
            t1 = time.perf_counter()
            venv._local.handle("step", (action[venv._main_slice], False))
            t2 = time.perf_counter()
            venv._gather(range(venv.n_workers), "step")
            t3 = time.perf_counter()
            venv.step(action)  # a whole step, for the rest (joining the parts): its time minus the parts above
            t4 = time.perf_counter()
            times["send"].append(t1 - t0)
            times["own block"].append(t2 - t1)
            times["wait + read replies"].append(t3 - t2)
            times["rest"].append((t4 - t3) - (t3 - t0))
    layout = f"main {venv.main_worlds} worlds + {venv.n_workers} worker(s)"
    venv.close()
    whole = np.array(times["send"]) + times["own block"] + times["wait + read replies"] + times["rest"]
    print(
        f"whole steps of the default layout (us): mean {whole.mean() * 1e6:.0f}, median "
        f"{np.median(whole) * 1e6:.0f}, 90th percentile {np.percentile(whole, 90) * 1e6:.0f}",
        flush=True,
    )
    cells = ", ".join(f"{name} {statistics.median(values) * 1e6:.0f}" for name, values in times.items())
    print(f"parts of a step, {n_worlds} worlds, {layout} (median us): {cells}", flush=True)
    # One block of worlds alone, and while a second process steps as many worlds on the other core.
    block = n_worlds // 2
    alone_venv = make_vec_env(ENV_ID, n_envs=block, seed=0)
    block_actions = actions[:, : block * 4]
    env_seconds(alone_venv, block_actions[:50])
    context = mp.get_context("fork")
    samples: dict[str, list[float]] = {"alone": [], "beside another": []}
    for _ in range(min(args.repeats, 5)):
        samples["alone"].append(env_seconds(alone_venv, block_actions))
        stop = context.Event()
        other = context.Process(target=_step_block_forever, args=(block, stop), daemon=True)
        other.start()
        time.sleep(1.0)  # built and stepping
        samples["beside another"].append(env_seconds(alone_venv, block_actions))
        stop.set()
        other.join()
    alone_venv.close()
    alone, beside = (statistics.median(values) for values in samples.values())
    print(
        f"contention: a step of {block} worlds alone {alone * 1e6:.0f} us, while another process steps {block} "
        f"worlds on the other core {beside * 1e6:.0f} us (+{(beside / alone - 1) * 100:.0f} %)",
        flush=True,
    )


def train_part(args: argparse.Namespace, results: dict[str, Any]) -> None:
    """Both modes train in rotating slices of ``train_steps / train_slices`` agent-steps, so that a slow minute of
    the machine falls on both; wall seconds per tick summed over the slices, and the median of the slice ratios."""
    for config in args.train_configs:
        for n_worlds in args.worlds:
            models = train_models(n_worlds, args.warmup, config)
            n_agents = models["dummy"].env.n_agents
            size = args.train_steps // args.train_slices
            seconds: dict[str, list[float]] = {mode: [] for mode in TRAIN_MODES}
            for _ in range(args.train_slices):
                for mode, model in models.items():
                    start = time.perf_counter()
                    model.learn(size, reset_num_timesteps=False)
                    seconds[mode].append(time.perf_counter() - start)
            n_steps = args.train_slices * size / (n_agents * n_worlds)  # vector steps per mode
            parts = {mode: (sum(seconds[mode]) / n_steps, model.env.step_seconds / n_steps) for mode, model in models.items()}
            for model in models.values():
                model.env.close()
            tick = {mode: sum(values) / (len(values) * size / n_agents) for mode, values in seconds.items()}
            paired = {
                mode: statistics.median(d / w for d, w in zip(seconds["dummy"], seconds[mode])) for mode in TRAIN_MODES[1:]
            }
            if config == args.train_configs[0]:
                results[f"train{n_worlds}"] = tick
            print(
                f"train GDQ ({config} settings) {n_worlds} worlds: in process {1 / tick['dummy']:5.0f} ticks/s, "
                f"default layout {1 / tick['subproc']:5.0f} ticks/s -> {tick['dummy'] / tick['subproc']:.2f}x per tick "
                f"(median of {args.train_slices} slice ratios {paired['subproc']:.2f}x); learning while all worlds "
                f"step in workers (overlap_training) {1 / tick['overlap']:5.0f} ticks/s -> "
                f"{tick['dummy'] / tick['overlap']:.2f}x (slice median {paired['overlap']:.2f}x)",
                flush=True,
            )
            print(
                "      per vector step: "
                + "; ".join(
                    f"{mode} {total * 1e6:.0f} us = env step {env * 1e6:.0f} + the rest {(total - env) * 1e6:.0f}"
                    for mode, (total, env) in parts.items()
                ),
                flush=True,
            )


def projection(results: dict[str, Any]) -> None:
    print("\nprojection (model: a step of S processes = (n/S) t_w + (S-1) c; measured t_w, c; the rest of a training")
    print("tick stays in the main process):")
    for n_worlds in (8, 16, 32):
        source = results.get(f"env{n_worlds}") or results.get("env8") or results.get("env4")
        if source is None:
            return
        t_w, c = source["t_w"], max(source["c"], 0.0)
        rest = None
        for key in ("train8", "train4"):
            if key in results and f"env{key[5:]}" in results:
                rest = results[key]["dummy"] - results[f"env{key[5:]}"]["step"]["dummy"] / int(key[5:])
                break
        cells = []
        for cores in (2, 4, 8, 16):
            processes = min(cores, n_worlds)
            step = n_worlds / processes * t_w + (processes - 1) * c
            env_ratio = (n_worlds * t_w) / step
            cell = f"{cores:>2} cores: env {env_ratio:5.2f}x"
            if rest is not None:
                in_process = t_w + rest
                with_workers = step / n_worlds + rest
                cell += f", GDQ {in_process / with_workers:4.2f}x"
            cells.append(cell)
        print(f"  {n_worlds:>2} worlds | " + " | ".join(cells))


def grid_part(args: argparse.Namespace, results: dict[str, Any]) -> None:
    grid = Grid(
        algos=["gdq"], envs=["MultiRobotNav-2-v0"], seeds=[0, 1, 2, 3], n_timesteps=args.grid_steps,
        train_args=["--eval-freq", "0", "--verbose", "0", "--hyperparams", "n_envs:1"],
    )  # fmt: skip
    samples: dict[str, list[float]] = {"sequence": [], "grid": []}
    for _ in range(args.grid_repeats):
        for name, n_jobs in (("sequence", 1), ("grid", None)):
            with tempfile.TemporaryDirectory() as folder:
                start = time.perf_counter()
                reports = run_grid(grid, Path(folder), n_jobs=n_jobs, verbose=0)
                samples[name].append(time.perf_counter() - start)
                assert all(report["status"] == "complete" for report in reports), reports
    wall = {name: statistics.median(values) for name, values in samples.items()}
    print(
        f"grid  4 runs ({args.grid_steps} agent-steps each): one after another {wall['sequence']:.1f} s, "
        f"local backend ({os.cpu_count()} side by side) {wall['grid']:.1f} s -> "
        f"{wall['grid'] / wall['sequence']:.2f}x the time",
        flush=True,
    )


def _burn(seconds: float) -> None:
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        pass


def _burn_worker(remote: Any) -> None:
    while (seconds := remote.recv()) is not None:
        _burn(seconds)
        remote.send(None)


def latency_part(args: argparse.Namespace, results: dict[str, Any]) -> None:
    """The machine's cost of one parallel round: 2 processes burning 0.5 ms each on command (the shape of a step of 4
    worlds in 2 workers) against 1 ms in one process, with and without a 0.3 ms gap between rounds (the main
    process's own work between steps, while the workers sleep)."""
    import multiprocessing as mp

    context = mp.get_context("fork")
    remotes, processes = [], []
    for _ in range(2):
        remote, child = context.Pipe()
        process = context.Process(target=_burn_worker, args=(child,), daemon=True)
        process.start()
        remotes.append(remote)
        processes.append(process)
    rounds = 1000
    for gap in (0.0, 0.0003):
        start = time.perf_counter()
        for _ in range(rounds):
            _burn(0.001)
            _burn(gap)
        serial = (time.perf_counter() - start) / rounds
        start = time.perf_counter()
        for _ in range(rounds):
            for remote in remotes:
                remote.send(0.0005)
            for remote in remotes:
                remote.recv()
            _burn(gap)
        parallel = (time.perf_counter() - start) / rounds
        overhead = parallel - 0.0005 - gap
        print(
            f"round 2 x 0.5 ms of work, gap {gap * 1e3:.1f} ms: serial {serial * 1e6:.0f} us, 2 processes "
            f"{parallel * 1e6:.0f} us -> {serial / parallel:.2f}x (overhead of a round {overhead * 1e6:.0f} us)",
            flush=True,
        )
    for remote, process in zip(remotes, processes):
        remote.send(None)
        process.join()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parts = ["latency", "env", "parts", "train", "grid"]
    parser.add_argument("--parts", nargs="+", default=parts, choices=parts)
    parser.add_argument("--worlds", nargs="+", type=int, default=[4, 8])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--env-steps", type=int, default=200, help="vector steps per env measurement")
    parser.add_argument("--warmup", type=int, default=2_000, help="agent-steps before timing training")
    parser.add_argument("--train-steps", type=int, default=8_000, help="timed agent-steps of training per mode")
    parser.add_argument("--train-slices", type=int, default=8, help="slices the modes train in, in turn")
    parser.add_argument("--train-configs", nargs="+", default=list(TRAIN_CONFIGS), choices=TRAIN_CONFIGS)
    parser.add_argument("--grid-steps", type=int, default=4_000, help="agent-steps of each grid run")
    parser.add_argument("--grid-repeats", type=int, default=1)
    args = parser.parse_args()
    th.set_num_threads(1)
    print(
        f"{os.cpu_count()} cores; torch threads in the main process: {th.get_num_threads()}; load average before: {load()}",
        flush=True,
    )
    results: dict[str, Any] = {}
    if "latency" in args.parts:
        latency_part(args, results)
    if "env" in args.parts:
        env_part(args, results)
    if "parts" in args.parts:
        parts_part(args, results)
    if "train" in args.parts:
        train_part(args, results)
    if "env" in args.parts:
        projection(results)
    if "grid" in args.parts:
        grid_part(args, results)
    print(f"load average after: {load()}")


if __name__ == "__main__":
    main()
