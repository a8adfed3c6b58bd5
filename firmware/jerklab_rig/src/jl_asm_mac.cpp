// The control law's multiply-accumulate on the AVR, in assembly (the default AVR build; the
// host build, and the AVR built with EXTRA_DEFS=-DJL_PURE_C=1, use the C++ below instead).
// It is an arithmetic primitive, like avr-gcc's own multiplies (libgcc's, also assembly): the
// law that calls it is C++ (jl_law.h). The C++ this replaces (jl_fixed.h, jl_fixed.cpp):
//
//   // acc + floor(a * g.mant / 2^(8 g.shift)), the product and the sum each saturated at
//   // the int32 range (|g.mant| < 2^23, g.shift 0..4: a QGain from to_qgain)
//   int32_t mac_g(int32_t acc, int32_t a, const QGain& g) {
//       int64_t p = (int64_t)a * g.mant;
//       for (uint8_t s = g.shift; s; --s) p >>= 8;
//       const int32_t m = p > INT32_MAX ? INT32_MAX : p < INT32_MIN ? INT32_MIN : (int32_t)p;
//       return add_sat(acc, m);
//   }
//
// (avr-gcc 5.4 makes that product a 32 x 32 -> 64-bit library call: ~400 cycles against ~100
// here; tests/test_firmware_fixed.py checks both on the simulated ATmega328P.)
#include "jl_fixed.h"

#if JL_AVR_MAC
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
asm(".section .text.jl_mac_core,\"ax\",@progbits\n"
    ".global jl_mac_core\n"
    ".global jl_add_acc\n"
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
// convention (the law's mac_g on the AVR).
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
#endif
