"""A model built through the Python API leaves torch at one thread unless the user chose a count."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

BUILD = """
import torch as th
import envs
from sb3_eps import GDQ, make_vec_env
{before}
GDQ("MlpPolicy", make_vec_env("MultiRobotNav-2-v0", n_envs=1, seed=0), policy_kwargs={{"net_arch": [8]}})
print(th.get_num_threads())
"""


def threads_after_build(before: str = "", **env: str) -> int:
    environ = {key: value for key, value in os.environ.items() if key not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    environ.update(env)
    out = subprocess.run(
        [sys.executable, "-c", BUILD.format(before=before)],
        capture_output=True,
        text=True,
        env=environ,
        check=True,
    )
    return int(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="torch's default is one thread on one core")
def test_a_model_sets_one_thread_where_torch_would_take_every_core():
    assert threads_after_build() == 1


def test_a_count_the_user_chose_is_kept():
    assert threads_after_build("th.set_num_threads(3)") == 3
    assert threads_after_build(OMP_NUM_THREADS="2") == 2
