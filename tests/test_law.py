"""The one control law (jerklab.law) against the rule written down from the spec.

The expected values below are computed by hand from the rule (Stojčić eq. 17 and eq. 18
with the output clamp and conditional-integration anti-windup; the firmware's lround PWM;
the encoder's floor), never by calling jerklab's own helpers. Every test runs on each form
of the law: the plain-Python scalar form, the numba-compiled form and the numpy vector form
(and, for the PID, the stateful DigitalController).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from jerklab import law
from jerklab.controller import DigitalController, DiscreteGains, Feedforward
from jerklab.plant import measure_angle, quantize_voltage

# --------------------------------------------------------------------------- the forms


def _pid_scalar(*a):
    return law.SCALAR["pid_step"](*a)


def _pid_compiled(*a):
    return law.pid_step(*a)


def _pid_vector(e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, limit, aw):
    arr = [np.array([x, 0.0]) for x in (e, e_prev, i_prev, d_prev)]  # a second, idle plant
    u, p, i, d, sat = law.pid_step_vec(*arr, ff, kpd, kid, kdd, gamma, limit, aw)
    return float(u[0]), float(p[0]), float(i[0]), float(d[0]), bool(sat[0])


def _pid_controller(e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, limit, aw):
    """The stateful controller with its state set to (e_prev, i_prev, d_prev).

    Position loop with r = e and y = 0, so the error is e; the feedforward (τ a + ω)/K with
    K = 1, τ = 0 is the reference velocity, so ``ff`` enters as ω.
    """
    c = DigitalController(
        DiscreteGains(kpd, kid, kdd, 0.005, gamma=gamma),
        Feedforward(1.0, 0.0) if ff != 0.0 else None,
        output_limit=None if math.isinf(limit) else limit,
        anti_windup=aw,
    )
    c._e, c._i, c._d, c._first = e_prev, i_prev, d_prev, False
    u = c.step(e, ff, 0.0, 0.0)
    pt = c.last_parts
    return u, pt["p"], pt["i"], pt["d"], pt["saturated"]


PID_FORMS = {
    "scalar": _pid_scalar,
    "compiled": _pid_compiled,
    "vector": _pid_vector,
    "controller": _pid_controller,
}


@pytest.fixture(params=list(PID_FORMS))
def pid(request):
    if request.param == "compiled" and not law.HAVE_NUMBA:
        pytest.skip("numba not installed: the compiled form is the scalar form")
    return PID_FORMS[request.param]


# kpd = 1, kid = 0.5, kdd = 0, gamma = 0, limit = 1 unless said otherwise
G = dict(kpd=1.0, kid=0.5, kdd=0.0, gamma=0.0, limit=1.0)


def _call(pid, e, i_prev, ff=0.0, aw=True, e_prev=0.0, d_prev=0.0, **kw):
    g = dict(G, **kw)
    return pid(
        e, e_prev, i_prev, d_prev, ff, g["kpd"], g["kid"], g["kdd"], g["gamma"], g["limit"], aw
    )


# --------------------------------------------------------------------------- PID, eq. 17/18


def test_linear_region_is_eq17_eq18(pid):
    # p = 1·0.2, i = 0.1 + 0.5·0.2 = 0.2, d = 0, u = 0.4: inside ±1, not saturated
    u, p, i, d, sat = _call(pid, 0.2, 0.1)
    assert (u, p, i, d, sat) == pytest.approx((0.4, 0.2, 0.2, 0.0, False), abs=1e-15)


def test_derivative_with_filter(pid):
    # d = γ d(k−1) + kdd (e − e(k−1)) = 0.5·0.2 + 2·(0.1 − 0.3) = −0.3; u = 0.1 + 0.05 − 0.3
    u, p, i, d, sat = _call(pid, 0.1, 0.0, e_prev=0.3, d_prev=0.2, kdd=2.0, gamma=0.5)
    assert d == pytest.approx(-0.3, abs=1e-15)
    assert u == pytest.approx(0.1 + 0.05 - 0.3, abs=1e-15) and not sat


def test_positive_clamp_error_into_saturation_freezes_integrator(pid):
    # unclamped u = 2 + (0.3 + 1) = 3.3 > 1 and e > 0 pushes further up: i keeps 0.3, u = +1
    u, p, i, d, sat = _call(pid, 2.0, 0.3)
    assert sat and u == 1.0 and i == pytest.approx(0.3, abs=1e-15)


def test_positive_clamp_without_anti_windup_integrates(pid):
    u, p, i, d, sat = _call(pid, 2.0, 0.3, aw=False)
    assert sat and u == 1.0 and i == pytest.approx(1.3, abs=1e-15)


def test_positive_clamp_error_out_of_saturation_integrates(pid):
    # feedforward 3 V holds the output above +1 while e = −0.2 pulls it back: the integrator
    # must integrate (0.5 − 0.1 = 0.4), or it would stay wound up
    u, p, i, d, sat = _call(pid, -0.2, 0.5, ff=3.0)
    assert sat and u == 1.0 and i == pytest.approx(0.4, abs=1e-15)


def test_negative_clamp_error_into_saturation_freezes_integrator(pid):
    # mirror image: unclamped u = −2 − 1.3 = −3.3 < −1 and e < 0: i keeps −0.3, u = −1
    u, p, i, d, sat = _call(pid, -2.0, -0.3)
    assert sat and u == -1.0 and i == pytest.approx(-0.3, abs=1e-15)


def test_negative_clamp_without_anti_windup_integrates(pid):
    u, p, i, d, sat = _call(pid, -2.0, -0.3, aw=False)
    assert sat and u == -1.0 and i == pytest.approx(-1.3, abs=1e-15)


def test_negative_clamp_error_out_of_saturation_integrates(pid):
    u, p, i, d, sat = _call(pid, 0.2, -0.5, ff=-3.0)
    assert sat and u == -1.0 and i == pytest.approx(-0.4, abs=1e-15)


def test_output_never_leaves_the_limits(pid):
    # the frozen increment (kid e = 5) is larger than the whole range: without the
    # increment the output is −2, past the other limit; it is still clamped to −1
    u, p, i, d, sat = _call(pid, 1.0, 0.0, ff=-3.0, kid=5.0, kpd=0.0)
    assert sat and u == -1.0 and i == 0.0


def test_no_limit(pid):
    u, p, i, d, sat = _call(pid, 50.0, 0.0, limit=math.inf)
    assert u == pytest.approx(50.0 + 25.0) and not sat


def test_random_cases_follow_the_rule(pid):
    """Many random states against the rule written as branches on the unclamped output."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        e, ep, ip, dp, ff = rng.normal(0, 2, 5)
        kpd, kid, kdd = rng.uniform(-1, 3, 3)
        gamma = rng.uniform(-0.9, 0.9)
        lim = rng.uniform(0.1, 3)
        aw = bool(rng.integers(0, 2))
        p = kpd * e
        d = gamma * dp + kdd * (e - ep)
        raw = ff + p + (ip + kid * e) + d
        if raw > lim:
            sat, freeze = True, aw and e > 0
        elif raw < -lim:
            sat, freeze = True, aw and e < 0
        else:
            sat, freeze = False, False
        i = ip if freeze else ip + kid * e
        u = min(max(ff + p + i + d, -lim), lim)
        got = pid(e, ep, ip, dp, ff, kpd, kid, kdd, gamma, lim, aw)
        assert got[4] == sat
        assert got[0] == pytest.approx(u, abs=1e-12) and got[2] == pytest.approx(i, abs=1e-12)
        assert -lim <= got[0] <= lim


def test_controller_winds_down_from_both_limits():
    """A run into each limit and back: the integrator holds while pushing, follows when pulled."""
    c = DigitalController(DiscreteGains(1.0, 0.5, 0.0, 0.005), None, output_limit=1.0)
    # e = +2: saturated high, integrator frozen at 0 for as long as e pushes up
    for _ in range(5):
        assert c.step(2.0, measured_position=0.0) == 1.0
        assert c.last_parts["i"] == 0.0 and c.last_parts["saturated"]
    # e = +0.2: 0.2 + 0.1 = 0.3 inside the range, integrating again (0.1, 0.2, ...)
    assert c.step(0.2, measured_position=0.0) == pytest.approx(0.3)
    # e = −2: saturated low, integrator frozen at 0.1
    for _ in range(5):
        assert c.step(-2.0, measured_position=0.0) == -1.0
        assert c.last_parts["i"] == pytest.approx(0.1) and c.last_parts["saturated"]
    assert c.step(-0.2, measured_position=0.0) == pytest.approx(-0.2 + 0.0)  # i = 0.1 − 0.1


# --------------------------------------------------------------------------- PWM


def _lround_spec(u, supply, levels):
    """The firmware's duty: lround(u/supply·levels), half away from zero, clamped to ±levels."""
    q = Fraction(u) / Fraction(supply) * levels
    n = math.floor(abs(q) + Fraction(1, 2))
    n = min(n, levels)
    return -n if q < 0 else n


def _duty_scalar(u, s, L):
    return law.SCALAR["pwm_duty"](u, s, L, L)


def _duty_compiled(u, s, L):
    return law.pwm_duty(u, s, L, L)


def _duty_amplifier(u, s, L):
    return law.amplifier(u, s, L)[0] / s * L


def _duty_vector(u, s, L):
    return float(law.amplifier_vec(np.array([u]), s, L)[0][0]) / s * L


def _duty_plant(u, s, L):
    bits = int(round(math.log2(L + 1)))
    return float(quantize_voltage(u, s, bits)) / s * L


DUTY_FORMS = {
    "scalar": _duty_scalar,
    "compiled": _duty_compiled,
    "amplifier": _duty_amplifier,
    "vector": _duty_vector,
    "plant.quantize_voltage": _duty_plant,
}


@pytest.fixture(params=list(DUTY_FORMS))
def duty(request):
    if request.param == "compiled" and not law.HAVE_NUMBA:
        pytest.skip("numba not installed")
    return DUTY_FORMS[request.param]


@pytest.mark.parametrize(
    "u, supply, levels, want",
    [
        (1.0, 2.0, 7, 4),  # q = 3.5: half away → 4 (truncation and banker's both give 3)
        (-1.0, 2.0, 7, -4),  # q = −3.5 → −4 (the sign is the direction pin)
        (0.5, 1.0, 1023, 512),  # q = 511.5 → 512
        (-0.5, 1.0, 1023, -512),
        (0.25, 1.0, 3, 1),  # q = 0.75 → 1 (truncation: 0)
        (-0.25, 1.0, 3, -1),
        (0.1, 1.0, 3, 0),  # q = 0.3 → 0
        (12.0, 12.0, 1023, 1023),  # full scale
        (-12.0, 12.0, 1023, -1023),
        (30.0, 12.0, 1023, 1023),  # beyond the supply: clamped
        (-30.0, 12.0, 1023, -1023),
    ],
)
def test_pwm_rounds_half_away_from_zero(duty, u, supply, levels, want):
    if duty is _duty_plant and levels not in (1, 3, 7, 1023):
        pytest.skip("plant.quantize_voltage takes bits")
    assert _lround_spec(u, supply, levels) == want  # the spec itself
    assert duty(u, supply, levels) == pytest.approx(want, abs=1e-9)


def test_pwm_random_against_spec(duty):
    rng = np.random.default_rng(3)
    for u in rng.uniform(-15, 15, 400):
        want = _lround_spec(float(u), 12.0, 1023)
        frac = abs(float(Fraction(float(u)) / 12 * 1023)) % 1.0
        if abs(frac - 0.5) < 1e-9:
            continue  # a float-level tie: the spec is exact, the code is float
        assert duty(float(u), 12.0, 1023) == pytest.approx(want, abs=1e-9)


def test_pwm_top_below_full_scale():
    for f in (law.SCALAR["pwm_duty"], law.pwm_duty):
        assert f(11.9, 12.0, 1023.0, 512.0) == 512.0 and f(-11.9, 12.0, 1023.0, 512.0) == -512.0


def test_amplifier_reports_the_supply_clamp():
    for f in (law.SCALAR["amplifier"], law.amplifier):
        assert f(12.5, 12.0, 1023.0) == (12.0, True)
        assert f(-12.5, 12.0, 1023.0) == (-12.0, True)
        assert f(3.0, 12.0, 1023.0)[1] is False
        assert f(3.3, 0.0, 0.0) == (3.3, False)  # no amplifier
    v, c = law.amplifier_vec(np.array([12.5, -12.5, 3.0]), 12.0, 1023.0)
    assert list(c) == [True, True, False] and list(v[:2]) == [12.0, -12.0]


# --------------------------------------------------------------------------- encoder

CPR = 448 / (2 * math.pi)


def _counts_scalar(th, cpr):
    return law.SCALAR["encoder_counts"](th, cpr)


def _counts_compiled(th, cpr):
    return law.encoder_counts(th, cpr)


def _counts_angle(th, cpr):
    return round(law.encoder(th, cpr) * cpr)


def _counts_vector(th, cpr):
    return round(float(law.encoder_vec(np.array([th]), cpr)[0]) * cpr)


def _counts_plant(th, cpr):
    return round(float(measure_angle(th, cpr)) * cpr)


COUNT_FORMS = {
    "scalar": _counts_scalar,
    "compiled": _counts_compiled,
    "angle": _counts_angle,
    "vector": _counts_vector,
    "plant.measure_angle": _counts_plant,
}


@pytest.fixture(params=list(COUNT_FORMS))
def counts(request):
    if request.param == "compiled" and not law.HAVE_NUMBA:
        pytest.skip("numba not installed")
    return COUNT_FORMS[request.param]


@pytest.mark.parametrize(
    "fraction, want",
    [
        (0.3, 0),  # floor 0, round 0
        (0.7, 0),  # floor 0 (round would give 1)
        (-0.3, -1),  # floor −1 (round and truncation give 0)
        (-0.7, -1),
        (-1.2, -2),  # floor −2 (truncation −1)
        (5.5, 5),
        (-5.5, -6),  # floor −6 (round half away −6, truncation −5)
    ],
)
def test_encoder_is_floor_not_round_or_truncation(counts, fraction, want):
    assert math.floor(fraction) == want  # the spec
    assert counts(fraction / CPR, CPR) == want


def test_encoder_exact_counts_read_exactly(counts):
    for k in range(-300, 301, 7):
        assert counts(k / CPR, CPR) == k


def test_ideal_sensor_passes_the_angle():
    assert law.encoder(-0.123, 0.0) == -0.123 and law.SCALAR["encoder"](0.5, 0.0) == 0.5
    assert law.encoder_vec(np.array([-0.123]), 0.0)[0] == -0.123


# --------------------------------------------------------------------------- ZOH of eq. 1


def test_zoh_coefficients_against_python_control():
    import control as ct

    K, tau, Ts = 32.4, 0.025, 0.005
    z = law.zoh_coefficients(K, tau, Ts)
    d = ct.c2d(ct.tf([K], [tau, 1.0, 0.0]), Ts, "zoh")
    num, den = np.ravel(d.num[0][0]), np.ravel(d.den[0][0])
    num = num / den[0]
    den = den / den[0]
    np.testing.assert_allclose(num[-2:], [z.b1, z.b0], rtol=1e-9)
    np.testing.assert_allclose(den, [1.0, -1.0 - z.a, z.a], rtol=1e-12)
    assert z.a + z.one_minus_a == pytest.approx(1.0, abs=1e-16)


@pytest.mark.parametrize(
    "kw, name",
    [
        (dict(K=float("nan")), "K"),
        (dict(tau=0.0), "tau"),
        (dict(Ts=-1.0), "Ts"),
        (dict(tau="x"), "tau"),
    ],
)
def test_zoh_bad_input(kw, name):
    args = {**dict(K=32.4, tau=0.025, Ts=0.005), **kw}
    with pytest.raises(ValueError, match=name):
        law.zoh_coefficients(**args)


def test_pack_layout():
    p = law.pack(
        kpd=1.0,
        kid=2.0,
        kdd=3.0,
        gamma=0.1,
        limit=math.inf,
        anti_windup=True,
        ff_on=False,
        ff_K=1.0,
        ff_tau=0.0,
        velocity=True,
        error_scale=2.0,
        bumpless=False,
        Ts=0.005,
    )
    assert len(p) == len(law.CTL_FIELDS)
    assert (
        p[law.C_KID] == 2.0
        and p[law.C_AW] == 1.0
        and p[law.C_VELOCITY] == 1.0
        and p[law.C_TS] == 0.005
    )
    assert math.isinf(p[law.C_LIMIT]) and p[law.C_FF_ON] == 0.0 and p[law.C_SCALE] == 2.0


def test_encoder_and_pwm_beyond_int64_and_nan():
    """A diverging run can reach angles beyond 2**63 counts: the floor stays a float (no int wrap)."""
    forms = [law.SCALAR["encoder"]] + ([law.encoder] if law.HAVE_NUMBA else [])
    for f in forms:
        assert f(1e25, CPR) == pytest.approx(1e25, rel=1e-12)
        assert f(-1e25, CPR) == pytest.approx(-1e25, rel=1e-12)
        assert math.isnan(f(math.nan, CPR))
    for f in [law.SCALAR["amplifier"]] + ([law.amplifier] if law.HAVE_NUMBA else []):
        assert f(1e300, 12.0, 1023.0) == (12.0, True)
