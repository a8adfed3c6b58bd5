// Optional assembly kernel of the control law (make -C firmware EXTRA_DEFS=-DJL_ASM=1, AVR
// only): PidQ::step as jl_pidq_step, and the multiply-accumulate mac_g as jl_mac. The default
// build does not use this file: it runs the C++ law of jl_law.h. The C++ this replaces:
//
//   // mac_g (jl_fixed.h): acc + floor(a * g.mant / 2^(8 g.shift)), both steps saturated
//   int32_t mac_g(int32_t acc, int32_t a, const QGain& g) { return add_sat(acc, mul_g(a, g)); }
//
//   int32_t PidQ::step(int32_t e, int32_t ff, bool* saturated) {    // jl_law.h
//       if (e > 0x3FFFFFFFL) e = 0x3FFFFFFFL;
//       else if (e < -0x40000000L) e = -0x40000000L;
//       int32_t d = filtered_ ? mac_g(0, d_, gamma_) : 0;
//       d = mac_g(d, e - e_prev_, kdd_);
//       d_ = d;
//       e_prev_ = e;
//       const int32_t fpd = mac_g(add_sat(ff, d), e, kpd_);
//       const int32_t i0 = i_;
//       int32_t i = mac_g(i0, e, kid_);
//       int32_t u = add_sat(fpd, i);
//       const int32_t lim = limit_;
//       const bool sat = u > lim || u < -lim;
//       if (sat) {
//           if (e != 0 && (e ^ u) >= 0) { u = add_sat(fpd, i0); i = i0; }
//           if (u > lim) u = lim;
//           else if (u < -lim) u = -lim;
//       }
//       i_ = i;
//       *saturated = sat;
//       return u;
//   }
//
// A law changed in jl_law.h is not this one: build without JL_ASM (the default) to run it.
// tests/test_firmware_fixed.py runs both builds of the law on the simulated ATmega328P against
// the integer law in Python.
#include "jl_control.h"

#if JL_AVR_ASM
// PidQ::step on the AVR, hand-written (the C++ above, compiled by avr-gcc 5.4 with its 64-bit
// library multiply, costs more cycles: firmware/README.md "Numbers"): jl_pidq_step(self: r24:r25,
// e: r20..r23, ff: r16..r19, saturated: r14:r15) -> u in r22..r25, the avr-gcc calling
// convention (r2..r13, r28, r29 saved; r14..r17 only read). The object's fields by offset
// (static_asserts in PidQ::set): kpd 0, kid 5, kdd 10, gamma 15 (QGain: mant int32, shift),
// limit 20, filtered 24, i 25, e_prev 29, d 33. Registers: Y the object, e in r2..r5, the
// accumulator ACC in r6..r9; ff, then fpd = ff + p + d wait on the stack.
//
// jl_mac_core and jl_add_acc: jl_asm_mac.cpp.
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
    "movw r30, r28\n" "adiw r30, 15\n" "call jl_mac_core\n"      // ACC = gamma d(k-1)
    "2:\n"
    "ldd r18, Y+29\n" "ldd r19, Y+30\n" "ldd r20, Y+31\n" "ldd r21, Y+32\n"
    "movw r22, r2\n" "movw r24, r4\n"
    "sub r22, r18\n" "sbc r23, r19\n" "sbc r24, r20\n" "sbc r25, r21\n"
    "movw r18, r22\n" "movw r20, r24\n"                          // e - e(k-1)
    "std Y+29, r2\n" "std Y+30, r3\n" "std Y+31, r4\n" "std Y+32, r5\n"
    "movw r30, r28\n" "adiw r30, 10\n" "call jl_mac_core\n"      // ACC = d
    "std Y+33, r6\n" "std Y+34, r7\n" "std Y+35, r8\n" "std Y+36, r9\n"
    "pop r21\n" "pop r20\n" "pop r19\n" "pop r18\n"
    "call jl_add_acc\n"                                          // ACC = ff + d
    "movw r18, r2\n" "movw r20, r4\n" "movw r30, r28\n" "call jl_mac_core\n"   // + kpd e
    "push r6\n" "push r7\n" "push r8\n" "push r9\n"              // fpd
    "ldd r6, Y+25\n" "ldd r7, Y+26\n" "ldd r8, Y+27\n" "ldd r9, Y+28\n"
    "movw r18, r2\n" "movw r20, r4\n" "movw r30, r28\n" "adiw r30, 5\n" "call jl_mac_core\n"
    "pop r21\n" "pop r20\n" "pop r19\n" "pop r18\n"              // fpd in r18..r21
    "movw r10, r6\n" "movw r12, r8\n"                            // i' = i + kid e
    "call jl_add_acc\n"                                          // u = fpd + i'
    "ldd r22, Y+20\n" "ldd r23, Y+21\n" "ldd r24, Y+22\n" "ldd r25, Y+23\n"      // limit
    "cp r22, r6\n" "cpc r23, r7\n" "cpc r24, r8\n" "cpc r25, r9\n" "brlt 5f\n"    // u > limit
    "movw r26, r6\n" "movw r30, r8\n"
    "add r26, r22\n" "adc r27, r23\n" "adc r30, r24\n" "adc r31, r25\n" "brlt 5f\n"   // u < -limit
    "clr r0\n" "rjmp 8f\n"
    "5:\n"                                                        // saturated
    "mov r0, r2\n" "or r0, r3\n" "or r0, r4\n" "or r0, r5\n" "breq 6f\n"
    "mov r0, r5\n" "eor r0, r9\n" "brmi 6f\n"
    "ldd r10, Y+25\n" "ldd r11, Y+26\n" "ldd r12, Y+27\n" "ldd r13, Y+28\n"      // i' = i
    "movw r6, r10\n" "movw r8, r12\n" "call jl_add_acc\n"        // u = fpd + i
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
    ".text\n");
#endif
