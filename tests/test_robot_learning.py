"""A short learning test on a robot world, with the package defaults.

The corridor tests (tests/test_algorithms.py) cannot see what fails on the robots: GDQ with the paper's target
and 3-step returns (an early default) solved the corridor and stayed at 0-1 % team success on
``MultiRobotNav-2-v0``. This test trains GDQ exactly as a user would, ``GDQ("MlpPolicy", venv, seed=...)``, for
30k ticks and asks for greedy team success well above what that setting reached. Measured budgets and
curves: docs/results/baselines.md.
"""

from __future__ import annotations

import torch as th

import envs  # noqa: F401
from sb3_eps import GDQ, make_vec_env
from sb3_eps.common.evaluation import evaluate_team

TICKS = 30_000
EPISODES = 40
# Measured for this seed on the 2-core VM, about 65 s of CPU. 2026-12-02, uniform replay, GDQ's
# default since then: 85 % at 30k ticks (prioritized replay, the same run otherwise, re-run that day: 75 %). Earlier
# that day, the package defaults of then (GDQ-lambda 0.1,
# 3-step returns, greedy actions from a 2e-4 weight average): 87.5 % at 30k ticks (the online network: 87.5 %); at
# 20k, this test's budget until then, the average had 20 % and the online network 32.5 %: an average lags a short
# run. 2026-12-01 (20k ticks, online): 50 % with GDQ-lambda, 88 % with the paper's target and 30-step returns (the
# defaults until 2026-12-01: faster here, but 58 % against GDQ-lambda's 86 % on 4 robots at 150k ticks), 0 % with the
# paper's target and 3-step returns.
MIN_SUCCESS = 0.3


def test_gdq_package_defaults_learn_the_two_robot_world() -> None:
    th.set_num_threads(1)
    venv = make_vec_env("MultiRobotNav-2-v0", n_envs=4, seed=7)
    model = GDQ("MlpPolicy", venv, seed=7)
    model.learn(TICKS * venv.n_agents)
    summary = evaluate_team(model, "MultiRobotNav-2-v0", EPISODES, n_envs=4, seed=10_007)
    venv.close()
    assert summary["success_rate"] >= MIN_SUCCESS, summary
