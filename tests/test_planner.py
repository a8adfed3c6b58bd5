"""Planners: invariants, the paper's equations, and independent checks (scipy, Ruckig).

Case counts in CI (fixed with ``max_examples``, independent of the hypothesis profile):
per-move property tests 3200 (invariants) + 1200 (synchronized) + 2000 (Ruckig) + 400
(quadrature) + 300 hypothesis examples, each one move checked on ~100 closed-form samples; the
seeded batch tests check 4 kinds x 25 hypothesis seeds x 4000 moves = 4e5 more random moves with
the same invariants, through ``plan_batch`` and ``BatchPlan.sample``.  Hypothesis by itself costs
1-3 ms per example here, so 1e5 single-move examples would not fit the minute this file may use.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy.integrate import fixed_quad

import jerklab.planner as planner
from jerklab.planner import (
    KINDS,
    BatchPlan,
    Profile,
    ProfileSample,
    plan_batch,
    plan_scurve,
    plan_sine_jerk,
    plan_sine_jerk_optimal,
    plan_trapezoid,
)

ruckig = pytest.importorskip("ruckig")

RTOL = 1e-9  # limits and end state, relative
PLANNERS = {
    "sine_jerk": plan_sine_jerk,
    "sine_jerk_optimal": plan_sine_jerk_optimal,
    "scurve": plan_scurve,
    "trapezoid": lambda d, j, a, v: plan_trapezoid(d, a, v),
}

# ------------------------------------------------------------------------------------------------
# strategies: limits and distances over many decades (log-uniform), both signs and zero
# ------------------------------------------------------------------------------------------------


# Plain float strategies (exponents), turned into values inside the tests: hypothesis spends
# ~1.5 ms per example on four plain floats and nearly twice that with .map/one_of.
EXP_D = st.floats(-9.0, 7.0)  # |distance| = 10**e, and exactly 0 below e = -8.5
EXP_J = st.floats(-4.0, 7.0)
EXP_A = st.floats(-4.0, 6.0)
EXP_V = st.floats(-4.0, 5.0)
SIGN = st.booleans()


def move(sign, ed, ej, ea, ev):
    d = 0.0 if ed < -8.5 else (-1.0 if sign else 1.0) * 10.0**ed
    return d, 10.0**ej, 10.0**ea, 10.0**ev


# ------------------------------------------------------------------------------------------------
# invariant checks, vectorized over moves (rows) and sample times (columns)
# ------------------------------------------------------------------------------------------------


def boundaries(phase_times):
    """(n, k+1) cumulative phase boundaries plus the middle of the move."""
    pt = np.atleast_2d(np.asarray(phase_times, float))
    b = np.concatenate([np.zeros((pt.shape[0], 1)), np.cumsum(pt, axis=1)], axis=1)
    return np.concatenate([b, 0.5 * b[:, -1:]], axis=1)


def check_moves(
    kind, distance, J, A, V, duration, phase_times, peak_j, peak_a, peak_v, sampler, n_grid=64
):
    """Assert every invariant of rest-to-rest moves; arrays are (n,), ``sampler(t)`` -> (n, m)."""
    distance, J, A, V, T = (
        np.asarray(x, float).reshape(-1, 1) for x in (distance, J, A, V, duration)
    )
    peak_j, peak_a, peak_v = (np.asarray(x, float).reshape(-1, 1) for x in (peak_j, peak_a, peak_v))
    d = np.abs(distance)
    # phase times add up, none negative, zero move is empty
    pt = np.atleast_2d(np.asarray(phase_times, float))
    assert np.all(pt >= 0.0)
    np.testing.assert_allclose(pt.sum(axis=1, keepdims=True), T, rtol=1e-12, atol=0)
    assert np.all(T[d == 0.0] == 0.0)
    # reported peaks within the limits
    if kind != "trapezoid":
        assert np.all(peak_j <= J * (1 + RTOL))
    assert np.all(peak_a <= A * (1 + RTOL))
    assert np.all(peak_v <= V * (1 + RTOL))
    # samples: a grid, every phase boundary (and the middle) approached from both sides
    b = boundaries(pt)
    pos_pt = np.where(pt > 0, pt, np.inf).min(axis=1, keepdims=True)
    delta = np.where(np.isfinite(pos_pt), 1e-7 * pos_pt, 0.0)
    grid = T * np.linspace(-0.05, 1.05, n_grid)[None, :]
    t = np.concatenate([grid, b - delta, b, b + delta], axis=1)
    order = np.argsort(t, axis=1)
    t = np.take_along_axis(t, order, axis=1)
    s = sampler(t)
    assert s.position.shape == t.shape
    for arr in s[1:]:
        assert np.all(np.isfinite(arr))
    # limits on every sample, and the samples below the reported peaks
    assert np.all(np.abs(s.accel) <= np.minimum(A, peak_a) * (1 + RTOL) + 1e-300)
    assert np.all(np.abs(s.velocity) <= np.minimum(V, peak_v) * (1 + RTOL) + 1e-300)
    if kind != "trapezoid":
        assert np.all(np.abs(s.jerk) <= np.minimum(J, peak_j) * (1 + RTOL) + 1e-300)
    # rest before 0, exact end state from the duration on
    before, after = t < 0.0, t >= T
    for arr in (s.jerk, s.accel, s.velocity, s.position):
        assert np.all(arr[before] == 0.0)
    assert np.all((s.jerk == 0.0)[after]) and np.all((s.accel == 0.0)[after])
    assert np.all((s.velocity == 0.0)[after])
    assert np.all(s.position[after] == np.broadcast_to(distance, t.shape)[after])
    # monotone position (rest to rest: the velocity never changes sign)
    step = np.diff(s.position, axis=1) * np.sign(distance)
    assert np.all(step >= -1e-12 * d), f"position not monotone: {step.min()}"
    assert np.all(s.velocity * np.sign(distance) >= 0.0)
    # continuity of position / velocity / acceleration across every boundary and the middle
    m = b.shape[1]
    k0 = n_grid
    back = np.argsort(order, axis=1)  # back to the order t was built in
    unsorted = [np.take_along_axis(arr, back, axis=1) for arr in (s.accel, s.velocity, s.position)]
    tu = np.take_along_axis(t, back, axis=1)
    dt_left = tu[:, k0 + m : k0 + 2 * m] - tu[:, k0 : k0 + m]  # the offsets actually sampled
    dt_right = tu[:, k0 + 2 * m : k0 + 3 * m] - tu[:, k0 + m : k0 + 2 * m]
    for arr, lip, scale in zip(
        unsorted, (J if kind != "trapezoid" else None, A, V), (peak_a, peak_v, d)
    ):
        if lip is None:
            continue  # a trapezoid's acceleration jumps
        left = arr[:, k0 : k0 + m]
        mid = arr[:, k0 + m : k0 + 2 * m]
        right = arr[:, k0 + 2 * m : k0 + 3 * m]
        # the closed form mirrors t -> T - t, which moves a time by up to an ulp of T
        tol = 1e-9 * scale + lip * 4 * np.finfo(float).eps * T + 1e-300
        assert np.all(np.abs(mid - left) <= lip * dt_left * (1 + 1e-6) + tol)
        assert np.all(np.abs(right - mid) <= lip * dt_right * (1 + 1e-6) + tol)
    # the reported peaks are reached: velocity in the middle, acceleration at the end of the
    # rising jerk pulse (middle of the published T, middle of a trapezoid's t_a)
    active = (d > 0).ravel()
    if np.any(active):
        first = pt[:, :1] if kind in ("sine_jerk_optimal", "scurve") else 0.5 * pt[:, :1]
        at = sampler(np.concatenate([0.5 * T, first], axis=1))
        np.testing.assert_allclose(np.abs(at.velocity[active, 0]), peak_v[active, 0], rtol=1e-9)
        np.testing.assert_allclose(np.abs(at.accel[active, 1]), peak_a[active, 0], rtol=1e-9)


def check_profile(p, J, A, V):
    assert isinstance(p, Profile)
    check_moves(
        p.kind,
        p.distance,
        J,
        A,
        V,
        p.duration,
        p.phase_times,
        p.peak_jerk,
        p.peak_accel,
        p.peak_velocity,
        p.sample,
    )


# ------------------------------------------------------------------------------------------------
# per-move property tests (hypothesis shrinks a failure to a small case)
# ------------------------------------------------------------------------------------------------
N_INVARIANT = 800  # x 4 planners
N_SYNC = 300  # x 4 planners
N_RUCKIG = 1000  # x 2 planners
N_INTEGRATE = 100  # x 4 planners (scipy quadrature)


@pytest.mark.parametrize("kind", KINDS)
@settings(max_examples=N_INVARIANT, deadline=None, suppress_health_check=list(HealthCheck))
@given(sign=SIGN, ed=EXP_D, ej=EXP_J, ea=EXP_A, ev=EXP_V)
def test_invariants(kind, sign, ed, ej, ea, ev):
    distance, J, A, V = move(sign, ed, ej, ea, ev)
    p = PLANNERS[kind](distance, J, A, V)
    assert p.kind == kind and p.distance == distance
    check_profile(p, J, A, V)
    if kind != "trapezoid" and distance != 0.0:
        assert p.peak_jerk == J  # every jerk-limited planner uses all of J
    # moving backwards mirrors moving forwards
    q = PLANNERS[kind](-distance, J, A, V)
    assert q.duration == p.duration and q.phase_times == p.phase_times


@pytest.mark.parametrize("kind", ["sine_jerk", "sine_jerk_optimal", "scurve", "trapezoid"])
@settings(max_examples=N_SYNC, deadline=None, suppress_health_check=list(HealthCheck))
@given(sign=SIGN, ed=EXP_D, ej=EXP_J, ea=EXP_A, ev=EXP_V, ts_exp=st.floats(-5, 0))
# a cruise of 6e13 s: the sum of the phase times rounds by more than Ts (found by CI)
@example(sign=False, ed=5.5625, ej=2.0, ea=-3.21875, ev=0.0, ts_exp=-4.0)
def test_synchronized(kind, sign, ed, ej, ea, ev, ts_exp):
    distance, J, A, V = move(sign, ed, ej, ea, ev)
    Ts = 10.0**ts_exp
    p = PLANNERS[kind](distance, J, A, V)
    q = p.synchronized(Ts)
    assert q.kind == kind and q.distance == distance
    n = np.asarray(q.phase_times) / Ts
    assert np.all(np.abs(n - np.round(n)) <= 1e-6 * np.maximum(1.0, n))
    assert q.duration >= p.duration * (1 - 1e-12)
    # at most one sample more per phase, up to the rounding of a sum of huge phase times
    assert q.duration <= p.duration * (1 + 1e-12) + len(q.phase_times) * Ts * (1 + 1e-9)
    # lowered peaks, never raised
    assert q.peak_accel <= p.peak_accel * (1 + RTOL) + 1e-300
    assert q.peak_velocity <= p.peak_velocity * (1 + RTOL) + 1e-300
    if kind != "trapezoid":
        assert q.peak_jerk <= J * (1 + RTOL)
    check_profile(q, J, A, V)
    # the end of the closed form is the distance (not only the clamp after the duration)
    if distance != 0.0:
        s = q.sample(q.duration * (1 - 1e-12))
        assert abs(s.position - distance) <= 1e-9 * abs(distance)


@pytest.mark.parametrize("kind", KINDS)
def test_synchronized_more_samples_than_float_integers(kind):
    """A cruise of ~2e17 samples: rounding up must not drop thousands of seconds (regression)."""
    p = PLANNERS[kind](1e6, 10.0**6.75, 10.0**-1.375, 1.0)
    q = p.synchronized(0.01)
    assert q.duration >= p.duration * (1 - 1e-12)
    assert q.peak_velocity <= 1.0 * (1 + 1e-9)


def _ruckig_duration(distance, J, A, V):
    otg, inp, traj = ruckig.Ruckig(1), ruckig.InputParameter(1), ruckig.Trajectory(1)
    inp.current_position, inp.target_position = [0.0], [distance]
    inp.max_jerk, inp.max_acceleration, inp.max_velocity = [J], [A], [V]
    res = otg.calculate(inp, traj)
    return res, traj


# Ruckig's range: distances 1e-5..1e5, limits 1e-3..1e4 (1e5 for the jerk)
R_D, R_J, R_A, R_V = st.floats(-5, 5), st.floats(-3, 5), st.floats(-3, 4), st.floats(-3, 4)


@settings(max_examples=N_RUCKIG, deadline=None, suppress_health_check=list(HealthCheck))
@given(sign=SIGN, ed=R_D, ej=R_J, ea=R_A, ev=R_V)
def test_scurve_equals_ruckig(sign, ed, ej, ea, ev):
    distance, J, A, V = move(sign, ed, ej, ea, ev)
    res, traj = _ruckig_duration(distance, J, A, V)
    assert res == ruckig.Result.Working
    p = plan_scurve(distance, J, A, V)
    assert abs(p.duration - traj.duration) <= 1e-9 * traj.duration
    # pointwise too: Ruckig's own closed form at a few times
    dt = 1e-12 * traj.duration  # the two durations may differ by this much
    for frac in (0.1, 0.37, 0.5, 0.81):
        t = frac * traj.duration
        x, v, a = (u[0] for u in traj.at_time(t))
        s = p.sample(t)
        assert abs(float(s.position) - x) <= 1e-8 * abs(distance) + p.peak_velocity * dt
        assert abs(float(s.velocity) - v) <= 1e-8 * p.peak_velocity + p.peak_accel * dt
        assert abs(float(s.accel) - a) <= 1e-7 * p.peak_accel + J * dt


@settings(max_examples=N_RUCKIG, deadline=None, suppress_health_check=list(HealthCheck))
@given(sign=SIGN, ed=R_D, ej=R_J, ea=R_A, ev=R_V)
def test_sine_optimal_equals_ruckig_at_2J_over_pi(sign, ed, ej, ea, ev):
    distance, J, A, V = move(sign, ed, ej, ea, ev)
    res, traj = _ruckig_duration(distance, 2.0 * J / math.pi, A, V)
    assert res == ruckig.Result.Working
    p = plan_sine_jerk_optimal(distance, J, A, V)
    assert abs(p.duration - traj.duration) <= 1e-9 * traj.duration
    # and it is never faster than the linear-jerk optimum with the full J, at most (pi/2)^(1/3) slower
    r = plan_scurve(distance, J, A, V).duration
    assert r * (1 - 1e-12) <= p.duration <= (math.pi / 2) ** (1 / 3) * r * (1 + 1e-12)
    # the published planner is never faster than the optimal sine planner
    assert plan_sine_jerk(distance, J, A, V).duration >= p.duration * (1 - 1e-12)


def integrate_jerk(p, n_nodes=64):
    """Integrate the sampled jerk (a trapezoid: its acceleration) numerically, phase by phase.

    Gauss-Legendre quadrature (``scipy.integrate.fixed_quad``, nodes strictly inside each phase,
    where the jerk is smooth) of Cauchy's formula for repeated integrals, from a state (a, v, x)
    at ``t0`` to ``t1 = t0 + L``::

        a1 = a0 + int j,   v1 = v0 + a0 L + int (t1 - s) j,   x1 = x0 + v0 L + a0 L^2/2 + int (t1 - s)^2/2 j

    Returns ``[(t, (a, v, x))]`` at every phase end and phase middle.
    """
    b = boundaries(p.phase_times)[0, :-1]
    a = v = x = 0.0
    out = []
    step = p.kind == "trapezoid"

    def advance(a, v, x, t0, L):
        # local time tau in [0, L] (L a phase time, exact), the jerk sampled at t0 + tau
        if L <= 0.0:
            return a, v, x
        f = (
            (lambda tau: p.sample(t0 + tau).accel)
            if step
            else (lambda tau: p.sample(t0 + tau).jerk)
        )
        i0 = fixed_quad(f, 0.0, L, n=n_nodes)[0]
        i1 = fixed_quad(lambda tau: (L - tau) * f(tau), 0.0, L, n=n_nodes)[0]
        if step:  # integrate the (piecewise constant) acceleration
            return 0.0, v + i0, x + v * L + i1
        i2 = fixed_quad(lambda tau: 0.5 * (L - tau) ** 2 * f(tau), 0.0, L, n=n_nodes)[0]
        return a + i0, v + a * L + i1, x + v * L + 0.5 * a * L * L + i2

    for t0, L in zip(b[:-1], p.phase_times):
        out.append((t0 + 0.5 * L, advance(a, v, x, t0, 0.5 * L)))
        a, v, x = advance(a, v, x, t0, L)
        out.append((t0 + L, (a, v, x)))
    return out


@pytest.mark.parametrize("kind", KINDS)
@settings(max_examples=N_INTEGRATE, deadline=None, suppress_health_check=list(HealthCheck))
@given(sign=SIGN, ed=R_D, ej=R_J, ea=R_A, ev=R_V)
def test_closed_form_matches_integrated_jerk(kind, sign, ed, ej, ea, ev):
    distance, J, A, V = move(sign, ed, ej, ea, ev)
    p = PLANNERS[kind](distance, J, A, V)
    ends = integrate_jerk(p)
    # Round-off allowances: a time is known to an ulp of the duration (the quadrature nodes
    # t0 + tau, the mirror t -> T - t), so a jerk pulse is resolved to J * ulp(T) in acceleration;
    # the integration carries such an acceleration error through the rest of the move
    # (velocity ~ error * T, position ~ error * T^2).
    T = p.duration
    slack = 4 * np.finfo(float).eps * T
    tol_a = 1e-9 * p.peak_accel + J * slack
    tol_v = 1e-9 * p.peak_velocity + A * slack + tol_a * T
    tol_x = 1e-9 * abs(distance) + V * slack + tol_v * T
    for t1, (a, v, x) in ends:
        s = p.sample(t1)
        if kind != "trapezoid":
            assert abs(a - float(s.accel)) <= tol_a
        assert abs(v - float(s.velocity)) <= tol_v
        assert abs(x - float(s.position)) <= tol_x
    # the integration ends at rest at the distance: the closed form's end state is right
    a, v, x = ends[-1][1]
    assert abs(x - distance) <= tol_x
    assert abs(v) <= tol_v
    if kind != "trapezoid":
        assert abs(a) <= tol_a


# ------------------------------------------------------------------------------------------------
# seeded batch tests: 1.2e6 moves through plan_batch and BatchPlan.sample
# ------------------------------------------------------------------------------------------------
N_BATCH_SEEDS = 25
BATCH = 4000


def random_moves(rng, n):
    d = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-8, 7, n)
    d[rng.random(n) < 0.01] = 0.0
    J = 10.0 ** rng.uniform(-4, 7, n)
    A = 10.0 ** rng.uniform(-4, 6, n)
    V = 10.0 ** rng.uniform(-4, 5, n)
    # a third of the moves with one limit far dominating the others
    k = rng.integers(0, 6, n)
    J = np.where(k == 0, J * 1e6, J)
    A = np.where(k == 1, A * 1e6, A)
    V = np.where(k == 2, V * 1e6, V)
    return d, J, A, V


@pytest.mark.parametrize("kind", KINDS)
@settings(max_examples=N_BATCH_SEEDS, deadline=None, suppress_health_check=list(HealthCheck))
@given(seed=st.integers(0, 2**63 - 1))
def test_batch_invariants(kind, seed):
    rng = np.random.default_rng(seed)
    d, J, A, V = random_moves(rng, BATCH)
    b = plan_batch(kind, d, J, A, V)
    assert isinstance(b, BatchPlan) and len(b) == BATCH
    check_moves(
        kind,
        d,
        J,
        A,
        V,
        b.duration,
        b.phase_times,
        b.peak_jerk,
        b.peak_accel,
        b.peak_velocity,
        b.sample,
        n_grid=24,
    )
    # the batch planner agrees with the scalar planner
    f = PLANNERS[kind]
    for i in rng.choice(BATCH, 25, replace=False):
        p = f(float(d[i]), float(J[i]), float(A[i]), float(V[i]))
        np.testing.assert_allclose(
            b.phase_times[i], p.phase_times, rtol=1e-9, atol=1e-12 * p.duration
        )
        q = b.profile(int(i))
        assert q.kind == kind and abs(q.duration - p.duration) <= 1e-9 * p.duration


@pytest.mark.parametrize("kind", KINDS)
def test_batch_engines_agree(kind):
    """The compiled loop (numba) and the numpy form give the same phase times on 2e4 moves."""
    pytest.importorskip("numba")
    rng = np.random.default_rng(7)
    d, J, A, V = random_moves(rng, 20000)
    a = plan_batch(kind, d, J, A, V, engine="numba")
    b = plan_batch(kind, d, J, A, V, engine="numpy")
    T = b.duration
    for x, y in ((a.tj, b.tj), (a.ta, b.ta), (a.tv, b.tv)):
        assert np.all(np.abs(x - y) <= 1e-9 * T)
    assert np.all(np.abs(a.duration - T) <= 1e-12 * T)
    with pytest.raises(ValueError, match="engine"):
        plan_batch(kind, d, J, A, V, engine="fortran")
    # the compiled loop checks every value and the error names the parameter
    for name, arr, bad in (
        ("distance", d, math.inf),
        ("max_accel", A, -1.0),
        ("max_velocity", V, math.nan),
        ("max_jerk", J, 0.0),
    ):
        if kind == "trapezoid" and name == "max_jerk":
            continue
        saved = arr[12345]
        arr[12345] = bad
        with pytest.raises(ValueError, match=name):
            plan_batch(kind, d, J, A, V, engine="numba")
        arr[12345] = saved


# ------------------------------------------------------------------------------------------------
# the paper: eq. 2-4, Fig. 2, eq. 15
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "theta,J,E,W",
    [
        (1.0, 1000.0, 100.0, 60.0),
        (100.0, 1000.0, 100.0, 60.0),
        (10 * math.pi, 2e4, 300.0, 100.0),
        (1e4, 10.0, 1e3, 1.0),
    ],
)
def test_eq3_peaks(theta, J, E, W):
    p = plan_sine_jerk(theta, J, E, W)
    T = p.accel_time
    s = p.sample(np.array([T / 4, T / 2, T]))
    assert s.jerk[0] == pytest.approx(J, rel=1e-12)  # eq. 2: J sin(2 pi t/T) at T/4
    assert s.accel[1] == pytest.approx(J * T / math.pi, rel=1e-12)  # eq. 3: E = J T / pi
    assert s.velocity[2] == pytest.approx(J * T**2 / (2 * math.pi), rel=1e-12)
    assert s.position[2] == pytest.approx(J * T**3 / (4 * math.pi), rel=1e-12)
    assert p.peak_accel == pytest.approx(J * T / math.pi, rel=1e-12)
    assert p.peak_velocity == pytest.approx(J * T**2 / (2 * math.pi), rel=1e-12)
    assert p.duration == pytest.approx(2 * T + p.cruise_time, rel=1e-15)
    assert p.phase_times == (T, p.cruise_time, T)
    # eq. 2 on the deceleration: -J sin(2 pi (t - t1)/T)
    t1 = T + p.cruise_time
    tt = t1 + np.linspace(0.01, 0.99, 7) * T
    np.testing.assert_allclose(
        p.sample(tt).jerk, -J * np.sin(2 * np.pi * (tt - t1) / T), rtol=1e-9, atol=1e-9 * J
    )


def test_fig2_distance_binds():
    theta, J = 1.0, 1000.0
    p = plan_sine_jerk(theta, J, 1e6, 1e6)
    assert p.accel_time == pytest.approx((2 * math.pi * theta / J) ** (1 / 3), rel=1e-14)  # eq. 4
    assert p.cruise_time == 0.0
    assert p.peak_accel < 1e6 and p.peak_velocity < 1e6


def test_fig2_accel_binds():
    # docs/THEORY.md (Stojčić eq. 4): Theta = 10 pi, J = 2e4, E = 300, Omega = 100
    # -> T = 47 ms, cruise 7.07, 4.49 s
    p = plan_sine_jerk(10 * math.pi, 2e4, 300.0, 100.0)
    assert p.accel_time == pytest.approx(300.0 * math.pi / 2e4, rel=1e-14)
    assert p.peak_accel == pytest.approx(300.0, rel=1e-14)
    assert p.peak_velocity == pytest.approx(7.0686, abs=1e-4)
    assert p.duration == pytest.approx(4.4916, abs=1e-4)
    assert p.peak_jerk == 2e4
    # the optimal sine planner keeps an acceleration plateau at 300 instead
    q = plan_sine_jerk_optimal(10 * math.pi, 2e4, 300.0, 100.0)
    assert q.peak_accel == pytest.approx(300.0, rel=1e-12)
    assert q.phase_times[1] > 0.0
    assert q.duration < p.duration / 6


def test_fig2_velocity_binds():
    J, W = 1000.0, 2.0
    p = plan_sine_jerk(100.0, J, 1e6, W)
    assert p.accel_time == pytest.approx(math.sqrt(2 * math.pi * W / J), rel=1e-14)
    assert p.peak_velocity == pytest.approx(W, rel=1e-14)
    assert p.cruise_time == pytest.approx(100.0 / W - p.accel_time, rel=1e-12)


def test_fig2_accel_then_velocity_binds():
    # both tests of the flowchart fire: T = min(T_Theta, T_E, T_Omega) = T_Omega
    J, E, W = 1000.0, 100.0, 1.0
    p = plan_sine_jerk(100.0, J, E, W)
    T_E, T_W = E * math.pi / J, math.sqrt(2 * math.pi * W / J)
    assert T_W < T_E
    assert p.accel_time == pytest.approx(T_W, rel=1e-14)


@settings(max_examples=300, deadline=None)
@given(ed=st.floats(-6, 6), ej=EXP_J, ea=EXP_A, ev=EXP_V)
def test_sine_jerk_is_min_of_three_times(ed, ej, ea, ev):
    theta, J, E, W = move(False, ed, ej, ea, ev)
    p = plan_sine_jerk(theta, J, E, W)
    T = min((2 * math.pi * theta / J) ** (1 / 3), E * math.pi / J, math.sqrt(2 * math.pi * W / J))
    assert p.accel_time == pytest.approx(T, rel=1e-13)
    assert p.cruise_time >= 0.0


def test_sine_jerk_clamps_negative_round_off():
    """Without the clamp the distance-limited branch gives t_v ~ -1e-16 for some distances."""
    J = 1000.0
    raw_negative = 0
    for theta in np.linspace(0.1, 10.0, 2000):
        theta = float(theta)
        T = (2 * math.pi * theta / J) ** (1 / 3)
        w = J * T * T / (2 * math.pi)
        if (theta - w * T) / w < 0.0:
            raw_negative += 1
        assert plan_sine_jerk(theta, J, 1e9, 1e9).cruise_time >= 0.0
    assert raw_negative > 0


def test_eq15_drifts_and_closed_form_does_not():
    # docs/THEORY.md (Stojčić eq. 15): -0.8 % for Theta = 100, J = 1000, E = 100, Omega = 60 at Ts = 5 ms
    p = plan_sine_jerk(100.0, 1000.0, 100.0, 60.0)
    disc = p.discretize(0.005)
    assert disc.t[0] == 0.0 and disc.t[1] == pytest.approx(0.005)
    assert disc.t[-1] >= p.duration
    drift = (disc.position[-1] - 100.0) / 100.0
    assert drift == pytest.approx(-0.008, abs=0.0005)
    # the recursion itself, written out (eq. 15)
    e = w = th = 0.0
    for k, tk in enumerate(disc.t):
        e += float(p.sample(tk).jerk) * 0.005
        w += e * 0.005
        th += w * 0.005
    assert th == pytest.approx(disc.position[-1], rel=1e-12)
    # the fix: a synchronized profile sampled in closed form ends exactly at the target
    q = p.synchronized(0.005)
    tk = np.arange(int(round(q.duration / 0.005)) + 1) * 0.005
    s = q.sample(tk)
    assert s.position[-1] == 100.0 and s.velocity[-1] == 0.0
    assert abs(q.sample(q.duration - 1e-9).position - 100.0) < 1e-6


def test_eq15_short_move_goes_backwards():
    # T spanning 9 samples (acceleration limit binding, long cruise): the recursion misses the
    # target by ~4 % and ends with the motor still moving backwards
    Ts, J, theta = 0.005, 1e4, 100.0
    E = J * 9 * Ts / math.pi  # T = E pi / J = 9 Ts
    p = plan_sine_jerk(theta, J, E, 1e9)
    assert p.accel_time == pytest.approx(9 * Ts)
    disc = p.discretize(Ts)
    drift = (disc.position[-1] - theta) / theta
    assert -0.05 < drift < -0.03
    assert disc.velocity[-1] < -0.05 * p.peak_velocity
    # T not a whole number of samples: the sampled pulse leaves an acceleration that the
    # recursion integrates over the cruise (9.5 samples: ends thousands of percent off)
    half = plan_sine_jerk(theta, J, J * 9.5 * Ts / math.pi, 1e9)
    assert (half.discretize(Ts).position[-1] - theta) / theta < -5.0
    sync = half.synchronized(Ts)
    assert sync.accel_time / Ts == pytest.approx(10.0)
    assert float(sync.sample(sync.duration * (1 - 1e-12)).position) == pytest.approx(
        theta, rel=1e-9
    )
    # the shorter the pulse in samples, the larger the drift
    long = plan_sine_jerk(theta, J, J * 63 * Ts / math.pi, 1e9).discretize(Ts)
    assert abs(long.position[-1] - theta) < abs(disc.position[-1] - theta) / 3


def test_discretize_trapezoid_integrates_accel():
    p = plan_trapezoid(10.0, 100.0, 20.0)
    disc = p.discretize(0.001)
    assert np.all(disc.jerk == 0.0)
    assert disc.position[-1] == pytest.approx(10.0, rel=0.02)


# ------------------------------------------------------------------------------------------------
# edges and interface
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(
    "case",
    [
        (1e-12, 1.0, 1.0, 1.0),  # tiny move
        (1e-300, 1.0, 1.0, 1.0),  # nearly the smallest normal float
        (1.0, 1e15, 1.0, 1.0),  # huge jerk: nearly a trapezoid
        (1.0, 1e-6, 1e6, 1e6),  # jerk dominates
        (1.0, 1e6, 1e-6, 1e6),  # acceleration dominates
        (1.0, 1e6, 1e6, 1e-6),  # velocity dominates
        (1e9, 1.0, 1.0, 1.0),  # long move
        (-3.0, 1000.0, 100.0, 60.0),
    ],
)
def test_edges(kind, case):
    d, J, A, V = case
    p = PLANNERS[kind](d, J, A, V)
    assert math.isfinite(p.duration) and p.duration > 0
    check_profile(p, J, A, V)


@pytest.mark.parametrize("kind", KINDS)
def test_subnormal_distance(kind):
    p = PLANNERS[kind](5e-324, 1.0, 1.0, 1.0)
    assert 0.0 < p.duration < 1e-100
    assert p.sample(p.duration).position == 5e-324


def test_huge_jerk_approaches_trapezoid():
    s = plan_scurve(1.0, 1e12, 2.0, 1.0)
    t = plan_trapezoid(1.0, 2.0, 1.0)
    assert s.duration == pytest.approx(t.duration, rel=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_zero_distance(kind):
    p = PLANNERS[kind](0.0, 1.0, 2.0, 3.0)
    assert p.duration == 0.0 and all(x == 0.0 for x in p.phase_times)
    assert p.peak_jerk == p.peak_accel == p.peak_velocity == 0.0
    s = p.sample(np.linspace(-1, 1, 5))
    assert all(np.all(x == 0.0) for x in s[1:])
    assert p.synchronized(0.01).duration == 0.0
    assert np.all(p.discretize(0.01).position == 0.0)


def test_sample_shapes_and_rest():
    p = plan_scurve(-2.0, 100.0, 10.0, 3.0)
    s = p.sample(0.1)
    assert isinstance(s, ProfileSample) and s.position.shape == ()
    s = p.sample(np.zeros((3, 4)))
    assert s.position.shape == (3, 4)
    s = p.sample([-5.0, p.duration, p.duration + 7.0])
    assert list(s.position) == [0.0, -2.0, -2.0]
    assert list(s.velocity) == [0.0, 0.0, 0.0]


def test_interface_and_to_dict():
    for kind, f in PLANNERS.items():
        p = f(1.5, 100.0, 10.0, 3.0)
        d = p.to_dict()
        json.dumps(d, allow_nan=False)
        assert d["kind"] == kind and d["distance"] == 1.5
        assert d["phase_times"] == list(p.phase_times)
        assert d["limits"]["max_accel"] == 10.0
        assert d["duration"] == p.duration
    p = plan_sine_jerk(1.5, 100.0, 10.0, 3.0)
    assert {"accel_time", "cruise_time"} <= set(p.to_dict())
    assert plan_trapezoid(1.0, 1.0, 1.0).peak_jerk == math.inf
    assert planner.plan_scurve is plan_scurve


def test_integer_and_numpy_inputs():
    a = plan_scurve(100, 1000, 100, 60)
    b = plan_scurve(np.float32(100.0), np.int64(1000), np.float64(100.0), np.array(60.0))
    assert a.duration == b.duration == plan_scurve(100.0, 1000.0, 100.0, 60.0).duration


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(
    "pos,name", [(0, "distance"), (1, "max_jerk"), (2, "max_accel"), (3, "max_velocity")]
)
@pytest.mark.parametrize(
    "bad", [math.nan, math.inf, -math.inf, -1.0, 0.0, "1", None, [1.0], True, 1 + 2j]
)
def test_bad_input_names_the_parameter(kind, pos, name, bad):
    if name == "distance" and bad in (-1.0, 0.0):
        return  # negative and zero distances are valid
    if kind == "trapezoid" and name == "max_jerk":
        return
    args = [1.0, 10.0, 10.0, 10.0]
    args[pos] = bad
    with pytest.raises(ValueError, match=name):
        PLANNERS[kind](*args)


@pytest.mark.parametrize("Ts", [0.0, -0.005, math.nan, math.inf, "5ms", None])
def test_bad_sample_time(Ts):
    p = plan_sine_jerk(1.0, 10.0, 10.0, 10.0)
    with pytest.raises(ValueError, match="Ts"):
        p.synchronized(Ts)
    with pytest.raises(ValueError, match="Ts"):
        p.discretize(Ts)


def test_bad_sample_times_and_batch_input():
    p = plan_scurve(1.0, 10.0, 10.0, 10.0)
    with pytest.raises(ValueError, match="t"):
        p.sample([0.0, math.nan])
    with pytest.raises(ValueError, match="kind"):
        plan_batch("bogus", [1.0], [1.0], [1.0], [1.0])
    with pytest.raises(ValueError, match="max_jerk"):
        plan_batch("scurve", [1.0], None, [1.0], [1.0])
    with pytest.raises(ValueError, match="max_accel"):
        plan_batch("scurve", [1.0, 2.0], [1.0], [1.0, -1.0], [1.0])
    with pytest.raises(ValueError, match="max_velocity"):
        plan_batch("scurve", [1.0], [1.0], [1.0], [math.inf])
    with pytest.raises(ValueError, match="distance"):
        plan_batch("scurve", [math.nan], [1.0], [1.0], [1.0])
    with pytest.raises(ValueError, match="distance"):
        plan_batch("scurve", ["a"], [1.0], [1.0], [1.0])
    b = plan_batch("trapezoid", [1.0, -2.0, 0.0], None, 2.0, 1.0)
    assert b.duration.shape == (3,) and b.duration[2] == 0.0
