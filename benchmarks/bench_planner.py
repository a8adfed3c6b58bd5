"""Planner speed and move time, against Ruckig in the same process.

``python -m benchmarks planner`` prints six tables:

1. microseconds per plan of each jerklab planner next to Ruckig's Python API (setting the inputs and
   ``calculate``); the ratio column is jerklab / Ruckig (target <= 1.0), the median of the ratios
   of rounds in which every planner plans the same short chunk of moves, one after the other in
   a shuffled order (:func:`_interleaved`: robust to a load that changes during the run);
2. the same for moves from a moving start (``initial_velocity``, ``initial_accel``,
   ``final_velocity``; Ruckig with ``current_velocity``, ``current_acceleration``,
   ``target_velocity``), target <= 1.0;
3. the batch planner (``plan_batch``) in plans per second on 1e6 moves (target >= 2e7), and
   ``plan_batch_any_state`` on 2e5 moves from moving starts;
4. the move time of the published sine-jerk planner and of the optimal sine planner divided by
   Ruckig's time-optimal duration, over a grid of limits (median, max);
5. from a moving start: the S-curve's duration / Ruckig's (max |ratio - 1|) and the optimal sine's
   duration / the S-curve's at jerk 2J/pi, with and without an initial acceleration
   (docs/THEORY.md, "Any start state").
"""

from __future__ import annotations

import itertools
import math
import statistics
import time

import numpy as np

from benchmarks._record import table
from jerklab.planner import (
    KINDS,
    plan_batch,
    plan_batch_any_state,
    plan_scurve,
    plan_sine_jerk,
    plan_sine_jerk_optimal,
    plan_trapezoid,
)

try:
    import ruckig
except ImportError:  # pragma: no cover - ruckig is in environment.txt
    ruckig = None


def _ruckig_planner():
    otg, inp, traj = ruckig.Ruckig(1), ruckig.InputParameter(1), ruckig.Trajectory(1)
    inp.current_position = [0.0]

    def plan(distance, max_jerk, max_accel, max_velocity):
        inp.target_position = [distance]
        inp.max_velocity = [max_velocity]
        inp.max_acceleration = [max_accel]
        inp.max_jerk = [max_jerk]
        otg.calculate(inp, traj)
        return traj.duration

    return plan


def _cases(n, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-3, 3, n)
    J = 10.0 ** rng.uniform(1, 5, n)
    A = 10.0 ** rng.uniform(0, 3, n)
    V = 10.0 ** rng.uniform(-1, 2, n)
    return [tuple(float(x) for x in c) for c in zip(d, J, A, V)]


def _interleaved(planners, cases, repeats, chunk=250, seed=0):
    """Time every planner on the same cases, interleaved: per-planner µs per plan and ratio to
    ``"ruckig..."``.

    ``cases`` are cut into chunks of ``chunk`` moves; in each round (``repeats`` passes over the
    chunks) every planner plans one chunk, the planners in a shuffled order, timed by the
    thread's CPU clock (a time slice given to another process is not counted).  Returns
    ``{name: (median µs per plan over the rounds, median over the rounds of the ratio to the
    reference planner in the same round)}`` -- a paired comparison, so that a load that comes
    and goes during the run moves both sides of each ratio together.
    """
    import random

    ref = next((k for k in planners if k.startswith("ruckig")), None)
    for f in planners.values():  # compile / load the cached solver outside the clock
        f(*cases[0])
    chunks = [cases[i : i + chunk] for i in range(0, len(cases), chunk)]
    rng = random.Random(seed)
    rounds = {k: [] for k in planners}
    clock = time.thread_time if hasattr(time, "thread_time") else time.perf_counter
    for _ in range(repeats):
        for ch in chunks:
            order = list(planners.items())
            rng.shuffle(order)
            for name, f in order:
                t0 = clock()
                for c in ch:
                    f(*c)
                rounds[name].append((clock() - t0) / len(ch) * 1e6)
    out = {}
    for name, us in rounds.items():
        ratio = statistics.median([u / r for u, r in zip(us, rounds[ref])]) if ref else math.nan
        out[name] = (statistics.median(us), ratio)
    return out


def time_per_plan(repeats=7, n=2000):
    """Median over the interleaved rounds (:func:`_interleaved`) of the time per plan (µs) of each
    planner on the same cases."""
    return {k: v[0] for k, v in time_per_plan_and_ratio(repeats, n).items()}


def time_per_plan_and_ratio(repeats=7, n=2000):
    """:func:`time_per_plan` and the median ratio to Ruckig (``{name: (µs, ratio)}``)."""
    cases = _cases(n)
    planners = {
        "plan_sine_jerk": plan_sine_jerk,
        "plan_sine_jerk_optimal": plan_sine_jerk_optimal,
        "plan_scurve": plan_scurve,
        "plan_trapezoid": lambda d, j, a, v: plan_trapezoid(d, a, v),
    }
    if ruckig is not None:
        planners["ruckig"] = _ruckig_planner()
    return _interleaved(planners, cases, repeats)


def _moving_cases(n, seed=0):
    """Non-rest moves inside Ruckig's numeric range: starts inside the limits and 20 % above them."""
    rng = np.random.default_rng(seed)
    d = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-3, 2, n)
    J = 10.0 ** rng.uniform(1, 4, n)
    A = 10.0 ** rng.uniform(0, 2, n)
    V = 10.0 ** rng.uniform(-1, 1, n)
    over = np.where(rng.random(n) < 0.2, 1.5, 1.0)
    v0 = rng.uniform(-1, 1, n) * V * over
    a0 = rng.uniform(-1, 1, n) * A * over
    vf = rng.uniform(-1, 1, n) * V
    return [tuple(float(x) for x in c) for c in zip(d, J, A, V, v0, a0, vf)]


def _ruckig_moving():
    otg, inp, traj = ruckig.Ruckig(1), ruckig.InputParameter(1), ruckig.Trajectory(1)
    inp.current_position = [0.0]

    def plan(distance, max_jerk, max_accel, max_velocity, v0, a0, vf):
        inp.target_position = [distance]
        inp.current_velocity = [v0]
        inp.current_acceleration = [a0]
        inp.target_velocity = [vf]
        inp.max_velocity = [max_velocity]
        inp.max_acceleration = [max_accel]
        inp.max_jerk = [max_jerk]
        otg.calculate(inp, traj)
        return traj.duration

    return plan


def time_per_moving_plan(repeats=7, n=2000):
    """Median over the interleaved rounds (:func:`_interleaved`) of the time per non-rest plan (µs)."""
    return {k: v[0] for k, v in time_per_moving_plan_and_ratio(repeats, n).items()}


def time_per_moving_plan_and_ratio(repeats=7, n=2000):
    """:func:`time_per_moving_plan` and the median ratio to Ruckig (``{name: (µs, ratio)}``)."""
    cases = _moving_cases(n)
    planners = {
        "plan_scurve (moving start)": lambda d, j, a, v, v0, a0, vf: plan_scurve(
            d, j, a, v, initial_velocity=v0, initial_accel=a0, final_velocity=vf
        ),
        "plan_sine_jerk_optimal (moving start)": lambda d, j, a, v, v0, a0, vf: (
            plan_sine_jerk_optimal(
                d, j, a, v, initial_velocity=v0, initial_accel=a0, final_velocity=vf
            )
        ),
    }
    if ruckig is not None:
        planners["ruckig (moving start)"] = _ruckig_moving()
    return _interleaved(planners, cases, repeats)


def batch_rate_moving(n=200_000, repeats=3):
    """plan_batch_any_state in plans per second (moving starts, 20 % above the limits)."""
    cols = np.array(_moving_cases(n, seed=2)).T
    out = {}
    for kind in ("scurve", "sine_jerk_optimal"):
        plan_batch_any_state(kind, *cols[:, :10])  # compile / load outside the clock
        best = math.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            plan_batch_any_state(kind, *cols)
            best = min(best, time.perf_counter() - t0)
        out[kind] = n / best
    return out


def moving_duration_ratios(n=3000):
    """S-curve vs Ruckig, and optimal sine vs the S-curve at jerk 2J/pi, from moving starts."""
    rk = _ruckig_moving()
    sc, sine0, sine1 = [], [], []
    for d, J, A, V, v0, a0, vf in _moving_cases(n, seed=1):
        sc.append(
            plan_scurve(
                d, J, A, V, initial_velocity=v0, initial_accel=a0, final_velocity=vf
            ).duration
            / rk(d, J, A, V, v0, a0, vf)
        )
        if abs(v0) > V or abs(a0) > A:
            continue
        for acc, out in ((0.0, sine0), (a0, sine1)):
            s = plan_sine_jerk_optimal(
                d, J, A, V, initial_velocity=v0, initial_accel=acc, final_velocity=vf
            )
            q = plan_scurve(
                d, 2 * J / math.pi, A, V, initial_velocity=v0, initial_accel=acc, final_velocity=vf
            )
            out.append(s.duration / q.duration)
    return sc, sine0, sine1


def batch_rate(n=1_000_000, repeats=3):
    rng = np.random.default_rng(1)
    d = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-3, 3, n)
    J = 10.0 ** rng.uniform(1, 5, n)
    A = 10.0 ** rng.uniform(0, 3, n)
    V = 10.0 ** rng.uniform(-1, 2, n)
    out = {}
    for kind in KINDS:
        best = math.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            plan_batch(kind, d, J, A, V)
            best = min(best, time.perf_counter() - t0)
        out[kind] = n / best
    return out


#: 48 limit sets: distance x jerk x acceleration x velocity (rad, rad/s^3, rad/s^2, rad/s)
GRID = list(
    itertools.product(
        [0.01, 0.1, 1.0, 10 * math.pi, 100.0, 1000.0], [1e3, 2e4], [10.0, 300.0], [10.0, 100.0]
    )
)


def move_time_ratios(grid=GRID):
    """Duration / Ruckig's duration on the same limits, for the two sine planners."""
    rk = _ruckig_planner()
    pub, opt, opt_eq = [], [], []
    for d, J, E, W in grid:
        r = rk(d, J, E, W)
        pub.append(plan_sine_jerk(d, J, E, W).duration / r)
        o = plan_sine_jerk_optimal(d, J, E, W).duration
        opt.append(o / r)
        opt_eq.append(o / rk(d, 2 * J / math.pi, E, W))
    return {
        "published sine (plan_sine_jerk)": pub,
        "optimal sine (plan_sine_jerk_optimal)": opt,
        "optimal sine vs Ruckig at jerk 2J/pi": opt_eq,
    }


def main():
    have_ref = ruckig is not None
    us = time_per_plan_and_ratio()
    table(
        "Time per plan (µs; 2000 random moves in chunks of 250, 7 rounds, planners interleaved in a "
        "shuffled order, thread CPU time; medians over the 56 rounds, x Ruckig = median of the "
        "per-round ratios)",
        ["planner", "µs/plan", "x Ruckig"],
        [(name, v, r if have_ref else "-") for name, (v, r) in us.items()],
    )
    us = time_per_moving_plan_and_ratio()
    table(
        "Time per non-rest plan (µs; 2000 random moves from a moving start, 20 % above the limits; "
        "rounds and medians as above)",
        ["planner", "µs/plan", "x Ruckig"],
        [(name, v, r if have_ref else "-") for name, (v, r) in us.items()],
    )
    table(
        "Batch planner (plan_batch, 1e6 random moves, best of 3)",
        ["kind", "plans/s", "target"],
        [(kind, rate, 2e7) for kind, rate in batch_rate().items()],
    )
    table(
        "Batch planner from moving starts (plan_batch_any_state, 2e5 random moves, best of 3)",
        ["kind", "plans/s"],
        list(batch_rate_moving().items()),
    )
    if ruckig is None:
        print("\n(ruckig not installed: no move-time comparison)")
        return
    table(
        f"Move time / Ruckig's time-optimal duration over {len(GRID)} limit sets "
        "(distance 0.01..1000, J 1e3|2e4, E 10|300, Omega 10|100)",
        ["planner", "median", "max"],
        [(name, statistics.median(r), max(r)) for name, r in move_time_ratios().items()],
    )
    sc, sine0, sine1 = moving_duration_ratios()
    table(
        "From a moving start (3000 random moves): duration ratios",
        ["ratio", "min", "median", "max"],
        [
            ("plan_scurve / Ruckig", min(sc), statistics.median(sc), max(sc)),
            (
                "optimal sine / S-curve at 2J/pi, initial_accel = 0",
                min(sine0),
                statistics.median(sine0),
                max(sine0),
            ),
            (
                "optimal sine / S-curve at 2J/pi, initial_accel != 0",
                min(sine1),
                statistics.median(sine1),
                max(sine1),
            ),
        ],
    )


if __name__ == "__main__":
    main()
