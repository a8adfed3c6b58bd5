"""The motor models the identification simulates (jerklab.ident.model): the exact ZOH simulation of
Stojčić eq. 1 and the full model (friction by the velocity with sticking, offset, dead zone, delay).

Independent references: python-control's ZOH discretization (``c2d``, ``forced_response``), scipy's
ODE solver with events for friction, and ``jerklab.plant.DCMotor``.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from _ident import K0, TAU0, TS, ct_response, levels
from scipy import integrate

from jerklab import ident
from jerklab.plant import DCMotor


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


def test_simulate_motor_reduces_to_eq1_and_matches_python_control_with_offset_and_delay():
    u = ident.prbs(1.0, TS, 3.0, offset=1.0, clock_period=0.02, seed=2)
    np.testing.assert_allclose(
        ident.simulate_motor(K0, TAU0, TS, u, 0.3, 2.0),
        ident.simulate_dc_motor(K0, TAU0, TS, u, 0.3, 2.0),
        atol=1e-12,
    )
    # offset and delay are linear: python-control on the shifted, offset input is an independent reference
    d, off = 3, 0.4
    ushift = np.concatenate([np.full(d, u[0]), u[:-d]]) + off
    sysd = ct.c2d(ct.ss([[0, 1], [0, -1 / TAU0]], [[0], [K0 / TAU0]], [[1, 0]], [[0]]), TS, "zoh")
    ref = np.ravel(ct.forced_response(sysd, T=np.arange(u.size) * TS, U=ushift).outputs)
    np.testing.assert_allclose(
        ident.simulate_motor(K0, TAU0, TS, u, offset=off, delay=d), ref, rtol=1e-10, atol=1e-10
    )


def test_simulate_motor_friction_by_velocity_matches_ode_integration():
    """Friction against the velocity with sticking, against scipy's ODE solver with events."""
    K, tau, fc = 20.0, 0.05, 0.8
    u = np.concatenate([np.full(20, 3.0), np.full(20, -0.5), np.full(20, -3.0), np.full(20, 0.5)])
    Ts = 0.01
    y = ident.simulate_motor(K, tau, Ts, u, friction=fc)

    def reference():
        th, om, out = 0.0, 0.0, []
        for k in range(u.size):
            out.append(th)
            v = u[k]
            t0 = 0.0
            while t0 < Ts - 1e-12:
                if om == 0.0 and abs(v) <= fc:
                    break  # stuck for the rest of the sample
                s = np.sign(om) if om != 0.0 else np.sign(v)
                ev = lambda t, x: x[1]  # noqa: E731 - velocity reaches zero
                ev.terminal, ev.direction = True, -s
                sol = integrate.solve_ivp(
                    lambda t, x: [x[1], (K * (v - s * fc) - x[1]) / tau],
                    (t0, Ts),
                    [th, om],
                    events=ev,
                    rtol=1e-11,
                    atol=1e-12,
                )
                th, om = sol.y[0, -1], sol.y[1, -1]
                if sol.status == 1:
                    om = 0.0
                t0 = sol.t[-1]
        return np.array(out)

    np.testing.assert_allclose(y, reference(), atol=1e-7)
    assert np.all(np.diff(y[45:60]) < 0)  # driven backwards
    # while |u| <= fc after a stop the motor sticks: -0.5 V after coasting to rest holds the angle
    held = ident.simulate_motor(
        K, tau, Ts, np.concatenate([np.full(5, 3.0), np.full(60, -0.5)]), friction=fc
    )
    assert np.ptp(held[-20:]) == 0.0


def test_dcmotor_offset_and_dead_zone():
    m = DCMotor(offset=0.3, dead_zone=0.5, supply_voltage=None, pwm_bits=None, encoder_ppr=None)
    np.testing.assert_allclose(m.drive_voltage([0.0, 0.2, 1.0, -1.0]), [0.0, 0.0, 0.8, -0.2])
    u = levels(1.0)
    th = m.open_loop(u, TS)[0][:-1]
    np.testing.assert_allclose(
        th, ident.simulate_motor(32.4, 0.025, TS, u, offset=0.3, dead_zone=0.5), atol=1e-9
    )
    # the defaults change nothing
    m0 = DCMotor()
    assert m0.offset == 0.0 and m0.dead_zone == 0.0
    assert m0.drive_voltage(1.25) == 1.25
    assert m.replace(K=10).offset == 0.3
    with pytest.raises(ValueError, match="dead_zone"):
        DCMotor(dead_zone=-1)
    with pytest.raises(ValueError, match="offset"):
        DCMotor(offset=float("nan"))
