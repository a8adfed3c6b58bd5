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
    memcpy(&limit_bits_, &limit, 4);
    kpk_ = kpd + kdd;
    kdg_ = kdd * (gamma - 1.0f);
    filtered_ = gamma != 0.0f;
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

float Pid::step_fast(float e, float ff, bool* saturated) {
    float i = i_ + kid_ * e;                        // eq. 17
    float pd;                                       // p + d
    if (!filtered_) {
        // gamma = 0: p + d = (kpd + kdd) e - kdd e(k-1), one addition fewer (d(k-1) unused)
        pd = kpk_ * e - kdd_ * e_prev_;
    } else {
        // p + d = (kpd + kdd) e + w, w = d - kdd e advanced by w = gamma w(k-1) + kdd (gamma - 1) e(k-1)
        const float w = gamma_ * w_ + kdg_ * e_prev_;
        w_ = w;
        pd = kpk_ * e + w;
    }
    e_prev_ = e;
    float u = ff + i + pd;                          // eq. 18 + feedforward (eq. 16)
    uint32_t ub;
    memcpy(&ub, &u, 4);
    // |u| > limit (or NaN): for floats the magnitude bits order like the values.
    const uint32_t mag = ub & 0x7FFFFFFFUL;
    if (mag > limit_bits_ && mag <= 0x7F800000UL) {
        *saturated = true;
        const bool neg = (ub & 0x80000000UL) != 0;
        uint32_t eb;
        memcpy(&eb, &e, 4);
        // e has the sign of u (and is not 0): freeze the integrator (conditional integration)
        if ((eb & 0x7FFFFFFFUL) != 0 && ((eb & 0x80000000UL) != 0) == neg) {
            u -= i - i_;
            i = i_;
        }
        if (u > limit_) u = limit_;
        else if (u < -limit_) u = -limit_;
    } else {
        *saturated = false;
    }
    i_ = i;
    return u;
}

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

int32_t __attribute__((noinline)) PidQ::step(int32_t e, int32_t ff, bool* saturated) {
    const int32_t kEmax = 0x40000000L;
    if (e > kEmax) e = kEmax;
    else if (e < -kEmax) e = -kEmax;
    const int32_t i0 = i_;
    const int32_t i = add_sat(i0, mul_q(e, kid_));          // eq. 17
    int32_t d = mul_q(e - e_prev_, kdd_);
    if (filtered_) {
        d = add_sat(d, mul_q(d_prev_, gamma_));              // derivative filter
        d_prev_ = d;
    }
    e_prev_ = e;
    const int32_t pd = add_sat(mul_q(e, kpd_), d);
    const int32_t fpd = add_sat(ff, pd);
    int32_t u = add_sat(fpd, i);                             // eq. 18 + feedforward (eq. 16)
    const int32_t lim = limit_;
    if (u > lim || u < -lim) {
        *saturated = true;
        if (e != 0 && (e > 0) == (u > 0)) {                  // freeze the integrator
            u = add_sat(fpd, i0);
            i_ = i0;
        } else {
            i_ = i;
        }
        if (u > lim) u = lim;
        else if (u < -lim) u = -lim;
    } else {
        *saturated = false;
        i_ = i;
    }
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
