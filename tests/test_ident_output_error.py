"""Output error (jerklab.ident.output_error): the variable-projection start of the linear model
against the states python-control simulates, and the paper's literal 'P2' call against
python-control records and against the integrator model of fit_dc_motor."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest
from _ident import TS, plant_record

from jerklab import ident
from jerklab.ident.output_error import _linear_start, _segment_starts


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


def test_linear_start_is_the_exact_optimum_with_every_segment_state():
    """Two noise-free records (python-control's ZOH simulation from known states), cut into
    segments of 60 samples: the projection recovers K, tau and each segment's initial angle and
    velocity, which python-control's state trajectory gives independently."""
    K, tau, delay = 20.0, 0.04, 2
    recs, states = [], []
    for seed, (th0, om0) in ((1, (0.3, -5.0)), (2, (-1.0, 40.0))):
        u = ident.prbs(1.0, TS, 2.0, offset=1.0, clock_period=0.02, seed=seed)
        ud = np.concatenate([np.full(delay, u[0]), u[:-delay]])  # the motor sees u late
        sysd = ct.c2d(ct.ss([[0, 1], [0, -1 / tau]], [[0], [K / tau]], [[1, 0]], [[0]]), TS)
        r = ct.forced_response(sysd, T=np.arange(u.size) * TS, U=ud, X0=[th0, om0])
        recs.append((u, np.asarray(r.outputs).ravel()))
        starts = _segment_starts(u.size, 60)
        states.append(np.asarray(r.states)[:, starts])
    start = _linear_start(recs, TS, delay, 60)
    assert start["K"] == pytest.approx(K, rel=1e-8) and start["tau"] == pytest.approx(tau, rel=1e-8)
    true = np.concatenate(states, axis=1)
    np.testing.assert_allclose(start["seg_theta0"], true[0], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(start["seg_omega0"], true[1], rtol=1e-6, atol=1e-6)
