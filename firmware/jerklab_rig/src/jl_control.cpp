#include "jl_control.h"
#include "jl_port.h"
#include <string.h>

namespace jl {

bool Feedforward::set(float K, float tau) {
    if (!finite_f(K) || !(K > 0.0f) || !finite_f(tau) || tau < 0.0f) return false;
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
    if (!finite_f(limit) || !(limit > 0.0f) || !(limit < 32768.0f)) return false;
    if (!finite_f(gamma) || !(jl_fabsf(gamma) < 1.0f)) return false;
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

// |u| > lim for 0 < lim < 2^31: one add and an unsigned compare
static inline bool beyond(int32_t u, int32_t lim) {
    return static_cast<uint32_t>(u) + static_cast<uint32_t>(lim) > 2u * static_cast<uint32_t>(lim);
}

int32_t __attribute__((noinline, noclone)) PidQ::step(int32_t e, int32_t ff, bool* saturated) {
    const int32_t kEmax = 0x40000000L;                             // (e - e(k-1) cannot overflow)
    if (e > kEmax) e = kEmax;
    else if (e < -kEmax) e = -kEmax;
    int32_t d = filtered_ ? mac_g(0, d_, gamma_) : 0;              // derivative filter
    d = mac_g(d, e - e_prev_, kdd_);                               // eq. 17
    d_ = d;
    e_prev_ = e;
    const int32_t fpd = mac_g(add_sat(ff, d), e, kpd_);            // ff + p + d
    const int32_t i0 = i_;
    int32_t i = mac_g(i0, e, kid_);
    int32_t u = add_sat(fpd, i);                                   // eq. 18 + feedforward (eq. 16)
    const int32_t lim = limit_;
    const bool sat = beyond(u, lim);
    if (sat) {
        if (e != 0 && (e ^ u) >= 0) {                              // freeze the integrator
            u = add_sat(fpd, i0);
            i = i0;
        }
        if (beyond(u, lim)) u = u < 0 ? -lim : lim;
    }
    i_ = i;
    *saturated = sat;
    return u;
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
