"""Bit-identical guard for refactors: train small seeded runs and print a SHA-256 of each final policy state_dict
and of its replay buffer's contents.

Run it before and after a change that must not alter learning and compare the lines (issue 56 keeps
``benchmarks/learning_hashes_before.txt``)::

    python benchmarks/learning_hashes.py > /tmp/after.txt && diff benchmarks/learning_hashes_before.txt /tmp/after.txt

Runs (all on ``MultiRobotNav-2-v0``, 2 worlds, in one process, ``n_workers=0``): GDQ, QMIX and IQL with their
package defaults and ``learning_starts`` lowered so that they train; EPS-GDQ with a round forced early (default
evaluation world, ``period=200`` ticks, no budget share); a population of two GDQ learners with a copy and a safe
mutation (``PopulationTrainer``); the zoo's ``population:`` key through ``python -m sb3_eps.train`` with a
distillation crossover. About a minute on 2 cores.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import importlib.util
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th

import envs  # noqa: F401  (registers the env ids)
from sb3_eps import GDQ, IQL, QMIX, EvolutionCallback, make_vec_env

ENV_ID = "MultiRobotNav-2-v0"
TIMESTEPS = 3_000  # agent-steps: 1,500 ticks of 2 robots in each of 2 worlds = 750 ticks per world
COMMON: dict[str, Any] = {"learning_starts": 400, "buffer_size": 5_000, "batch_size": 32, "seed": 0, "verbose": 0}


def state_dict_hash(module: th.nn.Module) -> str:
    """SHA-256 over every tensor of ``module.state_dict()``, in order, with its name, dtype and shape."""
    digest = hashlib.sha256()
    for name, tensor in module.state_dict().items():
        array = tensor.detach().cpu().contiguous().numpy()
        digest.update(f"{name}:{array.dtype}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def buffer_hash(buffer: Any) -> str:
    """SHA-256 over the filled part of a joint replay buffer (every array it stores) and its position."""
    digest = hashlib.sha256()
    size = buffer.buffer_size if buffer.full else buffer.pos
    digest.update(f"pos={buffer.pos} full={buffer.full}".encode())
    for name in sorted(vars(buffer)):
        value = getattr(buffer, name)
        if isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == buffer.buffer_size:
            digest.update(name.encode())
            digest.update(np.ascontiguousarray(value[:size]).tobytes())
    return digest.hexdigest()


def _venv() -> Any:
    return make_vec_env(ENV_ID, n_envs=2, seed=0)


def run_gdq() -> Any:
    return GDQ("MlpPolicy", _venv(), **COMMON).learn(TIMESTEPS)


def run_qmix() -> Any:
    return QMIX("MlpPolicy", _venv(), **COMMON).learn(TIMESTEPS)


def run_iql() -> Any:
    return IQL("MlpPolicy", _venv(), **COMMON).learn(TIMESTEPS)


def run_eps_gdq() -> Any:
    eps = EvolutionCallback(
        period=200, population_size=3, n_eval_episodes=1, n_reevaluation_episodes=0, min_gain=0.0,
        fitness="return", max_eps_share=None, n_workers=0, diagnostics_path="", seed=0,
    )  # fmt: skip
    model = GDQ("MlpPolicy", _venv(), **COMMON)
    model.learn(TIMESTEPS, callback=eps)
    if not eps.records.n_crossovers:
        raise RuntimeError(f"EPS made no crossover in {len(eps.records.history)} rounds: the guard would not cover it")
    return model


def run_population() -> Any:
    # The trainer moved under research/ in issue 56; the guard finds it where it lives.
    for module_name in ("research.population", "sb3_eps.eps.population"):
        try:
            trainer_class = importlib.import_module(module_name).PopulationTrainer
            break
        except (ImportError, AttributeError):
            continue
    trainer = trainer_class(GDQ, ENV_ID, k=2, n_envs=2, interval=600, turn_ticks=200, share_buffer=True,
                            fitness="return", fitness_episodes=1, seed=0, **{k: v for k, v in COMMON.items() if k != "seed"})  # fmt: skip
    trainer.learn(TIMESTEPS)  # world ticks, both learners together
    if not any("fittest" in record for record in trainer.history):
        raise RuntimeError("the population made no copy: the guard would not cover it")
    return trainer


def run_population_distill() -> Any:
    """The zoo's ``population:`` key through the training command (the shipped config's header), distillation
    crossover: the final model and the population's file are hashed."""
    import pathlib
    import shutil
    import tempfile

    from sb3_eps import train

    folder = pathlib.Path(tempfile.mkdtemp(prefix="learning_hashes_"))
    conf = folder / "population.yml"
    conf.write_text(ZOO_POPULATION)
    flags = ["--eval-freq", "1000", "--eval-episodes", "1", "--n-eval-envs", "1", "--verbose", "0"]
    if importlib.util.find_spec("research.population") is not None:  # the key's plug-in since issue 56
        flags += ["--gym-packages", "research.population"]
    argv = ["--algo", "gdq", "--env", ENV_ID, "-conf", str(conf), "--seed", "0", "-f", str(folder / "logs"), *flags]
    try:
        if train.main(argv) != 0:
            raise RuntimeError("the population run failed")
        (run,) = (folder / "logs" / "gdq").iterdir()
        selections = (run / "population_selections.jsonl").read_text()
        model = GDQ.load(run / f"{ENV_ID}.zip")
    finally:
        shutil.rmtree(folder)
    if '"distillation"' not in selections:
        raise RuntimeError("the population made no distillation: the guard would not cover it")
    digest = hashlib.sha256(selections.encode()).hexdigest()
    return [f"zoo_population_distill policy {state_dict_hash(model.policy)}", f"zoo_population_distill selections {digest}"]


ZOO_POPULATION = f"""\
{ENV_ID}:
  n_timesteps: 3000
  n_envs: 1
  env_kwargs: {{max_episode_steps: 60}}
  learning_starts: 100
  batch_size: 16
  buffer_size: 2000
  population:
    k: 2
    interval: 200
    turn_ticks: 100
    fitness: return
    fitness_episodes: 1
    share_buffer: true
    crossover: distill
    distillation_steps: 20
"""

RUNS: dict[str, Callable[[], Any]] = {
    "gdq": run_gdq,
    "qmix": run_qmix,
    "iql": run_iql,
    "eps_gdq": run_eps_gdq,
    "population_gdq": run_population,
    "zoo_population_distill": run_population_distill,
}


def describe(name: str, result: Any) -> list[str]:
    if isinstance(result, list):
        return result
    models = getattr(result, "learners", None) or [result]
    lines = []
    for index, model in enumerate(models):
        label = name if len(models) == 1 else f"{name}[{index}]"
        lines.append(f"{label} policy {state_dict_hash(model.policy)}")
        lines.append(f"{label} buffer {buffer_hash(model.replay_buffer)}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", help=f"some of {', '.join(RUNS)} (default: all)")
    args = parser.parse_args()
    unknown = sorted(set(args.runs) - set(RUNS))
    if unknown:
        parser.error(f"unknown runs {unknown}: choose from {list(RUNS)}")
    for name in args.runs or RUNS:
        for line in describe(name, RUNS[name]()):
            print(line, flush=True)


if __name__ == "__main__":
    main()
