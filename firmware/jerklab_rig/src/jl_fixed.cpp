#include "jl_fixed.h"
#include <string.h>
#include "jl_port.h"

namespace jl {

// (one out-of-line copy: the inline one was cloned into three places on the AVR)
bool __attribute__((noinline)) finite_f(float x) {
    volatile float d = x - x;
    return d == 0.0f;
}

bool __attribute__((noinline)) positive_le(float x, float m) {
    uint32_t b, c;
    memcpy(&b, &x, 4);
    memcpy(&c, &m, 4);
    return b - 1u < c;             // 1 <= b <= c (b = 0, +0, wraps to the largest)
}

bool __attribute__((noinline)) nonneg_f(float x) {
    uint32_t b;
    memcpy(&b, &x, 4);
    return b <= 0x7F7FFFFFUL || b == 0x80000000UL;   // +0 .. the largest float, or -0
}

// The signed product of a and b in the 8 bytes l (bytes 0..3) and h (4..7), AVR assembly.
// Column by column (byte i of a times byte j of b lands at byte i + j): each 16-bit partial
// product is added at k = i + j with the carry into k + 2 only, which cannot carry further (the
// products of columns <= k sum to < 4 * 255^2 * 256^k * 256/255 < 256^(k+3)). The unsigned
// product of the two's complement patterns is then corrected to the signed one: minus b 2^32 if
// a < 0, minus a 2^32 if b < 0.
#define JL_MUL_S32X32_ASM                                                                          \
        "clr %[z]\n\t"                                                                             \
        "mul %A[a], %A[b]\n\t" "movw %A[l], r0\n\t"                                               \
        "clr %C[l]\n\t" "clr %D[l]\n\t" "clr %A[h]\n\t" "clr %B[h]\n\t" "clr %C[h]\n\t" "clr %D[h]\n\t" \
        "mul %A[a], %B[b]\n\t" "add %B[l], r0\n\t" "adc %C[l], r1\n\t" "adc %D[l], %[z]\n\t"       \
        "mul %B[a], %A[b]\n\t" "add %B[l], r0\n\t" "adc %C[l], r1\n\t" "adc %D[l], %[z]\n\t"       \
        "mul %A[a], %C[b]\n\t" "add %C[l], r0\n\t" "adc %D[l], r1\n\t" "adc %A[h], %[z]\n\t"       \
        "mul %B[a], %B[b]\n\t" "add %C[l], r0\n\t" "adc %D[l], r1\n\t" "adc %A[h], %[z]\n\t"       \
        "mul %C[a], %A[b]\n\t" "add %C[l], r0\n\t" "adc %D[l], r1\n\t" "adc %A[h], %[z]\n\t"       \
        "mul %A[a], %D[b]\n\t" "add %D[l], r0\n\t" "adc %A[h], r1\n\t" "adc %B[h], %[z]\n\t"       \
        "mul %B[a], %C[b]\n\t" "add %D[l], r0\n\t" "adc %A[h], r1\n\t" "adc %B[h], %[z]\n\t"       \
        "mul %C[a], %B[b]\n\t" "add %D[l], r0\n\t" "adc %A[h], r1\n\t" "adc %B[h], %[z]\n\t"       \
        "mul %D[a], %A[b]\n\t" "add %D[l], r0\n\t" "adc %A[h], r1\n\t" "adc %B[h], %[z]\n\t"       \
        "mul %B[a], %D[b]\n\t" "add %A[h], r0\n\t" "adc %B[h], r1\n\t" "adc %C[h], %[z]\n\t"       \
        "mul %C[a], %C[b]\n\t" "add %A[h], r0\n\t" "adc %B[h], r1\n\t" "adc %C[h], %[z]\n\t"       \
        "mul %D[a], %B[b]\n\t" "add %A[h], r0\n\t" "adc %B[h], r1\n\t" "adc %C[h], %[z]\n\t"       \
        "mul %C[a], %D[b]\n\t" "add %B[h], r0\n\t" "adc %C[h], r1\n\t" "adc %D[h], %[z]\n\t"       \
        "mul %D[a], %C[b]\n\t" "add %B[h], r0\n\t" "adc %C[h], r1\n\t" "adc %D[h], %[z]\n\t"       \
        "mul %D[a], %D[b]\n\t" "add %C[h], r0\n\t" "adc %D[h], r1\n\t"                            \
        "sbrs %D[a], 7\n\t" "rjmp 1f\n\t"                                                          \
        "sub %A[h], %A[b]\n\t" "sbc %B[h], %B[b]\n\t" "sbc %C[h], %C[b]\n\t" "sbc %D[h], %D[b]\n\t" \
        "1:\n\t"                                                                                   \
        "sbrs %D[b], 7\n\t" "rjmp 2f\n\t"                                                          \
        "sub %A[h], %A[a]\n\t" "sbc %B[h], %B[a]\n\t" "sbc %C[h], %C[a]\n\t" "sbc %D[h], %D[a]\n\t" \
        "2:\n\t"                                                                                   \
        "clr r1\n\t"

void mul_s32x32(int32_t a, int32_t b, uint32_t* lo, int32_t* hi) {
#if defined(__AVR__)
    uint32_t l, h;
    uint8_t z;
    asm volatile(JL_MUL_S32X32_ASM
                 : [l] "=&r"(l), [h] "=&r"(h), [z] "=&r"(z)
                 : [a] "r"(a), [b] "r"(b)
                 : "r0", "r1");
    *lo = l;
    *hi = static_cast<int32_t>(h);
#else
    const int64_t p = static_cast<int64_t>(a) * static_cast<int64_t>(b);
    *lo = static_cast<uint32_t>(static_cast<uint64_t>(p));
    *hi = static_cast<int32_t>(p >> 32);
#endif
}

int32_t mul_q_(int32_t a, int32_t mant, uint8_t shift) {
#if defined(__AVR__)
    // the product in registers, then `shift` byte moves down (the vacated top bytes take the
    // product's sign), then the window l, saturated unless h is l's sign extension
    uint32_t l, h;
    uint8_t z;
    asm volatile(JL_MUL_S32X32_ASM
        "mov %[z], %D[h]\n\t" "lsl %[z]\n\t" "sbc %[z], %[z]\n\t"
        "tst %[s]\n\t" "breq 4f\n\t"
        "3:\n\t"
        "mov %A[l], %B[l]\n\t" "mov %B[l], %C[l]\n\t" "mov %C[l], %D[l]\n\t" "mov %D[l], %A[h]\n\t"
        "mov %A[h], %B[h]\n\t" "mov %B[h], %C[h]\n\t" "mov %C[h], %D[h]\n\t" "mov %D[h], %[z]\n\t"
        "dec %[s]\n\t" "brne 3b\n\t"
        "4:\n\t"
        : [l] "=&r"(l), [h] "=&r"(h), [z] "=&r"(z), [s] "+r"(shift)
        : [a] "r"(a), [b] "r"(mant)
        : "r0", "r1");
    const int32_t r = static_cast<int32_t>(l);
    if (static_cast<int32_t>(h) != (r < 0 ? -1L : 0L)) return z ? INT32_MIN : INT32_MAX;
    return r;
#else
    const int64_t p = (static_cast<int64_t>(a) * static_cast<int64_t>(mant)) >> (8 * shift);
    if (p > INT32_MAX) return INT32_MAX;
    if (p < INT32_MIN) return INT32_MIN;
    return static_cast<int32_t>(p);
#endif
}

int32_t mul_g_(int32_t a, int32_t mant, uint8_t shift) {
#if JL_AVR_MAC
    const QGain g = {mant, shift};
    return jl_mac(0, a, &g);
#else
    // The exact product (|p| < 2^54; avr-gcc: its widening 32 x 32 -> 64-bit library multiply),
    // then floor(p / 2^(8 shift)) as the 4 bytes from byte `shift` of p (little-endian, as on
    // the AVR and the hosts: byte moves, where avr-gcc -Os makes a 64-bit shift a library
    // call), saturated unless every byte above them is their sign extension.
    const int64_t p = static_cast<int64_t>(a) * static_cast<int64_t>(mant);
    uint8_t b[8];
    memcpy(b, &p, 8);
    int32_t w;
    memcpy(&w, b + shift, 4);
    const uint8_t sign = (b[7] & 0x80) ? 0xFF : 0x00;
    bool fits = (w < 0) == (sign != 0);
    for (uint8_t k = static_cast<uint8_t>(shift + 4); k < 8; ++k) fits = fits && b[k] == sign;
    if (!fits) return sign ? INT32_MIN : INT32_MAX;
    return w;
#endif
}

// round(m / 2^k) (halves up), k >= 1; 0 from k = 26 on (m < 2^25)
static uint32_t __attribute__((noinline)) round_shift(uint32_t m, uint8_t k) {
    if (k > 25) return 0;
    for (--k; k; --k) m >>= 1;
    return (m + 1) >> 1;
}

bool to_qgain(float g, QGain* out) {
    // integer work on the IEEE bits: |g| = m 2^(e - 150), m < 2^24; mant = round(m / 2^r),
    // r = 150 - e - 8 shift >= 1 with the largest shift <= 4
    uint32_t b;
    memcpy(&b, &g, 4);
    const uint8_t be = static_cast<uint8_t>((b >> 23) & 0xFF);   // biased exponent
    if (be >= 150) return false;                             // |g| >= 2^23, inf, NaN
    uint32_t m = be ? (b & 0x7FFFFFUL) | 0x800000UL : 0;      // (subnormals: 0)
    uint8_t r = static_cast<uint8_t>(150 - be), s = 0;
    while (s < 4 && r > 8) {
        r -= 8;
        ++s;
    }
    m = round_shift(m, r);
    if (m >= 0x800000UL) {                                   // rounded up to 2^23: one byte less
        if (s == 0) return false;
        --s;
        m = 0x8000UL;
    }
    out->mant = (b & 0x80000000UL) ? -static_cast<int32_t>(m) : static_cast<int32_t>(m);
    out->shift = s;
    return true;
}

// (out of line: one copy of add_sat_i, jl_fixed.h)
int32_t __attribute__((noinline)) add_sat(int32_t a, int32_t b) { return add_sat_i(a, b); }

int32_t sub_sat(int32_t a, int32_t b) {
    const int32_t r = static_cast<int32_t>(static_cast<uint32_t>(a) - static_cast<uint32_t>(b));
    if (((a ^ b) & (a ^ r)) < 0) return a < 0 ? INT32_MIN : INT32_MAX;
    return r;
}

int32_t to_q16(float x) {
    uint32_t b;
    memcpy(&b, &x, 4);
    const uint32_t mag = b & 0x7FFFFFFFUL;
    if (mag > 0x7F800000UL) return 0;                             // NaN
    if (mag >= 0x47000000UL) return (b & 0x80000000UL) ? -0x7FFFFFFFL : 0x7FFFFFFFL;   // |x| >= 2^15
    if (mag < 0x37000000UL) return 0;                             // |x| < 2^-17: rounds to 0
    // x 2^16 by the exponent (no float multiply), then + 0.5 and truncation toward 0
    uint32_t m = mag + (16UL << 23);
    float f;
    memcpy(&f, &m, 4);
    // (from 2^23 on f is an integer: no + 0.5, whose float rounding could add 1)
    const int32_t v = static_cast<int32_t>(m >= 0x4B000000UL ? f : f + 0.5f);
    return (b & 0x80000000UL) ? -v : v;
}

// lround(u) (halves away from zero) clamped to +-top (0 <= top < 2^15), in byte operations on the
// IEEE bits (no soft-float add and conversion, and no 32-bit shifts, which avr-gcc -Os makes
// loops: ~60-100 cycles instead of ~275, exhaustively equal to lroundf for |u| < 2048):
// |u| >= 2^15 (and NaN) is the clamp, |u| < 0.5 is 0, else |u| = v 2^(e - 141) with v the
// mantissa's top 16 bits and lround |u| = (floor(v 2^(e - 140)) + 1) >> 1.
int16_t round_clamp(float u, int16_t top) {
    uint8_t by[4];
    memcpy(by, &u, 4);                        // little endian: by[3] sign and exponent
    const bool neg = (by[3] & 0x80) != 0;
    const uint8_t e = static_cast<uint8_t>((by[3] << 1) | (by[2] >> 7));   // biased exponent
    int16_t pwm;
    if (e >= 142) {                           // |u| >= 2^15, inf, NaN
        pwm = top;
    } else if (e < 126) {                     // |u| < 0.5
        pwm = 0;
    } else {
        uint16_t v = static_cast<uint16_t>(((by[2] | 0x80) << 8) | by[1]);
        uint8_t k = static_cast<uint8_t>(141 - e);                  // 0..15
        if (k >= 8) { v >>= 8; k -= 8; }
        for (; k; --k) v >>= 1;
        v = static_cast<uint16_t>((v + 1u) >> 1);
        pwm = v > static_cast<uint16_t>(top) ? top : static_cast<int16_t>(v);
    }
    return neg ? static_cast<int16_t>(-pwm) : pwm;
}

}  // namespace jl
