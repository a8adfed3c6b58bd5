"""The motor model of identification (jerklab.ident.model): the exact ZOH simulation and
coefficients of Stojčić eq. 1 against python-control, and the fitted model's helpers."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from _ident import K0, TAU0, TS, ct_response, plant_record

from jerklab import ident


@pytest.mark.parametrize(
    "K,tau,Ts", [(32.4, 0.025, 0.005), (5.0, 0.3, 0.01), (100.0, 0.001, 0.005)]
)
def test_simulation_matches_python_control(K, tau, Ts):
    u = ident.prbs(1.0, Ts, 2.0, offset=1.0, clock_period=2 * Ts, seed=4)
    ours = ident.simulate_dc_motor(K, tau, Ts, u, theta0=0.3, omega0=-2.0)
    ref = ct_response(K, tau, Ts, u, 0.3, -2.0)
    assert np.max(np.abs(ours - ref)) <= 1e-9 * max(1.0, np.max(np.abs(ref)))


def test_zoh_coefficients_match_c2d():
    a, b1, b2 = ident.dc_motor_zoh_coefficients(K0, TAU0, TS)
    d = ct.c2d(ct.tf([K0], [TAU0, 1.0, 0.0]), TS, "zoh")
    num = np.ravel(d.num[0][0])
    den = np.ravel(d.den[0][0])
    num = num / den[0]
    den = den / den[0]
    np.testing.assert_allclose(den, np.convolve([1, -1], [1, -a]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(num[-2:], [b1, b2], rtol=1e-9)
    assert math.isclose(b1 + b2, K0 * TS * (1 - a), rel_tol=1e-12)


def test_confidence_interval_and_to_motor():
    u = ident.step_input(1.0, TS, 6.0)
    f = ident.fit_dc_motor(u, plant_record(u, 9), TS)
    lo, hi = f.confidence_interval(0.95)["K"]
    assert lo < f.K < hi and hi - lo == pytest.approx(2 * 1.959964 * f.K_std, rel=1e-5)
    m = f.to_motor(encoder_ppr=None)
    assert m.K == f.K and m.tau == f.tau
    with pytest.raises(ValueError, match="level"):
        f.confidence_interval(1.5)
