"""Rest-to-rest trajectory planners: Stojčić's sine-jerk profile and its peers.

ASCII spelling for grep: Stojcic eqs. 2–4, 15.

Four planners share one :class:`Profile` interface (see ``docs/INTERFACES.md``):

* :func:`plan_sine_jerk` -- Stojčić (2015) exactly as published (Stojčić eqs. 2–4, Fig. 2): the jerk
  is one full sine period of peak ``max_jerk`` while accelerating, a cruise, and the mirrored period
  while decelerating.  The peak jerk is *always* ``max_jerk``; when the acceleration limit binds,
  the published algorithm shortens the pulse instead of adding an acceleration plateau, which makes
  it slow (up to hundreds of times slower than a time-optimal planner on the same limits).
* :func:`plan_sine_jerk_optimal` -- the time-optimal profile made of half-sine jerk pulses of peak
  ``max_jerk``, with an acceleration plateau and a cruise where they help.  A half-sine jerk pulse of
  peak J and length Tj changes the acceleration by 2 J Tj / pi, exactly like a constant jerk 2J/pi
  over the same Tj, and the acceleration phase is symmetric about its middle, so this profile has
  exactly the duration of the linear-jerk S-curve planned with jerk 2J/pi.
* :func:`plan_scurve` -- the time-optimal linear-jerk 7-segment S-curve (Yang et al. 2013 is the
  special case without an acceleration plateau).
* :func:`plan_trapezoid` -- constant acceleration, cruise, constant deceleration (infinite jerk).

All take SI values, accept a negative ``distance`` (a move backwards) and zero, and return a
:class:`Profile` whose :meth:`Profile.sample` evaluates the closed form (polynomials and sine
terms, vectorized with numpy), never an integration.

:func:`plan_scurve` and :func:`plan_sine_jerk_optimal` also start from any state
(``initial_velocity``, ``initial_accel``) and end at any ``final_velocity``: they then return an
:class:`AnyStateProfile` (up to a dozen segments, a braking pre-trajectory first when the start is
outside the limits), planned by the one-axis time-optimal solver of ``jerklab._onedof``
(docs/THEORY.md, "Any start state").  The rest of this docstring is about rest-to-rest moves.

Every profile is symmetric: the velocity satisfies ``v(t) = v(duration - t)``, so the closed form is
evaluated on the first half and mirrored (``x(t) = distance - x(duration - t)``); the end state is
therefore exactly ``distance`` at rest.  Inside the acceleration phase the acceleration is symmetric
about the phase's middle, which is also used: the falling pulse is the rising one mirrored.

:func:`plan_batch` plans millions of moves at once (a numba-compiled loop when numba is installed,
else numpy in cache-sized chunks) and returns a :class:`BatchPlan` with the same closed-form sampler.

:meth:`Profile.synchronized` stretches every phase to whole sample times (the fix for the drift of
Stojčić's eq. 15 recursion, which :meth:`Profile.discretize` keeps to show it).

References
----------
M. J. Stojčić, "Design and implementation of a digital positioning system with controlled jerk",
Facta Universitatis, 2015 (Stojčić eqs. 2–4, 15 and Fig. 2).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jerklab import _onedof
from jerklab._validate import (
    as_finite_array,
    as_index,
    as_nonnegative,
    as_positive,
    as_real,
    at_least,
)

__all__ = [
    "Profile",
    "AnyStateProfile",
    "ProfileSample",
    "BatchPlan",
    "plan_sine_jerk",
    "plan_sine_jerk_optimal",
    "plan_scurve",
    "plan_trapezoid",
    "plan_batch",
    "plan_batch_any_state",
    "AnyStateBatch",
    "KINDS",
]

_PI = math.pi
_INF = math.inf
_TWO_OVER_PI = 2.0 / math.pi
#: kinds of profile, as in ``Profile.kind``
KINDS = ("sine_jerk", "sine_jerk_optimal", "scurve", "trapezoid")

# shape of the jerk pulses of a kind
_SINE, _LINEAR, _STEP = 0, 1, 2
_SHAPE = {"sine_jerk": _SINE, "sine_jerk_optimal": _SINE, "scurve": _LINEAR, "trapezoid": _STEP}

# a phase time within this relative distance of a whole number of samples is taken as that number
_SYNC_RTOL = 1e-12


class ProfileSample(NamedTuple):
    """Values of a profile at the times ``t`` (arrays of the shape of ``t``)."""

    t: np.ndarray
    jerk: np.ndarray
    accel: np.ndarray
    velocity: np.ndarray
    position: np.ndarray


# ---------------------------------------------------------------------------------------------
# closed form, shared by Profile.sample and BatchPlan.sample
# ---------------------------------------------------------------------------------------------
def _evaluate(t, distance, tj, ta, tv, jpar, shape):
    """Closed-form jerk, acceleration, velocity and position of symmetric rest-to-rest profiles.

    All arguments broadcast against each other.  ``jpar`` is the constant jerk (``_LINEAR``), the
    peak of the half-sine jerk pulses (``_SINE``) or the acceleration (``_STEP``, with ``tj = 0``).
    ``distance`` is signed; every other parameter is >= 0.

    The acceleration phase (length ``2 tj + ta``) is a rising pulse of length ``tj``, a plateau of
    length ``ta`` and a falling pulse; the rising pulse, with ``w = pi / tj``, ``c = jpar / w``, is::

        linear: j = J,           a = J r,          v = J r^2/2,             x = J r^3/6
        sine:   j = J sin(w r),  a = c (1-cos wr), v = c (r - sin(wr)/w),   x = c (r^2/2 - (1-cos wr)/w^2)

    (Stojčić eq. 2 integrated three times).  The falling pulse at ``u = Tacc - r`` follows from the
    symmetry ``a(Tacc - r) = a(r)``: ``v = V - v(r)``, ``x = V Tacc/2 - V r + x(r)``; the cruise is
    ``x = V Tacc/2 + V (u - Tacc)``; the deceleration mirrors the acceleration:
    ``x(t) = D - x(T - t)``, ``v(t) = v(T - t)``, ``a(t) = -a(T - t)``, ``j(t) = j(T - t)``.
    """
    t = np.asarray(t, dtype=float)
    dist = np.asarray(distance, dtype=float)
    sgn = np.sign(dist)
    d = np.abs(dist)
    tj = np.asarray(tj, dtype=float)
    ta = np.asarray(ta, dtype=float)
    tv = np.asarray(tv, dtype=float)
    jpar = np.asarray(jpar, dtype=float)
    tacc = 2.0 * tj + ta
    T = 2.0 * tacc + tv
    half = 0.5 * T
    mirror = t > half
    s = np.where(mirror, T - t, t)
    s = np.maximum(s, 0.0)  # before 0 and after T: at rest
    # peak acceleration and velocity of the acceleration phase
    if shape == _SINE:
        apk = _TWO_OVER_PI * jpar * tj
    elif shape == _LINEAR:
        apk = jpar * tj
    else:
        apk = jpar
    vpk = apk * (tj + ta)
    xacc = 0.5 * vpk * tacc  # position at the end of the acceleration phase
    in_rise = s < tj
    in_plat = ~in_rise & (s <= tj + ta)
    in_fall = (s > tj + ta) & (s < tacc)
    # r: time into the rising pulse (rising part directly, falling part by symmetry)
    r = np.where(in_fall, tacc - s, s)
    r = np.clip(r, 0.0, tj)
    if shape == _SINE:
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(tj > 0.0, _PI / np.where(tj > 0.0, tj, 1.0), 0.0)
            c = np.where(tj > 0.0, jpar / np.where(w > 0.0, w, 1.0), 0.0)
            wr = w * r
            sn = np.sin(wr)
            omc = 2.0 * np.sin(0.5 * wr) ** 2  # 1 - cos(wr), without cancellation
            jr = jpar * sn
            ar = c * omc
            winv = np.where(w > 0.0, 1.0 / np.where(w > 0.0, w, 1.0), 0.0)
            # v = c (wr - sin wr)/w and x = c (wr^2/2 - (1 - cos wr))/w^2, by their Taylor series
            # where the differences would cancel (relative error < 1e-16 below wr = 0.1)
            x2 = wr * wr
            small = wr < 0.1
            wms = np.where(
                small,
                wr
                * x2
                * (1 / 6 - x2 * (1 / 120 - x2 * (1 / 5040 - x2 * (1 / 362880 - x2 / 39916800)))),
                wr - sn,
            )
            hmo = np.where(
                small,
                x2
                * x2
                * (
                    1 / 24 - x2 * (1 / 720 - x2 * (1 / 40320 - x2 * (1 / 3628800 - x2 / 479001600)))
                ),
                0.5 * x2 - omc,
            )
            vr = c * wms * winv
            xr = c * hmo * winv * winv
    elif shape == _LINEAR:
        jr = jpar * np.ones_like(r)
        ar = jpar * r
        vr = 0.5 * ar * r
        xr = vr * r / 3.0
    else:
        jr = ar = vr = xr = np.zeros(r.shape)
    # plateau
    p = s - tj
    if shape == _SINE:
        v1 = 0.5 * apk * tj  # velocity at the end of the rising pulse
        x1 = apk * tj * tj * (0.25 - 1.0 / (_PI * _PI))
    elif shape == _LINEAR:
        v1 = 0.5 * apk * tj
        x1 = apk * tj * tj / 6.0
    else:
        v1 = x1 = 0.0
    jerk = np.where(in_rise, jr, np.where(in_fall, -jr, 0.0))
    accel = np.where(in_rise | in_fall, ar, np.where(in_plat, apk, 0.0))
    vel = np.where(in_rise, vr, np.where(in_plat, v1 + apk * p, np.where(in_fall, vpk - vr, vpk)))
    pos = np.where(
        in_rise,
        xr,
        np.where(
            in_plat,
            x1 + p * (v1 + 0.5 * apk * p),
            np.where(in_fall, xacc - vpk * r + xr, xacc + vpk * (s - tacc)),
        ),
    )
    outside = (t <= 0.0) | (t >= T)
    jerk = np.where(outside, 0.0, jerk)
    accel = np.where(outside, 0.0, np.where(mirror, -accel, accel))
    vel = np.where(outside, 0.0, vel)
    pos = np.where(mirror, d - pos, pos)
    pos = np.where(t <= 0.0, 0.0, np.where(t >= T, d, pos))
    if shape == _STEP:
        # a trapezoid's acceleration jumps at t = 0: keep the right-continuous value there
        accel = np.where((t == 0.0) & (T > 0.0), apk, accel)
    bshape = np.broadcast_shapes(t.shape, sgn.shape, T.shape)
    return ProfileSample(
        np.broadcast_to(t, bshape).copy(),
        np.broadcast_to(sgn * jerk, bshape).copy(),
        np.broadcast_to(sgn * accel, bshape).copy(),
        np.broadcast_to(sgn * vel, bshape).copy(),
        np.broadcast_to(sgn * pos, bshape).copy(),
    )


def _ceil_multiple(x: float, Ts: float) -> float:
    """Smallest whole multiple of ``Ts`` that is >= ``x`` (up to a relative 1e-12, at most 1e-6 Ts)."""
    if x <= 0.0:
        return 0.0
    r = x / Ts
    n = math.ceil(r - min(_SYNC_RTOL * r, 1e-6))  # never more than 1e-6 sample below x
    return max(n, 1) * Ts


# ---------------------------------------------------------------------------------------------
# profiles
# ---------------------------------------------------------------------------------------------
class Profile:
    """A planned symmetric rest-to-rest move (base class of every planner's result).

    Attributes
    ----------
    kind : str
        ``"sine_jerk"``, ``"sine_jerk_optimal"``, ``"scurve"`` or ``"trapezoid"``.
    distance : float
        Signed length of the move (any unit; rad for a motor).
    duration : float
        Length of the move (s).
    phase_times : tuple of float
        Segment durations (s), summing to ``duration``: 7 segments (rising jerk pulse, acceleration
        plateau, falling pulse, cruise, and the mirror) for the S-curve and the optimal sine profile;
        Stojčić eq. 2's three intervals ``(T, t_v, T)`` for the published sine profile; ``(t_a, t_v, t_a)``
        for the trapezoid.
    peak_jerk, peak_accel, peak_velocity : float
        Magnitudes actually reached (``inf`` jerk for the trapezoid's acceleration steps).
    max_jerk, max_accel, max_velocity : float
        The limits the profile was planned for (``None`` jerk for the trapezoid).
    """

    __slots__ = ("distance", "_tj", "_ta", "_tv", "_jpar", "_limits")
    kind = "profile"

    def __init__(self, distance, tj, ta, tv, jpar, limits):
        self.distance = distance
        self._tj = tj
        self._ta = ta
        self._tv = tv
        self._jpar = jpar
        self._limits = limits

    @property
    def max_jerk(self):
        """Jerk limit the move was planned for (``None`` for a trapezoid)."""
        return self._limits[0]

    @property
    def max_accel(self):
        """Acceleration limit the move was planned for."""
        return self._limits[1]

    @property
    def max_velocity(self):
        """Velocity limit the move was planned for."""
        return self._limits[2]

    # --- derived quantities -------------------------------------------------------------------
    @property
    def duration(self) -> float:
        """Total time of the move (s): ``2 (2 tj + ta) + tv``."""
        return 2.0 * (2.0 * self._tj + self._ta) + self._tv

    @property
    def phase_times(self) -> tuple:
        tj, ta, tv = self._tj, self._ta, self._tv
        return (tj, ta, tj, tv, tj, ta, tj)

    @property
    def peak_jerk(self) -> float:
        if self.distance == 0.0:
            return 0.0
        return self._jpar

    @property
    def peak_accel(self) -> float:
        shape = _SHAPE[self.kind]
        if shape == _SINE:
            return _TWO_OVER_PI * self._jpar * self._tj
        if shape == _LINEAR:
            return self._jpar * self._tj
        return self._jpar if self.distance != 0.0 else 0.0

    @property
    def peak_velocity(self) -> float:
        return self.peak_accel * (self._tj + self._ta)

    # --- evaluation ---------------------------------------------------------------------------
    def sample(self, t) -> ProfileSample:
        """Jerk, acceleration, velocity and position at the times ``t`` (closed form).

        Parameters
        ----------
        t : float or array_like
            Times (s).  Before 0 the move is at rest at 0, after ``duration`` at rest at
            ``distance``.

        Returns
        -------
        ProfileSample
            Arrays of the shape of ``t``.
        """
        t = as_finite_array("t", t)
        return _evaluate(
            t, self.distance, self._tj, self._ta, self._tv, self._jpar, _SHAPE[self.kind]
        )

    def synchronized(self, Ts) -> "Profile":
        """The same move with every phase time a whole multiple of ``Ts``.

        Each phase time is rounded up to the next multiple of the sample time; the peak jerk
        (the acceleration for a trapezoid) is then lowered so that the move still ends exactly at
        ``distance``.  As no phase got shorter, the peak acceleration and velocity do not grow
        either, so every limit still holds.  A controller sampling at ``Ts`` then sees every
        phase boundary on a sample (Stojčić's rig samples at Ts = 5 ms).

        Parameters
        ----------
        Ts : float
            Sample time (s), at least ``MIN_SYNC_TS`` = 1 ns (faster than any controller and
            than the FPGA's 50 MHz clock; a smaller ``Ts`` raises ValueError naming the limit).
            Any number of samples per move is legal (2e17 and more).
        """
        Ts = at_least("Ts", as_positive("Ts", Ts), MIN_SYNC_TS, "planner.MIN_SYNC_TS, 1 ns")
        d = abs(self.distance)
        kind = self.kind
        if d == 0.0:
            return self._replace(0.0, 0.0, 0.0, self._jpar)
        shape = _SHAPE[kind]
        if kind == "sine_jerk":
            T = _ceil_multiple(2.0 * self._tj, Ts)
            tj, ta, tv = 0.5 * T, 0.0, _ceil_multiple(self._tv, Ts)
        else:
            tj = _ceil_multiple(self._tj, Ts)
            ta = _ceil_multiple(self._ta, Ts)
            tv = _ceil_multiple(self._tv, Ts)
        # distance = apk (tj + ta) (2 tj + ta + tv), apk = k * jpar * tj
        if shape == _STEP:
            jpar = d / ((tj + ta) * (2.0 * tj + ta + tv))
        else:
            k = _TWO_OVER_PI if shape == _SINE else 1.0
            jpar = d / (k * tj * (tj + ta) * (2.0 * tj + ta + tv))
        return self._replace(tj, ta, tv, jpar)

    def _replace(self, tj, ta, tv, jpar) -> "Profile":
        return type(self)(self.distance, tj, ta, tv, jpar, self._limits)

    def discretize(self, Ts, t_end=None) -> ProfileSample:
        """Stojčić eq. 15: backward-Euler integration of the sampled jerk (kept to show its drift).

        ``eps(k) = eps(k-1) + j(k) Ts``, ``omega(k) = omega(k-1) + eps(k) Ts``,
        ``theta(k) = theta(k-1) + omega(k) Ts`` with ``j(k)`` the jerk of Stojčić eq. 2 at
        ``t_k = k Ts``
        and zero initial state.  The result does *not* end at ``distance``: with Ts = 5 ms,
        distance 100, J = 1000, E = 100, Omega = 60 the published profile ends about 0.8 % short.
        Sample the closed form (:meth:`sample`) of a :meth:`synchronized` profile instead.

        A trapezoid has no finite jerk: its sampled acceleration is integrated (the last two
        lines of Stojčić eq. 15).

        Parameters
        ----------
        Ts : float
            Sample time (s), > 0.
        t_end : float, optional
            Last time to cover (s, >= 0); default: the duration plus one sample.  At most
            ``MAX_SAMPLES`` samples (``t_end / Ts``): a larger request raises ValueError.

        Returns
        -------
        ProfileSample
            ``t_k = k Ts`` for ``k = 0 .. ceil(t_end / Ts)`` and the recursion's values.
        """
        Ts = as_positive("Ts", Ts)
        if t_end is None:
            t_end = self.duration + Ts
        t_end = as_nonnegative("t_end", t_end)
        steps = t_end / Ts
        if not steps < MAX_SAMPLES:
            raise ValueError(
                f"t_end / Ts = {t_end!r} / {Ts!r} asks for more than MAX_SAMPLES = "
                f"{MAX_SAMPLES} samples: raise Ts or lower t_end"
            )
        n = max(int(math.ceil(steps - 1e-9)), 0) + 1
        tk = np.arange(n) * Ts
        exact = self.sample(tk)
        if _SHAPE[self.kind] == _STEP:
            jerk = np.zeros(n)
            accel = exact.accel
        else:
            jerk = exact.jerk
            accel = np.cumsum(jerk) * Ts
        with np.errstate(over="ignore", invalid="ignore"):
            vel = np.cumsum(accel) * Ts
            pos = np.cumsum(vel) * Ts
        if not np.isfinite(pos[-1]):
            raise ValueError(
                f"Ts = {Ts!r} s is too large for this move (duration {self.duration!r} s): "
                f"the recursion overflows"
            )
        return ProfileSample(tk, jerk, accel, vel, pos)

    def to_dict(self) -> dict:
        """JSON-able description: kind, distance, limits, phase times, duration and peaks."""
        pj = self.peak_jerk
        return {
            "kind": self.kind,
            "distance": self.distance,
            "limits": {
                "max_jerk": self.max_jerk,
                "max_accel": self.max_accel,
                "max_velocity": self.max_velocity,
            },
            "phase_times": list(self.phase_times),
            "duration": self.duration,
            "peak_jerk": pj if math.isfinite(pj) else None,
            "peak_accel": self.peak_accel,
            "peak_velocity": self.peak_velocity,
            "jerk_shape": ("sine", "linear", "step")[_SHAPE[self.kind]],
        }

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(distance={self.distance!r}, duration={self.duration!r}, "
            f"phase_times={tuple(round(x, 12) for x in self.phase_times)!r})"
        )


class SineJerkProfile(Profile):
    """Stojčić's published sine-jerk profile (Stojčić eq. 2): ``j = J sin(2 pi t / T)`` on ``[0, T]``,
    0 on ``[T, t1]``, ``-J sin(2 pi (t - t1) / T)`` on ``[t1, tu]``.

    ``accel_time`` is T, ``cruise_time`` is t_v; ``phase_times = (T, t_v, T)``.
    """

    __slots__ = ()
    kind = "sine_jerk"

    @property
    def accel_time(self) -> float:
        """T = t_a, the length of the acceleration (and deceleration) phase (s)."""
        return 2.0 * self._tj

    @property
    def cruise_time(self) -> float:
        """t_v, the time at constant velocity (s)."""
        return self._tv

    @property
    def phase_times(self) -> tuple:
        T = 2.0 * self._tj
        return (T, self._tv, T)

    def to_dict(self) -> dict:
        d = Profile.to_dict(self)
        d["accel_time"] = self.accel_time
        d["cruise_time"] = self.cruise_time
        return d


class SineJerkOptimalProfile(Profile):
    """Half-sine jerk pulses with an acceleration plateau and a cruise (7 segments)."""

    __slots__ = ()
    kind = "sine_jerk_optimal"


class SCurveProfile(Profile):
    """Linear-jerk (constant-jerk segments) 7-segment S-curve."""

    __slots__ = ()
    kind = "scurve"


class TrapezoidProfile(Profile):
    """Constant acceleration, cruise, constant deceleration; ``phase_times = (t_a, t_v, t_a)``."""

    __slots__ = ()
    kind = "trapezoid"

    @property
    def phase_times(self) -> tuple:
        return (self._ta, self._tv, self._ta)

    @property
    def peak_jerk(self) -> float:
        return _INF if self.distance != 0.0 else 0.0


# ---------------------------------------------------------------------------------------------
# planners (scalar)
# ---------------------------------------------------------------------------------------------
#: most samples :meth:`Profile.discretize` produces (5 arrays of 8-byte floats: 400 MB)
MAX_SAMPLES = 10_000_000
#: shortest sample period :meth:`Profile.synchronized` takes (s): 1 ns, faster than any controller
#: and than the FPGA's 50 MHz clock; at 1e-300 s the rounding would do nothing while the result
#: claimed to be synchronized
MIN_SYNC_TS = 1e-9
#: most moves :func:`plan_batch` plans in one call (about 80 bytes a move: 1.6 GB)
MAX_BATCH_MOVES = 20_000_000


def _no_plan(func, distance, J, A, V):
    """The ValueError for limits that give no finite plan (a limit underflows, the move overflows)."""
    lim = f"max_jerk={J!r}, " if J is not None else ""
    return ValueError(
        f"{func}: no finite plan for distance={distance!r}, {lim}max_accel={A!r}, "
        f"max_velocity={V!r}: a limit is too small for the distance (the phase times "
        f"underflow to 0 or overflow to inf); scale the units"
    )


def _check_plan(p, func):
    """Raise :func:`_no_plan` unless the phase times are finite and the move has some duration."""
    tj, ta, tv = p._tj, p._ta, p._tv
    if not (
        (tj + ta + tv) * 0.0 == 0.0
        and (p.distance == 0.0 or tj + ta + tv > 0.0)
        and (p.distance == 0.0 or p._jpar * 0.0 == 0.0 and p._jpar > 0.0)
    ):
        raise _no_plan(func, p.distance, *p._limits)
    return p


def _check_limits(distance, max_jerk, max_accel, max_velocity):
    """Validated floats (``jerklab._validate`` raises the ``ValueError`` naming the parameter)."""
    return (
        as_real("distance", distance),
        as_positive("max_jerk", max_jerk),
        as_positive("max_accel", max_accel),
        as_positive("max_velocity", max_velocity),
    )


_new = object.__new__
#: the default of the any-state keywords: the rest-to-rest fast path tests it by identity
_ZERO = 0.0
_sqrt = math.sqrt
_THIRD = 1.0 / 3.0
_TWO_PI = 2.0 * math.pi

# The planners below are on the hot path (one call per move; benchmarks/bench_planner.py compares
# them with Ruckig): plain floats are checked inline, anything else goes through _check_limits.
# ``(a + b + c + d) * 0.0 == 0.0`` is False as soon as one of them is NaN or inf.


def plan_sine_jerk(distance, max_jerk, max_accel, max_velocity) -> "SineJerkProfile":
    """Stojčić's sine-jerk planner exactly as published (Stojčić eqs. 3, 4
    and the flowchart of Fig. 2).

    ``T = (2 pi Theta / J)^(1/3)`` (Stojčić eq. 4); if ``J T / pi > E`` then ``T = E pi / J``; if
    ``J T^2 / (2 pi) > Omega`` then ``T = sqrt(2 pi Omega / J)``; ``omega = min(J T^2/(2 pi), Omega)``,
    ``t_v = (Theta - omega T) / omega``, ``t_u = 2 T + t_v``.  This is ``T = min(T_Theta, T_E,
    T_Omega)``, so every limit holds.  The round-off ``t_v ~ -1e-16`` is clamped to 0.

    The peak jerk is always ``max_jerk`` (the paper never lowers it): when the acceleration limit
    binds, the cruise speed collapses to ``E T / 2``, far below ``max_velocity``.  See
    :func:`plan_sine_jerk_optimal` for the time-optimal sine-jerk profile.

    Parameters
    ----------
    distance : float
        Signed move length Theta (rad or any unit); negative moves backwards, 0 gives an empty move.
    max_jerk, max_accel, max_velocity : float
        J, E, Omega (> 0).

    Returns
    -------
    SineJerkProfile
        With ``accel_time`` (T) and ``cruise_time`` (t_v).
    """
    J, E, W = max_jerk, max_accel, max_velocity
    if not (
        type(distance) is float is type(J) is type(E) is type(W)
        and J > 0.0
        and E > 0.0
        and W > 0.0
        and (distance + J + E + W) * 0.0 == 0.0
    ):
        distance, J, E, W = _check_limits(distance, J, E, W)
    p = _new(SineJerkProfile)
    p.distance = distance
    p._ta = 0.0
    p._jpar = J
    p._limits = (J, E, W)
    theta = distance if distance >= 0.0 else -distance
    if theta == 0.0:
        p._tj = p._tv = 0.0
        return p
    T = (_TWO_PI * theta / J) ** _THIRD  # Stojčić eq. 4
    if J * T / _PI > E:  # Stojčić eq. 3: eps_max = J T / pi
        T = E * _PI / J
    wmax = J * T * T / _TWO_PI  # Stojčić eq. 3: omega_max = J T^2 / (2 pi)
    if wmax > W:
        T = _sqrt(_TWO_PI * W / J)
        wmax = W  # omega = min(omega_max, Omega)
    if not wmax > 0.0:  # 1e-300 limits: T^2 underflows
        raise _no_plan("plan_sine_jerk", distance, J, E, W)
    tv = (theta - wmax * T) / wmax
    if not tv > 0.0:
        tv = 0.0  # round-off only (T <= T_Theta)
    if not ((T + tv) * 0.0 == 0.0 and T + tv > 0.0):  # as _check_plan, written out
        raise _no_plan("plan_sine_jerk", distance, J, E, W)
    p._tj = 0.5 * T
    p._tv = tv
    return p


def _scurve_times(d, J, A, V):
    """Phase times ``(tj, ta, tv)`` of the time-optimal linear-jerk S-curve over ``d >= 0``.

    Cases: the velocity limit reached (with or without an acceleration plateau), or not (with the
    acceleration limit reached, ``d = A (tj + ta)(2 tj + ta)``, or not, ``d = 2 J tj^3``).
    """
    if d == 0.0:
        return 0.0, 0.0, 0.0
    tj = A / J
    if V * J >= A * A:  # V reachable with a plateau at A
        ta = V / A - tj
        dv = V * (tj + tj + ta)  # distance to reach V and stop again
    else:  # V reached before A
        tj = _sqrt(V / J)
        ta = 0.0
        dv = 2.0 * V * tj
    if d >= dv:
        return tj, ta, (d - dv) / V
    tj = A / J  # V not reached
    tj2 = tj * tj
    if d >= 2.0 * A * tj2:  # A still reached: solve d = A (tj + ta)(2 tj + ta)
        q = d / A
        return tj, 2.0 * (q - 2.0 * tj2) / (3.0 * tj + _sqrt(tj2 + 4.0 * q)), 0.0
    return d**_THIRD * (0.5 / J) ** _THIRD, 0.0, 0.0  # d = 2 J tj^3 (no underflow of d/2J)


def plan_sine_jerk_optimal(
    distance,
    max_jerk,
    max_accel,
    max_velocity,
    *,
    initial_velocity=_ZERO,
    initial_accel=_ZERO,
    final_velocity=_ZERO,
) -> "SineJerkOptimalProfile":
    """Time-optimal rest-to-rest profile made of half-sine jerk pulses of peak <= ``max_jerk``.

    Seven segments: a rising half-sine jerk pulse (length ``tj``), an acceleration plateau
    (``ta``), a falling pulse, a cruise (``tv``) and the mirror image.  A half-sine pulse of peak J
    changes the acceleration by ``2 J tj / pi`` -- exactly what a constant jerk ``2 J / pi`` does in
    the same time -- and the acceleration phase is symmetric, so the velocity peak and the distance
    equal those of the linear-jerk S-curve with jerk ``2 J / pi``: the phase times are that
    S-curve's (:func:`plan_scurve`).  Here the limits are upper bounds; the published algorithm
    (:func:`plan_sine_jerk`) is the special case ``ta = 0`` with a pulse shortened instead.

    From a moving start (``initial_velocity``, ``initial_accel`` or ``final_velocity`` not 0) the
    profile is the time-optimal one of the same family -- every constant-jerk ramp of the
    time-optimal S-curve at jerk ``2J/pi``, split where the acceleration crosses 0, becomes one
    half-sine pulse -- and its duration equals that S-curve's exactly when ``initial_accel`` is 0;
    otherwise the pulses' position lag is made up by the solver (docs/THEORY.md, "Any start
    state"; :class:`AnyStateProfile`).

    Parameters
    ----------
    distance : float
        Signed move length.
    max_jerk, max_accel, max_velocity : float
        Peak of the sine jerk, acceleration and velocity limits (> 0).
    initial_velocity, initial_accel, final_velocity : float, keyword-only
        Start velocity and acceleration, end velocity (default 0; the end acceleration is 0).
        A start above a limit brakes back inside it first; ``|final_velocity| > max_velocity``
        raises ValueError.
    """
    if not (initial_velocity is _ZERO is initial_accel is final_velocity) and (
        initial_velocity.__class__ is not float
        or initial_accel.__class__ is not float
        or final_velocity.__class__ is not float
        or initial_velocity
        or initial_accel
        or final_velocity
    ):
        # from a moving start; Python floats straight to the compiled solver (as _plan_any_state).
        # Written out in both planners on purpose: a shared helper adds a Python call to each plan.
        if (
            initial_velocity.__class__
            is initial_accel.__class__
            is final_velocity.__class__
            is float
        ) and (
            distance.__class__
            is max_jerk.__class__
            is max_accel.__class__
            is max_velocity.__class__
            is float
        ):
            res = (_SINE_PLAN or _packed(True))(
                distance,
                max_jerk,
                max_accel,
                max_velocity,
                initial_velocity,
                initial_accel,
                final_velocity,
            )
            if res[0] > 0.0:
                p = _new(AnyStateProfile)
                p.kind = "sine_jerk_optimal"
                p.distance = distance
                p._limits = (max_jerk, max_accel, max_velocity)
                p.initial_velocity = initial_velocity
                p.initial_accel = initial_accel
                p.final_velocity = final_velocity
                p._res = res
                return p
            return _any_state_special(
                "sine_jerk_optimal",
                distance,
                max_jerk,
                max_accel,
                max_velocity,
                initial_velocity,
                initial_accel,
                final_velocity,
                res,
            )
        return _plan_any_state(
            "sine_jerk_optimal",
            True,
            distance,
            max_jerk,
            max_accel,
            max_velocity,
            initial_velocity,
            initial_accel,
            final_velocity,
        )
    J, A, V = max_jerk, max_accel, max_velocity
    if not (
        type(distance) is float is type(J) is type(A) is type(V)
        and J > 0.0
        and A > 0.0
        and V > 0.0
        and (distance + J + A + V) * 0.0 == 0.0
    ):
        distance, J, A, V = _check_limits(distance, J, A, V)
    p = _new(SineJerkOptimalProfile)
    p.distance = distance
    p._jpar = J
    p._limits = (J, A, V)
    # the phase times of _scurve_times written out (one call less per plan: the hot path)
    d = distance if distance >= 0.0 else -distance
    if d == 0.0:
        p._tj = p._ta = p._tv = 0.0
        return p
    Jl = _TWO_OVER_PI * J
    try:
        tj = A / Jl
        if V * Jl >= A * A:  # V reachable with a plateau at A
            ta = V / A - tj
            dv = V * (tj + tj + ta)
        else:  # V reached before A
            tj = _sqrt(V / Jl)
            ta = 0.0
            dv = 2.0 * V * tj
        if d >= dv:
            tv = (d - dv) / V
        else:
            tv = 0.0
            tj = A / Jl  # V not reached
            tj2 = tj * tj
            if d >= 2.0 * A * tj2:  # A still reached: d = A (tj + ta)(2 tj + ta)
                q = d / A
                ta = 2.0 * (q - 2.0 * tj2) / (3.0 * tj + _sqrt(tj2 + 4.0 * q))
            else:  # d = 2 J tj^3
                tj = d**_THIRD * (0.5 / Jl) ** _THIRD
                ta = 0.0
    except ZeroDivisionError:
        raise _no_plan("plan_sine_jerk_optimal", distance, J, A, V) from None
    total = tj + ta + tv
    if not (total * 0.0 == 0.0 and total > 0.0):  # NaN, inf or underflow to 0 (as _check_plan)
        raise _no_plan("plan_sine_jerk_optimal", distance, J, A, V)
    p._tj = tj
    p._ta = ta
    p._tv = tv
    return p


def plan_scurve(
    distance,
    max_jerk,
    max_accel,
    max_velocity,
    *,
    initial_velocity=_ZERO,
    initial_accel=_ZERO,
    final_velocity=_ZERO,
) -> "SCurveProfile":
    """Time-optimal linear-jerk 7-segment S-curve, rest to rest.

    Jerk ``+J, 0, -J, 0, -J, 0, +J`` over ``(tj, ta, tj, tv, tj, ta, tj)``.  All four cases are
    handled: acceleration limit reached (``ta > 0``) or not, velocity limit reached (``tv > 0``) or
    not.  Yang et al. (2013) use the special case ``ta = 0`` with the velocity reached.

    From any start state (``initial_velocity``, ``initial_accel``) to any end velocity
    (``final_velocity``, end acceleration 0) the profile is the time-optimal one (Ruckig's
    duration): a braking pre-trajectory when the start is outside the limits (Ruckig's rule), then
    at most seven segments of jerk ``+-J`` or 0 (docs/THEORY.md, "Any start state";
    :class:`AnyStateProfile`).

    Parameters
    ----------
    distance : float
        Signed move length.
    max_jerk, max_accel, max_velocity : float
        Limits (> 0).
    initial_velocity, initial_accel, final_velocity : float, keyword-only
        Start velocity and acceleration, end velocity (default 0; the end acceleration is 0).
        A start above a limit brakes back inside it first; ``|final_velocity| > max_velocity``
        raises ValueError.
    """
    if not (initial_velocity is _ZERO is initial_accel is final_velocity) and (
        initial_velocity.__class__ is not float
        or initial_accel.__class__ is not float
        or final_velocity.__class__ is not float
        or initial_velocity
        or initial_accel
        or final_velocity
    ):
        # from a moving start; Python floats straight to the compiled solver (as _plan_any_state).
        # Written out in both planners on purpose: a shared helper adds a Python call to each plan.
        if (
            initial_velocity.__class__
            is initial_accel.__class__
            is final_velocity.__class__
            is float
        ) and (
            distance.__class__
            is max_jerk.__class__
            is max_accel.__class__
            is max_velocity.__class__
            is float
        ):
            res = (_SCURVE_PLAN or _packed(False))(
                distance,
                max_jerk,
                max_accel,
                max_velocity,
                initial_velocity,
                initial_accel,
                final_velocity,
            )
            if res[0] > 0.0:
                p = _new(AnyStateProfile)
                p.kind = "scurve"
                p.distance = distance
                p._limits = (max_jerk, max_accel, max_velocity)
                p.initial_velocity = initial_velocity
                p.initial_accel = initial_accel
                p.final_velocity = final_velocity
                p._res = res
                return p
            return _any_state_special(
                "scurve",
                distance,
                max_jerk,
                max_accel,
                max_velocity,
                initial_velocity,
                initial_accel,
                final_velocity,
                res,
            )
        return _plan_any_state(
            "scurve",
            False,
            distance,
            max_jerk,
            max_accel,
            max_velocity,
            initial_velocity,
            initial_accel,
            final_velocity,
        )
    J, A, V = max_jerk, max_accel, max_velocity
    if not (
        type(distance) is float is type(J) is type(A) is type(V)
        and J > 0.0
        and A > 0.0
        and V > 0.0
        and (distance + J + A + V) * 0.0 == 0.0
    ):
        distance, J, A, V = _check_limits(distance, J, A, V)
    p = _new(SCurveProfile)
    p.distance = distance
    p._jpar = J
    p._limits = (J, A, V)
    # the phase times of _scurve_times written out (one call less per plan: the hot path)
    d = distance if distance >= 0.0 else -distance
    if d == 0.0:
        p._tj = p._ta = p._tv = 0.0
        return p
    Jl = J
    try:
        tj = A / Jl
        if V * Jl >= A * A:  # V reachable with a plateau at A
            ta = V / A - tj
            dv = V * (tj + tj + ta)
        else:  # V reached before A
            tj = _sqrt(V / Jl)
            ta = 0.0
            dv = 2.0 * V * tj
        if d >= dv:
            tv = (d - dv) / V
        else:
            tv = 0.0
            tj = A / Jl  # V not reached
            tj2 = tj * tj
            if d >= 2.0 * A * tj2:  # A still reached: d = A (tj + ta)(2 tj + ta)
                q = d / A
                ta = 2.0 * (q - 2.0 * tj2) / (3.0 * tj + _sqrt(tj2 + 4.0 * q))
            else:  # d = 2 J tj^3
                tj = d**_THIRD * (0.5 / Jl) ** _THIRD
                ta = 0.0
    except ZeroDivisionError:
        raise _no_plan("plan_scurve", distance, J, A, V) from None
    total = tj + ta + tv
    if not (total * 0.0 == 0.0 and total > 0.0):  # NaN, inf or underflow to 0 (as _check_plan)
        raise _no_plan("plan_scurve", distance, J, A, V)
    p._tj = tj
    p._ta = ta
    p._tv = tv
    return p


def plan_trapezoid(distance, max_accel, max_velocity) -> "TrapezoidProfile":
    """Classic trapezoidal (triangular when short) velocity profile, the one the papers improve on.

    ``t_a = V / A`` and ``t_v = d / V - V / A`` when the velocity limit is reached, else
    ``t_a = sqrt(d / A)``, ``t_v = 0`` (Stojčić §1: ``t_u = 2 t_a + t_v``).

    Parameters
    ----------
    distance : float
        Signed move length.
    max_accel, max_velocity : float
        Limits (> 0).
    """
    A, V = max_accel, max_velocity
    if not (
        type(distance) is float is type(A) is type(V)
        and A > 0.0
        and V > 0.0
        and (distance + A + V) * 0.0 == 0.0
    ):
        distance = as_real("distance", distance)
        A = as_positive("max_accel", A)
        V = as_positive("max_velocity", V)
    p = _new(TrapezoidProfile)
    p.distance = distance
    p._tj = 0.0
    p._jpar = A
    p._limits = (None, A, V)
    d = distance if distance >= 0.0 else -distance
    if d == 0.0:
        p._ta = p._tv = 0.0
    elif d * A >= V * V:
        ta = V / A
        p._ta = ta
        p._tv = (d - V * ta) / V
    else:
        p._ta = _sqrt(d / A)
        p._tv = 0.0
    return _check_plan(p, "plan_trapezoid")


# ---------------------------------------------------------------------------------------------
# any start state (initial velocity and acceleration, final velocity)
# ---------------------------------------------------------------------------------------------
def _segment_states(p, v, a, jerk, times, sine, ascale):
    """Start states of the segments and the end state (exact integrals: Stojčić eq. 2 for pulses).

    A constant-jerk segment ``(j, tau)`` adds ``tau (v + tau (a/2 + j tau/6))`` to the position;
    a half-sine pulse of peak ``j`` and length ``tau`` changes ``a`` and ``v`` as the constant jerk
    ``2 j / pi`` does and the position by ``tau^2 (j tau)(2/pi)(1/4 - 1/pi^2)`` instead of
    ``(2 j tau/pi) tau^2 / 6`` (docs/THEORY.md, "Any start state").  An acceleration within
    ``1e-12 ascale`` of 0 after a ramp is 0 (the ramps end there; a long cruise would otherwise
    integrate the round-off into the velocity).
    """
    P = [p]
    Vv = [v]
    Aa = [a]
    for j, t in zip(jerk.tolist(), times.tolist()):
        if sine and j != 0.0:
            da = _TWO_OVER_PI * j * t
            p = p + t * (v + 0.5 * a * t) + da * t * t * (0.25 - 1.0 / (_PI * _PI))
            v = v + t * (a + 0.5 * da)
            a = a + da
        else:
            p = p + t * (v + t * (0.5 * a + t * j / 6.0))
            v = v + t * (a + 0.5 * j * t)
            a = a + j * t
        if j != 0.0 and abs(a) <= 1e-12 * ascale:
            a = 0.0
        P.append(p)
        Vv.append(v)
        Aa.append(a)
    return np.array(P), np.array(Vv), np.array(Aa)


class AnyStateProfile(Profile):
    """A move from any start state: ``plan_scurve`` / ``plan_sine_jerk_optimal`` with an initial
    velocity or acceleration or a final velocity.

    A sequence of segments of constant jerk (``kind = "scurve"``) or of half-sine jerk pulses
    (``kind = "sine_jerk_optimal"``; a segment of jerk 0 is a plateau or a cruise), starting with
    the braking pre-trajectory when the start is outside the limits (``brake_time`` > 0).

    Attributes
    ----------
    kind, distance, duration, phase_times, max_jerk, max_accel, max_velocity
        As :class:`Profile`; ``phase_times`` are the segment durations (the brake's first).
    initial_velocity, initial_accel, final_velocity : float
        The boundary state (the end acceleration is 0).
    segment_jerk : tuple of float
        Jerk of each segment (its peak for a half-sine pulse).
    brake_time : float
        Length of the braking pre-trajectory (s), 0 when the start is inside the limits.

    ``sample(0)`` is exactly ``(position 0, initial_velocity, initial_accel)`` and
    ``sample(duration)`` exactly ``(distance, final_velocity, 0)``; before 0 the initial state is
    held (jerk 0), after ``duration`` the motion goes on at ``final_velocity``.
    :meth:`synchronized` is for rest-to-rest moves only and raises ``NotImplementedError``.
    """

    __slots__ = ("kind", "initial_velocity", "initial_accel", "final_velocity", "_res", "_seg")

    def __init__(
        self,
        kind,
        distance,
        limits,
        initial_velocity,
        initial_accel,
        final_velocity,
        res,
        time_unit,
    ):
        self.kind = kind
        self.distance = distance
        self._limits = limits
        self.initial_velocity = initial_velocity
        self.initial_accel = initial_accel
        self.final_velocity = final_velocity
        # res: jerklab._onedof.solve_tuple's 16 floats (normalized units), kept in the form of
        # jerklab._onedof._pack: (status, T + i tu, code + i brake segments, t_1 + i t_2, ...);
        # _seg (the segments' states) is set on first use
        self._res = _pack_res(res, time_unit)

    @property
    def _sine(self):
        return self.kind == "sine_jerk_optimal"

    def _segments(self):
        """(jerk, times, start times, start positions, velocities, accelerations), built once."""
        try:
            return self._seg
        except AttributeError:
            pass
        jerk = np.array(self._jerk_signs()) * self._limits[0]
        times = np.array(self._times()) * self._res[1].imag
        start = np.concatenate(([0.0], np.cumsum(times)))
        P, V, A = _segment_states(
            0.0,
            self.initial_velocity,
            self.initial_accel,
            jerk,
            times,
            self._sine,
            max(self._limits[1], abs(self.initial_accel)),
        )
        self._seg = (jerk, times, start, P, V, A)
        return self._seg

    def _jerk_signs(self):
        """-1, 0 or +1 per segment, from the solver's packed code (jerklab._onedof.solve_tuple)."""
        code = int(self._res[2].real)
        out = []
        for _ in range(int(self._res[0])):
            code, digit = divmod(code, 3)
            out.append(digit - 1.0)
        return out

    def _times(self):
        """The segment times in the solver's time unit (normalized), a list."""
        out = []
        for z in self._res[3:]:
            out.append(z.real)
            out.append(z.imag)
        return out[: int(self._res[0])]

    @property
    def brake_time(self) -> float:
        """Length of the braking pre-trajectory (s), 0 when the start is inside the limits."""
        res = self._res
        return math.fsum(self._times()[: int(res[2].imag)]) * res[1].imag

    @property
    def duration(self) -> float:
        """Total time of the move (s), the brake included."""
        return self._res[1].real

    @property
    def phase_times(self) -> tuple:
        tu = self._res[1].imag
        return tuple([x * tu for x in self._times()])

    @property
    def segment_jerk(self) -> tuple:
        """Jerk of each segment (its peak for a half-sine pulse), as ``phase_times``."""
        J = self._limits[0]
        return tuple([x * J for x in self._jerk_signs()])

    @property
    def peak_jerk(self) -> float:
        jerk = self._segments()[0]
        return float(np.max(np.abs(jerk))) if jerk.size else 0.0

    @property
    def peak_accel(self) -> float:
        return float(np.max(np.abs(self._segments()[5])))

    @property
    def peak_velocity(self) -> float:
        jerk, _, _, _, V, A = self._segments()
        peak = float(np.abs(V).max())
        # a constant-jerk segment whose acceleration changes sign has a velocity extremum inside
        # (half-sine pulses never change its sign: the solver splits them at a = 0)
        a0, a1, j = A[:-1], A[1:], jerk
        cross = (a0 * a1 < 0.0) & (j != 0.0)
        if cross.any():
            scale = _TWO_OVER_PI if self._sine else 1.0
            vx = V[:-1][cross] - 0.5 * a0[cross] ** 2 / (scale * j[cross])
            peak = max(peak, float(np.max(np.abs(vx))))
        return peak

    def sample(self, t) -> ProfileSample:
        """Jerk, acceleration, velocity and position at the times ``t`` (closed form per segment).

        Parameters
        ----------
        t : float or array_like
            Times (s).  ``t <= 0`` gives the initial state (jerk 0 before 0), ``t >= duration``
            the final state moved on at ``final_velocity``.
        """
        t_in = as_finite_array("t", t)
        t = t_in.reshape(-1)
        jerk, times, start, P, V, A = self._segments()
        n = times.size
        i = np.clip(np.searchsorted(start, t, side="right") - 1, 0, max(n - 1, 0))
        r = np.clip(t - start[i], 0.0, None)
        if n:
            r = np.minimum(r, times[i])
            j = jerk[i]
            p0, v0, a0 = P[i], V[i], A[i]
            jk = j.copy()
            acc = a0 + j * r
            vel = v0 + r * (a0 + 0.5 * j * r)
            pos = p0 + r * (v0 + r * (0.5 * a0 + r * j / 6.0))
            if self._sine:
                pulse = (j != 0.0) & (times[i] > 1e-300)  # (a denormal pulse is a ramp)
                if pulse.any():
                    tau = times[i][pulse]
                    w = _PI / tau
                    jp = j[pulse]
                    c = jp / w
                    rp = r[pulse]
                    wr = w * rp
                    sn = np.sin(wr)
                    omc = 2.0 * np.sin(0.5 * wr) ** 2
                    x2 = wr * wr
                    small = wr < 0.1
                    with np.errstate(invalid="ignore", over="ignore"):
                        wms = np.where(
                            small,
                            wr
                            * x2
                            * (
                                1 / 6
                                - x2
                                * (1 / 120 - x2 * (1 / 5040 - x2 * (1 / 362880 - x2 / 39916800)))
                            ),
                            wr - sn,
                        )
                        hmo = np.where(
                            small,
                            x2
                            * x2
                            * (
                                1 / 24
                                - x2
                                * (1 / 720 - x2 * (1 / 40320 - x2 * (1 / 3628800 - x2 / 479001600)))
                            ),
                            0.5 * x2 - omc,
                        )
                    ap, vp, pp = a0[pulse], v0[pulse], p0[pulse]
                    jk[pulse] = jp * sn
                    acc[pulse] = ap + c * omc
                    vel[pulse] = vp + ap * rp + c * wms / w
                    # (/ w / w, not / (w * w): a pulse of 1e-160 s has w * w = inf, while its
                    # term underflows to 0 as it should)
                    pos[pulse] = pp + rp * (vp + 0.5 * ap * rp) + c * hmo / w / w
        else:
            jk = acc = vel = pos = np.zeros(t.shape)
        T = self._res[1].real
        before = t <= 0.0
        after = t >= T
        vf = self.final_velocity
        jk = np.where(before | after, 0.0, jk)
        if n:  # right-continuous jerk at 0 for constant-jerk segments
            j0 = 0.0 if self._sine else float(jerk[0])
            jk = np.where(t == 0.0, j0 if T > 0.0 else 0.0, jk)
        acc = np.where(before, self.initial_accel, np.where(after, 0.0, acc))
        vel = np.where(before, self.initial_velocity, np.where(after, vf, vel))
        pos = np.where(before, 0.0, np.where(after, self.distance + vf * (t - T), pos))
        shape = t_in.shape
        return ProfileSample(
            t_in.copy(),
            jk.reshape(shape),
            acc.reshape(shape),
            vel.reshape(shape),
            pos.reshape(shape),
        )

    def synchronized(self, Ts):
        """Not available from a moving start (the phase times cannot be rounded independently
        without changing the boundary state): raises ``NotImplementedError``."""
        raise NotImplementedError(
            f"synchronized(Ts) is for rest-to-rest moves; this {self.kind} move starts at "
            f"initial_velocity={self.initial_velocity!r}, initial_accel={self.initial_accel!r} or ends "
            f"at final_velocity={self.final_velocity!r}: sample the closed form at k Ts instead"
        )

    def discretize(self, Ts, t_end=None) -> ProfileSample:
        """Stojčić eq. 15 from the initial state (acceleration and velocity start at
        ``initial_accel`` and ``initial_velocity``); see :meth:`Profile.discretize`."""
        Ts = as_positive("Ts", Ts)
        if t_end is None:
            t_end = self.duration + Ts
        t_end = as_nonnegative("t_end", t_end)
        steps = t_end / Ts
        if not steps < MAX_SAMPLES:
            raise ValueError(
                f"t_end / Ts = {t_end!r} / {Ts!r} asks for more than MAX_SAMPLES = "
                f"{MAX_SAMPLES} samples: raise Ts or lower t_end"
            )
        n = max(int(math.ceil(steps - 1e-9)), 0) + 1
        tk = np.arange(n) * Ts
        jerk = self.sample(tk).jerk
        with np.errstate(over="ignore", invalid="ignore"):
            accel = self.initial_accel + np.cumsum(jerk) * Ts
            vel = self.initial_velocity + np.cumsum(accel) * Ts
            pos = np.cumsum(vel) * Ts
        return ProfileSample(tk, jerk, accel, vel, pos)

    def to_dict(self) -> dict:
        d = Profile.to_dict(self)
        d.update(
            initial_velocity=self.initial_velocity,
            initial_accel=self.initial_accel,
            final_velocity=self.final_velocity,
            segment_jerk=list(self.segment_jerk),
            brake_time=self.brake_time,
        )
        return d

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(kind={self.kind!r}, distance={self.distance!r}, "
            f"initial_velocity={self.initial_velocity!r}, initial_accel={self.initial_accel!r}, "
            f"final_velocity={self.final_velocity!r}, duration={self.duration!r})"
        )


_PLAN = None
#: the compiled scalar entries (jerklab._onedof.packed_planner), set on first use
_SCURVE_PLAN = None
_SINE_PLAN = None


def _planner():
    global _PLAN
    _PLAN = _onedof.planner()
    return _PLAN


def _packed(sine):
    global _SCURVE_PLAN, _SINE_PLAN
    f = _onedof.packed_planner(sine)
    if sine:
        _SINE_PLAN = f
    else:
        _SCURVE_PLAN = f
    return f


def _pack_res(res, time_unit):
    """:func:`jerklab._onedof._pack`'s form of a :func:`jerklab._onedof.solve_tuple` result
    (16 floats) and its time unit; the duration is ``res[2] * time_unit``, as the solver computes
    it."""
    r = [float(x) for x in res[: 4 + _onedof._MAX_SEG]]
    return (r[0], complex(r[2] * time_unit, time_unit), complex(r[1], r[3])) + tuple(
        complex(r[k], r[k + 1]) for k in range(4, 4 + _onedof._MAX_SEG, 2)
    )


def _solver():
    """The compiled (or pure-Python) solver, compiled on first use (jerklab._onedof.solver)."""
    return _onedof.solver()


def _plan_any_state(kind, sine, distance, max_jerk, max_accel, max_velocity, v0, a0, vf):
    """:func:`plan_scurve` / :func:`plan_sine_jerk_optimal` from a moving start (jerklab._onedof).

    The hot path (one call per move; benchmarks/bench_planner.py compares it with Ruckig): Python
    floats go straight to the compiled :func:`jerklab._onedof.plan_tuple`, which checks them,
    normalizes, solves and scales back in one call; anything else is validated here first.
    """
    J, A, V = max_jerk, max_accel, max_velocity
    if not (
        distance.__class__
        is J.__class__
        is A.__class__
        is V.__class__
        is v0.__class__
        is a0.__class__
        is vf.__class__
        is float
    ):
        distance, J, A, V = _check_limits(distance, J, A, V)
        v0 = as_real("initial_velocity", v0)
        a0 = as_real("initial_accel", a0)
        vf = as_real("final_velocity", vf)
        if v0 == 0.0 and a0 == 0.0 and vf == 0.0:
            return (plan_sine_jerk_optimal if sine else plan_scurve)(distance, J, A, V)
    f = (_SINE_PLAN or _packed(True)) if sine else (_SCURVE_PLAN or _packed(False))
    res = f(distance, J, A, V, v0, a0, vf)
    if not res[0] > 0.0:
        return _any_state_special(kind, distance, J, A, V, v0, a0, vf, res)
    p = _new(AnyStateProfile)  # (__init__'s work, inline)
    p.kind = kind
    p.distance = distance
    p._limits = (J, A, V)
    p.initial_velocity = v0
    p.initial_accel = a0
    p.final_velocity = vf
    p._res = res
    return p


def _any_state_special(kind, distance, J, A, V, v0, a0, vf, res):
    """The empty move (``res[0] == 0``), or the ValueError for :func:`jerklab._onedof.plan_tuple`'s
    status ``res[0] < 0``."""
    status = res[0]
    if status == 0.0:  # already on target
        p = _new(AnyStateProfile)
        p.kind = kind
        p.distance = distance
        p._limits = (J, A, V)
        p.initial_velocity = v0
        p.initial_accel = a0
        p.final_velocity = vf
        p._res = _pack_res((0.0,) * (4 + _onedof._MAX_SEG), 1.0)
        return p
    if status == -2.0:  # a value not finite or a limit <= 0: named here
        _check_limits(distance, J, A, V)
        as_real("initial_velocity", v0)
        as_real("initial_accel", a0)
        as_real("final_velocity", vf)
    if status == -3.0:
        raise ValueError(
            f"plan_{kind}: final_velocity={vf!r} is above max_velocity={V!r}: a move "
            f"cannot end outside the velocity limit (lower |final_velocity| or raise "
            f"max_velocity)"
        )
    if status == -4.0:
        raise ValueError(
            f"plan_{kind}: no finite plan for distance={distance!r}, max_jerk={J!r}, "
            f"max_accel={A!r}, max_velocity={V!r}, initial_velocity={v0!r}, "
            f"initial_accel={a0!r}, final_velocity={vf!r}: the limits are too far apart "
            f"in scale (the normalized values overflow); scale the units"
        )
    raise ValueError(
        f"plan_{kind}: no valid profile found for distance={distance!r}, max_jerk={J!r}, "
        f"max_accel={A!r}, max_velocity={V!r}, initial_velocity={v0!r}, "
        f"initial_accel={a0!r}, final_velocity={vf!r} (outside the solver's numeric "
        f"range); scale the units"
    )


# ---------------------------------------------------------------------------------------------
# batch form
# ---------------------------------------------------------------------------------------------
class BatchPlan:
    """Many moves of one kind planned at once (:func:`plan_batch`); arrays of shape ``(n,)``.

    Attributes
    ----------
    kind : str
    distance, duration : ndarray
    tj, ta, tv : ndarray
        Rising-pulse, acceleration-plateau and cruise times (s).  For ``"sine_jerk"`` the
        published T is ``2 tj``; for ``"trapezoid"`` ``tj`` is 0.
    jpar : ndarray
        Jerk actually used (peak of the sine pulses for the sine kinds), the acceleration for the
        trapezoid.
    """

    __slots__ = (
        "kind",
        "distance",
        "tj",
        "ta",
        "tv",
        "jpar",
        "max_jerk",
        "max_accel",
        "max_velocity",
    )

    def __init__(self, kind, distance, tj, ta, tv, jpar, max_jerk, max_accel, max_velocity):
        self.kind = kind
        self.distance = distance
        self.tj, self.ta, self.tv, self.jpar = tj, ta, tv, jpar
        self.max_jerk, self.max_accel, self.max_velocity = max_jerk, max_accel, max_velocity

    def __len__(self) -> int:
        return self.distance.shape[0]

    @property
    def duration(self) -> np.ndarray:
        return 2.0 * (2.0 * self.tj + self.ta) + self.tv

    @property
    def phase_times(self) -> np.ndarray:
        """``(n, k)`` array of the segment durations, as ``Profile.phase_times``."""
        tj, ta, tv = self.tj, self.ta, self.tv
        if self.kind == "sine_jerk":
            return np.stack([2 * tj, tv, 2 * tj], axis=-1)
        if self.kind == "trapezoid":
            return np.stack([ta, tv, ta], axis=-1)
        return np.stack([tj, ta, tj, tv, tj, ta, tj], axis=-1)

    @property
    def peak_accel(self) -> np.ndarray:
        shape = _SHAPE[self.kind]
        if shape == _SINE:
            return _TWO_OVER_PI * self.jpar * self.tj
        if shape == _LINEAR:
            return self.jpar * self.tj
        return np.where(self.distance != 0.0, self.jpar, 0.0)

    @property
    def peak_velocity(self) -> np.ndarray:
        return self.peak_accel * (self.tj + self.ta)

    @property
    def peak_jerk(self) -> np.ndarray:
        if self.kind == "trapezoid":
            return np.where(self.distance != 0.0, _INF, 0.0)
        return np.where(self.distance != 0.0, self.jpar, 0.0)

    def profile(self, i: int) -> Profile:
        """The ``i``-th move as a :class:`Profile` (``0 <= i < len(self)``; a negative ``i``
        raises ``ValueError``, as an index past the end does)."""
        i = as_index("i", i, len(self))
        cls = _CLASSES[self.kind]
        mj = None if self.max_jerk is None else float(self.max_jerk[i])
        return cls(
            float(self.distance[i]),
            float(self.tj[i]),
            float(self.ta[i]),
            float(self.tv[i]),
            float(self.jpar[i]),
            (mj, float(self.max_accel[i]), float(self.max_velocity[i])),
        )

    def sample(self, t) -> ProfileSample:
        """Closed form of every move at ``t`` (broadcast against shape ``(n, 1)``, e.g. ``t`` of
        shape ``(n, m)`` or ``(m,)`` gives ``(n, m)`` arrays)."""
        t = as_finite_array("t", t)
        col = (slice(None), None)
        return _evaluate(
            t,
            self.distance[col],
            self.tj[col],
            self.ta[col],
            self.tv[col],
            self.jpar[col],
            _SHAPE[self.kind],
        )


_CLASSES = {
    "sine_jerk": SineJerkProfile,
    "sine_jerk_optimal": SineJerkOptimalProfile,
    "scurve": SCurveProfile,
    "trapezoid": TrapezoidProfile,
}

_CHUNK = 8192


def _batch_scurve(d, J, A, V, tj_o, ta_o, tv_o):
    """Vectorized S-curve phase times on one chunk (``d >= 0``), written with min/max.

    ``tj = min(A/J, sqrt(V/J), (d/2J)^(1/3))`` (the acceleration, velocity or distance limit
    ends the jerk pulse first); with ``a = J tj`` the plateau is the longest that keeps both the
    velocity ``a (tj + ta) <= V`` and the distance ``a (tj + ta)(2 tj + ta) <= d``:
    ``ta = max(0, min(V/a - tj, ta_d))``; the cruise fills the rest: ``tv = max(0, d/v - 2tj - ta)``.
    The scalar :func:`_scurve_times` spells out the same cases with branches.
    """
    invj = 1.0 / J
    tj = np.minimum(A * invj, np.sqrt(V * invj))
    np.minimum(tj, np.cbrt(d) * np.cbrt(0.5 * invj), out=tj)
    a = J * tj
    with np.errstate(divide="ignore", invalid="ignore"):  # d = 0 gives a = 0: fixed below
        inva = 1.0 / a
        tav = V * inva - tj
        q = d * inva
        tj2 = tj * tj
        tad = 2.0 * (q - 2.0 * tj2) / (3.0 * tj + np.sqrt(tj2 + 4.0 * q))
        ta = np.minimum(tav, tad)
        np.maximum(ta, 0.0, out=ta)
        tacc = 2.0 * tj + ta
        tv = d / (a * (tj + ta)) - tacc
    np.maximum(tv, 0.0, out=tv)
    # round-off residues (~1e-17 s) of a plateau or cruise that should be absent
    ta[ta <= 1e-12 * tj] = 0.0
    tv[tv <= 1e-12 * tacc] = 0.0
    np.copyto(tj_o, tj)
    np.copyto(ta_o, ta)
    np.copyto(tv_o, tv)


def _batch_sine_jerk(d, J, E, W, tj_o, ta_o, tv_o):
    """Vectorized :func:`plan_sine_jerk` (Stojčić eq. 4, Fig. 2) on one chunk."""
    T = np.cbrt((2.0 * _PI) * d / J)
    T = np.minimum(T, E * _PI / J)
    T = np.minimum(T, np.sqrt((2.0 * _PI) * W / J))
    w = np.minimum(J * T * T / (2.0 * _PI), W)
    with np.errstate(divide="ignore", invalid="ignore"):
        tv = (d - w * T) / w
    tv = np.where(tv > 0.0, tv, 0.0)  # clamps round-off and the 0/0 of d = 0
    np.multiply(T, 0.5, out=tj_o)
    ta_o[...] = 0.0
    np.copyto(tv_o, tv)


def _batch_trapezoid(d, A, V, tj_o, ta_o, tv_o):
    reach = d * A >= V * V
    tj_o[...] = 0.0
    np.copyto(ta_o, np.where(reach, V / A, np.sqrt(d / A)))
    np.copyto(tv_o, np.where(reach, d / V - V / A, 0.0))


def _batch_kernel_py(code, d, J, A, V, tj_o, ta_o, tv_o):  # pragma: no cover - compiled
    """One loop over the moves, the scalar planners' algebra (compiled by numba when present).

    ``code``: 0 published sine (Stojčić eq. 4, Fig. 2), 1 optimal sine, 2 S-curve, 3 trapezoid.
    """
    two_pi = 2.0 * math.pi
    inf = math.inf
    for i in range(d.shape[0]):
        x = abs(d[i])
        a = A[i]
        v = V[i]
        # NaN fails every comparison: this rejects NaN, inf and limits <= 0
        if not (x < inf and 0.0 < a < inf and 0.0 < v < inf and 0.0 < J[i] < inf):
            return i
        if x == 0.0:
            tj_o[i] = 0.0
            ta_o[i] = 0.0
            tv_o[i] = 0.0
            continue
        if code == 3:
            tj_o[i] = 0.0
            if x * a >= v * v:
                ta_o[i] = v / a
                tv_o[i] = (x - v * (v / a)) / v
            else:
                ta_o[i] = math.sqrt(x / a)
                tv_o[i] = 0.0
            continue
        j = J[i]
        if code == 0:
            # T = min(T_Theta, T_E, T_Omega) (Fig. 2); the cube root only when T_Theta is smallest
            T = a * math.pi / j
            tw = math.sqrt(two_pi * v / j)
            if tw < T:
                T = tw
            y = two_pi * x / j
            if T * T * T > y:
                T = (
                    y ** (1.0 / 3.0)
                    if y > 1e-300
                    else (two_pi * x) ** (1.0 / 3.0) / j ** (1.0 / 3.0)
                )
            w = j * T * T / two_pi
            if w > v:
                w = v
            tv = (x - w * T) / w
            tj_o[i] = 0.5 * T
            ta_o[i] = 0.0
            tv_o[i] = tv if tv > 0.0 else 0.0
            continue
        if code == 1:
            j = j * (2.0 / math.pi)
        invj = 1.0 / j
        inva = 1.0 / a
        tja = a * invj
        if v * j >= a * a:
            tj = tja
            ta = v * inva - tj
            dv = v * (tj + tj + ta)
        else:
            tj = math.sqrt(v * invj)
            ta = 0.0
            dv = 2.0 * v * tj
        if x >= dv:
            tj_o[i] = tj
            ta_o[i] = ta
            tv_o[i] = (x - dv) / v
            continue
        tj2 = tja * tja
        tv_o[i] = 0.0
        if x >= 2.0 * a * tj2:
            q = x * inva
            tj_o[i] = tja
            ta_o[i] = 2.0 * (q - 2.0 * tj2) / (3.0 * tja + math.sqrt(tj2 + 4.0 * q))
        else:
            y = 0.5 * x * invj
            if y > 1e-300:
                tj_o[i] = y ** (1.0 / 3.0)
            else:  # d / 2J would underflow
                tj_o[i] = x ** (1.0 / 3.0) * (0.5 * invj) ** (1.0 / 3.0)
            ta_o[i] = 0.0
    return -1


def _batch_array(name, value, positive=True):
    """``value`` as a contiguous float array, finite (and > 0): ``ValueError`` naming ``name``."""
    try:
        a = np.ascontiguousarray(value, dtype=float)
    except (TypeError, ValueError):
        a = as_finite_array(name, value)  # raises with the parameter's name
    if a.size:
        lo, hi = a.min(), a.max()
        if not (-_INF < lo and hi < _INF):
            as_finite_array(name, a)
        if positive and not lo > 0.0:
            raise ValueError(f"{name} must be > 0 everywhere, got min {lo!r}")
    return a


_KERNEL = None  # the compiled kernel, or False when numba is not available
_KIND_CODE = {"sine_jerk": 0, "sine_jerk_optimal": 1, "scurve": 2, "trapezoid": 3}
#: below this many moves plan_batch uses numpy (no compilation); above, the numba kernel
NUMBA_MIN_MOVES = 50_000


def _compiled_kernel():
    global _KERNEL
    if _KERNEL is None:
        try:
            import numba

            _KERNEL = numba.njit(cache=True, nogil=True)(_batch_kernel_py)
        except Exception:  # pragma: no cover - numba missing or unusable
            _KERNEL = False
    return _KERNEL


def plan_batch(
    kind, distance, max_jerk=None, max_accel=None, max_velocity=None, engine="auto"
) -> BatchPlan:
    """Plan many moves of one ``kind`` at once, vectorized (arrays broadcast to one shape ``(n,)``).

    The same algebra as the scalar planners, evaluated with numpy in cache-sized chunks
    (millions of plans per second; ``benchmarks/bench_planner.py`` measures it).

    Parameters
    ----------
    kind : {"sine_jerk", "sine_jerk_optimal", "scurve", "trapezoid"}
    distance : array_like
        Signed move lengths.
    max_jerk : array_like or None
        Jerk limits (> 0); not used (may be None) for ``"trapezoid"``.
    max_accel, max_velocity : array_like
        Limits (> 0).
    engine : {"auto", "numpy", "numba"}
        ``"numpy"``: vectorized numpy in cache-sized chunks; ``"numba"``: one compiled loop over
        the moves with the scalar planners' branches (numba, compiled once and cached on disk);
        ``"auto"``: numba for ``NUMBA_MIN_MOVES`` moves or more when numba is installed.

    Returns
    -------
    BatchPlan
    """
    if engine not in ("auto", "numpy", "numba"):
        raise ValueError(f"engine must be 'auto', 'numpy' or 'numba', got {engine!r}")
    if kind not in _SHAPE:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if kind != "trapezoid" and max_jerk is None:
        raise ValueError(f"max_jerk is required for kind {kind!r}")
    # The compiled loop checks every value itself (and, on a bad one, the checks below run to
    # name it); the numpy form checks first (min/max propagate NaN).
    names = ("distance", "max_accel", "max_velocity") + (
        ("max_jerk",) if kind != "trapezoid" else ()
    )
    values = (distance, max_accel, max_velocity) + ((max_jerk,) if kind != "trapezoid" else ())
    arrays = []
    for name, value in zip(names, values):
        if isinstance(value, (str, bytes)):
            as_finite_array(name, value)  # raises with the parameter's name
        try:
            arrays.append(
                np.asarray(value, dtype=float)
            )  # no copy yet (a broadcast view stays one)
        except (TypeError, ValueError):
            as_finite_array(name, value)  # raises with the parameter's name
            raise ValueError(f"{name} must be numeric, got {value!r}") from None
    try:
        shape = np.broadcast_shapes(*(a.shape for a in arrays))
    except ValueError:
        raise ValueError(
            "distance, max_jerk, max_accel, max_velocity must broadcast to one shape (n,); "
            f"got {', '.join(f'{nm} {a.shape}' for nm, a in zip(names, arrays))}"
        ) from None
    n_moves = math.prod(shape)
    if n_moves > MAX_BATCH_MOVES:
        raise ValueError(
            f"distance and the limits ask for {n_moves} moves, more than MAX_BATCH_MOVES = "
            f"{MAX_BATCH_MOVES}: plan them in several calls"
        )
    arrays = [np.ascontiguousarray(a) for a in arrays]
    n_max = max(a.size for a in arrays)
    use_kernel = engine == "numba" or (engine == "auto" and n_max >= NUMBA_MIN_MOVES)
    kernel = _compiled_kernel() if use_kernel else False
    if engine == "numba" and not kernel:
        raise ValueError("engine='numba' needs the numba package")
    if not kernel:
        arrays = [
            _batch_array(name, a, positive=name != "distance") for name, a in zip(names, arrays)
        ]
    J = arrays[3] if kind != "trapezoid" else None
    if len({a.shape for a in arrays}) > 1 or arrays[0].ndim != 1:
        arrays = [np.ascontiguousarray(np.ravel(a)) for a in np.broadcast_arrays(*arrays)]
    dist, A, V = arrays[:3]
    if J is not None:
        J = arrays[3]
    n = dist.shape[0]
    tj = np.empty(n)
    ta = np.empty(n)
    tv = np.empty(n)
    if kernel:
        Jk = J if J is not None else A  # a trapezoid has no jerk: A passes the check
        bad = kernel(_KIND_CODE[kind], dist, Jk, A, V, tj, ta, tv)
        if bad >= 0:
            for name, a in zip(names, arrays):
                _batch_array(name, a, positive=name != "distance")
            raise AssertionError("unreachable: a bad value passed the checks")  # pragma: no cover
        jpar = A if kind == "trapezoid" else J
        _check_batch(kind, dist, tj, ta, tv, J, A, V)
        return BatchPlan(kind, dist, tj, ta, tv, jpar, J, A, V)
    d_all = np.abs(dist)
    if kind == "sine_jerk_optimal":
        jeq = _TWO_OVER_PI * J
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        for lo in range(0, n, _CHUNK):  # (a non-finite plan is refused by _check_batch)
            sl = slice(lo, min(lo + _CHUNK, n))
            d = d_all[sl]
            if kind == "scurve":
                _batch_scurve(d, J[sl], A[sl], V[sl], tj[sl], ta[sl], tv[sl])
            elif kind == "sine_jerk_optimal":
                _batch_scurve(d, jeq[sl], A[sl], V[sl], tj[sl], ta[sl], tv[sl])
            elif kind == "sine_jerk":
                _batch_sine_jerk(d, J[sl], A[sl], V[sl], tj[sl], ta[sl], tv[sl])
            else:
                _batch_trapezoid(d, A[sl], V[sl], tj[sl], ta[sl], tv[sl])
    zero = d_all == 0.0
    if zero.any():
        tj[zero] = ta[zero] = tv[zero] = 0.0
    jpar = A if kind == "trapezoid" else J
    _check_batch(kind, dist, tj, ta, tv, J, A, V)
    return BatchPlan(kind, dist, tj, ta, tv, jpar, J, A, V)


def _check_batch(kind, dist, tj, ta, tv, J, A, V):
    """ValueError naming the first move whose plan is not finite (limits too small for it)."""
    with np.errstate(all="ignore"):
        total = tj + ta + tv
        ok = np.isfinite(total) & ((total > 0.0) | (dist == 0.0))
    if not ok.all():
        i = int(np.argmin(ok))
        jj = None if J is None else float(J[i])
        raise _no_plan(f"plan_batch (move {i})", float(dist[i]), jj, float(A[i]), float(V[i]))


class AnyStateBatch:
    """Many moves from moving starts (:func:`plan_batch_any_state`); arrays of shape ``(n,)``.

    ``duration``, ``brake_time``; ``phase_times`` and ``segment_jerk`` as ``(n, 12)`` arrays padded
    with 0; ``profile(i)`` is move ``i`` as the :class:`AnyStateProfile` the scalar planner returns.
    """

    __slots__ = (
        "kind",
        "distance",
        "max_jerk",
        "max_accel",
        "max_velocity",
        "initial_velocity",
        "initial_accel",
        "final_velocity",
        "_packed",
        "_tu",
    )

    def __init__(self, kind, arrays, packed, tu):
        self.kind = kind
        (
            self.distance,
            self.max_jerk,
            self.max_accel,
            self.max_velocity,
            self.initial_velocity,
            self.initial_accel,
            self.final_velocity,
        ) = arrays
        self._packed = packed
        self._tu = tu

    def __len__(self) -> int:
        return self.distance.shape[0]

    @property
    def duration(self) -> np.ndarray:
        return self._packed[:, 2] * self._tu

    @property
    def phase_times(self) -> np.ndarray:
        return self._packed[:, 4:] * self._tu[:, None]

    @property
    def segment_jerk(self) -> np.ndarray:
        code = self._packed[:, 1].astype(np.int64)
        n = self._packed[:, 0].astype(np.int64)
        digits = (code[:, None] // 3 ** np.arange(_onedof._MAX_SEG)) % 3 - 1.0
        digits[np.arange(_onedof._MAX_SEG)[None, :] >= n[:, None]] = 0.0
        return digits * self.max_jerk[:, None]

    @property
    def brake_time(self) -> np.ndarray:
        nb = self._packed[:, 3].astype(np.int64)
        mask = np.arange(_onedof._MAX_SEG)[None, :] < nb[:, None]
        return np.where(mask, self.phase_times, 0.0).sum(axis=1)

    def profile(self, i: int) -> AnyStateProfile:
        """The ``i``-th move as an :class:`AnyStateProfile` (``0 <= i < len(self)``; a negative
        ``i`` raises ``ValueError``, as an index past the end does)."""
        i = as_index("i", i, len(self))
        lim = (float(self.max_jerk[i]), float(self.max_accel[i]), float(self.max_velocity[i]))
        return AnyStateProfile(
            self.kind,
            float(self.distance[i]),
            lim,
            float(self.initial_velocity[i]),
            float(self.initial_accel[i]),
            float(self.final_velocity[i]),
            tuple(self._packed[i].tolist()),
            float(self._tu[i]),
        )


def plan_batch_any_state(
    kind,
    distance,
    max_jerk,
    max_accel,
    max_velocity,
    initial_velocity=0.0,
    initial_accel=0.0,
    final_velocity=0.0,
) -> AnyStateBatch:
    """Plan many moves from moving starts at once: :func:`plan_scurve` or
    :func:`plan_sine_jerk_optimal` with ``initial_velocity``, ``initial_accel``,
    ``final_velocity``, over arrays that broadcast to one shape ``(n,)``.

    One compiled loop over the moves (numba when installed), the scalar planners' solver and
    results (``profile(i)`` equals the scalar plan).  ``benchmarks/bench_planner.py`` measures
    the plans per second.

    Parameters
    ----------
    kind : {"scurve", "sine_jerk_optimal"}
    distance, max_jerk, max_accel, max_velocity, initial_velocity, initial_accel, final_velocity
        array_like, as the scalar planners' arguments.

    Returns
    -------
    AnyStateBatch
    """
    if kind not in ("scurve", "sine_jerk_optimal"):
        raise ValueError(f"kind must be 'scurve' or 'sine_jerk_optimal', got {kind!r}")
    names = (
        "distance",
        "max_jerk",
        "max_accel",
        "max_velocity",
        "initial_velocity",
        "initial_accel",
        "final_velocity",
    )
    values = (
        distance,
        max_jerk,
        max_accel,
        max_velocity,
        initial_velocity,
        initial_accel,
        final_velocity,
    )
    arrays = [as_finite_array(name, v) for name, v in zip(names, values)]
    try:
        shape = np.broadcast_shapes(*(a.shape for a in arrays))
    except ValueError:
        raise ValueError(
            "the arguments must broadcast to one shape (n,); got "
            + ", ".join(f"{nm} {a.shape}" for nm, a in zip(names, arrays))
        ) from None
    if math.prod(shape) > MAX_BATCH_MOVES:
        raise ValueError(
            f"more than MAX_BATCH_MOVES = {MAX_BATCH_MOVES} moves: plan them in several calls"
        )
    arrays = [np.ascontiguousarray(np.ravel(a)) for a in np.broadcast_arrays(*arrays)]
    d, J, A, V, v0, a0, vf = arrays
    n = d.shape[0]
    packed = np.zeros((n, 4 + _onedof._MAX_SEG))
    tu = np.ones(n)
    _solver()  # compiles (or picks the pure-Python) solver
    bad = _onedof.solve_many(d, v0, a0, vf, J, A, V, kind == "sine_jerk_optimal", packed, tu)
    if bad >= 0:
        i = int(bad)
        for name, a in zip(("max_jerk", "max_accel", "max_velocity"), (J, A, V)):
            if not a[i] > 0.0:
                raise ValueError(f"{name} must be > 0 everywhere, got {a[i]!r} (move {i})")
        if abs(vf[i]) > V[i]:
            raise ValueError(f"final_velocity={vf[i]!r} is above max_velocity={V[i]!r} (move {i})")
        KINDS_SCALAR = {"scurve": plan_scurve, "sine_jerk_optimal": plan_sine_jerk_optimal}
        KINDS_SCALAR[kind](
            float(d[i]),
            float(J[i]),
            float(A[i]),
            float(V[i]),
            initial_velocity=float(v0[i]),
            initial_accel=float(a0[i]),
            final_velocity=float(vf[i]),
        )  # raises, naming the reason
        raise ValueError(f"plan_batch_any_state: no valid profile for move {i}")  # pragma: no cover
    return AnyStateBatch(kind, (d, J, A, V, v0, a0, vf), packed, tu)
