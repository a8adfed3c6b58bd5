"""jerklab.tuning: the panel's numbers without widgets, checked against python-control.

The sampled loop is rebuilt here from python-control alone (ZOH plant by ``ct.c2d``, the
Stojčić eq. 12 PID with its derivative filter written out), independent of
``jerklab.controller``'s polynomials.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jerklab import tuning
from jerklab.controller import Gains

K, TAU = 32.4, 0.025
COUNT = 2 * math.pi / 448


def loop_radius(g, K=K, tau=TAU):
    """Largest closed-loop |z| of the eq.-12 PID (with filter γ) on the ZOH plant, python-control only."""
    P = ct.c2d(ct.tf([K], [tau, 1.0, 0.0]), g.Ts, "zoh")
    z = ct.tf([1.0, 0.0], [1.0], g.Ts)
    C = g.kpd + g.kid * z / (z - 1) + g.kdd * (z - 1) / (z - g.gamma)
    return float(np.max(np.abs(ct.feedback(C * P, 1).poles())))


def first_unstable_wn(design, Ts):
    for wn in range(2, 101):
        d, _ = tuning.design_gains(K, TAU, 1.0, float(wn), 7.0, Ts, design)
        if loop_radius(d) >= 1.0:
            return wn
    return None


def test_z_domain_design_leaves_the_unit_circle_inside_the_slider_range():
    """The z-domain design's fourth pole leaves the unit circle (ωn 35, Ts 11 ms, ±1 rad/s)."""
    for Ts, wn_reported in ((0.005, 52), (0.011, 30), (0.020, 21)):
        wn = first_unstable_wn("z-domain", Ts)
        assert wn is not None and abs(wn - wn_reported) <= 1, (Ts, wn)
        d, _ = tuning.design_gains(K, TAU, 1.0, float(wn), 7.0, Ts, "z-domain")
        assert tuning.closed_loop_max_radius(K, TAU, d) == pytest.approx(loop_radius(d), rel=1e-7)
    # the four-pole design (derivative filter) never does, over the whole slider range
    assert first_unstable_wn("z-domain-filter", 0.020) is None


@pytest.mark.parametrize(
    "design,wn,Ts",
    [
        ("z-domain", 35.0, 0.011),
        ("continuous", 50.0, 0.005),
        ("continuous", 40.0, 0.005),
        ("z-domain", 60.0, 0.005),
    ],
)
def test_advice_is_checked_for_the_selected_design(design, wn, Ts):
    res = tuning.compute_pole_placement(wn=wn, Ts=Ts, design=design)
    assert res.level in ("near", "unstable")
    assert res.advice and res.advice_text.startswith("What would help")
    # never the failing design itself
    assert tuning.DESIGN_NAMES[design] not in res.advice_text
    for s in res.advice:
        p = dict(zeta=1.0, wn=wn, sigma_ratio=7.0, Ts=Ts, design=design)
        p[s.change] = s.value
        d, _ = tuning.design_gains(
            K, TAU, p["zeta"], p["wn"], p["sigma_ratio"], p["Ts"], p["design"]
        )
        r = loop_radius(d)
        assert r < 1.0 and s.max_radius == pytest.approx(r, rel=1e-6)
        if s.change == "wn" and s.value + 1.0 < wn:  # the largest such ωn on the slider grid
            assert tuning._level(K, TAU, 1.0, s.value + 1.0, 7.0, Ts, design)[0] != "ok"


def test_z_domain_selected_and_unstable_is_not_told_to_use_z_domain():
    """ωn 35, Ts 11 ms, z-domain design selected."""
    res = tuning.compute_pole_placement(wn=35.0, Ts=0.011, design="z-domain")
    assert res.level == "unstable" and res.max_radius > 1.0
    assert "direct z-domain design" not in res.advice_text
    changes = {s.change: s.value for s in res.advice}
    assert changes["design"] == "z-domain-filter"
    assert changes["wn"] < 35.0 and changes["Ts"] < 0.011


def test_check_runnable_refuses_unstable_unless_forced():
    res = tuning.compute_pole_placement(wn=35.0, Ts=0.011, design="z-domain")
    with pytest.raises(tuning.UnstableDesignError, match=r"\|z\| = 1\.\d+ ≥ 1") as err:
        tuning.check_runnable(K, TAU, res.gains, design="z-domain")
    assert isinstance(err.value, ValueError) and err.value.max_radius == pytest.approx(
        loop_radius(res.gains)
    )
    assert "direct z-domain design" in str(err.value)
    assert tuning.check_runnable(K, TAU, res.gains, force=True) > 1.0
    ok = tuning.compute_pole_placement()
    assert tuning.check_runnable(K, TAU, ok.gains) == pytest.approx(loop_radius(ok.gains))
    # continuous gains need Ts; anything else is a TypeError
    with pytest.raises(ValueError, match="Ts"):
        tuning.closed_loop_max_radius(K, TAU, Gains(1.0, 1.0, 0.1))
    with pytest.raises(TypeError, match="gains"):
        tuning.closed_loop_max_radius(K, TAU, (1.0, 2.0, 3.0))


def test_measured_error_is_reference_minus_encoder():
    res = tuning.compute_pole_placement()
    measured = np.asarray(tuning.move_profile().sample(res.t_move).position) - res.err_move_measured
    # the encoder reading is a whole number of counts; the true angle is not
    assert np.max(np.abs(measured / COUNT - np.round(measured / COUNT))) < 1e-6
    true = np.asarray(tuning.move_profile().sample(res.t_move).position) - res.err_move
    assert np.max(np.abs(true / COUNT - np.round(true / COUNT))) > 0.1
    assert np.max(np.abs(measured - true)) <= COUNT + 1e-9


def test_cache_returns_same_read_only_result():
    tuning.clear_cache()
    a = tuning.compute_pole_placement(wn=23.0)
    b = tuning.compute_pole_placement(wn=23.0, move=dict(tuning.DEFAULT_MOVE))
    assert a is b
    with pytest.raises(ValueError):
        a.err_move[0] = 1.0
    tuning.clear_cache()
    assert tuning.compute_pole_placement(wn=23.0) is not a


@given(st.floats(1e-3, 0.02), st.floats(-50, 50), st.floats(0, 1e4), st.floats(-1, 1))
def test_continuous_equivalent_inverts_eq13(Ts, kp, ki, kd):
    g = Gains(kp, ki, kd).discretize(Ts)
    assert tuning.continuous_equivalent(g) == pytest.approx((kp, ki, kd), rel=1e-9, abs=1e-9)


def test_gain_table_units():
    res = tuning.compute_pole_placement()
    rows = {n: (v, u) for n, v, u in tuning.gain_table(res.gains, res.continuous_gains)}
    assert rows["Kp"][1] == "V/rad" and rows["Ki"][1] == "V/(rad·s)" and rows["Kd"][1] == "V·s/rad"
    assert rows["Ki"][0] == pytest.approx(res.continuous_gains.ki)
    f = tuning.compute_pole_placement(design="z-domain-filter")
    assert "γ" in {n for n, _, _ in tuning.gain_table(f.gains)}


def test_angle_units_scale():
    assert tuning.format_angle(142.19934) == "142 rad"
    assert tuning.format_angle(0.00321) == "3.21 mrad"
    assert tuning.format_angle(-0.5) == "-500 mrad"
    assert tuning.format_angle(1.0) == "1.00 rad"
    assert tuning.angle_unit(0.999) == (1e3, "mrad") and tuning.angle_unit(1.0) == (1.0, "rad")


def test_bad_input_names_parameter():
    with pytest.raises(ValueError, match="design"):
        tuning.compute_pole_placement(design="bode")
    with pytest.raises(ValueError, match="move"):
        tuning.compute_pole_placement(move={"distance": 1.0})
    with pytest.raises(ValueError, match="max_velocity"):
        tuning.move_profile(dict(tuning.DEFAULT_MOVE, max_velocity=-1.0))
    with pytest.raises(ValueError, match="tau"):
        tuning.advise(K, 0.0, 1.0, 20.0, 7.0, 0.005)
