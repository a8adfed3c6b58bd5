#include "jl_planner.h"
#include "jl_port.h"
#include "jl_protocol.h"
#include <stddef.h>
#include <string.h>

namespace jl {

static const float kTwoOverPi = 0.636619772367581f;

// Peak acceleration, velocity and position at the end of the rising pulse of an acceleration
// phase from rest with pulse time tj (jerklab.planner._evaluate: apk, v1, x1).
static void pulse_ends(uint8_t shape, float jpar, float tj, float* apk, float* v1, float* x1) {
    if (shape == kShapeSine) {
        *apk = kTwoOverPi * jpar * tj;
        *v1 = 0.5f * *apk * tj;
        *x1 = *apk * tj * tj * (0.25f - 1.0f / (kPi * kPi));
    } else if (shape == kShapeLinear) {
        *apk = jpar * tj;
        *v1 = 0.5f * *apk * tj;
        *x1 = *apk * tj * tj * (1.0f / 6.0f);
    } else {
        *apk = jpar;
        *v1 = *x1 = 0.0f;
    }
}

// The next segment of a rest-to-rest layout along the move (+x): from time t the state (x, v, a)
// under the jerk 0 (a pulse: pulse() then sets its jerk and frequency).
static Segment* __attribute__((noinline)) put(Plan* p, float t, float x, float v, float a) {
    Segment* s = &p->seg.at[p->nseg++];
    s->t0 = t;
    s->x0 = x;
    s->v0 = v;
    s->a0 = a;
    s->jp = 0.0f;
    s->w = 0.0f;
    return s;
}
static void __attribute__((noinline)) pulse(Segment* s, float jp, float w) {
    s->jp = jp;
    s->w = w;
}

// The plan of a rest-to-rest move from (0, 0): its segments from the phase times (tj, ta, tv)
// and shape. Each segment is laid out along the move: positions of the acceleration half
// integrated forward from rest, those of the deceleration backward from the target (the mirror
// of an acceleration from rest), so the end is exactly the target. A move in -x then has x0, v0,
// a0 and jp negated (exactly -1 times them) and place() adds the start (0, 0), which makes a -0
// position +0.
static void rest_to_rest(Plan* p, uint8_t shape, float distance, float jpar, float tj, float ta,
                         float tv) {
    const bool sine = shape == kShapeSine;
    const float D = jl_fabsf(distance);
    p->cruise_time = tv;
    float apk, v1, x1;
    pulse_ends(shape, jpar, tj, &apk, &v1, &x1);
    const float vp = apk * (tj + ta);               // the cruise velocity
    p->cruise_velocity = vp;
    const float tacc = 2.0f * tj + ta;
    const float w = sine && tj > 0.0f ? kPi / tj : 0.0f;   // the pulses' (0: linear jerk)
    const float jl = shape == kShapeStep ? 0.0f : jpar;
    p->nseg = 0;
    float t = 0.0f;
    if (tacc > 0.0f) {
        if (tj > 0.0f) pulse(put(p, 0.0f, 0.0f, 0.0f, 0.0f), jl, w);
        float x = x1, v = v1;
        t = tj;
        if (ta > 0.0f) {
            put(p, t, x, v, apk);
            x += ta * (v + 0.5f * apk * ta);
            v += apk * ta;
            t += ta;
        }
        if (tj > 0.0f) pulse(put(p, t, x, v, apk), -jl, w);
        t = tacc;
    }
    const float xc = 0.5f * vp * tacc;             // symmetric pulse pair: mean velocity
    if (tv > 0.0f) put(p, t, xc, vp, 0.0f);
    t += tv;
    if (tacc > 0.0f) {
        if (tj > 0.0f) pulse(put(p, t, D - xc, vp, 0.0f), -jl, w);
        if (ta > 0.0f) {
            // mirror of the rising pulse's end plus the plateau: tau = tj + ta
            const float xa = x1 + ta * (v1 + 0.5f * apk * ta);
            put(p, t + tj, D - xa, vp - v1, -apk);
        }
        if (tj > 0.0f) pulse(put(p, t + tj + ta, D - x1, v1, -apk), jl, w);
        t += tacc;
    }
    if (distance < 0.0f) {
        for (uint8_t i = 0; i < p->nseg; ++i)
            for (float* f = &p->seg.at[i].x0; f <= &p->seg.at[i].jp; ++f) *f = -*f;   // x0, v0, a0, jp
    }
    p->duration = t;
    p->target = distance;                          // the rest at the target (exactly)
    ++p->nseg;
    place(p, 0.0f, 0.0f);
    p->accel_time = tacc;
}

// The cube root of x >= 0 (jl_planner.h).
float __attribute__((noinline)) cube_root(float x) {
    uint32_t i;
    memcpy(&i, &x, 4);
    if (i - 1u >= 0x7F7FFFFFu) return x;   // (on the bits) +0, inf, NaN and x < 0 as they are
    if (i < 0x00800000u) return cube_root(x * 16777216.0f) * (1.0f / 256.0f);  // subnormal
    i = i / 3u + 709921077u;
    float y;
    memcpy(&y, &i, 4);
    for (uint8_t k = 0; k < 4; ++k) y -= (y - x / (y * y)) * (1.0f / 3.0f);
    return y;
}

// (the range checks on the IEEE bits: jl_fixed's positive_le and nonneg_f)
static PlanStatus check(float d, float J, float E, float W) {
    if (!finite_f(d)) return kPlanBadDistance;
    // (finite and > 0: 0 < x <= the largest float)
    if (!positive_le(J, 3.40282347e38f)) return kPlanBadJerk;
    if (!positive_le(E, 3.40282347e38f)) return kPlanBadAccel;
    if (!positive_le(W, 3.40282347e38f)) return kPlanBadVelocity;
    return kPlanOk;
}

PlanStatus plan_sine_jerk(float distance, float J, float E, float W, Plan* p) {
    PlanStatus st = check(distance, J, E, W);
    if (st != kPlanOk) return st;
    const float theta = jl_fabsf(distance);
    if (theta == 0.0f) { rest_to_rest(p, kShapeSine, distance, J, 0.0f, 0.0f, 0.0f); return kPlanOk; }
    float T = cube_root(kTwoPi * theta / J);                   // x(T) = J T^3/(4 pi) = theta/2
    if (J * T / kPi > E) T = E * kPi / J;                       // eps_max = J T / pi
    if (J * T * T / kTwoPi > W) T = jl_sqrtf(kTwoPi * W / J);   // omega_max = J T^2/(2 pi)
    float wmax = J * T * T / kTwoPi;
    float wbar = wmax < W ? wmax : W;
    if (!(wbar > 0.0f)) return kPlanBadTime;
    float tv = (theta - wbar * T) / wbar;
    if (tv < 0.0f) tv = 0.0f;                                   // rounding leaves ~ -1e-7
    rest_to_rest(p, kShapeSine, distance, J, 0.5f * T, 0.0f, tv);
    p->accel_time = T;
    return kPlanOk;
}

// jerklab.planner._scurve_times: (tj, ta, tv) of the time-optimal S-curve over d >= 0.
static void scurve_times(float d, float J, float A, float V, float* tj, float* ta, float* tv) {
    *tj = *ta = *tv = 0.0f;
    if (d == 0.0f) return;
    float t = A / J, a = 0.0f, dv;
    if (V * J >= A * A) {
        a = V / A - t;
        dv = V * (t + t + a);
    } else {
        t = jl_sqrtf(V / J);
        dv = 2.0f * V * t;
    }
    if (d >= dv) { *tj = t; *ta = a; *tv = (d - dv) / V; return; }
    t = A / J;
    const float t2 = t * t;
    if (d >= 2.0f * A * t2) {
        const float q = d / A;
        *tj = t;
        *ta = 2.0f * (q - 2.0f * t2) / (3.0f * t + jl_sqrtf(t2 + 4.0f * q));
        return;
    }
    *tj = cube_root(d * (0.5f / J));
}

PlanStatus plan_sine_jerk_optimal(float distance, float J, float E, float W, Plan* p) {
    PlanStatus st = check(distance, J, E, W);
    if (st != kPlanOk) return st;
    float tj, ta, tv;
    scurve_times(jl_fabsf(distance), kTwoOverPi * J, E, W, &tj, &ta, &tv);
    rest_to_rest(p, kShapeSine, distance, J, tj, ta, tv);
    return kPlanOk;
}

PlanStatus plan_scurve(float distance, float J, float A, float V, Plan* p) {
    PlanStatus st = check(distance, J, A, V);
    if (st != kPlanOk) return st;
    float tj, ta, tv;
    scurve_times(jl_fabsf(distance), J, A, V, &tj, &ta, &tv);
    rest_to_rest(p, kShapeLinear, distance, J, tj, ta, tv);
    return kPlanOk;
}

PlanStatus plan_trapezoid(float distance, float A, float V, Plan* p) {
    PlanStatus st = check(distance, 1.0f, A, V);
    if (st != kPlanOk) return st;
    const float d = jl_fabsf(distance);
    float ta = 0.0f, tv = 0.0f;
    if (d == 0.0f) {
    } else if (d * A >= V * V) {
        ta = V / A;
        tv = (d - V * ta) / V;
    } else {
        ta = jl_sqrtf(d / A);
    }
    rest_to_rest(p, kShapeStep, distance, A, 0.0f, ta, tv);
    return kPlanOk;
}

PlanStatus plan_kind(uint8_t kind, float d, float J, float A, float V, Plan* p) {
#if JL_WITH_BOARD_PLANNERS
    switch (kind) {
    case kPlannerSineJerk: return plan_sine_jerk(d, J, A, V, p);
    case kPlannerSineJerkOptimal: return plan_sine_jerk_optimal(d, J, A, V, p);
    case kPlannerScurve: return plan_scurve(d, J, A, V, p);
    default: return plan_trapezoid(d, A, V, p);
    }
#else
    // (the planners 1-3 are the host's: only Stojcic eq. 4's is built)
    if (kind != kPlannerSineJerk) return kPlanBadTime;
    return plan_sine_jerk(d, J, A, V, p);
#endif
}

// ------------------------------------------------------------------ host-planned plans

uint8_t HostPlanner::add(Plan* p, const HostSegment& s) {
    const uint8_t i = s.index;
    if (!(i == 0 || i == count) || i >= kMaxHostSegments) return 0;
    if (s.kind > 1) return 1;
    if (!positive_le(s.duration, 1e7f)) return 2;
    if (!abs_le(s.x0, 1e6f)) return 3;
    float f[3];                             // v0, a0, jerk: fields 4, 5, 6
    memcpy(f, reinterpret_cast<const uint8_t*>(&s) + offsetof(HostSegment, v0), sizeof(f));
    for (uint8_t k = 0; k < 3; ++k)
        if (!abs_le(f[k], 3.40282347e38f)) return static_cast<uint8_t>(4 + k);
    if (i == 0) {
        p->x_start = s.x0;
        p->t_start = 0.0f;
    }
    const float t0 = i == 0 ? 0.0f : p->duration;   // the previous segment's end
    Segment& g = p->seg.at[i];
    g.t0 = t0;
    memcpy(&g.x0, &s.x0, 3 * sizeof(float));   // x0, v0, a0 (the same order)
    g.jp = s.jerk;
    g.w = s.kind ? kPi / s.duration : 0.0f;
    p->duration = t0 + s.duration;
    p->nseg = static_cast<uint8_t>(i + 1);
    count = static_cast<uint8_t>(i + 1);
    return 0xFF;
}

uint8_t HostPlanner::check(const HostCommit& c) const {
    if (c.n_segments == 0 || c.n_segments != count) return 0;
    if (!abs_le(c.target, 1e6f)) return 1;
    float f[3];                             // accel_time, cruise_time, cruise_velocity: 2, 3, 4
    memcpy(f, reinterpret_cast<const uint8_t*>(&c) + offsetof(HostCommit, accel_time), sizeof(f));
    for (uint8_t k = 0; k < 3; ++k)
        if (!nonneg_f(f[k])) return static_cast<uint8_t>(2 + k);
    if (c.planner > kPlannerTrapezoid && c.planner != kPlannerHost) return 5;
    return 0xFF;
}

void __attribute__((noinline)) HostPlanner::commit(Plan* p, const HostCommit& c) {
    p->target = c.target;                  // the rest at the target, from t_start + duration
    p->nseg = static_cast<uint8_t>(count + 1);
    p->accel_time = c.accel_time;
    p->cruise_time = c.cruise_time;
    p->cruise_velocity = c.cruise_velocity;
    count = 0;
}

void __attribute__((noinline)) place(Plan* p, float t_start, float x_start) {
    p->t_start = t_start;
    p->x_start = x_start;
    Segment* g = p->seg.at;
    for (uint8_t n = static_cast<uint8_t>(p->nseg - 1); n > 0; --n, ++g) {   // (not the rest)
        g->t0 += t_start;
        g->x0 += x_start;
    }
    p->target += x_start;                   // (the rest's t0 is t_start + duration)
}

// The closed form on a segment of constant jerk at local time u >= 0.
static void eval_poly(const Segment& s, float u, Sample* o) {
    const float ju = s.jp * u;
    o->jerk = s.jp;
    o->accel = s.a0 + ju;
    o->velocity = s.v0 + u * (s.a0 + 0.5f * ju);
    o->position = s.x0 + u * (s.v0 + u * (0.5f * s.a0 + ju * (1.0f / 6.0f)));
}

// The closed form on segment s at local time u >= 0.
static void eval_seg(const Segment& s, float u, Sample* o) {
    if (is_pulse(s)) {
        const float w = s.w, wu = w * u;
        const float sn = jl_sinf(wu), omc = 1.0f - jl_cosf(wu);
        const float c = s.jp / w;
        o->jerk = s.jp * sn;
        o->accel = s.a0 + c * omc;
        o->velocity = s.v0 + s.a0 * u + c * (u - sn / w);
        o->position = s.x0 + u * (s.v0 + 0.5f * s.a0 * u) + c * (0.5f * u * u - omc / (w * w));
    } else {
        o->jerk = s.jp;
        o->accel = s.a0 + s.jp * u;
        o->velocity = s.v0 + u * (s.a0 + 0.5f * s.jp * u);
        o->position = s.x0 + u * (s.v0 + u * (0.5f * s.a0 + u * s.jp * (1.0f / 6.0f)));
    }
}

// Segment i of p is the rest at the target (the last one, not stored: see Plan).
static bool is_rest(const Plan& p, uint8_t i) { return i + 1 >= p.nseg; }

// The start time of segment i of p.
static float __attribute__((noinline)) t0_of(const Plan& p, uint8_t i) {
    return is_rest(p, i) ? p.t_start + p.duration : p.seg.at[i].t0;
}

// Segment i of p is a half-sine pulse.
static bool pulse_at(const Plan& p, uint8_t i) { return !is_rest(p, i) && is_pulse(p.seg.at[i]); }

void sample(const Plan& p, float t, Sample* s) {
    if (t < t0_of(p, 0)) {
        s->jerk = s->accel = s->velocity = 0.0f;
        s->position = p.x_start;
        return;
    }
    uint8_t i = static_cast<uint8_t>(p.nseg - 1);
    const float tr = t0_of(p, i);
    if (!(t < tr)) {
        // the rest: the closed form with v0 = a0 = jp = 0 is x0 + u 0 (-0 made +0)
        s->jerk = s->accel = s->velocity = 0.0f;
        s->position = p.target + (t - tr) * 0.0f;
        return;
    }
    do --i; while (i > 0 && t < p.seg.at[i].t0);
    eval_seg(p.seg.at[i], t - p.seg.at[i].t0, s);
}

// ------------------------------------------------------------------------------- stepper

// ------------------------------------------------------------------- fixed point

void q32_add(Q32* a, const Q32& b) {
#if defined(__AVR__)
    // eight add-with-carry steps through the X and Z pointers (~60 cycles; avr-gcc's C for the
    // carry compare is twice the code)
    uint8_t* pa = reinterpret_cast<uint8_t*>(a);
    const uint8_t* pb = reinterpret_cast<const uint8_t*>(&b);
    asm volatile(
        "ld r18, X\n\t" "ld r19, Z+\n\t" "add r18, r19\n\t" "st X+, r18\n\t"
        "ld r18, X\n\t" "ld r19, Z+\n\t" "adc r18, r19\n\t" "st X+, r18\n\t"
        "ld r18, X\n\t" "ld r19, Z+\n\t" "adc r18, r19\n\t" "st X+, r18\n\t"
        "ld r18, X\n\t" "ld r19, Z+\n\t" "adc r18, r19\n\t" "st X+, r18\n\t"
        "ld r18, X\n\t" "ld r19, Z+\n\t" "adc r18, r19\n\t" "st X+, r18\n\t"
        "ld r18, X\n\t" "ld r19, Z+\n\t" "adc r18, r19\n\t" "st X+, r18\n\t"
        "ld r18, X\n\t" "ld r19, Z+\n\t" "adc r18, r19\n\t" "st X+, r18\n\t"
        "ld r18, X\n\t" "ld r19, Z+\n\t" "adc r18, r19\n\t" "st X+, r18\n\t"
        : "+x"(pa), "+z"(pb)
        :
        : "r18", "r19", "memory");
#else
    const uint32_t lo = a->lo + b.lo;
    a->hi += b.hi + (lo < b.lo ? 1 : 0);
    a->lo = lo;
#endif
}

int32_t __attribute__((noinline)) q32_window24(const Q32& x) {
    const int32_t hi = x.hi;
    if (static_cast<uint32_t>(hi + 8388608L) >= 16777216UL) return hi < 0 ? INT32_MIN : INT32_MAX;
    int32_t w;
    memcpy(&w, reinterpret_cast<const uint8_t*>(&x) + 3, 4);
    return w;
}

// a[i] += a[i + 1] for i = 0 .. n - 1 (n >= 1), in this order (each with the next one's old
// value): a chunk's forward differences advanced by one sample in one call. On the AVR each
// add is eight add-with-carry steps in place (Z post-incremented, the addend at Z + 8).
static void __attribute__((noinline)) q32_diffs(Q32* a, uint8_t n) {
#if defined(__AVR__)
    uint8_t* pa = reinterpret_cast<uint8_t*>(a);
    asm volatile(
        "1:\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "add r18, r19\n\t" "st Z+, r18\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "adc r18, r19\n\t" "st Z+, r18\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "adc r18, r19\n\t" "st Z+, r18\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "adc r18, r19\n\t" "st Z+, r18\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "adc r18, r19\n\t" "st Z+, r18\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "adc r18, r19\n\t" "st Z+, r18\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "adc r18, r19\n\t" "st Z+, r18\n\t"
        "ld r18, Z\n\t" "ldd r19, Z+8\n\t" "adc r18, r19\n\t" "st Z+, r18\n\t"
        "dec %[n]\n\t" "brne 1b\n\t"
        : "+z"(pa), [n] "+r"(n)
        :
        : "r18", "r19", "memory");
#else
    for (uint8_t i = 0; i < n; ++i) q32_add(&a[i], a[i + 1]);
#endif
}

// a += y 2^s (s = 0..31): the sinusoid in units 2^(s - 32) into a Q32.32. On the AVR y 2^(s & 7)
// by four MULs (40 bits, the top one MULSU), added at byte s >> 3 with the carry and the sign
// through the top.
void __attribute__((noinline)) q32_add_units(Q32* a, int32_t y, uint8_t s) {
#if defined(__AVR__)
    // m = 2^(s & 7) by three conditional shifts (the last a nibble swap), the byte s >> 3 added
    // to the pointer, cnt = 3 - (s >> 3) bytes above the five of y 2^(s & 7). Fixed registers,
    // all call-clobbered (none to save): y in r20..r23 (its low byte then holds the product's
    // fifth), s then cnt in r18, m then the sign byte in r19, the product's bytes 0..3 in
    // r24, r25, r30, r31.
    register uint8_t* pa asm("r26") = reinterpret_cast<uint8_t*>(a);
    register int32_t yy asm("r20") = y;
    register uint8_t ss asm("r18") = s;
    asm volatile(
        "ldi r19, 1\n\t"
        "sbrc r18, 0\n\t" "lsl r19\n\t"
        "sbrc r18, 1\n\t" "lsl r19\n\t"
        "sbrc r18, 1\n\t" "lsl r19\n\t"
        "sbrc r18, 2\n\t" "swap r19\n\t"
        "lsr r18\n\t" "lsr r18\n\t" "lsr r18\n\t"
        "add r26, r18\n\t" "adc r27, __zero_reg__\n\t"
        "neg r18\n\t" "subi r18, -3\n\t"
        "mul r20, r19\n\t" "movw r24, r0\n\t"
        "mul r21, r19\n\t" "add r25, r0\n\t" "clr r30\n\t" "adc r30, r1\n\t"
        "mul r22, r19\n\t" "add r30, r0\n\t" "clr r31\n\t" "adc r31, r1\n\t"
        "mulsu r23, r19\n\t" "add r31, r0\n\t" "clr r20\n\t" "adc r20, r1\n\t"
        "clr r1\n\t"
        "clr r19\n\t" "sbrc r20, 7\n\t" "com r19\n\t"
        "ld r0, X\n\t" "add r0, r24\n\t" "st X+, r0\n\t"
        "ld r0, X\n\t" "adc r0, r25\n\t" "st X+, r0\n\t"
        "ld r0, X\n\t" "adc r0, r30\n\t" "st X+, r0\n\t"
        "ld r0, X\n\t" "adc r0, r31\n\t" "st X+, r0\n\t"
        "ld r0, X\n\t" "adc r0, r20\n\t" "st X+, r0\n\t"
        "tst r18\n\t" "breq 2f\n\t"
        "1:\n\t" "ld r0, X\n\t" "adc r0, r19\n\t" "st X+, r0\n\t" "dec r18\n\t" "brne 1b\n\t"
        "2:\n\t"
        : "+r"(pa), "+r"(yy), "+r"(ss)
        :
        : "r0", "r19", "r24", "r25", "r30", "r31", "memory");
#else
    const uint64_t v = ((static_cast<uint64_t>(static_cast<uint32_t>(a->hi)) << 32) | a->lo)
                       + static_cast<uint64_t>(static_cast<int64_t>(y) * (static_cast<int64_t>(1) << s));
    a->lo = static_cast<uint32_t>(v);
    a->hi = static_cast<int32_t>(static_cast<uint32_t>(v >> 32));
#endif
}

// x 2^32 from the float's bits: the 24-bit mantissa m, x 2^32 = m 2^(e - 118), signed and added
// by q32_add_units (from 2^23 up m shifted into hi); exact from 2^-8 up, truncated toward 0 to
// 2^-32 below. No 64-bit arithmetic.
static void __attribute__((noinline)) q32_set(Q32* r, float x) {
    uint8_t by[4];
    memcpy(by, &x, 4);
    const bool neg = (by[3] & 0x80) != 0;
    const uint8_t e = static_cast<uint8_t>((by[3] << 1) | (by[2] >> 7));   // biased exponent
    by[3] = 0;
    by[2] |= 0x80;
    int32_t m;                                      // the mantissa: x 2^32 = m 2^(e - 118)
    memcpy(&m, by, 4);
    r->lo = 0;
    r->hi = 0;
    if (e >= 118 + 32) {                            // whole: m 2^(e - 150) in hi
        if (e >= 127 + 31) m = 0x7FFFFFFFL;         // |x| >= 2^31, inf, NaN: saturated
        else for (uint8_t k = static_cast<uint8_t>(e - 150); k; --k) m <<= 1;   // < 2^31
        r->hi = neg ? -m : m;
        return;
    }
    uint8_t sh = 0;
    if (e < 118) {                                  // (0 and subnormals: m shifted out)
        for (uint8_t k = static_cast<uint8_t>(118 - e); k && m; --k) m >>= 1;
    } else {
        sh = static_cast<uint8_t>(e - 118);
    }
    q32_add_units(r, neg ? -m : m, sh);
}

Q32 to_q32(float x) {
    Q32 r;
    q32_set(&r, x);
    return r;
}

// The widest 32-bit window of x that holds it: Q16.16 (*n = 16) when |x| < 2^15, else Q24.8
// (*n = 8) when |x| < 2^23, else Q24.8's +-(2^31 - 1) (*n = 8). Byte moves (AVR: hi's bytes 2, 3
// compared with byte 1's sign, byte 3 with byte 2's).
static int32_t __attribute__((noinline)) q32_window(const Q32& x, uint8_t* n) {
    int32_t w;
    uint8_t nb;
#if defined(__AVR__)
    const uint8_t* px = reinterpret_cast<const uint8_t*>(&x);
    uint8_t t;
    asm volatile(
        "ldd %A[w], Z+2\n\t" "ldd %B[w], Z+3\n\t" "ldd %C[w], Z+4\n\t" "ldd %D[w], Z+5\n\t"
        "ldi %[n], 16\n\t"
        "mov %[t], %D[w]\n\t" "lsl %[t]\n\t" "sbc %[t], %[t]\n\t"
        "ldd __tmp_reg__, Z+6\n\t" "cp __tmp_reg__, %[t]\n\t" "brne 1f\n\t"
        "ldd __tmp_reg__, Z+7\n\t" "cp __tmp_reg__, %[t]\n\t" "breq 3f\n\t"
        "1:\n\t"
        "ldi %[n], 8\n\t"
        "mov %A[w], %B[w]\n\t" "mov %B[w], %C[w]\n\t" "mov %C[w], %D[w]\n\t" "ldd %D[w], Z+6\n\t"
        "mov %[t], %D[w]\n\t" "lsl %[t]\n\t" "sbc %[t], %[t]\n\t"
        "ldd __tmp_reg__, Z+7\n\t" "cp __tmp_reg__, %[t]\n\t" "breq 3f\n\t"
        "ldi %A[w], 0xFF\n\t" "ldi %B[w], 0xFF\n\t" "ldi %C[w], 0xFF\n\t" "ldi %D[w], 0x7F\n\t"
        "sbrs __tmp_reg__, 7\n\t" "rjmp 3f\n\t"
        "ldi %A[w], 0x01\n\t" "ldi %B[w], 0x00\n\t" "ldi %C[w], 0x00\n\t" "ldi %D[w], 0x80\n\t"
        "3:\n\t"
        : [w] "=&d"(w), [n] "=&d"(nb), [t] "=&r"(t)
        : "z"(px)
        : "r0");
#else
    const int32_t hi = x.hi;
    if (hi >= -32768L && hi < 32768L) {
        w = static_cast<int32_t>((static_cast<uint32_t>(hi) << 16) | (x.lo >> 16));
        nb = 16;
    } else {
        w = hi > 8388607L ? 0x7FFFFFFFL : (hi < -8388608L ? -0x7FFFFFFFL
            : static_cast<int32_t>((static_cast<uint32_t>(hi) << 8) | (x.lo >> 24)));
        nb = 8;
    }
#endif
    *n = nb;
    return w;
}

float q32_to_float(const Q32& x) {
    // the window, one conversion, the window's 2^-16 or 2^-8 by the exponent
    uint8_t n;
    const int32_t w = q32_window(x, &n);
    float f = static_cast<float>(w);
    if (w != 0) {                                   // exponent - n: (n / 2) off the top byte
        uint8_t by[4];
        memcpy(by, &f, 4);
        by[3] = static_cast<uint8_t>(by[3] - (n >> 1));
        memcpy(&f, by, 4);
    }
    return f;
}

// ------------------------------------------------------------------- the pulses' sinusoids

// floor(y E / 2^(8 eb)) for 0 <= E < 2^31, eb = 3..7, |result| < 2^31: the signed product y eps
// of a sinusoid's recurrence (eps = E 2^(-8 eb), docs/THEORY.md). On the AVR a loop over y's four
// bytes: byte times E (four MULs) added into a 5-byte accumulator, which then moves a byte down
// (the product's bytes 0..2 only carry; byte 3 is kept); y's two's complement corrected (minus
// E 2^32 when y < 0); then eb - 3 byte moves down with the sign.
static inline int32_t mul_eps(const int32_t* py, int32_t E, uint8_t eb) {
#if defined(__AVR__)
    // (y's bytes read from memory one per pass through the X pointer: y needs no registers)
    uint32_t acc;
    uint8_t a4, d, z, c, yb;
    const uint8_t* px = reinterpret_cast<const uint8_t*>(py);
    asm volatile(
        "adiw r26, 3\n\t" "ld %[yb], X\n\t" "sbiw r26, 3\n\t" "bst %[yb], 7\n\t"
        "clr %[z]\n\t" "clr %A[acc]\n\t" "clr %B[acc]\n\t" "clr %C[acc]\n\t" "clr %D[acc]\n\t"
        "clr %[a4]\n\t" "ldi %[c], 4\n\t"
        "1:\n\t"
        "ld %[yb], X+\n\t"
        "mul %[yb], %A[e]\n\t" "add %A[acc], r0\n\t" "adc %B[acc], r1\n\t" "adc %C[acc], %[z]\n\t"
        "adc %D[acc], %[z]\n\t" "adc %[a4], %[z]\n\t"
        "mul %[yb], %B[e]\n\t" "add %B[acc], r0\n\t" "adc %C[acc], r1\n\t" "adc %D[acc], %[z]\n\t"
        "adc %[a4], %[z]\n\t"
        "mul %[yb], %C[e]\n\t" "add %C[acc], r0\n\t" "adc %D[acc], r1\n\t" "adc %[a4], %[z]\n\t"
        "mul %[yb], %D[e]\n\t" "add %D[acc], r0\n\t" "adc %[a4], r1\n\t"
        "mov %[d], %A[acc]\n\t" "mov %A[acc], %B[acc]\n\t" "mov %B[acc], %C[acc]\n\t"
        "mov %C[acc], %D[acc]\n\t" "mov %D[acc], %[a4]\n\t" "clr %[a4]\n\t"
        "dec %[c]\n\t" "brne 1b\n\t"
        "clr r1\n\t"
        "brtc 2f\n\t"
        "sub %A[acc], %A[e]\n\t" "sbc %B[acc], %B[e]\n\t" "sbc %C[acc], %C[e]\n\t" "sbc %D[acc], %D[e]\n\t"
        "2:\n\t"
        "mov %[z], %D[acc]\n\t" "lsl %[z]\n\t" "sbc %[z], %[z]\n\t"
        "subi %[s], 3\n\t" "breq 4f\n\t"
        "3:\n\t"
        "mov %[d], %A[acc]\n\t" "mov %A[acc], %B[acc]\n\t" "mov %B[acc], %C[acc]\n\t"
        "mov %C[acc], %D[acc]\n\t" "mov %D[acc], %[z]\n\t"
        "dec %[s]\n\t" "brne 3b\n\t"
        "4:\n\t"
        : [acc] "=&r"(acc), [a4] "=&r"(a4), [d] "=&r"(d), [z] "=&r"(z), [c] "=&d"(c),
          [yb] "=&r"(yb), "+x"(px), [s] "+d"(eb)
        : [e] "r"(E), "m"(*py)
        : "r0", "r1");
    return static_cast<int32_t>((acc << 8) | d);
#else
    const int32_t y = *py;
    return static_cast<int32_t>((static_cast<int64_t>(y) * E) >> (8 * eb));
#endif
}

// The biased exponent of a float (byte operations: no 32-bit shift).
static uint8_t exponent_of(float x) {
    uint8_t by[4];
    memcpy(by, &x, 4);
    return static_cast<uint8_t>((by[3] << 1) | (by[2] >> 7));
}

// The units of a sinusoid of amplitude <= amp: s with amp 2^(32 - s) < 2^28 (s = 0: 2^-32, the
// Q32.32's own; amp < 2^27 for s <= 31).
static uint8_t units_of(float amp) {
    const uint8_t e = exponent_of(amp);             // amp < 2^(e - 126)
    if (e <= 122) return 0;
    return e - 122 > 31 ? 31 : static_cast<uint8_t>(e - 122);
}

// 2^(32 - s) as a float (s = -24..31): the scale of a sinusoid's units.
static float scale_of(int8_t s) {
    const uint8_t v = static_cast<uint8_t>(127 + 32 - s);   // the biased exponent
    const uint8_t by[4] = {0, 0, static_cast<uint8_t>(v << 7), static_cast<uint8_t>(v >> 1)};
    float p;
    memcpy(&p, by, 4);
    return p;
}

// One sample of a sinusoid (yD = {y, D}, units 2^(s - 32)) of chunk c: *out += y, then the
// difference form's step D -= eps y; y += D (the step first, *out += y last: a tail call, y
// read by the product from memory, so that few registers live through the function).
static void __attribute__((noinline)) sin_out(Q32* out, int32_t* yD, uint8_t s,
                                              const PlanStepper::Coef& c) {
    const int32_t D = yD[1] - mul_eps(yD, c.E, c.eb);
    const int32_t y = yD[0];
    yD[1] = D;
    yD[0] = y + D;
    q32_add_units(out, y, s);                       // (a tail call)
}

// The smallest k with (float)k * Ts >= t0 (in the float arithmetic of the stepper).
static uint32_t __attribute__((noinline)) first_k(float t0, float Ts) {
    if (!(t0 > 0.0f)) return 0;
    // from above: t0 / Ts's truncation + 2 is past the answer (float k Ts is monotonic in k and
    // within a relative 2^-24 of k Ts, for t0 / Ts < 2^23), then down to it
    uint32_t k = static_cast<uint32_t>(t0 / Ts) + 2;
    while (k > 0 && static_cast<float>(k - 1) * Ts >= t0) --k;
    return k;
}

uint32_t PlanStepper::first_sample(uint8_t i) const { return first_k(t0_of(*p_, i), Ts_); }

uint32_t first_sample_at(float t, float Ts) { return first_k(t, Ts); }

// The first sample after the chunk of segment i that starts at k0 (none after the rest at the
// target).
uint32_t PlanStepper::chunk_end(uint8_t i, uint32_t k0) const {
    if (i + 1 >= p_->nseg) return 0xFFFFFFFFUL;
    const uint32_t ke = first_sample(static_cast<uint8_t>(i + 1));
    if (ke <= k0) return ke;
    const uint32_t len = ke - k0;
    // chunks of kChunk, the last two balanced: no short tail whose preparation would have to
    // run in a few ticks (each chunk of a longer segment has >= kChunk / 2 samples)
    if (len > 2u * kChunk) return k0 + kChunk;
    if (len > kChunk) return k0 + len / 2;
    return ke;
}

// Stage 0 of a chunk's coefficients: its first sample k0 and the next chunk's known.
void PlanStepper::begin_coef(uint8_t i, Coef* c, uint32_t k0, uint32_t k_end) const {
    c->seg = 0xFE;                              // in preparation
    c->k0 = k0;
    c->k_end = k_end;
    c->sine = pulse_at(*p_, i) ? 1 : 0;
    c->s_delta = static_cast<float>(k0) * Ts_ - t0_of(*p_, i);   // delta = k0 Ts - t0 (>= 0 but on the slow path)
}

// *r = to_q32(a b) (one call site per product: smaller code on the AVR).
static void __attribute__((noinline)) q32_of(Q32* r, float a, float b) { q32_set(r, a * b); }

// The coefficients of chunk c of segment i, one stage per call (prepare() runs them in the idle
// time after the control step). The state (x, v, a) at the chunk's first sample and the jerk j
// of the polynomial part give, on every segment, x = x(n Ts) as forward differences in Q32.32
// (sx x, sx Ts (v + ...), ...), the feedforward alpha a + beta v likewise and the float velocity
// polynomial. A polynomial segment: 1 the state (closed form), 2 and 3 the position's
// differences, 4 the feedforward's and the velocity. A half-sine pulse
// x = (x0 - B) + v0 u + q2 u^2 + B cos(w u) (j = 0 on the polynomial part, whose X3 and F2 are 0:
// their bytes hold the sinusoids): 1 cos, sin(w delta), 2 sin, cos(theta/2) (theta = w Ts), 3 B
// and the state, 4 to 6 the position's, the feedforward's and the velocity's sinusoids, 7 and 8
// the differences and the velocity. Each stage reads its
// scratch (Coef's unions) before it writes an output that shares its bytes.
bool PlanStepper::compute_stage(uint8_t i, Coef* c, uint8_t stage) const {
    const float Ts = Ts_, sx = sx_, sv = sv_;
    if (is_rest(*p_, i)) {                          // the rest at the target
        memset(&c->yv, 0, sizeof(float) * 6);     // yv .. v2
        memset(&c->X, 0, sizeof(Q32) * 7);       // X..F2
        q32_set(&c->X, sx * p_->target);
        c->sine = 0;
        c->seg = i;
        return true;
    }
    const Segment& g = p_->seg.at[i];
    const bool sine = is_pulse(g);
    const float w = g.w, j = sine ? 0.0f : g.jp;
    uint8_t st = stage;
    if (sine) {
        switch (stage) {
        case 1: {
            const float wd = w * c->s_delta;
            c->s_cw = jl_cosf(wd);
            c->s_sw = jl_sinf(wd);
            return false;
        }
        case 2: {
            const float h = 0.5f * (w * Ts);
            c->s_s2 = jl_sinf(h);
            c->s_c2 = jl_cosf(h);
            return false;
        }
        case 3: {
            const float jw = g.jp / w, a2 = g.a0 + jw, d = c->s_delta;
            const float B = jw / (w * w);
            c->s_B = B;
            c->s_x = (g.x0 - B) + d * (g.v0 + d * (0.5f * a2));   // the polynomial part at delta
            c->s_v = g.v0 + a2 * d;
            c->s_a = a2;                                          // 2 q2
            return false;
        }
        case 4: case 5: case 6: {
            // y(u) = P cos(w u) + Q sin(w u) at u = delta + n Ts: y(0) = P cw + Q sw and
            // D(0) = y(0) - y(-1) = 2 s2 (Q C - P S), S, C = sin, cos(w delta - theta/2), in units
            // 2^(s - 32) for the amplitude |P| + |Q|; eps = 4 s2^2 as E 2^(-8 eb), exactly.
            // 4 position (x sx, counts): P = sx B. 5 feedforward alpha a + beta v (ticks) with
            // a = -w^2 B cos, v = -w B sin: P = -alpha w^2 B, Q = -beta w B. 6 velocity (x sv).
            const float cw = c->s_cw, sw = c->s_sw, B = c->s_B, s2 = c->s_s2, c2 = c->s_c2;
            const float S = sw * c2 - cw * s2, C = cw * c2 + sw * s2;
            const float wB = w * B;
            float P = 0.0f, Q = -sv * wB;
            if (stage == 4) { P = sx * B; Q = 0.0f; }
            if (stage == 5) { P = -alpha_ * w * wB; Q = -beta_ * wB; }
            const uint8_t u = units_of(jl_fabsf(P) + jl_fabsf(Q));
            const float p = scale_of(u);               // (exact: a power of 2)
            P *= p;
            Q *= p;
            // truncated toward 0 (|y| < 2^28, |D| < 2^29)
            const int32_t y = static_cast<int32_t>(P * cw + Q * sw);
            const int32_t D = static_cast<int32_t>(2.0f * s2 * (Q * C - P * S));
            if (stage == 4) {
                c->xs = u; c->yx = y; c->Dx = D;
                // eps = E 2^(-8 eb): eb = ceil(t / 8) for eps = m 2^-t (t >= 21), at most 7
                // (eps < 2^-32 then keeps 24 - (t - 56) bits); E < 2^31 (E = eps 2^(8 eb))
                const float eps = 4.0f * s2 * s2;
                uint8_t eb = static_cast<uint8_t>((157 - exponent_of(eps)) >> 3);
                if (eb > 7) eb = 7;
                c->E = static_cast<int32_t>(eps * scale_of(static_cast<int8_t>(32 - 8 * eb)));
                c->eb = eb;
            } else if (stage == 5) {
                c->fs = u; c->yf = y; c->Df = D;
            } else {
                c->vs = u; c->yv = y; c->Dv = D;
            }
            return false;
        }
        default: break;
        }
        st = stage == 7 ? 2 : 4;                    // 7 -> 2 (X3 = 0), 8 -> 4 (F2 = 0)
    } else if (stage == 1) {
        Sample s;
        eval_poly(g, c->s_delta, &s);
        c->s_x = s.position;
        c->s_v = s.velocity;
        c->s_a = s.accel;
        return false;
    }
    const float sxTs = sx * Ts;
    if (st == 2) {
        // x = x0 + x1 n + x2 n^2 + x3 n^3 in Q32.32 (each rounded once), as forward differences
        Q32 x2;
        q32_of(&x2, 0.5f * sxTs * Ts, c->s_a);
        q32_of(&c->X, sx, c->s_x);
        q32_of(&c->X1, sxTs, c->s_v);
        q32_add(&c->X1, x2);                        // + x3 in stage 3
        c->X2 = x2;
        q32_add(&c->X2, x2);                        // + 6 x3 in stage 3
        return false;
    }
    if (st == 3) {
        Q32 x3;
        q32_of(&x3, sxTs * Ts * Ts * (1.0f / 6.0f), j);
        q32_add(&c->X1, x3);
        c->X3 = x3;
        q32_add(&c->X3, x3);
        q32_add(&c->X3, x3);                        // 3 x3
        q32_add(&c->X3, c->X3);                     // 6 x3
        q32_add(&c->X2, c->X3);
        return false;
    }
    // the last stage: u_F = f0 + f1 n + f2 n^2 (f2 = 0 on a pulse, where F2's bytes hold a
    // sinusoid) and the float part (its scratch a, v read first)
    const float a = c->s_a, v = c->s_v, hjT2 = 0.5f * j * Ts * Ts;
    Q32 f2;
    q32_of(&f2, beta_, hjT2);
    q32_set(&c->F, alpha_ * a + beta_ * v);
    q32_of(&c->F1, alpha_ * j + beta_ * a, Ts);
    q32_add(&c->F1, f2);
    if (!sine) {
        c->F2 = f2;
        q32_add(&c->F2, f2);
    }
    c->v0 = sv * v;
    c->v1 = sv * a * Ts;
    c->v2 = sv * hjT2;
    c->seg = i;
    return true;
}

uint8_t __attribute__((noinline)) PlanStepper::segment_at(uint8_t j, uint32_t k) const {
    while (j + 1 < p_->nseg && first_sample(static_cast<uint8_t>(j + 1)) <= k) ++j;
    return j;
}

// All the stages of segment i's chunk from sample k0 at once (start, switch_plan, slow path).
void PlanStepper::compute(uint8_t i, Coef* c, uint32_t k0) const {
    begin_coef(i, c, k0, chunk_end(i, k0));
    for (uint8_t st = 1; !compute_stage(i, c, st); ++st) {}
}

void PlanStepper::start(const Plan& p, float Ts, float alpha, float beta, float sx, float sv) {
    p_ = &p;
    pend_p_ = nullptr;
    Ts_ = Ts;
    alpha_ = alpha;
    beta_ = beta;
    sx_ = sx;
    sv_ = sv;
    k_ = 0;
    misses_ = 0;
    seg_ = segment_at(0, 0);
    ci_ = 0;
    compute(seg_, &buf_[0], first_sample(seg_));
    reset_next();
    prepare();
}

void PlanStepper::switch_plan(const Plan& p) {
    p_ = &p;
    seg_ = segment_at(0, k_);
    compute(seg_, &buf_[ci_], k_);
    reset_next();
}

// One stage of the next chunk's coefficients; true when they are ready (or not needed).
bool PlanStepper::prepare_stage() {
    if (buf_[ci_].k_end == 0xFFFFFFFFUL) return true;   // the rest at the target: nothing follows
    Coef* nx = &buf_[ci_ ^ 1];
    if (nx->seg < 0xFD) return true;                // ready
    if (nx->seg == 0xFF) {
        // The segment that holds the next chunk's first sample kj (skip those without a
        // sample); one first_k per call.
        const uint8_t j = prep_seg_;
        const uint32_t kj = buf_[ci_].k_end;
        const uint32_t ke = j + 1 < p_->nseg ? first_sample(static_cast<uint8_t>(j + 1)) : 0xFFFFFFFFUL;
        if (ke <= kj) { ++prep_seg_; return false; }   // segment j ends before kj: the next one
        nx->k0 = kj;
        nx->k_end = chunk_end(j, kj);
        nx->seg = 0xFD;                             // both ends known
        return false;
    }
    if (nx->seg == 0xFD) {
        begin_coef(prep_seg_, nx, nx->k0, nx->k_end);
        prep_stage_ = 1;
        return false;
    }
    if (compute_stage(prep_seg_, nx, prep_stage_)) { prep_stage_ = 0; return true; }
    ++prep_stage_;
    return false;
}

// One stage per call while the current chunk has as many samples left as stages to go;
// otherwise the stages left spread evenly over its last samples (short segments, long Ts), so
// the change of chunk never finds the next one unprepared.
void PlanStepper::prepare() {
    if (prepare_stage()) return;
    // stages to go (over-estimated before stage 1: prep_stage_ is 0 until then)
    const uint8_t left = static_cast<uint8_t>((pulse_at(*p_, prep_seg_) ? 12 : 8) - prep_stage_);
    const uint32_t ticks = buf_[ci_].k_end - k_;    // calls before the change
    if (ticks > left) return;
    const uint8_t t = static_cast<uint8_t>(ticks);
    for (uint8_t n = t ? static_cast<uint8_t>((left + t - 1) / t) : left; n > 1; --n)
        if (prepare_stage()) return;
}

bool PlanStepper::pressed() const {
    // (the rest at the target, k_end 0xFFFFFFFF, is never pressed: nothing follows it; a next
    // chunk already prepared makes prepare() return at once)
    return buf_[ci_].k_end - k_ <= 14u;
}

bool PlanStepper::prepare_switch(const Plan& p) {
    if (pend_p_ != &p) {
        pend_p_ = &p;
        pend_stage_ = 0;
        pend_.seg = 0xFF;
    }
    if (pend_.seg < 0xFD) return true;
    // the first segment of p (its first sample at or after p.t_start); p_ swapped for the call
    const Plan* keep = p_;
    p_ = &p;
    const uint8_t j = segment_at(0, first_sample(0));
    bool done = false;
    if (pend_stage_ == 0) {
        const uint32_t k0 = first_sample(j);
        begin_coef(j, &pend_, k0, chunk_end(j, k0));
    } else {
        done = compute_stage(j, &pend_, pend_stage_);
    }
    p_ = keep;
    if (done) pend_stage_ = 0; else ++pend_stage_;
    return done;
}

void PlanStepper::advance_segment() {
    // Called when k_ reached the end of the current chunk: the prepared coefficients take over
    // (a buffer swap), or, unprepared, the chunk is computed here (slow path, counted).
    Coef* nx = &buf_[ci_ ^ 1];
    if (nx->seg < 0xFD && k_ >= nx->k0 && k_ < nx->k_end) {
        ci_ ^= 1;
        seg_ = nx->seg;
    } else {
        if (misses_ < 0xFFFF) ++misses_;
        seg_ = segment_at(seg_, k_);
        compute(seg_, &buf_[ci_], k_);
    }
    reset_next();
}

// The Q16.16 window of a Q32.32 (|value| < 2^15, saturated to +-(2^31 - 1)).
static int32_t q16_window(const Q32& f) {
    uint8_t n;
    const int32_t w = q32_window(f, &n);
    if (n == 16) return w;
    return f.hi < 0 ? -0x7FFFFFFFL : 0x7FFFFFFFL;
}

bool PlanStepper::next_q(Q32* position, int32_t* ff, float* velocity) {
    if (pend_p_ != nullptr && pend_.seg < 0xFD && k_ >= pend_.k0) {
        // re-targeting: the new plan takes over at its first sample
        p_ = pend_p_;
        pend_p_ = nullptr;
        buf_[ci_] = pend_;
        seg_ = pend_.seg;
        reset_next();
    }
    if (k_ >= buf_[ci_].k_end) advance_segment();
    Coef* const c = &buf_[ci_];
    *position = c->X;
    float vs = 0.0f;
    const bool sine = c->sine != 0;
    const Q32* fq = &c->F;                         // the feedforward (a pulse's: in f)
    Q32 f;
    if (sine) {
        // a half-sine pulse: the polynomial part (X3 = F2 = 0) plus the sinusoids, each
        // advanced by D -= eps y; y += D (one MUL product)
        if (velocity) {
            Q32 t = {0, 0};
            sin_out(&t, &c->yv, c->vs, *c);
            vs = q32_to_float(t);
        }
        sin_out(position, &c->yx, c->xs, *c);
        if (ff) {
            f = c->F;
            sin_out(&f, &c->yf, c->fs, *c);
            fq = &f;
        }
    }
    if (ff) *ff = q16_window(*fq);
    if (velocity) {                               // (the velocity loop only)
        const float n = static_cast<float>(k_ - c->k0);   // the chunk's sample n
        *velocity = c->v0 + n * (c->v1 + n * c->v2) + vs;
    }
    // the forward differences (a pulse's X3, F2 bytes hold its sinusoids: not added)
    if (ff) q32_diffs(&c->F, sine ? 1 : 2);
    q32_diffs(&c->X, sine ? 2 : 3);
    ++k_;
    return seg_ + 1 < p_->nseg;
}

bool PlanStepper::next_fast(float* position, float* velocity, float* ff) {
    Q32 x;
    int32_t f;
    const bool moving = next_q(&x, ff ? &f : nullptr, velocity);
    *position = q32_to_float(x);
    if (ff) {
        // f 2^-16: one conversion, the exponent lowered by 16 (8 off the top byte)
        float u = static_cast<float>(f);
        if (f != 0) {
            uint8_t by[4];
            memcpy(by, &u, 4);
            by[3] = static_cast<uint8_t>(by[3] - 8);
            memcpy(&u, by, 4);
        }
        *ff = u;
    }
    return moving;
}

bool PlanStepper::next(Sample* s) {
    const float t = static_cast<float>(k_) * Ts_;
    float x, v;
    const bool moving = next_fast(&x, &v, nullptr);
    Sample cf;
    sample(*p_, t, &cf);
    s->jerk = cf.jerk;
    s->accel = cf.accel;
    s->position = x;
    s->velocity = v;
    prepare();
    return moving;
}

}  // namespace jl
