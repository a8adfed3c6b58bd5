// Sine-jerk rest-to-rest planner, Stojčić (2015) eqs. 2-4 and Fig. 2, in float32.
// Mirrors jerklab.planner.plan_sine_jerk (the published algorithm) and the closed-form
// sampling of its Profile; see docs/THEORY.md (Stojčić eq. 15).
#ifndef JL_PLANNER_H
#define JL_PLANNER_H
#include <stdint.h>

namespace jl {

enum PlanStatus : uint8_t {
    kPlanOk = 0,
    kPlanBadDistance = 1,   // not finite
    kPlanBadJerk = 2,       // not finite or <= 0
    kPlanBadAccel = 3,
    kPlanBadVelocity = 4,
    kPlanBadTime = 5,       // phase time not finite, T <= 0 or t_v < 0
};

struct Sample {
    float jerk, accel, velocity, position;
};

/// A planned sine-jerk move. Jerk (eq. 2): J sin(wt) on [0,T], 0 on [T,t1],
/// -J sin(w(t-t1)) on [t1,tu], w = 2 pi / T, t1 = T + t_v, tu = 2T + t_v.
struct SineJerkPlan {
    float distance;      // signed
    float jerk;          // peak jerk J actually used (>= 0)
    float accel_time;    // T
    float cruise_time;   // t_v
    float duration;      // tu
    float cruise_velocity;  // omega_bar = J T^2 / (2 pi)
    // Derived constants (precomputed so that sampling needs no division).
    float sign, w, inv_w, inv_w2, j_over_w, t1, x_t1;
    // The same constants with the sign of the move folded in (saves 4 fmul per sample).
    float s_jerk, s_j_over_w, s_cruise_velocity, s_x_t1;
};

/// Stojčić eq. 4 / Fig. 2 exactly as published: T = cbrt(2 pi |d| / J), shortened to
/// E pi / J if J T / pi > E, then to sqrt(2 pi Omega / J) if J T^2 / (2 pi) > Omega;
/// t_v = (|d| - wbar T) / wbar clamped at 0 (rounding). Peak jerk is always J.
/// distance == 0 gives an empty plan (duration 0).
PlanStatus plan_sine_jerk(float distance, float max_jerk, float max_accel, float max_velocity,
                          SineJerkPlan* out);

/// The sine-jerk move with given phase times (e.g. a plan synchronised to Ts by the host):
/// the jerk is chosen so that the move covers `distance`: |d| = J T^2 (T + t_v) / (2 pi).
PlanStatus plan_sine_jerk_phases(float distance, float accel_time, float cruise_time,
                                 SineJerkPlan* out);

/// Closed-form sample at time t (rest at 0 before t = 0, at `distance` after the end).
void sample(const SineJerkPlan& p, float t, Sample* s);

/// Samples at t = k Ts, k = 0, 1, 2, ... for the control loop, without trigonometric
/// calls per step: cos/sin(w u) advance by a rotation by w Ts (4 fmul), re-anchored at
/// the start of each jerk pulse from values precomputed in start().
class PlanStepper {
public:
    void start(const SineJerkPlan& p, float Ts);
    /// Sample at t = k Ts, then advance k. Returns false once the move is over (the
    /// sample is then the rest at the target).
    bool next(Sample* s);
    uint32_t index() const { return k_; }
    bool done() const { return k_ > k_end_; }

private:
    const SineJerkPlan* p_ = nullptr;
    float Ts_ = 0.005f;
    uint32_t k_ = 0, k1_ = 0, k_end_ = 0, k_accel_end_ = 0;
    float c_ = 1.0f, s_ = 0.0f;        // cos, sin of w u at the current step
    float cd_ = 1.0f, sd_ = 0.0f;      // rotation by w Ts
    float c1_ = 1.0f, s1_ = 0.0f;      // cos, sin of w (k1 Ts - t1)
};

}  // namespace jl
#endif
