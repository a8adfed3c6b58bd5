"""The firmware's fixed-point helpers (firmware/jerklab_rig/src/jl_fixed, the host build) against
Python's exact integer arithmetic: the signed 32 x 32 -> 64-bit product, the gain as mantissa and
byte shift with its floor and saturation, the Q16.16 conversion of a float32 and the saturating
adds. The AVR's inline-assembly multiply (the same functions under ``__AVR__``) is compiled for
the ATmega328P and run in simavr against avr-gcc's own int64 arithmetic and a checksum of Python's."""

from __future__ import annotations

import math
import random
import struct
import subprocess

import numpy as np
import pytest
from _avr import run_on_atmega328p
from conftest import require_tool

I32_MIN, I32_MAX = -(2**31), 2**31 - 1
EDGES = [
    I32_MIN,
    I32_MIN + 1,
    -(2**30),
    -65536,
    -256,
    -255,
    -1,
    0,
    1,
    2,
    255,
    256,
    65535,
    2**23,
    2**30,
    I32_MAX - 1,
    I32_MAX,
]


def _run(host, lines):
    out = subprocess.run(
        [str(host), "fixed"],
        input="\n".join(lines) + "\n",
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    ).stdout.split("\n")
    return [ln.split() for ln in out if ln.strip()]


def _sat(x):
    return max(I32_MIN, min(I32_MAX, x))


def _bits(x):
    return struct.unpack("<I", struct.pack("<f", x))[0]


def _pairs(n, seed):
    rng = random.Random(seed)
    pairs = [(a, b) for a in EDGES for b in EDGES]
    pairs += [(rng.randint(I32_MIN, I32_MAX), rng.randint(I32_MIN, I32_MAX)) for _ in range(n)]
    # small and mixed magnitudes (one byte, two bytes, ...) where carries between columns matter
    pairs += [
        (
            rng.randint(-(2 ** rng.randint(1, 31)), 2 ** rng.randint(1, 31) - 1),
            rng.randint(-(2 ** rng.randint(1, 31)), 2 ** rng.randint(1, 31) - 1),
        )
        for _ in range(n)
    ]
    return pairs


def test_signed_product_is_exact(host_driver):
    pairs = _pairs(3000, 1)
    got = _run(host_driver, [f"w {a} {b}" for a, b in pairs])
    assert len(got) == len(pairs)
    for (a, b), (lo, hi) in zip(pairs, got):
        p = a * b
        assert (int(hi) << 32) + int(lo) == p, (a, b)
        assert 0 <= int(lo) < 2**32


def test_mul_q_is_the_floor_of_the_shifted_product_saturated(host_driver):
    rng = random.Random(2)
    cases = [(a, m, s) for (a, m) in _pairs(1500, 3) for s in (rng.randint(0, 4),)]
    cases += [(a, m, s) for a in EDGES for m in (I32_MIN + 1, -1, 1, I32_MAX) for s in range(5)]
    got = _run(host_driver, [f"m {a} {m} {s}" for a, m, s in cases])
    for (a, m, s), (r,) in zip(cases, got):
        assert int(r) == _sat((a * m) >> (8 * s)), (a, m, s)  # >> floors in Python


def _round_away(x):
    """round half away from 0 of an exact Fraction."""
    from fractions import Fraction

    f = math.floor(abs(Fraction(x)) + Fraction(1, 2))
    return f if x >= 0 else -f


def test_gain_quantisation_bound(host_driver):
    """to_qgain: a 24-bit signed mantissa and a byte shift, the largest shift <= 4 with
    |round(g 2^(8 shift))| < 2^23 (rounded half away from 0, exact against Python's fractions);
    so |mant| >= 2^15 (16 significant bits) and |error| <= 2^-16 |g| from |g| >= 2^-17, and
    <= 2^-33 below; |g| >= 2^23 (also after rounding), inf and NaN refused."""
    from fractions import Fraction

    rng = np.random.default_rng(4)
    gains = [
        0.0,
        1.0,
        -1.0,
        0.5,
        0.4999999,
        2.0**-9,
        3e-3,
        -7e-6,
        1e-12,
        123.456,
        -(2.0**22),
        2.0**23 - 1.0,
        -(2.0**23 - 1.0),
        255.99998,
        65535.996,
        2.0**-17,
        1e-40,
        float(np.nextafter(np.float32(32768.0), np.float32(0))),
    ]
    gains += list(np.float32(10.0 ** rng.uniform(-12, 6.9, 400) * rng.choice([-1, 1], 400)))
    # mantissas of all ones: rounding up to 2^23 takes one byte less
    gains += [float(np.float32((2**24 - 1) * 2.0**k)) for k in range(-60, -1)]
    refused = [2.0**23, -(2.0**23), 8388607.5, -8388607.5, 2.0**31, math.inf, -math.inf, math.nan]
    got = _run(host_driver, [f"g {_bits(float(g))}" for g in gains + refused])
    for g, (ok, mant, s) in zip(gains, got):
        g = float(np.float32(g))
        ok, mant, s = int(ok), int(mant), int(s)
        want_s = next(
            (k for k in range(4, -1, -1) if abs(_round_away(Fraction(g) * 256**k)) < 2**23), None
        )
        assert want_s is not None
        assert ok == 1 and s == want_s and mant == _round_away(Fraction(g) * 256**s), (g, mant, s)
        assert abs(mant) < 2**23
        err = abs(Fraction(mant, 256**s) - Fraction(g))
        assert err <= Fraction(1, 2 * 256**s)
        if abs(g) >= 2.0**-17:
            assert abs(mant) >= 2**15 and err <= Fraction(abs(g)) / 2**16, g
        else:
            assert err <= Fraction(1, 2**33), g
    assert all(int(r[0]) == 0 for r in got[len(gains) :])


def test_q16_conversion(host_driver):
    rng = np.random.default_rng(5)
    xs = [
        0.0,
        -0.0,
        0.5,
        -0.5,
        1.0 / 65536,
        1.5 / 65536,
        -2.5 / 65536,
        1.0 / 131072 * 0.99,
        100.25,
        -32767.99,
        32767.999,
        32768.0,
        -32768.0,
        1e30,
        -1e30,
        math.inf,
        -math.inf,
        math.nan,
    ]
    xs += list(np.float32(rng.uniform(-40000, 40000, 300))) + list(
        np.float32(rng.normal(0, 3, 300))
    )
    got = _run(host_driver, [f"q {_bits(float(x))}" for x in xs])
    for x, (r,) in zip(xs, got):
        x = float(np.float32(x))
        r = int(r)
        if math.isnan(x):
            assert r == 0
        elif abs(x) >= 32768.0:
            assert r == (I32_MAX if x > 0 else -I32_MAX)
        else:
            exact = x * 65536.0  # exact in float64
            want = math.floor(abs(exact) + 0.5) * (1 if x >= 0 else -1)
            assert abs(r - want) <= (
                1 if abs(exact - round(exact)) > 0.5 - 2**-24 * abs(exact) else 0
            ), x
            assert abs(r - exact) <= 0.5 + 1e-6 * abs(exact) + 1e-9, x


def test_saturating_adds(host_driver):
    pairs = _pairs(500, 6)
    got = _run(host_driver, [f"s {a} {b}" for a, b in pairs])
    for (a, b), (s, d) in zip(pairs, got):
        assert int(s) == _sat(a + b) and int(d) == _sat(a - b), (a, b)


_AVR_MAIN = r"""
#include <avr/io.h>
#include <avr/interrupt.h>
#include <avr/pgmspace.h>
#include <avr/sleep.h>
#include <util/delay.h>
#include "jl_fixed.h"
static const int32_t kV[][3] PROGMEM = {VECTORS};
static void tx(uint8_t c) { while (!(UCSR0A & _BV(UDRE0))) {} UDR0 = c; }
static void hex32(uint32_t v) {
    for (int8_t i = 28; i >= 0; i -= 4) { uint8_t d = (v >> i) & 15; tx(d < 10 ? '0' + d : 'a' + d - 10); }
}
int main() {
    UBRR0 = 0;
    UCSR0B = _BV(TXEN0);
    // each result against avr-gcc's own int64 arithmetic (the library multiply), and a
    // checksum of all of them for the host to recompute
    uint16_t bad = 0;
    uint32_t sum = 0;
    for (uint16_t k = 0; k < sizeof(kV) / sizeof(kV[0]); ++k) {
        const int32_t a = (int32_t)pgm_read_dword(&kV[k][0]), b = (int32_t)pgm_read_dword(&kV[k][1]);
        const uint8_t s = (uint8_t)pgm_read_dword(&kV[k][2]);
        uint32_t lo;
        int32_t hi;
        jl::mul_s32x32(a, b, &lo, &hi);
        const int32_t q = jl::mul_q_(a, b, s);
        const int64_t p = (int64_t)a * (int64_t)b;
        int64_t w = p >> (8 * s);
        if (w > INT32_MAX) w = INT32_MAX;
        if (w < INT32_MIN) w = INT32_MIN;
        // the narrow product (jl_mac) with b's low 24 bits as a signed mantissa, and its
        // multiply-accumulate onto a (saturated)
        const int32_t m = (int32_t)((uint32_t)b << 8) >> 8;
        const jl::QGain g = {m, s};
        const int32_t n = jl::mul_g_(a, m, s);
        const int32_t c = jl::mac_g(a, b, g);
        int64_t v = ((int64_t)a * (int64_t)m) >> (8 * s);
        if (v > INT32_MAX) v = INT32_MAX;
        if (v < INT32_MIN) v = INT32_MIN;
        int64_t t = (int64_t)a + (((int64_t)b * (int64_t)m) >> (8 * s) > INT32_MAX ? INT32_MAX :
                     (((int64_t)b * (int64_t)m) >> (8 * s) < INT32_MIN ? INT32_MIN :
                      ((int64_t)b * (int64_t)m) >> (8 * s)));
        if (t > INT32_MAX) t = INT32_MAX;
        if (t < INT32_MIN) t = INT32_MIN;
        if (lo != (uint32_t)p || hi != (int32_t)(p >> 32) || q != (int32_t)w) ++bad;
        if (n != (int32_t)v || c != (int32_t)t) ++bad;
        sum += lo ^ (uint32_t)hi ^ (uint32_t)q ^ (uint32_t)n ^ (uint32_t)c;
    }
    tx('<'); hex32(bad); tx(' '); hex32(sum); tx('>'); tx('\n');   // (simavr prints whole lines)
    _delay_ms(20);               // the simulated UART drains before the simulation ends
    cli();
    sleep_cpu();
}
"""


# The firmware's builds of the control law on the AVR (firmware/jerklab_rig/src/jl_port.h): the
# default (the C++ law of jl_law.h, its multiply-accumulate the assembly primitive jl_mac),
# JL_ASM=1 (the law's assembly twin jl_pidq_step) and JL_PURE_C=1 (no assembly in the law's path)
AVR_BUILDS = pytest.mark.parametrize(
    "avr_flags", [(), ("-DJL_ASM=1",), ("-DJL_PURE_C=1",)], ids=["default", "asm", "pure-c"]
)


@AVR_BUILDS
def test_avr_assembly_multiply_on_the_simulated_atmega328p(tmp_path, avr_flags):
    """The inline-assembly product (sixteen MULs, the signed correction) and mul_q's window and
    saturation, and the control step's narrow multiply-accumulate (jl_mac: twelve MULs, the
    24-bit mantissa's signed correction, the window, both saturations) as compiled for the
    ATmega328P, run in simavr, against avr-gcc's int64 arithmetic and Python's integers."""
    require_tool("avr-g++", "simavr")
    rng = random.Random(7)
    pairs = [(a, b) for a in EDGES[::2] + [-1, 1] for b in EDGES[1::2] + [0]]
    pairs += [(rng.randint(I32_MIN, I32_MAX), rng.randint(I32_MIN, I32_MAX)) for _ in range(60)]
    pairs += [
        (
            rng.randint(-(2 ** rng.randint(1, 31)), 2 ** rng.randint(1, 31) - 1),
            rng.randint(-(2 ** rng.randint(1, 31)), 2 ** rng.randint(1, 31) - 1),
        )
        for _ in range(60)
    ]
    cases = [(a, b, rng.randint(0, 4)) for a, b in pairs]
    body = ",".join(
        f"{{{a}L,{b}L,{s}}}"
        if a != I32_MIN and b != I32_MIN
        else f"{{{'(-2147483647L-1)' if a == I32_MIN else str(a) + 'L'},"
        f"{'(-2147483647L-1)' if b == I32_MIN else str(b) + 'L'},{s}}}"
        for a, b, s in cases
    )
    import re

    text = run_on_atmega328p(tmp_path, _AVR_MAIN.replace("VECTORS", body), flags=avr_flags)
    got = re.findall(r"<([0-9a-f]{8}) ([0-9a-f]{8})>", text)
    assert len(got) == 1, text[-500:]
    bad, checksum = int(got[0][0], 16), int(got[0][1], 16)
    want = 0
    for a, b, s in cases:
        p = a * b
        lo, hi, q = p & 0xFFFFFFFF, (p >> 32) & 0xFFFFFFFF, _sat(p >> (8 * s)) & 0xFFFFFFFF
        m = ((b & 0xFFFFFF) ^ 0x800000) - 0x800000  # b's low 24 bits, signed
        n = _sat((a * m) >> (8 * s)) & 0xFFFFFFFF
        c = _sat(a + _sat((b * m) >> (8 * s))) & 0xFFFFFFFF
        want = (want + (lo ^ hi ^ q ^ n ^ c)) & 0xFFFFFFFF
    assert bad == 0 and checksum == want, (bad, hex(checksum), hex(want))


def test_pwm_rounding_is_lround_clamped(host_driver):
    """round_clamp (the control step's PWM write): lround, halves away from 0, clamped to +-top,
    on every half-integer and its float32 neighbours below 2048, random floats, the edges."""
    rng = np.random.default_rng(9)
    xs = []
    for k in range(0, 2048):
        h = np.float32(k + 0.5)
        xs += [h, np.nextafter(h, np.float32(0)), np.nextafter(h, np.float32(4096)), np.float32(k)]
    xs += list(np.float32(rng.uniform(-3000, 3000, 3000))) + list(
        np.float32(rng.normal(0, 2, 1000))
    )
    xs += [
        np.float32(v)
        for v in (0.0, -0.0, 0.49999997, 1e-40, 32767.0, 32768.0, -1e30, np.inf, -np.inf)
    ]
    xs += [-x for x in xs[:8192]]
    cases = [(float(x), top) for x in xs for top in (1023,)] + [(float(x), 255) for x in xs[:2000]]
    got = _run(
        host_driver, [f"p {_bits(x)} {top}" for x, top in cases] + [f"p {_bits(math.nan)} 1023"]
    )
    for (x, top), (r,) in zip(cases, got):
        want = math.floor(abs(x) + 0.5) if math.isfinite(x) else top
        want = min(want, top) * (-1 if math.copysign(1.0, x) < 0 else 1)
        assert int(r) == want, (x, top)
    assert int(got[-1][0]) == 1023


def _qgain_model(g):
    """to_qgain in Python: (mant, shift) of the float32 g (the rule test_gain_quantisation_bound
    checks the host's against)."""
    from fractions import Fraction

    g = float(np.float32(g))
    s = next(k for k in range(4, -1, -1) if abs(_round_away(Fraction(g) * 256**k)) < 2**23)
    return _round_away(Fraction(g) * 256**s), s


class _PidQModel:
    """jl::PidQ's integer law (jl_law.h) on Python integers: products floored and saturated,
    sums saturated, conditional integration, the clamp."""

    def __init__(self, kpd, kid, kdd, gamma, limit):
        self.g = [_qgain_model(x) for x in (kpd, kid, kdd, gamma)]
        self.lim = _round_away(__import__("fractions").Fraction(float(np.float32(limit))) * 65536)
        self.i = self.e_prev = self.d = 0

    @staticmethod
    def _mac(acc, a, g):
        m, s = g
        return _sat(acc + _sat((a * m) >> (8 * s)))

    def step(self, e, ff):
        kpd, kid, kdd, gamma = self.g
        e = max(-(2**30), min(2**30 - 1, e))
        d = self._mac(0, self.d, gamma) if gamma[0] != 0 else 0
        d = self._mac(d, e - self.e_prev, kdd)
        self.d, self.e_prev = d, e
        fpd = self._mac(_sat(ff + d), e, kpd)
        i0 = self.i
        i = self._mac(i0, e, kid)
        u = _sat(fpd + i)
        sat = abs(u) > self.lim
        if sat:
            if e != 0 and (e < 0) == (u < 0):
                u, i = _sat(fpd + i0), i0
            u = max(-self.lim, min(self.lim, u))
        self.i = i
        return u, sat


_AVR_PID_MAIN = r"""
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <avr/sleep.h>
#include <avr/interrupt.h>
#include <util/delay.h>
#include "jl_control.h"
static const float kG[][5] PROGMEM = {GAINS};
static const int32_t kV[][2] PROGMEM = {VECTORS};
static void tx(uint8_t c) { while (!(UCSR0A & _BV(UDRE0))) {} UDR0 = c; }
static void hex32(uint32_t v) {
    for (int8_t i = 28; i >= 0; i -= 4) { uint8_t d = (v >> i) & 15; tx(d < 10 ? '0' + d : 'a' + d - 10); }
}
static jl::PidQ pid;
int main() {
    UBRR0 = 0;
    UCSR0B = _BV(TXEN0);
    for (uint8_t g = 0; g < sizeof(kG) / sizeof(kG[0]); ++g) {
        float p[5];
        memcpy_P(p, kG[g], sizeof(p));
        const bool ok = pid.set(p[0], p[1], p[2], p[3], p[4]);
        pid.reset();
        uint32_t sum = 0, nsat = 0;
        for (uint16_t k = 0; k < sizeof(kV) / sizeof(kV[0]); ++k) {
            bool sat;
            const int32_t u = pid.step((int32_t)pgm_read_dword(&kV[k][0]),
                                       (int32_t)pgm_read_dword(&kV[k][1]), &sat);
            sum = (sum * 31u) ^ (uint32_t)u;
            nsat += sat;
        }
        tx('<'); hex32(ok); tx(' '); hex32(sum); tx(' '); hex32(nsat); tx('>'); tx('\n');
    }
    _delay_ms(20);
    cli();
    sleep_cpu();
}
"""


def _c_i32(v):
    return "(-2147483647L-1)" if v == I32_MIN else f"{v}L"


@AVR_BUILDS
def test_avr_pid_matches_the_integer_law_on_the_simulated_atmega328p(tmp_path, avr_flags):
    """PidQ::step as the Uno runs it, in each build (the C++ law of jl_law.h; with JL_ASM=1 its
    assembly twin jl_pidq_step; with JL_PURE_C=1 without the assembly multiply) against the
    integer law in Python, sample by sample (a running checksum of u and the count of saturated
    samples): with and without the derivative filter, negative gains, errors beyond 2^30 (the
    clamp), the output clamp with and without the integrator frozen, e = 0."""
    require_tool("avr-g++", "simavr")
    import re

    gains = [
        (374.6, 0.05, 310.0, 0.0, 1023.0),
        (12.0, 1.2e-3, 60.0, 0.6, 1023.0),
        (-3.5, -0.02, 7.25, -0.3, 255.0),
        (1.0e4, 2.0e-6, 4.0e5, 0.95, 1023.0),
        (0.75, 0.0, 0.0, 0.0, 100.0),
    ]
    rng = random.Random(11)
    vecs = []
    for k in range(300):
        r = rng.random()
        if r < 0.5:
            e = rng.randint(-40 * 65536, 40 * 65536)
        elif r < 0.7:
            e = rng.randint(-(2**16), 2**16)
        elif r < 0.8:
            e = 0
        elif r < 0.9:
            e = rng.choice([I32_MIN, I32_MAX, -I32_MAX, 2**30 + 1, -(2**30) - 1, 2**30, -(2**30)])
        else:
            e = rng.randint(-(2**31), 2**31 - 1)
        ff = rng.randint(-600 * 65536, 600 * 65536) if rng.random() < 0.7 else 0
        vecs.append((e, ff))
    body_g = ",".join("{" + ",".join(f"{float(np.float32(x))!r}f" for x in g) + "}" for g in gains)
    body_v = ",".join(f"{{{_c_i32(e)},{_c_i32(f)}}}" for e, f in vecs)
    text = run_on_atmega328p(
        tmp_path,
        _AVR_PID_MAIN.replace("GAINS", body_g).replace("VECTORS", body_v),
        flags=avr_flags,
    )
    got = re.findall(r"<([0-9a-f]{8}) ([0-9a-f]{8}) ([0-9a-f]{8})>", text)
    assert len(got) == len(gains), text[-500:]
    for g, (ok, checksum, nsat) in zip(gains, got):
        model = _PidQModel(*g)
        s, n = 0, 0
        for e, ff in vecs:
            u, sat = model.step(e, ff)
            s = ((s * 31) ^ (u & 0xFFFFFFFF)) & 0xFFFFFFFF
            n += sat
        assert int(ok, 16) == 1, g
        assert (int(checksum, 16), int(nsat, 16)) == (s, n), (g, checksum, hex(s), nsat, n)
        assert 0 < n < len(vecs), g  # both branches ran
