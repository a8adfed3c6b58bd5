"""Tests of jerklab.piezo (Xu & Meckl): model, robust time-optimal shaping, Table II, eq. 19,
closed loop. Results are checked against the paper's numbers and against independent
computations (python-control simulation, direct series sums, closed-form minimum-norm solutions).
"""

from __future__ import annotations

import math
import time

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jerklab import piezo as pz
from jerklab.piezo import (
    PZTModel,
    ScanSpec,
    closed_loop,
    energy_optimal_return,
    evaluate_cycle,
    pole_placement_gains,
    rampup_time_vs_scan_start,
    shape_cycle,
    shape_rampup,
    shape_return,
    table_ii,
    with_return,
)


@pytest.fixture(scope="module")
def table():
    t0 = time.perf_counter()
    rows = table_ii()
    return rows, time.perf_counter() - t0


def ct_sim(model, u, Ts=pz.TS):
    """Independent simulation: python-control's ZOH discretization of the tf and forced_response."""
    sysd = control.c2d(model.tf(), Ts, method="zoh")
    t = np.arange(u.size) * Ts
    return np.asarray(control.forced_response(sysd, T=t, U=u).outputs).ravel()


# ---------------------------------------------------------------------------- model
def test_model_dc_gain_poles_and_nmp_zeros():
    m = PZTModel()
    assert m.dc_gain() == pytest.approx(0.18759, abs=1e-5)  # docs/THEORY.md, Xu & Meckl eq. 1
    assert float(np.real(control.dcgain(m.tf()))) == pytest.approx(m.dc_gain(), rel=1e-9)
    sysd = m.zoh()
    assert sysd.dt == pytest.approx(2e-4)
    eig = np.linalg.eigvals(np.asarray(sysd.A))
    for z in m.mode_poles().values():
        assert np.min(np.abs(eig - z)) < 1e-9
    assert m.mode_poles()[1] == pytest.approx(0.9518 + 0.2987j, abs=1e-4)
    assert m.mode_poles()[2] == pytest.approx(0.4252 + 0.5349j, abs=1e-4)
    zeros = control.zeros(control.c2d(m.tf(), 2e-4, "zoh"))
    cz = zeros[np.abs(np.imag(zeros)) > 1e-6]  # the NMP pair (+ one sampling zero)
    assert np.allclose(np.sort_complex(cz), [-0.112 - 3.847j, -0.112 + 3.847j], atol=2e-3)
    assert np.all(np.abs(cz) > 1)
    assert np.any(np.real(control.zeros(m.tf())) > 0)  # NMP continuous zero


def test_perturbed_model_holds_dc_gain():
    m = PZTModel()
    p = m.perturbed(1.1)
    assert p.f_1 == pytest.approx(1.1 * m.f_1) and p.f_2 == m.f_2
    assert p.dc_gain() == pytest.approx(m.dc_gain(), rel=1e-12)
    q = m.perturbed(1.1, hold_dc_gain=False)
    assert q.dc_gain() == pytest.approx(m.dc_gain() / 1.21, rel=1e-12)


def test_own_simulation_matches_python_control():
    rng = np.random.default_rng(1)
    u = rng.normal(size=300)
    m = PZTModel().perturbed(1.07)
    assert np.allclose(pz.simulate(m, u), ct_sim(m, u), atol=1e-10)


# ---------------------------------------------------------------------------- z-transform rows
@settings(max_examples=60)
@given(
    N=st.integers(1, 12),
    j=st.integers(0, 2),
    r=st.floats(1.05, 1.6),
    ang=st.floats(0.1, 2.5),
    a=st.floats(-5, 5),
    seed=st.integers(0, 1000),
)
def test_rampup_rows_equal_direct_series(N, j, r, ang, a, seed):
    """For |z| > 1 the series converges: compare the closed form with a direct (truncated) sum."""
    z = r * np.exp(1j * ang)
    u = np.random.default_rng(seed).normal(size=N)
    w = 0.7
    E, f = pz.robustness_rows_rampup(N, {1: z}, {1: j}, w)
    K = 4000
    k = np.arange(K)
    cmd = np.concatenate([u, a + w * np.arange(K - N)])
    dj = np.ones(K)
    for i in range(j):
        dj = dj * (k + i)
    direct = np.sum(cmd * (-1) ** j * dj * z ** (-k - j))
    row_re, row_im = E[2 * j], E[2 * j + 1]
    # undo the row scaling: E x - f is the condition scaled by 1/|row|; compare via ratios
    x = np.concatenate([u, [a]])
    val_re = row_re @ x - f[2 * j]
    val_im = row_im @ x - f[2 * j + 1]
    # rebuild the unscaled rows
    raw = np.concatenate([pz._dz_power(np.arange(N), z, j), [pz._dz_step_tail(N, z, j)]])
    s_re, s_im = np.linalg.norm(np.real(raw)), np.linalg.norm(np.imag(raw))
    got = val_re * s_re + 1j * val_im * s_im
    assert abs(got - direct) <= 1e-8 * max(1.0, abs(direct))


@settings(max_examples=40)
@given(
    Nr=st.integers(1, 10),
    j=st.integers(0, 2),
    r=st.floats(1.05, 1.6),
    ang=st.floats(0.1, 2.5),
    b=st.floats(-5, 5),
    seed=st.integers(0, 1000),
)
def test_return_rows_equal_direct_series(Nr, j, r, ang, b, seed):
    z = r * np.exp(1j * ang)
    u = np.random.default_rng(seed).normal(size=Nr)
    w = 0.9
    E, f = pz.robustness_rows_return(Nr, {1: z}, {1: j}, w)
    K = 4000
    k = np.arange(K)
    d = np.concatenate([u, np.zeros(K - Nr)]) - (b + w * k)
    dj = np.ones(K)
    for i in range(j):
        dj = dj * (k + i)
    direct = np.sum(d * (-1) ** j * dj * z ** (-k - j))
    pk = pz._dz_power(np.arange(Nr), z, j)
    raw = np.concatenate([pk, [-pk.sum() - pz._dz_step_tail(Nr, z, j)]])
    s_re, s_im = np.linalg.norm(np.real(raw)), np.linalg.norm(np.imag(raw))
    x = np.concatenate([u, [b]])
    got = (E[2 * j] @ x - f[2 * j]) * s_re + 1j * (E[2 * j + 1] @ x - f[2 * j + 1]) * s_im
    assert abs(got - direct) <= 1e-8 * max(1.0, abs(direct))


# ---------------------------------------------------------------------------- shaping
@pytest.mark.parametrize("orders", [0, 1, 2])
def test_rampup_reaches_exact_ramp_and_is_minimal(orders):
    m, spec = PZTModel(), ScanSpec()
    r = shape_rampup(m, spec, orders)
    assert np.abs(r.u).max() <= spec.F_max + 1e-7
    u = np.concatenate([r.u, r.a + r.w * np.arange(200)])
    y = ct_sim(m, u)  # independent simulation
    assert y[r.N] == pytest.approx(r.scan_start, abs=1e-8)
    assert r.scan_start >= -1e-9  # min_scan_start = 0
    v = np.diff(y[r.N :]) / spec.Ts
    assert np.abs(v - spec.scan_velocity).max() <= spec.velocity_tolerance
    # one sample shorter is infeasible (bisection found the minimum)
    w, G1, beta = pz._ramp_constants(m, spec)
    assert (
        pz._rampup_lp(r.N - 1, m, spec, pz._normalize_orders(orders), m.mode_poles(), w, G1, beta)
        is None
    )


def test_rampup_robustness_order_scales_residual():
    """m-th order robust: the perturbed vibration after the ramp-up scales like δ^(m+1)."""
    m, spec = PZTModel(), ScanSpec()
    for order in (0, 1, 2):
        r = shape_rampup(m, spec, {1: order, 2: order})
        u = np.concatenate([r.u, r.a + r.w * np.arange(400)])
        errs = []
        for d in (0.005, 0.01):
            p = m.perturbed(1 + d, modes=(1, 2))
            e = ct_sim(p, u) - ct_sim(m, u)
            # the vibration part: remove the steady offset (lag change) of the ramp
            tail = e[r.N + 100 :]
            errs.append(
                np.ptp(
                    tail
                    - np.polyval(np.polyfit(np.arange(tail.size), tail, 1), np.arange(tail.size))
                )
            )
        ratio = errs[1] / errs[0]
        assert ratio == pytest.approx(2 ** (order + 1), rel=0.25), (order, ratio)


def test_return_ends_at_rest():
    m, spec = PZTModel(), ScanSpec()
    for orders in (0, 1, 2):
        b = 20.0
        ret = shape_return(b, m, spec, orders)
        w, G1, beta = pz._ramp_constants(m, spec)
        # start the plant on the steady ramp: a 3 s ramp history lets the start-up transient
        # decay (mode 1: e^{-ζω t} ~ 1e-16), then apply the return
        K = 15000
        pre = b + w * np.arange(-K, 0)
        u = np.concatenate([pre, ret.u, np.zeros(300)])
        y = ct_sim(m, u)
        assert np.abs(y[K + ret.N :]).max() < 1e-6
        assert np.abs(ret.u).max() <= spec.F_max + 1e-7


def test_outer_search_matches_joint_lp():
    """Fig. 4's search over y(T) never beats the LP with y(T) free, and attains it there."""
    m, spec = PZTModel(), ScanSpec()
    best = shape_rampup(m, spec, 1)
    grid = np.linspace(0.0, 1.2, 13)
    times = rampup_time_vs_scan_start(grid, 1, m, spec)
    assert np.nanmin(times) >= best.N * spec.Ts - 1e-12
    at_opt = rampup_time_vs_scan_start([best.scan_start], 1, m, spec)[0]
    assert at_opt == pytest.approx(best.N * spec.Ts)


# ---------------------------------------------------------------------------- Table II
def test_table_ii_against_paper(table):
    rows, elapsed = table
    assert elapsed < 10.0
    for name, r in rows.items():
        tc, em, er = r["paper"]
        assert abs(r["cycle_time"] - tc) <= 1e-3 + 1e-12, name
        assert em / 2 <= r["e_m"] <= 2 * em, name
        assert er / 2 <= r["e_r"] <= 2 * er, name
        assert r["velocity_error"] <= 0.1, name
    order = ["non-robust", "1st-order robust", "combined-robust", "2nd-order robust"]
    times = [rows[n]["cycle_time"] for n in order]
    assert all(a < b for a, b in zip(times, times[1:]))
    assert (
        rows["2nd-order robust"]["e_m"]
        < rows["1st-order robust"]["e_m"]
        < rows["non-robust"]["e_m"]
    )
    assert rows["combined-robust"]["e_r"] < rows["1st-order robust"]["e_r"]


def test_table_ii_values_by_independent_simulation(table):
    rows, _ = table
    m = PZTModel()
    p = m.perturbed(1.1)
    for name, r in rows.items():
        c = r["cycle"]
        u = c.command()
        y, yp = ct_sim(m, u), ct_sim(p, u)
        sl = c.scan_slice
        n_end = c.N + c.S + c.N_r
        assert np.abs(yp - y)[sl].max() == pytest.approx(r["e_m"], rel=1e-6)
        assert np.abs(yp - y)[n_end:].max() == pytest.approx(r["e_r"], rel=1e-6)
        # the cycle: rest -> scan of 6 µm at v_d -> back to rest at the start
        assert y[sl][-1] - y[sl][0] == pytest.approx(6.0, abs=1e-6)
        assert np.abs(np.diff(y[sl]) / 2e-4 - 1e3).max() <= 0.1
        assert np.abs(y[n_end:]).max() < 1e-6 and abs(u[n_end:]).max() == 0
        assert np.abs(u).max() <= 38.0 + 1e-7


def test_lsq_solver_finds_the_same_horizons():
    """Eq. 6 literally (bounded least squares) and the feasibility LP agree on every horizon."""
    for t_o, r_o in [(0, 0), (1, 2)]:
        a = shape_cycle(t_o, r_o, solver="lp")
        b = shape_cycle(t_o, r_o, solver="lsq")
        assert (a.N, a.N_r) == (b.N, b.N_r)
    with pytest.raises(ValueError, match="solver"):
        shape_cycle(0, 0, solver="cvx")


def test_scan_tolerance_e_allow():
    """Eq. 4 as inequalities on the scan: held on simulation, and a looser bound never costs time."""
    exact = shape_cycle(1, 2)
    spec = ScanSpec(e_allow=1e-3)
    c = shape_cycle(1, 2, spec=spec)
    assert c.cycle_time == pytest.approx(exact.cycle_time)  # 0.1 µm/s leaves nothing to gain
    y = ct_sim(PZTModel(), c.command())
    line = c.scan_start + 0.2 * np.arange(c.S + 1)
    assert np.abs(y[c.scan_slice] - line).max() <= 1e-3 + 1e-9
    assert np.abs(np.diff(y[c.scan_slice]) / 2e-4 - 1e3).max() <= 0.1 + 1e-6
    assert np.abs(y[c.N + c.S + c.N_r :]).max() < 1e-8  # whole-cycle rest condition
    loose = shape_cycle(0, 0, spec=ScanSpec(e_allow=0.3, velocity_tolerance=300.0))
    assert loose.cycle_time <= shape_cycle(0, 0).cycle_time
    with pytest.raises(ValueError, match="solver"):
        shape_cycle(0, 0, spec=spec, solver="lsq")
    with pytest.raises(ValueError, match="e_allow"):
        ScanSpec(e_allow=-1.0)


def test_format_table_ii(table):
    s = pz.format_table_ii(table[0])
    assert "non-robust" in s and "10.4" in s and len(s.splitlines()) == 5


# ---------------------------------------------------------------------------- eq. 19
def test_energy_optimal_return_rest_and_min_norm():
    m, spec = PZTModel(), ScanSpec(F_max=200.0)
    b = 10.0
    k_r = 40
    ret = energy_optimal_return(b, k_r, m, spec, orders=1)
    w, _, _ = pz._ramp_constants(m, spec)
    E, f = pz.robustness_rows_return(k_r, m.mode_poles(), pz._normalize_orders(1), w)
    Eu, fu = E[:, :-1], f - E[:, -1] * b
    # bounds inactive at this F_max: the QP optimum is the closed-form minimum-norm solution
    closed = np.linalg.pinv(Eu) @ fu
    assert np.abs(closed).max() < spec.F_max
    assert np.allclose(ret.u, closed, atol=1e-5 * np.abs(closed).max())
    K = 15000  # 3 s of ramp: start-up transient gone
    pre = b + w * np.arange(-K, 0)
    y = ct_sim(m, np.concatenate([pre, ret.u, np.zeros(200)]))
    assert np.abs(y[K + k_r :]).max() < 1e-6


@pytest.mark.parametrize("objective", ["input", "increment"])
def test_energy_optimal_tradeoff(objective):
    c = shape_cycle(1, 1)
    b = c.a + c.S * c.w
    costs = []
    for k_r in (c.N_r + 5, c.N_r + 15):
        ret = energy_optimal_return(b, k_r, orders=1, objective=objective)
        assert np.abs(ret.u).max() <= c.spec.F_max + 1e-7
        c2 = with_return(c, ret)
        ev = evaluate_cycle(c2)
        assert np.abs(ev.y_nominal[c2.N + c2.S + c2.N_r :]).max() < 1e-6
        x = ret.u if objective == "input" else np.diff(np.concatenate([[b], ret.u, [0.0]]))
        costs.append(x @ x)
    assert costs[1] <= costs[0] + 1e-6  # more steps never cost more energy
    with pytest.raises(RuntimeError):
        energy_optimal_return(b, c.N_r - 1, orders=1)


def test_increment_objective_is_smoother_than_time_optimal():
    c = shape_cycle(1, 1)
    b = c.a + c.S * c.w
    smooth = energy_optimal_return(b, c.N_r + 18, orders=1, objective="increment")
    y0 = evaluate_cycle(c).y_nominal[c.N + c.S :]
    c2 = with_return(c, smooth)
    y1 = evaluate_cycle(c2).y_nominal[c2.N + c2.S :]

    def osc(y):  # upward motion during the return
        return np.clip(np.diff(y), 0, None).sum()

    assert osc(y1) < 0.5 * osc(y0)
    assert y1.min() > -0.05


# ---------------------------------------------------------------------------- closed loop
def test_pole_placement_places_poles():
    g = pole_placement_gains()
    m = PZTModel()
    sysd = m.zoh()
    A, B, C = (np.asarray(x) for x in (sysd.A, sysd.B, sysd.C))
    n = A.shape[0]
    Aa = np.block([[A, np.zeros((n, 1))], [C, np.ones((1, 1))]])
    Ba = np.vstack([B, [[0.0]]])
    K = np.concatenate([g.K, [g.k_i]])[None, :]
    assert np.allclose(
        np.sort_complex(np.linalg.eigvals(Aa - Ba @ K)), np.sort_complex(g.poles), atol=1e-6
    )
    assert np.allclose(
        np.sort_complex(np.linalg.eigvals(A - np.outer(g.L, C))),
        np.sort_complex(g.observer_poles),
        atol=1e-6,
    )


def test_closed_loop_nominal_is_exact_and_perturbed_is_close_to_paper():
    c = shape_cycle(1, 2)
    ideal = closed_loop(c, perturbed=c.model, cancellation_error=0.0)
    assert np.abs(ideal.y - ideal.y_desired).max() < 1e-8
    assert np.allclose(ideal.u_r, ideal.u_ff, atol=1e-8)
    r = closed_loop(c)
    assert 0.07 / 2 <= r.scan_error <= 0.07 * 2  # paper: 0.07 µm in the scan region
    assert r.scan_error < r.open_loop_scan_error  # feedback reduces the cancellation error
    # after the cycle the integrator pulls the error down
    assert np.abs(r.y - r.y_desired)[-10:].max() < np.abs(r.y - r.y_desired).max()


def test_closed_loop_with_preisach_compensation():
    hyst = pytest.importorskip("jerklab.hysteresis")
    P = hyst.Preisach.piezo_like(-45.0, 45.0, n=30)
    c = shape_cycle(1, 2)
    r = closed_loop(c, hysteresis=P, cancellation_error=0.0, perturbed=c.model)
    # inversion within eps (0.2 % of the 90 V range) -> the linear input follows u_r to 0.18 V
    assert np.abs(r.f - r.u_r).max() <= P.default_eps + 1e-9
    assert r.scan_error < 0.05
    r2 = closed_loop(c, hysteresis=P)
    assert r2.scan_error <= 0.15


# ---------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "kwargs",
    [
        dict(F_max=-1.0),
        dict(F_max=float("nan")),
        dict(Ts=0.0),
        dict(velocity_tolerance=float("inf")),
        dict(scan_length="6"),
    ],
)
def test_scan_spec_rejects_bad_input(kwargs):
    with pytest.raises(ValueError):
        ScanSpec(**kwargs)


def test_bad_arguments_raise_named_errors():
    with pytest.raises(ValueError, match="K"):
        PZTModel(K=-1.0)
    with pytest.raises(ValueError, match="zeta_1"):
        PZTModel(zeta_1=float("nan"))
    with pytest.raises(ValueError, match="orders"):
        shape_rampup(orders={3: 1})
    with pytest.raises(ValueError, match="orders"):
        shape_rampup(orders={1: -1})
    with pytest.raises(ValueError, match="F_max"):
        table_ii(F_max=0.0)
    with pytest.raises(ValueError, match="modes"):
        PZTModel().perturbed(1.1, modes=(3,))
    with pytest.raises(ValueError, match="k_r"):
        energy_optimal_return(1.0, 0)
    with pytest.raises(ValueError, match="cancellation_model"):
        closed_loop(shape_cycle(0, 0), cancellation_model="random")
    with pytest.raises(ValueError, match="scan_samples|whole number"):
        ScanSpec(scan_length=6.1).scan_samples
    with pytest.raises(RuntimeError):
        shape_rampup(spec=ScanSpec(F_max=16.0))  # the scan ramp alone needs 31 V
    assert math.isfinite(ScanSpec().scan_samples)
