"""Tests of jerklab.ident: exactness against python-control, PEM accuracy on the plant model,
ARX bias against its asymptotic prediction, uncertainty coverage, bad data."""

from __future__ import annotations

import json
import math
import types

import control as ct
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from jerklab import ident
from jerklab.plant import DCMotor

K0, TAU0, TS = 32.4, 0.025, 0.005


def ct_response(K, tau, Ts, u, theta0=0.0, omega0=0.0):
    """Independent reference: python-control's ZOH discretization of the state space of eq. 1."""
    sys = ct.ss([[0.0, 1.0], [0.0, -1.0 / tau]], [[0.0], [K / tau]], [[1.0, 0.0]], [[0.0]])
    sysd = ct.c2d(sys, Ts, "zoh")
    r = ct.forced_response(sysd, T=np.arange(len(u)) * Ts, U=u, X0=[theta0, omega0])
    return np.asarray(r.outputs).ravel()


def plant_record(u, seed, **kw):
    """(u, theta_measured) as the identification would see them from jerklab.plant.DCMotor."""
    kw.setdefault("noise_std", 0.002)
    m = DCMotor(K=K0, tau=TAU0, seed=seed, **kw)
    _, meas = m.open_loop(u, TS)
    return meas[:-1]


# ---------------------------------------------------------------- the ZOH model itself
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


# ---------------------------------------------------------------- ARX
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


@settings(max_examples=60, deadline=None)
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


# ---------------------------------------------------------------- PEM on the plant model
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


# ---------------------------------------------------------------- the paper's 'P2' call
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


# ---------------------------------------------------------------- bad data
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


# ---------------------------------------------------------------- data container
def test_identdata_roundtrip(tmp_path):
    u = ident.prbs(0.5, TS, 3.0, offset=6.0, seed=1)
    y = ident.simulate_dc_motor(K0, TAU0, TS, u) + 1e-3 * np.random.default_rng(0).normal(
        size=u.size
    )
    d = ident.IdentData(u, y, TS, metadata={"seed": 1, "note": "ö"})
    csv, js = d.save(tmp_path / "run")
    assert csv.name == "run.csv" and js.name == "run.json"
    side = json.loads(js.read_text())
    assert side["Ts"] == TS and side["n_samples"] == u.size and side["input_unit"] == "V"
    for p in (tmp_path / "run", csv, js):
        e = ident.IdentData.load(p)
        np.testing.assert_array_equal(e.u, u)
        np.testing.assert_array_equal(e.y, y)
        assert e.Ts == TS and e.metadata == {"seed": 1, "note": "ö"}
    assert d[:40].n == 40 and d[40:].metadata["slice_start_sample"] == 40
    np.testing.assert_allclose(d.t[-1], (u.size - 1) * TS)
    assert d.fit("pem").fit_percent > 99


def test_identdata_bad(tmp_path):
    with pytest.raises(ValueError, match="same length"):
        ident.IdentData(np.ones(5), np.ones(6), TS)
    with pytest.raises(ValueError, match="Ts"):
        ident.IdentData(np.ones(5), np.ones(5), -1.0)
    with pytest.raises(ValueError, match="metadata"):
        ident.IdentData(np.ones(5), np.ones(5), TS, metadata={"x": object()})
    with pytest.raises(ValueError, match="sidecar"):
        ident.IdentData.load(tmp_path / "missing")
    d = ident.IdentData(np.arange(5.0), np.ones(5), TS)
    d.save(tmp_path / "x")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(ValueError, match="corrupt"):
        ident.IdentData.load(tmp_path / "x")
    d.save(tmp_path / "x")
    (tmp_path / "x.csv").write_text("time_s,u_V,y_rad\n0,1,2\n0.005,1,oops\n")
    with pytest.raises(ValueError, match="path"):
        ident.IdentData.load(tmp_path / "x")


def test_identdata_from_recording_object():
    t = np.arange(100) * TS
    u = ident.step_input(0.5, TS, 6.0)
    rec = types.SimpleNamespace(
        time=t + 1.0,
        position=ident.simulate_dc_motor(K0, TAU0, TS, u),
        control=u,
        metadata={"Ts": TS, "port": "virtual"},
    )
    d = ident.IdentData.from_recording(rec)
    assert d.Ts == TS and d.n == 100 and d.metadata["port"] == "virtual" and d.metadata["t0"] == 1.0
    jitter = types.SimpleNamespace(
        time=t + np.r_[np.zeros(50), np.full(50, 0.2 * TS)],
        position=rec.position,
        control=u,
        metadata={},
    )
    with pytest.raises(ValueError, match="rec.time"):
        ident.IdentData.from_recording(jitter)
    with pytest.raises(ValueError, match="position"):
        ident.IdentData.from_recording(types.SimpleNamespace(time=t, control=u))


def test_identdata_from_virtual_rig_recording(tmp_path):
    """A real Recording from the virtual rig: sampling convention matches, PEM recovers K, tau."""
    from jerklab.rig import Recording, connect

    rig = connect(progress=False, recordings=tmp_path, device=DCMotor(seed=4))
    try:
        rec = rig.step(6.0, 0.5, Ts=TS, rest=0.05)
    finally:
        rig.close()
    for r in (rec, Recording.load(rec.csv_path)):
        d = ident.IdentData.from_recording(r)
        assert d.Ts == pytest.approx(TS) and d.n == 110
        assert np.all(d.u[:10] == 0.0) and d.y[10] == 0.0 and d.y[11] > 0.0
        f = d.fit("pem")
        assert f.K == pytest.approx(K0, rel=0.01) and f.tau == pytest.approx(TAU0, rel=0.01)


# ---------------------------------------------------------------- validation helpers
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


def test_confidence_interval_and_to_motor():
    u = ident.step_input(1.0, TS, 6.0)
    f = ident.fit_dc_motor(u, plant_record(u, 9), TS)
    lo, hi = f.confidence_interval(0.95)["K"]
    assert lo < f.K < hi and hi - lo == pytest.approx(2 * 1.959964 * f.K_std, rel=1e-5)
    m = f.to_motor(encoder_ppr=None)
    assert m.K == f.K and m.tau == f.tau
    with pytest.raises(ValueError, match="level"):
        f.confidence_interval(1.5)


# ---------------------------------------------------------------- input design
def test_prbs_properties():
    u = ident.prbs(127 * 0.02, TS, 2.0, offset=5.0, clock_period=0.02, nbits=7, seed=3)
    assert u.size == 127 * 4
    assert set(np.unique(u)) == {3.0, 7.0}
    bits = u[::4]
    assert np.all(u.reshape(-1, 4) == bits[:, None])  # each bit held 4 samples
    assert np.count_nonzero(bits == 7.0) == 64  # maximum-length: 2^(n-1) ones per period
    assert not np.array_equal(
        bits, ident.prbs(127 * 0.02, TS, 2.0, offset=5.0, clock_period=0.02, nbits=7, seed=4)[::4]
    )
    with pytest.raises(ValueError, match="clock_period"):
        ident.prbs(1.0, TS, 1.0, clock_period=0.0123)
    with pytest.raises(ValueError, match="amplitude"):
        ident.prbs(1.0, TS, -1.0)


def test_step_input_and_sample_time_rule():
    u = ident.step_input(0.1, TS, 6.0, t_step=0.02)
    assert u.size == 20 and np.all(u[:4] == 0) and np.all(u[4:] == 6.0)
    with pytest.raises(ValueError, match="t_step"):
        ident.step_input(0.1, TS, 6.0, t_step=0.2)
    lo, hi = ident.sample_time_range(0.025)
    assert lo == pytest.approx(0.005) and hi == pytest.approx(0.0125)
