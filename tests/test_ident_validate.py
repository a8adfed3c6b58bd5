"""Validation (jerklab.ident.validate): fit %, the residual tests, validate, compare (simulation and
k-step prediction) and resid, against hand-computed cases and python-control.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _ident import K0, TAU0, TS, ct_response, plant_record, record
from scipy import signal, stats

from jerklab import ident


def test_fit_percent_definition():
    y = np.array([0.0, 1.0, 2.0, 3.0])
    assert ident.fit_percent(y, y) == 100.0
    assert ident.fit_percent(y, np.full(4, y.mean())) == pytest.approx(0.0)
    yh = y + np.array([0.1, -0.1, 0.1, -0.1])
    assert ident.fit_percent(y, yh) == pytest.approx(100 * (1 - 0.2 / math.sqrt(5)))


def test_fit_percent_hand_computed():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    yh = np.array([1.0, 2.0, 3.0, 5.0])
    # ||y - yh|| = 1, ||y - mean|| = sqrt(1.5^2 + 0.5^2 + 0.5^2 + 1.5^2) = sqrt(5)
    assert ident.fit_percent(y, yh) == pytest.approx(100 * (1 - 1 / math.sqrt(5)))


def test_residual_analysis_detects_colour_and_feedthrough():
    rng = np.random.default_rng(3)
    N = 2000
    u = rng.normal(size=N)
    white = rng.normal(size=N)
    ra = ident.residual_analysis(white, u)
    assert ra.auto_bound == pytest.approx(2.5758 / math.sqrt(N), rel=1e-4)
    assert ra.white and ra.independent
    assert 0.01 < ra.auto_pvalue and 0.01 < ra.cross_pvalue
    # the joint tests hold their level: about 1 % false alarms over many white sequences
    alarms = sum(not ident.residual_analysis(rng.normal(size=400)).white for _ in range(100))
    assert alarms <= 5
    assert ra.autocorr[0] == pytest.approx(1.0)
    coloured = signal.lfilter([1.0], [1.0, -0.5], white)
    assert not ident.residual_analysis(coloured).white
    leaky = white + 0.3 * np.roll(u, 3)
    rl = ident.residual_analysis(leaky, u)
    assert not rl.independent
    assert rl.cross_lags[np.argmax(np.abs(rl.crosscorr))] == 3


def test_residual_analysis_hand_computed():
    e = np.array([1.0, -2.0, 3.0, 0.0, -1.0, 2.0, -3.0, 1.0, 0.0, -1.0, 2.0, -2.0])
    u = np.array([0.5, 1.0, -1.0, 2.0, 0.0, -0.5, 1.5, -2.0, 1.0, 0.0, -1.0, 0.5])
    r = ident.residual_analysis(e, u, max_lag=2, confidence=0.99)
    ec, uc = e - e.mean(), u - u.mean()
    N = e.size
    r1 = sum(ec[t] * ec[t - 1] for t in range(1, N)) / sum(ec**2)
    assert r.autocorr[0] == pytest.approx(1.0)
    assert r.autocorr[1] == pytest.approx(r1)
    assert r.auto_bound == pytest.approx(2.5758293035489 / math.sqrt(N))
    # cross-correlation at lag +1: u leads e by one sample
    c1 = sum(uc[t - 1] * ec[t] for t in range(1, N)) / math.sqrt(sum(uc**2) * sum(ec**2))
    assert r.crosscorr[list(r.cross_lags).index(1)] == pytest.approx(c1)
    cm1 = sum(uc[t + 1] * ec[t] for t in range(N - 1)) / math.sqrt(sum(uc**2) * sum(ec**2))
    assert r.crosscorr[list(r.cross_lags).index(-1)] == pytest.approx(cm1)
    # Ljung-Box by hand
    Q = N * (N + 2) * sum(r.autocorr[k] ** 2 / (N - k) for k in (1, 2))

    assert r.auto_pvalue == pytest.approx(stats.chi2.sf(Q, 2))


def test_validate_on_fresh_record_and_plots():
    import matplotlib

    matplotlib.use("Agg")
    u_est = ident.prbs(2.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=1)
    u_val = ident.step_input(1.0, TS, 5.0)
    fit = ident.fit_dc_motor(u_est, plant_record(u_est, 1), TS)
    y_val = plant_record(u_val, 2)
    v = ident.validate(fit, u_val, y_val, TS)
    assert v.fit_percent > 99
    assert v.residuals.size == u_val.size
    d = ident.IdentData(u_val, y_val, TS)
    ax = ident.plot_compare(
        d, fit, ident.fit_dc_motor(u_est, plant_record(u_est, 1), TS, method="arx")
    )
    assert "rad" in ax.get_ylabel() and "s" in ax.get_xlabel()
    assert len(ax.get_lines()) == 3
    axes = ident.plot_residuals(v.analysis)
    assert len(axes) == 2
    with pytest.raises(ValueError, match="Ts"):
        ident.validate(fit, u_val, y_val, 0.01)
    with pytest.raises(ValueError, match="initial"):
        ident.validate(fit, u_val, y_val, initial="zero")


def test_validate_estimates_initial_velocity():
    """A record cut while the motor turns: the initial state is recovered (vs python-control)."""
    u = ident.prbs(1.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=6)
    th = ct_response(K0, TAU0, TS, u, theta0=1.5, omega0=150.0)
    u_fit = ident.step_input(1.0, TS, 6.0)
    fit = ident.fit_dc_motor(u_fit, ident.simulate_dc_motor(K0, TAU0, TS, u_fit), TS)
    v = ident.validate(fit, u, th)
    assert v.theta0 == pytest.approx(1.5, abs=1e-6) and v.omega0 == pytest.approx(150.0, rel=1e-6)
    assert v.fit_percent > 100 - 1e-6
    assert ident.validate(fit, u, th, initial="rest").fit_percent < 99.9
    import matplotlib.pyplot as plt

    plt.close("all")


@pytest.mark.parametrize("k", [1, 2, 5])
def test_k_step_prediction_is_the_arx_predictor_by_hand(k):
    rng = np.random.default_rng(0)
    u = ident.prbs(0.5, TS, 3.0, offset=2.0, clock_period=0.02)
    y = ident.simulate_dc_motor(K0, TAU0, TS, u) + rng.normal(0, 0.01, u.size)
    f = ident.fit_dc_motor(u, y, TS)
    a, b1, b2 = ident.dc_motor_zoh_coefficients(f.K, f.tau, TS)
    c = ident.compare((u, y), f, horizon=k)
    for t in range(k + 1, u.size):
        p = list(y[: t - k + 1])  # y known up to t - k
        for s in range(t - k + 1, t + 1):  # A = (1 - q^-1)(1 - a q^-1)
            p.append((1 + a) * p[s - 1] - a * p[s - 2] + b1 * u[s - 1] + b2 * u[s - 2])
        assert c.y_hat[t] == pytest.approx(p[t], abs=1e-9)
    assert c.fit_percent == pytest.approx(ident.fit_percent(y, c.y_hat))
    assert c.horizon == k
    sim = ident.compare((u, y), f)
    assert sim.horizon is None and c.fit_percent > sim.fit_percent - 1.0


def test_compare_simulation_matches_validate():
    u = ident.prbs(2.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=5)
    y = record(u)
    f = ident.fit_dc_motor(u[:200], y[:200], TS)
    c = ident.compare((u[200:], y[200:]), f)
    v = ident.validate(f, u[200:], y[200:], TS)
    np.testing.assert_allclose(c.y_hat, v.y_sim, atol=1e-9)
    assert c.fit_percent == pytest.approx(v.fit_percent)


def test_resid_defaults_and_verdicts():
    u = ident.prbs(4.0, TS, 4.0, offset=0.0, clock_period=0.04, seed=3)
    y = record(u, coulomb_friction=0.4, offset=0.2, noise_std=0.005)
    d = ident.IdentData(u, y, TS)
    good = ident.fit_dc_motor(u[:400], y[:400], TS, friction=True, offset=True)
    bad = ident.fit_dc_motor(u[:400], y[:400], TS)
    rg = ident.resid(d[400:], good)
    rb = ident.resid(d[400:], bad)
    assert rg.lags[-1] == 25 and rg.cross_lags[0] == -25 and rg.confidence == 0.99
    assert rg.white and rg.independent
    assert not rb.white
