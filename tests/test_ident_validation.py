"""Validation (jerklab.ident.validation): fit % by its definition, the residual tests' levels and
power, a fitted model on a fresh record and on a record cut while the motor turns."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _ident import K0, TAU0, TS, ct_response, plant_record
from scipy import signal

from jerklab import ident


def test_fit_percent_definition():
    y = np.array([0.0, 1.0, 2.0, 3.0])
    assert ident.fit_percent(y, y) == 100.0
    assert ident.fit_percent(y, np.full(4, y.mean())) == pytest.approx(0.0)
    yh = y + np.array([0.1, -0.1, 0.1, -0.1])
    assert ident.fit_percent(y, yh) == pytest.approx(100 * (1 - 0.2 / math.sqrt(5)))


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
