"""Re-targeting: the moving-start planner of jerklab.rig.retarget (the firmware's
rule in float64) and RETARGET on the virtual rig. The firmware on simavr is checked against the
virtual rig in tests/test_rig_simavr.py."""

from __future__ import annotations

import dataclasses
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


@settings(deadline=None, derandomize=True)
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
        # (the first plan here from the float64 distance, the device's from the float32 one of
        # PLAN; the re-targeted plans are float32 PLAN_SEGMENTs, as the device steps them:
        # within a few float32 steps of the position and of the velocity's scale 60 rad/s)
        assert xr == pytest.approx(xl, abs=1e-6 + 4e-7 * abs(xl))
        assert vr == pytest.approx(vl, abs=1e-6 + 4e-7 * 60.0)
        # (the switch time is the device's float32 one, the plan before it float64: within a
        # few float32 steps of the time, where the jerk is at most J)
        dt = 4.0 * float(np.spacing(np.float32(t_s)))
        if kind != 3:  # a trapezoid's acceleration steps there
            assert abs(al) <= 1e-9 * 300.0 + 2000.0 * dt and abs(ar) <= 1e-9 * 300.0
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
            rig._request(P.Retarget(20, 0.1, 0, 1, 1.0))
        except Exception as exc:  # RigCommandError
            nack = exc
        assert nack is not None and "NOT_READY" in str(nack).upper().replace(" ", "_")


# ------------------------------------------------------------------ host-planned (version 5)
_F = st.floats(-1e6, 1e6, allow_nan=False, width=32)


@given(
    k=st.integers(0, 2**32 - 1),
    t=st.floats(0.0, 1e7, width=32),
    base=st.integers(0, 255),
    n=st.integers(0, 255),
    target=_F,
    acc=st.floats(0.0, 1e3, width=32),
    cruise=st.floats(0.0, 1e3, width=32),
    flags=st.integers(0, 255),
)
def test_retarget_frame_round_trips_and_its_checks_name_the_field(
    k, t, base, n, target, acc, cruise, flags
):
    m = P.Retarget(k, t, base, n, target, acc, cruise, flags)
    assert len(m.pack()) == 23
    (f,) = P.Decoder().feed(P.encode(m, 7))
    assert P.parse(f) == m and f.seq == 7
    bad = P.check_retarget(m, n)
    assert bad == (7 if n and flags & ~P.RETARGET_HOLD else (3 if not n else None))
    assert P.check_retarget(m, n + 1) == 3
    nan = float("nan")
    if n:
        assert P.check_retarget(dataclasses.replace(m, target=nan), n) == 4
        assert P.check_retarget(dataclasses.replace(m, accel_time=-1.0), n) == 5
        assert P.check_retarget(dataclasses.replace(m, cruise_time=nan), n) == 6
        assert P.check_retarget(dataclasses.replace(m, flags=1, t_switch=-1.0), n) == 1


@settings(deadline=None, derandomize=True)
@given(
    kind=st.integers(0, 3),
    d=st.floats(0.05, 200.0),
    k_frac=st.floats(0.0, 1.3),
    new=st.floats(-300.0, 300.0),
    Ts_ms=st.sampled_from([1, 2, 5, 10]),
)
def test_host_switch_is_where_jerk_and_accel_are_zero_and_the_device_accepts_it(
    kind, d, k_frac, new, Ts_ms
):
    """plan_switch: the switch sample is at or after the earliest one asked for, at an instant
    the device's check allows (the running plan's cruise, its ends included, or rest) where the
    plan's jerk and acceleration are 0; the new plan starts from its state there, its segments
    join and end at rest at the target (or, braking, at rest with `hold`)."""
    J, A, V = 2000.0, 300.0, 60.0
    Ts = Ts_ms * 1e-3
    jk = None if kind == 3 else J
    first = R.rest_plan(kind, float(np.float32(d)), jk, A, V)
    f32 = np.float32
    run = R.RunningPlan(first, 0.0, first.accel_time, first.cruise_time, first.duration, kind)
    k_e = int(k_frac * first.duration / Ts)
    if abs(new - first.target) < 1e-3:
        new += 1.0
    sw = R.plan_switch(run, k_e, new, Ts, J, A, V)
    m = sw.message
    assert sw.k_switch == m.switch_index >= k_e
    assert m.switch_index == R.first_sample(m.t_switch, Ts)
    tc0, tc1, t_end = run.switch_times()
    assert tc0 <= m.t_switch <= tc1 or m.t_switch >= t_end
    assert P.check_retarget(m, len(sw.segments)) is None
    assert float(f32(f32(m.switch_index) * f32(Ts))) >= m.t_switch
    j, a, v, x = first.state(min(m.t_switch, first.end))
    if kind != 3:
        assert abs(a) <= 1e-6 * A + 4 * J * float(np.spacing(f32(m.t_switch)))
    if kind in (0, 1):
        assert abs(j) <= 1e-3 * J
    s0 = sw.segments[0]
    assert s0.x0 == pytest.approx(x, abs=1e-9 * (1 + abs(x)))
    assert s0.v0 == pytest.approx(v, abs=1e-6 * V)
    end = P.PlanCommit(len(sw.segments), m.target)
    assert P.check_plan_continuity(sw.segments, end) is None
    if m.flags & P.RETARGET_HOLD:
        # braking: the move to the target follows from its end, from rest
        assert s0.v0 != 0.0 and (new - x) * s0.v0 < 0 or abs(new - x) < abs(m.target - x)
        k2 = sw.k_switch + 1
        nxt = R.plan_switch(sw.running, k2, new, Ts, J, A, V, base=1)
        assert nxt.message.base == 1 and not nxt.message.flags
        assert nxt.message.t_switch >= sw.running.switch_times()[2]
        assert nxt.message.target == pytest.approx(new, abs=1e-9)
    else:
        assert m.target == pytest.approx(new, abs=1e-9)


def test_plan_switch_refuses_bad_parameters_by_name():
    first = R.rest_plan(1, 5.0, 2000.0, 300.0, 60.0)
    run = R.RunningPlan(first, 0.0, first.accel_time, first.cruise_time, first.duration, 1)
    with pytest.raises(TypeError, match="running"):
        R.plan_switch(first, 0, 1.0, 0.005, 2000.0, 300.0, 60.0)
    for kw, name in (
        (dict(k_earliest=-1), "k_earliest"),
        (dict(target=float("nan")), "target"),
        (dict(target=2e6), "target"),
        (dict(Ts=0.0), "Ts"),
        (dict(max_accel=-1.0), "max_accel"),
    ):
        args = dict(k_earliest=0, target=1.0, Ts=0.005, max_jerk=2000.0, max_accel=300.0)
        args.update(kw)
        with pytest.raises(ValueError, match=name):
            R.plan_switch(run, max_velocity=60.0, **args)
    with pytest.raises(ValueError, match="n_bytes"):
        R.margin_samples(-1, 0.005)
    assert R.margin_samples(233, 0.005) == R.RETARGET_LEAD + 15 + 1  # 20 ms line + 50 ms


def test_late_retarget_is_refused_and_retried_then_given_up(monkeypatch):
    """A switch the device gets too late is refused (NACK LATE) and planned again later by the
    host: the run still ends on the new target. When every try is late, the host gives up with
    a warning and the reason in the recording; the move ends on its old target."""
    real = R.margin_samples
    calls = []

    def first_late(n_bytes, Ts, baudrate=115200, attempt=0, decimation=1):
        calls.append(attempt)
        return 2 if attempt == 0 else real(n_bytes, Ts, baudrate, attempt, decimation)

    monkeypatch.setattr(R, "margin_samples", first_late)
    rec, pieces, prof = _run(1, 200, 2.0, settle=0.5)  # in the settling: at once
    assert calls == [0, 1]
    assert rec.metadata["status"] == "complete" and len(rec.metadata["retargets_late"]) == 1
    assert rec.reference[-1] == pytest.approx(2.0, abs=1e-6)
    monkeypatch.setattr(R, "margin_samples", lambda *a, **k: 2)
    with pytest.warns(RuntimeWarning, match="refused as late"):
        rec, pieces, prof = _run(1, 200, 2.0, settle=0.5)  # in the settling: at once
    assert len(rec.metadata["retargets_late"]) == R.RETARGET_TRIES
    assert rec.metadata["retargets_refused"][-1][0] == "LATE"
    assert rec.reference[-1] == pytest.approx(float(np.float32(prof.distance)), abs=1e-6)


def test_virtual_device_checks_a_retarget_as_the_firmware_does():
    """The virtual rig's RETARGET: the same NACKs, field by field, as the firmware's (see
    tests/test_firmware.py), and the accepted switch at the sample it names."""
    from jerklab.controller import DiscreteGains
    from jerklab.rig.virtual import VirtualDevice

    t = [0.0]
    dev = VirtualDevice(DCMotor(**MOTOR, supply_voltage=12.0, encoder_ppr=448), clock=lambda: t[0])

    def send(*msgs):
        for m in msgs:
            dev.receive(P.encode(m, 1))
        return [P.parse(f) for f in P.Decoder().feed(dev.read_output())]

    nan = float("nan")
    assert send(P.Retarget(20, 0.1, 0, 1, 1.0)) == [P.Nack(P.MsgType.RETARGET, 5, 0xFF)]
    g = DiscreteGains(0.5, 0.01, 1.0, 0.005)
    send(P.SetGains(g.kpd, g.kid, g.kdd, 5000, 0, 1, 0.0))
    send(P.SetLimits(2000.0, 300.0, 60.0, 12.0, 0))
    segs, commit = P.profile_segments(plan_sine_jerk_optimal(4 * math.pi, 2000.0, 300.0, 60.0))
    (info,) = send(*segs, commit)[-1:]
    send(P.Run(20, 1))
    for _ in range(10):
        dev.tick()
        t[0] += 0.005
    dev.read_output()
    first = R.rest_plan(1, float(np.float32(4 * math.pi)), 2000.0, 300.0, 60.0)
    run = R.RunningPlan(first, 0.0, info.accel_time, info.cruise_time, info.duration, 1)
    sw = R.plan_switch(run, 40, 20.0, 0.005, 2000.0, 300.0, 60.0)
    m = sw.message
    assert all(isinstance(r, P.Ack) for r in send(*sw.segments))
    rep = dataclasses.replace
    bad = [
        (rep(m, n_segments=m.n_segments + 1), P.ErrorCode.BAD_VALUE, 3),
        (rep(m, target=nan), P.ErrorCode.BAD_VALUE, 4),
        (rep(m, accel_time=-1.0), P.ErrorCode.BAD_VALUE, 5),
        (rep(m, cruise_time=nan), P.ErrorCode.BAD_VALUE, 6),
        (rep(m, flags=2), P.ErrorCode.BAD_VALUE, 7),
        (rep(m, t_switch=nan), P.ErrorCode.BAD_VALUE, 1),
        (rep(m, base=1), P.ErrorCode.LATE, 2),
        (rep(m, t_switch=0.1, switch_index=20), P.ErrorCode.BAD_VALUE, 1),
        (rep(m, switch_index=m.switch_index + 1), P.ErrorCode.BAD_VALUE, 0),
    ]
    for msg, err, param in bad:
        assert send(msg) == [P.Nack(P.MsgType.RETARGET, int(err), param)], msg
    assert send(m) == [P.Ack(P.MsgType.RETARGET)]
    assert dev._piece_k[-1] == m.switch_index
