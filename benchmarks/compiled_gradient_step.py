"""Does ``torch.compile`` make GDQ's gradient step cheaper on CPU? Eager and compiled agent networks, alternated.

Builds GDQ on ``MultiRobotNav-4-v0`` (``--n-envs`` worlds, ``--batch-size`` joint rows, one thread), fills the replay
buffer with ``--warmup`` ticks of training, then times ``model.train`` for ``--steps`` gradient steps with the agent
networks' forward passes (``value_advantage``, ``advantage`` of the online and the target network) eager and compiled
(``torch.compile``, static shapes), ``--rounds`` times alternated, and prints milliseconds per gradient step and the
ratio compiled / eager of the medians. Compiling the whole loss breaks its graph at every ``.item()`` and recompiles
on each logged value, so only the networks are compiled. Example::

    python benchmarks/compiled_gradient_step.py --rounds 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch as th

import envs  # noqa: F401
from sb3_eps import GDQ, make_vec_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--warmup", type=int, default=2_500, help="ticks of training before timing")
    parser.add_argument("--steps", type=int, default=300, help="timed gradient steps per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    th.set_num_threads(1)
    venv = make_vec_env("MultiRobotNav-4-v0", n_envs=args.n_envs, seed=0)
    model = GDQ("MlpPolicy", venv, seed=0, batch_size=args.batch_size, learning_starts=500)
    model.learn(args.warmup * venv.n_agents, log_interval=10**9)
    nets = [model.policy.q_net, model.policy.q_net_target]
    eager = [(net.value_advantage, net.advantage) for net in nets]
    compiled = [(th.compile(a, dynamic=False), th.compile(b, dynamic=False)) for a, b in eager]

    def use(methods: list) -> None:
        for net, (value_advantage, advantage) in zip(nets, methods):
            net.value_advantage, net.advantage = value_advantage, advantage

    def milliseconds() -> float:
        model.train(20, args.batch_size)
        start = time.perf_counter()
        model.train(args.steps, args.batch_size)
        return (time.perf_counter() - start) / args.steps * 1000

    use(compiled)
    start = time.perf_counter()
    model.train(10, args.batch_size)
    print(f"compilation: {time.perf_counter() - start:.1f} s")
    times: dict[str, list[float]] = {"eager": [], "compiled": []}
    for _ in range(args.rounds):
        use(eager)
        times["eager"].append(milliseconds())
        use(compiled)
        times["compiled"].append(milliseconds())
    for name, values in times.items():
        print(f"{name}: {', '.join(f'{v:.2f}' for v in values)} ms per gradient step")
    print(f"compiled / eager (medians): {statistics.median(times['compiled']) / statistics.median(times['eager']):.2f}")
    venv.close()


if __name__ == "__main__":
    main()
