"""jerklab.ident.covariance: the Newey-West sandwich against the closed-form long-run variance of
an AR(1) mean, the encoder grid, and the simulated quantization error against refits of
independently quantized records."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from jerklab.ident import covariance
from jerklab.ident.covariance import (
    bartlett_lags,
    grid_step,
    newey_west,
    quantization_covariance,
)


def ar1(n, rho, seed):
    """x_t = rho x_{t-1} + e_t, unit innovations, started from its stationary distribution."""
    e = np.random.default_rng(seed).standard_normal(n)
    x0 = e[0] / np.sqrt(1 - rho**2)
    return np.r_[x0, signal.lfilter([1.0], [1.0, -rho], e[1:], zi=[rho * x0])[0]]


def test_newey_west_of_an_ar1_mean_matches_its_long_run_variance():
    # the mean of an AR(1) with unit innovations: var = 1 / ((1 - rho)^2 n) for large n
    n, rho = 20000, 0.6
    x = ar1(n, rho, 7)
    J = np.ones((n, 1))
    cov, lags = newey_west(J, x - x.mean())
    exact = 1.0 / ((1 - rho) ** 2 * n)
    naive = np.var(x) / n  # s^2 (J^T J)^-1: (1 + rho)/(1 - rho) = 4 times too small here
    assert cov[0, 0] == pytest.approx(exact, rel=0.12)
    assert naive < 0.3 * exact
    assert 10 <= lags <= 200


def test_newey_west_with_white_residuals_is_the_textbook_covariance():
    rng = np.random.default_rng(3)
    n = 5000
    J = np.column_stack([np.ones(n), np.linspace(-1, 1, n)])
    r = rng.normal(0.0, 0.3, n)
    cov, lags = newey_west(J, r)
    textbook = (r @ r) / (n - 2) * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(np.diag(cov), np.diag(textbook), rtol=0.1)
    assert lags <= 5


def test_lags_stay_within_each_record():
    # two records of a slow AR(1): the lag products do not pair the end of one with the next
    x = np.concatenate([ar1(400, 0.9, 1), ar1(400, 0.9, 2) + 50.0])
    groups = np.repeat([0, 1], 400)
    J = np.column_stack([groups == 0, groups == 1]).astype(float)
    r = x - J @ np.array([x[:400].mean(), x[400:].mean()])
    cov, _ = newey_west(J, r, groups)
    one, _ = newey_west(J[:400, :1], r[:400])
    assert cov[0, 0] == pytest.approx(one[0, 0], rel=0.3)
    assert abs(cov[0, 1]) < 1e-12
    assert bartlett_lags(J * r[:, None], groups) <= 100  # a quarter of the shorter record


def test_sparse_and_dense_products_agree(monkeypatch):
    rng = np.random.default_rng(0)
    J, r, groups = rng.normal(size=(3000, 5)), rng.normal(size=3000), np.repeat([0, 1, 2], 1000)
    dense, lags = newey_west(J, r, groups)
    qd = quantization_covariance(J, J[:, 0], groups, 0.5, 0.1, replicates=50)
    monkeypatch.setattr(covariance, "SPARSE_ABOVE", 0)
    sparse_, lags_s = newey_west(J, r, groups)
    qs = quantization_covariance(J, J[:, 0], groups, 0.5, 0.1, replicates=50)
    assert lags == lags_s
    np.testing.assert_allclose(sparse_, dense, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(qs, qd, rtol=1e-10, atol=1e-14)


def test_newey_west_names_bad_input():
    with pytest.raises(ValueError, match="J must be"):
        newey_west(np.ones((5, 1)), np.ones(4))
    with pytest.raises(ValueError, match="groups"):
        newey_west(np.ones((5, 1)), np.ones(5), groups=np.zeros(4))
    with pytest.raises(ValueError, match="lags"):
        newey_west(np.ones((5, 1)), np.ones(5), lags=-1)


def test_grid_step_finds_the_encoder_count_and_not_noise():
    q = 2 * np.pi / 448
    theta = np.cumsum(np.random.default_rng(0).uniform(0, 0.05, 300))
    counts = q * np.floor(theta / q + 0.37)
    assert grid_step(counts - counts[0]) == pytest.approx(q, rel=1e-9)
    # two records, each from its own first count
    two = np.concatenate([counts - counts[0], counts + 0.123])
    assert grid_step(two, np.repeat([0, 1], 300)) == pytest.approx(q, rel=1e-9)
    # a fast shaft that never moves by one count a sample (steps of 9, 17 and 26 counts)
    fast = q * np.cumsum(np.r_[0, np.tile([9, 26, 17], 30)])
    assert grid_step(fast) == pytest.approx(q, rel=1e-9)
    noisy = counts + np.random.default_rng(1).normal(0, 1e-4, counts.size)
    assert grid_step(noisy) is None
    assert grid_step(np.zeros(10)) is None


def test_quantization_covariance_matches_refits_of_quantized_ramps():
    # a shaft that turns 0.03 counts a sample: the quantization error is a slow staircase, far
    # from white; the slope fitted to the counts spreads over the shaft's phase as predicted
    q, n = 1.0, 400
    t = np.arange(n, dtype=float)
    J = np.column_stack([np.ones(n), t])
    truth = 0.03 * t
    rng = np.random.default_rng(11)
    slopes = []
    for _ in range(1000):
        y = q * np.floor(truth / q + rng.uniform()) - 0.5 * q
        slopes.append(np.linalg.lstsq(J, y, rcond=None)[0][1])
    cov = quantization_covariance(J, truth, np.zeros(n, int), q, replicates=2000, seed=5)
    assert np.sqrt(cov[1, 1]) == pytest.approx(np.std(slopes), rel=0.1)
    again = quantization_covariance(J, truth, np.zeros(n, int), q, replicates=2000, seed=5)
    np.testing.assert_array_equal(cov, again)
