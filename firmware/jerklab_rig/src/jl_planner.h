// The rig's planners in float32: Stojčić's published sine-jerk (eqs. 2-4, Fig. 2), the
// time-optimal half-sine-jerk profile, the linear-jerk S-curve and the trapezoid, rest to rest,
// plus the moving start (v0 >= 0, a0 = 0, rest at the end) that re-targeting needs. They mirror
// jerklab.planner (plan_sine_jerk, plan_sine_jerk_optimal, plan_scurve, plan_trapezoid) and the
// closed form of its Profile (docs/THEORY.md; Stojčić eq. 15 is the recursion they replace).
//
// Every plan is a list of at most 7 segments on which the jerk is a constant (linear-jerk,
// plateau, cruise) or a half-sine pulse J sin(w u), w = pi / tj; each segment stores its start
// time and start state, so a sample needs no search through the past (see Plan).
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
    kPlanOvershoot = 6,     // moving start: cannot stop within the distance (see plan_moving)
};

struct Sample {
    float jerk, accel, velocity, position;
};

/// Shape of the jerk pulses (as jerklab.planner's _SINE, _LINEAR, _STEP).
enum PulseShape : uint8_t { kShapeSine = 0, kShapeLinear = 1, kShapeStep = 2 };

/// One piece of a plan: from time t0 the state (x0, v0, a0) evolves under the jerk jp
/// (kShapeLinear: constant jp; kShapeSine: jp sin(w (t - t0)); plateaus and cruise: jp = 0).
struct Segment {
    float t0, x0, v0, a0, jp, w;
    uint8_t sine;
};

/// A planned move. Rest-to-rest plans have v0 = 0 and equal halves (tj, ta); the moving start
/// has its own acceleration half (tj1, ta1, towards v_peak from v0, possibly tj1 = ta1 = 0).
struct Plan {
    float distance;       // signed, relative to the start point x_start
    float x_start;        // absolute start position (0 for PLAN; the switch point for RETARGET)
    float t_start;        // absolute start time (0 for PLAN)
    float sign;           // +1 or -1: direction of the move
    uint8_t kind;         // PlannerKind of jl_protocol.h
    uint8_t shape;        // PulseShape
    float jerk;           // jpar: peak jerk (sine), jerk (linear), acceleration (trapezoid)
    float v_start;        // |v0| along the move (0 rest to rest)
    float tj1, ta1;       // acceleration half: pulse and plateau times (towards v_peak)
    float tj, ta, tv;     // deceleration half (= acceleration half rest to rest) and cruise
    float v_peak;         // cruise velocity (>= 0, along the move)
    float duration;       // from t_start to rest at the target
    // PLAN_INFO fields: acceleration phase 2 tj1 + ta1 (the published planner: T) and t_v.
    float accel_time, cruise_time;
    float cruise_velocity;  // = v_peak (the published planner's omega_bar)
    uint8_t nseg;
    Segment seg[8];       // the last one is the rest at the target
};

/// Stojčić eq. 4 / Fig. 2 exactly as published: T = cbrt(2 pi |d| / J), shortened to
/// E pi / J if J T / pi > E, then to sqrt(2 pi Omega / J) if J T^2 / (2 pi) > Omega;
/// t_v = (|d| - wbar T) / wbar clamped at 0 (rounding). Peak jerk is always J.
/// distance == 0 gives an empty plan (duration 0).
PlanStatus plan_sine_jerk(float distance, float max_jerk, float max_accel, float max_velocity,
                          Plan* out);

/// The time-optimal half-sine-jerk profile: the phase times of the S-curve with jerk 2J/pi
/// (jerklab.planner.plan_sine_jerk_optimal).
PlanStatus plan_sine_jerk_optimal(float distance, float max_jerk, float max_accel,
                                  float max_velocity, Plan* out);

/// The time-optimal 7-segment linear-jerk S-curve (jerklab.planner.plan_scurve).
PlanStatus plan_scurve(float distance, float max_jerk, float max_accel, float max_velocity,
                       Plan* out);

/// Constant acceleration, cruise, constant deceleration (jerklab.planner.plan_trapezoid).
PlanStatus plan_trapezoid(float distance, float max_accel, float max_velocity, Plan* out);

/// Dispatch on the PLAN planner byte (kPlannerSineJerk .. kPlannerTrapezoid).
PlanStatus plan_kind(uint8_t kind, float distance, float max_jerk, float max_accel,
                     float max_velocity, Plan* out);

/// Moving start, rest at the end: from velocity v0 along the move (a0 = 0) over `distance`
/// (same sign as the velocity, or v0 = 0): a pulse pair from v0 to v_peak in [v0, max_velocity]
/// (no plateau when short), a cruise, and the rest-to-rest deceleration from v_peak; v_peak is
/// the largest whose distance fits (bisection, `iterations` halvings). kPlanOvershoot when even
/// v_peak = v0 needs more than `distance` to stop. kind picks the pulse shape: the sine family
/// (published and optimal) uses half-sine pulses of peak max_jerk (the optimal profile's
/// pulses), the S-curve linear jerk, the trapezoid steps. The plan starts at (t_start, x_start).
PlanStatus plan_moving(uint8_t kind, float distance, float v0, float max_jerk, float max_accel,
                       float max_velocity, float t_start, float x_start, Plan* out,
                       uint8_t iterations = 24);

/// Brake from |v0| (a0 = 0) to rest in the direction `sign` (+-1): the deceleration half of
/// kind's shape alone (re-targeting behind the stopping distance).
PlanStatus plan_stop(uint8_t kind, float v0, float sign, float max_jerk, float max_accel,
                     float t_start, float x_start, Plan* out);

/// Move a plan made at (t = 0, x = 0) to start at (t_start, x_start).
void place(Plan* p, float t_start, float x_start);

/// Bisection state of plan_moving, run a few steps at a time (re-targeting in a 1 ms loop).
struct MovingSolver {
    uint8_t kind, shape, left;
    float d, v0, J, A, V, Je, lo, hi, dlo;
    /// kPlanOk: ready for finish() (maybe after step()s); kPlanOvershoot; or a bad limit.
    PlanStatus begin(uint8_t kind, float distance, float v0, float J, float A, float V,
                     uint8_t iterations = 24);
    /// Up to n halvings; true when done.
    bool step(uint8_t n);
    void finish(float distance, float t_start, float x_start, Plan* out);
};

/// Position at a re-targeting switch time t: in a cruise (a = j = 0) or at a segment's start.
float position_at_switch(const Plan& p, float t);

/// Closed-form sample at absolute time t (rest at x_start before t_start, at the target after
/// the end).
void sample(const Plan& p, float t, Sample* s);

/// Samples at t = k Ts, k = 0, 1, 2, ... for the control loop, in a fixed number of float
/// operations: on each segment the position, velocity, acceleration and the feedforward
/// alpha a + beta v are polynomials in n = k - k0 (Horner) plus, on a sine pulse, terms of a
/// pair (h, q) advanced by Minsky's two-multiply recurrence (see compute()). The
/// coefficients of a segment are prepared before it starts (prepare(), outside the timed step).
class PlanStepper {
public:
    /// Start at k = 0. The fast samples come scaled: position x sx (e.g. counts per rad),
    /// velocity x sv, feedforward alpha a + beta v (e.g. alpha = tau/K in PWM ticks per V).
    /// next() (the full sample) needs sx = 1.
    void start(const Plan& p, float Ts, float alpha = 0.0f, float beta = 0.0f, float sx = 1.0f,
               float sv = 1.0f);
    /// Continue with the plan `p` (same Ts, same k) from its first sample on: p.t_start must be
    /// after the last sample taken (re-targeting).
    void switch_plan(const Plan& p);
    /// Re-targeting: prepare (one stage per call, like prepare()) the first segment of `p`,
    /// which takes over at its first sample; true once scheduled. next_fast() then switches.
    bool prepare_switch(const Plan& p);
    void cancel_switch() { pend_p_ = nullptr; }
    bool switch_scheduled() const { return pend_p_ != nullptr && pend_.seg < 0xFE; }
    const Plan* plan() const { return p_; }
    /// The control loop's sample at t = k Ts: position (and velocity, feedforward), then k++.
    /// Returns false once the move is over (rest at the target).
    bool next_fast(float* position, float* velocity, float* ff);
    /// The full sample (jerk, acceleration, velocity, position) at t = k Ts, then k++.
    bool next(Sample* s);
    /// Work ahead: one stage (of up to five, each <= ~5000 AVR cycles) of the coefficients of the
    /// next segment, if not ready yet (call after each step; nothing to do most of the time).
    void prepare();
    uint32_t index() const { return k_; }
    bool done() const { return seg_ + 1 >= p_->nseg; }
    /// Index of the current segment in the plan.
    uint8_t segment() const { return seg_; }
    /// First sample index of segment i of the current plan.
    uint32_t first_sample(uint8_t i) const;

    struct Coef {
        uint32_t k0;      // first sample of the segment
        uint8_t seg;      // segment index (0xFF: not prepared)
        uint8_t sine;
        float x0, x1, x2, x3;      // x = x0 + n (x1 + n (x2 + n x3)) [+ h]
        float v0, v1, v2;          // v = v0 + n (v1 + n v2) [- w h']
        float a0, a1;              // a = a0 + n a1 [- w^2 h]
        float f0, f1, f2;          // u_F = f0 + n (f1 + n f2) [+ fh h + fhp h']
        float j;                   // constant jerk
        // sine: (h, q) = sx B (cos w u, sin(w u + theta/2)) advanced by Minsky's recurrence
        float h, q, eps, w, s2, ic2, isx, fh, fq, vh, vq;
        float delta;               // k0 Ts - t0
    };

private:
    void compute(uint8_t i, Coef* c) const;
    bool compute_stage(uint8_t i, Coef* c, uint8_t stage) const;
    void advance_segment();
    const Plan* p_ = nullptr;
    float Ts_ = 0.005f, alpha_ = 0.0f, beta_ = 0.0f, sx_ = 1.0f, sv_ = 1.0f;
    uint32_t k_ = 0, n_ = 0, k_next_ = 0;   // k_next_: first sample of the next segment
    uint8_t seg_ = 0, prep_seg_ = 0, prep_stage_ = 0, pend_stage_ = 0;
    Coef cur_, next_, pend_;
    const Plan* pend_p_ = nullptr;
};

}  // namespace jl
#endif
