"""ARX (jerklab.ident.arx): any order against numpy's least squares, the covariance against Monte
Carlo, the velocity ARX fit of Stojčić eq. 1 exact on noise-free data, and its bias under noise
against the asymptotic prediction ``arx_asymptotic_bias``.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from _ident import K0, TAU0, TS, ct_response
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from jerklab import ident


@pytest.mark.parametrize("kind", ["step", "prbs"])
def test_arx_exact_on_noise_free_data(kind):
    u = (
        ident.step_input(1.0, TS, 6.0)
        if kind == "step"
        else ident.prbs(1.0, TS, 3.0, offset=2.0, clock_period=0.02, seed=2)
    )
    theta = ct_response(K0, TAU0, TS, u)
    f = ident.fit_dc_motor(u, theta, TS, method="arx")
    assert abs(f.K / K0 - 1) < 1e-9
    assert abs(f.tau / TAU0 - 1) < 1e-9
    assert f.fit_percent > 100 - 1e-6


@settings(deadline=None)
@given(K=st.floats(0.5, 200.0), tau=st.floats(0.004, 0.5), seed=st.integers(0, 10_000))
def test_arx_exact_property(K, tau, seed):
    u = ident.prbs(60 * TS, TS, 1.0, offset=0.5, clock_period=2 * TS, seed=seed)
    a, b1, b2 = ident.dc_motor_zoh_coefficients(K, tau, TS)
    # independent generation: the transfer function (b1 z + b2)/((z-1)(z-a)) run by lfilter
    theta = signal.lfilter([0.0, b1, b2], np.convolve([1, -1], [1, -a]), u)
    f = ident.fit_dc_motor(u, theta, TS, method="arx")
    assert abs(f.K / K - 1) < 1e-9 and abs(f.tau / tau - 1) < 1e-9


def test_arx_any_order_matches_lstsq_and_covariance():
    rng = np.random.default_rng(0)
    A = [1.0, -1.5, 0.7]
    B = [0.5, 0.25, -0.1]
    nk = 2
    n = 4000
    u = rng.normal(size=n)
    num = np.concatenate([np.zeros(nk), B])
    e = 0.1 * rng.normal(size=n)
    y = signal.lfilter(num, A, u) + signal.lfilter([1.0], A, e)  # ARX: A y = B u(t-nk) + e
    r = ident.arx(y, u, na=2, nb=3, nk=nk)
    # independent: build the regression by hand and call numpy's least squares
    n0 = 4
    Phi = np.column_stack(
        [
            -y[n0 - 1 : n - 1],
            -y[n0 - 2 : n - 2],
            u[n0 - 2 : n - 2],
            u[n0 - 3 : n - 3],
            u[n0 - 4 : n - 4],
        ]
    )
    p_ref, *_ = np.linalg.lstsq(Phi, y[n0:], rcond=None)
    np.testing.assert_allclose(r.params, p_ref, rtol=1e-9, atol=1e-12)
    assert r.noise_variance == pytest.approx(0.01, rel=0.1)
    z = (r.params - np.concatenate([A[1:], B])) / r.std
    assert np.all(np.abs(z) < 4.0)
    # the discrete tf reproduces the noise-free part
    G = r.tf(1.0)
    yf = np.asarray(ct.forced_response(G, T=np.arange(n), U=u).outputs).ravel()
    yh = signal.lfilter(np.concatenate([np.zeros(nk), r.B]), r.A, u)
    np.testing.assert_allclose(yf, yh, atol=1e-8)


def test_arx_covariance_calibrated_monte_carlo():
    rng = np.random.default_rng(11)
    A, B = [1.0, -0.8], [1.0, 0.5]
    zs = []
    for _ in range(150):
        u = rng.normal(size=300)
        y = signal.lfilter([0.0] + B, A, u) + signal.lfilter([1.0], A, 0.2 * rng.normal(size=300))
        r = ident.arx(y, u, 1, 2, 1)
        zs.append((r.params - [-0.8, 1.0, 0.5]) / r.std)
    zs = np.array(zs)
    assert np.all(np.abs(zs.std(axis=0) - 1.0) < 0.2)
    assert np.all(np.abs(zs.mean(axis=0)) < 0.3)


def test_arx_bad_input():
    u = np.ones(50)
    with pytest.raises(ValueError, match="na"):
        ident.arx(np.arange(50.0), u, -1, 1, 1)
    with pytest.raises(ValueError, match="na \\+ nb"):
        ident.arx(np.arange(50.0), u, 0, 0, 1)
    with pytest.raises(ValueError, match="rank deficient"):
        ident.arx(np.arange(50.0) ** 2, u, 1, 2, 1)  # constant input cannot split b0, b1
    with pytest.raises(ValueError, match="too short"):
        ident.arx(np.arange(5.0), np.arange(5.0), 3, 3, 1)
    with pytest.raises(ValueError, match="same length"):
        ident.arx(np.arange(50.0), np.arange(40.0), 1, 1, 1)


def test_arx_bias_shown_and_bounded():
    """ARX under output noise: tau comes out short, as predicted by arx_asymptotic_bias; PEM does not."""
    rng = np.random.default_rng(7)
    u = ident.prbs(4.0, TS, 3.0, offset=3.0, clock_period=0.02, seed=8)
    clean = ident.simulate_dc_motor(K0, TAU0, TS, u)
    sigma = 0.03
    Ka, Ta, Kp, Tp = [], [], [], []
    for _ in range(30):
        y = clean + rng.normal(0, sigma, u.size)
        fa = ident.fit_dc_motor(u, y, TS, method="arx")
        fp = ident.fit_dc_motor(u, y, TS, method="pem")
        Ka.append(fa.K), Ta.append(fa.tau), Kp.append(fp.K), Tp.append(fp.tau)
    K_pred, tau_pred = ident.arx_asymptotic_bias(u, K0, TAU0, TS, sigma)
    tau_bias = np.mean(Ta) / TAU0 - 1
    # shown: the bias is real (many standard errors of the Monte-Carlo mean) and negative
    assert tau_bias < -0.05
    assert abs(np.mean(Ta) - TAU0) > 5 * np.std(Ta) / math.sqrt(len(Ta))
    # bounded: it matches the asymptotic prediction to within 15 % of the bias itself
    assert abs(np.mean(Ta) - tau_pred) < 0.15 * abs(tau_pred - TAU0)
    assert abs(tau_pred / TAU0 - 1) < 0.5
    # PEM on the same data is unbiased (mean within 4 standard errors, under 0.5 %)
    assert abs(np.mean(Tp) / TAU0 - 1) < 0.005
    assert abs(np.mean(Kp) / K0 - 1) < 0.005
    # no noise, no bias
    assert ident.arx_asymptotic_bias(u, K0, TAU0, TS, 0.0) == pytest.approx((K0, TAU0), rel=1e-9)


def test_arx_bias_grows_with_noise():
    u = ident.prbs(4.0, TS, 3.0, offset=3.0, clock_period=0.02, seed=8)
    taus = [ident.arx_asymptotic_bias(u, K0, TAU0, TS, s)[1] for s in (0.0, 0.001, 0.003, 0.01)]
    assert all(x > y for x, y in zip(taus, taus[1:]))
