#include "jl_excite.h"
#include <string.h>
#include "jl_port.h"

namespace jl {

static const uint16_t kPrbsMasks[15] JL_PROGMEM = {
    0x3, 0x6, 0xC, 0x14, 0x30, 0x60, 0xB8, 0x110, 0x240, 0x500, 0x829, 0x100D, 0x2015,
    0x6000, 0xD008};

uint16_t prbs_mask(uint8_t order) {
    if (order < 2 || order > 16) return 0;
    return JL_READ_U16(&kPrbsMasks[order - 2]);
}

#if JL_WITH_SHAPER
static const uint8_t kRingMask = kShaperRing - 1;
static const int32_t kOneQ24 = 16777216L;   // 1.0 in Q8.24

// a - b modulo 2^32 (the exact difference of two windows while it is below 2^31 in magnitude)
static inline int32_t wrap_sub(int32_t a, int32_t b) {
    return static_cast<int32_t>(static_cast<uint32_t>(a) - static_cast<uint32_t>(b));
}

// acc + floor(a x) for a tap a = m 2^-24 (Q8.24) and x in Q16.16 (|x| < 2^30), saturated:
// k x + floor(b x / 2^24) with k = round(a) (halves up; |k| <= 21 for the taps SET_SHAPER
// takes) by |k| saturating adds and b = m - k 2^24 in [-2^23, 2^23), the 24-bit mantissa of the
// control law's multiply-accumulate
static int32_t __attribute__((noinline)) tap_mac(int32_t acc, int32_t x, int32_t m) {
    const int32_t t = m + 0x800000L;
    int8_t k = static_cast<int8_t>(t >> 24);
    int32_t step = x;
    if (k < 0) {
        k = static_cast<int8_t>(-k);
        step = -x;
    }
    for (; k; --k) acc = add_sat_i(acc, step);
    QGain g;
    g.mant = static_cast<int32_t>(t & 0xFFFFFFL) - 0x800000L;
    g.shift = 3;
    return mac_g(acc, x, g);
}

uint8_t Shaper::load(const uint8_t* p) {
    const uint8_t n = p[0];
    if (n > kShaperMaxTaps) return 0;
    float sum = 0.0f;
    for (uint8_t i = 0; i < kShaperMaxTaps; ++i) {
        float a;
        memcpy(&a, p + 1 + 4 * i, 4);
        // |a| <= 2 (finite; jl_fixed.h), and past n_taps only +-0 (|a| <= 0 on the bits)
        if (!abs_le(a, i < n ? kShaperMaxAmplitude : 0.0f)) return 1;
        sum += a;
    }
    if (n && !(jl_fabsf(sum - 1.0f) <= 1e-3f)) return 1;
    const uint8_t* d = p + 1 + 4 * kShaperMaxTaps;
    for (uint8_t i = 0; i < kShaperMaxTaps; ++i) {
        if (i < n ? d[i] >= kShaperRing : d[i] != 0) return 2;
    }
    set(n, p + 1, d);
    return kShaperOk;
}

void Shaper::set(uint8_t n, const uint8_t* amps, const uint8_t* d) {
    n_ = n;
    max_delay_ = 0;
    int32_t a0 = -kOneQ24, s = -kOneQ24;
    float abs_sum = 0.0f;
    for (uint8_t i = 0; i < n; ++i) {
        uint32_t b;
        memcpy(&b, amps + 4 * i, 4);
        float a;
        memcpy(&a, &b, 4);
        abs_sum += jl_fabsf(a);
        // round(a 2^24) (halves away from 0) as to_q16(a 2^8), |a| <= 2 (the caller's check):
        // a 2^8 by the exponent (exact); a subnormal or 0 left as it is (to_q16 makes both 0)
        if (b & 0x7F800000UL) b += 8UL << 23;
        memcpy(&a, &b, 4);
        const int32_t m = to_q16(a);
        a_[i] = m;
        d_[i] = d[i];
        if (d[i] > max_delay_) max_delay_ = d[i];
        if (d[i] == 0) a0 += m;
        s += m;
    }
    a0m1_ = a0;
    sm1_.mant = s;
    sm1_.shift = 2;
    span_ = abs_sum * static_cast<float>(max_delay_) + 1.0f;
}

bool Shaper::fits(float v) const {
    return span_ * v < kShaperSpan;   // (false for a NaN)
}

void Shaper::reset() {
    // the run's state, from q_ to the end of ring_ (jl_excite.h): 0
    memset(&q_, 0, reinterpret_cast<uint8_t*>(ring_ + kShaperRing) - reinterpret_cast<uint8_t*>(&q_));
    pos_ = 0;
}

// (out of line: sample_ahead()'s frame, on every run's stack, stays as without the shaper)
void Shaper::apply(Q32* position, int32_t* velocity, int32_t* accel) {
    const uint8_t* bytes = reinterpret_cast<const uint8_t*>(position);
    int32_t w;
    memcpy(&w, bytes + 2, 4);   // r(k)'s Q16.16 window (bytes 2..5 of the Q32.32, little-endian)
    const uint8_t pos = pos_;
    const int32_t dk = wrap_sub(w, ring_[(pos - 1) & kRingMask]);
    ring_[pos] = w;
    pos_ = (pos + 1) & kRingMask;
    // the Q24.8 window of r(k) (bytes 3..6 of the Q32.32), saturated from |r| >= 2^23 counts
    prev_x_ = q32_window24(*position);
    // r_s = r + (a0 - 1) D + Q, the correction in Q16.16 added to the Q32.32 (units 2^-16)
    q32_add_units(position, tap_mac(q_, dk, a0m1_), 16);
    int32_t s;
    memcpy(&s, bytes + 2, 4);   // r_s(k)'s window
    const int32_t v = wrap_sub(s, prev_s_);
    *accel = wrap_sub(v, prev_v_);
    *velocity = v;
    prev_s_ = s;
    prev_v_ = v;
}

void Shaper::prepare() {
    const int32_t w1 = ring_[(pos_ - 1) & kRingMask];   // w(k - 1)
    int32_t p = 0;
    for (uint8_t i = 0; i < n_; ++i) {
        const uint8_t d = d_[i];
        if (d > 1) p = tap_mac(p, wrap_sub(ring_[(pos_ - d) & kRingMask], w1), a_[i]);
    }
    // (S - 1) r(k - 1), |S - 1| < 2^-9 (|S - 1| 2^24 < 2^15, a 24-bit mantissa), on the Q24.8
    // window x of r(k - 1) (apply()): floor(x (S - 1) 2^24 / 2^16), Q16.16
    q_ = add_sat(mac_g(0, prev_x_, sm1_), p);
}
#endif

}  // namespace jl
