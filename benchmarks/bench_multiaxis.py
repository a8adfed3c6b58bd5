"""Several axes (``jerklab.multiaxis``) against Ruckig's multi-DoF synchronization, same process.

``python -m benchmarks multiaxis`` prints two tables:

1. microseconds per synchronized plan of 2, 3 and 6 axes (``plan_multi_axis``, S-curve) next to
   Ruckig's Python API (setting the inputs and ``calculate``) with ``Synchronization.Time`` /
   ``Phase``, interleaved and repeated, the median of the repeats; the ratio column is
   jerklab / Ruckig;
2. the move time: phase (straight line) over time synchronization, and how often Ruckig's phase
   synchronization leaves the straight line (it then falls back to time synchronization), over the
   same random moves.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from benchmarks._record import table
from jerklab.multiaxis import plan_multi_axis

try:
    import ruckig
except ImportError:  # pragma: no cover - ruckig is in environment.txt
    ruckig = None


def _cases(n_axes, n, seed=0):
    rng = np.random.default_rng(seed + n_axes)
    out = []
    for _ in range(n):
        d = rng.choice([-1.0, 1.0], n_axes) * 10.0 ** rng.uniform(-2, 2, n_axes)
        lims = [tuple(float(x) for x in 10.0 ** rng.uniform(-1, 3, 3)) for _ in range(n_axes)]
        out.append(([float(x) for x in d], lims))
    return out


def _ruckig_planner(n_axes, sync):
    otg, inp, traj = ruckig.Ruckig(n_axes), ruckig.InputParameter(n_axes), ruckig.Trajectory(n_axes)
    inp.current_position = [0.0] * n_axes
    inp.synchronization = (
        ruckig.Synchronization.Phase if sync == "phase" else ruckig.Synchronization.Time
    )

    def plan(d, lims):
        inp.target_position = d
        inp.max_jerk = [L[0] for L in lims]
        inp.max_acceleration = [L[1] for L in lims]
        inp.max_velocity = [L[2] for L in lims]
        otg.calculate(inp, traj)
        return traj

    return plan


def time_per_plan(n_axes, repeats=7, n=500):
    """Median over ``repeats`` of the mean time per plan (µs), each planner on the same cases."""
    cases = _cases(n_axes, n)
    planners = {
        f"jerklab {s}": (lambda s: lambda d, L: plan_multi_axis(d, L, sync=s))(s)
        for s in ("time", "phase")
    }
    if ruckig is not None:
        for s in ("time", "phase"):
            planners[f"ruckig {s}"] = _ruckig_planner(n_axes, s)
    runs = {k: [] for k in planners}
    clock = time.perf_counter
    for _ in range(repeats):
        for name, f in planners.items():  # interleaved: load changes hit every planner
            t0 = clock()
            for d, L in cases:
                f(d, L)
            runs[name].append((clock() - t0) / n * 1e6)
    return {k: statistics.median(v) for k, v in runs.items()}


def move_times(n_axes, n=500):
    """Phase/time duration ratios, and the share of moves where Ruckig's phase sync is off the line."""
    ratios, off = [], 0
    rk = _ruckig_planner(n_axes, "phase") if ruckig is not None else None
    for d, L in _cases(n_axes, n, seed=100):
        ratios.append(
            plan_multi_axis(d, L, sync="phase").duration
            / plan_multi_axis(d, L, sync="time").duration
        )
        if rk is not None:
            traj = rk(d, L)
            x = np.array([traj.at_time(t)[0] for t in np.linspace(0.0, traj.duration, 11)]).T
            u = np.asarray(d) / np.linalg.norm(d)
            off += np.abs(x - np.outer(u, u @ x)).max() > 1e-9 * np.linalg.norm(d)
    return ratios, (off / n if rk is not None else None)


def main():
    rows = []
    for n_axes in (2, 3, 6):
        us = time_per_plan(n_axes)
        for s in ("time", "phase"):
            ref = us.get(f"ruckig {s}")
            rows.append(
                (
                    f"{n_axes} axes, {s} sync",
                    us[f"jerklab {s}"],
                    ref if ref else "-",
                    us[f"jerklab {s}"] / ref if ref else "-",
                )
            )
    table(
        "Time per synchronized plan (µs, median of 7 interleaved runs of 500 random moves, S-curve)",
        ["case", "jerklab µs", "Ruckig µs", "x Ruckig"],
        rows,
    )
    rows = []
    for n_axes in (2, 3, 6):
        r, off = move_times(n_axes)
        rows.append((f"{n_axes} axes", statistics.median(r), max(r), "-" if off is None else off))
    table(
        "Move time, phase (straight line) / time sync, 500 random moves; share of them where "
        "Ruckig's phase sync leaves the line",
        ["case", "median", "max", "Ruckig off the line"],
        rows,
    )


if __name__ == "__main__":
    main()
