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

private:
    float inv_k_ JL_ZERO, tau_over_k_ JL_ZERO;
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
    void reset() { i_ = 0.0f; e_prev_ = 0.0f; d_prev_ = 0.0f; }
    /// One sample: error e = reference - measurement, feedforward ff. Returns u.
    float step(float e, float ff, ControlParts* parts = nullptr);
    float limit() const { return limit_; }

private:
    float kpd_ = 0.0f, kid_ = 0.0f, kdd_ = 0.0f, gamma_ = 0.0f, limit_ = 12.0f;
    float i_ = 0.0f, e_prev_ = 0.0f, d_prev_ = 0.0f;
};

class PidQ;
#if JL_AVR_ASM
extern "C" int32_t jl_pidq_step(PidQ* self, int32_t e, int32_t ff, bool* saturated);
#endif

/// The same law in fixed point: the control loop's PID (docs/THEORY.md "The fixed-point PID"),
/// its step() in jl_law.h (the one place to change the law the rig runs).
/// The error e and the feedforward in Q16.16 (encoder counts and PWM ticks x 2^16), u in Q16.16
/// of the feedforward's unit; the gains quantised by to_qgain (24-bit mantissas). p = kpd e,
/// i' = i + kid e, d = kdd (e - e(k-1)) [+ gamma d(k-1)], u = ff + p + d + i': three products a
/// sample without the derivative filter, four with it, each a multiply-accumulate mac_g
/// (product floored, saturated, then added saturated at +-2^31 / 2^16). |u| > limit: saturated,
/// and when e has the sign of u, u = ff + p + d + i and i' = i (conditional integration), then
/// u clamped to +-limit. e is clamped to [-2^30, 2^30 - 1] (e - e(k-1) cannot overflow). Zero
/// initial state. (p and d are two products, not one product of (kpd + kdd) e plus a remainder:
/// that form's two terms are each about kdd e, which leave the Q16.16 range long before their
/// difference does.)
class PidQ {
public:
    /// Returns false unless all gains are finite with |g| < 2^23, |gamma| < 1 and
    /// 0 < limit < 2^15 (the limit in the output's unit).
    bool set(float kpd, float kid, float kdd, float gamma, float limit);
    void reset() { i_ = 0; e_prev_ = 0; d_ = 0; }
    /// One sample: e and ff in Q16.16; returns u in Q16.16 and the saturation flag. The C++
    /// law of jl_law.h; built with JL_ASM=1 on the AVR, the assembly routine jl_pidq_step
    /// (jl_asm_pid.cpp).
#if JL_AVR_ASM
    int32_t step(int32_t e, int32_t ff, bool* saturated) { return jl_pidq_step(this, e, ff, saturated); }
#else
    inline int32_t step(int32_t e, int32_t ff, bool* saturated);
#endif
    int32_t limit() const { return limit_; }

private:
    QGain kpd_ JL_ZERO, kid_ JL_ZERO, kdd_ JL_ZERO, gamma_ JL_ZERO;
    int32_t limit_ = 12L << 16;
    bool filtered_ JL_ZERO;
    int32_t i_ JL_ZERO, e_prev_ JL_ZERO, d_ JL_ZERO;
};

/// u (Q16.16) to PWM ticks: round half away from 0, clamped to +-top.
int16_t q16_to_pwm(int32_t u, int16_t top);

}  // namespace jl
#include "jl_law.h"
#endif
