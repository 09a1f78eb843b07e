"""The aggregate statistics of ``python -m sb3_eps.plot --aggregate`` (one implementation of rliable's estimators),
checked against SciPy's trimmed mean and the normal-theory widths of a stratified percentile bootstrap."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from sb3_eps.zoo.plotting import AGGREGATES, bootstrap_intervals, interquartile_mean


@pytest.mark.parametrize("n", [1, 4, 5, 7, 10, 101])
def test_iqm_is_scipys_trimmed_mean_as_rliable_defines_it(n) -> None:
    values = np.random.default_rng(n).normal(size=n) ** 3  # skewed: trimming matters
    assert interquartile_mean(values) == pytest.approx(stats.trim_mean(values, proportiontocut=0.25))
    assert interquartile_mean([1, 2, 3, 4, 100, -100, 5, 6]) == pytest.approx(3.5)  # by hand: mean of 2, 3, 4, 5


def test_point_estimates_pool_every_run() -> None:
    scores = {"a": [0.1, 0.2, 0.9], "b": [0.5, 0.6]}
    result = bootstrap_intervals(scores, n_resamples=50)
    pooled = np.array([0.1, 0.2, 0.9, 0.5, 0.6])
    for name, function in AGGREGATES.items():
        estimate, low, high = result[name]
        assert estimate == pytest.approx(function(pooled)) and low <= estimate <= high


def test_the_bootstrap_resamples_runs_inside_each_task() -> None:
    """Two tasks 10 apart, 200 runs of unit spread each: the stratified 95 % interval of the mean is
    +/- 1.96 sqrt(n1 s1^2 + n2 s2^2) / N = +/- 0.098; resampling the pooled runs would give +/- 0.50."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(0.0, 1.0, 200), rng.normal(10.0, 1.0, 200)
    estimate, low, high = bootstrap_intervals({"a": list(a), "b": list(b)}, n_resamples=2_000)["mean"]
    expected = 1.96 * np.sqrt(200 * a.var() + 200 * b.var()) / 400
    assert estimate == pytest.approx(np.concatenate([a, b]).mean())
    assert (high - low) / 2 == pytest.approx(expected, rel=0.1)
    assert (low + high) / 2 == pytest.approx(estimate, abs=0.02)


def test_one_task_percentile_interval_of_the_mean_matches_normal_theory() -> None:
    values = np.random.default_rng(1).normal(3.0, 2.0, 400)
    _, low, high = bootstrap_intervals({"task": list(values)}, n_resamples=4_000, seed=3)["mean"]
    half_width = 1.96 * values.std() / np.sqrt(len(values))
    assert (high - low) / 2 == pytest.approx(half_width, rel=0.08)
    assert bootstrap_intervals({"task": list(values)}, n_resamples=200, seed=3) == bootstrap_intervals(
        {"task": list(values)}, n_resamples=200, seed=3
    )  # seeded: the same intervals every time
