"""The front door fit_dc_motor (jerklab.ident.fit) and its result MotorFit: bad data and options
raise naming the parameter, FitOptions is the keyword form, the diagnostics name the cause.
"""

from __future__ import annotations

import numpy as np
import pytest
from _ident import K0, TAU0, TS, plant_record, record, rel

from jerklab import ident
from jerklab.ident import diagnostics


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


def test_bad_options():
    u = ident.step_input(1.0, TS, 6.0)
    y = record(u)
    with pytest.raises(ValueError, match="offset"):
        ident.fit_dc_motor(u, y, TS, offset=1)
    with pytest.raises(ValueError, match="delay"):
        ident.fit_dc_motor(u, y, TS, delay=-1)
    with pytest.raises(ValueError, match="method='pem'"):
        ident.fit_dc_motor(u, y, TS, method="arx", delay=2)
    with pytest.raises(ValueError, match="segment"):
        ident.fit_dc_motor(u, y, TS, segment=0.001)
    with pytest.raises(ValueError, match="method"):
        ident.fit_dc_motor(u, y, TS, method="oe")


def test_confidence_interval_and_to_motor():
    u = ident.step_input(1.0, TS, 6.0)
    f = ident.fit_dc_motor(u, plant_record(u, 9), TS)
    lo, hi = f.confidence_interval(0.95)["K"]
    assert lo < f.K < hi and hi - lo == pytest.approx(2 * 1.959964 * f.K_std, rel=1e-5)
    m = f.to_motor(encoder_ppr=None)
    assert m.K == f.K and m.tau == f.tau
    with pytest.raises(ValueError, match="level"):
        f.confidence_interval(1.5)


def test_reversed_encoder_warns_with_the_cause():
    u = ident.prbs(2.0, TS, 3.0, offset=6.0, clock_period=0.02, seed=5)
    y = record(u)
    for kw in ({}, {"method": "arx"}, {"friction": True, "offset": True}):
        with pytest.warns(ident.IdentificationWarning, match="reversed"):
            f = ident.fit_dc_motor(u, -y, TS, **kw)
        assert f.K < 0 and any("reversed" in w for w in f.warnings)


def test_single_step_cannot_separate_friction_and_says_so():
    u = ident.step_input(2.0, TS, 6.0)
    with pytest.warns(ident.IdentificationWarning, match="not exciting enough"):
        ident.fit_dc_motor(u, record(u, coulomb_friction=0.3), TS, friction=True)


def test_friction_stuck_at_its_bound_is_reported():
    u = ident.prbs(2.0, TS, 4.0, offset=0.0, clock_period=0.04, seed=4)
    with pytest.warns(ident.IdentificationWarning, match="bound"):
        f = ident.fit_dc_motor(u, record(u), TS, friction=True)
    assert f.friction < 2 * f.friction_std + 1e-3


def test_friction_above_the_input_range_is_reported():
    msgs = diagnostics._diagnose(
        {"K": 10.0, "tau": 0.1, "friction": 5.0, "offset": 0.0, "dead_zone": 0.0},
        np.diag([1.0, 1e-4, 0.01]),
        ["K", "tau", "friction"],
        u_abs_max=3.0,
    )
    assert any("larger than the largest input" in m for m in msgs)


# ---------------------------------------------------------------- the options as one object
def test_fit_options_are_the_keywords():
    u = ident.prbs(2.0, TS, 4.0, offset=0.0, clock_period=0.04, seed=3)
    y = record(u, 2, coulomb_friction=0.4, offset=0.2)
    kw = dict(friction=True, offset=True, delay=True, max_delay=4)
    a = ident.fit_dc_motor(u, y, TS, **kw)
    b = ident.fit_dc_motor(u, y, TS, options=ident.FitOptions(**kw))
    c = ident.IdentData(u, y, TS).fit(options=ident.FitOptions(**kw))
    for f in (b, c):
        assert (f.K, f.tau, f.friction, f.offset, f.delay) == (
            a.K,
            a.tau,
            a.friction,
            a.offset,
            a.delay,
        )
        np.testing.assert_array_equal(f.covariance, a.covariance)
    assert a.estimated == tuple(ident.FitOptions(**kw).names) == ("K", "tau", "friction", "offset")
    opts = ident.FitOptions(coast="coulomb", friction=True)
    with pytest.raises(AttributeError):
        opts.friction = False  # frozen
    assert ident.FitOptions(delay=False).delay == 0 and ident.FitOptions(delay=True).delay is True


@pytest.mark.parametrize(
    "kw,name",
    [
        (dict(method="oe"), "method"),
        (dict(friction=1), "friction"),
        (dict(fit_theta0="yes"), "fit_theta0"),
        (dict(delay=-1), "delay"),
        (dict(delay=1.5), "delay"),
        (dict(max_delay=-2), "max_delay"),
        (dict(cutoff=0.0), "cutoff"),
        (dict(cutoff=float("nan")), "cutoff"),
        (dict(segment=-1.0), "segment"),
        (dict(coast="viscous"), "coast"),
        (dict(coast="coulomb"), "friction=True"),
        (dict(method="arx", offset=True), "method='pem'"),
        (dict(method="idim", coast=True), "method='pem'"),
    ],
)
def test_fit_options_name_the_bad_field(kw, name):
    with pytest.raises(ValueError, match=name):
        ident.FitOptions(**kw)


def test_options_and_keywords_are_not_mixed():
    u = ident.step_input(1.0, TS, 6.0)
    y = record(u)
    with pytest.raises(ValueError, match="options"):
        ident.fit_dc_motor(u, y, TS, friction=True, options=ident.FitOptions(offset=True))
    with pytest.raises(ValueError, match="options"):
        ident.fit_dc_motor(u, y, TS, options={"friction": True})
    # keywords left at their defaults are not a conflict
    f = ident.fit_dc_motor(u, y, TS, "pem", friction=False, options=ident.FitOptions())
    assert f.method == "pem"


@pytest.mark.parametrize("kw", [{}, {"friction": True}, {"delay": 1}, {"method": "arx"}])
def test_fit_theta0_false_holds_the_first_sample(kw):
    """fit_theta0=False starts the model at the measured first angle, for every method and option
    (the output-error fit once ignored it whenever it cut or extended the model)."""
    u = np.concatenate([np.zeros(10), np.full(150, 3.0), np.full(150, 8.0)])
    fc = 0.3 if kw.get("friction") else 0.0
    y = record(u, kw.get("delay", 0), coulomb_friction=fc) + 0.05
    free = ident.fit_dc_motor(u, y, TS, **kw)
    held = ident.fit_dc_motor(u, y, TS, fit_theta0=False, **kw)
    assert held.theta0 == y[0] and free.theta0 != y[0]
    assert held.y_sim[0] == pytest.approx(y[0], abs=1e-12)
    if kw.get("method") == "arx":  # the angle offset does not enter the velocity regression
        assert (held.K, held.tau) == (free.K, free.tau)
    else:
        assert rel(held.K, K0) < 0.01 and rel(held.tau, TAU0) < 0.01, held.summary()
        # merged experiments: each record's first angle is held
        u2 = np.concatenate([np.zeros(10), np.full(200, -5.0)])
        y2 = record(u2, kw.get("delay", 0), seed=1, coulomb_friction=fc) - 0.3
        m = ident.fit_dc_motor([u, u2], [y, y2], TS, fit_theta0=False, **kw)
        np.testing.assert_allclose(m.y_sim[[0, u.size]], [y[0], y2[0]], atol=1e-12)
