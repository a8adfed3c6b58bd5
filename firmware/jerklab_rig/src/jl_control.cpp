#include "jl_control.h"
#include "jl_port.h"
#include <string.h>
#include <stddef.h>

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
#if defined(__AVR__)
    // the field offsets jl_pidq_step uses
    static_assert(offsetof(PidQ, kpd_) == 0 && offsetof(PidQ, kid_) == 5 && offsetof(PidQ, kdd_) == 10 &&
                  offsetof(PidQ, gamma_) == 15 && offsetof(PidQ, limit_) == 20 &&
                  offsetof(PidQ, filtered_) == 24 && offsetof(PidQ, i_) == 25 &&
                  offsetof(PidQ, e_prev_) == 29 && offsetof(PidQ, d_) == 33 && sizeof(QGain) == 5,
                  "jl_pidq_step's offsets");
#endif
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

#if defined(__AVR__)
// PidQ::step on the AVR, hand-written (the C version below, compiled by avr-gcc, spent ~230
// cycles and ~470 bytes on moving values between its calls): jl_pidq_step(self: r24:r25,
// e: r20..r23, ff: r16..r19, saturated: r14:r15) -> u in r22..r25, the avr-gcc calling
// convention (r2..r13, r28, r29 saved; r14..r17 only read). The object's fields by offset
// (static_asserts in PidQ::set): kpd 0, kid 5, kdd 10, gamma 15 (QGain: mant int32, shift),
// limit 20, filtered 24, i 25, e_prev 29, d 33. Registers: Y the object, e in r2..r5, the
// accumulator ACC in r6..r9; ff, then fpd = ff + p + d wait on the stack.
//
// jl_mac_core: ACC += floor(a * g) saturated, a in r18..r21, Z -> g; clobbers r0, r1 (left 0),
// r10..r13, r18..r27, r30, r31 (r13 its zero register). The mantissa m0..m2 in r22..r24, the
// shift in r25, the product p0..p6 in r10, r11, r12, r26, r27, r30, r31. Column k = i + j of
// a_i m_j (a0..a2 first): each 16-bit partial product is added at k with its carry into k + 2,
// which cannot carry further (the columns <= k sum to < 4 255^2 256^k 256/255 < 256^(k+3)).
// When a fits in 24 bits (a3 is a2's sign: the usual error) a3's three products are skipped;
// else they follow, carried through p6. The unsigned product of the two's complement patterns
// is corrected to the signed one mod 2^56: - m 2^32 if a < 0 (- m 2^24 for a 24-bit a), - a 2^24
// if m < 0. Then the product's sign byte z (r1) as byte 7, the bytes moved down by `shift` (its
// bits 1, 0, 2: two, one, four bytes, z shifted in), the window r10 r11 r12 r26 saturated unless
// the bytes above it (r27 r30 r31 z) are its sign. jl_add_acc: ACC += r18..r21, saturated on
// overflow (the sum's sign bit is then the opposite of the true sum's).
asm(".section .text.jl_pidq,\"ax\",@progbits\n"
    ".global jl_pidq_step\n"
    ".type jl_pidq_step, @function\n"
    "jl_pidq_step:\n"
    "push r2\n" "push r3\n" "push r4\n" "push r5\n" "push r6\n" "push r7\n" "push r8\n"
    "push r9\n" "push r10\n" "push r11\n" "push r12\n" "push r13\n" "push r28\n" "push r29\n"
    "push r16\n" "push r17\n" "push r18\n" "push r19\n"          // ff
    "movw r28, r24\n"
    // e clamped to [-2^30, 2^30 - 1] (bits 31 and 30 equal: e - e(k-1) cannot overflow)
    "mov r0, r23\n" "lsl r0\n" "eor r0, r23\n" "sbrs r0, 7\n" "rjmp 1f\n"
    "sbrc r23, 7\n" "rjmp 0f\n"
    "ldi r20, 0xFF\n" "ldi r21, 0xFF\n" "ldi r22, 0xFF\n" "ldi r23, 0x3F\n" "rjmp 1f\n"
    "0:\n"
    "clr r20\n" "clr r21\n" "clr r22\n" "ldi r23, 0xC0\n"
    "1:\n"
    "movw r2, r20\n" "movw r4, r22\n"
    "clr r6\n" "clr r7\n" "movw r8, r6\n"
    "ldd r0, Y+24\n" "tst r0\n" "breq 2f\n"
    "ldd r18, Y+33\n" "ldd r19, Y+34\n" "ldd r20, Y+35\n" "ldd r21, Y+36\n"
    "movw r30, r28\n" "adiw r30, 15\n" "rcall jl_mac_core\n"      // ACC = gamma d(k-1)
    "2:\n"
    "ldd r18, Y+29\n" "ldd r19, Y+30\n" "ldd r20, Y+31\n" "ldd r21, Y+32\n"
    "movw r22, r2\n" "movw r24, r4\n"
    "sub r22, r18\n" "sbc r23, r19\n" "sbc r24, r20\n" "sbc r25, r21\n"
    "movw r18, r22\n" "movw r20, r24\n"                          // e - e(k-1)
    "std Y+29, r2\n" "std Y+30, r3\n" "std Y+31, r4\n" "std Y+32, r5\n"
    "movw r30, r28\n" "adiw r30, 10\n" "rcall jl_mac_core\n"      // ACC = d
    "std Y+33, r6\n" "std Y+34, r7\n" "std Y+35, r8\n" "std Y+36, r9\n"
    "pop r21\n" "pop r20\n" "pop r19\n" "pop r18\n"
    "rcall jl_add_acc\n"                                          // ACC = ff + d
    "movw r18, r2\n" "movw r20, r4\n" "movw r30, r28\n" "rcall jl_mac_core\n"   // + kpd e
    "push r6\n" "push r7\n" "push r8\n" "push r9\n"              // fpd
    "ldd r6, Y+25\n" "ldd r7, Y+26\n" "ldd r8, Y+27\n" "ldd r9, Y+28\n"
    "movw r18, r2\n" "movw r20, r4\n" "movw r30, r28\n" "adiw r30, 5\n" "rcall jl_mac_core\n"
    "pop r21\n" "pop r20\n" "pop r19\n" "pop r18\n"              // fpd in r18..r21
    "movw r10, r6\n" "movw r12, r8\n"                            // i' = i + kid e
    "rcall jl_add_acc\n"                                          // u = fpd + i'
    "ldd r22, Y+20\n" "ldd r23, Y+21\n" "ldd r24, Y+22\n" "ldd r25, Y+23\n"      // limit
    "cp r22, r6\n" "cpc r23, r7\n" "cpc r24, r8\n" "cpc r25, r9\n" "brlt 5f\n"    // u > limit
    "movw r26, r6\n" "movw r30, r8\n"
    "add r26, r22\n" "adc r27, r23\n" "adc r30, r24\n" "adc r31, r25\n" "brlt 5f\n"   // u < -limit
    "clr r0\n" "rjmp 8f\n"
    "5:\n"                                                        // saturated
    "mov r0, r2\n" "or r0, r3\n" "or r0, r4\n" "or r0, r5\n" "breq 6f\n"
    "mov r0, r5\n" "eor r0, r9\n" "brmi 6f\n"
    "ldd r10, Y+25\n" "ldd r11, Y+26\n" "ldd r12, Y+27\n" "ldd r13, Y+28\n"      // i' = i
    "movw r6, r10\n" "movw r8, r12\n" "rcall jl_add_acc\n"        // u = fpd + i
    "6:\n"
    "cp r22, r6\n" "cpc r23, r7\n" "cpc r24, r8\n" "cpc r25, r9\n" "brge 7f\n"
    "movw r6, r22\n" "movw r8, r24\n" "rjmp 9f\n"                 // u = limit
    "7:\n"
    "movw r26, r6\n" "movw r30, r8\n"
    "add r26, r22\n" "adc r27, r23\n" "adc r30, r24\n" "adc r31, r25\n" "brge 9f\n"
    "clr r6\n" "clr r7\n" "movw r8, r6\n"
    "sub r6, r22\n" "sbc r7, r23\n" "sbc r8, r24\n" "sbc r9, r25\n"   // u = -limit
    "9:\n"
    "clr r0\n" "inc r0\n"
    "8:\n"
    "std Y+25, r10\n" "std Y+26, r11\n" "std Y+27, r12\n" "std Y+28, r13\n"
    "movw r30, r14\n" "st Z, r0\n"
    "movw r22, r6\n" "movw r24, r8\n"
    "pop r29\n" "pop r28\n" "pop r13\n" "pop r12\n" "pop r11\n" "pop r10\n" "pop r9\n"
    "pop r8\n" "pop r7\n" "pop r6\n" "pop r5\n" "pop r4\n" "pop r3\n" "pop r2\n"
    "ret\n"
    ".size jl_pidq_step, .-jl_pidq_step\n"
    "jl_mac_core:\n"
    "clr r13\n"
    "ld r22, Z\n" "ldd r23, Z+1\n" "ldd r24, Z+2\n" "ldd r25, Z+4\n"
    "mul r18, r22\n" "movw r10, r0\n"
    "clr r12\n" "clr r26\n" "clr r27\n" "clr r30\n" "clr r31\n"
    "mul r18, r23\n" "add r11, r0\n" "adc r12, r1\n" "adc r26, r13\n"
    "mul r19, r22\n" "add r11, r0\n" "adc r12, r1\n" "adc r26, r13\n"
    "mul r18, r24\n" "add r12, r0\n" "adc r26, r1\n" "adc r27, r13\n"
    "mul r19, r23\n" "add r12, r0\n" "adc r26, r1\n" "adc r27, r13\n"
    "mul r20, r22\n" "add r12, r0\n" "adc r26, r1\n" "adc r27, r13\n"
    "mul r19, r24\n" "add r26, r0\n" "adc r27, r1\n" "adc r30, r13\n"
    "mul r20, r23\n" "add r26, r0\n" "adc r27, r1\n" "adc r30, r13\n"
    "mul r20, r24\n" "add r27, r0\n" "adc r30, r1\n" "adc r31, r13\n"
    // a within 24 bits (a3 a2's sign, the usual error): a3's three products are 0 or, with
    // a < 0, together with the correction below, - m 2^24
    "mov r0, r20\n" "lsl r0\n" "sbc r0, r0\n" "cp r0, r21\n" "brne 7f\n"
    "sbrs r21, 7\n" "rjmp 1f\n"
    "sub r26, r22\n" "sbc r27, r23\n" "sbc r30, r24\n" "sbc r31, r13\n"
    "rjmp 1f\n"
    "7:\n"                                                       // a3's products, carried through
    "mul r21, r22\n" "add r26, r0\n" "adc r27, r1\n" "adc r30, r13\n" "adc r31, r13\n"
    "mul r21, r23\n" "add r27, r0\n" "adc r30, r1\n" "adc r31, r13\n"
    "mul r21, r24\n" "add r30, r0\n" "adc r31, r1\n"
    "sbrs r21, 7\n" "rjmp 1f\n"
    "sub r27, r22\n" "sbc r30, r23\n" "sbc r31, r24\n"
    "1:\n"
    "sbrs r24, 7\n" "rjmp 2f\n"
    "sub r26, r18\n" "sbc r27, r19\n" "sbc r30, r20\n" "sbc r31, r21\n"
    "2:\n"
    "mov r1, r31\n" "lsl r1\n" "sbc r1, r1\n"
    "sbrs r25, 1\n" "rjmp 3f\n"                                 // shift & 2: two bytes
    "mov r10, r12\n" "mov r11, r26\n" "mov r12, r27\n" "mov r26, r30\n" "mov r27, r31\n"
    "mov r30, r1\n" "mov r31, r1\n"
    "3:\n"
    "sbrs r25, 0\n" "rjmp 4f\n"                                 // shift & 1: one byte
    "mov r10, r11\n" "mov r11, r12\n" "mov r12, r26\n" "mov r26, r27\n" "mov r27, r30\n"
    "mov r30, r31\n" "mov r31, r1\n"
    "4:\n"
    "sbrs r25, 2\n" "rjmp 4f\n"                                 // shift & 4: four bytes
    "mov r10, r27\n" "mov r11, r30\n" "mov r12, r31\n" "mov r26, r1\n" "mov r27, r1\n"
    "mov r30, r1\n" "mov r31, r1\n"
    "4:\n"
    "mov r0, r26\n" "lsl r0\n" "sbc r0, r0\n"
    "cp r27, r0\n" "cpc r30, r0\n" "cpc r31, r0\n" "cpc r1, r0\n" "breq 5f\n"
    "mov r10, r1\n" "com r10\n" "mov r11, r10\n" "mov r12, r10\n" "mov r26, r10\n"
    "bst r1, 7\n" "bld r26, 7\n"
    "5:\n"
    "clr r1\n"
    "movw r18, r10\n" "mov r20, r12\n" "mov r21, r26\n"
    "jl_add_acc:\n"
    "add r6, r18\n" "adc r7, r19\n" "adc r8, r20\n" "adc r9, r21\n"
    "brvc 6f\n"
    "mov r6, r9\n" "lsl r6\n" "sbc r6, r6\n" "mov r7, r6\n" "mov r8, r6\n"
    "mov r30, r6\n" "subi r30, 0x80\n" "mov r9, r30\n"
    "6:\n"
    "ret\n"
    ".text\n");

// jl_mac(acc: r22..r25, a: r18..r21, g: r16:r17) -> r22..r25: jl_mac_core behind the C calling
// convention (the tests' entry; not linked into the firmware, which calls jl_pidq_step only).
asm(".section .text.jl_mac,\"ax\",@progbits\n"
    ".global jl_mac\n"
    ".type jl_mac, @function\n"
    "jl_mac:\n"
    "push r6\n" "push r7\n" "push r8\n" "push r9\n" "push r10\n" "push r11\n" "push r12\n"
    "push r13\n"
    "movw r6, r22\n" "movw r8, r24\n" "movw r30, r16\n"
    "call jl_mac_core\n"
    "movw r22, r6\n" "movw r24, r8\n"
    "pop r13\n"
    "pop r12\n" "pop r11\n" "pop r10\n" "pop r9\n" "pop r8\n" "pop r7\n" "pop r6\n"
    "ret\n"
    ".size jl_mac, .-jl_mac\n"
    ".text\n");
#else
// |u| > lim for 0 < lim < 2^31
static inline bool beyond(int32_t u, int32_t lim) { return u > lim || u < -lim; }

int32_t PidQ::step(int32_t e, int32_t ff, bool* saturated) {
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
    const bool sat = beyond(u, lim);
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
#endif

int16_t q16_to_pwm(int32_t u, int16_t top) {
    // |u| rounded (halves up), in ticks; |u| <= 2^31 - 1 (a saturated sum never is INT32_MIN + 0)
    const bool neg = u < 0;
    const uint32_t m = neg ? static_cast<uint32_t>(-(u + 1)) + 1u : static_cast<uint32_t>(u);
    const uint32_t r = (m + 0x8000UL) >> 16;
    const int16_t t = r > static_cast<uint32_t>(top) ? top : static_cast<int16_t>(r);
    return neg ? static_cast<int16_t>(-t) : t;
}

}  // namespace jl
