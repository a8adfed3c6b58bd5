"""Tests of jerklab.plant against python-control and brute-force integration."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jerklab.plant import (
    DCMotor,
    FlexibleDCMotor,
    StepDisturbance,
    advance,
    advance_scalar,
    quantize_voltage,
)


def test_defaults_are_the_paper_motor():
    m = DCMotor()
    assert (m.K, m.tau) == (32.4, 0.025)
    assert m.counts_per_rad == pytest.approx(448 / (2 * math.pi))
    assert DCMotor(decoding=4).counts_per_rad == pytest.approx(4 * 448 / (2 * math.pi))


def test_transfer_functions_match_eq1():
    m = DCMotor(K=20.0, tau=0.04)
    w = np.logspace(-1, 3, 30)
    s = 1j * w
    np.testing.assert_allclose(m.tf()(s), 20.0 / (s * (0.04 * s + 1)), rtol=1e-12)
    np.testing.assert_allclose(m.velocity_tf()(s), 20.0 / (0.04 * s + 1), rtol=1e-12)
    np.testing.assert_allclose(ct.ss2tf(m.ss())(s), m.tf()(s), rtol=1e-10)
    np.testing.assert_allclose(ct.ss2tf(m.ss("omega"))(s), m.velocity_tf()(s), rtol=1e-10)


@pytest.mark.parametrize("Ts", [1e-4, 0.005, 0.05, 1.0])
def test_zoh_matches_python_control(Ts):
    m = DCMotor()
    Phi, Gamma = m.zoh(Ts)
    d = ct.c2d(m.ss(), Ts, "zoh")
    np.testing.assert_allclose(Phi, d.A, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(Gamma, d.B, rtol=1e-9, atol=1e-14)


def test_open_loop_linear_equals_forced_response():
    m = DCMotor(supply_voltage=None, pwm_bits=None, encoder_ppr=None)
    rng = np.random.default_rng(1)
    u = rng.uniform(-5, 5, 200)
    Ts = 0.005
    theta, meas = m.open_loop(u, Ts)
    d = ct.c2d(m.ss(), Ts, "zoh")
    r = ct.forced_response(d, T=np.arange(201) * Ts, U=np.r_[u, 0.0])
    np.testing.assert_allclose(theta, r.outputs, rtol=1e-9, atol=1e-11)
    np.testing.assert_array_equal(theta, meas)


def _brute_force(theta, omega, v, fc, K, tau, dt, n=200_000):
    """Semi-implicit Euler with a Karnopp stick band: independent of the event solution."""
    h = dt / n
    for _ in range(n):
        if omega == 0.0 and abs(v) <= fc:
            continue
        s = math.copysign(1.0, omega) if omega != 0.0 else math.copysign(1.0, v)
        new = omega + h * (K * (v - s * fc) - omega) / tau
        if omega != 0.0 and new * omega < 0.0:  # crossed zero inside this tiny step
            new = 0.0
        omega = new
        theta += h * omega
    return theta, omega


@pytest.mark.parametrize(
    "x0, v",
    [
        ((0.0, 0.0), 0.8),
        ((0.0, 0.0), 1.7),
        ((0.3, 40.0), -0.5),
        ((0.3, 40.0), -4.0),
        ((0.0, -12.0), 0.2),
        ((0.0, 5.0), 3.0),
    ],
)
def test_coulomb_friction_against_brute_force(x0, v):
    fc, K, tau, dt = 1.0, 32.4, 0.025, 0.1
    th, om = advance_scalar(x0[0], x0[1], v, fc, K, tau, dt)
    thb, omb = _brute_force(x0[0], x0[1], v, fc, K, tau, dt)
    assert th == pytest.approx(thb, abs=2e-4)
    assert om == pytest.approx(omb, abs=5e-3)


def test_friction_sticks_and_steady_speed():
    m = DCMotor(coulomb_friction=1.0, supply_voltage=None, pwm_bits=None, encoder_ppr=None)
    assert np.all(m.step_state([0.2, 0.0], 0.99, 1.0) == [0.2, 0.0])
    x = m.step_state([0.0, 0.0], 3.0, 2.0)
    assert x[1] == pytest.approx(32.4 * 2.0, rel=1e-9)  # K (u - f_c)
    # decelerating with a small opposite voltage: stops and stays stopped
    x = m.step_state([0.0, 30.0], -0.5, 1.0)
    assert x[1] == 0.0 and x[0] > 0.0


@given(st.floats(-50, 50), st.floats(-8, 8), st.floats(0, 3), st.floats(1e-4, 0.2))
def test_vectorized_advance_equals_scalar(omega, v, fc, dt):
    for om in (omega, 0.0):
        a = advance_scalar(0.1, om, v, fc, 32.4, 0.025, dt)
        b = advance(0.1, om, v, fc, 32.4, 0.025, dt)
        assert float(b[0]) == pytest.approx(a[0], rel=1e-12, abs=1e-12)
        assert float(b[1]) == pytest.approx(a[1], rel=1e-12, abs=1e-12)


def test_friction_free_advance_is_zoh():
    m = DCMotor()
    Phi, Gamma = m.zoh(0.005)
    x = np.array([0.4, -7.0])
    th, om = advance_scalar(x[0], x[1], 2.5, 0.0, m.K, m.tau, 0.005)
    np.testing.assert_allclose([th, om], Phi @ x + Gamma[:, 0] * 2.5, rtol=1e-13)


def test_quantize_voltage_saturates_and_quantizes():
    u = quantize_voltage([-20.0, 0.004, 5.0, 20.0], 12.0, 10)
    assert u[0] == -12.0 and u[-1] == 12.0
    assert u[1] == pytest.approx(0.0 if 0.004 < 6 / 1023 else 12 / 1023)
    assert round(u[2] / 12 * 1023) == pytest.approx(u[2] / 12 * 1023, abs=1e-9)
    assert abs(u[2] - 5.0) <= 6.0 / 1023 + 1e-12
    m = DCMotor(pwm_bits=None)
    assert m.quantize_voltage(5.123) == 5.123


def test_encoder_quantization_and_noise():
    m = DCMotor()
    c = m.counts_per_rad
    th = np.linspace(-1, 1, 1001)
    y = m.measure(th)
    assert np.all(np.abs(y - th) < 1 / c + 1e-12)
    np.testing.assert_allclose(y * c, np.round(y * c), atol=1e-9)
    n = DCMotor(encoder_ppr=None, noise_std=0.01, seed=3).measure(np.zeros(20000))
    assert np.std(n) == pytest.approx(0.01, rel=0.05)


def test_step_disturbance_splits_interval():
    m = DCMotor(
        load_disturbance=(0.0123, -2.0), supply_voltage=None, pwm_bits=None, encoder_ppr=None
    )
    assert isinstance(m.load_disturbance, StepDisturbance)
    x = m.step_state([0.0, 0.0], 1.0, 0.02, t=0.01)
    ref = m.ideal().step_state([0.0, 0.0], 1.0, 0.0023)
    ref = m.ideal().step_state(ref, -1.0, 0.0177)
    np.testing.assert_allclose(x, ref, rtol=1e-12)


def test_flexible_rigid_body_and_mode():
    f = FlexibleDCMotor(load_ratio=1e-4, mode_frequency=50.0, mode_damping=0.02)
    p = f.ss().poles()
    q = p[np.argmax(p.imag)]
    assert abs(q) == pytest.approx(50.0, rel=1e-3)
    assert -q.real / abs(q) == pytest.approx(0.02, rel=1e-2)
    g = FlexibleDCMotor()
    m = DCMotor()
    w = np.logspace(-1, 0.5, 10)  # far below the mode: eq. 1
    np.testing.assert_allclose(g.tf()(1j * w), m.tf()(1j * w), rtol=2e-3)
    Phi, Gamma = g.zoh(0.005)
    d = ct.c2d(g.ss(), 0.005, "zoh")
    np.testing.assert_allclose(Phi, d.A, atol=1e-12)
    np.testing.assert_allclose(Gamma, d.B, atol=1e-12)
    th_load, meas = g.open_loop(np.ones(50), 0.005, output="load")
    assert th_load.shape == meas.shape == (51,)


@pytest.mark.parametrize(
    "kw",
    [
        dict(K=-1),
        dict(tau=float("nan")),
        dict(decoding=3),
        dict(coulomb_friction=-0.1),
        dict(noise_std=float("inf")),
        dict(supply_voltage=0.0),
        dict(pwm_bits=1.5),
        dict(load_disturbance="x"),
    ],
)
def test_bad_input_names_the_parameter(kw):
    name = next(iter(kw))
    with pytest.raises(ValueError, match=name):
        DCMotor(**kw)


def test_bad_call_arguments():
    m = DCMotor()
    with pytest.raises(ValueError, match="Ts"):
        m.zoh(-1.0)
    with pytest.raises(ValueError, match="u"):
        m.open_loop([1.0, float("nan")], 0.005)
    with pytest.raises(ValueError, match="x0"):
        m.open_loop([1.0], 0.005, x0=[1, 2, 3])
