"""Benchmark of jerklab.piezo (Xu & Meckl command shaping) against peers in the same process.

1. One horizon of the ramp-up problem: our LP feasibility problem (HiGHS via scipy.optimize.linprog)
   vs the paper's literal eq. 6, a bound-constrained least-squares problem at fixed y(T)
   (scipy.optimize.lsq_linear, BVLS), for the same horizon.
2. The minimum horizon by bisection with each of them (and whether they agree).
3. Simulation of a cycle command: pz.simulate (lfilter on the ZOH pulse transfer function) vs python-control's forced_response.
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
    rows = []

    t_lp = _best_time(lambda: pz._rampup_lp(N, model, spec, orders, poles, w, G1, beta, ru.scan_start))
    t_ls = _best_time(lambda: _lsq_feasible(N, a, model, spec, orders, w))
    rows.append(("one horizon, 1st-order ramp-up", f"N={N}", "HiGHS LP", t_lp, "lsq_linear BVLS (eq. 6)", t_ls))

    def bisect_lp():
        return pz._bisect(lambda n: pz._rampup_lp(n, model, spec, orders, poles, w, G1, beta, ru.scan_start), 0, 200)

    def bisect_ls():
        return pz._bisect(lambda n: _lsq_feasible(n, a, model, spec, orders, w), 0, 200)

    n_lp, n_ls = bisect_lp()[0], bisect_ls()[0]
    rows.append(("min horizon by bisection", f"LP N={n_lp}, LSQ N={n_ls}", "HiGHS LP", _best_time(bisect_lp, 3),
                 "lsq_linear BVLS", _best_time(bisect_ls, 3)))

    cyc = pz.shape_cycle(1, 2, model, spec)
    u = cyc.command()
    sysd = control.c2d(model.tf(), spec.Ts, "zoh")
    t = np.arange(u.size) * spec.Ts
    y_own = pz.simulate(model, u, spec.Ts)
    y_ct = np.asarray(control.forced_response(sysd, T=t, U=u).outputs).ravel()
    diff = np.abs(y_own - y_ct).max()
    rows.append(("simulate a cycle command", f"{u.size} samples, max diff {diff:.1e} µm", "pz.simulate (lfilter)",
                 _best_time(lambda: pz.simulate(model, u, spec.Ts)), "control.forced_response",
                 _best_time(lambda: control.forced_response(sysd, T=t, U=u))))

    t0 = time.perf_counter()
    table = pz.table_ii()
    t_table = time.perf_counter() - t0
    t0 = time.perf_counter()
    table_lsq = pz.table_ii(solver="lsq")
    t_table_lsq = time.perf_counter() - t0
    same = all(table[k]["cycle_time"] == table_lsq[k]["cycle_time"] for k in table)
    rows.append(("whole Table II", f"same cycle times: {same}", "HiGHS LP", t_table, "lsq_linear BVLS", t_table_lsq))
    n_lps = sum(r["cycle"].lp_count for r in table.values())

    record_table("Xu & Meckl shaping: jerklab against peers in the same process",
                 ["case", "detail", "ours", "ours ms", "peer", "peer ms", "peer/ours"],
                 [(case, det, a_name, ta * 1e3, b_name, tb * 1e3, tb / ta) for case, det, a_name, ta, b_name, tb in rows],
                 note=f"whole Table II: {t_table:.2f} s for {n_lps} LPs ({t_table / n_lps * 1e3:.1f} ms per LP, "
                      f"shaping + evaluation; acceptance < 10 s)")
    print(pz.format_table_ii(table))


if __name__ == "__main__":
    main()
