"""Several axes that start and arrive together: time and phase synchronization.

ASCII spelling for grep: the per-axis profiles are those of ``jerklab.planner`` (Stojcic eq. 2
for the sine-jerk pulse shape, the linear-jerk S-curve of Yang eqs. 5, 6).

:func:`plan_multi_axis` plans a rest-to-rest move of ``n`` axes (a gantry, Yang et al.'s x–y
stand) from one set of distances and per-axis limits, with one of the single-axis planners of
:mod:`jerklab.planner` (``"scurve"``, ``"sine_jerk_optimal"`` or ``"trapezoid"``):

* ``sync="time"``: every axis starts at 0 and arrives at the common duration ``T``, the longest
  of the axes' time-optimal durations.  The slowest axis keeps its time-optimal profile; every
  other axis gets the time-optimal profile for its own jerk and acceleration limits and a
  *lowered velocity limit* ``v`` chosen, in closed form, so that its duration is exactly ``T``
  (:func:`stretch_to_duration`).  The path in joint space is in general not a straight line.
* ``sync="phase"``: a straight line in joint space.  One normalized profile ``s(t)`` from 0 to 1
  is planned with the limits ``J_n = min_i J_i / |d_i|``, ``A_n = min_i A_i / |d_i|``,
  ``V_n = min_i V_i / |d_i|`` (over the axes that move), and axis ``i`` follows
  ``x_i(t) = d_i s(t)``.  Axis ``i`` then sees at most ``|d_i| J_n <= J_i`` (and the same for the
  acceleration and velocity), so every limit holds; and as ``|s'''| <= J_n`` (etc.) is exactly
  the condition for a straight-line motion to respect every axis's limits, the phase-synchronized
  move is the time-optimal straight-line move for the time-optimal planners (``"scurve"``,
  ``"trapezoid"``), and the fastest straight line of the half-sine family for
  ``"sine_jerk_optimal"``.  Its duration is therefore at least the time-synchronized one, equal
  when one axis sets all three normalized limits.

For rest-to-rest moves phase synchronization is always possible with this construction (the
normalized limits are finite and positive as soon as one axis moves).  It is the non-zero start
and end states of a general (Ruckig-style) problem that can make a straight line impossible:
then the axes' initial velocities need not point along the line.

Against Ruckig (``tests/test_multiaxis.py``, same process): its time synchronization gives the
same duration and the same per-axis positions (to 1e-9); its phase synchronization scales the
limiting axis's profile and, when that breaks another axis's limit, falls back to time
synchronization off the line (about a quarter of random 2-4 axis moves).  Wherever Ruckig's
result is a straight line, its duration equals ours; the normalized construction here always
gives the line.

References
----------
M. J. Stojčić, "Design and implementation of a digital positioning system with controlled jerk",
Facta Universitatis, 2015 (the sine-jerk pulse, Stojčić eq. 2).
X. Yang, P. Ye, Y. Pan, Z. Ma, "The implementation of S-curve acceleration and deceleration using
FPGA", 2013 (the linear-jerk S-curve of Yang eqs. 5, 6; the x–y stand of §4, Fig. 9).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from jerklab._validate import as_finite_array, as_nonnegative, as_positive, at_least
from jerklab.planner import (
    MIN_SYNC_TS,
    Profile,
    ProfileSample,
    SCurveProfile,
    SineJerkOptimalProfile,
    TrapezoidProfile,
    plan_scurve,
    plan_sine_jerk_optimal,
    plan_trapezoid,
)

__all__ = ["plan_multi_axis", "MultiAxisPlan", "stretch_to_duration", "SYNCS", "PLANNERS"]

#: synchronization modes of :func:`plan_multi_axis`
SYNCS = ("time", "phase")
#: single-axis planners :func:`plan_multi_axis` can synchronize
PLANNERS = ("scurve", "sine_jerk_optimal", "trapezoid")

_CLASS = {
    "scurve": SCurveProfile,
    "sine_jerk_optimal": SineJerkOptimalProfile,
    "trapezoid": TrapezoidProfile,
}
_LIMIT_KEYS = ("max_jerk", "max_accel", "max_velocity")
_TWO_OVER_PI = 2.0 / math.pi
_SQRT3 = math.sqrt(3.0)
_INF = math.inf


# ---------------------------------------------------------------------------------------------
# one axis: the optimal profile, and the same limits stretched to a longer duration
# ---------------------------------------------------------------------------------------------
def _plan_one(planner, distance, J, A, V) -> Profile:
    if planner == "scurve":
        return plan_scurve(distance, J, A, V)
    if planner == "sine_jerk_optimal":
        return plan_sine_jerk_optimal(distance, J, A, V)
    return plan_trapezoid(distance, A, V)


def _times(p: Profile):
    """``(tj, ta, tv)`` of a 7-segment profile or of a trapezoid (``tj = 0``)."""
    if p.kind == "trapezoid":
        ta, tv, _ = p.phase_times
        return 0.0, ta, tv
    tj, ta, _, tv = p.phase_times[:4]
    return tj, ta, tv


def _jerk_for_distance(kind, d, tj, ta, tv):
    """Jerk parameter (peak jerk; acceleration of a trapezoid) that makes the phase times cover ``d``.

    ``d = a_pk (tj + ta)(2 tj + ta + tv)`` with ``a_pk = k jpar tj`` (``k = 1`` linear jerk,
    ``2/pi`` half-sine pulses) or ``a_pk = jpar`` (trapezoid), as in ``Profile.synchronized``.
    """
    if kind == "trapezoid":
        return d / (ta * (ta + tv))
    k = _TWO_OVER_PI if kind == "sine_jerk_optimal" else 1.0
    return d / (k * tj * (tj + ta) * (2.0 * tj + ta + tv))


def _make(kind, distance, tj, ta, tv, jpar, limits) -> Profile:
    return _CLASS[kind](distance, tj, ta, tv, jpar, limits)


def _standstill(kind, duration, limits) -> Profile:
    """A zero-distance axis that stays at rest for ``duration`` (all of it a "cruise" at speed 0)."""
    return _make(kind, 0.0, 0.0, 0.0, duration, 0.0, limits)


def _fill(T, tj, ta):
    """``(tj, ta, tv)`` with ``tv >= 0`` and ``2 (2 tj + ta) + tv == T`` in floating point.

    ``Profile.duration`` sums the phase times that way.  ``T - a`` may round, and when the bits of
    ``a = 2 (2 tj + ta)`` below ``ulp(T)`` make every ``a + tv`` a tie, no cruise gives ``T``
    exactly: then ``a`` is lowered by one of its ulps (through ``ta``, or ``tj`` without a plateau;
    a change at the round-off level of the sum) and the cruise searched again.
    """
    for _ in range(8):
        a = 2.0 * (2.0 * tj + ta)
        tv = max(T - a, 0.0)
        for _k in range(8):  # step tv by ulps until the sum is T
            tot = a + tv
            if tot == T:
                return tj, ta, tv
            if tv == 0.0 and tot > T:
                break
            tv = max(math.nextafter(tv, math.inf if tot < T else -math.inf), 0.0)
        if ta > 0.0:
            ta = max(ta - math.ulp(2.0 * tj + ta), 0.0)
        else:
            tj = max(tj - math.ulp(tj), 0.0)
    return tj, ta, max(T - 2.0 * (2.0 * tj + ta), 0.0)  # pragma: no cover - not met


def stretch_to_duration(profile: Profile, duration) -> Profile:
    """The same move and limits as ``profile`` (a time-optimal plan), lasting exactly ``duration``.

    The result is the time-optimal profile for the profile's jerk and acceleration limits and a
    lowered velocity limit ``v``; ``v`` solves ``duration = d / v + t_acc(v)`` in closed form, where
    ``t_acc(v)`` is the time to reach ``v`` from rest (a cruise at ``v`` fills the rest of the
    distance):

    * trapezoid (acceleration ``A``): ``t_acc = v / A``, so ``v^2 / A - T v + d = 0`` and
      ``v = 2 d / (T + sqrt(T^2 - 4 d / A))`` (the smaller root, written without cancellation);
    * 7 segments with an acceleration plateau (``v >= A^2 / J``, ``J`` the linear jerk, ``2 J/pi``
      for half-sine pulses): ``t_acc = v / A + A / J``, the same quadratic with ``T - A/J``
      for ``T``;
    * without a plateau (``v < A^2 / J``, i.e. ``T > d J / A^2 + 2 A / J``): with the pulse length
      ``tj = sqrt(v / J)``, ``T = d / (J tj^2) + 2 tj``, the cubic ``2 tj^3 - T tj^2 + d/J = 0``,
      whose smaller positive root is (trigonometric form, no cancellation)
      ``tj = T/3 sin^2(theta/2) + T/(2 sqrt 3) sin(theta)``, ``theta = 2/3 asin(sqrt(27 d / (J T^3)))``.

    The duration ``T(v) = d / v + t_acc(v)`` falls strictly with ``v`` wherever the cruise is not
    negative (``dT/dv = -d/v^2 + t_acc'(v) < 0``), so each ``T`` longer than the optimum has exactly
    one such ``v``, below the optimal profile's peak velocity.  The cruise is then set to
    ``T - 2 t_acc`` and the jerk (the acceleration of a trapezoid) to the value that covers the
    distance: the phase times sum to ``T`` exactly in floating point (the cruise is adjusted by
    ulps) and the end point is exactly ``d``.  ``v`` is capped at the optimal peak velocity, so a
    rounding error of ``v`` can raise the jerk or acceleration by a few ulp only (at most 1.4e-15
    relative over 6e4 random moves).  ``tests/test_multiaxis.py`` re-plans each stretched axis with
    the single-axis planner and its peak velocity as the limit: the same duration to 1e-12.

    Parameters
    ----------
    profile : Profile
        A rest-to-rest plan of kind ``"scurve"``, ``"sine_jerk_optimal"`` or ``"trapezoid"``.
    duration : float
        Target duration (s), ``>= profile.duration`` (a relative 1e-12 below is taken as equal).

    Returns
    -------
    Profile
        Of the same kind, distance and limits, with ``duration`` equal to the requested one.
        A zero-distance profile becomes a standstill of that duration.
    """
    if not isinstance(profile, Profile) or profile.kind not in _CLASS:
        raise ValueError(f"profile must be a Profile of kind {PLANNERS}, got {profile!r}")
    T = as_nonnegative("duration", duration)
    try:
        return _stretch(profile, T)
    except (ZeroDivisionError, OverflowError):
        raise ValueError(
            f"duration = {T!r} s: no finite profile of distance {profile.distance!r} lasts that "
            f"long (a phase time underflows): scale the units"
        ) from None


def _stretch(profile, T):
    """:func:`stretch_to_duration` without the argument checks."""
    kind = profile.kind
    limits = (profile.max_jerk, profile.max_accel, profile.max_velocity)
    if profile.distance == 0.0:
        return _standstill(kind, T, limits)
    T0 = profile.duration
    if T == T0:
        return profile
    if T < T0 * (1.0 - 1e-12):
        raise ValueError(
            f"duration = {T!r} s is shorter than the time-optimal {T0!r} s of this move"
        )
    d = abs(profile.distance)
    tj0, ta0, tv0 = _times(profile)
    if T <= T0:
        tj, ta = tj0, ta0
    else:
        A = profile.max_accel
        v0 = profile.peak_velocity  # the optimum's peak: never exceeded
        if kind == "trapezoid":
            tj = 0.0
            v = 2.0 * d / (T + math.sqrt(max(T * T - 4.0 * d / A, 0.0)))
            ta = min(v, v0) / A
        else:
            J = profile.max_jerk * (_TWO_OVER_PI if kind == "sine_jerk_optimal" else 1.0)
            tja = A / J  # pulse length up to the acceleration limit
            # v >= A^2/J (a plateau at A) needs the optimum to reach A^2/J, and T up to T(A^2/J)
            if v0 >= A * tja and T <= d / (A * tja) + 2.0 * tja:
                B = T - tja
                v = 2.0 * d / (B + math.sqrt(max(B * B - 4.0 * d / A, 0.0)))
                tj, ta = tja, max(min(v, v0) / A - tja, 0.0)
            else:  # no plateau: the cubic in tj
                z = min(27.0 * (d / J) / (T * T * T), 1.0)
                th = (2.0 / 3.0) * math.asin(math.sqrt(z))
                tj = T / 3.0 * math.sin(0.5 * th) ** 2 + T / (2.0 * _SQRT3) * math.sin(th)
                tj = min(tj, math.sqrt(v0 / J))
                ta = 0.0
    tj, ta, tv = _fill(T, tj, ta)
    jpar = _jerk_for_distance(kind, d, tj, ta, tv)
    if not (math.isfinite(jpar) and jpar > 0.0):
        raise ValueError(
            f"no finite profile of distance {profile.distance!r} lasting {T!r} s "
            f"(a phase time underflows): scale the units"
        )
    return _make(kind, profile.distance, tj, ta, tv, jpar, limits)


# ---------------------------------------------------------------------------------------------
# input checking
# ---------------------------------------------------------------------------------------------
def _axis_limits(limits_per_axis, n, planner):
    """One ``(max_jerk, max_accel, max_velocity)`` float triple per axis (``None`` jerk: trapezoid)."""
    if type(limits_per_axis) in (list, tuple) and len(limits_per_axis) == n:
        out = []
        for row in limits_per_axis:  # fast path: (J, A, V) tuples of finite floats > 0
            if not (type(row) is tuple and len(row) == 3):
                break
            J, A, V = row
            if not (
                type(A) is float
                and type(V) is float
                and 0.0 < A < _INF
                and 0.0 < V < _INF
                and (type(J) is float and 0.0 < J < _INF or J is None and planner == "trapezoid")
            ):
                break
            out.append(row)
        else:
            return out
    if isinstance(limits_per_axis, (str, bytes, Mapping)) or not isinstance(
        limits_per_axis, (Sequence, np.ndarray)
    ):
        raise ValueError(
            "limits_per_axis must be a sequence with one (max_jerk, max_accel, max_velocity) "
            f"tuple or dict per axis, got {limits_per_axis!r:.80}"
        )
    rows = list(limits_per_axis)
    if len(rows) != n:
        raise ValueError(
            f"limits_per_axis has {len(rows)} entries for {n} distances: give one per axis"
        )
    out = []
    for i, row in enumerate(rows):
        name = f"limits_per_axis[{i}]"
        if isinstance(row, Mapping):
            unknown = set(row) - set(_LIMIT_KEYS)
            if unknown:
                raise ValueError(
                    f"{name} has unknown keys {sorted(map(str, unknown))}; expected {_LIMIT_KEYS}"
                )
            missing = [k for k in _LIMIT_KEYS[1:] if k not in row]
            if planner != "trapezoid" and "max_jerk" not in row:
                missing.insert(0, "max_jerk")
            if missing:
                raise ValueError(f"{name} lacks {missing}")
            vals = (row.get("max_jerk"), row["max_accel"], row["max_velocity"])
        elif isinstance(row, (Sequence, np.ndarray)) and not isinstance(row, (str, bytes)):
            vals = tuple(row)
            if len(vals) != 3:
                raise ValueError(
                    f"{name} must be (max_jerk, max_accel, max_velocity), got {len(vals)} values"
                )
        else:
            raise ValueError(
                f"{name} must be a (max_jerk, max_accel, max_velocity) tuple or a dict, "
                f"got {row!r:.60}"
            )
        J, A, V = vals
        if planner == "trapezoid" and J is None:
            J = None
        else:
            J = as_positive(f"{name}.max_jerk", J)
        out.append((J, as_positive(f"{name}.max_accel", A), as_positive(f"{name}.max_velocity", V)))
    return out


# ---------------------------------------------------------------------------------------------
# the plan
# ---------------------------------------------------------------------------------------------
class MultiAxisPlan:
    """A synchronized rest-to-rest move of several axes (:func:`plan_multi_axis`).

    Attributes
    ----------
    distances : ndarray
        Signed distance of each axis, shape ``(n,)``.
    sync : {"time", "phase"}
    planner : {"scurve", "sine_jerk_optimal", "trapezoid"}
    limits : tuple of tuple
        ``(max_jerk, max_accel, max_velocity)`` of each axis (``max_jerk`` ``None`` for a trapezoid
        planned without one).
    axes : tuple of Profile
        One profile per axis, each of duration :attr:`duration` (a zero-distance axis is a
        standstill of that length), with the interface of :class:`jerklab.planner.Profile`.
    duration : float
        Common duration (s).
    min_durations : tuple of float
        Each axis's time-optimal duration on its own (s); ``sync="time"`` has
        ``duration == max(min_durations)``.
    path : Profile or None
        ``sync="phase"``: the normalized profile ``s(t)`` from 0 to 1 (distance 1, the normalized
        limits); ``None`` for time synchronization or when no axis moves.
    """

    __slots__ = (
        "distances",
        "sync",
        "planner",
        "limits",
        "axes",
        "duration",
        "min_durations",
        "path",
    )

    def __init__(self, distances, sync, planner, limits, axes, duration, min_durations, path):
        self.distances = distances
        self.sync = sync
        self.planner = planner
        self.limits = limits
        self.axes = axes
        self.duration = duration
        self.min_durations = min_durations
        self.path = path

    def __len__(self) -> int:
        return len(self.axes)

    @property
    def normalized_limits(self):
        """``(J_n, A_n, V_n)`` of the phase-synchronized path (``None`` otherwise)."""
        if self.path is None:
            return None
        return (self.path.max_jerk, self.path.max_accel, self.path.max_velocity)

    def sample(self, t) -> ProfileSample:
        """Every axis at the times ``t``: arrays of shape ``(n_axes,) + shape(t)``.

        ``sync="phase"`` evaluates the normalized path once and scales it, ``x_i = d_i s(t)``
        (also for the jerk, acceleration and velocity), so every sample lies on the straight line
        to round-off; ``axes[i].sample(t)`` gives the same values to a few ulp.

        Parameters
        ----------
        t : float or array_like
            Times (s); before 0 every axis is at rest at 0, after :attr:`duration` at its distance.
        """
        t = as_finite_array("t", t)
        d = self.distances.reshape((-1,) + (1,) * t.ndim)
        if self.path is not None:
            s = self.path.sample(t)
            tt = np.broadcast_to(s.t, d.shape[:1] + t.shape).copy()
            pos = d * s.position
            pos = np.where(t >= self.duration, d, pos)  # the target, exactly
            return ProfileSample(tt, d * s.jerk, d * s.accel, d * s.velocity, pos)
        parts = [p.sample(t) for p in self.axes]
        return ProfileSample(
            *(np.stack([getattr(p, f) for p in parts]) for f in ProfileSample._fields)
        )

    def synchronized(self, Ts) -> "MultiAxisPlan":
        """The same move with every phase time of every axis a whole multiple of ``Ts``, still together.

        ``axes[i].synchronized(Ts)`` rounds each axis on its own, so the axes would no longer
        end together; this rounds them as one:

        * phase sync: the normalized path is synchronized (``Profile.synchronized``: phases rounded
          up, the jerk lowered to keep the distance) and scaled again, so the axes stay on the line;
        * time sync: each axis's pulse and plateau times are rounded up to whole samples; the
          common duration is the longest axis's total with its cruise rounded up too, in whole
          samples; every axis's cruise fills it, and its jerk (a trapezoid's acceleration) is
          lowered to keep its distance.

        No phase gets shorter, so no peak grows: every limit still holds (as for one axis).

        Parameters
        ----------
        Ts : float
            Sample time (s), at least ``planner.MIN_SYNC_TS`` = 1 ns.
        """
        Ts = at_least("Ts", as_positive("Ts", Ts), MIN_SYNC_TS, "planner.MIN_SYNC_TS, 1 ns")
        if self.duration == 0.0:
            return self
        kind = self.planner
        if self.path is not None:
            path = self.path.synchronized(Ts)
            return _scaled(self.distances, self.sync, kind, self.limits, self.min_durations, path)
        counts = []
        for p, di in zip(self.axes, self.distances.tolist()):
            if di == 0.0:
                counts.append(None)
                continue
            tj, ta, tv = _times(p)
            counts.append((_samples(tj, Ts), _samples(ta, Ts), _samples(tv, Ts)))
        n_total = max(4 * nj + 2 * na + nv for nj, na, nv in (c for c in counts if c is not None))
        T = n_total * Ts
        axes = []
        for p, di, c, lim in zip(self.axes, self.distances.tolist(), counts, self.limits):
            if c is None:
                axes.append(_standstill(kind, T, lim))
                continue
            tj, ta, tv = _fill(T, c[0] * Ts, c[1] * Ts)
            axes.append(
                _make(kind, di, tj, ta, tv, _jerk_for_distance(kind, abs(di), tj, ta, tv), lim)
            )
        return MultiAxisPlan(
            self.distances, self.sync, kind, self.limits, tuple(axes), T, self.min_durations, None
        )

    def to_dict(self) -> dict:
        """JSON-able description: sync, planner, duration, and each axis's ``Profile.to_dict()``."""
        return {
            "sync": self.sync,
            "planner": self.planner,
            "duration": self.duration,
            "distances": [float(x) for x in self.distances],
            "min_durations": list(self.min_durations),
            "normalized_limits": None if self.path is None else list(self.normalized_limits),
            "axes": [p.to_dict() for p in self.axes],
        }

    def __repr__(self) -> str:
        return (
            f"MultiAxisPlan(sync={self.sync!r}, planner={self.planner!r}, "
            f"distances={self.distances.tolist()!r}, duration={self.duration!r})"
        )


def plan_multi_axis(distances, limits_per_axis, sync="time", planner="scurve") -> MultiAxisPlan:
    """Plan a rest-to-rest move of several axes that start and arrive together.

    Parameters
    ----------
    distances : array_like of float
        Signed distance of each axis, shape ``(n,)``, ``n >= 1`` (zero: the axis stays at rest).
    limits_per_axis : sequence
        One entry per axis: a ``(max_jerk, max_accel, max_velocity)`` tuple (or a row of an
        ``(n, 3)`` array) or a dict with those keys; all > 0.  For ``planner="trapezoid"`` the
        jerk is not used and may be ``None`` (or left out of the dict).
    sync : {"time", "phase"}
        ``"time"``: common duration = the slowest axis's time-optimal duration; every other axis
        follows its time-optimal profile under a lowered velocity limit found in closed form
        (:func:`stretch_to_duration`).  ``"phase"``: a straight line in joint space, one profile
        ``s(t)`` on ``[0, 1]`` planned with the limits ``min_i limit_i / |d_i|`` and scaled by
        ``d_i`` (see the module docstring for why this is always feasible from rest to rest and
        the fastest straight line).
    planner : {"scurve", "sine_jerk_optimal", "trapezoid"}
        The single-axis planner (:mod:`jerklab.planner`).  The published ``"sine_jerk"``
        (Stojčić eq. 4) is refused: it has no free parameter to stretch a move to a given duration
        with its peak jerk held.

    Returns
    -------
    MultiAxisPlan
        ``.duration``, ``.axes`` (one :class:`jerklab.planner.Profile` each, all of that
        duration), ``.sample(t)`` (arrays per axis).

    Raises
    ------
    ValueError
        Naming the parameter: a non-finite distance, a limit that is not > 0 (e.g.
        ``limits_per_axis[1].max_accel``), a wrong number of limit entries, an unknown ``sync``
        or ``planner``, or limits too small for a finite plan.

    Notes
    -----
    Tolerances: the time-synchronized axes have durations equal to the common one exactly (their
    phase times sum to it in floating point) and reach their distances exactly (closed form, no
    iteration); every limit holds to a few ulp.  The phase-synchronized axes are ``d_i s(t)``: the
    plan's samples are on the line to round-off (tests check 1e-9 relative to the distance).
    """
    if sync not in SYNCS:
        raise ValueError(f"sync must be one of {SYNCS}, got {sync!r}")
    if planner not in PLANNERS:
        hint = (
            " (the published sine-jerk planner cannot be stretched to a given duration: use "
            "'sine_jerk_optimal')"
            if planner == "sine_jerk"
            else ""
        )
        raise ValueError(f"planner must be one of {PLANNERS}, got {planner!r}{hint}")
    if (
        type(distances) in (list, tuple)
        and distances
        and all(type(x) is float and -_INF < x < _INF for x in distances)
    ):
        dl = list(distances)  # fast path: finite floats
        d = np.array(dl)
    else:
        d = as_finite_array("distances", distances)
        if d.ndim != 1 or d.size == 0:
            raise ValueError(
                f"distances must be a non-empty 1-D sequence (one per axis), got shape {d.shape}"
            )
        d = d.copy()
        dl = d.tolist()
    limits = tuple(_axis_limits(limits_per_axis, len(dl), planner))
    optimal = [_plan_one(planner, di, *lim) for di, lim in zip(dl, limits)]
    min_durations = tuple(p.duration for p in optimal)
    if not any(dl):
        axes = tuple(_standstill(planner, 0.0, lim) for lim in limits)
        return MultiAxisPlan(d, sync, planner, limits, axes, 0.0, min_durations, None)
    if sync == "time":
        T = max(min_durations)
        axes = tuple(_stretch(p, T) for p in optimal)
        return MultiAxisPlan(d, sync, planner, limits, axes, T, min_durations, None)
    # phase: one normalized profile on [0, 1]
    mv = [(abs(di), lim) for di, lim in zip(dl, limits) if di != 0.0]
    A_n = min(L[1] / x for x, L in mv)  # may overflow to inf for a tiny distance:
    V_n = min(L[2] / x for x, L in mv)  # the min over the axes is what counts
    J_n = None if planner == "trapezoid" else min(L[0] / x for x, L in mv)
    try:
        path = _plan_one(planner, 1.0, J_n, A_n, V_n)
    except ValueError as exc:
        raise ValueError(
            f"distances and limits_per_axis give normalized limits (J, A, V) = "
            f"({J_n!r}, {A_n!r}, {V_n!r}) with no finite plan: {exc}"
        ) from None
    return _scaled(d, sync, planner, limits, min_durations, path)


def _scaled(d, sync, planner, limits, min_durations, path) -> MultiAxisPlan:
    """The phase-synchronized plan: axis ``i`` is the normalized ``path`` scaled by ``d_i``."""
    tj, ta, tv = _times(path)
    jn = path.peak_accel if planner == "trapezoid" else path.peak_jerk
    axes = []
    for di, lim_i in zip(d.tolist(), limits):
        if di == 0.0:
            axes.append(_standstill(planner, path.duration, lim_i))
        else:
            axes.append(_make(planner, di, tj, ta, tv, jn * abs(di), lim_i))
    return MultiAxisPlan(d, sync, planner, limits, tuple(axes), path.duration, min_durations, path)


def _samples(x, Ts):
    """Whole samples covering ``x`` (as ``Profile.synchronized``: a relative 1e-12 below a whole
    number counts as that number); 0 stays 0."""
    if x <= 0.0:
        return 0
    r = x / Ts
    return max(math.ceil(r - min(1e-12 * r, 1e-6)), 1)
