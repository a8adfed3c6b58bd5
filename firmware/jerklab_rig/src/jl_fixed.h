// Fixed-point arithmetic of the control step (docs/THEORY.md "The fixed-point PID"): a signed
// 32 x 32 -> 64-bit multiply written for the AVR's MUL instruction, a gain as a 32-bit mantissa
// with a byte shift, and saturating 32-bit adds. The host build computes the same values with
// int64 arithmetic (the golden vectors check one against the other's closed form).
#ifndef JL_FIXED_H
#define JL_FIXED_H
#include <stdint.h>
#include <string.h>
#include "jl_port.h"

// A member whose initial value is 0: `int32_t x JL_ZERO;`. On the AVR the objects holding such
// members are static (the sketch's Device and its parts: zero-initialised storage before any
// constructor runs), so they get no initialiser there, which spares the constructor a store of
// 0 per byte (~2-4 bytes of flash each, ~600 bytes in all); elsewhere (the host driver's
// Device on the stack) they are value-initialised as usual.
#if defined(__AVR__)
#define JL_ZERO
#else
#define JL_ZERO = {}
#endif

namespace jl {

/// A gain g = mant * 2^(-8 shift), shift 0..4, |mant| < 2^23 (a 24-bit signed mantissa, the
/// narrow operand of mul_g): the largest shift with |mant| < 2^23, so that |mant| >= 2^15 (16
/// significant bits at least, up to 23) for |g| >= 2^-17; the quantisation (round half away from
/// 0) is |error| <= 2^-(8 shift + 1), i.e. <= 2^-16 |g| for |g| >= 2^-17 and <= 2^-33 below.
struct QGain {
    int32_t mant;
    uint8_t shift;
};

/// |x| <= m (abs_le) or |x| < m (abs_lt) for a finite m >= 0, false for a NaN or an infinite x
/// (a finiteness check as well): on the IEEE bits, as non-negative floats order as their bits
/// (an integer compare, no soft-float call).
static inline bool abs_le(float x, float m) {
    uint32_t b, c;
    memcpy(&b, &x, 4);
    memcpy(&c, &m, 4);
    return (b & 0x7FFFFFFFUL) <= c;
}
static inline bool abs_lt(float x, float m) {
    uint32_t b, c;
    memcpy(&b, &x, 4);
    memcpy(&c, &m, 4);
    return (b & 0x7FFFFFFFUL) < c;
}

/// 0 < x <= m (positive_le) for a finite m > 0, and x >= 0 finite, -0 included (nonneg_f): on
/// the IEEE bits as abs_le (a negative x and -0 have the top bit set, a NaN and +inf lie above
/// m's bits, +0 and a subnormal x order as their values). Out of line (jl_fixed.cpp): one copy
/// for the parameter checks.
bool positive_le(float x, float m);
bool nonneg_f(float x);

/// a + b saturated to [INT32_MIN, INT32_MAX] (overflow: the sum's sign differs from both's).
int32_t add_sat(int32_t a, int32_t b);

/// add_sat inline, for a loop of adds whose call would cost more registers than the add (on the
/// AVR four add-with-carry and a branch on the overflow flag; add_sat is its one out-of-line copy).
static inline int32_t add_sat_i(int32_t a, int32_t b) {
#if defined(__AVR__)
    asm("add %A[r], %A[b]\n\t" "adc %B[r], %B[b]\n\t" "adc %C[r], %C[b]\n\t" "adc %D[r], %D[b]\n\t"
        "brvc 1f\n\t"
        // overflow: the sum's sign bit is the opposite of the true sum's; 0x7FFFFFFF or 0x80000000
        "mov %A[r], %D[r]\n\t" "lsl %A[r]\n\t" "sbc %A[r], %A[r]\n\t"
        "mov %B[r], %A[r]\n\t" "mov %C[r], %A[r]\n\t" "mov %D[r], %A[r]\n\t" "subi %D[r], 0x80\n\t"
        "1:\n\t"
        : [r] "+d"(a)
        : [b] "r"(b));
    return a;
#else
    const int32_t r = static_cast<int32_t>(static_cast<uint32_t>(a) + static_cast<uint32_t>(b));
    if (((a ^ r) & (b ^ r)) < 0) return a < 0 ? INT32_MIN : INT32_MAX;
    return r;
#endif
}

/// The QGain of g; false (gain unchanged) unless g is finite and |g| < 2^23.
bool to_qgain(float g, QGain* out);

/// floor(a * mant / 2^(8 shift)), saturated to [INT32_MIN, INT32_MAX], for any 32-bit mant (the
/// reference the narrow product is tested against). On the AVR the 64-bit product is sixteen
/// 8 x 8 MULs in inline assembly, the window taken by byte moves in registers.
int32_t mul_q_(int32_t a, int32_t mant, uint8_t shift);
static inline int32_t mul_q(int32_t a, const QGain& g) { return mul_q_(a, g.mant, g.shift); }

/// The control step's product: floor(a * mant / 2^(8 shift)) saturated to [INT32_MIN, INT32_MAX],
/// equal to mul_q_ for |mant| < 2^23 and shift 0..4 (a QGain from to_qgain).
int32_t mul_g_(int32_t a, int32_t mant, uint8_t shift);
static inline int32_t mul_g(int32_t a, const QGain& g) { return mul_g_(a, g.mant, g.shift); }

/// add_sat(acc, mul_g(a, g)): the multiply-accumulate of the control law (jl_law.h). On the AVR
/// the assembly primitive of jl_asm_mac.cpp (twelve 8 x 8 MULs into 7 bytes, the window by
/// `shift` byte moves, its saturation, the saturating add) through its C-callable entry jl_mac;
/// on the host, and on the AVR built with JL_PURE_C=1, this C++.
#if JL_AVR_MAC
extern "C" int32_t jl_mac(int32_t acc, int32_t a, const QGain* g);
static inline int32_t mac_g(int32_t acc, int32_t a, const QGain& g) { return jl_mac(acc, a, &g); }
#else
static inline int32_t mac_g(int32_t acc, int32_t a, const QGain& g) { return add_sat(acc, mul_g(a, g)); }
#endif

/// The full signed 64-bit product a * b as two words (lo, hi), AVR inline assembly on the AVR.
void mul_s32x32(int32_t a, int32_t b, uint32_t* lo, int32_t* hi);

/// a - b saturated to [INT32_MIN, INT32_MAX].
int32_t sub_sat(int32_t a, int32_t b);

/// round(x * 2^16) (halves away from 0) for |x| < 2^15, saturated to +-(2^31 - 1) beyond (NaN: 0).
int32_t to_q16(float x);

/// lround(u) (halves away from 0) clamped to +-top (0 <= top < 2^15), NaN to +top: byte
/// operations on the IEEE bits (the PWM write of the control step; ~60-100 AVR cycles against
/// ~275 through the soft-float add and conversion).
int16_t round_clamp(float u, int16_t top);

}  // namespace jl
#endif
