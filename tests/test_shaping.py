"""Input shapers, profiles as shapers, robust LP moves, the shaper for a mode (jerklab.shaping).

Independent references: the closed forms of Singer & Seering (ZV, ZVD) and of Singhose
(undamped EI, 2-hump and 3-hump EI) written out here; the published insensitivity widths
(Klipper's docs/Resonance_Compensation.md table, Singhose's papers); numerical integration of a
second-order mode (scipy solve_ivp) for the residual vibration of shapers and profiles; a
continuous-time convolution for ``apply``; the plant simulation (``FlexibleDCMotor.open_loop``)
for the LP moves; a simulated encoder record for the shaper ``identify_mode`` recommends.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.optimize import linprog

from jerklab import planner
from jerklab.ident import ModeEstimate
from jerklab.ident import identify_mode as identify_mode_estimate
from jerklab.plant import FlexibleDCMotor
from jerklab.shaping import (
    KINDS,
    InputShaper,
    ModeFit,
    chirp_input,
    energy_optimal_move,
    flexible_mode,
    identify_mode,
    input_shaper,
    insensitivity_table,
    move_time_comparison,
    profile_residual_vibration,
    residual_amplitude,
    residual_vibration_of,
    robust_move,
    robust_move_rows,
    tradeoff,
    tuned_profile,
)


# ----------------------------------------------------------------------------------------------
# a second-order mode integrated numerically: the residual amplitude after a command
# ----------------------------------------------------------------------------------------------
def _mode_residual(x_of_t, T, f, zeta, D, t_breaks=()):
    """Residual vibration (%) of y'' + 2ζω y' + ω² y = ω² x(t) after T, relative to a step of D at T.

    The free oscillation after T has the amplitude sqrt(e² + ((ė + ζω e)/ω_d)²) at T, e = y − D;
    a step of D at T leaves D/√(1−ζ²).
    """
    w = 2 * math.pi * f
    wd = w * math.sqrt(1 - zeta**2)

    def rhs(t, s):
        return [s[1], w * w * (x_of_t(t) - s[0]) - 2 * zeta * w * s[1]]

    edges = sorted({0.0, *[b for b in t_breaks if 0 < b < T], T})
    s = [0.0, 0.0]
    for a, b in zip(edges[:-1], edges[1:]):
        sol = solve_ivp(
            rhs,
            (a, b),
            s,
            method="DOP853",
            rtol=1e-11,
            atol=1e-13 * max(1.0, D),
            max_step=(b - a) / 20 or None,
        )
        s = sol.y[:, -1]
    e, ed = s[0] - D, s[1]
    amp = math.hypot(e, (ed + zeta * w * e) / wd)
    return 100 * amp / (D / math.sqrt(1 - zeta**2))


# ----------------------------------------------------------------------------------------------
# closed forms
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("zeta", [0.0, 0.02, 0.1, 0.3])
@pytest.mark.parametrize("f", [1.0, 8.0, 42.5])
def test_zv_zvd_closed_forms(f, zeta):
    K = math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    Td = 1 / (f * math.sqrt(1 - zeta**2))
    zv = input_shaper("zv", f, zeta)
    np.testing.assert_allclose(zv.amplitudes, [1 / (1 + K), K / (1 + K)], rtol=1e-13)
    np.testing.assert_allclose(zv.times, [0, Td / 2], rtol=1e-13)
    zvd = input_shaper("ZVD", f, zeta)
    np.testing.assert_allclose(
        zvd.amplitudes, np.array([1, 2 * K, K * K]) / (1 + K) ** 2, rtol=1e-13
    )
    np.testing.assert_allclose(zvd.times, [0, Td / 2, Td], rtol=1e-13)
    for s in (zv, zvd, input_shaper("zvdd", f, zeta), input_shaper("mzv", f, zeta)):
        assert s.residual_vibration(f) < 1e-10
        assert s.amplitudes.sum() == pytest.approx(1.0, abs=1e-14)
        assert s.times[0] == 0.0 and s.duration == s.times[-1]


@pytest.mark.parametrize("zeta", [0.0, 0.1])
def test_mzv_closed_form(zeta):
    """MZV: impulses at 0, 3T_d/8, 3T_d/4 with amplitudes ∝ [1, √2 K', K'²], K' = e^{−3ζπ/(4√(1−ζ²))}
    (the z-polynomial 1 + √2 q + q² has its roots at e^{±j3π/4}: the mode; Klipper's mzv)."""
    f = 12.0
    df = math.sqrt(1 - zeta**2)
    Kp = math.exp(-0.75 * zeta * math.pi / df)
    A = np.array([1, math.sqrt(2) * Kp, Kp * Kp])
    s = input_shaper("mzv", f, zeta)
    np.testing.assert_allclose(s.amplitudes, A / A.sum(), rtol=1e-13)
    np.testing.assert_allclose(s.times, np.array([0, 0.375, 0.75]) / (f * df), rtol=1e-13)
    assert s.duration == pytest.approx(0.75 / (f * df))


@pytest.mark.parametrize("kind", ["zv", "zvd", "mzv", "ei", "2hump_ei"])
@pytest.mark.parametrize("zeta", [0.0, 0.05])
def test_residual_against_integrated_mode(kind, zeta):
    """The formula against a numerically integrated second-order mode driven by the shaped step,
    at the design frequency and 10 % off it."""
    f = 2.0
    s = input_shaper(kind, f, zeta)
    D = 1.5
    for r in (1.0, 1.1):

        def x(t):
            return D * float(np.sum(s.amplitudes[s.times <= t + 1e-15]))

        got = _mode_residual(x, s.duration, f * r, zeta, D, t_breaks=s.times)
        assert got == pytest.approx(s.residual_vibration(f * r), abs=2e-6)


def test_singhose_undamped_ei_family():
    """ζ = 0: the undamped EI, 2-hump and 3-hump closed forms (Singhose et al.), V = 5 %."""
    V = 0.05
    ei = input_shaper("ei", 1.0, 0.0)
    np.testing.assert_allclose(ei.amplitudes, [(1 + V) / 4, (1 - V) / 2, (1 + V) / 4], rtol=1e-12)
    np.testing.assert_allclose(ei.times, [0, 0.5, 1.0], rtol=1e-12)
    X = (V * V * (math.sqrt(1 - V * V) + 1)) ** (1 / 3)
    a1 = (3 * X * X + 2 * X + 3 * V * V) / (16 * X)
    np.testing.assert_allclose(
        input_shaper("2-hump EI", 1.0).amplitudes, [a1, 0.5 - a1, 0.5 - a1, a1], rtol=1e-12
    )
    b1 = (1 + 3 * V + 2 * math.sqrt(2 * V * (V + 1))) / 16
    b2 = (1 - V) / 4
    np.testing.assert_allclose(
        input_shaper("3hump_ei", 1.0).amplitudes, [b1, b2, 1 - 2 * (b1 + b2), b2, b1], rtol=1e-12
    )
    # the humps of the undamped EI family are exactly V high
    for kind, humps in (("ei", 1), ("2hump_ei", 2), ("3hump_ei", 3)):
        s = input_shaper(kind, 1.0)
        r = np.linspace(0.4, 1.6, 24001)
        v = s.sensitivity_curve(r)
        inner = (r > 0.5) & (r < 1.5)
        peaks = [
            i for i in np.flatnonzero(inner) if v[i] >= v[i - 1] and v[i] >= v[i + 1] and v[i] > 1
        ]
        assert len(peaks) == humps
        np.testing.assert_allclose(v[peaks], 5.0, atol=1e-3)


@pytest.mark.parametrize("kind", ["ei", "2hump_ei", "3hump_ei"])
@pytest.mark.parametrize("zeta", [0.03, 0.1])
def test_damped_ei_conditions(kind, zeta):
    """ζ > 0: humps of 5 % with zero slope, m + 1 zeros, positive amplitudes."""
    s = input_shaper(kind, 5.0, zeta)
    m = {"ei": 1, "2hump_ei": 2, "3hump_ei": 3}[kind]
    assert len(s.amplitudes) == m + 2 and np.all(s.amplitudes > 0)
    r = np.linspace(0.4, 1.7, 26001)
    v = s.sensitivity_curve(r)
    mins = [i for i in range(1, r.size - 1) if v[i] <= v[i - 1] and v[i] < v[i + 1] and v[i] < 1e-2]
    maxs = [
        i
        for i in range(1, r.size - 1)
        if v[i] >= v[i - 1] and v[i] > v[i + 1] and r[mins[0]] < r[i] < r[mins[-1]]
    ]
    assert len(mins) >= m + 1 and len(maxs) == m
    np.testing.assert_allclose(v[maxs], 5.0, atol=2e-3)
    if m % 2:
        assert s.residual_vibration(5.0) == pytest.approx(
            5.0, abs=1e-6
        )  # the middle hump at the design
    else:
        assert s.residual_vibration(5.0) < 1e-6  # the middle zero at the design


@pytest.mark.parametrize("kind", ["ei", "2hump_ei", "3hump_ei"])
def test_ei_family_over_its_damping_range(kind):
    """Designable at every damping up to Klipper's limit (continuation in ζ), refused above it."""
    from jerklab.shaping import EI_MAX_DAMPING

    zmax = EI_MAX_DAMPING[kind]
    for z in np.linspace(0.0, zmax, 9)[1:]:
        s = input_shaper(kind, 3.0, float(z) - 0.003)  # off the cached grid points
        lo, hi = s.insensitivity(5.0)
        assert lo < 1 < hi and np.all(s.amplitudes > 0)
    with pytest.raises(ValueError, match="damping"):
        input_shaper(kind, 3.0, zmax + 0.01)


def test_klipper_ei_amplitudes_close():
    """Klipper's EI (Singhose's curve fit, v_tol = 5 %) at ζ = 0.1: our numerically designed EI
    should be near its published first amplitude 0.2497 + 0.2496 v + (0.8001 + 1.2333 v) ζ + ... ≈ 0.355."""
    s = input_shaper("ei", 1.0, 0.1)
    v, z = 0.05, 0.1
    a1 = (0.24968 + 0.24961 * v) + ((0.80008 + 1.23328 * v) + (0.49599 + 3.17316 * v) * z) * z
    assert s.amplitudes[0] == pytest.approx(a1, abs=0.01)


# ----------------------------------------------------------------------------------------------
# insensitivity: the published widths
# ----------------------------------------------------------------------------------------------
#: Klipper, docs/Resonance_Compensation.md ("vibration reduction 20x / 10x"): (low %, high %)
PUBLISHED = {
    "zv": {10.0: (-5, 5)},
    "mzv": {5.0: (-4, 4)},
    "zvd": {5.0: (-15, 15), 10.0: (-22, 22)},
    "ei": {5.0: (-20, 20), 10.0: (-25, 25)},
    "2hump_ei": {5.0: (-35, 35), 10.0: (-40, 40)},
    "3hump_ei": {5.0: (-45, 50), 10.0: (-50, 55)},
}


@pytest.mark.parametrize("kind", list(PUBLISHED))
def test_published_insensitivity_widths(kind):
    """The widths at ζ = 0 (Singhose's undamped analysis, which Klipper's table rounds) within
    3.5 percentage points on each side."""
    tab = insensitivity_table(tolerances=tuple(PUBLISHED[kind]), damping=0.0, kinds=(kind,))[kind]
    for tol, (lo, hi) in PUBLISHED[kind].items():
        glo, ghi = tab[tol]
        assert 100 * (glo - 1) == pytest.approx(lo, abs=3.5), (kind, tol)
        assert 100 * (ghi - 1) == pytest.approx(hi, abs=3.5), (kind, tol)


def test_klipper_asymmetric_bands_at_light_damping():
    """At ζ = 0.05 (inside the 0.05–0.2 range Klipper's widths cover) the asymmetric MZV 10 %
    band −10…+15 % and ZVD ±15/±22 % are met within 1.5 points."""
    mzv = input_shaper("mzv", 1.0, 0.05).insensitivity(10.0)
    assert 100 * (mzv[0] - 1) == pytest.approx(-10, abs=1.5)
    assert 100 * (mzv[1] - 1) == pytest.approx(15, abs=1.5)
    zvd = input_shaper("zvd", 1.0, 0.05)
    for tol, w in ((5.0, 15), (10.0, 22)):
        lo, hi = zvd.insensitivity(tol)
        assert 100 * (1 - lo) == pytest.approx(w, abs=1.5)
        assert 100 * (hi - 1) == pytest.approx(w, abs=1.5)


def test_klipper_reading_worst_case_over_damping():
    """Klipper: shapers designed at ζ = 0.1, widths meant to hold for ζ ≈ 0.05–0.2. The worst case
    over that range gives its ZVD row (±15 %, ±22 %) and its MZV 10 % band (−10…+15 %) within 2 points."""
    zs = np.linspace(0.05, 0.2, 7)
    zvd = input_shaper("zvd", 1.0, 0.1)
    for tol, w in ((5.0, 15), (10.0, 22)):
        lo, hi = zvd.insensitivity(tol, damping=zs)
        assert 100 * (1 - lo) == pytest.approx(w, abs=1.0) and 100 * (hi - 1) == pytest.approx(
            w, abs=1.0
        )
    lo, hi = input_shaper("mzv", 1.0, 0.1).insensitivity(10.0, damping=zs)
    assert 100 * (lo - 1) == pytest.approx(-10, abs=2.0) and 100 * (hi - 1) == pytest.approx(
        15, abs=2.0
    )
    # the worst case is never better than any single damping of the range
    r = np.linspace(0.5, 1.5, 101)
    worst = zvd.sensitivity_curve(r, damping=zs)
    for z in zs:
        assert np.all(worst >= zvd.sensitivity_curve(r, damping=z) - 1e-12)


def test_insensitivity_units_and_edges():
    s = input_shaper("zvd", 20.0, 0.0)
    lo, hi = s.insensitivity(5.0)
    lo_hz, hi_hz = s.insensitivity(5.0, hz=True)
    assert (lo_hz, hi_hz) == pytest.approx((20 * lo, 20 * hi))
    # the edges are where the curve crosses the tolerance
    assert s.residual_vibration(lo_hz) == pytest.approx(5.0, abs=1e-6)
    assert s.residual_vibration(hi_hz) == pytest.approx(5.0, abs=1e-6)
    assert s.residual_vibration(0.5 * (lo_hz + hi_hz)) < 5.0


# ----------------------------------------------------------------------------------------------
# digitization and apply()
# ----------------------------------------------------------------------------------------------
def test_fir_split_preserves_area_and_delay():
    s = input_shaper("ei", 7.3, 0.04)
    for Ts in (0.001, 0.005, 0.013):
        h = s.fir(Ts)
        assert h.sum() == pytest.approx(1.0, abs=1e-14)
        assert np.all(h >= 0)
        assert (np.arange(h.size) * h).sum() * Ts == pytest.approx(
            (s.amplitudes * s.times).sum(), rel=1e-12
        )


def test_fir_on_grid_is_exact_and_off_grid_is_reported():
    s = input_shaper("zv", 10.0, 0.0)  # impulses at 0 and 50 ms
    h = s.fir(0.005)
    np.testing.assert_allclose(h[[0, 10]], [0.5, 0.5])
    assert s.digitized(0.005).residual_vibration(10.0) < 1e-10
    off = s.digitized(0.007)  # 50 ms = 7.14 samples: split 0.86/0.14
    assert 0 < off.residual_vibration(10.0) < 5.0
    assert off.kind == "fir"


def test_apply_equals_continuous_convolution_for_piecewise_linear_reference():
    """For a reference linear between its samples, delaying by linear interpolation is exact: the
    result equals Σ A_i r(t − t_i) of the continuous reference."""
    rng = np.random.default_rng(3)
    Ts = 0.004
    r = np.cumsum(rng.normal(size=300))
    t = np.arange(r.size) * Ts
    for kind in KINDS:
        s = input_shaper(kind, 9.1, 0.03)
        y = s.apply(r, Ts)
        tk = np.arange(y.size) * Ts
        cont = sum(
            A * np.interp(tk - ti, t, r, left=r[0], right=r[-1])
            for A, ti in zip(s.amplitudes, s.times)
        )
        np.testing.assert_allclose(y, cont, atol=1e-12)


def test_apply_smooth_reference_close_to_continuous():
    p = planner.plan_sine_jerk(1.0, 2e4, 300.0, 100.0)
    Ts = 0.005
    t = np.arange(0, p.duration + Ts, Ts)
    r = p.sample(t).position
    s = input_shaper("zvd", 8.0, 0.02)
    y = s.apply(r, Ts)
    tk = np.arange(y.size) * Ts
    cont = sum(A * p.sample(tk - ti).position for A, ti in zip(s.amplitudes, s.times))
    assert np.abs(y - cont).max() < 5e-4  # O(Ts²) interpolation error
    assert y[-1] == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------------
# hypothesis: apply() and residual properties
# ----------------------------------------------------------------------------------------------
kinds = st.sampled_from(KINDS)
dampings = st.sampled_from([0.0, 0.01, 0.05, 0.1, 0.2])
freqs = st.floats(0.5, 40.0)
sample_times = st.floats(1e-4, 0.02)


@settings(max_examples=150, deadline=None)
@given(
    kind=kinds,
    f=freqs,
    zeta=dampings,
    Ts=sample_times,
    ref=st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=1, max_size=60),
)
def test_apply_properties(kind, f, zeta, Ts, ref):
    s = input_shaper(kind, f, zeta)
    r = np.array(ref)
    y = s.apply(r, Ts)
    n = s.fir(Ts).size - 1
    assert y.size == r.size + n
    assert y[-1] == pytest.approx(r[-1], abs=1e-9 * (1 + np.abs(r).max()))
    assert y[0] == pytest.approx(r[0], abs=1e-9 * (1 + np.abs(r).max()))
    # positive taps: the shaped reference stays within the reference's range, a constant stays put
    assert y.min() >= r.min() - 1e-9 * (1 + np.abs(r).max())
    assert y.max() <= r.max() + 1e-9 * (1 + np.abs(r).max())
    np.testing.assert_allclose(s.apply(np.full(5, 2.5), Ts), 2.5)
    # linear
    np.testing.assert_allclose(s.apply(2 * r + 1, Ts), 2 * y + 1, atol=1e-9 * (1 + np.abs(r).max()))
    assert s.apply(r, Ts, extend=False).size == r.size


@settings(max_examples=150, deadline=None)
@given(kind=kinds, f=freqs, zeta=dampings, ratio=st.floats(0.1, 4.0), zp=dampings)
def test_residual_properties(kind, f, zeta, ratio, zp):
    s = input_shaper(kind, f, zeta)
    v = s.residual_vibration(f * ratio, zp)
    assert 0.0 <= v <= 100.0 + 1e-9  # positive impulses never beat a step
    if kind in ("zv", "zvd", "zvdd", "mzv"):
        assert s.residual_vibration(f) < 1e-8
    # scaling the time axis: a shaper for f at ratio r is the shaper for 2f at ratio r
    s2 = input_shaper(kind, 2 * f, zeta)
    assert s2.residual_vibration(2 * f * ratio, zp) == pytest.approx(v, abs=1e-7)
    np.testing.assert_allclose(
        residual_vibration_of(3 * s.amplitudes, s.times, f * ratio, zp), v, atol=1e-9
    )


# ----------------------------------------------------------------------------------------------
# profiles as shapers: closed form against the integrated mode
# ----------------------------------------------------------------------------------------------
PROFILES = {
    "trapezoid": lambda: planner.plan_trapezoid(0.8, 300.0, 40.0),
    "scurve": lambda: planner.plan_scurve(0.8, 6000.0, 300.0, 40.0),
    "sine_jerk": lambda: planner.plan_sine_jerk(0.8, 2e4, 300.0, 40.0),
    "sine_jerk_optimal": lambda: planner.plan_sine_jerk_optimal(0.8, 6000.0, 300.0, 40.0),
}


@pytest.mark.parametrize("kind", list(PROFILES))
@pytest.mark.parametrize("f,zeta", [(3.0, 0.0), (8.0, 0.03), (17.0, 0.1)])
def test_profile_spectrum_against_mass_spring(kind, f, zeta):
    p = PROFILES[kind]()
    T = p.duration
    breaks = np.cumsum(p.phase_times)
    got = _mode_residual(
        lambda t: float(p.sample(t).position), T, f, zeta, p.distance, t_breaks=breaks
    )
    assert profile_residual_vibration(p, f, zeta) == pytest.approx(got, rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("kind", ["trapezoid", "scurve", "sine_jerk", "sine_jerk_optimal"])
@pytest.mark.parametrize("distance", [0.3, 2.0, 30.0])
def test_tuned_profile_puts_a_zero_on_the_mode(kind, distance):
    f = 8.0
    p = tuned_profile(kind, distance, f, 300.0, 100.0)
    assert profile_residual_vibration(p, f) < 1e-7
    assert p.peak_accel <= 300.0 * (1 + 1e-9) and p.peak_velocity <= 100.0 * (1 + 1e-9)
    assert p.sample(p.duration).position == pytest.approx(distance)
    base = planner.plan_trapezoid(distance, 300.0, 100.0)
    assert p.duration >= base.duration - 1e-12


def test_move_time_comparison_both_ways():
    """A long move: rounding the trapezoid's own timing to the mode period costs less than ZV's
    half period; a short fast move: the S-curve's jerk time 1/f costs more than ZVD's 1/f delay."""
    long_ = move_time_comparison(30.0, 8.0, 300.0, 100.0)
    assert long_["tuned trapezoid"]["penalty"] < long_["trapezoid + ZV"]["penalty"]
    short = move_time_comparison(0.5, 8.0, 300.0, 100.0)
    assert short["tuned scurve"]["penalty"] > short["trapezoid + ZVD"]["penalty"]
    for row in list(long_.values()) + list(short.values()):
        assert row["penalty"] >= -1e-12


# ----------------------------------------------------------------------------------------------
# robust time-optimal LP on the flexible motor
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def flex():
    return FlexibleDCMotor().ideal()


@pytest.mark.parametrize("order", [0, 1, 2])
def test_robust_move_ends_at_rest(flex, order):
    d, Ts = 1.0, 0.005
    m = robust_move(d, flex, Ts, order=order)
    assert np.abs(m.u).max() <= 12.0 + 1e-7
    u = np.r_[m.u, np.zeros(400)]
    th_m, _ = flex.open_loop(u, Ts)
    th_l, _ = flex.open_loop(u, Ts, output="load")
    n = m.u.size
    np.testing.assert_allclose(th_m[n:], d, atol=1e-7)
    np.testing.assert_allclose(th_l[n:], d, atol=1e-7)
    assert m.residual_vibration(m.mode_hz) < 1e-8


def test_robust_move_is_time_optimal(flex):
    """One sample fewer is infeasible (HiGHS, independently of the bisection's screen)."""
    d, Ts = 1.0, 0.005
    for order in (0, 1, 2):
        m = robust_move(d, flex, Ts, order=order)
        N = m.u.size - 1
        E, f = robust_move_rows(N, flex, Ts, d, order)
        res = linprog(np.zeros(N), A_eq=E, b_eq=f, bounds=[(-12, 12)] * N, method="highs")
        assert res.status == 2
        assert robust_move(d, flex, Ts, order=order, solver="highs").u.size == m.u.size


def test_robust_order_flattens_the_curve(flex):
    """Order m: V(1 + h) ~ h^(m+1) near the mode."""
    for order in (0, 1, 2):
        m = robust_move(1.0, flex, 0.005, order=order)
        v1, v2 = m.sensitivity_curve(np.array([1.004, 1.008]))
        assert math.log2(v2 / v1) == pytest.approx(order + 1, abs=0.15)


def test_robust_residual_on_the_perturbed_plant(flex):
    """The density measure against the plant: with the shaft 10 % stiffer the order-2 command
    leaves much less load ringing than order 0 (simulated FlexibleDCMotor)."""
    stiff = FlexibleDCMotor(mode_frequency=flex.mode_frequency * 1.1).ideal()
    amps = []
    for order in (0, 2):
        m = robust_move(1.0, flex, 0.005, order=order)
        th_l, _ = stiff.open_loop(np.r_[m.u, np.zeros(200)], 0.005, output="load")
        amps.append(np.abs(th_l[m.u.size :] - th_l[-1]).max())
    assert amps[1] < amps[0] / 5


def test_energy_optimal_move(flex):
    d, Ts = 1.0, 0.005
    m = robust_move(d, flex, Ts, order=1)
    e = energy_optimal_move(d, m.u.size + 20, flex, Ts, order=1)
    assert (e.u**2).sum() < (m.u**2).sum()
    th_l, _ = flex.open_loop(np.r_[e.u, np.zeros(100)], Ts, output="load")
    np.testing.assert_allclose(th_l[e.u.size :], d, atol=1e-6)
    inc = energy_optimal_move(d, m.u.size + 20, flex, Ts, order=1, objective="increment")
    assert np.abs(np.diff(inc.u)).max() < np.abs(np.diff(e.u)).max()
    with pytest.raises(RuntimeError):
        energy_optimal_move(d, m.u.size - 1, flex, Ts, order=1)


def test_tradeoff_table_and_figure():
    t = tradeoff()
    names = [r["name"] for r in t.rows]
    assert set(names) == set(t.curves)
    for r in t.rows:
        assert t.curves[r["name"]].shape == t.ratios.shape
        lo, hi = r["band"]
        if not math.isnan(lo):
            assert lo <= 1 <= hi
    rows = {r["name"]: r for r in t.rows}
    assert rows["ZV"]["width"] < rows["ZVD"]["width"] < rows["2-hump EI"]["width"]
    assert (
        rows["robust LP order 0"]["width"]
        < rows["robust LP order 1"]["width"]
        < rows["robust LP order 2"]["width"]
    )
    text = t.table()
    assert "penalty" in text and "3-hump EI" in text
    ax = t.plot()
    assert "Hz" in ax.get_xlabel() and "%" in ax.get_ylabel()


# ----------------------------------------------------------------------------------------------
# the shaper recommended for an identified mode (the identification: tests/test_ident_mode.py)
# ----------------------------------------------------------------------------------------------
def test_identify_mode_recommends_a_shaper_that_covers_the_mode():
    m = FlexibleDCMotor(
        load_ratio=0.15,
        mode_frequency=2 * math.pi * 8.0,
        mode_damping=0.02,
        noise_std=0.002,
        seed=7,
    )
    Ts = 0.005
    u = chirp_input(8.0, Ts, 3.0, 1.0, 30.0)
    _, y = m.open_loop(u, Ts)  # quantized to 448 counts/rev, plus noise
    fit = identify_mode(u, y, Ts)
    assert isinstance(fit, ModeFit) and isinstance(fit, ModeEstimate)
    est = identify_mode_estimate(u, y, Ts)  # the identification alone gives the same mode
    assert (fit.frequency_hz, fit.damping) == (est.frequency_hz, est.damping)
    f0, _ = flexible_mode(m)
    lo, hi = fit.shaper.insensitivity(5.0, hz=True)
    assert lo <= f0 <= hi
    again = ModeFit.recommend(fit.frequency_hz, fit.damping, fit.frequency_se)
    assert fit.shaper.kind == again.kind
    np.testing.assert_array_equal(fit.shaper.times, again.times)
    # with a drift margin the recommendation widens, and its band holds the margin
    for margin in (0.05, 0.15, 0.3):
        s = ModeFit.recommend(fit.frequency_hz, fit.damping, fit.frequency_se, margin=margin)
        lo, hi = s.insensitivity(5.0)
        assert lo <= 1 - margin and hi >= 1 + margin, (margin, s.kind)
        assert s.duration >= fit.shaper.duration


# ----------------------------------------------------------------------------------------------
# bad input
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "call,name",
    [
        (lambda: input_shaper("zz", 1.0), "kind"),
        (lambda: input_shaper(3, 1.0), "kind"),
        (lambda: input_shaper("zv", -1.0), "frequency_hz"),
        (lambda: input_shaper("zv", float("nan")), "frequency_hz"),
        (lambda: input_shaper("zv", 1.0, 1.0), "damping"),
        (lambda: input_shaper("zv", 1.0, -0.1), "damping"),
        (lambda: input_shaper("ei", 1.0, 0.0, vtol=0.7), "vtol"),
        (lambda: input_shaper("zv", 1.0).fir(0.0), "Ts"),
        (lambda: input_shaper("zv", 1.0).apply([0.0, float("inf")], 0.01), "reference"),
        (lambda: input_shaper("zv", 1.0).apply([], 0.01), "reference"),
        (lambda: input_shaper("zv", 1.0).insensitivity(0.0), "tolerance"),
        (lambda: input_shaper("zv", 1.0).insensitivity(150.0), "tolerance"),
        (lambda: input_shaper("zv", 1.0).residual_vibration(0.0), "frequency_hz"),
        (lambda: chirp_input(1.0, 0.01, 1.0, 1.0, 80.0), "f1"),
        (
            lambda: identify_mode(np.sin(np.arange(100.0)), np.arange(101.0), 0.01, margin=-0.1),
            "margin",
        ),
        (lambda: tuned_profile("ramp", 1.0, 8.0, 300.0, 100.0), "kind"),
        (lambda: tuned_profile("scurve", 1.0, 8.0, -300.0, 100.0), "max_accel"),
        (lambda: robust_move(0.0), "distance"),
        (lambda: robust_move(1.0, model="motor"), "model"),
        (lambda: robust_move(1.0).sensitivity_curve([-1.0, 1.0]), "ratios"),
        (lambda: input_shaper("zv", 1.0).sensitivity_curve([0.0]), "ratios"),
        (lambda: input_shaper("zv", 1.0).sensitivity_curve([1.0], damping=[]), "damping"),
        (
            lambda: profile_residual_vibration(planner.plan_trapezoid(1.0, 1.0, 1.0), -2.0),
            "frequency_hz",
        ),
        (lambda: tradeoff(ratios=[0.0, 1.0]), "ratios"),
        (lambda: robust_move(1.0, order=-1), "order"),
        (lambda: robust_move(1.0, u_max=0.0), "u_max"),
        (lambda: energy_optimal_move(1.0, 40, objective="fast"), "objective"),
        (
            lambda: InputShaper("custom", 1.0, 0.0, np.array([0.5, 0.6]), np.array([0.0, 1.0])),
            "amplitudes",
        ),
    ],
)
def test_bad_input_names_the_parameter(call, name):
    with pytest.raises((ValueError, TypeError), match=name):
        call()


def test_kind_aliases():
    for alias, kind in (
        ("ZV", "zv"),
        ("2-hump EI", "2hump_ei"),
        ("EI2", "2hump_ei"),
        ("3-Hump EI", "3hump_ei"),
        ("3hump_ei", "3hump_ei"),
        (" Mzv ", "mzv"),
    ):
        assert input_shaper(alias, 5.0).kind == kind
    with pytest.raises(TypeError, match="profile"):
        profile_residual_vibration("trapezoid", 8.0)


@settings(max_examples=200, deadline=None)
@given(
    kind=st.sampled_from(["trapezoid", "scurve", "sine_jerk", "sine_jerk_optimal"]),
    distance=st.floats(1e-3, 1e3),
    f=st.floats(0.5, 50.0),
    A=st.floats(1.0, 1e4),
    V=st.floats(0.1, 1e3),
    zeta=st.sampled_from([0.0, 0.02, 0.1]),
)
def test_tuned_profile_properties(kind, distance, f, A, V, zeta):
    p = tuned_profile(kind, distance, f, A, V, damping=zeta)
    assert p.peak_accel <= A * (1 + 1e-9) and p.peak_velocity <= V * (1 + 1e-9)
    assert p.duration >= planner.plan_trapezoid(distance, A, V).duration * (1 - 1e-12)
    v = profile_residual_vibration(p, np.array([0.5 * f, f, 2 * f]), zeta)
    assert np.all((v >= 0) & (v <= 100 + 1e-9))  # a positive density never beats a step
    if zeta == 0.0:
        assert v[1] < 1e-7


def test_residual_amplitude_from_a_record():
    """A shaped step into a second-order mode, sampled and quantized: the fitted amplitude matches
    the formula's V times the step."""
    from scipy.signal import lsim

    f, zeta, Ts, D = 6.0, 0.03, 0.001, 2.0
    w = 2 * math.pi * f
    t = np.arange(0, 3.0, Ts)
    for kind, ratio in (("zv", 1.08), ("zvd", 1.2), ("ei", 0.8)):
        s = input_shaper(kind, f, zeta)
        x = D * np.array([s.amplitudes[s.times <= tk + 1e-12].sum() for tk in t])
        _, y, _ = lsim(([(w * ratio) ** 2], [1, 2 * zeta * w * ratio, (w * ratio) ** 2]), x, t)
        yq = np.floor(y / 1e-3) * 1e-3 + 5e-4  # a 1 mrad encoder
        k0 = int(math.ceil(s.duration / Ts)) + 1
        got = residual_amplitude(yq, Ts, k0, frequency_hz=f * ratio, damping=zeta, final=D)
        want = (
            s.residual_vibration(f * ratio)
            / 100
            * D
            / math.sqrt(1 - zeta**2)
            * math.exp(-zeta * w * ratio * (k0 * Ts - s.duration))
        )
        assert got == pytest.approx(want, rel=0.03, abs=2e-4)
        assert residual_amplitude(yq, Ts, k0, final=D) == pytest.approx(want, rel=0.1, abs=1e-3)
    with pytest.raises(ValueError, match="start"):
        residual_amplitude(np.zeros(10), 0.01, 8)


@settings(max_examples=150, deadline=None)
@given(
    kind=kinds,
    f=freqs,
    zeta=dampings,
    Ts=st.floats(1e-3, 0.02),
    bits=st.integers(8, 24),
    ref=st.lists(st.integers(-(10**6), 10**6), min_size=1, max_size=40),
)
def test_fixed_point_fir(kind, f, zeta, Ts, bits, ref):
    s = input_shaper(kind, f, zeta)
    q = s.fir_fixed(Ts, bits)
    h = s.fir(Ts)
    assert q.dtype == np.int64 and q.sum() == 1 << bits and np.all(q >= 0)
    assert np.abs(q - h * (1 << bits)).max() < 1.0
    r = np.array(ref, dtype=np.int64)
    y = s.apply_fixed(r, Ts, bits)
    assert y[-1] == r[-1] and y[0] == r[0]  # exact ends
    # against the float FIR: the rounding of the taps plus half a count
    err = np.abs(y - s.apply(r.astype(float), Ts))
    assert np.all(err <= 0.5 + q.size * np.abs(r).max() / (1 << bits) + 1e-9)
    # integer arithmetic written out for one sample, as the firmware would
    k = min(len(ref) - 1, 3)
    hist = [r[max(k - j, 0)] for j in range(q.size)]
    assert (
        y[k] == (sum(int(q[j]) * int(hist[j]) for j in range(q.size)) + (1 << (bits - 1))) >> bits
    )
