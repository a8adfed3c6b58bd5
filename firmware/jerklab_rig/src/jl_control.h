// Feedforward and discrete PID of Stojčić (2015) eqs. 16-18, in float32, with the output
// clamp and integrator anti-windup the paper leaves out. Mirrors jerklab.controller
// (Feedforward, DigitalController).
#ifndef JL_CONTROL_H
#define JL_CONTROL_H
#include <stdint.h>
#include "jl_fixed.h"

namespace jl {

struct ControlParts {
    float p, i, d, ff, u;
    bool saturated;
};

/// u_F = (tau * accel + velocity) / K, Stojčić eq. 8 / 16 (the inverse of K/(tau s + 1)).
class Feedforward {
public:
    /// Returns false (and keeps the previous values) unless K > 0 and tau >= 0 are finite.
    bool set(float K, float tau);
    float operator()(float velocity, float accel) const { return tau_over_k_ * accel + inv_k_ * velocity; }
    float alpha() const { return tau_over_k_; }   // u_F = alpha a + beta v
    float beta() const { return inv_k_; }
    bool enabled = true;

private:
    float inv_k_ = 0.0f, tau_over_k_ = 0.0f;
};

/// Discrete PID, Stojčić eqs. 17-18 (the law of jerklab.controller.DigitalController):
/// p = kpd e, i' = i + kid e, d = gamma d(k-1) + kdd (e - e(k-1)) (gamma = 0: the paper's
/// backward derivative; |gamma| < 1 a derivative filter), u = u_F + p + i' + d. If |u| > limit
/// the sample is saturated, and when e has the sign of u (it pushes further into the clamp)
/// u -= i' - i and i' = i (conditional integration, the anti-windup the paper lacks); then u
/// is clamped to +-limit. Zero initial state: i = 0, e(-1) = 0, d(-1) = 0.
class Pid {
public:
    /// Returns false unless all gains are finite, |gamma| < 1 and limit > 0.
    bool set(float kpd, float kid, float kdd, float gamma, float limit);
    void reset() { i_ = 0.0f; e_prev_ = 0.0f; d_prev_ = 0.0f; w_ = 0.0f; }
    /// One sample: error e = reference - measurement, feedforward ff. Returns u.
    float step(float e, float ff, ControlParts* parts = nullptr);
    /// The same law for the control loop: only the saturation flag out, |u| > limit as an
    /// integer compare of the IEEE bits (no soft-float compare), p + d = (kpd + kdd) e + w with
    /// w = d - kdd e carried instead of d: without the derivative filter w = -kdd e(k-1), with it
    /// w(k) = gamma w(k-1) + kdd (gamma - 1) e(k-1) (from d(k) = gamma d(k-1) + kdd (e - e(k-1)));
    /// one float addition fewer either way, the same value up to float32 rounding.
    float step_fast(float e, float ff, bool* saturated);
    float limit() const { return limit_; }

private:
    float kpd_ = 0.0f, kid_ = 0.0f, kdd_ = 0.0f, gamma_ = 0.0f, limit_ = 12.0f;
    uint32_t limit_bits_ = 0x41400000UL;   // IEEE bits of limit_ (> 0)
    float kpk_ = 0.0f;                     // kpd + kdd (step_fast)
    float kdg_ = 0.0f;                     // kdd (gamma - 1) (step_fast, derivative filter)
    bool filtered_ = false;                // gamma != 0
    float i_ = 0.0f, e_prev_ = 0.0f, d_prev_ = 0.0f;
    float w_ = 0.0f;                       // step_fast: d - kdd e of the last sample
};

/// The same law in fixed point for the control loop (docs/THEORY.md "The fixed-point PID"):
/// the error e and the feedforward in Q16.16 (e.g. encoder counts and PWM ticks x 2^16), u in
/// Q16.16 of the feedforward's unit; gains as QGain (set() quantises them, see to_qgain); each
/// product floor(e g) by mul_q, the sums saturated at +-2^31 / 2^16. p = kpd e, i' = i + kid e,
/// d = kdd (e - e(k-1)) [+ gamma d(k-1)], u = ff + p + i' + d; |u| > limit: saturated, and
/// when e has the sign of u, u = ff + p + i + d and i' = i (conditional integration), then u
/// clamped to +-limit. |e| is clamped to 2^30 (so that e - e(k-1) cannot overflow).
class PidQ {
public:
    /// Returns false unless all gains are finite with |g| < 2^31, |gamma| < 1 and
    /// 0 < limit < 2^15 (the limit in the output's unit).
    bool set(float kpd, float kid, float kdd, float gamma, float limit);
    void reset() { i_ = 0; e_prev_ = 0; d_prev_ = 0; }
    /// One sample: e and ff in Q16.16; returns u in Q16.16 and the saturation flag.
    int32_t step(int32_t e, int32_t ff, bool* saturated);
    int32_t limit() const { return limit_; }

private:
    QGain kpd_ = {0, 0}, kid_ = {0, 0}, kdd_ = {0, 0}, gamma_ = {0, 0};
    int32_t limit_ = 12L << 16;
    bool filtered_ = false;
    int32_t i_ = 0, e_prev_ = 0, d_prev_ = 0;
};

/// u (Q16.16) to PWM ticks: round half away from 0, clamped to +-top.
int16_t q16_to_pwm(int32_t u, int16_t top);

}  // namespace jl
#endif
