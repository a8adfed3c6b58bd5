"""fit_dc_motor (jerklab.ident.fit): PEM accuracy on the plant model, convergence from its own start,
uncertainty coverage, the options as keywords or a FitOptions, bad data and bad options."""

from __future__ import annotations

import dataclasses

import control as ct
import numpy as np
import pytest
from _ident import K0, TAU0, TS, ct_response, plant_record
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from jerklab import ident


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("kind", ["step", "prbs"])
def test_pem_within_one_percent_on_quantized_noisy_plant(kind, seed):
    u = (
        ident.step_input(2.0, TS, 6.0)
        if kind == "step"
        else ident.prbs(2.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=seed)
    )
    theta = plant_record(u, seed)  # 448-pulse encoder, 10-bit PWM, noise 2 mrad
    f = ident.fit_dc_motor(u, theta, TS, method="pem")
    assert abs(f.K / K0 - 1) < 0.01, f.summary()
    assert abs(f.tau / TAU0 - 1) < 0.01, f.summary()
    assert f.fit_percent > 99.0
    assert isinstance(f.model, ct.TransferFunction)
    np.testing.assert_allclose(np.ravel(f.model.den[0][0]), [f.tau, 1.0, 0.0])


@settings(max_examples=80, deadline=None)
@given(
    K=st.floats(-200, 200).filter(lambda k: abs(k) > 0.1),
    tau=st.floats(0.0005, 2.0),
    Ts=st.sampled_from([0.001, 0.005, 0.02]),
    n=st.integers(30, 600),
    kind=st.sampled_from(["step", "prbs"]),
    amp=st.floats(0.1, 12.0),
    seed=st.integers(0, 99),
)
def test_pem_converges_from_its_own_start(K, tau, Ts, n, kind, amp, seed):
    """No initial guess from the user: the tau grid + LM finds the optimum over 4 decades of tau/Ts,
    either sign of K, records shorter than tau."""
    u = (
        ident.step_input(n * Ts, Ts, amp, t_step=3 * Ts)
        if kind == "step"
        else ident.prbs(n * Ts, Ts, amp, offset=amp / 2, seed=seed)
    )
    a, b1, b2 = ident.dc_motor_zoh_coefficients(K, tau, Ts)
    y = signal.lfilter([0.0, b1, b2], np.convolve([1, -1], [1, -a]), u) + 0.7
    f = ident.fit_dc_motor(u, y, Ts, method="pem")
    assert abs(f.K / K - 1) < 1e-6 and abs(f.tau / tau - 1) < 1e-6
    assert f.theta0 == pytest.approx(0.7, abs=1e-6 * max(1.0, abs(K) * amp * n * Ts))


def test_pem_with_friction_on_prbs():
    u = ident.prbs(2.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=5)
    theta = plant_record(u, 5, coulomb_friction=0.3)
    plain = ident.fit_dc_motor(u, theta, TS)
    fr = ident.fit_dc_motor(u, theta, TS, friction=True)
    assert abs(fr.K / K0 - 1) < 0.01 and abs(fr.tau / TAU0 - 1) < 0.01, fr.summary()
    assert fr.friction == pytest.approx(0.3, abs=0.03)
    assert plain.K < 0.97 * K0  # friction unmodelled: K biased by ~ -f_c/|u|
    # the fitted model, simulated on the record, includes the friction
    np.testing.assert_allclose(fr.simulate(u, fr.theta0, fr.omega0), fr.y_sim, atol=1e-9)


def test_pem_coverage_monte_carlo():
    """With white noise the Jacobian-based standard errors cover the truth at the nominal rate."""
    rng = np.random.default_rng(2024)
    u = ident.step_input(0.5, TS, 3.0, t_step=0.02)
    clean = ident.simulate_dc_motor(K0, TAU0, TS, u)
    n, hitK, hitT = 200, 0, 0
    for _ in range(n):
        f = ident.fit_dc_motor(u, clean + rng.normal(0, 0.02, u.size), TS, method="pem")
        hitK += abs(f.K - K0) <= 1.96 * f.K_std
        hitT += abs(f.tau - TAU0) <= 1.96 * f.tau_std
    # binomial(200, 0.95): 0.90 .. 0.99 holds with probability > 0.999
    assert 0.90 <= hitK / n <= 0.99
    assert 0.90 <= hitT / n <= 0.99


@pytest.mark.parametrize(
    "u,theta,Ts,msg",
    [
        (
            np.r_[np.zeros(10), np.full(40, 6.0)],
            np.r_[np.zeros(10), np.arange(40.0)][:-1],
            TS,
            "same length",
        ),
        (np.r_[np.nan, np.ones(49)], np.arange(50.0), TS, "u contains"),
        (np.r_[0.0, np.ones(49)], np.r_[np.arange(49.0), np.inf], TS, "theta contains"),
        (np.r_[0.0, np.ones(4)], np.arange(5.0), TS, "too short"),
        (np.full(50, 6.0), np.arange(50.0), TS, "u is constant"),
        (np.r_[0.0, np.ones(49)], np.zeros(50), TS, "theta is constant"),
        (np.r_[0.0, np.ones(49)], np.arange(50.0), 0.0, "Ts"),
        (np.r_[0.0, np.ones(49)], np.arange(50.0), float("nan"), "Ts"),
    ],
)
@pytest.mark.parametrize("method", ["pem", "arx"])
def test_bad_data_raises(u, theta, Ts, msg, method):
    with pytest.raises(ValueError, match=msg):
        ident.fit_dc_motor(u, theta, Ts, method=method)


def test_bad_options_raise():
    u = ident.step_input(0.5, TS, 6.0)
    th = ident.simulate_dc_motor(K0, TAU0, TS, u)
    with pytest.raises(ValueError, match="method"):
        ident.fit_dc_motor(u, th, TS, method="p2")
    with pytest.raises(ValueError, match="friction"):
        ident.fit_dc_motor(u, th, TS, method="arx", friction=True)
    with pytest.raises(ValueError, match="u must be"):
        ident.fit_dc_motor(np.ones((10, 10)), th, TS)
    with pytest.raises(ValueError, match="theta"):
        ident.fit_dc_motor(
            u, -th * 0 + np.where(np.arange(u.size) % 2, 1.0, -1.0), TS, method="arx"
        )


def test_pem_on_a_record_cut_while_the_motor_turns():
    """One output-error path for every record: the initial angle and velocity are estimated, so a
    record that starts while the motor turns (the second half of a PRBS) is fitted exactly
    (python-control's ZOH simulation as the reference). The single-shooting fit from rest of
    earlier versions assumed omega0 = 0 and was biased here."""
    u = ident.prbs(1.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=6)
    th = ct_response(K0, TAU0, TS, u, theta0=1.5, omega0=150.0)
    f = ident.fit_dc_motor(u, th, TS)
    assert f.K == pytest.approx(K0, rel=1e-6) and f.tau == pytest.approx(TAU0, rel=1e-6)
    assert f.theta0 == pytest.approx(1.5, abs=1e-6) and f.omega0 == pytest.approx(150.0, rel=1e-6)
    assert f.n_segments == 1 and f.estimated == ("K", "tau") and f.fit_percent > 100 - 1e-6


def test_options_as_keywords_or_as_one_object():
    u = ident.prbs(2.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=5)
    theta = plant_record(u, 5, coulomb_friction=0.3)
    by_keyword = ident.fit_dc_motor(u, theta, TS, friction=True, delay=True)
    opts = ident.FitOptions(friction=True, delay=True)
    by_object = ident.fit_dc_motor(u, theta, TS, options=opts)
    assert (by_object.K, by_object.tau, by_object.friction, by_object.delay) == (
        by_keyword.K,
        by_keyword.tau,
        by_keyword.friction,
        by_keyword.delay,
    )
    # keywords given with an options object replace its fields
    linear = ident.fit_dc_motor(u, theta, TS, options=opts, friction=False)
    assert linear.estimated == ("K", "tau") and linear.friction == 0.0
    # the record's own fit passes them on too
    d = ident.IdentData(u, theta, TS)
    assert d.fit(options=opts).K == by_keyword.K
    assert opts.names == ["K", "tau", "friction"] and opts.estimate_delay and not opts.is_linear
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.friction = False


@pytest.mark.parametrize(
    "make,exc,name",
    [
        (lambda: ident.FitOptions(friction="yes"), ValueError, "friction"),
        (lambda: ident.FitOptions(delay=-1), ValueError, "delay"),
        (lambda: ident.FitOptions(max_delay=2.5), ValueError, "max_delay"),
        (lambda: ident.FitOptions(segment=-0.1), ValueError, "segment"),
        (lambda: ident.FitOptions(cutoff=float("nan")), ValueError, "cutoff"),
        (lambda: ident.FitOptions(coast="always"), ValueError, "coast"),
        (lambda: ident.FitOptions(coast="coulomb"), ValueError, "friction"),
    ],
)
def test_fit_options_name_the_bad_field(make, exc, name):
    with pytest.raises(exc, match=name):
        make()


def test_bad_option_objects_and_keywords():
    u = ident.step_input(0.5, TS, 6.0)
    th = ident.simulate_dc_motor(K0, TAU0, TS, u)
    with pytest.raises(TypeError, match="frictoin"):
        ident.fit_dc_motor(u, th, TS, frictoin=True)
    with pytest.raises(ValueError, match="options"):
        ident.fit_dc_motor(u, th, TS, options={"friction": True})
    # the first sample as the initial angle is an ARX option: the output-error fit estimates it
    with pytest.raises(ValueError, match="fit_theta0"):
        ident.fit_dc_motor(u, th, TS, fit_theta0=False)
    f = ident.fit_dc_motor(u, th + 0.3, TS, method="arx", fit_theta0=False)
    assert f.theta0 == 0.3 and f.K == pytest.approx(K0, rel=1e-9)
