"""Tests of jerklab.controller: gains against python-control, the difference equations."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jerklab.controller import (
    DigitalController,
    DiscreteGains,
    Feedforward,
    Gains,
    PositionLoop,
    VelocityLoop,
    discrete_pole_placement_pid,
    paper_error_scale,
    paper_velocity_controller,
    pole_placement_pid,
    velocity_pole_placement_pid,
)
from jerklab.plant import DCMotor

K, TAU, TS = 32.4, 0.025, 0.005


def _pid_tf(g):
    return ct.tf([g.kd, g.kp, g.ki], [1.0, 0.0])


def _match(actual, expected, tol):
    """Every expected root has a distinct actual root within tol (relative)."""
    actual = list(np.asarray(actual, dtype=complex))
    for p in np.asarray(expected, dtype=complex):
        i = int(np.argmin([abs(a - p) for a in actual]))
        assert abs(actual[i] - p) <= tol * max(1.0, abs(p)), (actual, expected)
        actual.pop(i)


def _z_pid_tf(d):
    num, den = d._polys()
    return ct.tf(num, den, d.Ts)


@settings(max_examples=60)
@given(
    st.floats(0.5, 200),
    st.floats(0.3, 2.0),
    st.floats(1.5, 15),
    st.floats(1, 100),
    st.floats(0.005, 0.2),
)
def test_eq11_places_position_poles(wn, zeta, ratio, K_, tau_):
    g = pole_placement_pid(K_, tau_, wn, zeta, sigma=ratio * wn)
    P = ct.tf([K_], [tau_, 1.0, 0.0])
    cl = ct.feedback(P * _pid_tf(g), 1)
    expected = np.r_[-ratio * wn, np.roots([1, 2 * zeta * wn, wn * wn])]
    _match(cl.poles(), expected, 1e-5)


def test_eq11_closed_form_and_times():
    wn, zeta, sigma = 30.0, 1.0, 210.0
    g = pole_placement_pid(K, TAU, wn)
    assert g.design["sigma"] == sigma
    assert g.kp == pytest.approx(wn * TAU * (2 * zeta * sigma + wn) / K)
    assert g.ki == pytest.approx(TAU * sigma * wn**2 / K)
    assert g.kd == pytest.approx((TAU * (2 * zeta * wn + sigma) - 1) / K)
    assert g.Ti == pytest.approx((2 * zeta * sigma + wn) / (sigma * wn))  # eq. 11
    assert g.Td == pytest.approx(
        (TAU * (2 * zeta * wn + sigma) - 1) / (wn * TAU * (2 * zeta * sigma + wn))
    )


def test_eq13_coefficients():
    g = pole_placement_pid(K, TAU, 20.0)
    d = g.discretize(TS)
    assert d.kpd == pytest.approx(g.kp * (1 - TS / (2 * g.Ti)), rel=1e-12)
    assert d.kid == pytest.approx(g.kp * TS / g.Ti, rel=1e-12)
    assert d.kdd == pytest.approx(g.kp * g.Td / TS, rel=1e-12)
    # eq. 12 equals the trapezoid/backward substitution into eq. 10
    z = np.exp(1j * np.linspace(0.1, 3.0, 7))
    s_trap = 2 / TS * (z - 1) / (z + 1)
    s_back = (z - 1) / (z * TS)
    B = g.kp + g.ki / s_trap + g.kd * s_back
    np.testing.assert_allclose(d.tf()(z), B, rtol=1e-10)


@pytest.mark.parametrize("wn, radius", [(10, 0.952), (30, 0.876), (40, 0.992), (50, 1.16)])
def test_reading_numbers_discretized_continuous_design(wn, radius):
    """docs/THEORY.md (Stojčić eq. 13): largest |z| of the eq.-13 design on the ZOH plant, via
    python-control."""
    d = pole_placement_pid(K, TAU, wn).discretize(TS)
    Pz = ct.c2d(ct.tf([K], [TAU, 1, 0]), TS, "zoh")
    cl = ct.feedback(Pz * _z_pid_tf(d), 1)
    r = np.max(np.abs(cl.poles()))
    assert r == pytest.approx(radius, abs=0.006)
    assert PositionLoop(K, TAU, d).max_pole_radius() == pytest.approx(r, rel=1e-8)


@pytest.mark.parametrize("wn", [5.0, 10.0, 30.0, 50.0, 80.0])
@pytest.mark.parametrize("extra", [None, 0.0, 0.3])
def test_z_domain_design_places_poles_exactly(wn, extra):
    d = discrete_pole_placement_pid(K, TAU, wn, 1.0, 7 * wn, TS, extra_pole=extra)
    Pz = ct.c2d(ct.tf([K], [TAU, 1, 0]), TS, "zoh")
    cl = ct.feedback(Pz * _z_pid_tf(d), 1)
    want = np.exp(np.r_[-7 * wn, -wn, -wn] * TS)
    if extra is not None:
        want = np.r_[want, extra]
    else:
        want = np.r_[want, d.design["fourth_pole"]]
    _match(cl.poles(), want, 1e-5)


def test_z_domain_stable_where_eq13_is_not():
    wn = 50.0
    eq13 = PositionLoop(K, TAU, pole_placement_pid(K, TAU, wn), Ts=TS)
    zdes = PositionLoop(K, TAU, discrete_pole_placement_pid(K, TAU, wn, Ts=TS))
    assert not eq13.is_stable()
    assert zdes.is_stable() and zdes.max_pole_radius() < 0.96


def test_velocity_design_places_velocity_poles():
    for wn, kd in [(30.0, 0.0), (15.0, 0.002)]:
        g = velocity_pole_placement_pid(K, TAU, wn, 0.8, kd=kd)
        cl = ct.feedback(ct.tf([K], [TAU, 1]) * _pid_tf(g), 1)
        _match(cl.poles(), np.roots([1, 1.6 * wn, wn * wn]), 1e-6)
    # the paper's gains on the velocity loop do not land on eq. 11's poles
    g = pole_placement_pid(K, TAU, 30.0)
    p = VelocityLoop(K, TAU, g).poles()
    assert np.min(np.abs(p + 30.0)) > 1.0


def test_velocity_z_design_on_pulse_count_model():
    d = discrete_pole_placement_pid(K, TAU, 20.0, Ts=TS, loop="velocity", extra_pole=0.0)
    # plant to the measured (pulse-count) velocity: (1 - 1/z)/Ts * P(z)
    Pz = ct.c2d(ct.tf([K], [TAU, 1, 0]), TS, "zoh")
    Pm = ct.tf([1, -1], [TS, 0], TS) * Pz
    cl = ct.feedback(Pm * _z_pid_tf(d), 1)
    _match(cl.poles(), np.r_[np.exp(np.r_[-140.0, -20.0, -20.0] * TS), 0.0], 1e-5)
    assert paper_error_scale() == pytest.approx(1 / 2.80, rel=2e-3)


def test_paper_velocity_controller_is_4b_as_published():
    c = paper_velocity_controller(K, TAU, wn=10.0, Ts=TS)
    d = pole_placement_pid(K, TAU, 10.0).discretize(TS)
    assert (c.gains.kpd, c.gains.kid, c.gains.kdd) == (d.kpd, d.kid, d.kdd)
    assert c.loop == "velocity" and not c.anti_windup
    assert c.error_scale == pytest.approx(448 * TS / (2 * np.pi))
    # 4 counts in one sample against a 10 rad/s reference: error in pulses = 10*0.3565 - 4
    c.step(0.0, 10.0, 0.0, 0.0)
    c.step(0.0, 10.0, 0.0, 4 * 2 * np.pi / 448)
    assert c.last_parts["e"] == pytest.approx(10.0 * 448 * TS / (2 * np.pi) - 4.0)
    assert VelocityLoop(K, TAU, c.gains, error_scale=c.error_scale).max_pole_radius() > 1.0


def test_loop_objects_against_python_control():
    d = pole_placement_pid(K, TAU, 30.0).discretize(TS)
    L = PositionLoop(K, TAU, d)
    Pz = ct.c2d(ct.tf([K], [TAU, 1, 0]), TS, "zoh")
    ref = ct.feedback(Pz * _z_pid_tf(d), 1)
    w = np.linspace(0.5, 600, 40)
    z = np.exp(1j * w * TS)
    np.testing.assert_allclose(L.closed_loop()(z), ref(z), rtol=1e-8)
    np.testing.assert_allclose(L.disturbance_tf()(z), ct.feedback(Pz, _z_pid_tf(d))(z), rtol=1e-8)
    t, y = L.step_response(0.3)
    r = ct.step_response(ref, T=t)
    np.testing.assert_allclose(y, r.outputs, atol=1e-10)
    m = L.margins()
    gm, pm, _, _ = ct.margin(Pz * _z_pid_tf(d))
    assert m["phase_margin"] == pytest.approx(pm)
    np.testing.assert_allclose(
        np.sort(np.abs(L.poles_s())), np.sort(np.abs(np.log(L.poles_z()) / TS))
    )
    c = PositionLoop(K, TAU, pole_placement_pid(K, TAU, 30.0))
    _match(c.poles_s(), [-210, -30, -30], 1e-5)
    assert c.is_stable() and not c.discrete


def _linear_loop_python_control(d, ff, r, v, a):
    """Closed-loop simulation of the same linear loop with python-control (ZOH plant)."""
    Pz = ct.c2d(ct.ss(ct.tf([K], [TAU, 1, 0])), TS, "zoh")
    Cz = ct.ss(_z_pid_tf(d))
    # inputs: reference r, feedforward u_ff; the loop closed by interconnect
    sumu = ct.summing_junction(inputs=["uc", "uff"], output="u")
    sume = ct.summing_junction(inputs=["r", "-y"], output="e")
    P = ct.ss(Pz.A, Pz.B, Pz.C, Pz.D, TS, inputs="u", outputs="y")
    C = ct.ss(Cz.A, Cz.B, Cz.C, Cz.D, TS, inputs="e", outputs="uc")
    sys = ct.interconnect([P, C, sumu, sume], inputs=["r", "uff"], outputs=["y"])
    t = np.arange(len(r)) * TS
    return np.ravel(ct.forced_response(sys, T=t, U=np.vstack([r, ff(v, a)])).outputs)


def test_difference_equations_agree_with_python_control():
    d = discrete_pole_placement_pid(K, TAU, 25.0, Ts=TS)
    ff = Feedforward(K, TAU)
    n = 300
    t = np.arange(n) * TS
    r = 0.5 * (1 - np.cos(2 * np.pi * t / 0.8)) * (t < 0.8) + (t >= 0.8) * 0.0
    v = np.gradient(r, TS)
    a = np.gradient(v, TS)
    y_ref = _linear_loop_python_control(d, ff, r, v, a)
    m = DCMotor(supply_voltage=None, pwm_bits=None, encoder_ppr=None)
    c = DigitalController(d, feedforward=ff, output_limit=None)
    x = np.zeros(2)
    y = np.empty(n)
    for k in range(n):
        y[k] = x[0]
        u = c.step(r[k], v[k], a[k], x[0])
        parts = c.last_parts
        assert parts["u"] == pytest.approx(
            parts["p"] + parts["i"] + parts["d"] + parts["ff"], abs=1e-12
        )
        x = m.step_state(x, u, TS)
    np.testing.assert_allclose(y, y_ref, atol=1e-9)


def test_eq17_state_and_output_limit():
    d = DiscreteGains(2.0, 0.5, 3.0, TS)
    c = DigitalController(d, output_limit=None)
    u0 = c.step(1.0, measured_position=0.0)  # e = 1, e(-1) = 0: p=2, i=0.5, d=3
    assert u0 == pytest.approx(5.5)
    u1 = c.step(1.0, measured_position=0.5)  # e = 0.5: p=1, i=0.75, d=-1.5
    assert u1 == pytest.approx(0.25)
    c = DigitalController(d, output_limit=1.0, anti_windup=True)
    assert c.step(10.0) == 1.0 and c.last_parts["saturated"]
    assert c.last_parts["i"] == 0.0  # frozen while clamped
    c = DigitalController(d, output_limit=1.0, anti_windup=False)
    c.step(10.0)
    assert c.last_parts["i"] == pytest.approx(5.0)


def test_bumpless_start():
    d = DiscreteGains(2.0, 0.5, 3.0, TS)
    c = DigitalController(d, output_limit=None, bumpless=True)
    c.step(1.0, measured_position=0.0)
    assert c.last_parts["d"] == 0.0  # no derivative kick
    c.reset(last_output=4.0)
    assert c.step(0.3, measured_position=0.1) == pytest.approx(4.0)
    assert c.step(0.3, measured_position=0.1) == pytest.approx(4.0 + 0.5 * 0.2)


def test_velocity_loop_controller_error():
    d = DiscreteGains(1.0, 0.0, 0.0, TS, loop="velocity")
    c = DigitalController(d, output_limit=None, error_scale=paper_error_scale())
    c.step(0.0, 10.0, 0.0, 0.0)
    assert c.last_parts["e"] == pytest.approx(10.0 * paper_error_scale())
    c.step(0.0, 10.0, 0.0, 0.05)  # measured 10 rad/s
    assert c.last_parts["e"] == pytest.approx(0.0, abs=1e-12)


def test_feedforward_eq8():
    ff = Feedforward(K, TAU)
    assert ff(3.0, 100.0) == pytest.approx((TAU * 100.0 + 3.0) / K)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: pole_placement_pid(K, TAU, -1.0), "wn"),
        (lambda: pole_placement_pid(K, float("nan"), 10.0), "tau"),
        (lambda: pole_placement_pid(K, TAU, 10.0, sigma=0.0), "sigma"),
        (lambda: pole_placement_pid(K, TAU, 10.0).discretize(0.0), "Ts"),
        (lambda: discrete_pole_placement_pid(K, TAU, 10.0, Ts=-1.0), "Ts"),
        (lambda: discrete_pole_placement_pid(K, TAU, 10.0, extra_pole=1.5), "extra_pole"),
        (lambda: DigitalController(pole_placement_pid(K, TAU, 10.0)), "gains"),
        (lambda: DigitalController(DiscreteGains(1, 1, 1, TS), output_limit=-1), "output_limit"),
        (lambda: Feedforward(0.0, TAU), "K"),
        (lambda: Gains(1.0, float("inf"), 0.0), "ki"),
    ],
)
def test_bad_input(call, name):
    with pytest.raises(ValueError, match=name):
        call()
