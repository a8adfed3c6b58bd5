"""Time-optimal jerk-limited motion of one axis from any start state (private kernel of planner.py).

The problem: from position 0, velocity ``v0`` and acceleration ``a0`` to position ``d``, velocity
``vf`` and acceleration 0, with ``|j| <= J``, ``|a| <= A``, ``|v| <= V``, in least time.

Everything here works in normalized units -- time ``A/J``, acceleration ``A``, velocity ``A^2/J``,
position ``A^3/J^2`` -- so that ``J = A = 1`` and every acceleration of a candidate lies in
``[-1, 1]``; :func:`solve` returns the segments in those units and ``planner.py`` scales them back.

Structure of the optimum (docs/THEORY.md, "Any start state"): after an optional braking
pre-trajectory that brings a start outside the limits back inside them (the same rule as Ruckig's),
the acceleration is made of three ramps at full jerk, ``sigma`` up, down, up (``sigma = +-1``):
``a0 -> P`` (hold ``P = sigma A`` for ``t1`` if it is reached), ``P -> -N`` (through 0, where a
cruise at ``v = sigma V`` may be inserted), ``-N -> 0`` (hold ``N = A`` for ``t5``).  With the
velocity equation solved for one unknown, each case (which acceleration limits are reached) is one
polynomial equation in one variable of degree <= 5 (the end position), whose real roots in the
admissible interval are found by isolating them between the roots of its derivatives.  Every root is
checked against all limits and the shortest valid profile wins; the winner is integrated once more
and refused if it misses the target (limits too far apart in scale for double precision).

The sine family (``kappa != 0``) uses the same algebra: a half-sine jerk pulse of peak J changes the
acceleration and the velocity exactly as a constant jerk ``2J/pi`` over the same time, and moves the
position by ``-kappa * da^3 / J'^2`` less, with ``kappa = 1/pi^2 - 1/12`` and ``J' = 2J/pi``
(docs/THEORY.md); the end-position polynomials carry that term.

Written in the subset of Python that numba compiles (floats and preallocated arrays, no objects);
:func:`solver` returns the compiled :func:`solve_tuple` when numba is installed.
"""

from __future__ import annotations

import math

import numpy as np

#: the functions numba compiles (:func:`solver`), in the order they are defined
_JITTED = []


def _jit(f):
    """Mark ``f`` for compilation by :func:`solver` (numba is imported only when a plan needs it)."""
    _JITTED.append(f.__name__)
    return f


_SOLVER = None
#: compiled functions called once per plan from Python (they keep the GIL)
_ENTRIES = ("plan_tuple", "plan_scurve_packed", "plan_sine_packed")
#: small helpers that numba inlines into their callers
_INLINED = ("_keep", "_check", "_near", "_cubes", "_append", "_set", "_pvalue", "_advance")
#: the pure-Python functions, kept when :func:`solver` replaces them by their compiled versions
PURE = {}


def solver():
    """:func:`solve_tuple`, compiled by numba (cached on disk) when numba is installed, else pure Python.

    The compiled form takes a few microseconds a plan, the pure-Python one two orders of
    magnitude longer.
    """
    global _SOLVER
    if _SOLVER is None:
        g = globals()
        PURE.update({name: g[name] for name in _JITTED})
        try:
            import numba

            for name in _JITTED:  # module globals, so that compiled code calls compiled code
                # (the scalar planners' entries from Python keep the GIL: releasing and taking it
                # back costs about 0.05 us a call, 3 % of a plan; the small helpers are inlined by
                # numba itself: 5 % of a solve, 3 s more to compile once)
                g[name] = numba.njit(
                    cache=True,
                    nogil=name not in _ENTRIES,
                    inline="always" if name in _INLINED else "never",
                )(PURE[name])
            # compiled now (or loaded from the cache) for float arguments, while the globals it
            # calls are the compiled ones (the planners call plan_tuple, not solve_tuple)
            try:
                g["solve_tuple"].compile((numba.types.float64,) * 6)
            except Exception:  # pragma: no cover - compiled on the first call instead
                pass
            _SOLVER = g["solve_tuple"]
        except Exception:  # pragma: no cover - numba missing or unusable
            for name in _JITTED:
                g[name] = PURE[name]
            _SOLVER = PURE["solve_tuple"]
    return _SOLVER


_PLAN = None


def planner():
    """:func:`plan_tuple` for Python floats (``sine`` a bool): compiled by numba when installed, else
    pure Python (:func:`solver` compiles).

    The compiled form is the float64 overload's entry point, which skips numba's type dispatch
    (about 0.1 us a call); the callers (``planner.py``) pass Python floats only.
    """
    global _PLAN
    if _PLAN is None:
        solver()
        f = globals()["plan_tuple"]
        if f is not PURE["plan_tuple"]:
            try:
                from numba import types

                f = f.compile((types.float64,) * 7 + (types.boolean,))
            except Exception:  # pragma: no cover - an older numba: the dispatcher itself
                pass
        _PLAN = f
    return _PLAN


_PACKED = {}


def packed_planner(sine):
    """:func:`plan_scurve_packed` (``sine`` false) or :func:`plan_sine_packed` for Python floats:
    compiled by numba when installed (the float64 entry point, as :func:`planner`), else pure
    Python.  These are the scalar planners' entries (``planner.py``): seven arguments, the family
    fixed at compile time, nine Python objects returned instead of eighteen floats."""
    f = _PACKED.get(bool(sine))
    if f is None:
        solver()
        name = "plan_sine_packed" if sine else "plan_scurve_packed"
        f = globals()[name]
        if f is not PURE[name]:
            try:
                from numba import types

                f = f.compile((types.float64,) * 7)
            except Exception:  # pragma: no cover - an older numba: the dispatcher itself
                pass
        _PACKED[bool(sine)] = f
    return f


#: 1/pi^2 - 1/12: position lag of a half-sine jerk pulse behind the linear ramp of the same impulse
KAPPA_SINE = 1.0 / (math.pi * math.pi) - 1.0 / 12.0

_TOL = 1e-10  # slack of the validity checks, in normalized units (times, accelerations)
# the solver's scratch array (one array, so that each compiled call takes one reference): the
# polynomial and its derivatives in six rows of 6 (row i at 6 i), the critical points, the roots
# found, the best candidate
_CRIT = 36
_OUT = 44
_BEST = 52
_SCRATCH = 60
_MAX_SEG = 12  # most segments of a profile (2 brake + 8 + a cruise)


# ---------------------------------------------------------------------------------------------
# real roots of a polynomial on an interval
# ---------------------------------------------------------------------------------------------
@_jit
def _pvalue(D, i, deg, x):
    """Value of row ``i`` at ``x`` (Horner) and whether it is at round-off level: within ``1e-13`` of
    the sum of ``|terms|`` at ``x``, the round-off scale of the value (both in one pass)."""
    f = 0.0
    r = 0.0
    ax = abs(x)
    for m in range(deg + 1):
        c = D[6 * i + m]
        f = f * x + c
        r = r * ax + abs(c)
    return f, abs(f) <= 1e-13 * r


@_jit
def _root_between(D, i, deg, lo, hi, flo):
    """The root of row ``i`` in ``[lo, hi]``, where it is monotone and changes sign (safeguarded Newton)."""
    a, b = lo, hi
    neg_lo = flo < 0.0
    x = 0.5 * (a + b)
    for _ in range(100):
        f = 0.0
        df = 0.0
        for m in range(deg + 1):
            df = df * x + f
            f = f * x + D[6 * i + m]
        if f == 0.0:
            return x
        if (f < 0.0) == neg_lo:
            a = x
        else:
            b = x
        xn = x - f / df if df != 0.0 else a - 1.0
        if not (a < xn < b):
            xn = 0.5 * (a + b)
        if abs(xn - x) <= 4e-16 * abs(x) + 1e-22 or b - a <= 4e-16 * max(abs(a), abs(b)) + 1e-22:
            return xn  # (1e-22: a root at 0 is not refined below the normalized unit)
        x = xn
    return x


@_jit
def _roots_from_critical(D, i, deg, ncrit, lo, hi):
    """Real roots of row ``i`` of ``D`` in ``[lo, hi]`` into ``D[_OUT:]`` (their number is returned),
    given its sorted critical points ``D[_CRIT:_CRIT + ncrit]`` (it is monotone between them)."""
    nout = 0
    xprev = lo
    fprev, small_prev = _pvalue(D, i, deg, lo)
    if small_prev:
        D[_OUT + nout] = lo
        nout += 1
    for m in range(ncrit + 1):
        if m < ncrit:
            x = D[_CRIT + m]
            if not (xprev < x < hi):
                continue
        else:
            x = hi
        f, small = _pvalue(D, i, deg, x)
        if small:
            D[_OUT + nout] = x  # a (double) root at a critical point or an end
            nout += 1
        elif not small_prev and (f < 0.0) != (fprev < 0.0):
            D[_OUT + nout] = _root_between(D, i, deg, xprev, x, fprev)
            nout += 1
        xprev, fprev, small_prev = x, f, small
    return nout


@_jit
def _real_roots(D, deg, lo, hi):
    """Real roots in ``[lo, hi]`` of the polynomial in ``D[:deg + 1]`` (highest power first,
    degree <= 5) into ``D[_OUT:_OUT + 8]``; returns their number.  ``D`` is the solver's scratch
    array (``_SCRATCH`` floats, flat: six rows of 6, row ``i`` at ``6 i``, then the critical points
    from ``_CRIT``).

    The roots of the derivatives, from the linear one up, split ``[lo, hi]`` into pieces on which
    the polynomial is monotone; a sign change on a piece is bisected (safeguarded Newton), a value
    at round-off level at a piece's end (a double root) is taken as a root.  A polynomial whose
    Taylor bound on the interval clears 0 (:func:`_no_root`) has none: nothing is searched.
    """
    if _no_root(D, deg, lo, hi):
        return 0
    return _search_roots(D, deg, lo, hi)


@_jit
def _roots5(c0, c1, c2, c3, c4, c5, lo, hi, D):
    """:func:`_real_roots` of ``c0 x^5 + ... + c5`` on ``[lo, hi]``: the coefficients go into
    row 0 of ``D`` only when :func:`_no_root5` cannot rule a root out."""
    if _no_root5(c0, c1, c2, c3, c4, c5, lo, hi):
        return 0
    _set(D, c0, c1, c2, c3, c4, c5)
    return _search_roots(D, 5, lo, hi)


@_jit
def _search_roots(D, deg, lo, hi):
    """:func:`_real_roots` without the no-root test."""
    k = 0
    while k < deg and D[k] == 0.0:
        k += 1
    if k:
        for m in range(deg + 1 - k):
            D[m] = D[m + k]
        deg -= k
    if deg <= 0:
        return 0
    for i in range(1, deg):  # row i = i-th derivative, degree deg - i
        di = deg - i
        for m in range(di + 1):
            D[6 * i + m] = D[6 * i - 6 + m] * (di + 1 - m)
    ncrit = 0
    if deg >= 2:
        i = deg - 1  # the linear derivative
        if D[6 * i] != 0.0:
            x = -D[6 * i + 1] / D[6 * i]
            if lo < x < hi:
                D[_CRIT] = x
                ncrit = 1
        for i in range(deg - 2, 0, -1):
            ncrit = _roots_from_critical(D, i, deg - i, ncrit, lo, hi)
            for m in range(ncrit):
                D[_CRIT + m] = D[_OUT + m]
    return _roots_from_critical(D, 0, deg, ncrit, lo, hi)


@_jit
def _no_root(D, deg, lo, hi):
    """True when the polynomial in ``D[:deg + 1]`` (degree <= 5) provably has no root on
    ``[lo, hi]``, nor a value that :func:`_real_roots` would take for one (so that it would find
    none): :func:`_no_root5` on the coefficients (leading zeros added up to degree 5, which change
    no value)."""
    c = np.zeros(6)
    for m in range(deg + 1):
        c[5 - deg + m] = D[m]
    return _no_root5(c[0], c[1], c[2], c[3], c[4], c[5], lo, hi)


@_jit
def _no_root5(c0, c1, c2, c3, c4, c5, lo, hi):
    """True when ``c0 x^5 + ... + c5`` provably has no root on ``[lo, hi]``, nor a value that
    :func:`_real_roots` would take for one (so that it would find none): a cheap test that saves
    most of the root searches (on scalars: no array is touched).

    The Taylor coefficients ``t_k`` at ``lo`` (repeated synthetic division) bound the polynomial on
    the interval, ``h = hi - lo``: ``t_0 + sum(min(t_k h^k, 0)) <= p <= t_0 + sum(max(t_k h^k, 0))``.
    The bound must clear 0 by ``1e-11`` of the sum of ``|terms|`` at ``|lo| + h`` (the round-off of the
    shift, and the root search's own test, ``1e-13`` of the same scale at most, with a wide margin).
    """
    h = hi - lo
    d0, d1, d2, d3, d4, d5 = c0, c1, c2, c3, c4, c5
    d1 += lo * d0  # after pass k, d_(5 - k) = t_k
    d2 += lo * d1
    d3 += lo * d2
    d4 += lo * d3
    d5 += lo * d4
    d1 += lo * d0
    d2 += lo * d1
    d3 += lo * d2
    d4 += lo * d3
    d1 += lo * d0
    d2 += lo * d1
    d3 += lo * d2
    d1 += lo * d0
    d2 += lo * d1
    d1 += lo * d0
    low = d5
    high = low
    hk = h
    term = d4 * hk
    if term < 0.0:
        low += term
    else:
        high += term
    hk *= h
    term = d3 * hk
    if term < 0.0:
        low += term
    else:
        high += term
    hk *= h
    term = d2 * hk
    if term < 0.0:
        low += term
    else:
        high += term
    hk *= h
    term = d1 * hk
    if term < 0.0:
        low += term
    else:
        high += term
    hk *= h
    term = d0 * hk
    if term < 0.0:
        low += term
    else:
        high += term
    x = abs(lo) + h  # sum of |terms| at x (as _pvalue)
    r = abs(c0)
    r = r * x + abs(c1)
    r = r * x + abs(c2)
    r = r * x + abs(c3)
    r = r * x + abs(c4)
    r = r * x + abs(c5)
    margin = 1e-11 * r
    return low > margin or high < -margin


@_jit
def _set(D, c0, c1, c2, c3, c4, c5):
    """Row 0 of ``D`` = the coefficients (highest power first; leading zeros are stripped later)."""
    D[0] = c0
    D[1] = c1
    D[2] = c2
    D[3] = c3
    D[4] = c4
    D[5] = c5


# ---------------------------------------------------------------------------------------------
# the step profile (sigma = +1) from (v0, a0) to (vf, 0) over d, normalized units
# ---------------------------------------------------------------------------------------------
@_jit
def _cubes(P, N, a0):
    """Sum of the cubes of the acceleration changes of the pulses (each ramp split at a = 0)."""
    if P >= 0.0:
        if a0 >= 0.0:
            return (P - a0) ** 3 - P**3
        return -(a0**3)
    return (P - a0) ** 3 - (N + P) ** 3 + N**3


@_jit
def _check(P, N, t1, t5, tc, a0, v0, V):
    """Times and limits of a sigma = +1 candidate; returns its duration or -1 if invalid."""
    t0 = P - a0
    t2 = P + N
    if t0 < -_TOL or t2 < -_TOL or N < -_TOL or t1 < -_TOL or t5 < -_TOL or tc < -_TOL:
        return -1.0
    if P > 1.0 + _TOL or N > 1.0 + _TOL or P < -1.0 - _TOL:
        return -1.0
    if t1 > _TOL and P < 1.0 - 1e-9:
        return -1.0
    if t5 > _TOL and N < 1.0 - 1e-9:
        return -1.0
    vtol = _TOL * (1.0 + V)
    if P > 0.0:
        vpk = v0 + P * P - 0.5 * a0 * a0 + P * max(t1, 0.0)
        if vpk > V + vtol:
            return -1.0
        if a0 < 0.0 and v0 - 0.5 * a0 * a0 < -V - vtol:
            return -1.0
    return max(t0, 0.0) + max(t1, 0.0) + max(t2, 0.0) + max(t5, 0.0) + max(N, 0.0) + max(tc, 0.0)


@_jit
def _end_pos(P, N, t1, t5, tc, a0, v0, k):
    """End position of the candidate (sigma = +1), integrated segment by segment."""
    p = 0.0
    v = v0
    a = a0
    # (jerk, time) segments; the cruise sits where a = 0 in the middle ramp
    segs_j = (1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0)
    if P > 0.0:
        segs_t = (P - a0, t1, P, tc, N, t5, N)
    else:
        segs_t = (P - a0, t1, P + N, tc, 0.0, t5, N)
    for i in range(7):
        j = segs_j[i]
        t = segs_t[i]
        if t <= 0.0:
            continue
        p += t * (v + t * (0.5 * a + t * j / 6.0))
        v += t * (a + 0.5 * j * t)
        a += j * t
    return p - k * _cubes(P, N, a0)


@_jit
def _near(p, d, T, v0, V):
    """End position ``p`` is ``d`` to 1e-9 of the path's scale (a candidate root, not a spurious one)."""
    return abs(p - d) <= 1e-9 * (abs(d) + (abs(v0) + V) * T + 1.0)


@_jit
def _candidates(d, v0, a0, vf, V, k, s, D):
    """Valid sigma = +1 candidates; the shortest so far is kept in ``D[_BEST:_BEST + 7]`` =
    (T, P, N, t1, t5, tc, s) (:func:`_keep`).

    ``D``: the solver's scratch array (:func:`_real_roots`).
    """
    H = vf - v0 + 0.5 * a0 * a0
    # --- cruise at +V (VEL, ACC0_VEL, ACC1_VEL, ACC0_ACC1_VEL) ---
    pn2 = V - v0 + 0.5 * a0 * a0
    nn2 = V - vf
    if pn2 >= 0.0 and nn2 >= -_TOL:
        P = math.sqrt(pn2)
        t1 = 0.0
        if P > 1.0:
            P = 1.0
            t1 = pn2 - 1.0
        N = math.sqrt(max(nn2, 0.0))
        t5 = 0.0
        if N > 1.0:
            N = 1.0
            t5 = nn2 - 1.0
        if P >= a0 - _TOL:
            rest = d - _end_pos(P, N, t1, t5, 0.0, a0, v0, k)
            tc = rest / V
            T = _check(P, N, t1, t5, tc, a0, v0, V)
            if T >= 0.0:
                _keep(D, T, P, N, t1, t5, max(tc, 0.0), s)
    # --- no cruise ---
    a2 = a0 * a0
    a3 = a2 * a0
    # branches of the sine term: A (P >= 0, a0 >= 0), B (P >= 0, a0 < 0), C (P < 0)
    kA = k if a0 >= 0.0 else 0.0  # the P-dependent part of the cubes exists only in branch A
    # ACC0_ACC1: P = N = 1, t1 = t5 + H, quadratic in t5
    c1 = 2.0 * H - a2 + 2.0 * v0 + 3.0
    c0 = (
        -(
            -3.0 * H * H
            + 3.0 * H * a2
            - 6.0 * H * v0
            - 21.0 * H
            - 6.0 * k * a3
            - 2.0 * a3
            + (12.0 + 18.0 * kA) * a2
            - 18.0 * kA * a0
            + 6.0 * a0 * v0
            + 6.0 * d
            - 24.0 * v0
            - 12.0
        )
        / 6.0
    )
    disc = c1 * c1 - 4.0 * c0
    if disc >= 0.0:
        q = -0.5 * (
            c1 + math.copysign(math.sqrt(disc), c1)
        )  # the roots q and c0/q, no cancellation
        for t5 in (q, c0 / q if q != 0.0 else 0.0):
            t1 = t5 + H
            T = _check(1.0, 1.0, t1, t5, 0.0, a0, v0, V)
            if T >= 0.0 and _near(
                _end_pos(1.0, 1.0, max(t1, 0.0), max(t5, 0.0), 0.0, a0, v0, k), d, T, v0, V
            ):
                _keep(D, T, 1.0, 1.0, max(t1, 0.0), max(t5, 0.0), 0.0, s)
    # ACC0: P = 1, t1 = H - 1 + N^2 >= 0, quartic in N on [sqrt(1 - H), 1] (none if H < 0)
    if H >= -1e-9:
        e0 = (
            -(
                -3.0 * H * H
                + 3.0 * H * a2
                - 6.0 * H * v0
                - 3.0 * H
                - 6.0 * k * a3
                - 2.0 * a3
                + (3.0 + 18.0 * kA) * a2
                - 18.0 * kA * a0
                + 6.0 * a0 * v0
                + 6.0 * d
                - 6.0 * v0
            )
            / 6.0
        )
        lo = max(math.sqrt(max(1.0 - H, 0.0)) - 1e-9, 0.0)
        for r in range(
            _roots5(
                0.0,
                0.5,
                1.0,
                0.5 * (2.0 * H - a2 + 2.0 * v0 + 1.0),
                2.0 * H - a2 + 2.0 * v0,
                e0,
                lo,
                1.0,
                D,
            )
        ):
            N = D[_OUT + r]
            t1 = H - 1.0 + N * N
            T = _check(1.0, N, t1, 0.0, 0.0, a0, v0, V)
            if T >= 0.0 and _near(_end_pos(1.0, N, max(t1, 0.0), 0.0, 0.0, a0, v0, k), d, T, v0, V):
                _keep(D, T, 1.0, N, max(t1, 0.0), 0.0, 0.0, s)
    # ACC1: N = 1, t5 = P^2 - 1 - H >= 0, quartic in P (none if H > 0); |P| >= sqrt(1 + H);
    # branch C on [a0, 0), A/B on [max(a0, 0), 1]
    if H <= 1e-9:
        e0 = (
            -(
                3.0 * H * H
                - 3.0 * H * a2
                + 6.0 * H * v0
                - 3.0 * H
                - 6.0 * k * a3
                - 2.0 * a3
                + 3.0 * a2
                + 6.0 * a0 * v0
                + 6.0 * d
                - 6.0 * v0
            )
            / 6.0
        )
        pmin = math.sqrt(max(1.0 + H, 0.0)) - 1e-9
        lo_ab = max(a0, 0.0, pmin)
        if lo_ab <= 1.0:
            for r in range(
                _roots5(
                    0.0,
                    0.5,
                    1.0,
                    0.5 * (-a2 + 6.0 * kA * a0 + 2.0 * v0 + 1.0),
                    -3.0 * kA * a2 - a2 + 2.0 * v0,
                    e0,
                    lo_ab,
                    1.0,
                    D,
                )
            ):
                P = D[_OUT + r]
                t5 = P * P - 1.0 - H
                T = _check(P, 1.0, 0.0, t5, 0.0, a0, v0, V)
                if T >= 0.0 and _near(
                    _end_pos(P, 1.0, 0.0, max(t5, 0.0), 0.0, a0, v0, k), d, T, v0, V
                ):
                    _keep(D, T, P, 1.0, 0.0, max(t5, 0.0), 0.0, s)
        hi_c = min(0.0, -pmin)
        if a0 < 0.0 and max(a0, -1.0) < hi_c:
            for r in range(
                _roots5(
                    0.0,
                    0.5,
                    1.0,
                    0.5 * (-a2 + 6.0 * k * a0 + 6.0 * k + 2.0 * v0 + 1.0),
                    -3.0 * k * a2 - a2 + 3.0 * k + 2.0 * v0,
                    e0,
                    max(a0, -1.0),
                    hi_c,
                    D,
                )
            ):
                P = D[_OUT + r]
                if P >= 0.0:
                    continue
                t5 = P * P - 1.0 - H
                T = _check(P, 1.0, 0.0, t5, 0.0, a0, v0, V)
                if T >= 0.0 and _near(
                    _end_pos(P, 1.0, 0.0, max(t5, 0.0), 0.0, a0, v0, k), d, T, v0, V
                ):
                    _keep(D, T, P, 1.0, 0.0, max(t5, 0.0), 0.0, s)
    # NONE: u = P + N, P = (u^2 + H)/(2u), N = (u^2 - H)/(2u); quintic in u on (0, 2]
    b2 = 12.0 * H - 18.0 * a2 * k - 12.0 * a2 + 24.0 * v0
    b1 = 18.0 * H * a0 * k + 12.0 * a3 * k + 4.0 * a3 - 12.0 * a0 * v0 - 12.0 * d
    if H >= 0.0:
        split = 0.0
    else:
        split = math.sqrt(-H)  # P < 0 below (branch C), P >= 0 above
    ulo = math.sqrt(H) if H > 0.0 else 0.0
    # P <= 1 and N <= 1: u in [1 - m, 1 + m], m = sqrt(1 - |H|) (nothing if |H| > 1)
    if abs(H) > 1.0 + 1e-9:
        return
    m = math.sqrt(max(1.0 - abs(H), 0.0))
    ulo = max(ulo, 1.0 - m - 1e-9)
    uhi = min(2.0, 1.0 + m + 1e-9)
    for br in range(2):
        if br == 0:  # P >= 0: branch A or B
            lo, hi = max(split, ulo), uhi
            if a0 >= 0.0:
                q0, q1, q2, q3 = 3.0, 9.0 * a0 * k, b2, b1
                q4, q5 = -3.0 * H * (H + 6.0 * a2 * k), 9.0 * H * H * a0 * k
            else:
                q0, q1, q2, q3 = 0.0, 3.0, 0.0, 12.0 * (H - a2 + 2.0 * v0)
                q4, q5 = -4.0 * (-3.0 * a3 * k - a3 + 3.0 * a0 * v0 + 3.0 * d), -3.0 * H * H
        else:  # P < 0: branch C (only when H < 0)
            if split <= 0.0:
                continue
            lo, hi = ulo, min(split, uhi)
            q0, q1, q2, q3 = 3.0 * (3.0 * k + 1.0), 9.0 * a0 * k, b2, b1
            q4, q5 = -3.0 * H * (3.0 * H * k + H + 6.0 * a2 * k), 9.0 * H * H * a0 * k
        if hi <= lo:
            continue
        for r in range(_roots5(q0, q1, q2, q3, q4, q5, max(lo, 1e-300), hi, D)):
            u = D[_OUT + r]
            if u <= 0.0:
                continue
            P = 0.5 * (u + H / u)
            N = 0.5 * (u - H / u)
            if (br == 0 and P < -_TOL) or (br == 1 and P > _TOL):
                continue
            T = _check(P, N, 0.0, 0.0, 0.0, a0, v0, V)
            if T >= 0.0 and _near(_end_pos(P, N, 0.0, 0.0, 0.0, a0, v0, k), d, T, v0, V):
                _keep(D, T, P, N, 0.0, 0.0, 0.0, s)


@_jit
def _keep(D, T, P, N, t1, t5, tc, s):
    """The candidate into ``D[_BEST:_BEST + 7]`` if it is shorter than the one there."""
    if T < D[_BEST]:
        D[_BEST] = T
        D[_BEST + 1] = P
        D[_BEST + 2] = N
        D[_BEST + 3] = t1
        D[_BEST + 4] = t5
        D[_BEST + 5] = tc
        D[_BEST + 6] = s


@_jit
def _brake(v0, a0, V):
    """Ruckig's braking pre-trajectory for a start outside the limits (normalized units).

    Returns ``(j1, t1, j2, t2)``: jerk and time of up to two segments (``t = 0`` when unused).
    A start with ``a0 > A`` ramps the acceleration down to the limit (then holds it while the
    velocity is below ``-V``); a start whose velocity is above the limit, or will be whatever the
    jerk does (``v0 + a0|a0|/2J > V``), ramps the acceleration down until the velocity is back at
    the limit or the acceleration at ``-A`` (then holds ``-A``).  Mirror images for the other sign.
    """
    if a0 > 1.0:
        if v0 + 0.5 * a0 * a0 > V:
            return _velocity_brake(v0, a0, V, 1.0)
        vA = v0 + 0.5 * (a0 * a0 - 1.0)
        if vA < -V:
            t_lo = -V - vA
            t_hi = -0.5 + V - vA
            return -1.0, a0 - 1.0, 0.0, max(min(t_lo, t_hi), 0.0)
        return -1.0, a0 - 1.0, 0.0, 0.0
    if a0 < -1.0:
        if v0 - 0.5 * a0 * a0 < -V:
            return _velocity_brake(-v0, -a0, V, -1.0)
        vA = -v0 + 0.5 * (a0 * a0 - 1.0)
        if vA < -V:
            t_lo = -V - vA
            t_hi = -0.5 + V - vA
            return 1.0, -a0 - 1.0, 0.0, max(min(t_lo, t_hi), 0.0)
        return 1.0, -a0 - 1.0, 0.0, 0.0
    if (v0 > V and v0 - 0.5 * a0 * a0 > -V) or (a0 > 0.0 and v0 + 0.5 * a0 * a0 > V):
        return _velocity_brake(v0, a0, V, 1.0)
    if (v0 < -V and v0 + 0.5 * a0 * a0 < V) or (a0 < 0.0 and v0 - 0.5 * a0 * a0 < -V):
        return _velocity_brake(-v0, -a0, V, -1.0)
    return 0.0, 0.0, 0.0, 0.0


@_jit
def _velocity_brake(v0, a0, V, s):
    """Jerk -1 until v = V on the way down (or a = -1, then hold -1); ``s`` flips the result."""
    t_amin = a0 + 1.0
    q1 = a0 * a0 + 2.0 * (v0 - V)
    q2 = 0.5 * a0 * a0 + (v0 + V)
    t_vmax = a0 + math.sqrt(q1) if q1 >= 0.0 else math.inf
    t_vmin = a0 + math.sqrt(q2) if q2 >= 0.0 else math.inf
    tm = min(t_vmax, t_vmin)
    if t_amin < tm:
        v_amin = v0 + t_amin * (a0 - 0.5 * t_amin)
        t2 = max(min(v_amin - V, -0.5 + v_amin + V), 0.0)
        return -s, max(t_amin, 0.0), 0.0, t2
    return -s, max(tm, 0.0), 0.0, 0.0


@_jit
def solve(d, v0, a0, vf, V, k):
    """Shortest profile from (0, v0, a0) to (d, vf, 0) in normalized units (J = A = 1).

    ``k`` is 0 for the linear-jerk S-curve and :data:`KAPPA_SINE` for half-sine pulses.  Returns a
    list of floats ``[n, j_1, t_1, ..., j_n, t_n]``: the jerk (in units of J, the mean jerk of the
    pulse for the sine family) and duration of every segment, brake included; ``n = -1`` if no
    valid profile was found; then the total duration and, last, the number of brake segments
    (a numpy array of length ``2 * _MAX_SEG + 3``).
    """
    # one allocation: the result, then the scratch arrays (views of the same buffer)
    nres = 2 * _MAX_SEG + 3
    buf = np.empty(nres + _SCRATCH)
    res = buf[:nres]
    res[:] = 0.0  # (the scratch arrays are written before they are read)
    # braking pre-trajectory (jerk segments then a constant-acceleration segment)
    bj, bt, bj2, bt2 = _brake(v0, a0, V)
    p = 0.0
    v = v0
    a = a0
    if bt > 0.0:
        # split at a = 0 so that each half-sine pulse keeps one sign of the acceleration
        ts = bt
        if k != 0.0 and ((a > 0.0 and bj < 0.0 and a < bt) or (a < 0.0 and bj > 0.0 and -a < bt)):
            tz = abs(a)
            _append(res, bj, tz)
            p, v, a = _advance(p, v, a, bj, tz, k)
            ts = bt - tz
        _append(res, bj, ts)
        p, v, a = _advance(p, v, a, bj, ts, k)
    if bt2 > 0.0:
        _append(res, bj2, bt2)
        p, v, a = _advance(p, v, a, bj2, bt2, k)
    res[-1] = res[0]  # the number of brake segments
    if bt > 0.0 and a > 1.0:  # round-off of the ramp to the limit
        a = 1.0
    if bt > 0.0 and a < -1.0:
        a = -1.0
    D = buf[nres:]
    D[_BEST] = math.inf
    D[_BEST + 6] = 0.0
    dd = d - p
    _candidates(dd, v, a, vf, V, k, 1.0, D)
    _candidates(-dd, -v, -a, -vf, V, k, -1.0, D)
    if D[_BEST + 6] == 0.0:
        res[0] = -1.0
        return res
    P, N, t1, t5, tc, s = (
        D[_BEST + 1],
        D[_BEST + 2],
        D[_BEST + 3],
        D[_BEST + 4],
        D[_BEST + 5],
        D[_BEST + 6],
    )
    a0s = s * a
    # rebuild the segments in the sigma frame, then flip the jerk signs by s
    if P > 0.0:
        if a0s < 0.0 and k != 0.0:  # split the first ramp at a = 0 (sine pulses keep one sign)
            _append(res, s, -a0s)
            _append(res, s, P)
        else:
            _append(res, s, P - a0s)
        _append(res, 0.0, t1)
        _append(res, -s, P)
        _append(res, 0.0, tc)
        _append(res, -s, N)
    else:  # no a = 0 in the middle ramp (a cruise only when P = 0)
        _append(res, s, P - a0s)
        _append(res, 0.0, t1)
        _append(res, 0.0, tc)
        _append(res, -s, P + N)
    _append(res, 0.0, t5)
    _append(res, s, N)
    # the whole profile integrated once more: a result the round-off has spoilt (limits far apart
    # in scale) is refused rather than returned
    total = 0.0
    p = 0.0
    v = v0
    a = a0
    pvar = 0.0
    vvar = 0.0
    for i in range(int(res[0])):
        j = res[2 * i + 1]
        t = res[2 * i + 2]
        total += t
        p2, v2, a2 = _advance(p, v, a, j, t, k)
        if j != 0.0 and abs(a2) <= 1e-12 * (1.0 + abs(a0)):
            a2 = 0.0  # a ramp that ends at a = 0 (as planner._segment_states)
        pvar += abs(p2 - p)
        vvar += abs(v2 - v)
        p, v, a = p2, v2, a2
    res[-2] = total
    if not (
        abs(p - d) <= 1e-8 * (abs(d) + pvar) + 1e-300
        and abs(v - vf) <= 1e-8 * (V + vvar)
        and abs(a) <= 1e-8 * (1.0 + abs(a0))
    ):
        res[0] = -1.0
    return res


@_jit
def solve_tuple(d, v0, a0, vf, V, k):
    """:func:`solve`'s result packed in 16 floats (cheaper to hand to Python than an array):
    ``(n, jerk code, duration, brake segments, t_1, ..., t_12)``, the jerk of segment ``i`` being
    ``(code // 3**i) % 3 - 1``."""
    r = solve(d, v0, a0, vf, V, k)
    n = int(r[0])
    code = 0.0
    p3 = 1.0
    for i in range(max(n, 0)):
        code += (r[2 * i + 1] + 1.0) * p3
        p3 *= 3.0
    # (the unused entries of r are 0)
    return (
        r[0],
        code,
        r[-2],
        r[-1],
        r[2],
        r[4],
        r[6],
        r[8],
        r[10],
        r[12],
        r[14],
        r[16],
        r[18],
        r[20],
        r[22],
        r[24],
    )


@_jit
def plan_tuple(d, J, A, V, v0, a0, vf, sine):
    """One move in SI units: the checks, the normalization, :func:`solve_tuple` and the time unit,
    in one compiled call (:func:`solve_many`'s entry; the scalar planners call it through
    :func:`plan_scurve_packed` / :func:`plan_sine_packed`).

    Returns 18 floats: ``(status, code, duration, brake segments, t_1, ..., t_12, tu, T)`` --
    :func:`solve_tuple`'s result in normalized units, then the time unit ``tu = A / J'`` (``J' = J``,
    or ``2J/pi`` when ``sine``) and the duration ``T`` in seconds.  ``status`` is the number of
    segments (> 0), or: 0 when the start is already the target (the empty move, ``tu = 1``);
    -1 no valid profile (the solver's numeric range); -2 a value not finite or a limit <= 0;
    -3 ``|vf| > V``; -4 the normalized values overflow (limits far apart in scale).
    """
    if not (
        0.0 < J < math.inf
        and 0.0 < A < math.inf
        and 0.0 < V < math.inf
        and abs(d) < math.inf
        and abs(v0) < math.inf
        and abs(a0) < math.inf
        and abs(vf) < math.inf
    ):
        return (
            -2.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
        )
    if vf > V or -vf > V:
        return (
            -3.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
        )
    if d == 0.0 and a0 == 0.0 and v0 == vf:  # (|v0| <= V: v0 == vf)
        # already on target (Ruckig plans a loop out and back here; the empty move is optimal)
        return (
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
        )
    Jm = J * (2.0 / math.pi) if sine else J  # the mean jerk of a half-sine pulse of peak J
    tu = A / Jm  # normalized units: J' = A = 1
    vu = A * tu
    pu = vu * tu
    if not pu > 0.0:
        return (
            -4.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            tu,
            0.0,
        )
    dn = d / pu
    v0n = v0 / vu
    a0n = a0 / A
    vfn = vf / vu
    Vn = V / vu
    if not (dn + v0n + a0n + vfn + Vn + tu + vu + pu) * 0.0 == 0.0:
        return (
            -4.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            tu,
            0.0,
        )
    r = solve(dn, v0n, a0n, vfn, Vn, KAPPA_SINE if sine else 0.0)
    n = int(r[0])
    if n <= 0:
        return (
            -1.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            tu,
            0.0,
        )
    code = 0.0
    p3 = 1.0
    for i in range(n):
        code += (r[2 * i + 1] + 1.0) * p3
        p3 *= 3.0
    # (the unused entries of r are 0)
    return (
        r[0],
        code,
        r[-2],
        r[-1],
        r[2],
        r[4],
        r[6],
        r[8],
        r[10],
        r[12],
        r[14],
        r[16],
        r[18],
        r[20],
        r[22],
        r[24],
        tu,
        r[-2] * tu,
    )


@_jit
def _pack(r):
    """:func:`plan_tuple`'s 18 floats as ``(status, complex(T, tu), complex(code, brake segments),
    complex(t_1, t_2), ..., complex(t_11, t_12))``: the same values (the normalized duration
    left out), in 9 Python objects -- boxing and freeing a float costs about as much as a complex,
    and 18 of them were a tenth of a plan's time."""
    return (
        r[0],
        complex(r[17], r[16]),
        complex(r[1], r[3]),
        complex(r[4], r[5]),
        complex(r[6], r[7]),
        complex(r[8], r[9]),
        complex(r[10], r[11]),
        complex(r[12], r[13]),
        complex(r[14], r[15]),
    )


@_jit
def plan_scurve_packed(d, J, A, V, v0, a0, vf):
    """:func:`plan_tuple` for the S-curve (``sine`` false, so compiled for it alone), :func:`_pack`-ed."""
    return _pack(plan_tuple(d, J, A, V, v0, a0, vf, False))


@_jit
def plan_sine_packed(d, J, A, V, v0, a0, vf):
    """:func:`plan_tuple` for the sine family (``sine`` true), :func:`_pack`-ed."""
    return _pack(plan_tuple(d, J, A, V, v0, a0, vf, True))


@_jit
def _append(res, j, t):
    if t > 0.0:
        n = int(res[0])
        res[2 * n + 1] = j
        res[2 * n + 2] = t
        res[0] = n + 1


@_jit
def _advance(p, v, a, j, t, k):
    """State after a segment: a constant jerk j, or (k != 0) a half-sine pulse of mean jerk j."""
    da = j * t
    p2 = p + t * (v + t * (0.5 * a + t * j / 6.0)) - k * da * da * da
    v2 = v + t * (a + 0.5 * j * t)
    return p2, v2, a + da


@_jit
def solve_many(d, v0, a0, vf, J, A, V, sine, out, tu_out):
    """:func:`solve_tuple` over arrays of moves in SI units (one loop, compiled with the rest).

    Row ``i`` of ``out`` (shape ``(n, 16)``) receives the packed result of move ``i``, ``tu_out[i]``
    its time unit.  Returns -1, or the index of the first move that cannot be planned (a value not
    finite, a limit <= 0, ``|vf| > V``, or no valid profile): the caller names it.
    """
    for i in range(d.shape[0]):
        r = plan_tuple(d[i], J[i], A[i], V[i], v0[i], a0[i], vf[i], sine)
        if r[0] < 0.0:
            return i
        for m in range(16):
            out[i, m] = r[m]
        tu_out[i] = r[16]
    return -1
