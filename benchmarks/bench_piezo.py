"""Benchmark of jerklab.piezo (Xu & Meckl command shaping) against peers in the same process.

1. One horizon of the ramp-up problem: our LP feasibility problem (HiGHS via scipy.optimize.linprog)
   vs the paper's literal eq. 6, a bound-constrained least-squares problem at fixed y(T)
   (scipy.optimize.lsq_linear, BVLS), for the same horizon.
2. The minimum horizon by bisection with each of them (and whether they agree).
3. Simulation of a cycle command: pz.simulate (lfilter on the ZOH pulse transfer function) vs
   python-control's forced_response.
4. The whole Table II (four cycles shaped and evaluated), with either solver.
"""

from __future__ import annotations

import time

import control
import numpy as np
from scipy.optimize import lsq_linear

from benchmarks._record import table as record_table
from jerklab import piezo as pz


def _best_time(fn, repeat=7):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def _lsq_feasible(N, a, model, spec, orders, w, tol=1e-9):
    """Eq. 6 literally: min |terminal-condition residual| s.t. |u| <= F_max, y(T) fixed by a."""
    E, f = pz.robustness_rows_rampup(N, model.mode_poles(spec.Ts), orders, w)
    rhs = f - E[:, -1] * a
    res = lsq_linear(E[:, :-1], rhs, bounds=(-spec.F_max, spec.F_max), method="bvls")
    return res.x if np.abs(E[:, :-1] @ res.x - rhs).max() <= tol else None


def main():
    model, spec = pz.PZTModel(), pz.ScanSpec()
    orders = pz._normalize_orders(1)
    w, G1, beta = pz._ramp_constants(model, spec)
    poles = model.mode_poles(spec.Ts)
    ru = pz.shape_rampup(model, spec, orders)
    N, a = ru.N, ru.a

    def horizon(how):
        return lambda: pz._rampup_lp(N, model, spec, orders, poles, w, G1, beta, ru.scan_start, how)

    def rampup(solver):
        return lambda: pz.shape_rampup(model, spec, orders, solver=solver)

    rows = []
    t_nn, t_lp, t_ls = (
        _best_time(horizon("nnls")),
        _best_time(horizon("lp")),
        _best_time(lambda: _lsq_feasible(N, a, model, spec, orders, w)),
    )
    rows.append(("one horizon, 1st-order ramp-up", f"N={N}", t_nn, t_lp, t_ls))
    n = {s_: rampup(s_)().N for s_ in ("lp", "highs", "lsq")}
    rows.append(
        (
            "min ramp-up horizon (bisection)",
            "N " + "/".join(str(v) for v in n.values()),
            _best_time(rampup("lp"), 3),
            _best_time(rampup("highs"), 3),
            _best_time(rampup("lsq"), 3),
        )
    )
    times, tables = {}, {}
    for solver in ("lp", "highs", "lsq", "lp", "highs", "lsq"):  # twice, interleaved: keep the best
        t0 = time.perf_counter()
        tables[solver] = pz.table_ii(solver=solver)
        times[solver] = min(times.get(solver, np.inf), time.perf_counter() - t0)
    same_lp = all(
        np.array_equal(tables["lp"][k]["cycle"].u, tables["highs"][k]["cycle"].u)
        for k in tables["lp"]
    )
    same_t = all(
        tables["lp"][k]["cycle_time"] == tables["lsq"][k]["cycle_time"] for k in tables["lp"]
    )
    rows.append(
        (
            "whole Table II",
            f"LP commands identical: {same_lp}; BVLS cycle times equal: {same_t}",
            times["lp"],
            times["highs"],
            times["lsq"],
        )
    )
    record_table(
        "Xu & Meckl shaping solvers (ms): default (NNLS screen + one LP per search) against an LP at every "
        "horizon (HiGHS, the former default) and lsq_linear BVLS (eq. 6)",
        ["case", "detail", "default ms", "HiGHS LP ms", "BVLS ms", "LP/default", "BVLS/default"],
        [(c, d, 1e3 * x, 1e3 * y, 1e3 * z, y / x, z / x) for c, d, x, y, z in rows],
        note="one horizon: the default's screen alone (the LP runs once per search, at the minimum)",
    )

    cyc = pz.shape_cycle(1, 2, model, spec)
    u = cyc.command()
    sysd = control.c2d(model.tf(), spec.Ts, "zoh")
    t = np.arange(u.size) * spec.Ts
    y_own = pz.simulate(model, u, spec.Ts)
    y_ct = np.asarray(control.forced_response(sysd, T=t, U=u).outputs).ravel()
    diff = np.abs(y_own - y_ct).max()
    ta, tb = (
        _best_time(lambda: pz.simulate(model, u, spec.Ts)),
        _best_time(lambda: control.forced_response(sysd, T=t, U=u)),
    )
    record_table(
        "Xu & Meckl cycle simulation against python-control",
        ["case", "detail", "pz.simulate ms", "forced_response ms", "peer/ours"],
        [
            (
                "simulate a cycle command",
                f"{u.size} samples, max diff {diff:.1e} µm",
                1e3 * ta,
                1e3 * tb,
                tb / ta,
            )
        ],
    )
    table = tables["lp"]
    n_lps = sum(r["cycle"].lp_count for r in table.values())
    print(
        f"\nwhole Table II: {times['lp']:.2f} s for {n_lps} feasibility problems (acceptance < 10 s)"
    )
    print(pz.format_table_ii(table))


if __name__ == "__main__":
    main()
