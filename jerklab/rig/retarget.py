"""Re-targeting a running move: the host plans it, the firmware and the virtual rig check it.

A re-targeting (``firmware/PROTOCOL.md`` "Re-targeting") changes the target of the move that
runs: the host plans the switch and the new plan (:func:`plan_switch`) and sends them as
PLAN_SEGMENTs and a RETARGET naming the switch sample.
The reference must stay jerk-continuous, so the new plan starts where the running one has
jerk 0 *and* acceleration 0 (see ``docs/THEORY.md`` "Re-targeting"):

* during the acceleration phase: at its end (the half-sine pulses end there, j = a = 0);
* during the cruise: at once, i.e. at the first sample the host's frames reach the board in
  time for (:func:`margin_samples`);
* during the deceleration or after the end: at rest at the old target.

From there (position ``x_s``, velocity ``v_s`` along the move, acceleration 0) the new plan is
the *moving-start* profile: a pulse pair from ``v_s`` up to a peak ``v_p``, a cruise, and the
rest-to-rest deceleration from ``v_p`` -- the largest ``v_p <= max_velocity`` whose distance
fits (bisection), the pulses of the planner's shape (half-sine of peak ``max_jerk`` for the
sine family, linear jerk for the S-curve, steps for the trapezoid). When the new target lies
behind the stopping distance (or behind the start), the plan brakes to rest first (the
overshoot a jerk-limited move cannot avoid) and a rest-to-rest move to the target follows.

:class:`SegmentPlan` mirrors the firmware's ``jl::Plan`` (``firmware/jerklab_rig/src/jl_planner``)
in float64: the same segments, start states and closed forms.
"""

from __future__ import annotations

import math

import numpy as np

from jerklab import planner
from jerklab import protocol as P
from jerklab._validate import as_int, as_nonnegative, as_positive, as_real

__all__ = [
    "SegmentPlan",
    "moving_plan",
    "stop_plan",
    "rest_plan",
    "switch_point",
    "lead_samples",
    "BISECTION_STEPS",
    "RETARGET_LEAD",
    "RETARGET_TRIES",
    "RunningPlan",
    "SwitchPlan",
    "first_sample",
    "margin_samples",
    "plan_segments",
    "plan_switch",
    "placed_segments",
    "host_running_plan",
]

_TWO_OVER_PI = 2.0 / math.pi
#: bisection halvings of the peak velocity
BISECTION_STEPS = 24
_SINE, _LINEAR, _STEP = 0, 1, 2
_SHAPES = {0: _SINE, 1: _SINE, 2: _LINEAR, 3: _STEP}


def _checked(kind, max_jerk, max_accel):
    """PLAN's planner byte ``kind`` (0..3) and the limits, checked (``ValueError`` naming them);
    the trapezoid (3) takes ``max_jerk=None``."""
    if (
        isinstance(kind, bool)
        or not isinstance(kind, (int, np.integer))
        or int(kind) not in _SHAPES
    ):
        raise ValueError(
            f"kind must be PLAN's planner byte 0..3 (sine_jerk, sine_jerk_optimal, scurve, "
            f"trapezoid), got {kind!r}"
        )
    kind = int(kind)
    if not (kind == 3 and max_jerk is None):
        max_jerk = as_positive("max_jerk", max_jerk)
    return kind, max_jerk, as_positive("max_accel", max_accel)


def lead_samples(Ts_us: int) -> int:
    """Samples between a RETARGET and the earliest switch when the board planned it itself
    (protocol versions 3 and 4, a few bisection steps per tick): ``2 + ceil(24 / max(2, Ts_us
    // 400))`` -- 14 at 1 ms, 4 at 5 ms. Version 5 plans on the host: :func:`plan_switch`,
    :data:`RETARGET_LEAD`."""
    per_tick = max(2, as_int("Ts_us", Ts_us, minimum=1) // 400)
    return 2 + -(-BISECTION_STEPS // per_tick)


def _pulse_ends(shape, jpar, tj):
    """Peak acceleration and the velocity and position at the end of the rising pulse."""
    if shape == _SINE:
        apk = _TWO_OVER_PI * jpar * tj
        return apk, 0.5 * apk * tj, apk * tj * tj * (0.25 - 1.0 / (math.pi * math.pi))
    if shape == _LINEAR:
        apk = jpar * tj
        return apk, 0.5 * apk * tj, apk * tj * tj / 6.0
    return jpar, 0.0, 0.0


def _pair_times(shape, dv, Je, A):
    """Pulse pair changing the velocity by ``dv >= 0``: pulse time and plateau."""
    if not dv > 0.0:
        return 0.0, 0.0
    if shape == _STEP:
        return 0.0, dv / A
    if dv * Je >= A * A:
        return A / Je, dv / A - A / Je
    return math.sqrt(dv / Je), 0.0


def _moving_dist(shape, v0, vp, Je, A):
    tj1, ta1 = _pair_times(shape, vp - v0, Je, A)
    tj2, ta2 = _pair_times(shape, vp, Je, A)
    return 0.5 * (v0 + vp) * (2.0 * tj1 + ta1) + 0.5 * vp * (2.0 * tj2 + ta2)


class SegmentPlan:
    """A move as segments of constant or half-sine jerk with their start states (the
    firmware's ``jl::Plan``), sampled in closed form.

    Attributes
    ----------
    t_start, x_start : float
        Start time and position (s, rad).
    distance, sign : float
        Signed length and direction.
    v_start, v_peak : float
        Speed at the start and in the cruise (>= 0, along the move).
    accel_time, cruise_time, duration : float
        Acceleration phase, cruise and whole length (s).
    """

    def __init__(
        self, shape, jpar, distance, v_start, tj1, ta1, tv, tj, ta, v_peak, t_start=0.0, x_start=0.0
    ):
        self.shape, self.jerk = shape, float(jpar)
        self.distance = float(distance)
        self.sign = -1.0 if distance < 0 else 1.0
        self.v_start, self.v_peak = float(v_start), float(v_peak)
        self.tj1, self.ta1, self.tv, self.tj, self.ta = tj1, ta1, tv, tj, ta
        self.t_start, self.x_start = float(t_start), float(x_start)
        self._build()

    def _build(self):
        sh, J, v0, D, sg = self.shape, self.jerk, self.v_start, abs(self.distance), self.sign
        segs = []

        def add(t, x, v, a, jp, sine, w):
            segs.append((self.t_start + t, self.x_start + sg * x, sg * v, sg * a, sg * jp, sine, w))

        apk1, v11, x11 = _pulse_ends(sh, J, self.tj1)
        tacc1 = 2.0 * self.tj1 + self.ta1
        w1 = math.pi / self.tj1 if self.tj1 > 0 else 0.0
        jl = 0.0 if sh == _STEP else J
        sine = sh == _SINE
        t = 0.0
        if tacc1 > 0.0:
            if self.tj1 > 0.0:
                add(0.0, 0.0, v0, 0.0, jl, sine, w1)
            x, v = v0 * self.tj1 + x11, v0 + v11
            t = self.tj1
            if self.ta1 > 0.0:
                add(t, x, v, apk1, 0.0, False, 0.0)
                x += self.ta1 * (v + 0.5 * apk1 * self.ta1)
                v += apk1 * self.ta1
                t += self.ta1
            if self.tj1 > 0.0:
                add(t, x, v, apk1, -jl, sine, w1)
            t = tacc1
        vp = self.v_peak
        xc = 0.5 * (v0 + vp) * tacc1
        apk, v1, x1 = _pulse_ends(sh, J, self.tj)
        tacc = 2.0 * self.tj + self.ta
        if self.tv > 0.0:
            add(t, xc, vp, 0.0, 0.0, False, 0.0)
        t += self.tv
        if tacc > 0.0:
            w = math.pi / self.tj if self.tj > 0 else 0.0
            if self.tj > 0.0:
                add(t, D - 0.5 * vp * tacc, vp, 0.0, -jl, sine, w)
            if self.ta > 0.0:
                xa = x1 + self.ta * (v1 + 0.5 * apk * self.ta)
                add(t + self.tj, D - xa, vp - v1, -apk, 0.0, False, 0.0)
            if self.tj > 0.0:
                add(t + self.tj + self.ta, D - x1, v1, -apk, jl, sine, w)
            t += tacc
        self.duration = t
        segs.append((self.t_start + t, self.x_start + self.distance, 0.0, 0.0, 0.0, False, 0.0))
        self.accel_time, self.cruise_time = tacc1, self.tv
        self.segments = segs

    @property
    def target(self) -> float:
        return self.x_start + self.distance

    @property
    def end(self) -> float:
        return self.t_start + self.duration

    def state(self, t):
        """``(jerk, accel, velocity, position)`` at the time ``t`` (scalar)."""
        segs = self.segments
        if t < segs[0][0]:
            return 0.0, 0.0, 0.0, self.x_start
        i = len(segs) - 1
        while i > 0 and t < segs[i][0]:
            i -= 1
        t0, x0, v0, a0, jp, sine, w = segs[i]
        if i == len(segs) - 1:
            return 0.0, 0.0, 0.0, x0
        u = t - t0
        if sine:
            wu = w * u
            sn, omc = math.sin(wu), 2.0 * math.sin(0.5 * wu) ** 2
            c = jp / w
            return (
                jp * sn,
                a0 + c * omc,
                v0 + a0 * u + c * (u - sn / w),
                x0 + u * (v0 + 0.5 * a0 * u) + c * (0.5 * u * u - omc / (w * w)),
            )
        return (
            jp,
            a0 + jp * u,
            v0 + u * (a0 + 0.5 * jp * u),
            x0 + u * (v0 + u * (0.5 * a0 + u * jp / 6.0)),
        )

    def sample(self, t):
        """Arrays ``(position, velocity, accel, jerk)`` at the times ``t`` (vectorized
        :meth:`state`)."""
        t = np.atleast_1d(np.asarray(t, float))
        x = np.full(t.shape, self.x_start)
        v, a, j = np.zeros(t.shape), np.zeros(t.shape), np.zeros(t.shape)
        segs = self.segments
        for i, (t0, x0, v0, a0, jp, sine, w) in enumerate(segs):
            t_next = segs[i + 1][0] if i + 1 < len(segs) else np.inf
            sel = (t >= t0) & (t < t_next)
            if not sel.any():
                continue
            if i == len(segs) - 1:
                x[sel] = x0
                continue
            u = t[sel] - t0
            if sine:
                wu = w * u
                sn, omc = np.sin(wu), 2.0 * np.sin(0.5 * wu) ** 2
                c = jp / w
                j[sel] = jp * sn
                a[sel] = a0 + c * omc
                v[sel] = v0 + a0 * u + c * (u - sn / w)
                x[sel] = x0 + u * (v0 + 0.5 * a0 * u) + c * (0.5 * u * u - omc / (w * w))
            else:
                j[sel] = jp
                a[sel] = a0 + jp * u
                v[sel] = v0 + u * (a0 + 0.5 * jp * u)
                x[sel] = x0 + u * (v0 + u * (0.5 * a0 + u * jp / 6.0))
        return x, v, a, j


def rest_plan(kind, distance, max_jerk, max_accel, max_velocity, t_start=0.0, x_start=0.0):
    """The rest-to-rest plan of PLAN's ``kind`` (0..3) as a :class:`SegmentPlan` (jerklab's
    phase times, the same closed form)."""
    kind, max_jerk, max_accel = _checked(kind, max_jerk, max_accel)
    if kind == 3:
        prof = planner.plan_trapezoid(distance, max_accel, max_velocity)
    else:
        fn = (planner.plan_sine_jerk, planner.plan_sine_jerk_optimal, planner.plan_scurve)[kind]
        prof = fn(distance, max_jerk, max_accel, max_velocity)
    shape = _SHAPES[kind]
    tj, ta, tv = prof._tj, prof._ta, prof._tv
    jpar = max_accel if shape == _STEP else max_jerk
    return SegmentPlan(
        shape, jpar, distance, 0.0, tj, ta, tv, tj, ta, prof.peak_velocity, t_start, x_start
    )


def moving_plan(
    kind,
    distance,
    v0,
    max_jerk,
    max_accel,
    max_velocity,
    t_start=0.0,
    x_start=0.0,
    iterations=BISECTION_STEPS,
):
    """Moving start ``v0 >= 0`` along ``distance`` (a0 = 0), rest at the end; ``None`` when
    the move cannot stop within ``distance`` (what the host sends for a re-targeting in motion)."""
    kind, max_jerk, max_accel = _checked(kind, max_jerk, max_accel)
    distance = as_real("distance", distance)
    v0 = as_nonnegative("v0", v0)
    max_velocity = as_positive("max_velocity", max_velocity)
    shape = _SHAPES[kind]
    J, A, V = max_jerk, max_accel, max(max_velocity, v0)
    Je = _TWO_OVER_PI * J if shape == _SINE else J
    d = abs(distance)
    dmax = _moving_dist(shape, v0, V, Je, A)
    if dmax <= d:
        vp, tv = V, (d - dmax) / V
    else:
        lo, hi = v0, V
        dlo = _moving_dist(shape, v0, v0, Je, A)
        if dlo > d * (1.0 + 1e-6) + 1e-30:
            return None
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            dm = _moving_dist(shape, v0, mid, Je, A)
            if dm <= d:
                lo, dlo = mid, dm
            else:
                hi = mid
        vp = lo
        tv = (d - dlo) / vp if vp > 0.0 and d > dlo else 0.0
    tj1, ta1 = _pair_times(shape, vp - v0, Je, A)
    tj, ta = _pair_times(shape, vp, Je, A)
    jpar = A if shape == _STEP else J
    return SegmentPlan(shape, jpar, distance, v0, tj1, ta1, tv, tj, ta, vp, t_start, x_start)


def stop_plan(kind, v, max_jerk, max_accel, t_start=0.0, x_start=0.0):
    """Brake from the velocity ``v`` (signed, a0 = 0) to rest: the deceleration half only."""
    kind, max_jerk, max_accel = _checked(kind, max_jerk, max_accel)
    v = as_real("v", v)
    shape = _SHAPES[kind]
    Je = _TWO_OVER_PI * max_jerk if shape == _SINE else max_jerk
    v0 = abs(v)
    tj, ta = _pair_times(shape, v0, Je, max_accel)
    d = 0.5 * v0 * (2.0 * tj + ta)
    if not math.isfinite(d):
        raise ValueError(f"v = {v!r}: the braking distance overflows; scale the units")
    jpar = max_accel if shape == _STEP else max_jerk
    return SegmentPlan(
        shape, jpar, math.copysign(d, v), v0, 0.0, 0.0, 0.0, tj, ta, v0, t_start, x_start
    )


def switch_point(plan, t_earliest, Ts):
    """Where a RETARGET takes over ``plan``: ``(t_s, x_s, v_s)`` (v_s signed) for a command
    that may act from ``t_earliest`` on (a sample time)."""
    tc0 = plan.t_start + plan.accel_time
    tc1 = tc0 + plan.cruise_time
    if t_earliest <= tc0:
        t_s = tc0
    elif t_earliest < tc1:
        t_s = t_earliest
    else:
        return max(plan.end, t_earliest), plan.target, 0.0
    x = plan.state(t_s)[3]
    return t_s, x, plan.sign * plan.v_peak


# ---------------------------------------------------------------------------- host-planned
#: samples the device needs between the RETARGET frame and the switch it names (the stepper
#: prepares the new plan's first chunk in its idle time, one stage a tick: PROTOCOL.md
#: "Re-targeting")
RETARGET_LEAD = 16
#: retries of a RETARGET the device refused as late (NACK LATE), each with twice the allowance
RETARGET_TRIES = 4
#: the margin's fixed allowance (s) on top of the frames' line time: the host's own latency
#: and the device's reply time (doubled at each retry)
RETARGET_ALLOWANCE = 0.05
_MIN_SEGMENT = 1e-9


def _f32(x) -> float:
    return float(np.float32(x))


def _f32_sum(a, b) -> float:
    return float(np.float32(np.float32(a) + np.float32(b)))


def first_sample(t, Ts) -> int:
    """The smallest ``k`` with ``float32(k) * float32(Ts) >= float32(t)`` (float32 arithmetic,
    as the device's stepper finds a plan's first sample)."""
    t32, ts32 = np.float32(t), np.float32(Ts)
    if not t32 > 0:
        return 0
    k = int(np.float32(t32 / ts32)) + 2
    while k > 0 and np.float32(np.float32(k - 1) * ts32) >= t32:
        k -= 1
    return k


class RunningPlan:
    """The plan the device steps, as the host knows it.

    Parameters
    ----------
    plan : SegmentPlan
        Its float64 reference (its state at the switch is the new plan's start).
    t_start, accel_time, cruise_time, duration : float
        Its start, acceleration phase, cruise and length as the device holds them (float32:
        PLAN_INFO's fields, or the RETARGET that made it): the switch rule uses these.
    kind : int
        The run's planner (PLAN's byte 0..3): the shape of the plans that follow.
    hold : bool
        A braking plan: the move to the target follows from its end.
    """

    def __init__(self, plan, t_start, accel_time, cruise_time, duration, kind, hold=False):
        self.plan = plan
        self.t_start = _f32(t_start)
        self.accel_time = _f32(accel_time)
        self.cruise_time = _f32(cruise_time)
        self.duration = _f32(duration)
        self.kind, _, _ = _checked(kind, 1.0, 1.0)
        self.hold = bool(hold)

    def switch_times(self):
        """``(tc0, tc1, t_end)`` in the device's float32 sums: the cruise's start and end and
        the plan's end."""
        tc0 = _f32_sum(self.t_start, self.accel_time)
        return tc0, _f32_sum(tc0, self.cruise_time), _f32_sum(self.t_start, self.duration)


def plan_segments(plan):
    """The PLAN_SEGMENTs of a :class:`SegmentPlan` (absolute start states, float64 values;
    segments shorter than 1 ns left out) and their float32 total duration as the device sums
    them."""

    segs, acc = [], np.float32(0.0)
    rows = plan.segments
    for (t0, x0, v0, a0, jp, sine, _), nxt in zip(rows[:-1], rows[1:]):
        u = nxt[0] - t0
        if u < _MIN_SEGMENT:
            continue
        kind = P.SegmentKind.HALF_SINE if sine else P.SegmentKind.POLYNOMIAL
        segs.append(P.PlanSegment(len(segs), int(kind), u, x0, v0, a0, jp))
        acc = np.float32(acc + np.float32(u))
    return segs, float(acc)


class SwitchPlan:
    """A host-planned re-targeting: the frames to send and the plan that then runs.

    Attributes
    ----------
    segments : list of PlanSegment
        The new plan, into the device's second buffer.
    message : Retarget
        The commit that names the switch sample.
    running : RunningPlan
        The plan that runs from the switch on (what the next re-targeting starts from).
    k_switch : int
        The sample where it takes over.
    """

    def __init__(self, segments, message, running, k_switch):
        self.segments, self.message = segments, message
        self.running, self.k_switch = running, int(k_switch)

    def n_bytes(self) -> int:
        """Bytes on the wire of all the frames (7 of framing each)."""

        return sum(len(P.encode(m)) for m in [*self.segments, self.message])


def plan_switch(
    running, k_earliest, target, Ts, max_jerk, max_accel, max_velocity, base=0
) -> SwitchPlan:
    """Plan the re-targeting of ``running`` to ``target`` on the host.

    The switch is at an instant where the running plan's jerk and acceleration are 0 (the
    rule of :func:`switch_point`, in the device's float32 times): the end of the acceleration
    when ``k_earliest`` comes before it, else at sample ``k_earliest`` in the cruise, else at
    rest at the old target. From the state there the new plan is :func:`rest_plan`,
    :func:`moving_plan` or, when the target lies behind the stopping distance,
    :func:`stop_plan` (``hold``: the move to the target follows from its end).

    Parameters
    ----------
    running : RunningPlan
        The plan the device steps.
    k_earliest : int
        The earliest sample the switch may be at (the host's margin included).
    target : float
        The new target (rad from the run's start).
    Ts : float
        The sample period (s).
    max_jerk, max_accel, max_velocity : float
        The run's limits (the trapezoid takes any ``max_jerk``).
    base : int
        The number of re-targeted plans that took over in this run so far (mod 256).

    Returns
    -------
    SwitchPlan

    Raises
    ------
    ValueError
        A parameter out of range, named.
    """

    if not isinstance(running, RunningPlan):
        raise TypeError(f"running must be a RunningPlan, got {type(running).__name__}")
    k_earliest = as_int("k_earliest", k_earliest, minimum=0)
    target = as_real("target", target)
    if not abs(target) <= 1e6:
        raise ValueError(f"target must be within +-1e6 rad, got {target!r}")
    Ts = as_positive("Ts", Ts)
    base = as_int("base", base, minimum=0) & 0xFF
    kind = running.kind
    J, A = _checked(kind, None if kind == 3 else max_jerk, max_accel)[1:]
    V = as_positive("max_velocity", max_velocity)
    tc0, tc1, t_end = running.switch_times()
    t_e = _f32(np.float32(k_earliest) * np.float32(Ts))
    p = running.plan
    if running.hold or not (t_e <= tc0 or t_e < tc1):
        t_s = max(t_end, t_e)
        x_s, v_s = p.target, 0.0
    else:
        t_s = tc0 if t_e <= tc0 else t_e
        x_s, v_s = float(p.state(t_s)[3]), p.sign * p.v_peak
    d = target - x_s
    new, hold = None, False
    if d == 0.0 and v_s == 0.0:
        raise ValueError(f"target {target!r} is where the move rests: nothing to re-target")
    if v_s == 0.0:
        new = rest_plan(kind, d, J, A, V, t_s, x_s)
    elif d != 0.0 and (d > 0) == (v_s > 0):
        new = moving_plan(kind, d, abs(v_s), J, A, V, t_s, x_s)
    if new is None:
        new, hold = stop_plan(kind, v_s, J, A, t_s, x_s), True
    segs, duration = plan_segments(new)
    end = P.PlanCommit(len(segs), new.target)
    gap = P.check_plan_continuity(segs, end)
    if gap is not None:  # pragma: no cover - the planners' segments join
        raise ValueError(f"re-targeted plan: segment {gap[0]}'s {gap[1]} does not join")
    k_s = first_sample(t_s, Ts)
    msg = P.Retarget(
        k_s,
        t_s,
        base,
        len(segs),
        new.target,
        _f32(new.accel_time),
        _f32(new.cruise_time),
        P.RETARGET_HOLD if hold else 0,
    )
    nxt = RunningPlan(new, t_s, new.accel_time, new.cruise_time, duration, kind, hold)
    return SwitchPlan(segs, msg, nxt, k_s)


def margin_samples(n_bytes, Ts, baudrate=115200, attempt=0, decimation=1) -> int:
    """Samples between the host's latest known sample and the switch it asks for: the
    device's :data:`RETARGET_LEAD`, the frames' line time (``n_bytes`` at ``baudrate``, 10
    bits a byte), :data:`RETARGET_ALLOWANCE` s doubled at each retry ``attempt`` and the
    telemetry's ``decimation``."""
    n_bytes = as_int("n_bytes", n_bytes, minimum=0)
    Ts = as_positive("Ts", Ts)
    baudrate = as_positive("baudrate", baudrate)
    attempt = as_int("attempt", attempt, minimum=0)
    decimation = as_int("decimation", decimation, minimum=1)
    wait = n_bytes * 10.0 / baudrate + RETARGET_ALLOWANCE * 2.0**attempt
    return RETARGET_LEAD + int(math.ceil(wait / Ts)) + decimation


def placed_segments(segments, target, t_start) -> SegmentPlan:
    """The plan of host-planned ``segments`` (PLAN_SEGMENTs) at rest at ``target``, starting at
    ``t_start`` s, with the device's float32 segment start times (``t_start`` plus the float32
    sum of the durations before): what a device steps after a RETARGET."""

    segments = list(segments)
    if not segments:
        raise ValueError("segments must hold at least one PlanSegment")
    t0 = np.float32(t_start)
    acc = np.float32(0.0)
    rows = []
    for s in segments:
        sine = s.kind == P.SegmentKind.HALF_SINE
        w = math.pi / s.duration if sine else 0.0
        rows.append((float(np.float32(acc + t0)), s.x0, s.v0, s.a0, s.jerk, sine, w))
        acc = np.float32(acc + np.float32(s.duration))
    rows.append((float(np.float32(acc + t0)), float(target), 0.0, 0.0, 0.0, False, 0.0))
    plan = object.__new__(SegmentPlan)
    plan.segments = rows
    plan.t_start, plan.x_start = float(t0), float(segments[0].x0)
    plan.distance = float(target) - plan.x_start
    plan.sign = -1.0 if plan.distance < 0 else 1.0
    plan.duration = float(acc)
    plan.shape, plan.jerk = None, 0.0
    plan.v_start = plan.v_peak = 0.0
    plan.accel_time = plan.cruise_time = 0.0
    return plan


def host_running_plan(segments, commit, kind) -> RunningPlan:
    """The :class:`RunningPlan` of a host-planned move (PLAN_SEGMENTs and their PLAN_COMMIT,
    :func:`jerklab.protocol.profile_segments`) that is no planner's own rest-to-rest result --
    a synchronized profile, a moving start --, so that the host re-targets it by the same rule.

    The switch window is the commit's (``accel_time``, ``cruise_time``: where the move has jerk
    and acceleration 0), the velocity there the plan's own at the window's start (its sign the
    direction the move then runs), and the plans that follow have the shape of ``kind``.

    Parameters
    ----------
    segments : sequence of PlanSegment
        The plan as sent (its first segment starts at the run's t = 0).
    commit : PlanCommit
        Its end: the target, the window and the sum of the durations.
    kind : int
        The planner (PLAN's byte 0..3) whose pulses the re-targeted plans take: the profile's
        own kind (the moving starts of ``jerklab.planner`` are the S-curve's and the optimal
        sine jerk's).

    Returns
    -------
    RunningPlan
    """
    if not isinstance(commit, P.PlanCommit):
        raise TypeError(f"commit must be a PlanCommit, got {type(commit).__name__}")
    plan = placed_segments(segments, commit.target, 0.0)
    tc0 = _f32(commit.accel_time)
    v = float(plan.state(tc0)[2]) if commit.accel_time or commit.cruise_time else 0.0
    if v != 0.0:
        plan.sign = math.copysign(1.0, v)
    plan.v_peak = abs(v)
    plan.accel_time, plan.cruise_time = float(commit.accel_time), float(commit.cruise_time)
    acc = np.float32(0.0)
    for g in segments:
        acc = np.float32(acc + np.float32(g.duration))
    return RunningPlan(plan, 0.0, commit.accel_time, commit.cruise_time, float(acc), kind)
