"""Re-targeting a running move: the rule the firmware and the virtual rig share.

A RETARGET (``firmware/PROTOCOL.md`` "Re-targeting") changes the target of the move that runs.
The reference must stay jerk-continuous, so the new plan starts where the running one has
jerk 0 *and* acceleration 0 (see ``docs/THEORY.md`` "Re-targeting"):

* during the acceleration phase: at its end (the half-sine pulses end there, j = a = 0);
* during the cruise: at once, i.e. at the first sample at least :func:`lead_samples` after the
  command (the time the board needs to plan);
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
from jerklab._validate import as_int, as_nonnegative, as_positive, as_real

__all__ = [
    "SegmentPlan",
    "moving_plan",
    "stop_plan",
    "rest_plan",
    "switch_point",
    "lead_samples",
    "BISECTION_STEPS",
]

_TWO_OVER_PI = 2.0 / math.pi
#: bisection halvings of the peak velocity (the firmware's plan_moving default)
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
    """Samples between a RETARGET and the earliest switch (the board plans meanwhile, a few
    bisection steps per tick): ``2 + ceil(24 / max(2, Ts_us // 400))`` -- 14 at 1 ms, 4 at 5 ms."""
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
    the move cannot stop within ``distance`` (mirrors the firmware's ``plan_moving``)."""
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
