"""jerklab._onedof's fast paths: the no-root test that skips root searches, and the one-call entry
``plan_tuple`` (compiled and pure Python agree; statuses)."""

import math

import numpy as np
import pytest

from jerklab import _onedof


def _poly_cases(rng, n):
    """Quintics (highest power first) with real roots placed in, near or around ``[lo, hi]``."""
    for _ in range(n):
        lo = rng.uniform(-1.5, 1.5)
        hi = lo + 10 ** rng.uniform(-6, 0.5)
        kind = rng.integers(5)
        if kind == 0:  # roots anywhere
            roots = rng.uniform(-3, 3, rng.integers(1, 6))
        elif kind == 1:  # one root just outside the interval
            roots = [hi + 10 ** rng.uniform(-12, -2), rng.uniform(-3, 3)]
        elif kind == 2:  # a double root inside (the polynomial only touches 0)
            r = rng.uniform(lo, hi)
            roots = [r, r, rng.uniform(-3, 3)]
        elif kind == 3:  # a root at an end
            roots = [lo if rng.random() < 0.5 else hi, rng.uniform(-3, 3), rng.uniform(-3, 3)]
        else:  # complex pair + a real root away
            roots = [rng.uniform(-3, 3)]
        c = np.poly(roots) * rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-3, 3)
        if kind == 4:
            c = np.polymul(c, [1.0, -2 * rng.uniform(-1, 1), rng.uniform(1, 4)])
        c = np.concatenate((np.zeros(6 - c.size), c))[:6]
        yield c, lo, hi


def test_no_root_is_sound():
    """Whenever the Taylor bound says "no root", numpy.roots finds no real root in [lo, hi] and the
    root search (without the test) finds none either; it does skip most searches of this mix."""
    _onedof.solver()
    rng = np.random.default_rng(21)
    real_roots = _onedof.PURE["_real_roots"]
    saved = _onedof._no_root
    skipped = 0
    total = 0
    for c, lo, hi in _poly_cases(rng, 4000):
        D = np.zeros(_onedof._SCRATCH)
        D[:6] = c
        total += 1
        if not _onedof._no_root(D, 5, lo, hi):
            continue
        skipped += 1
        r = np.roots(np.trim_zeros(c, "f"))
        r = r[np.abs(r.imag) <= 1e-7 * (1 + np.abs(r.real))].real
        assert not np.any((r >= lo - 1e-12) & (r <= hi + 1e-12)), (c, lo, hi, r)
        _onedof._no_root = lambda D, deg, lo, hi: False  # the search alone (pure Python)
        try:
            D = np.zeros(_onedof._SCRATCH)
            D[:6] = c
            assert real_roots(D, 5, lo, hi) == 0
        finally:
            _onedof._no_root = saved
    assert 0.2 * total < skipped < total


@pytest.mark.parametrize("sine", [False, True])
def test_plan_tuple_compiled_is_pure_python(sine):
    """The compiled entry (its float64 entry point) and the Python function give the same floats,
    statuses included (0 on target, -2 a bad value, -3 |vf| > V)."""
    compiled = _onedof.planner()
    _onedof.solver()
    pure = _onedof.PURE["plan_tuple"]
    saved = {name: getattr(_onedof, name) for name in _onedof._JITTED}
    rng = np.random.default_rng(22 + sine)
    cases = [
        (0.0, 10.0, 2.0, 1.0, 0.3, 0.0, 0.3),
        (1.0, 10.0, 2.0, 1.0, 0.0, 0.0, 1.5),
        (1.0, -1.0, 2.0, 1.0, 0.1, 0.0, 0.0),
        (math.nan, 1.0, 2.0, 1.0, 0.1, 0.0, 0.0),
        (1.0, 1.0, 2.0, math.inf, 0.1, 0.0, 0.0),
    ]
    for _ in range(60):
        J, A, V = 10 ** rng.uniform(1, 4), 10 ** rng.uniform(0, 2), 10 ** rng.uniform(-1, 1)
        cases.append(
            (
                rng.uniform(-3, 3),
                J,
                A,
                V,
                rng.uniform(-1.5, 1.5) * V,
                rng.uniform(-1.5, 1.5) * A,
                rng.uniform(-1, 1) * V,
            )
        )
    try:
        for name in _onedof._JITTED:
            setattr(_onedof, name, _onedof.PURE[name])
        for c in cases:
            a, b = np.asarray(pure(*c, sine), dtype=float), np.asarray(compiled(*c, sine))
            assert a.shape == b.shape == (18,)
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
    finally:
        for name, f in saved.items():
            setattr(_onedof, name, f)
    status = [compiled(*c, sine)[0] for c in cases[:5]]
    assert status == [0.0, -3.0, -2.0, -2.0, -2.0]
    assert all(compiled(*c, sine)[0] > 0 for c in cases[5:])


@pytest.mark.parametrize("sine", [False, True])
def test_packed_entry_is_plan_tuple(sine):
    """The scalar planners' entry (packed_planner: 7 arguments, 9 objects) returns exactly
    plan_tuple's values: status, duration, time unit, code, brake segments and the 12 times, bit
    for bit; and planner._pack_res (the batch's profiles) packs a solve_tuple row the same way."""
    from jerklab.planner import _pack_res

    packed = _onedof.packed_planner(sine)
    full = _onedof.planner()
    rng = np.random.default_rng(31 + sine)
    cases = [
        (0.0, 10.0, 2.0, 1.0, 0.3, 0.0, 0.3),
        (1.0, 10.0, 2.0, 1.0, 0.0, 0.0, 1.5),
        (math.nan, 1.0, 2.0, 1.0, 0.1, 0.0, 0.0),
    ]
    for _ in range(300):
        J, A, V = 10 ** rng.uniform(0, 4), 10 ** rng.uniform(-1, 2), 10 ** rng.uniform(-1, 1)
        cases.append(
            (
                rng.uniform(-3, 3),
                J,
                A,
                V,
                rng.uniform(-1.6, 1.6) * V,
                rng.uniform(-1.6, 1.6) * A,
                rng.uniform(-1, 1) * V,
            )
        )
    for c in cases:
        z, r = packed(*c), full(*c, sine)
        assert len(z) == 9 and z[0] == r[0]
        assert (z[1].real, z[1].imag, z[2].real, z[2].imag) == (r[17], r[16], r[1], r[3])
        times = [v for w in z[3:] for v in (w.real, w.imag)]
        assert times == list(r[4:16])
        if r[0] > 0:
            assert _pack_res(r[:16], r[16]) == z
