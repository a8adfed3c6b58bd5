"""The paper's literal call, MATLAB pem(data, 'P2') (jerklab.ident.p2), against python-control's
ZOH simulation of a two-pole plant and against fit_dc_motor on the motor.
"""

from __future__ import annotations

import control as ct
import numpy as np
import pytest
from _ident import TS, plant_record

from jerklab import ident


@pytest.mark.parametrize("T1", [0.08, 0.4, 3.0])
def test_fit_p2_recovers_a_two_pole_plant(T1):
    u = ident.prbs(2.0, TS, 3.0, offset=3.0, seed=1)
    sysd = ct.c2d(ct.tf([5.0], np.convolve([T1, 1.0], [0.02, 1.0])), TS, "zoh")
    y = np.asarray(ct.forced_response(sysd, T=np.arange(u.size) * TS, U=u).outputs).ravel() + 0.3
    p = ident.fit_p2(u, y, TS)
    assert p.K == pytest.approx(5.0, rel=1e-6) and p.T1 == pytest.approx(T1, rel=1e-6)
    assert p.T2 == pytest.approx(0.02, rel=1e-6) and p.theta0 == pytest.approx(0.3, abs=1e-6)
    assert not p.at_bound
    # the eq. 1 structure cannot describe a plant that settles: a clear error, or a poor fit
    try:
        f = ident.fit_dc_motor(u, y, TS)
        assert f.fit_percent < p.fit_percent
    except ValueError as exc:
        assert "theta" in str(exc)


def test_fit_p2_on_the_motor_runs_to_an_integrator():
    """Stojčić's pem(data,'P2') on a motor: T1 runs away, K/T1 is the K of eq. 1."""
    u = ident.step_input(2.0, TS, 6.0)
    y = plant_record(u, 3)
    p = ident.fit_p2(u, y, TS)
    f = ident.fit_dc_motor(u, y, TS)
    assert p.at_bound and p.T1 > 100 * u.size * TS
    assert p.integrator_gain == pytest.approx(f.K, rel=1e-3)
    assert p.T2 == pytest.approx(f.tau, rel=1e-3)
    assert abs(p.fit_percent - f.fit_percent) < 0.01
