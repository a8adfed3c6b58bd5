"""Host-planned plans (protocol version 5): every jerklab.planner profile as PLAN_SEGMENTs and a
PLAN_COMMIT, their closed form equal to the profile's, the frames' round trip, the device's
checks (jerklab.protocol.check_plan_segment / check_plan_commit) naming the field at fault and
the host's (check_plan_continuity), and Rig.run_move choosing PLAN or the segments."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import cases
from hypothesis import given
from hypothesis import strategies as st

from jerklab import protocol as P
from jerklab.planner import (
    AnyStateProfile,
    plan_scurve,
    plan_sine_jerk,
    plan_sine_jerk_optimal,
    plan_trapezoid,
)

PLANNERS = {
    "sine_jerk": plan_sine_jerk,
    "sine_jerk_optimal": plan_sine_jerk_optimal,
    "scurve": plan_scurve,
    "trapezoid": lambda d, J, A, V: plan_trapezoid(d, A, V),
}


def _rest_profile(kind, ed, neg, ej, ea, ev, sync):
    d = (-1.0 if neg else 1.0) * 10.0**ed
    p = PLANNERS[kind](d, 10.0**ej, 10.0**ea, 10.0**ev)
    return p.synchronized(sync) if sync else p


def _times(p, Ts):
    n = min(int(math.ceil(p.duration / Ts)) + 3, 20000)
    bounds = np.cumsum([0.0, *p.phase_times])
    return np.concatenate([np.arange(n) * Ts, bounds, [-1.0, p.duration + 1.0]])


def _assert_reproduces(p, segs, commit, Ts):
    sp = P.SegmentProfile(segs, commit.target)
    # (a phase under 1 ns, the planner's round-off, is left out: the plan is that much shorter)
    left_out = sum(float(t) for t in p.phase_times if t < 1e-9)
    assert math.isclose(sp.duration, p.duration, rel_tol=1e-12, abs_tol=1e-15 + left_out)
    t = _times(p, Ts)
    if isinstance(p, AnyStateProfile):
        t = t[t >= 0.0]  # (before 0 it holds its start state, a run is at rest there)
    a, b = p.sample(t), sp.sample(t)
    scale_x = abs(p.distance) + 1e-300
    scale_v = p.peak_velocity + 1e-300
    scale_a = p.peak_accel + 1e-300
    jmax = p.max_jerk if p.max_jerk is not None else 0.0
    # the acceleration may step (a trapezoid): compare it away from the segment starts; a
    # phase left out moves the later ones that much earlier (each quantity by its rate times it)
    starts = np.asarray(sp.starts)
    near_t = 1e-12 * max(p.duration, 1.0) + left_out
    near = np.min(np.abs(t[:, None] - starts[None, :]), axis=1) <= near_t
    assert np.max(np.abs(a.position - b.position)) <= 1e-9 * scale_x + scale_v * left_out
    assert np.max(np.abs(a.velocity - b.velocity)) <= 1e-9 * scale_v + scale_a * left_out
    err_a = np.max(np.abs(a.accel - b.accel)[~near], initial=0.0)
    assert err_a <= 1e-9 * scale_a + jmax * left_out


def _wire(m):
    """The message as the device decodes it (float32 fields), through a frame."""
    frames = P.Decoder().feed(P.encode(m, seq=m.index if hasattr(m, "index") else 9))
    assert len(frames) == 1
    return P.parse(frames[0])


def _device_accepts(segs, commit):
    for i, s in enumerate(segs):
        assert P.check_plan_segment(s, i) is None, (i, s)
    assert P.check_plan_commit(commit, len(segs)) is None, commit
    assert P.check_plan_continuity(segs, commit) is None


@cases("cheap")
@given(
    kind=st.sampled_from(sorted(PLANNERS)),
    ed=st.floats(-3.0, 3.0),
    neg=st.booleans(),
    ej=st.floats(2.0, 5.0),
    ea=st.floats(1.0, 4.0),
    ev=st.floats(0.0, 3.0),
    sync=st.sampled_from([None, 0.001, 0.005]),
)
def test_rest_to_rest_segments_reproduce_the_profile_and_round_trip(
    kind, ed, neg, ej, ea, ev, sync
):
    """Every planner (Stojčić eq. 4's published one too), synchronized or not: the segments'
    closed form is the profile's at k Ts, at the phase boundaries and outside the move; the
    frames round-trip to their float32 values, which the device's checks accept."""
    p = _rest_profile(kind, ed, neg, ej, ea, ev, sync)
    segs, commit = P.profile_segments(p)
    assert 1 <= len(segs) <= P.MAX_PLAN_SEGMENTS
    assert [s.index for s in segs] == list(range(len(segs)))
    assert commit.n_segments == len(segs) and commit.target == p.distance
    assert all(s.duration >= 1e-9 for s in segs)
    half = kind.startswith("sine")
    assert all((s.kind == P.SegmentKind.HALF_SINE) == (half and s.jerk != 0.0) for s in segs)
    _assert_reproduces(p, segs, commit, sync or 0.005)
    wire = [_wire(s) for s in segs]
    for s, w in zip(segs, wire):
        f32 = {f.name: float(np.float32(getattr(s, f.name))) for f in dataclasses.fields(s)}
        assert w == dataclasses.replace(
            s, **{k: v for k, v in f32.items() if k not in ("index", "kind")}
        )
    wc = _wire(commit)
    assert wc.n_segments == commit.n_segments and wc.target == float(np.float32(p.distance))
    _device_accepts(wire, wc)


@cases("costly")
@given(
    kind=st.sampled_from(["scurve", "sine_jerk_optimal"]),
    ed=st.floats(-2.0, 2.0),
    neg=st.booleans(),
    uv0=st.floats(-1.5, 1.5),
    ua0=st.floats(-0.9, 0.9),
)
def test_any_state_segments_reproduce_the_profile(kind, ed, neg, uv0, ua0):
    """A move from a moving start (velocity and acceleration, within and beyond the limits) to
    rest: its segments, polynomial or half-sine, reproduce it; one with more segments than a
    plan holds is refused by name."""
    J, A, V = 2e4, 300.0, 30.0
    d = (-1.0 if neg else 1.0) * 10.0**ed
    fn = plan_scurve if kind == "scurve" else plan_sine_jerk_optimal
    p = fn(d, J, A, V, initial_velocity=uv0 * V, initial_accel=ua0 * A)
    n_nonzero = sum(1 for t in p.phase_times if t >= 1e-9)
    if n_nonzero > P.MAX_PLAN_SEGMENTS:
        with pytest.raises(ValueError, match="MAX_PLAN_SEGMENTS"):
            P.profile_segments(p)
        return
    segs, commit = P.profile_segments(p)
    assert len(segs) == n_nonzero
    v0, a0 = getattr(p, "initial_velocity", 0.0), getattr(p, "initial_accel", 0.0)
    tiny = 1.2e-38  # (below float32: sent as 0)
    # the start state: the profile's, but for the planner's round-off about 0 (a0 = -6e-25) and
    # a segment under 1 ns left out in front (a0 = 2e-6: under 1 ns of the jerk takes it to 0)
    dt = 1e-9  # at most _MIN_SEGMENT_TIME of the profile is left out before segs[0]
    assert segs[0].a0 == pytest.approx(a0 if abs(a0) >= tiny else 0.0, rel=1e-12, abs=J * dt)
    assert segs[0].v0 == pytest.approx(
        v0 if abs(v0) >= tiny else 0.0, rel=1e-12, abs=(abs(a0) + J * dt) * dt + 1e-12 * V
    )
    _assert_reproduces(p, segs, commit, 0.001)
    _device_accepts([_wire(s) for s in segs], _wire(commit))


@cases("costly")
@given(
    kind=st.sampled_from(["scurve", "sine_jerk_optimal"]),
    ed=st.floats(-1.0, 2.0),
    neg=st.booleans(),
    uv0=st.floats(-1.5, 1.5),
    ua0=st.floats(-0.9, 0.9),
    frac=st.floats(0.0, 1.0),
    new=st.floats(-20.0, 20.0),
)
def test_any_state_commit_names_a_window_of_zero_acceleration(kind, ed, neg, uv0, ua0, frac, new):
    """A moving start's PLAN_COMMIT names its re-targeting window: on the profile itself
    (jerklab.planner's closed form, not the segments) the move has acceleration 0 there (and,
    with half-sine pulses, jerk 0) at the speed cruise_velocity, and from its end on it only
    slows down to rest; the host's switch planned anywhere (jerklab.rig.retarget.plan_switch
    from host_running_plan) starts the new plan from the profile's state."""
    from jerklab.rig import retarget as R

    J, A, V = 2e4, 300.0, 30.0
    d = (-1.0 if neg else 1.0) * 10.0**ed
    fn = plan_scurve if kind == "scurve" else plan_sine_jerk_optimal
    p = fn(d, J, A, V, initial_velocity=uv0 * V, initial_accel=ua0 * A)
    if sum(1 for t in p.phase_times if t >= 1e-9) > P.MAX_PLAN_SEGMENTS:
        return
    segs, commit = P.profile_segments(p)
    t0, tv = commit.accel_time, commit.cruise_time
    if commit.cruise_velocity == 0.0:  # no window: never at acceleration 0 in motion
        assert t0 == tv == 0.0
    else:
        t = t0 + tv * np.linspace(0.0, 1.0, 9)
        s_ = p.sample(t)
        assert np.all(np.abs(np.asarray(s_.accel)) <= 1e-6 * A + J * 2e-7), s_.accel
        if kind == "sine_jerk_optimal":
            assert abs(float(np.asarray(s_.jerk)[0])) <= 1e-4 * J
        assert np.allclose(np.abs(s_.velocity), commit.cruise_velocity, rtol=1e-6, atol=1e-6)
        after = np.abs(p.sample(np.linspace(t0 + tv, p.duration, 200)).velocity)
        assert np.all(np.diff(after) <= 1e-6 * V)
    run = R.host_running_plan(segs, commit, int(P.Planner[kind.upper()]))
    Ts = 0.001
    k_e = int(frac * p.duration / Ts) + 1
    target = new if abs(new - d) > 1e-3 else new + 1.0
    sw = R.plan_switch(run, k_e, target, Ts, J, A, V)
    t_s = sw.message.t_switch
    x, v = p.sample(t_s).position, p.sample(t_s).velocity
    g = sw.segments[0]
    assert g.x0 == pytest.approx(float(x), abs=2e-6 * max(1.0, abs(d)))
    assert g.v0 == pytest.approx(float(v), abs=2e-5 * V)
    assert g.a0 == pytest.approx(0.0, abs=1e-6 * A + J * 2e-7)
    if not sw.running.hold:  # (a braking plan ends where it stops; the move to target follows)
        assert sw.message.target == pytest.approx(target)


def test_any_state_that_ends_moving_or_not_a_profile_is_refused():
    p = plan_scurve(1.0, 2e4, 300.0, 30.0, final_velocity=5.0)
    with pytest.raises(ValueError, match="final_velocity"):
        P.profile_segments(p)
    with pytest.raises(TypeError, match="jerklab.planner Profile"):
        P.profile_segments({"distance": 1.0})


def test_device_checks_name_the_field():
    """NaN, a segment out of order, too many segments, a wrong kind, a value out of range: the
    field index of the device's NACK; a jump in position or velocity, or a plan that does not
    end at rest at its target: the host's check names the segment and the field."""
    segs, commit = P.profile_segments(plan_scurve(2.0, 2e4, 300.0, 30.0))
    s0, s1 = segs[0], segs[1]
    nan = float("nan")
    rep = dataclasses.replace
    assert P.check_plan_segment(rep(s1, index=2), 1) == 0  # out of order
    assert P.check_plan_segment(s1, 0) == 0  # (none yet)
    assert P.check_plan_segment(rep(s0, index=P.MAX_PLAN_SEGMENTS), 7) == 0  # too many
    assert P.check_plan_segment(rep(s0, kind=2), 0) == 1
    assert P.check_plan_segment(rep(s0, duration=0.0), 0) == 2
    assert P.check_plan_segment(rep(s0, duration=nan), 0) == 2
    assert P.check_plan_segment(rep(s0, duration=2e7), 0) == 2
    assert P.check_plan_segment(rep(s0, x0=nan), 0) == 3
    assert P.check_plan_segment(rep(s0, x0=2e6), 0) == 3
    assert P.check_plan_segment(rep(s0, v0=float("inf")), 0) == 4
    assert P.check_plan_segment(rep(s0, a0=nan), 0) == 5
    assert P.check_plan_segment(rep(s0, jerk=nan), 0) == 6
    assert P.check_plan_segment(s0, 5) is None  # index 0 starts afresh
    assert P.check_plan_commit(rep(commit, n_segments=0), len(segs)) == 0
    assert P.check_plan_commit(commit, len(segs) - 1) == 0
    assert P.check_plan_commit(rep(commit, target=nan), len(segs)) == 1
    assert P.check_plan_commit(rep(commit, target=-2e6), len(segs)) == 1
    assert P.check_plan_commit(rep(commit, accel_time=-1.0), len(segs)) == 2
    assert P.check_plan_commit(rep(commit, cruise_time=nan), len(segs)) == 3
    assert P.check_plan_commit(rep(commit, cruise_velocity=-1.0), len(segs)) == 4
    assert P.check_plan_commit(rep(commit, planner=7), len(segs)) == 5
    # the host's check that the segments join (a jump in position or velocity, a wrong end)
    assert P.check_plan_continuity(segs, commit) is None
    jump = segs[:1] + [rep(s1, x0=s1.x0 + 1e-3)] + segs[2:]
    assert P.check_plan_continuity(jump, commit) == (1, "x0")
    kink = segs[:1] + [rep(s1, v0=s1.v0 * 1.01)] + segs[2:]
    assert P.check_plan_continuity(kink, commit) == (1, "v0")
    tsegs, tcommit = P.profile_segments(plan_trapezoid(2.0, 300.0, 30.0))
    assert tsegs[0].a0 != tsegs[1].a0  # a trapezoid's acceleration steps: still joined
    assert P.check_plan_continuity(tsegs, tcommit) is None
    assert P.check_plan_continuity(segs, rep(commit, target=2.1)) == (len(segs), "target")
    moving = segs[:-1] + [rep(segs[-1], v0=1.0)]
    assert P.check_plan_continuity(moving, commit)[1] in ("v0", "target")
    with pytest.raises(P.ProtocolError, match="duration"):
        rep(s0, duration="1").pack()
    with pytest.raises(P.ProtocolError, match="index"):
        rep(s0, index=256).pack()


def _virtual_rig(without=0):
    from jerklab.rig import connect

    rig = connect(None, progress=False)
    dev = rig.link.device
    if without:
        dev.capabilities &= ~P.Capability(without)
    rig.info = dataclasses.replace(rig.info, capabilities=int(dev.capabilities))
    return rig


def test_run_move_sends_segments_when_the_board_lacks_the_planner():
    """Rig.run_move: PLAN when the device has the planner and the profile is its own result;
    the host's segments when the device lacks it, or for a synchronized profile or a moving
    start; the telemetry's reference is the profile either way."""
    from jerklab.controller import pole_placement_pid

    g = pole_placement_pid(32.4, 0.025, 20.0)
    Ts = 0.005
    cases = [
        (plan_scurve(2.0, 2e4, 300.0, 30.0), P.Capability.PLANNER_SCURVE, "host", 2),
        (plan_scurve(2.0, 2e4, 300.0, 30.0), 0, "board", None),
        (plan_sine_jerk(2.0, 2e4, 300.0, 30.0).synchronized(Ts), 0, "host", P.PLANNER_NONE),
        (plan_scurve(2.0, 2e4, 300.0, 30.0, initial_velocity=3.0), 0, "host", P.PLANNER_NONE),
    ]
    for prof, without, by, planner in cases:
        rig = _virtual_rig(without)
        sent = []
        write = rig._write

        def spy(msg, _write=write):
            sent.append(msg)
            return _write(msg)

        rig._write = spy
        try:
            rec = rig.run_move(prof, g, Ts, path=False, settle=0.05)
        finally:
            rig.close()
        assert rec.metadata["status"] == "complete"
        assert rec.metadata["plan"]["planned_by"] == by
        commits = [m for m in sent if isinstance(m, P.PlanCommit)]
        assert any(isinstance(m, P.Plan) for m in sent) == (by == "board")
        if by == "host":
            assert len(commits) == 1 and commits[0].planner == planner
        k = np.asarray(rec.index)
        ref = prof.sample(k * Ts).position
        assert np.max(np.abs(np.asarray(rec.reference) - ref)) <= 1e-5 * abs(prof.distance)


def test_host_plans_of_no_planner_are_re_targeted_too():
    """A host-planned move that is no planner's rest-to-rest result -- synchronized, or from a
    moving start (overshooting and coming back, too) -- is re-targeted by the same rule as a
    planner's own: PLAN_COMMIT's window (accel_time, cruise_time) says where the move has jerk
    and acceleration 0, the host plans from its segments there
    (jerklab.rig.retarget.host_running_plan), the virtual device checks and takes the switch,
    the reference stays continuous across it and ends on the new target."""
    from jerklab.controller import pole_placement_pid
    from jerklab.planner import AnyStateProfile
    from jerklab.rig import retarget as R

    g = pole_placement_pid(32.4, 0.025, 20.0)
    Ts = 0.005
    cases = [
        # (profile, the sample of the request, the new target)
        (plan_scurve(2.0, 2e4, 300.0, 30.0).synchronized(Ts), 5, 3.0),  # before the cruise
        (plan_scurve(2.0, 2e4, 300.0, 30.0).synchronized(Ts), 30, 1.5),  # in it, shorter
        (plan_scurve(8.0, 2e4, 300.0, 30.0, initial_velocity=10.0), 3, 12.0),  # cruise
        (plan_scurve(5.0, 2e4, 300.0, 60.0, initial_velocity=20.0), 2, 7.0),  # no cruise
        (plan_sine_jerk_optimal(5.0, 2e4, 300.0, 60.0, initial_velocity=-20.0), 2, 6.0),
        (plan_scurve(0.5, 2e4, 300.0, 60.0, initial_velocity=40.0), 3, -1.0),  # back, further
    ]
    for prof, at, new in cases:
        segs, commit = P.profile_segments(prof)
        if isinstance(prof, AnyStateProfile):
            assert commit.accel_time > 0  # (a moving start has its window)
        rig = _virtual_rig()
        dev = rig.link.device

        def cb(k, r, y, rig=rig, at=at, new=new):
            if k == at:
                rig.retarget(new)

        try:
            rec = rig.run_move(prof, g, Ts, path=False, settle=0.2, on_telemetry=cb)
            pieces = list(dev._pieces)
        finally:
            rig.close()
        what = (prof.kind, getattr(prof, "initial_velocity", 0.0), at, new)
        assert rec.metadata["plan"]["planned_by"] == "host", what
        assert rec.metadata["status"] == "complete", (what, rec.metadata["status"])
        assert rec.metadata["retargets"][0][1] == new, what
        assert not rec.metadata.get("retargets_refused"), (what, rec.metadata["retargets_refused"])
        assert len(rec.metadata["retarget_switches"]) >= 1, what
        # the switch is where the running plan has acceleration 0 (and, for the half-sine
        # pulses, jerk 0), the new plan starts from its state there
        assert len(pieces) >= 2, what
        prev = R.placed_segments(segs, commit.target, 0.0)
        for t_s, plan in pieces[1:]:
            jl, al, vl, xl = prev.state(np.nextafter(t_s, -np.inf))
            jr, ar, vr, xr = plan.state(t_s)
            dt = 4.0 * float(np.spacing(np.float32(t_s)))
            assert xr == pytest.approx(xl, abs=2e-6 + 4e-7 * abs(xl)), what
            assert vr == pytest.approx(vl, abs=2e-6 + 4e-7 * 60.0), what
            assert abs(al) <= 1e-6 * 300.0 + 2e4 * dt and abs(ar) <= 1e-6 * 300.0, what
            if prof.kind == "sine_jerk_optimal":
                assert abs(jl) <= 1e-6 * 2e4 and abs(jr) <= 1e-6 * 2e4, what
            prev = plan
        assert rec.reference[-1] == pytest.approx(new, abs=1e-5), what
