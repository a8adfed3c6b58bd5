// Fixed-point arithmetic of the control step (docs/THEORY.md "The fixed-point PID"): a signed
// 32 x 32 -> 64-bit multiply written for the AVR's MUL instruction, a gain as a 32-bit mantissa
// with a byte shift, and saturating 32-bit adds. The host build computes the same values with
// int64 arithmetic (the golden vectors check one against the other's closed form).
#ifndef JL_FIXED_H
#define JL_FIXED_H
#include <stdint.h>

namespace jl {

/// A gain g = mant * 2^(-8 shift), shift 0..4: the largest shift with |mant| < 2^31, so that
/// |mant| >= 2^23 (24 significant bits) for |g| >= 2^-9 and the quantisation is |error| <= 2^-33
/// below that; a float32 g with |g| >= 2^-9 is represented exactly.
struct QGain {
    int32_t mant;
    uint8_t shift;
};

/// The QGain of g; false (gain unchanged) unless g is finite and |g| < 2^31.
bool to_qgain(float g, QGain* out);

/// floor(a * g.mant / 2^(8 g.shift)), saturated to [INT32_MIN, INT32_MAX]. On the AVR the
/// 64-bit product is sixteen 8 x 8 MULs in inline assembly, the window taken by byte moves in registers.
int32_t mul_q_(int32_t a, int32_t mant, uint8_t shift);
static inline int32_t mul_q(int32_t a, const QGain& g) { return mul_q_(a, g.mant, g.shift); }

/// The full signed 64-bit product a * b as two words (lo, hi), AVR inline assembly on the AVR.
void mul_s32x32(int32_t a, int32_t b, uint32_t* lo, int32_t* hi);

/// a + b saturated to [INT32_MIN, INT32_MAX] (overflow: the sum's sign differs from both's).
int32_t add_sat(int32_t a, int32_t b);
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
