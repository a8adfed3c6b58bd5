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
        const float d = kdd_ * (e - e_prev_) + gamma_ * d_prev_;
        d_prev_ = d;
        pd = kpd_ * e + d;
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

}  // namespace jl
