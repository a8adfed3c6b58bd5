#include "jl_control.h"
#include "jl_port.h"
#include <string.h>
#include <stddef.h>

namespace jl {

bool Feedforward::set(float K, float tau) {
    if (!positive_le(K, 3.40282347e38f) || !nonneg_f(tau)) return false;   // K > 0, tau >= 0, finite
    inv_k_ = 1.0f / K;
    tau_over_k_ = tau / K;
    return true;
}

bool Pid::set(float kpd, float kid, float kdd, float gamma, float limit) {
    if (!finite_f(kpd) || !finite_f(kid) || !finite_f(kdd) || !finite_f(limit) || !(limit > 0.0f))
        return false;
    if (!finite_f(gamma) || !(jl_fabsf(gamma) < 1.0f)) return false;
    gamma_ = gamma;
    kpd_ = kpd;
    kid_ = kid;
    kdd_ = kdd;
    limit_ = limit;
    return true;
}

float Pid::step(float e, float ff, ControlParts* parts) {
    const float p = kpd_ * e;                       // eq. 17
    float i = i_ + kid_ * e;
    float d = kdd_ * (e - e_prev_);
    if (gamma_ != 0.0f) d += gamma_ * d_prev_;      // derivative filter (skipped for eq. 17)
    e_prev_ = e;
    d_prev_ = d;
    float u = ff + p + i + d;                       // eq. 18 + feedforward (eq. 16)
    bool sat = false;
    if (u > limit_) {
        sat = true;
        if (e > 0.0f) { u -= i - i_; i = i_; }        // freeze the integrator
        if (u > limit_) u = limit_;
    } else if (u < -limit_) {
        sat = true;
        if (e < 0.0f) { u -= i - i_; i = i_; }
        if (u < -limit_) u = -limit_;
    }
    i_ = i;
    if (parts) {
        parts->p = p;
        parts->i = i;
        parts->d = d;
        parts->ff = ff;
        parts->u = u;
        parts->saturated = sat;
    }
    return u;
}

}  // namespace jl

namespace jl {

bool PidQ::set(float kpd, float kid, float kdd, float gamma, float limit) {
#if JL_AVR_ASM
    // the field offsets jl_pidq_step uses
    static_assert(offsetof(PidQ, kpd_) == 0 && offsetof(PidQ, kid_) == 5 && offsetof(PidQ, kdd_) == 10 &&
                  offsetof(PidQ, gamma_) == 15 && offsetof(PidQ, limit_) == 20 &&
                  offsetof(PidQ, filtered_) == 24 && offsetof(PidQ, i_) == 25 &&
                  offsetof(PidQ, e_prev_) == 29 && offsetof(PidQ, d_) == 33 && sizeof(QGain) == 5,
                  "jl_pidq_step's offsets");
#endif
    // 0 < limit < 2^15 (32767.998046875: the largest float below 2^15), |gamma| < 1, finite
    if (!positive_le(limit, 32767.998046875f) || !abs_lt(gamma, 1.0f)) return false;
    QGain p, i, d, g;
    if (!to_qgain(kpd, &p) || !to_qgain(kid, &i) || !to_qgain(kdd, &d) || !to_qgain(gamma, &g))
        return false;
    kpd_ = p;
    kid_ = i;
    kdd_ = d;
    gamma_ = g;
    filtered_ = g.mant != 0;
    limit_ = to_q16(limit);
    return true;
}

int16_t q16_to_pwm(int32_t u, int16_t top) {
    // |u| rounded (halves up), in ticks; |u| <= 2^31 - 1 (a saturated sum never is INT32_MIN + 0)
    const bool neg = u < 0;
    const uint32_t m = neg ? static_cast<uint32_t>(-(u + 1)) + 1u : static_cast<uint32_t>(u);
    const uint32_t r = (m + 0x8000UL) >> 16;
    const int16_t t = r > static_cast<uint32_t>(top) ? top : static_cast<int16_t>(r);
    return neg ? static_cast<int16_t>(-t) : t;
}

}  // namespace jl
