#include "jl_planner.h"
#include "jl_port.h"

namespace jl {

static void finish(float distance, float J, float T, float tv, SineJerkPlan* p) {
    p->distance = distance;
    p->sign = distance < 0.0f ? -1.0f : 1.0f;
    p->jerk = J;
    p->accel_time = T;
    p->cruise_time = tv;
    p->duration = 2.0f * T + tv;
    p->t1 = T + tv;
    if (T > 0.0f) {
        p->w = kTwoPi / T;
        p->inv_w = T / kTwoPi;
        p->inv_w2 = p->inv_w * p->inv_w;
        p->j_over_w = J * p->inv_w;
        p->cruise_velocity = J * T * T / kTwoPi;             // eq. 3: v(T) = J T^2 / (2 pi)
        p->x_t1 = 0.5f * p->cruise_velocity * T + p->cruise_velocity * tv;  // x(T) + wbar t_v
    } else {
        p->w = p->inv_w = p->inv_w2 = p->j_over_w = 0.0f;
        p->cruise_velocity = 0.0f;
        p->x_t1 = 0.0f;
    }
    p->s_jerk = p->sign * J;
    p->s_j_over_w = p->sign * p->j_over_w;
    p->s_cruise_velocity = p->sign * p->cruise_velocity;
    p->s_x_t1 = p->sign * p->x_t1;
}

PlanStatus plan_sine_jerk(float distance, float J, float E, float W, SineJerkPlan* p) {
    if (!finite_f(distance)) return kPlanBadDistance;
    if (!finite_f(J) || !(J > 0.0f)) return kPlanBadJerk;
    if (!finite_f(E) || !(E > 0.0f)) return kPlanBadAccel;
    if (!finite_f(W) || !(W > 0.0f)) return kPlanBadVelocity;
    const float theta = jl_fabsf(distance);
    if (theta == 0.0f) { finish(distance, J, 0.0f, 0.0f, p); return kPlanOk; }
    float T = jl_cbrtf(kTwoPi * theta / J);                   // x(T) = J T^3/(4 pi) = theta/2
    if (J * T / kPi > E) T = E * kPi / J;                       // eps_max = J T / pi
    if (J * T * T / kTwoPi > W) T = jl_sqrtf(kTwoPi * W / J);   // omega_max = J T^2/(2 pi)
    float wmax = J * T * T / kTwoPi;
    float wbar = wmax < W ? wmax : W;
    float tv = (theta - wbar * T) / wbar;
    if (tv < 0.0f) tv = 0.0f;                                   // rounding leaves ~ -1e-7
    finish(distance, J, T, tv, p);
    return kPlanOk;
}

PlanStatus plan_sine_jerk_phases(float distance, float T, float tv, SineJerkPlan* p) {
    if (!finite_f(distance)) return kPlanBadDistance;
    if (!finite_f(T) || !finite_f(tv) || tv < 0.0f || T < 0.0f) return kPlanBadTime;
    const float theta = jl_fabsf(distance);
    if (theta == 0.0f) { finish(distance, 0.0f, 0.0f, 0.0f, p); return kPlanOk; }
    if (!(T > 0.0f)) return kPlanBadTime;
    const float J = kTwoPi * theta / (T * T * (T + tv));
    if (!finite_f(J)) return kPlanBadJerk;
    finish(distance, J, T, tv, p);
    return kPlanOk;
}

// Evaluate the move at time t with c, s = cos, sin of w u, where u is the time into the
// current jerk pulse (acceleration: u = t; deceleration: u = t - t1).
static void eval(const SineJerkPlan& p, float t, float u, float c, float s, uint8_t phase,
                 Sample* out) {
    // Every term is proportional to J, so the signed constants give the signed move.
    if (phase == 0) {                      // before the start
        out->jerk = out->accel = out->velocity = out->position = 0.0f;
    } else if (phase == 1) {               // acceleration, eq. 3
        out->jerk = p.s_jerk * s;
        out->accel = p.s_j_over_w * (1.0f - c);
        out->velocity = p.s_j_over_w * (u - s * p.inv_w);
        out->position = p.s_j_over_w * (0.5f * u * u + (c - 1.0f) * p.inv_w2);
    } else if (phase == 2) {               // cruise
        out->jerk = out->accel = 0.0f;
        out->velocity = p.s_cruise_velocity;
        out->position = p.s_x_t1 - p.s_cruise_velocity * (p.t1 - t);
    } else if (phase == 3) {
        // Deceleration, the acceleration pulse mirrored about the end: with r = tu - t = T - u,
        // cos(w r) = cos(w u) and sin(w r) = -sin(w u) (w T = 2 pi), so
        // x = d - x_acc(r), v = v_acc(r), a = -a_acc(r), j = j_acc(r) -- exact at the target.
        const float r = p.duration - t;
        out->jerk = -p.s_jerk * s;
        out->accel = p.s_j_over_w * (c - 1.0f);
        out->velocity = p.s_j_over_w * (r + s * p.inv_w);
        out->position = p.distance - p.s_j_over_w * (0.5f * r * r + (c - 1.0f) * p.inv_w2);
    } else {                               // at rest at the target
        out->jerk = out->accel = out->velocity = 0.0f;
        out->position = p.distance;
    }
}

void sample(const SineJerkPlan& p, float t, Sample* s) {
    if (t < 0.0f) { eval(p, t, 0, 1, 0, 0, s); return; }
    if (t >= p.duration) { eval(p, t, 0, 1, 0, 4, s); return; }
    if (t < p.accel_time) {
        float wu = p.w * t;
        eval(p, t, t, jl_cosf(wu), jl_sinf(wu), 1, s);
    } else if (t < p.t1) {
        eval(p, t, 0, 1, 0, 2, s);
    } else {
        float u = t - p.t1;
        float wu = p.w * u;
        eval(p, t, u, jl_cosf(wu), jl_sinf(wu), 3, s);
    }
}

void PlanStepper::start(const SineJerkPlan& p, float Ts) {
    p_ = &p;
    Ts_ = Ts;
    k_ = 0;
    c_ = 1.0f;
    s_ = 0.0f;
    const float wts = p.w * Ts;
    cd_ = jl_cosf(wts);
    sd_ = jl_sinf(wts);
    // First sample of the deceleration pulse: the smallest k with k Ts >= t1 (in float,
    // exactly as next() compares), and the last sample before rest: k Ts < tu.
    uint32_t k1 = static_cast<uint32_t>(p.t1 / Ts);
    while (k1 > 0 && static_cast<float>(k1 - 1) * Ts >= p.t1) --k1;
    while (static_cast<float>(k1) * Ts < p.t1) ++k1;
    k1_ = k1;
    // First sample of the cruise (k Ts >= T), in the same float arithmetic as next().
    uint32_t ka = static_cast<uint32_t>(p.accel_time / Ts);
    while (ka > 0 && static_cast<float>(ka - 1) * Ts >= p.accel_time) --ka;
    while (static_cast<float>(ka) * Ts < p.accel_time) ++ka;
    k_accel_end_ = ka;
    const float u0 = static_cast<float>(k1) * Ts - p.t1;
    c1_ = jl_cosf(p.w * u0);
    s1_ = jl_sinf(p.w * u0);
    uint32_t ke = static_cast<uint32_t>(p.duration / Ts);
    while (static_cast<float>(ke) * Ts < p.duration) ++ke;
    k_end_ = ke;  // first k at rest
}

bool PlanStepper::next(Sample* out) {
    const SineJerkPlan& p = *p_;
    const float t = static_cast<float>(k_) * Ts_;
    bool moving = true;
    if (k_ >= k_end_ || t >= p.duration) {
        eval(p, t, 0, 1, 0, 4, out);
        moving = false;
    } else if (t < p.accel_time) {
        eval(p, t, t, c_, s_, 1, out);
    } else if (t < p.t1) {
        eval(p, t, 0, 1, 0, 2, out);
    } else {
        if (k_ == k1_) { c_ = c1_; s_ = s1_; }
        eval(p, t, t - p.t1, c_, s_, 3, out);
    }
    // Advance the rotator by w Ts (only inside a jerk pulse: the deceleration pulse starts
    // from the values precomputed for k1, so cruise and rest skip the 4 fmul).
    if (k_ + 1 < k_accel_end_ || (k_ + 1 > k1_ && k_ + 1 < k_end_)) {
        const float c = c_ * cd_ - s_ * sd_;
        s_ = s_ * cd_ + c_ * sd_;
        c_ = c;
    }
    if (k_ <= k_end_) ++k_;
    return moving;
}

}  // namespace jl
