// THE CONTROL LAW: what the rig computes at every sample from the position error and the
// feedforward. This is the one place to change it (firmware/README.md "Change the control law").
//
// Stojčić (2015) eqs. 16-18, the law of jerklab.controller.DigitalController, in fixed point:
//   p  = kpd e                                  (proportional)
//   i' = i + kid e                              (integral)
//   d  = kdd (e - e(k-1)) + gamma d(k-1)        (derivative, gamma = 0: the paper's backward
//                                                difference; |gamma| < 1 a derivative filter)
//   u  = ff + p + d + i'                        (eq. 18 plus the feedforward u_F of eq. 16)
// and when |u| > limit the sample is saturated: if e has the sign of u (it pushes further into
// the clamp) the integrator keeps its old value, u = ff + p + d + i (conditional integration,
// the anti-windup the paper leaves out); then u is clamped to +-limit.
//
// Units: e and ff are Q16.16 (encoder counts and PWM ticks times 2^16: the value 1.0 is 65536),
// u is returned in Q16.16 PWM ticks (the device rounds it to the PWM register, q16_to_pwm).
// The gains kpd_, kid_, kdd_, gamma_ are in PWM ticks per count (per count and sample for the
// velocity loop, Stojčić §4B), set by PidQ::set from SET_GAINS (jl_control.cpp). The helpers:
//   mac_g(acc, x, g)  acc + x g, the product floored, both steps saturated at +-2^31
//   add_sat(a, b)     a + b saturated at +-2^31
// State that survives from sample to sample lives in PidQ (jl_control.h): i_, e_prev_, d_, all
// zero at RUN (PidQ::reset). *saturated tells the device this sample hit the clamp (TELEMETRY
// bit 0 and the saturation stop of PROTOCOL.md).
//
// This file is C++ on every build. The Uno runs it as it is, unless the firmware is built with
// make -C firmware EXTRA_DEFS=-DJL_ASM=1, which swaps in the hand-written assembly of the same
// law (jl_asm_pid.cpp). The golden vectors (tests/test_firmware.py) and the simulated ATmega328P
// (tests/test_firmware_fixed.py) check this law against the integer law in Python.
#ifndef JL_LAW_H
#define JL_LAW_H
#include "jl_control.h"

namespace jl {

#if !JL_AVR_ASM
// JL_LAW_BEGIN (tests/test_firmware_law.py replaces the lines from here to JL_LAW_END with
// firmware/README.md's example)
inline int32_t PidQ::step(int32_t e, int32_t ff, bool* saturated) {
    if (e > 0x3FFFFFFFL) e = 0x3FFFFFFFL;                          // (e - e(k-1) cannot overflow)
    else if (e < -0x40000000L) e = -0x40000000L;
    int32_t d = filtered_ ? mac_g(0, d_, gamma_) : 0;              // derivative filter
    d = mac_g(d, e - e_prev_, kdd_);                               // eq. 17
    d_ = d;
    e_prev_ = e;
    const int32_t fpd = mac_g(add_sat(ff, d), e, kpd_);            // ff + p + d
    const int32_t i0 = i_;
    int32_t i = mac_g(i0, e, kid_);
    int32_t u = add_sat(fpd, i);                                   // eq. 18 + feedforward (eq. 16)
    const int32_t lim = limit_;
    const bool sat = u > lim || u < -lim;
    if (sat) {
        if (e != 0 && (e ^ u) >= 0) {                              // freeze the integrator
            u = add_sat(fpd, i0);
            i = i0;
        }
        if (u > lim) u = lim;
        else if (u < -lim) u = -lim;
    }
    i_ = i;
    *saturated = sat;
    return u;
}
// JL_LAW_END
#endif

}  // namespace jl
#endif
