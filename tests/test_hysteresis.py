"""Preisach operator and CNIA (Xu & Meckl, Fig. 2) against closed forms and invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import dblquad

from jerklab.hysteresis import ForcData, Preisach, fit_preisach, forc_experiment


def piezo():
    return Preisach.piezo_like(0.0, 100.0, n=30, width=0.25)


# ---------------------------------------------------------------- closed forms
def test_uniform_major_and_first_order_curves_closed_form():
    P = Preisach.uniform(-10.0, 30.0, n=16, gain=2.0)
    span, mu = 40.0, 2 * 2.0 / 40.0
    for u in np.linspace(-10, 30, 17):
        P.reset()
        assert P.apply(u) == pytest.approx(-10.0 + mu * (u + 10) ** 2 / 2, abs=1e-12)
    # FORC from alpha down to beta: f = f_alpha - mu (alpha - beta)^2 / 2
    for alpha, beta in [(25.0, 0.0), (5.3, -7.7), (30.0, -10.0)]:
        P.reset()
        fa = P.apply(alpha)
        assert P.apply(beta) == pytest.approx(fa - mu * (alpha - beta) ** 2 / 2, abs=1e-12)
    assert P.output_range == pytest.approx((-10.0, -10.0 + 2.0 * span))


def test_everett_matches_numerical_integration_of_density():
    P = Preisach.from_density(
        0.0, 10.0, lambda a, b: 1.0 + np.sin(a) * np.cos(b) ** 2 + 0.1 * a, n=7
    )

    def mu(a, b):
        i = min(int(a / P.h), P.n - 1)
        j = min(int(b / P.h), P.n - 1)
        return P.density[i, j]

    x = P.h * np.arange(P.n + 1)
    for alpha, beta in [(9.3, 0.4), (5.0, 4.2), (7.77, 1.0), (10.0, 0.0)]:
        # integrate mu over {beta <= b <= a <= alpha}, box by box between cell edges
        # (the density is constant in each box, so each quadrature is exact)
        val = 0.0
        edges = np.unique(np.clip(np.r_[beta, x, alpha], beta, alpha))
        for a0, a1 in zip(edges[:-1], edges[1:]):
            for b0, b1 in zip(edges[:-1], edges[1:]):
                if b0 >= a1:
                    continue
                m = mu(0.5 * (a0 + a1), 0.5 * (b0 + b1))
                val += dblquad(lambda b, a: m, a0, a1, lambda a: b0, lambda a: min(b1, a))[0]
        assert P.everett(alpha, beta) == pytest.approx(val, rel=1e-7)


def test_from_everett_reproduces_everett_on_nodes():
    E = lambda a, b: (a - b) ** 2 * (1 + 0.05 * (a + b))  # noqa: E731  (mixed derivative >= 0 here)
    P = Preisach.from_everett(0.0, 8.0, E, n=8)
    for a in range(9):
        for b in range(a + 1):
            assert P.everett(float(a), float(b)) == pytest.approx(E(a, b), abs=1e-10)


# ---------------------------------------------------------------- memory
def test_wiping_out_removes_dominated_extrema():
    P, Q = piezo(), piezo()
    y1 = P.apply([70.0, 20.0, 50.0, 30.0, 90.0])  # 90 wipes out (50, 30) and (70, 20)
    y2 = Q.apply([90.0])
    assert P.state == Q.state == (0.0, 90.0)
    assert y1[-1] == pytest.approx(y2[-1], abs=1e-12)
    P.apply([40.0, 60.0, 45.0, 10.0])  # 10 wipes out 45 and 40
    Q.apply([10.0])
    assert P.state == Q.state
    assert P.output == pytest.approx(Q.output, abs=1e-12)


def test_minor_loops_are_congruent():
    """Minor loops between the same extrema are congruent (Mayergoyz's second property)."""
    u = np.r_[np.linspace(40, 60, 21), np.linspace(60, 40, 21)[1:]]
    loops = []
    for history in ([100.0, 40.0], [70.0, 40.0], [90.0, 5.0, 65.0, 40.0]):
        P = piezo()
        P.apply(history)
        y = P.apply(u)
        loops.append(y - y[0])
    for other in loops[1:]:
        assert np.allclose(other, loops[0], atol=1e-10)
    # but the loops are not at the same height: the operator remembers
    P1, P2 = piezo(), piezo()
    assert abs(P1.apply([100.0, 40.0])[-1] - P2.apply([70.0, 40.0])[-1]) > 0.5


def test_rate_independence_and_peek_does_not_commit():
    P, Q = piezo(), piezo()
    seq = [10.0, 80.0, 35.0, 65.0, 50.0]
    y = P.apply(seq)
    yq = [Q.apply(v) for v in seq]
    assert np.allclose(y, yq)
    st0 = P.state
    cand = P.peek([0.0, 20.0, 50.0, 64.0, 100.0])
    assert P.state == st0
    assert np.all(np.diff(cand) >= 0)  # monotone from the current memory
    assert cand[2] == pytest.approx(P.output)
    R = P.copy()
    assert R.apply(20.0) == pytest.approx(cand[1])


def test_state_roundtrip_and_validation():
    P = piezo()
    P.apply([80.0, 10.0, 60.0, 30.0])
    s, out = P.state, P.output
    Q = piezo().set_state(s)
    assert Q.output == pytest.approx(out, abs=1e-12)
    with pytest.raises(ValueError, match="alternate"):
        piezo().set_state([0.0, 50.0, 60.0])
    with pytest.raises(ValueError, match="wiping-out"):
        piezo().set_state([0.0, 50.0, 10.0, 70.0])
    with pytest.raises(ValueError, match="u_min"):
        piezo().set_state([5.0, 50.0])


def test_interface_area_gives_output_for_uniform_density():
    """Uniform weight mu: output = offset + mu * area(S+) (shoelace on the staircase)."""
    P = Preisach.uniform(0.0, 10.0, n=5)
    mu = P.density[0, 0]
    for seq in (
        [7.0],
        [7.0, 2.0],
        [9.0, 1.0, 6.0],
        [9.0, 1.0, 6.0, 3.5],
        [10.0, 0.0, 8.0, 4.0, 7.0],
    ):
        P.reset()
        P.apply(seq)
        b, a = P.interface()
        xs = np.r_[P.u_min, b]
        ys = np.r_[P.u_min, a]
        area = 0.5 * abs(np.dot(xs, np.roll(ys, -1)) - np.dot(ys, np.roll(xs, -1)))
        assert P.output == pytest.approx(P.offset + mu * area, abs=1e-12)


def test_positive_saturation_reset():
    P = piezo()
    P.reset("positive")
    assert P.output == pytest.approx(P.output_range[1])
    assert P.apply(0.0) == pytest.approx(P.output_range[0])


# ---------------------------------------------------------------- CNIA
def test_fig2_inverse_linearizes_within_eps():
    """Xu & Meckl Fig. 2: H(H^-1(u_r)) = u_r within eps = 0.2 % of the input range."""
    P = piezo()
    t = np.linspace(0, 1, 3000)
    u_r = 50 + 45 * np.sin(2 * np.pi * 5 * t) * (1 - 0.7 * t)
    u_c = P.invert(u_r)
    H = piezo()
    y = H.apply(u_c)
    assert np.max(np.abs(y - u_r)) <= P.default_eps * (1 + 1e-9)
    # the uncompensated loop is far from linear
    assert np.max(np.abs(piezo().apply(u_r) - u_r)) > 10 * P.default_eps


history = st.lists(st.floats(-20.0, 120.0, allow_nan=False), min_size=0, max_size=12)


@settings(max_examples=400)
@given(history, st.floats(-30.0, 130.0, allow_nan=False), st.sampled_from([None, 0.01, 1.0]))
def test_cnia_stays_on_branch_and_in_bounds(hist, f_d, eps):
    P = piezo()
    P.apply(np.asarray(hist, dtype=float)) if hist else None
    u0, f0 = P.input, P.output
    lo, hi = P.peek(P.u_min), P.peek(P.u_max)
    tol = P.default_eps if eps is None else eps
    u = P.invert(f_d, eps=eps, commit=False)
    assert P.state[-1] == u0  # not committed
    assert P.u_min <= u <= P.u_max
    if f_d > f0 + tol:
        assert u >= u0  # ascending branch
    elif f_d < f0 - tol:
        assert u <= u0  # descending branch
    y = P.peek(u)
    if lo - tol <= f_d <= hi + tol:
        assert abs(y - f_d) <= tol * (1 + 1e-9)
    elif f_d > hi:
        assert u == P.u_max
    else:
        assert u == P.u_min
    # committing gives the same memory as applying u
    Q = P.copy()
    P.invert(f_d, eps=eps)
    Q.apply(u)
    assert P.state == Q.state


@settings(max_examples=100)
@given(st.lists(st.floats(0.0, 100.0, allow_nan=False), min_size=1, max_size=40))
def test_cnia_sequence_tracks_any_reachable_target(targets):
    P = piezo()
    u = P.invert(np.asarray(targets))
    assert np.all((u >= 0) & (u <= 100))
    y = piezo().apply(u)
    assert np.max(np.abs(y - np.asarray(targets))) <= P.default_eps * (1 + 1e-9)


# ---------------------------------------------------------------- FORC fit
def test_fit_recovers_density_on_same_grid():
    true = Preisach.piezo_like(0.0, 100.0, n=12, width=0.2)
    data = forc_experiment(true, 0.0, 100.0, n_curves=12, points_per_curve=12)
    fit = fit_preisach(data, n=12)
    assert np.allclose(fit.density, true.density, rtol=1e-6, atol=1e-9 * true.density.max())
    assert fit.offset == pytest.approx(true.offset, abs=1e-8)


def test_fit_on_coarser_grid_predicts_unseen_input():
    true = Preisach.from_density(
        0.0, 100.0, lambda a, b: np.exp(-(((a - b) / 20) ** 2)) * (1 + 0.01 * (a + b)), n=60
    )
    data = forc_experiment(true, 0.0, 100.0, n_curves=25, points_per_curve=25)
    fit = fit_preisach(data, n=25)
    rng = np.random.default_rng(1)
    u = np.cumsum(rng.normal(0, 8, 400)).clip(0, 100)
    y_true = true.apply(u)
    y_fit = fit.apply(u)
    span = true.output_range[1] - true.output_range[0]
    assert np.max(np.abs(y_fit - y_true)) < 0.01 * span


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: Preisach.uniform(1.0, 1.0), "u_max"),
        (lambda: Preisach.uniform(0.0, math.nan), "u_max"),
        (lambda: Preisach.uniform(0.0, 1.0, n=0), "n"),
        (lambda: Preisach(0.0, 1.0, -np.ones((3, 3))), "density"),
        (lambda: Preisach(0.0, 1.0, np.ones((3, 2))), "density"),
        (lambda: piezo().apply([1.0, math.inf]), "u"),
        (lambda: piezo().invert(math.nan), "f_d"),
        (lambda: piezo().invert(1.0, eps=0.0), "eps"),
        (lambda: piezo().invert([1.0, 2.0], commit=False), "commit"),
        (lambda: piezo().reset("sideways"), "state"),
        (lambda: Preisach.from_everett(0.0, 1.0, lambda a, b: -((a - b) ** 2), n=4), "everett"),
        (lambda: fit_preisach({"alpha": [1]}), "forc_data"),
        (lambda: fit_preisach(ForcData(np.ones(2), np.ones(3), np.ones(2), 0.0, 1.0)), "same"),
    ],
)
def test_bad_input_raises_naming_parameter(call, name):
    with pytest.raises(ValueError, match=name):
        call()


# ------------------------------------------------------------------------------ Preisach image (notebook 08)
def test_masked_density():
    P = Preisach.piezo_like(0.0, 100.0, n=12)
    m = P.masked_density()
    i, j = np.indices(m.shape)
    assert np.array_equal(m[i >= j], P.density[i >= j]) and np.all(np.isnan(m[i < j]))
    # the weight over the half plane (diagonal cells are half squares) is the output span
    area = np.where(i == j, 0.5, 1.0) * P.h**2
    assert np.nansum(m * area) == pytest.approx(P.everett(100.0, 0.0))
    assert np.nansum(m * area) == pytest.approx(P.output_range[1] - P.output_range[0])
