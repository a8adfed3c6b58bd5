#include "jl_planner.h"
#include "jl_port.h"
#include "jl_protocol.h"
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

static void add_seg(Plan* p, float t, float x, float v, float a, float jp, bool sine, float w) {
    Segment& s = p->seg[p->nseg++];
    const float sg = p->sign;
    s.t0 = p->t_start + t;
    s.x0 = p->x_start + sg * x;
    s.v0 = sg * v;
    s.a0 = sg * a;
    s.jp = sg * jp;
    s.w = sine ? w : 0.0f;
    s.sine = sine ? 1 : 0;
}

// Lay out the segments of p from its times (tj1, ta1, tv, tj, ta), v_start and shape; positions
// of the first half are integrated forward from (0, v0, 0), those of the deceleration backward
// from the target (the mirror of an acceleration from rest), so the end is exactly the target.
static void build(Plan* p) {
    const uint8_t sh = p->shape;
    const bool sine = sh == kShapeSine;
    const float J = p->jerk, v0 = p->v_start, D = jl_fabsf(p->distance);
    p->nseg = 0;
    float apk1, v11, x11;
    pulse_ends(sh, J, p->tj1, &apk1, &v11, &x11);
    const float tacc1 = 2.0f * p->tj1 + p->ta1;
    const float w1 = p->tj1 > 0.0f ? kPi / p->tj1 : 0.0f;
    const float jl1 = sh == kShapeStep ? 0.0f : J;
    float t = 0.0f;
    if (tacc1 > 0.0f) {
        if (p->tj1 > 0.0f) add_seg(p, 0.0f, 0.0f, v0, 0.0f, jl1, sine, w1);
        float x = v0 * p->tj1 + x11, v = v0 + v11;
        t = p->tj1;
        if (p->ta1 > 0.0f) {
            add_seg(p, t, x, v, apk1, 0.0f, false, 0.0f);
            x += p->ta1 * (v + 0.5f * apk1 * p->ta1);
            v += apk1 * p->ta1;
            t += p->ta1;
        }
        if (p->tj1 > 0.0f) add_seg(p, t, x, v, apk1, -jl1, sine, w1);
        t = tacc1;
    }
    const float vp = p->v_peak;
    const float xc = 0.5f * (v0 + vp) * tacc1;         // symmetric pulse pair: mean velocity
    float apk, v1, x1;
    pulse_ends(sh, J, p->tj, &apk, &v1, &x1);
    const float tacc = 2.0f * p->tj + p->ta;
    const float xacc = 0.5f * vp * tacc;
    if (p->tv > 0.0f) add_seg(p, t, xc, vp, 0.0f, 0.0f, false, 0.0f);
    t += p->tv;
    if (tacc > 0.0f) {
        const float w = p->tj > 0.0f ? kPi / p->tj : 0.0f;
        const float jl = sh == kShapeStep ? 0.0f : J;
        if (p->tj > 0.0f) add_seg(p, t, D - xacc, vp, 0.0f, -jl, sine, w);
        if (p->ta > 0.0f) {
            // mirror of the rising pulse's end plus the plateau: tau = tj + ta
            const float xa = x1 + p->ta * (v1 + 0.5f * apk * p->ta);
            add_seg(p, t + p->tj, D - xa, vp - v1, -apk, 0.0f, false, 0.0f);
        }
        if (p->tj > 0.0f) add_seg(p, t + p->tj + p->ta, D - x1, v1, -apk, jl, sine, w);
        t += tacc;
    }
    p->duration = t;
    add_seg(p, t, D, 0.0f, 0.0f, 0.0f, false, 0.0f);
    p->seg[p->nseg - 1].x0 = p->x_start + p->distance;   // exactly the target
    p->accel_time = tacc1;
    p->cruise_time = p->tv;
    p->cruise_velocity = vp;
}

static void init(Plan* p, uint8_t kind, uint8_t shape, float distance, float jpar) {
    p->distance = distance;
    p->x_start = 0.0f;
    p->t_start = 0.0f;
    p->sign = distance < 0.0f ? -1.0f : 1.0f;
    p->kind = kind;
    p->shape = shape;
    p->jerk = jpar;
    p->v_start = 0.0f;
    p->tj1 = p->ta1 = p->tj = p->ta = p->tv = 0.0f;
    p->v_peak = 0.0f;
}

static void rest_to_rest(Plan* p, float tj, float ta, float tv) {
    p->tj1 = p->tj = tj;
    p->ta1 = p->ta = ta;
    p->tv = tv;
    float apk, v1, x1;
    pulse_ends(p->shape, p->jerk, tj, &apk, &v1, &x1);
    p->v_peak = apk * (tj + ta);
    build(p);
}

static PlanStatus check(float d, float J, float E, float W) {
    if (!finite_f(d)) return kPlanBadDistance;
    if (!finite_f(J) || !(J > 0.0f)) return kPlanBadJerk;
    if (!finite_f(E) || !(E > 0.0f)) return kPlanBadAccel;
    if (!finite_f(W) || !(W > 0.0f)) return kPlanBadVelocity;
    return kPlanOk;
}

PlanStatus plan_sine_jerk(float distance, float J, float E, float W, Plan* p) {
    PlanStatus st = check(distance, J, E, W);
    if (st != kPlanOk) return st;
    init(p, kPlannerSineJerk, kShapeSine, distance, J);
    const float theta = jl_fabsf(distance);
    if (theta == 0.0f) { rest_to_rest(p, 0.0f, 0.0f, 0.0f); return kPlanOk; }
    float T = jl_cbrtf(kTwoPi * theta / J);                   // x(T) = J T^3/(4 pi) = theta/2
    if (J * T / kPi > E) T = E * kPi / J;                       // eps_max = J T / pi
    if (J * T * T / kTwoPi > W) T = jl_sqrtf(kTwoPi * W / J);   // omega_max = J T^2/(2 pi)
    float wmax = J * T * T / kTwoPi;
    float wbar = wmax < W ? wmax : W;
    if (!(wbar > 0.0f)) return kPlanBadTime;
    float tv = (theta - wbar * T) / wbar;
    if (tv < 0.0f) tv = 0.0f;                                   // rounding leaves ~ -1e-7
    rest_to_rest(p, 0.5f * T, 0.0f, tv);
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
    *tj = jl_cbrtf(d * (0.5f / J));
}

PlanStatus plan_sine_jerk_optimal(float distance, float J, float E, float W, Plan* p) {
    PlanStatus st = check(distance, J, E, W);
    if (st != kPlanOk) return st;
    init(p, kPlannerSineJerkOptimal, kShapeSine, distance, J);
    float tj, ta, tv;
    scurve_times(jl_fabsf(distance), kTwoOverPi * J, E, W, &tj, &ta, &tv);
    rest_to_rest(p, tj, ta, tv);
    return kPlanOk;
}

PlanStatus plan_scurve(float distance, float J, float A, float V, Plan* p) {
    PlanStatus st = check(distance, J, A, V);
    if (st != kPlanOk) return st;
    init(p, kPlannerScurve, kShapeLinear, distance, J);
    float tj, ta, tv;
    scurve_times(jl_fabsf(distance), J, A, V, &tj, &ta, &tv);
    rest_to_rest(p, tj, ta, tv);
    return kPlanOk;
}

PlanStatus plan_trapezoid(float distance, float A, float V, Plan* p) {
    PlanStatus st = check(distance, 1.0f, A, V);
    if (st != kPlanOk) return st;
    init(p, kPlannerTrapezoid, kShapeStep, distance, A);
    const float d = jl_fabsf(distance);
    float ta = 0.0f, tv = 0.0f;
    if (d == 0.0f) {
    } else if (d * A >= V * V) {
        ta = V / A;
        tv = (d - V * ta) / V;
    } else {
        ta = jl_sqrtf(d / A);
    }
    rest_to_rest(p, 0.0f, ta, tv);
    return kPlanOk;
}

PlanStatus plan_kind(uint8_t kind, float d, float J, float A, float V, Plan* p) {
    switch (kind) {
    case kPlannerSineJerk: return plan_sine_jerk(d, J, A, V, p);
    case kPlannerSineJerkOptimal: return plan_sine_jerk_optimal(d, J, A, V, p);
    case kPlannerScurve: return plan_scurve(d, J, A, V, p);
    default: return plan_trapezoid(d, A, V, p);
    }
}

// Pulse pair changing the velocity by dv >= 0 with the pulse jerk Je (2J/pi for the sine
// family) and acceleration limit A: pulse time tj and plateau ta (the S-curve rule).
static void pair_times(uint8_t shape, float dv, float Je, float A, float* tj, float* ta) {
    if (!(dv > 0.0f)) { *tj = *ta = 0.0f; return; }
    if (shape == kShapeStep) { *tj = 0.0f; *ta = dv / A; return; }
    if (dv * Je >= A * A) { *tj = A / Je; *ta = dv / A - *tj; }
    else { *tj = jl_sqrtf(dv / Je); *ta = 0.0f; }
}

// Distance of the moving-start profile without cruise at peak velocity vp.
static float moving_dist(uint8_t shape, float v0, float vp, float Je, float A) {
    float tj1, ta1, tj2, ta2;
    pair_times(shape, vp - v0, Je, A, &tj1, &ta1);
    pair_times(shape, vp, Je, A, &tj2, &ta2);
    return 0.5f * (v0 + vp) * (2.0f * tj1 + ta1) + 0.5f * vp * (2.0f * tj2 + ta2);
}

static uint8_t shape_of(uint8_t kind) {
    return kind == kPlannerTrapezoid ? kShapeStep : (kind == kPlannerScurve ? kShapeLinear : kShapeSine);
}

PlanStatus MovingSolver::begin(uint8_t k, float distance, float v, float j, float a, float vmax,
                               uint8_t iterations) {
    PlanStatus st = check(distance, j, a, vmax);
    if (st != kPlanOk) return st;
    if (!finite_f(v) || v < 0.0f) return kPlanBadVelocity;
    kind = k;
    shape = shape_of(k);
    d = jl_fabsf(distance);
    v0 = v;
    J = j;
    A = a;
    V = vmax < v ? v : vmax;               // never asked to exceed the cruise it is in
    Je = shape == kShapeSine ? kTwoOverPi * J : J;
    const float dmax = moving_dist(shape, v0, V, Je, A);
    lo = hi = V;
    dlo = dmax;
    left = 0;
    if (dmax <= d) return kPlanOk;
    lo = v0;
    dlo = moving_dist(shape, v0, v0, Je, A);
    if (dlo > d * (1.0f + 1e-6f) + 1e-30f) return kPlanOvershoot;
    left = iterations;
    return kPlanOk;
}

bool MovingSolver::step(uint8_t n) {
    for (; n > 0 && left > 0; --n, --left) {
        const float mid = 0.5f * (lo + hi);
        const float dm = moving_dist(shape, v0, mid, Je, A);
        if (dm <= d) { lo = mid; dlo = dm; } else hi = mid;
    }
    return left == 0;
}

void MovingSolver::finish(float distance, float t_start, float x_start, Plan* p) {
    init(p, static_cast<uint8_t>(kind == kPlannerSineJerk ? kPlannerSineJerkOptimal : kind), shape,
         distance, shape == kShapeStep ? A : J);
    p->x_start = x_start;
    p->t_start = t_start;
    p->v_start = v0;
    const float vp = lo;
    p->v_peak = vp;
    p->tv = vp > 0.0f && d > dlo ? (d - dlo) / vp : 0.0f;
    pair_times(shape, vp - v0, Je, A, &p->tj1, &p->ta1);
    pair_times(shape, vp, Je, A, &p->tj, &p->ta);
    build(p);
}

PlanStatus plan_moving(uint8_t kind, float distance, float v0, float J, float A, float V,
                       float t_start, float x_start, Plan* p, uint8_t iterations) {
    MovingSolver s;
    PlanStatus st = s.begin(kind, distance, v0, J, A, V, iterations);
    if (st != kPlanOk) return st;
    s.step(iterations);
    s.finish(distance, t_start, x_start, p);
    return kPlanOk;
}

PlanStatus plan_stop(uint8_t kind, float v0, float sign, float J, float A, float t_start,
                     float x_start, Plan* p) {
    PlanStatus st = check(sign, J, A, 1.0f);
    if (st != kPlanOk) return st;
    const uint8_t shape = shape_of(kind);
    const float Je = shape == kShapeSine ? kTwoOverPi * J : J;
    float tj, ta;
    pair_times(shape, v0, Je, A, &tj, &ta);
    const float d = 0.5f * v0 * (2.0f * tj + ta);
    init(p, static_cast<uint8_t>(kind == kPlannerSineJerk ? kPlannerSineJerkOptimal : kind), shape,
         sign < 0.0f ? -d : d, shape == kShapeStep ? A : J);
    p->sign = sign < 0.0f ? -1.0f : 1.0f;
    p->x_start = x_start;
    p->t_start = t_start;
    p->v_start = v0;
    p->v_peak = v0;
    p->tj = tj;
    p->ta = ta;
    build(p);
    return kPlanOk;
}

void place(Plan* p, float t_start, float x_start) {
    p->t_start = t_start;
    p->x_start = x_start;
    for (uint8_t i = 0; i < p->nseg; ++i) {
        p->seg[i].t0 += t_start;
        p->seg[i].x0 += x_start;
    }
}

// The closed form on a segment of constant jerk at local time u >= 0.
static void eval_poly(const Segment& s, float u, Sample* o) {
    o->jerk = s.jp;
    o->accel = s.a0 + s.jp * u;
    o->velocity = s.v0 + u * (s.a0 + 0.5f * s.jp * u);
    o->position = s.x0 + u * (s.v0 + u * (0.5f * s.a0 + u * s.jp * (1.0f / 6.0f)));
}

float position_at_switch(const Plan& p, float t) {
    uint8_t i = p.nseg - 1;
    while (i > 0 && t < p.seg[i].t0) --i;
    const Segment& s = p.seg[i];
    if (i == p.nseg - 1) return s.x0;
    return s.x0 + (t - s.t0) * s.v0;      // a cruise (a = j = 0) or the start of a segment
}

// The closed form on segment s at local time u >= 0.
static void eval_seg(const Segment& s, float u, Sample* o) {
    if (s.sine) {
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

void sample(const Plan& p, float t, Sample* s) {
    if (t < p.seg[0].t0) {
        s->jerk = s->accel = s->velocity = 0.0f;
        s->position = p.x_start;
        return;
    }
    uint8_t i = p.nseg - 1;
    while (i > 0 && t < p.seg[i].t0) --i;
    eval_seg(p.seg[i], t - p.seg[i].t0, s);
    if (i == p.nseg - 1) s->jerk = s->accel = s->velocity = 0.0f;
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

// x 2^32 from the float's bits: the 24-bit mantissa placed at its bit position in the 64-bit
// image (a byte offset and at most 7 bit shifts; exact from 2^-8 up, truncated to 2^-32 below),
// then the sign. No 64-bit arithmetic.
Q32 to_q32(float x) {
    uint32_t b;
    memcpy(&b, &x, 4);
    const uint8_t e = static_cast<uint8_t>(b >> 23);        // biased exponent
    Q32 r = {0, 0};
    if (e == 0) return r;                                   // 0, subnormals
    if (e >= 127 + 31) {                                    // |x| >= 2^31, inf, NaN: saturated
        r.hi = 0x7FFFFFFFL;
    } else {
        uint32_t m = (b & 0x7FFFFFUL) | 0x800000UL;         // x 2^32 = m 2^(e - 118)
        if (e < 118) {
            const uint8_t sh = static_cast<uint8_t>(118 - e);
            r.lo = sh < 24 ? m >> sh : 0;
        } else {
            const uint8_t sh = static_cast<uint8_t>(e - 118);   // 0..39
            for (uint8_t k = sh & 7; k; --k) m <<= 1;             // < 2^31
            uint8_t img[8] = {0, 0, 0, 0, 0, 0, 0, 0};
            memcpy(img + (sh >> 3), &m, 4);                       // byte offset 0..4
            memcpy(&r.lo, img, 4);
            memcpy(&r.hi, img + 4, 4);
        }
    }
    if (b & 0x80000000UL) {                                 // two's complement negation
        r.hi = ~r.hi + (r.lo == 0 ? 1 : 0);
        r.lo = 0u - r.lo;
    }
    return r;
}

float q32_to_float(const Q32& x) {
    // the widest 32-bit window that holds the value: Q16.16 below 2^15, else Q24.8 (byte moves),
    // one conversion, the window's 2^-16 or 2^-8 by the exponent
    const int32_t hi = x.hi;
    int32_t w;
    uint32_t n;
    if (hi >= -32768L && hi < 32768L) {
        w = static_cast<int32_t>((static_cast<uint32_t>(hi) << 16) | (x.lo >> 16));
        n = 16UL << 23;
    } else {
        const int32_t h = hi > 8388607L ? 8388607L : (hi < -8388608L ? -8388608L : hi);
        w = static_cast<int32_t>((static_cast<uint32_t>(h) << 8) | (x.lo >> 24));
        n = 8UL << 23;
    }
    float f = static_cast<float>(w);
    uint32_t b;
    memcpy(&b, &f, 4);
    if (b & 0x7F800000UL) b -= n;
    memcpy(&f, &b, 4);
    return f;
}

// The smallest k with (float)k * Ts >= t0 (in the float arithmetic of the stepper).
static uint32_t first_k(float t0, float Ts) {
    if (!(t0 > 0.0f)) return 0;
    uint32_t k = static_cast<uint32_t>(t0 / Ts);
    while (k > 0 && static_cast<float>(k - 1) * Ts >= t0) --k;
    while (static_cast<float>(k) * Ts < t0) ++k;
    return k;
}

uint32_t PlanStepper::first_sample(uint8_t i) const { return first_k(p_->seg[i].t0, Ts_); }

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
    const Segment& g = p_->seg[i];
    c->seg = 0xFE;                              // in preparation
    c->k0 = k0;
    c->k_end = k_end;
    c->sine = g.sine;
    c->s_delta = static_cast<float>(k0) * Ts_ - g.t0;   // delta = k0 Ts - t0 (>= 0 but on the slow path)
}

// to_q32(a b) (one call site per product: smaller code on the AVR).
static Q32 __attribute__((noinline)) q32_of(float a, float b) { return to_q32(a * b); }

// The coefficients of chunk c of segment i, one stage per call (prepare() runs them in the idle
// time after the control step). The state (x, v, a) at the chunk's first sample and the jerk j
// of the polynomial part give, on every segment, x = x(n Ts) as forward differences in Q32.32
// (sx x, sx Ts (v + ...), ...), the feedforward alpha a + beta v likewise and the float velocity
// polynomial. A polynomial segment: 1 the state (closed form), 2 to 4 the differences, 5 the
// velocity. A half-sine pulse x = (x0 - B) + v0 u + q2 u^2 + B cos(w u) (j = 0 on the
// polynomial part): 1 cos(w delta), 2 sin(w delta), 3 sin(theta/2), 4 cos(theta/2) (theta = w
// Ts), 5 B and the state, 6 to 8 the differences, 9 Minsky's pair, 10 the velocity and the
// pair's terms. Each stage reads its scratch (Coef's union) before it writes an output that
// shares its bytes.
bool PlanStepper::compute_stage(uint8_t i, Coef* c, uint8_t stage) const {
    const Segment& g = p_->seg[i];
    const float Ts = Ts_, sx = sx_, sv = sv_;
    if (i == p_->nseg - 1) {                        // the rest at the target
        memset(&c->h, 0, sizeof(float) * 10);     // the float part
        memset(&c->X, 0, sizeof(Q32) * 7);       // X..F2
        c->X = to_q32(sx * g.x0);
        c->sine = 0;
        c->seg = i;
        return true;
    }
    const bool sine = g.sine != 0;
    const float w = g.w, j = sine ? 0.0f : g.jp;
    uint8_t st = stage;
    if (sine) {
        switch (stage) {
        case 1: c->s_cw = jl_cosf(w * c->s_delta); return false;
        case 2: c->s_sw = jl_sinf(w * c->s_delta); return false;
        case 3: c->s_s2 = jl_sinf(0.5f * (w * Ts)); return false;
        case 4: c->s_c2 = jl_cosf(0.5f * (w * Ts)); return false;
        case 5: {
            const float jw = g.jp / w, a2 = g.a0 + jw, d = c->s_delta;
            const float B = jw / (w * w);
            c->s_B = B;
            c->s_x = (g.x0 - B) + d * (g.v0 + d * (0.5f * a2));   // the polynomial part at delta
            c->s_v = g.v0 + a2 * d;
            c->s_a = a2;                                          // 2 q2
            return false;
        }
        case 9: {
            // Minsky's recurrence h -= e q; q += e h with e = 2 sin(theta/2) keeps
            // h_n = A cos(w u_n) and q_n = A sin(w u_n + theta/2) exactly (2 fmul a step), A = sx B:
            // sin(w u_n) = (q_n - s2 h_n) / c2, s2, c2 = sin, cos(theta/2).
            const float cw = c->s_cw, sw = c->s_sw, B = c->s_B, s2 = c->s_s2, c2 = c->s_c2;
            const float a = sx * B;
            c->h = a * cw;
            c->q = a * (sw * c2 + cw * s2);        // sin(w delta + theta/2)
            c->eps = 2.0f * s2;
            return false;
        }
        default: break;
        }
        st = stage >= 10 ? 5 : static_cast<uint8_t>(stage - 4);   // 6..8 -> 2..4, 10 -> 5
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
        const Q32 x2 = q32_of(0.5f * sxTs * Ts, c->s_a);
        c->X = q32_of(sx, c->s_x);
        c->X1 = q32_of(sxTs, c->s_v);
        q32_add(&c->X1, x2);                        // + x3 in stage 3
        c->X2 = x2;
        q32_add(&c->X2, x2);                        // + 6 x3 in stage 3
        return false;
    }
    if (st == 3) {
        const Q32 x3 = q32_of(sxTs * Ts * Ts * (1.0f / 6.0f), j);
        q32_add(&c->X1, x3);
        c->X3 = x3;
        q32_add(&c->X3, x3);
        q32_add(&c->X3, x3);                        // 3 x3
        q32_add(&c->X3, c->X3);                     // 6 x3
        q32_add(&c->X2, c->X3);
        return false;
    }
    const float a = c->s_a, v = c->s_v;
    if (st == 4) {
        // u_F = f0 + f1 n + f2 n^2
        const Q32 f2 = q32_of(beta_ * 0.5f * Ts * Ts, j);
        c->F = to_q32(alpha_ * a + beta_ * v);
        c->F1 = q32_of(alpha_ * j + beta_ * a, Ts);
        q32_add(&c->F1, f2);
        c->F2 = f2;
        q32_add(&c->F2, f2);
        return false;
    }
    // the last stage: the float part (scratch read above: a, v; below: s2, c2)
    float fh = 0.0f, fq = 0.0f, vh = 0.0f, vq = 0.0f;
    if (sine) {
        const float s2 = c->s_s2, c2 = c->s_c2;
        const float unit = 1.0f / sx;               // rad per unit of h
        // a = a2 - w^2 B cos, v = vd + a2 u - w B sin, w B sin = w (q - s2 h) / c2 per unit of h
        // and of q: with t = unit w / c2, v: (t s2, -t), a: -unit w^2 h
        const float t = unit * w / c2;
        vq = -sv * t;
        vh = -vq * s2;
        fq = -beta_ * t;
        fh = -fq * s2 - alpha_ * unit * w * w;
    } else {
        c->h = c->q = c->eps = 0.0f;
    }
    c->v0 = sv * v;
    c->v1 = sv * a * Ts;
    c->v2 = sv * 0.5f * j * Ts * Ts;
    c->fh = fh;
    c->fq = fq;
    c->vh = vh;
    c->vq = vq;
    c->seg = i;
    return true;
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
    n_ = 0;
    misses_ = 0;
    seg_ = 0;
    while (seg_ + 1 < p.nseg && first_sample(seg_ + 1) <= 0) ++seg_;
    ci_ = 0;
    compute(seg_, &buf_[0], first_sample(seg_));
    n_ = k_ - buf_[0].k0;
    reset_next();
    prepare();
}

void PlanStepper::switch_plan(const Plan& p) {
    p_ = &p;
    seg_ = 0;
    while (seg_ + 1 < p.nseg && first_sample(seg_ + 1) <= k_) ++seg_;
    compute(seg_, &buf_[ci_], k_);
    n_ = 0;
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
    const uint8_t left = static_cast<uint8_t>((p_->seg[prep_seg_].sine ? 14 : 9) - prep_stage_);
    const uint32_t ticks = buf_[ci_].k_end - k_;    // calls before the change
    if (ticks > left) return;
    const uint8_t t = static_cast<uint8_t>(ticks);
    for (uint8_t n = t ? static_cast<uint8_t>((left + t - 1) / t) : left; n > 1; --n)
        if (prepare_stage()) return;
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
    uint8_t j = 0;
    while (j + 1 < p.nseg && first_sample(j + 1) <= first_sample(0)) ++j;
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
        while (seg_ + 1 < p_->nseg && first_sample(seg_ + 1) <= k_) ++seg_;
        compute(seg_, &buf_[ci_], k_);
    }
    reset_next();
    n_ = k_ - buf_[ci_].k0;
}

bool PlanStepper::next_q(Q32* position, int32_t* ff, float* velocity) {
    if (pend_p_ != nullptr && pend_.seg < 0xFD && k_ >= pend_.k0) {
        // re-targeting: the new plan takes over at its first sample
        p_ = pend_p_;
        pend_p_ = nullptr;
        buf_[ci_] = pend_;
        seg_ = pend_.seg;
        n_ = k_ - pend_.k0;
        reset_next();
    }
    if (k_ >= buf_[ci_].k_end) advance_segment();
    Coef& c = buf_[ci_];
    const float h = c.h, q = c.q;                 // 0 off a sine pulse
    if (velocity) {                               // (the velocity loop only)
        const float n = static_cast<float>(n_);
        *velocity = c.v0 + n * (c.v1 + n * c.v2) + c.vh * h + c.vq * q;
    }
    Q32 x = c.X;
    int32_t fs = 0;
    if (c.sine) {
        q32_add(&x, to_q32(h));
        if (ff) fs = static_cast<int32_t>((c.fh * h + c.fq * q) * 65536.0f);   // |.| < 2^15
        const float h1 = h - c.eps * q;           // Minsky: advance by w Ts
        c.q = q + c.eps * h1;
        c.h = h1;
    }
    *position = x;
    q32_add(&c.X, c.X1);
    if (ff) {
        // the Q16.16 window (|ff| < 2^15 ticks, saturated)
        const int32_t fhi = c.F.hi;
        const int32_t fw = fhi >= 32768L ? 0x7FFFFFFFL : (fhi < -32768L ? -0x7FFFFFFFL
                           : static_cast<int32_t>((static_cast<uint32_t>(fhi) << 16) | (c.F.lo >> 16)));
        *ff = fw + fs;
        q32_add(&c.F, c.F1);
        q32_add(&c.F1, c.F2);
    }
    q32_add(&c.X1, c.X2);
    q32_add(&c.X2, c.X3);
    ++n_;
    ++k_;
    return seg_ + 1 < p_->nseg;
}

bool PlanStepper::next_fast(float* position, float* velocity, float* ff) {
    Q32 x;
    int32_t f;
    const bool moving = next_q(&x, ff ? &f : nullptr, velocity);
    *position = q32_to_float(x);
    if (ff) *ff = static_cast<float>(f) * (1.0f / 65536.0f);
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
