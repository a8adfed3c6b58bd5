// Protocol version 3 additions (firmware/PROTOCOL.md): the PRBS of SEQUENCE (0x0A) and the
// FIR input shaper of SET_SHAPER (0x0B) on the run reference. Mirrors jerklab.protocol
// (prbs_bits, SetShaper) and jerklab.rig.virtual.
#ifndef JL_EXCITE_H
#define JL_EXCITE_H
#include <stdint.h>
#include "jl_fixed.h"     // (JL_ZERO, mac_g)
#include "jl_planner.h"   // (Q32)

namespace jl {

/// Maximal-length Galois LFSR mask of an order 2..16 (0 for any other order).
uint16_t prbs_mask(uint8_t order);

/// The PRBS of SEQUENCE: b = s & 1; s >>= 1; if (b) s ^= mask -- one bit per `hold` samples.
/// (No member initialisers: start() sets every member; a Prbs lives in a union of Device.)
class Prbs {
public:
    void start(uint16_t seed, uint8_t order, uint8_t hold) {
        mask_ = prbs_mask(order);
        state_ = static_cast<uint16_t>(seed & ((1UL << order) - 1));
        hold_ = hold;
        left_ = 0;
        bit_ = 0;
    }
    /// The bit of the next sample.
    uint8_t next() {
        if (left_ == 0) {
            bit_ = state_ & 1u;
            state_ >>= 1;
            if (bit_) state_ ^= mask_;
            left_ = hold_;
        }
        --left_;
        return bit_;
    }

private:
    uint16_t mask_, state_;
    uint8_t hold_, left_, bit_;
};

// Build options (firmware/README.md): JL_WITH_SEQUENCE, JL_WITH_SHAPER (default 1; 0 leaves the
// feature out, its capability bit clear and its command answered NACK UNSUPPORTED) and
// JL_SHAPER_RING (the reference history, a power of two <= 128, default 32: the Uno's RAM is
// nearly full with the four planners and re-targeting; delays up to JL_SHAPER_RING - 1; 4 bytes of
// RAM each, a Q16.16 window; jerklab.protocol.SHAPER_MAX_DELAY must match the default).
#ifndef JL_WITH_SEQUENCE
#define JL_WITH_SEQUENCE 1
#endif
#ifndef JL_WITH_SHAPER
#define JL_WITH_SHAPER 1
#endif
#ifndef JL_SHAPER_RING
#define JL_SHAPER_RING 32
#endif
static const uint8_t kShaperMaxTaps = 10;
static const uint8_t kShaperRing = JL_SHAPER_RING;   // a power of two; delays up to kShaperRing - 1
static_assert((JL_SHAPER_RING & (JL_SHAPER_RING - 1)) == 0 && JL_SHAPER_RING >= 2 && JL_SHAPER_RING <= 128,
              "JL_SHAPER_RING must be a power of two in 2..128");

/// Shaper::load's answer for a valid payload (else the NACK's parameter index).
static const uint8_t kShaperOk = 0xFF;

#if JL_WITH_SHAPER
/// Largest |amplitude| SET_SHAPER takes (a tap's product is round(a) <= 2 saturating adds and one
/// multiply-accumulate; the delay-0 taps' sum a0 - 1 <= 21 adds).
static const float kShaperMaxAmplitude = 2.0f;
/// RUN with a shaper: (sum |a_i| * D + 1) * (max_velocity in counts per sample) must stay below
/// this (counts), so that every difference of the ring's Q16.16 windows is exact (below 2^15
/// counts) and the correction term has 2^14 counts left for (S - 1) r(k - 1).
static const float kShaperSpan = 16384.0f;

/// Sparse FIR on the position reference (PROTOCOL.md SET_SHAPER), in fixed point:
/// r_s(k) = sum_i a_i r(k - d_i), r(j < 0) = 0, with the velocity and acceleration references the
/// backward differences of r_s. Formats: the reference r in counts as Q32.32 (the stepper's);
/// the taps a_i as Q8.24 (int32, a_i 2^24 rounded once by set(), |a_i| <= 2); the ring holds
/// w(j), the Q16.16 window of r(j) modulo 2^32 (bits 16..47 of the Q32.32), whose differences
/// are exact while |r(j) - r(j')| < 2^15 counts; every product is Q16.16 x Q8.24 -> Q16.16,
/// floor(a x), saturated (k x + floor(b x / 2^24) by mac_g, k = round(a), |b| <= 2^23). The FIR is evaluated in the difference form
///   r_s(k) = r(k) + (a0 - 1) D(k) + Q(k),  D(k) = w(k) - w(k - 1),
///   Q(k) = (S - 1) r(k - 1) + sum_{d_i > 1} a_i (w(k - d_i) - w(k - 1)),
/// a0 the sum of the delay-0 taps and S of all taps (exact integer sums of the Q8.24 taps), which
/// is the FIR with the quantised taps: Q(k) is summed by prepare() after the previous sample's
/// PWM is out (untimed), and apply() in the control step does one product whatever the number of
/// taps. Velocity v(k) and acceleration a(k) (counts per sample, per sample^2) are Q16.16
/// differences of r_s's windows. Error against the FIR with the float32 taps on the same r:
/// |a_i - a_q,i| <= 2^-25 per tap (so <= n 2^-25 max|r|) plus (2 sum|a_i| + n + 4) 2^-16 counts
/// of rounding (jerklab.rig.virtual.FixedShaper is the bit-exact twin, checked by test_firmware's
/// golden vectors; the bound by tests/test_rig_sequence_shaper.py).
class Shaper {
public:
    /// Check a SET_SHAPER payload (u8 n_taps, f32 amplitudes[10], u8 delays[10], taps past
    /// n_taps 0; PROTOCOL.md) and set() it: kShaperOk, else the NACK's parameter index (0 n_taps,
    /// 1 an amplitude or their sum, 2 a delay) and the shaper unchanged.
    uint8_t load(const uint8_t* payload);
    /// Quantise the taps of a checked SET_SHAPER payload (n = 0: off) once: `amps` its n
    /// amplitudes (float32, little-endian as in the frame), `d` their delays.
    void set(uint8_t n, const uint8_t* amps, const uint8_t* d);
    bool on() const { return n_ != 0; }
    uint8_t max_delay() const { return max_delay_; }
    /// Whether a run whose reference moves at most `v` counts per sample fits the ring's Q16.16
    /// windows (kShaperSpan).
    bool fits(float v) const;
    /// Start of a run: the history is the rest position 0.
    void reset();
    /// Shape one sample in place: r(k) -> r_s(k); its velocity and acceleration in Q16.16.
    /// (noclone: `this` stays a pointer, not the static Device's constant address, so that
    /// the members are 2-byte displacement loads and stores, not 4-byte absolute ones)
    __attribute__((noinline, noclone)) void apply(Q32* position, int32_t* velocity, int32_t* accel);
    /// After apply(): Q(k + 1), the delayed taps' part of the next sample.
    __attribute__((noinline, noclone)) void prepare();

private:
    // (JL_ZERO: 0 initially, jl_fixed.h; the shaper is a member of the sketch's static Device)
    // The scalars first: apply() and prepare() reach them at a displacement below 64 from
    // `this` (2-byte loads and stores on the AVR), the arrays after them.
    uint8_t n_ JL_ZERO, max_delay_ JL_ZERO, pos_ JL_ZERO;
    int32_t a0m1_ JL_ZERO;             // a0 - 1, Q8.24
    QGain sm1_ JL_ZERO;                // S - 1, Q8.24 as a QGain of shift 2 (Q24.8 x -> Q16.16)
    float span_ JL_ZERO;               // sum |a_i| D + 1 (RUN's range check)
    // a run's state (reset() zeroes it all, from q_ to the end of ring_)
    int32_t q_ JL_ZERO;                // Q(k), Q16.16
    int32_t prev_x_ JL_ZERO;           // r(k - 1)'s Q24.8 window (saturated)
    int32_t prev_s_ JL_ZERO, prev_v_ JL_ZERO;   // r_s(k - 1)'s window, v(k - 1)
    int32_t ring_[kShaperRing];        // w(j), Q16.16 modulo 2^32
    // the taps
    int32_t a_[kShaperMaxTaps];        // Q8.24
    uint8_t d_[kShaperMaxTaps];
};
#else
/// Built without the shaper (JL_WITH_SHAPER 0): never on, no RAM, calls compile to nothing.
class Shaper {
public:
    uint8_t load(const uint8_t*) { return kShaperOk; }
    void set(uint8_t, const uint8_t*, const uint8_t*) {}
    bool on() const { return false; }
    uint8_t max_delay() const { return 0; }
    bool fits(float) const { return true; }
    void reset() {}
    void apply(Q32*, int32_t*, int32_t*) {}
    void prepare() {}
};
#endif

}  // namespace jl
#endif
