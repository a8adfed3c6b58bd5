"""Several axes (jerklab.multiaxis): time and phase synchronization, and Yang's x–y stand in Verilog.

Checks against something independent of ``jerklab.multiaxis``'s algebra:

* the common end time and every limit, on dense closed-form samples of each axis;
* the continuity of each stretched axis, by integrating its sampled jerk/acceleration/velocity
  (trapezoid rule) and comparing with the closed form;
* a time-synchronized axis is the *time-optimal* plan of the existing single-axis planner for its
  own jerk and acceleration limits and its lowered peak velocity (``plan_scurve`` etc. recompute the
  duration);
* phase synchronization: every axis on the straight line ``x_i = d_i s(t)`` to 1e-9;
* the x–y stand: two ``YangSCurve`` generators (Python model) and their Verilog (Icarus) from one
  plan, pulse edge for pulse edge.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import cases
from hypothesis import example, given, settings
from hypothesis import strategies as st

from jerklab.fpga import (
    PAPER,
    YANG_TICK_SEARCH,
    HardwareLimitError,
    YangSCurve,
    simulate_verilog_xy,
    yang_axes,
)
from jerklab.multiaxis import PLANNERS, plan_multi_axis, stretch_to_duration
from jerklab.planner import plan_scurve, plan_sine_jerk_optimal, plan_trapezoid

RTOL = 1e-9
SINGLE = {
    "scurve": lambda d, J, A, V: plan_scurve(d, J, A, V),
    "sine_jerk_optimal": lambda d, J, A, V: plan_sine_jerk_optimal(d, J, A, V),
    "trapezoid": lambda d, J, A, V: plan_trapezoid(d, A, V),
}


def dense_times(plan, m=4001):
    """Uniform samples plus both sides of every phase boundary of every axis."""
    T = plan.duration
    t = [np.linspace(0.0, T, m)]
    for p in plan.axes:
        b = np.cumsum((0.0,) + tuple(p.phase_times))
        for eps in (-1e-12, 0.0, 1e-12):
            t.append(np.clip(b + eps * max(T, 1e-300), 0.0, T))
    return np.unique(np.concatenate(t))


def check_limits(plan, t=None):
    t = dense_times(plan) if t is None else t
    s = plan.sample(t)
    for i, (J, A, V) in enumerate(plan.limits):
        p = plan.axes[i]
        tol = 1.0 + RTOL
        assert np.abs(s.velocity[i]).max() <= V * tol, (i, "velocity")
        assert np.abs(s.accel[i]).max() <= A * tol, (i, "accel")
        assert p.peak_velocity <= V * tol and p.peak_accel <= A * tol
        if plan.planner != "trapezoid":
            assert np.abs(s.jerk[i]).max() <= J * tol, (i, "jerk")
            assert p.peak_jerk <= J * tol


def check_ends(plan):
    T = plan.duration
    for i, p in enumerate(plan.axes):
        assert p.duration == pytest.approx(T, rel=RTOL, abs=1e-300), i
        assert math.fsum(p.phase_times) == pytest.approx(T, rel=RTOL, abs=1e-300)
        end = p.sample(T)
        d = plan.distances[i]
        assert float(end.position) == d
        assert float(end.velocity) == 0.0 and float(end.accel) == 0.0
        start = p.sample(0.0)
        assert float(start.position) == 0.0 and float(start.velocity) == 0.0
    s = plan.sample(np.array([0.0, T, 2 * T + 1]))
    assert np.array_equal(s.position[:, 1], plan.distances) and np.array_equal(
        s.position[:, 2], plan.distances
    )
    assert np.all(s.position[:, 0] == 0.0)


def check_integrates(plan, m=20001):
    """Position and velocity of each axis equal the integrals of its velocity and acceleration."""
    T = plan.duration
    if T == 0.0:
        return
    t = np.linspace(0.0, T, m)
    dt = t[1] - t[0]
    for i, p in enumerate(plan.axes):
        s = p.sample(t)
        scale = max(abs(plan.distances[i]), 1e-300)
        pos = np.concatenate([[0.0], np.cumsum(0.5 * (s.velocity[1:] + s.velocity[:-1]) * dt)])
        vel = np.concatenate([[0.0], np.cumsum(0.5 * (s.accel[1:] + s.accel[:-1]) * dt)])
        # trapezoid-rule error ~ dt^2 T max|x'''|/12, bounded by the jerk/accel limits
        J, A, V = plan.limits[i]
        jmax = A / (dt) if plan.planner == "trapezoid" else J
        assert np.abs(pos - s.position).max() <= 1e-6 * scale + dt * dt * T * (jmax + A) / 6, i
        assert np.abs(vel - s.velocity).max() <= 1e-6 * max(p.peak_velocity, 1e-300) + dt * (
            A + jmax * dt
        ), i


# --------------------------------------------------------------------------- examples
LIMS = [(80000.0, 40000.0, 20000.0), (80000.0, 40000.0, 20000.0)]


@pytest.mark.parametrize("planner", PLANNERS)
@pytest.mark.parametrize("sync", ["time", "phase"])
def test_two_axes_end_together_within_limits(planner, sync):
    plan = plan_multi_axis([40000.0, -15000.0], LIMS, sync=sync, planner=planner)
    check_ends(plan)
    check_limits(plan)
    check_integrates(plan)
    assert len(plan) == 2 and plan.sync == sync and plan.planner == planner
    if sync == "time":
        assert plan.duration == max(plan.min_durations)
    else:
        assert plan.duration >= max(plan.min_durations) * (1 - 1e-12)


def test_time_sync_slowest_axis_keeps_its_optimal_plan():
    plan = plan_multi_axis([3.0, 1.0, 0.2], [(50.0, 10.0, 2.0), (5.0, 1.0, 0.5), (1.0, 1.0, 1.0)])
    k = int(np.argmax(plan.min_durations))
    opt = plan_scurve(*(plan.distances[k],), *plan.limits[k])
    assert plan.axes[k].phase_times == opt.phase_times
    others = [i for i in range(3) if i != k]
    assert all(plan.axes[i].peak_velocity < plan.limits[i][2] for i in others)


def test_phase_sync_is_the_fastest_straight_line():
    """The normalized limits are min limit_i/|d_i|: scaling any of them up breaks some axis's limit."""
    d = np.array([4.0, -1.0, 2.0])
    lims = [(40.0, 8.0, 3.0), (30.0, 1.0, 2.0), (5.0, 6.0, 0.7)]
    plan = plan_multi_axis(d, lims, sync="phase")
    Jn, An, Vn = plan.normalized_limits
    assert Jn == min(L[0] / abs(x) for L, x in zip(lims, d))
    assert An == min(L[1] / abs(x) for L, x in zip(lims, d))
    assert Vn == min(L[2] / abs(x) for L, x in zip(lims, d))
    # the same straight line with every normalized limit 1 % larger: the path is faster, and one
    # axis at least exceeds one of its limits
    faster = plan_scurve(1.0, 1.01 * Jn, 1.01 * An, 1.01 * Vn)
    assert faster.duration < plan.duration
    over = [
        abs(x) * faster.peak_jerk > L[0] * (1 + 1e-12)
        or abs(x) * faster.peak_accel > L[1] * (1 + 1e-12)
        or abs(x) * faster.peak_velocity > L[2] * (1 + 1e-12)
        for L, x in zip(lims, d)
    ]
    assert any(over)


def test_standstill_axes():
    plan = plan_multi_axis([0.0, 2.0, 0.0], [(1, 1, 1)] * 3, sync="time")
    assert plan.axes[0].duration == plan.duration == plan.axes[1].duration
    s = plan.sample(np.linspace(0, plan.duration, 101))
    assert np.all(s.position[0] == 0.0) and np.all(s.velocity[2] == 0.0)
    for sync in ("time", "phase"):
        zero = plan_multi_axis([0.0, -0.0], [(1, 1, 1)] * 2, sync=sync)
        assert zero.duration == 0.0 and all(p.duration == 0.0 for p in zero.axes)
        assert np.all(zero.sample([0.0, 1.0]).position == 0.0)


def test_dict_limits_and_array_limits():
    a = plan_multi_axis(
        [1.0, 2.0], [dict(max_jerk=5, max_accel=2, max_velocity=1)] * 2, sync="phase"
    )
    b = plan_multi_axis([1.0, 2.0], np.array([[5.0, 2.0, 1.0]] * 2), sync="phase")
    assert a.duration == b.duration
    c = plan_multi_axis(
        [1.0, 2.0], [dict(max_accel=2, max_velocity=1), (None, 3, 1)], planner="trapezoid"
    )
    assert c.axes[0].kind == "trapezoid" and c.to_dict()["axes"][1]["kind"] == "trapezoid"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(sync="space"), "sync"),
        (dict(sync=None), "sync"),
        (dict(planner="sine_jerk"), "planner.*sine_jerk_optimal"),
        (dict(planner="bang"), "planner"),
        (dict(distances=[1.0, math.nan]), "distances"),
        (dict(distances=[1.0, math.inf]), "distances"),
        (dict(distances=[]), "distances"),
        (dict(distances=[[1.0, 2.0]]), "distances"),
        (dict(distances="12"), "distances"),
        (dict(limits_per_axis=[(1, 1, 1)]), "limits_per_axis"),
        (dict(limits_per_axis=[(1, 1, 1), (1, -1, 1)]), r"limits_per_axis\[1\]\.max_accel"),
        (dict(limits_per_axis=[(1, 1, 1), (math.nan, 1, 1)]), r"limits_per_axis\[1\]\.max_jerk"),
        (dict(limits_per_axis=[(1, 1, 0.0), (1, 1, 1)]), r"limits_per_axis\[0\]\.max_velocity"),
        (dict(limits_per_axis=[(1, 1), (1, 1, 1)]), r"limits_per_axis\[0\]"),
        (
            dict(limits_per_axis=[{"max_jerk": 1, "max_accel": 1, "max_vel": 1}, (1, 1, 1)]),
            "unknown keys",
        ),
        (dict(limits_per_axis=[{"max_accel": 1, "max_velocity": 1}, (1, 1, 1)]), "max_jerk"),
        (dict(limits_per_axis=[(None, 1, 1), (1, 1, 1)]), r"limits_per_axis\[0\]\.max_jerk"),
        (dict(limits_per_axis=[("1", 1, 1), (1, 1, 1)]), r"limits_per_axis\[0\]\.max_jerk"),
        (
            dict(limits_per_axis={"max_jerk": 1, "max_accel": 1, "max_velocity": 1}),
            "limits_per_axis",
        ),
        (dict(limits_per_axis=5.0), "limits_per_axis"),
        # plain float tuples take a fast path: it must hand every bad value to the named checks
        (
            dict(limits_per_axis=[(1.0, 1.0, 1.0), (1.0, math.nan, 1.0)]),
            r"limits_per_axis\[1\]\.max_accel",
        ),
        (
            dict(limits_per_axis=[(1.0, 1.0, math.inf), (1.0, 1.0, 1.0)]),
            r"limits_per_axis\[0\]\.max_velocity",
        ),
        (
            dict(limits_per_axis=[(-1.0, 1.0, 1.0), (1.0, 1.0, 1.0)]),
            r"limits_per_axis\[0\]\.max_jerk",
        ),
        (
            dict(limits_per_axis=[(None, 1.0, 1.0), (1.0, 1.0, 1.0)]),
            r"limits_per_axis\[0\]\.max_jerk",
        ),
        (dict(distances=[1.0, -math.inf]), "distances"),
    ],
)
def test_bad_input_names_the_parameter(kwargs, match):
    args = dict(distances=[1.0, 2.0], limits_per_axis=[(1, 1, 1), (1, 1, 1)])
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        plan_multi_axis(**args)


def test_stretch_to_duration_rejects_a_shorter_duration():
    p = plan_scurve(1.0, 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="shorter than the time-optimal"):
        stretch_to_duration(p, 0.5 * p.duration)
    with pytest.raises(ValueError, match="duration"):
        stretch_to_duration(p, math.nan)
    assert stretch_to_duration(p, p.duration) is p


@pytest.mark.parametrize("planner", PLANNERS)
@pytest.mark.parametrize("factor", [1.0 + 1e-15, 1.0 + 1e-9, 1.0001, 1.3, 3.0, 1e3, 1e6])
@pytest.mark.parametrize(
    "d, J, A, V",
    [
        (1.0, 1.0, 1.0, 1.0),
        (100.0, 10.0, 5.0, 1.0),
        (0.01, 1e4, 1.0, 10.0),
        (2.0, 1.0, 10.0, 0.3),
        (1.0, 1.0, 1.0, 0.5),
    ],
)  # last: V = d A / ... edge of a cruise
def test_stretch_is_time_optimal_for_a_lowered_velocity(planner, factor, d, J, A, V):
    """Independent check: the existing planner, given the stretched axis's peak velocity as its
    velocity limit, plans the same duration (1e-9) -- the axis is 'no faster than its own limits
    allow' and uses them fully except the velocity."""
    opt = SINGLE[planner](d, J, A, V)
    T = opt.duration * factor
    p = stretch_to_duration(opt, T)
    assert p.duration == pytest.approx(T, rel=1e-15)
    assert float(p.sample(T).position) == d
    assert p.peak_velocity <= V * (1 + 1e-12) and p.peak_accel <= A * (1 + 1e-12)
    if planner != "trapezoid":
        assert p.peak_jerk <= J * (1 + 1e-12)
    again = SINGLE[planner](d, J, A, p.peak_velocity)
    assert again.duration == pytest.approx(T, rel=RTOL)


# --------------------------------------------------------------------------- properties
SIGN = st.sampled_from([1.0, -1.0])
AXIS = st.tuples(
    st.one_of(st.just(0.0), st.floats(-4, 4)),
    SIGN,  # log10 |d| (0.0 flag below)
    st.floats(-2, 5),
    st.floats(-2, 4),
    st.floats(-2, 3),  # log10 J, A, V
    st.booleans(),
)  # zero-distance axis


def build(axes):
    d, lims = [], []
    for ed, sgn, ej, ea, ev, zero in axes:
        d.append(0.0 if zero else sgn * 10.0**ed)
        lims.append((10.0**ej, 10.0**ea, 10.0**ev))
    return d, lims


@cases("costly", deadline=None)
@given(axes=st.lists(AXIS, min_size=1, max_size=5), planner=st.sampled_from(PLANNERS))
@example(
    axes=[(0.0, 1.0, 0.0, 0.0, 0.0, False), (-4.0, -1.0, 5.0, 4.0, 3.0, False)], planner="scurve"
)
@example(
    axes=[
        (4.0, 1.0, -2.0, -2.0, -2.0, False),
        (-4.0, 1.0, 5.0, 4.0, 3.0, False),
        (0.0, 1.0, 0.0, 0.0, 0.0, True),
    ],
    planner="sine_jerk_optimal",
)
def test_time_sync_property(axes, planner):
    """Random distances and limits, zero axes, one axis dominating, negative distances."""
    d, lims = build(axes)
    plan = plan_multi_axis(d, lims, sync="time", planner=planner)
    assert plan.duration == max(plan.min_durations)
    check_ends(plan)
    check_limits(plan, np.linspace(0.0, plan.duration, 801))
    for i, p in enumerate(plan.axes):
        if d[i] != 0.0:  # the single-axis planner agrees that the axis is time-optimal for its v
            J, A, _ = lims[i]
            assert SINGLE[planner](d[i], J, A, p.peak_velocity).duration == pytest.approx(
                plan.duration, rel=RTOL
            )


@settings(deadline=None)
@given(axes=st.lists(AXIS, min_size=1, max_size=5), planner=st.sampled_from(PLANNERS))
@example(
    axes=[(0.0, 1.0, 0.0, 0.0, 0.0, False), (-4.0, -1.0, 5.0, 4.0, 3.0, False)], planner="trapezoid"
)
def test_phase_sync_property(axes, planner):
    """Every axis on the straight line x_i = d_i s(t) to 1e-9 at many sample times."""
    d, lims = build(axes)
    plan = plan_multi_axis(d, lims, sync="phase", planner=planner)
    check_ends(plan)
    check_limits(plan, np.linspace(0.0, plan.duration, 801))
    assert plan.duration >= max(plan.min_durations) * (1 - 1e-12)
    if plan.path is None:
        assert all(x == 0.0 for x in d)
        return
    t = np.sort(np.random.default_rng(len(d)).uniform(0.0, plan.duration, 997))
    s = plan.path.sample(t).position  # the normalized profile, 0 -> 1
    assert np.all(np.diff(s) >= -1e-15) and 0.0 <= s.min() and s.max() <= 1.0
    dd = np.asarray(d)
    for x in (plan.sample(t).position, np.stack([p.sample(t).position for p in plan.axes])):
        assert np.all(np.abs(x - dd[:, None] * s) <= RTOL * np.abs(dd)[:, None]), "off the line"
    # the cross product with the direction: the distance from the line, relative to the move
    unit = dd / np.linalg.norm(dd)
    x = np.stack([p.sample(t).position for p in plan.axes])
    off = x - unit[:, None] * (unit @ x)
    assert np.abs(off).max() <= RTOL * np.linalg.norm(dd)


@cases("costly", deadline=None)
@given(
    axes=st.lists(AXIS, min_size=2, max_size=3),
    planner=st.sampled_from(PLANNERS),
    sync=st.sampled_from(["time", "phase"]),
)
def test_continuity_property(axes, planner, sync):
    d, lims = build(axes)
    plan = plan_multi_axis(d, lims, sync=sync, planner=planner)
    check_integrates(plan)


def test_seeded_batch_time_and_phase():
    """A seeded batch of 2000 random 3-axis moves (a cheap sweep next to the hypothesis tests)."""
    rng = np.random.default_rng(21)
    for k in range(2000):
        n = 3
        d = np.where(
            rng.random(n) < 0.15, 0.0, rng.choice([-1, 1], n) * 10 ** rng.uniform(-3, 3, n)
        )
        lims = [tuple(10 ** rng.uniform(-1, 3, 3)) for _ in range(n)]
        planner = PLANNERS[k % 3]
        for sync in ("time", "phase"):
            plan = plan_multi_axis(d, lims, sync=sync, planner=planner)
            T = plan.duration
            for i, p in enumerate(plan.axes):
                assert abs(p.duration - T) <= RTOL * T
                assert float(p.sample(T).position) == d[i]
                J, A, V = lims[i]
                assert p.peak_velocity <= V * (1 + RTOL) and p.peak_accel <= A * (1 + RTOL)
                if planner != "trapezoid":
                    assert p.peak_jerk <= J * (1 + RTOL)


# --------------------------------------------------------------------------- Yang's x–y stand

#: the paper's axis limits: V = 20 mm/s, T = 1 s -> A = 2V/T, J = 4V/T^2 (µm, s)
YANG_LIMITS = (4 * 20000.0, 2 * 20000.0, 20000.0)
XY = [40000.0, -15000.0]  # µm: x is the paper's move (Yang §3), y a shorter one backwards


def move_error_bound(axes, i):
    """Derived bound on |k * pulses - |d_i||: f = v // k drops < 1 pulse per second of the move,
    the integer V is within half a pulse, the start counts drop their ramp (< 1 pulse here) and the
    latched divider may leave one period unfinished: k (duration/1 s + 2)."""
    g = axes.generators[i]
    duration = (g.end_tick) * g.refresh_period
    return g.step_um * (duration + 2.0)


def end_window(axes):
    """The longest pulse period of any axis (its cycle at the start speed), in clocks."""
    return max(int(g.speed_table().cycle.max()) for g in axes.generators if g is not None)


@pytest.mark.parametrize("sync", ["phase", "time"])
def test_yang_axes_mapping(sync):
    plan = plan_multi_axis(XY, [YANG_LIMITS] * 2, sync=sync)
    axes = yang_axes(plan, clock_hz=100_000)
    gx, gy = axes.generators
    assert axes.directions == (1, -1)
    # the x axis is the paper's generator (Yang eq. 7, Yang eq. 8), clock scaled
    assert gx.verilog_defines() == YangSCurve(**{**PAPER, "clock_hz": 100_000}).verilog_defines()
    for g, lim, d in zip(axes.generators, plan.limits, XY):
        J, A, V = lim
        T = g.accel_time
        assert g.end_tick == axes.end_tick  # every generator stops at tick M
        assert g.max_velocity <= V and 2 * g.max_velocity / T <= A * (1 + 1e-12)
        assert 4 * g.max_velocity / T**2 <= J * (1 + 1e-12)
        assert abs(g.distance_um - abs(d)) <= g.step_um / 2 + 1e-9  # the ideal generator move
        assert g.speed(g.start_count) >= g.step_um  # >= 1 pulse/s at the start
    if sync == "phase":
        assert (gx.half_counts, gx.cruise_counts) == (gy.half_counts, gy.cruise_counts)
        assert gy.max_velocity / gx.max_velocity == pytest.approx(15000 / 40000, rel=1e-4)


@pytest.mark.parametrize("sync", ["phase", "time"])
def test_xy_stand_model_reaches_target_together(sync):
    plan = plan_multi_axis(XY, [YANG_LIMITS] * 2, sync=sync)
    axes = yang_axes(plan, clock_hz=100_000)
    trains = axes.pulses()
    final = axes.positions(1e3)
    W = end_window(axes)
    for i, (tr, d) in enumerate(zip(trains, XY)):
        assert abs(final[i] - d) <= move_error_bound(axes, i), (i, final[i], d)
        assert len(tr.rise) == len(tr.fall)  # every pulse completed
        assert abs(int(tr.fall[-1]) - axes.end_posedge) <= W  # ends in the common window
    t = np.linspace(0.0, 3.5, 3501)
    pos = axes.positions(t)
    assert np.all(np.diff(pos[0]) >= 0) and np.all(np.diff(pos[1]) <= 0)


def test_xy_path_phase_sync_is_straight_time_sync_is_not():
    """On the pulse counts: phase sync stays within the pulses' own lag of the line, time sync
    (y arrives at the same time but on its own velocity profile) bends away by many pulses."""
    t = np.linspace(0.0, 3.2, 6401)
    d = np.asarray(XY)
    u = d / np.linalg.norm(d)
    off, lag = {}, {}
    for sync in ("phase", "time"):
        plan = plan_multi_axis(XY, [YANG_LIMITS] * 2, sync=sync)
        axes = yang_axes(plan, clock_hz=100_000)
        pos = axes.positions(t)
        off[sync] = np.linalg.norm(pos - np.outer(u, u @ pos), axis=0).max()
        lag[sync] = np.abs(pos - plan.sample(t).position).max()
        # the planned path is exactly on the line (phase) or not (time)
    assert off["phase"] <= lag["phase"]
    assert off["time"] > 5 * off["phase"]


@pytest.mark.parametrize("sync", ["phase", "time"])
@pytest.mark.verilog
def test_xy_stand_verilog_matches_model_on_both_axes(sync, tmp_path):
    """Two scurve_gen + pulse_divider pairs in one Icarus run (firmware/fpga/tb_xy.v), driven by
    the parameters of one synchronized plan: every tick and every edge of both axes equal the
    Python model; the pulse counts reach the target and both axes end in the same window."""
    from conftest import require_tool

    require_tool("iverilog", "vvp")
    plan = plan_multi_axis(XY, [YANG_LIMITS] * 2, sync=sync)
    axes = yang_axes(plan, clock_hz=100_000)
    runs = simulate_verilog_xy(axes, workdir=str(tmp_path))
    trains = axes.pulses()
    for run, g, tr in zip(runs, axes.generators, trains):
        tab = g.speed_table()
        for f in ("m", "n", "speed", "frequency", "cycle"):
            assert np.array_equal(getattr(run.table, f), getattr(tab, f)), f
        assert len(run.rise) > 500
        assert np.array_equal(run.rise, tr.rise) and np.array_equal(run.fall, tr.fall)
    final = [s * g.step_um * len(r.rise) for s, g, r in zip(axes.directions, axes.generators, runs)]
    for i in range(2):
        assert abs(final[i] - XY[i]) <= move_error_bound(axes, i)
        assert abs(int(runs[i].fall[-1]) - axes.end_posedge) <= end_window(axes)


def test_yang_axes_refuses_what_the_generator_cannot_run():
    with pytest.raises(ValueError, match="planner"):
        yang_axes(plan_multi_axis(XY, [YANG_LIMITS] * 2, planner="trapezoid"))
    plateau = plan_multi_axis(XY, [(80000.0, 10000.0, 20000.0)] * 2, sync="phase")
    with pytest.raises(ValueError, match="plateau"):
        yang_axes(plateau)
    with pytest.raises(ValueError, match="plan"):
        yang_axes("xy")
    with pytest.raises(ValueError, match="no axis"):
        yang_axes(plan_multi_axis([0.0, 0.0], [YANG_LIMITS] * 2))
    with pytest.raises(HardwareLimitError):
        yang_axes(plan_multi_axis([40000.0, 1.0], [YANG_LIMITS] * 2, sync="phase"))  # V < 1 µm/s
    with pytest.raises(ValueError, match="two moving axes"):
        simulate_verilog_xy(yang_axes(plan_multi_axis([1e4, 0.0], [YANG_LIMITS] * 2)))


@settings(deadline=None)
@given(
    dx=st.floats(500.0, 80000.0),
    dy=st.floats(500.0, 80000.0),
    sx=SIGN,
    sy=SIGN,
    sync=st.sampled_from(["phase", "time"]),
    vy=st.floats(0.3, 1.0),
)
def test_yang_axes_property(dx, dy, sx, sy, sync, vy):
    """Random x–y moves (y with its own, lower limits): the generators stop on the same tick,
    keep each axis's limits and cover the distance within half a pulse (ideal integer move)."""
    lims = [YANG_LIMITS, tuple(vy * x for x in YANG_LIMITS)]
    plan = plan_multi_axis([sx * dx, sy * dy], lims, sync=sync)
    try:
        axes = yang_axes(plan, clock_hz=1_000_000)
    except HardwareLimitError as exc:
        # a speed below the 1 µm/s resolution, or no integer speed within the bounded search
        # fits the multiplier (the stated limit, naming what to change)
        assert "1 µm/s" in str(exc) or "use another refresh_period" in str(exc), str(exc)
        return
    for g, (J, A, V), d in zip(axes.generators, lims, plan.distances):
        assert g.end_tick == axes.end_tick
        th = g.half_counts * g.refresh_period  # T / 2
        assert g.max_velocity <= V * (1 + 1e-12) and g.max_velocity / th <= A * (1 + 1e-12)
        assert g.max_velocity / th**2 <= J * (1 + 1e-12)
        assert abs(g.distance_um - abs(d)) <= g.step_um / 2 + 1e-9
    assert axes.end_tick * PAPER["refresh_period"] >= plan.duration * (1 - 1e-12)
    # rounded up to whole counts (4 N <= 4 (tj/tc + 1)), then at most YANG_TICK_SEARCH ticks later
    tc = PAPER["refresh_period"]
    assert axes.end_tick * tc <= plan.duration + (4 + YANG_TICK_SEARCH) * tc
    if sync == "phase":
        assert len({(g.half_counts, g.cruise_counts) for g in axes.generators}) == 1


@settings(deadline=None)
@given(
    ed=st.floats(-6, 6),
    ej=st.floats(-3, 6),
    ea=st.floats(-3, 6),
    ev=st.floats(-3, 6),
    ef=st.one_of(st.floats(-16, 3), st.just(-math.inf)),
    planner=st.sampled_from(PLANNERS),
)
@example(
    ed=math.log10(474.7185969920547),
    ej=math.log10(0.0012307999088097205),
    ea=math.log10(0.015660035597204983),
    ev=math.log10(0.34173348751316734),
    ef=math.log10(3.046619e-10),
    planner="sine_jerk_optimal",
)  # every a + tv a tie
def test_stretch_property(ed, ej, ea, ev, ef, planner):
    """The stretched axis lasts T to the last bit, ends exactly at d, keeps every limit to 1e-12
    (a few ulp), and the single-axis planner, given its peak velocity, plans the same duration."""
    d, J, A, V = 10.0**ed, 10.0**ej, 10.0**ea, 10.0**ev
    opt = SINGLE[planner](d, J, A, V)
    T = opt.duration * (1.0 + 10.0**ef)
    p = stretch_to_duration(opt, T)
    assert p.duration == T
    assert float(p.sample(T).position) == d and float(p.sample(T).velocity) == 0.0
    assert p.peak_velocity <= V * (1 + 1e-12) and p.peak_accel <= A * (1 + 1e-12)
    if planner != "trapezoid":
        assert p.peak_jerk <= J * (1 + 1e-12)
    assert SINGLE[planner](d, J, A, p.peak_velocity).duration == pytest.approx(T, rel=1e-12)


# --------------------------------------------------------------------------- against Ruckig
def ruckig_multi(d, lims, sync):
    ruckig = pytest.importorskip("ruckig")
    n = len(d)
    otg, inp, traj = ruckig.Ruckig(n), ruckig.InputParameter(n), ruckig.Trajectory(n)
    inp.current_position, inp.target_position = [0.0] * n, [float(x) for x in d]
    inp.max_jerk = [L[0] for L in lims]
    inp.max_acceleration = [L[1] for L in lims]
    inp.max_velocity = [L[2] for L in lims]
    inp.synchronization = (
        ruckig.Synchronization.Phase if sync == "phase" else ruckig.Synchronization.Time
    )
    assert otg.calculate(inp, traj) == ruckig.Result.Working
    return traj


def random_moves(seed, count):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n = int(rng.integers(2, 5))
        d = np.where(
            rng.random(n) < 0.15, 0.0, rng.choice([-1, 1], n) * 10 ** rng.uniform(-2, 2, n)
        )
        if not d.any():
            continue
        yield d, [tuple(10 ** rng.uniform(-1, 3, 3)) for _ in range(n)]


def test_time_sync_equals_ruckig():
    """Ruckig's time synchronization (same process, rest to rest): the same duration and, axis by
    axis, the same positions -- Ruckig also gives each faster axis the time-optimal profile under a
    lowered velocity."""
    for d, lims in random_moves(11, 400):
        plan = plan_multi_axis(d, lims, sync="time")
        traj = ruckig_multi(d, lims, "time")
        assert traj.duration == pytest.approx(plan.duration, rel=RTOL)
        t = np.linspace(0.0, plan.duration, 9)
        theirs = np.array([traj.at_time(x)[0] for x in t]).T
        assert np.abs(plan.sample(t).position - theirs).max() <= RTOL * np.abs(d).max()


def test_phase_sync_against_ruckig():
    """Ruckig's phase synchronization scales the limiting axis's profile and, when that breaks
    another axis's limit, falls back to time synchronization, off the line.  Where Ruckig's result
    is a straight line its duration equals ours; where it is not, ours still is (and Ruckig, having
    left the line, may be faster)."""
    on_line = off_line = 0
    for d, lims in random_moves(12, 400):
        plan = plan_multi_axis(d, lims, sync="phase")
        traj = ruckig_multi(d, lims, "phase")
        t = np.linspace(0.0, traj.duration, 21)
        x = np.array([traj.at_time(s)[0] for s in t]).T
        u = d / np.linalg.norm(d)
        if np.abs(x - np.outer(u, u @ x)).max() <= RTOL * np.linalg.norm(d):
            on_line += 1
            assert traj.duration == pytest.approx(plan.duration, rel=RTOL)
        else:
            off_line += 1
            assert traj.duration <= plan.duration * (1 + RTOL)
    assert on_line > 100 and off_line > 10  # both cases are exercised


@settings(deadline=None)
@given(V=st.integers(1, 40000), N=st.integers(1, 3000), s=st.integers(0, 40000))
def test_min_start_count_is_the_first_count_reaching_the_speed(V, N, s):
    """Against a brute force over every count of the integer speed (Yang eq. 5, Yang eq. 6),
    evaluated with exact rationals: floor(V n^2 / (2 N^2)), V - floor(V (2N - n)^2 / (2 N^2))."""
    from fractions import Fraction

    from jerklab.fpga import min_start_count

    if s > V:
        with pytest.raises(ValueError, match="min_speed"):
            min_start_count(V, N, s)
        return
    n0 = min_start_count(V, N, s)
    c = Fraction(V, 2 * N * N)

    def speed(n):
        return math.floor(c * n * n) if n <= N else V - math.floor(c * (2 * N - n) ** 2)

    assert speed(n0) >= s and all(speed(n) < s for n in range(n0))


@pytest.mark.parametrize("dy", [300.0, 200.0, 45.0])
def test_yang_axes_slow_axis(dy):
    """y far slower than x: its start speed (the paper's 144 µm/s, or V when V is lower) lies on the
    second half of its ramp or at its top.  Below the start count the generator is silent, so its
    pulses stop when the deceleration passes that count, tick M - n0 (Yang's PWM_INITAL_COUNT,
    symmetric with the start), up to one of its periods later; they still reach the target."""
    plan = plan_multi_axis([40000.0, dy], [YANG_LIMITS] * 2, sync="phase")
    axes = yang_axes(plan, clock_hz=100_000)
    gy = axes.generators[1]
    assert gy.speed(gy.start_count) >= min(144, gy.max_velocity)
    assert gy.start_count > gy.half_counts  # not reached on the first half
    trains = axes.pulses()
    assert abs(axes.positions(1e3)[1] - dy) <= move_error_bound(axes, 1)
    R = gy.refresh_clocks
    silent_from = (
        axes.end_tick - gy.start_count + 1
    ) * R + 1  # n < n0: speed 0 from this posedge on
    longest = int(gy.speed_table().cycle.max())
    assert silent_from - longest <= int(trains[1].fall[-1]) <= silent_from + longest


@settings(deadline=None)
@given(
    axes=st.lists(AXIS, min_size=1, max_size=4),
    planner=st.sampled_from(PLANNERS),
    sync=st.sampled_from(["time", "phase"]),
    ets=st.floats(-4, 0),
)
def test_synchronized_keeps_the_axes_together(axes, planner, sync, ets):
    """Every phase time of every axis a whole multiple of Ts, one common duration, the limits and
    the end points kept, and phase sync still on the line."""
    d, lims = build(axes)
    Ts = 10.0**ets
    plan = plan_multi_axis(d, lims, sync=sync, planner=planner)
    sp = plan.synchronized(Ts)
    assert sp.duration >= plan.duration * (1 - 1e-12)
    if plan.duration == 0.0:
        return
    n = sp.duration / Ts
    assert abs(n - round(n)) <= 1e-9 * max(n, 1.0)
    for p in sp.axes:
        for x in p.phase_times:
            assert abs(x / Ts - round(x / Ts)) <= 1e-9 * max(x / Ts, 1.0)
    check_ends(sp)
    check_limits(sp, np.linspace(0.0, sp.duration, 401))
    if sync == "phase" and sp.path is not None:
        t = np.linspace(0.0, sp.duration, 301)
        s = sp.path.sample(t).position
        x = np.stack([p.sample(t).position for p in sp.axes])
        dd = np.asarray(d)
        assert np.all(np.abs(x - dd[:, None] * s) <= RTOL * np.abs(dd)[:, None])
    with pytest.raises(ValueError, match="Ts"):
        plan.synchronized(0.0)
