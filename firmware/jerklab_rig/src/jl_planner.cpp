#include "jl_planner.h"
#include "jl_port.h"
#include "jl_protocol.h"

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

// The smallest k with (float)k * Ts >= t0 (in the float arithmetic of the stepper).
static uint32_t first_k(float t0, float Ts) {
    if (!(t0 > 0.0f)) return 0;
    uint32_t k = static_cast<uint32_t>(t0 / Ts);
    while (k > 0 && static_cast<float>(k - 1) * Ts >= t0) --k;
    while (static_cast<float>(k) * Ts < t0) ++k;
    return k;
}

uint32_t PlanStepper::first_sample(uint8_t i) const { return first_k(p_->seg[i].t0, Ts_); }

// The coefficients of segment i in stages of at most ~5000 AVR cycles each (prepare() runs one
// stage per control tick, so even a 1 ms tick never runs long): 0 the first sample; on a sine
// pulse 1 cos and sin of w delta, 2 cos and sin of theta/2, 3 the polynomial parts, 4 the
// recurrence; on a polynomial segment 1 all coefficients.
bool PlanStepper::compute_stage(uint8_t i, Coef* c, uint8_t stage) const {
    const Segment& g = p_->seg[i];
    const float Ts = Ts_, sx = sx_, sv = sv_;
    if (stage == 0) {
        const uint32_t k0 = first_k(g.t0, Ts);
        c->seg = 0xFE;                              // in preparation
        c->k0 = k0;
        c->sine = g.sine;
        c->delta = static_cast<float>(k0) * Ts - g.t0;   // >= 0, < Ts
        return false;
    }
    if (g.sine && stage == 1) {
        c->h = jl_cosf(g.w * c->delta);
        c->q = jl_sinf(g.w * c->delta);
        return false;
    }
    if (g.sine && stage == 2) {
        const float th = g.w * Ts;
        c->s2 = jl_sinf(0.5f * th);
        c->ic2 = jl_cosf(0.5f * th);
        return false;
    }
    if (g.sine && stage == 3) {
        // the polynomial parts: x = (x0 - B) + v0 u + q2 u^2 + B cos(w u) (kept in x0..x2)
        const float w = g.w, jw = g.jp / w;
        const float B = jw / (w * w);
        const float q2 = 0.5f * (g.a0 + jw);
        const float delta = c->delta;
        const float vd = g.v0 + 2.0f * q2 * delta;
        c->x0 = sx * ((g.x0 - B) + delta * (g.v0 + delta * q2));
        c->x1 = sx * Ts * vd;
        c->x2 = sx * q2 * Ts * Ts;
        c->x3 = 0.0f;
        c->v0 = sv * vd;                           // v = v0 + 2 q2 u - w B sin(w u)
        c->v1 = sv * 2.0f * q2 * Ts;
        c->v2 = 0.0f;
        c->a0 = 2.0f * q2;                         // a = 2 q2 - w^2 B cos(w u)
        c->a1 = 0.0f;
        c->f0 = alpha_ * c->a0 + beta_ * vd;
        c->f1 = beta_ * 2.0f * q2 * Ts;
        c->f2 = 0.0f;
        c->j = 0.0f;
        c->w = B;                                  // (B until stage 4)
        return false;
    }
    const float delta = c->delta;
    if (g.sine) {
        const float w = g.w, B = c->w;
        // Minsky's recurrence h -= e q; q += e h with e = 2 sin(theta/2), theta = w Ts, keeps
        // h_n = sx B cos(w u_n) and q_n = sx B sin(w u_n + theta/2) exactly (2 fmul a step):
        // sx B sin(w u_n) = (q_n - s2 h_n) / c2, s2 = sin(theta/2), c2 = cos(theta/2).
        const float s2 = c->s2, c2 = c->ic2;
        const float cwd = c->h, swd = c->q;        // cos, sin of w delta (stage 0)
        const float isx = 1.0f / sx, ic2 = 1.0f / c2;
        c->eps = 2.0f * s2;
        c->w = w;
        c->ic2 = ic2;
        c->isx = isx;
        c->fh = isx * (-alpha_ * w * w + beta_ * w * s2 * ic2);
        c->fq = -isx * beta_ * w * ic2;
        c->vh = sv * isx * w * s2 * ic2;
        c->vq = -sv * isx * w * ic2;
        c->h = sx * B * cwd;
        c->q = sx * B * (swd * c2 + cwd * s2);     // sin(w delta + theta/2)
    } else {
        Sample s;
        eval_poly(g, delta, &s);
        const float j = g.jp;
        c->x0 = sx * s.position;
        c->x1 = sx * s.velocity * Ts;
        c->x2 = sx * 0.5f * s.accel * Ts * Ts;
        c->x3 = sx * j * Ts * Ts * Ts * (1.0f / 6.0f);
        c->v0 = sv * s.velocity;
        c->v1 = sv * s.accel * Ts;
        c->v2 = sv * 0.5f * j * Ts * Ts;
        c->a0 = s.accel;
        c->a1 = j * Ts;
        c->f0 = alpha_ * s.accel + beta_ * s.velocity;
        c->f1 = alpha_ * j * Ts + beta_ * s.accel * Ts;
        c->f2 = beta_ * 0.5f * j * Ts * Ts;
        c->j = j;
        c->h = c->q = c->eps = c->w = c->s2 = c->ic2 = c->isx = 0.0f;
        c->fh = c->fq = c->vh = c->vq = 0.0f;
    }
    if (i == p_->nseg - 1) {                        // the rest at the target
        c->x0 = sx * g.x0;
        c->x1 = c->x2 = c->x3 = c->v0 = c->v1 = c->v2 = c->a0 = c->a1 = 0.0f;
        c->f0 = c->f1 = c->f2 = c->j = 0.0f;
    }
    c->seg = i;
    return true;
}

void PlanStepper::compute(uint8_t i, Coef* c) const {
    for (uint8_t st = 0; !compute_stage(i, c, st); ++st) {}
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
    seg_ = 0;
    while (seg_ + 1 < p.nseg && first_sample(seg_ + 1) <= 0) ++seg_;
    compute(seg_, &cur_);
    n_ = k_ - cur_.k0;
    next_.seg = 0xFF;
    k_next_ = seg_ + 1 < p.nseg ? first_sample(seg_ + 1) : 0xFFFFFFFFUL;
    prepare();
}

void PlanStepper::switch_plan(const Plan& p) {
    p_ = &p;
    seg_ = 0;
    while (seg_ + 1 < p.nseg && first_sample(seg_ + 1) <= k_) ++seg_;
    compute(seg_, &cur_);
    n_ = k_ - cur_.k0;
    next_.seg = 0xFF;
    k_next_ = seg_ + 1 < p.nseg ? first_sample(seg_ + 1) : 0xFFFFFFFFUL;
}

void PlanStepper::prepare() {
    if (seg_ + 1 >= p_->nseg) return;
    // The segment that the next change of segment enters: skip those without a sample.
    uint8_t j = seg_ + 1;
    if (next_.seg < 0xFE && next_.seg >= j) return;     // ready
    if (next_.seg != 0xFE || prep_seg_ < j) {       // start afresh
        uint32_t kj = first_sample(j);
        while (j + 1 < p_->nseg && first_sample(j + 1) <= kj) { ++j; kj = first_sample(j); }
        if (next_.seg == j) return;
        prep_seg_ = j;
        prep_stage_ = 0;
    }
    if (compute_stage(prep_seg_, &next_, prep_stage_)) prep_stage_ = 0;
    else ++prep_stage_;
}

bool PlanStepper::prepare_switch(const Plan& p) {
    if (pend_p_ != &p) {
        pend_p_ = &p;
        pend_stage_ = 0;
        pend_.seg = 0xFF;
    }
    if (pend_.seg < 0xFE) return true;
    // the first segment of p (its first sample at or after p.t_start); p_ swapped for the call
    const Plan* keep = p_;
    p_ = &p;
    uint8_t j = 0;
    while (j + 1 < p.nseg && first_sample(j + 1) <= first_sample(0)) ++j;
    const bool done = compute_stage(j, &pend_, pend_stage_);
    p_ = keep;
    if (done) pend_stage_ = 0; else ++pend_stage_;
    return done;
}

void PlanStepper::advance_segment() {
    // Called when k_ reached next_.k0 (prepared) or, unprepared, found by search (slow path).
    if (next_.seg < 0xFE && next_.seg > seg_ && k_ >= next_.k0) {
        cur_ = next_;
        seg_ = cur_.seg;
    } else {
        while (seg_ + 1 < p_->nseg && first_sample(seg_ + 1) <= k_) ++seg_;
        compute(seg_, &cur_);
    }
    next_.seg = 0xFF;
    n_ = k_ - cur_.k0;
    k_next_ = seg_ + 1 < p_->nseg ? first_sample(seg_ + 1) : 0xFFFFFFFFUL;
}

bool PlanStepper::next_fast(float* position, float* velocity, float* ff) {
    if (pend_p_ != nullptr && pend_.seg < 0xFE && k_ >= pend_.k0) {
        // re-targeting: the new plan takes over at its first sample
        p_ = pend_p_;
        pend_p_ = nullptr;
        cur_ = pend_;
        seg_ = cur_.seg;
        n_ = k_ - cur_.k0;
        next_.seg = 0xFF;
        k_next_ = seg_ + 1 < p_->nseg ? first_sample(seg_ + 1) : 0xFFFFFFFFUL;
    }
    if (seg_ + 1 < p_->nseg) {
        if (k_ >= k_next_) advance_segment();
    }
    Coef& c = cur_;
    const float n = static_cast<float>(n_);
    if (c.sine) {
        const float h = c.h, q = c.q;
        *position = c.x0 + n * (c.x1 + n * c.x2) + h;
        if (velocity) *velocity = c.v0 + n * c.v1 + c.vh * h + c.vq * q;
        if (ff) *ff = c.f0 + n * c.f1 + c.fh * h + c.fq * q;
        const float h1 = h - c.eps * q;           // Minsky: advance by w Ts
        c.q = q + c.eps * h1;
        c.h = h1;
    } else {
        *position = c.x0 + n * (c.x1 + n * (c.x2 + n * c.x3));
        if (velocity) *velocity = c.v0 + n * (c.v1 + n * c.v2);
        if (ff) *ff = c.f0 + n * (c.f1 + n * c.f2);
    }
    ++n_;
    ++k_;
    return seg_ + 1 < p_->nseg;
}

bool PlanStepper::next(Sample* s) {
    if (seg_ + 1 < p_->nseg) {
        if (k_ >= k_next_) advance_segment();
    }
    const Coef& c = cur_;
    const bool moving = c.seg + 1 < p_->nseg;
    const float n = static_cast<float>(n_);
    if (c.sine) {
        const float w = c.w;
        s->jerk = w * w * w * (c.q - c.s2 * c.h) * c.ic2 * c.isx;
        s->accel = c.a0 - w * w * c.h * c.isx;
    } else {
        s->jerk = c.j;
        s->accel = c.a0 + n * c.a1;
    }
    float x, v;
    next_fast(&x, &v, nullptr);
    s->position = x;
    s->velocity = v;
    prepare();
    return moving;
}

}  // namespace jl
