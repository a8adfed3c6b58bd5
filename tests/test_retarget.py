"""Issue 21, re-targeting: the moving-start planner of jerklab.rig.retarget (the firmware's
rule in float64) and RETARGET on the virtual rig. The firmware on simavr is checked against the
virtual rig in tests/test_rig_simavr.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jerklab import protocol as P
from jerklab.controller import pole_placement_pid
from jerklab.planner import plan_scurve, plan_sine_jerk, plan_sine_jerk_optimal, plan_trapezoid
from jerklab.plant import DCMotor
from jerklab.rig import RigError, connect
from jerklab.rig import retarget as R

MOTOR = dict(K=27.5, tau=0.034)


def _check_plan(p, J, A, V, v0):
    """Exact start and end states, continuity of x, v, a at every segment boundary (and of the
    jerk for the sine family), the limits, and the closed form against a numerical integration
    of its own jerk."""
    t0, t1 = p.t_start, p.end
    j0, a0, v_0, x0 = p.state(t0)
    # (a plan's later segments are laid out backwards from the target: the start position is
    # exact up to the rounding of the distance)
    assert abs(x0 - p.x_start) <= 4 * np.spacing(abs(p.distance) + abs(p.x_start))
    assert v_0 == pytest.approx(p.sign * v0, abs=1e-12)
    assert a0 == 0.0 or p.shape == 2  # a trapezoid's acceleration steps
    assert p.state(t1) == (0.0, 0.0, 0.0, p.target)
    scale = (abs(p.distance) + 1.0, V + v0, A, J)
    for seg in p.segments[1:]:
        tb = seg[0]
        left = p.state(np.nextafter(tb, -np.inf) if tb > t0 else tb)
        right = p.state(tb)
        for i, (lv, rv) in enumerate(zip(left[1:], right[1:])):  # a, v, x
            if i == 0 and p.shape == 2:
                continue
            # (plus the rounding of the time tb itself times the derivative)
            deriv = (J, A, V + v0)[i]
            assert abs(lv - rv) <= 1e-9 * scale[2 - i] + 8 * deriv * np.spacing(tb) + 1e-12, (
                i,
                tb,
                lv,
                rv,
            )
        if p.shape == 0:
            assert abs(left[0] - right[0]) <= 1e-6 * J  # half-sine pulses: jerk continuous
    bounds = [seg[0] for seg in p.segments]
    a_i, v_i, x_i = 0.0, p.sign * v0, p.x_start  # state integrated from the start
    for ta_, tb_ in zip(bounds[:-1], bounds[1:]):
        t = np.linspace(ta_, tb_, 401)
        t[-1] = np.nextafter(tb_, -np.inf)  # the segment's own end value
        x, v, a, j = p.sample(t)
        assert np.all(np.abs(v) <= max(V, v0) * (1 + 1e-9) + 1e-12)
        assert np.all(np.abs(a) <= A * (1 + 1e-9) + 1e-12)
        if p.shape == 2:
            a_i, v_i, x_i = a[-1], v[-1], x[-1]
            continue
        assert np.all(np.abs(j) <= J * (1 + 1e-9))
        # integrate the closed form's own jerk (trapezoid rule) from the integrated state at the
        # segment's start: it must give the closed form's a, v, x (independent check)
        dt = np.diff(t)
        ai = a_i + np.concatenate([[0.0], np.cumsum(0.5 * (j[1:] + j[:-1]) * dt)])
        vi = v_i + np.concatenate([[0.0], np.cumsum(0.5 * (ai[1:] + ai[:-1]) * dt)])
        xi = x_i + np.concatenate([[0.0], np.cumsum(0.5 * (vi[1:] + vi[:-1]) * dt)])
        assert np.max(np.abs(ai - a)) <= 1e-5 * A + 1e-12
        assert np.max(np.abs(vi - v)) <= 1e-5 * (V + v0) + 1e-12
        assert np.max(np.abs(xi - x)) <= 1e-5 * (abs(p.distance) + 1.0)
        a_i, v_i, x_i = ai[-1], vi[-1], xi[-1]
    assert abs(x_i - p.target) <= 1e-5 * (abs(p.distance) + 1.0)


@settings(max_examples=80, deadline=None, derandomize=True)
@given(
    kind=st.integers(0, 3),
    d=st.floats(1e-3, 1e3),
    frac=st.floats(0.0, 1.0),
    J=st.floats(10.0, 1e5),
    A=st.floats(1.0, 1e3),
    V=st.floats(0.1, 200.0),
    back=st.booleans(),
)
def test_moving_start_plan_is_continuous_exact_and_within_limits(kind, d, frac, J, A, V, back):
    v0 = frac * V
    d = -d if back else d
    p = R.moving_plan(kind, d, v0, J, A, V, t_start=0.7, x_start=-2.0)
    if p is None:
        # only when even braking at once overshoots: the stopping distance exceeds |d|
        stop = R.stop_plan(kind, v0, J, A)
        assert abs(stop.distance) > abs(d)
        _check_plan(stop, J, A, V, v0)
        return
    _check_plan(p, J, A, V, v0)


def test_moving_start_from_rest_is_the_rest_to_rest_planner():
    """v0 = 0: the same duration as jerklab's time-optimal planners (the published one is
    replaced by the optimal sine profile, which the moving start generalises)."""
    for kind, fn in [(1, plan_sine_jerk_optimal), (2, plan_scurve)]:
        for d in (0.01, 1.0, 50.0, 900.0):
            prof = fn(d, 2000.0, 300.0, 60.0)
            p = R.moving_plan(kind, d, 0.0, 2000.0, 300.0, 60.0, iterations=60)
            assert p.duration == pytest.approx(prof.duration, rel=1e-9)
    prof = plan_trapezoid(5.0, 300.0, 60.0)
    assert R.moving_plan(3, 5.0, 0.0, 1.0, 300.0, 60.0, iterations=60).duration == pytest.approx(
        prof.duration, rel=1e-9
    )


def _run(kind, at, new, Ts=0.005, settle=0.3):
    prof = [
        plan_sine_jerk,
        plan_sine_jerk_optimal,
        plan_scurve,
        lambda d, J, A, V: plan_trapezoid(d, A, V),
    ][kind](4 * math.pi, 2000.0, 300.0, 60.0)
    g = pole_placement_pid(MOTOR["K"], MOTOR["tau"], wn=20.0).discretize(Ts)
    rig = connect(model=(MOTOR["K"], MOTOR["tau"]), progress=False, device=DCMotor(**MOTOR))
    dev = rig.link.device

    def cb(k, r, y):
        if k == at:
            rig.retarget(new)

    rec = rig.run_move(prof, g, Ts=Ts, settle=settle, path=False, on_telemetry=cb)
    pieces = list(dev._pieces)
    rig.close()
    return rec, pieces, prof


@pytest.mark.parametrize(
    "kind,at,new,case",
    [
        (1, 10, 25.0, "accel"),  # during the acceleration: switch at its end, then further
        (2, 10, 25.0, "accel"),
        (0, 10, 9.0, "accel"),  # shorter than planned: brake earlier
        (1, 75, 20.0, "cruise"),  # in the cruise: at once (after the planning lead)
        (2, 20, -3.0, "brake"),  # behind: brake to rest, then back
        (3, 10, 15.0, "accel"),
        (1, 200, 2.0, "rest"),  # after the end (settling): a new move from rest
    ],
)
def test_virtual_rig_retarget_is_jerk_continuous_and_ends_on_target(kind, at, new, case):
    rec, pieces, prof = _run(kind, at, new, settle=0.5 if case == "rest" else 0.3)
    assert rec.metadata["status"] == "complete", rec.metadata["status"]
    assert rec.metadata["retargets"][0][1] == new
    assert len(pieces) >= 2
    # across every change of plan the reference's state is continuous, with acceleration 0 and,
    # for the half-sine pulses, jerk 0 on both sides (the S-curve's and the trapezoid's own
    # jerk and acceleration steps are theirs, not the change's)
    prev = R.rest_plan(
        kind, float(np.float32(prof.distance)), 2000.0, 300.0, 60.0
    )  # as sent in PLAN
    for t_s, plan in pieces[1:]:
        jl, al, vl, xl = prev.state(np.nextafter(t_s, -np.inf))
        jr, ar, vr, xr = plan.state(t_s)
        # (the first plan here from the float64 distance, the device's from the float32 one of PLAN)
        assert xr == pytest.approx(xl, abs=1e-6) and vr == pytest.approx(vl, abs=1e-6)
        if kind != 3:  # a trapezoid's acceleration steps there
            assert abs(al) <= 1e-9 * 300.0 and abs(ar) <= 1e-9 * 300.0
        if kind in (0, 1):
            assert abs(jl) <= 1e-6 * 2000.0 and abs(jr) <= 1e-6 * 2000.0
        prev = plan
    # the telemetry reference ends on the new target, the motor there within 2 counts
    assert rec.reference[-1] == pytest.approx(new, abs=1e-6)
    assert abs(rec.position[-1] - new) < 2 / rec.metadata["counts_per_rad"]
    # the jerk from the sampled reference (third differences, a 3-sample average) never jumps:
    # a step of the peak jerk J would move it by >= J/2 between samples; the smooth pulses of
    # this run by < 0.2 J
    if kind in (0, 1):
        j = np.diff(rec.reference.astype(float), 3) / 0.005**3
        assert np.max(np.abs(np.diff(j))) <= 0.4 * 2000.0


def test_retarget_outside_a_run_and_bad_values_are_refused():
    with connect(progress=False, device=DCMotor(**MOTOR)) as rig:
        assert rig.capabilities & P.Capability.RETARGET
        with pytest.raises(RigError, match="during run_move"):
            rig.retarget(1.0)
        with pytest.raises(ValueError, match="new_distance"):
            rig.retarget(float("nan"))
        with pytest.raises(ValueError, match="new_distance"):
            rig.retarget(2e6)
        # on the wire: NOT_READY when no move runs
        nack = None
        try:
            rig._request(P.Retarget(1.0))
        except Exception as exc:  # RigCommandError
            nack = exc
        assert nack is not None and "NOT_READY" in str(nack).upper().replace(" ", "_")
