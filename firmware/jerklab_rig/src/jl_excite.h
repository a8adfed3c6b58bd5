// Protocol version 3 additions (firmware/PROTOCOL.md): the PRBS of SEQUENCE (0x0A) and the
// FIR input shaper of SET_SHAPER (0x0B) on the run reference. Mirrors jerklab.protocol
// (prbs_bits, SetShaper) and jerklab.rig.virtual.
#ifndef JL_EXCITE_H
#define JL_EXCITE_H
#include <stdint.h>
#include "jl_fixed.h"   // (JL_ZERO)

namespace jl {

/// Maximal-length Galois LFSR mask of an order 2..16 (0 for any other order).
uint16_t prbs_mask(uint8_t order);

/// The PRBS of SEQUENCE: b = s & 1; s >>= 1; if (b) s ^= mask -- one bit per `hold` samples.
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
    uint16_t mask_ = 0, state_ = 1;
    uint8_t hold_ = 1, left_ = 0, bit_ = 0;
};

// Build options (firmware/README.md): JL_WITH_SEQUENCE, JL_WITH_SHAPER (default 1; 0 leaves the
// feature out, its capability bit clear and its command answered NACK UNSUPPORTED) and
// JL_SHAPER_RING (the reference history, a power of two <= 128, default 32: the Uno's RAM is
// nearly full with the four planners and re-targeting; delays up to JL_SHAPER_RING - 1; 4 bytes of
// RAM each; jerklab.protocol.SHAPER_MAX_DELAY must match the default).
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

#if JL_WITH_SHAPER
/// Sparse FIR on the position reference: r_s(k) = sum_i a_i r(k - d_i), r(j < 0) = 0; the
/// velocity and acceleration references are the backward differences of r_s. Split in two so
/// that the control step stays short: prepare() (after a sample's PWM is out, untimed) sums the
/// taps with a delay for the next sample; apply() (in the control step) adds the delay-0 taps
/// and takes the differences: 3 multiplications and 3 additions whatever the number of taps.
class Shaper {
public:
    /// Copy the taps of a checked SET_SHAPER payload (n = 0: off).
    void set(uint8_t n, const float* a, const uint8_t* d);
    bool on() const { return n_ != 0; }
    uint8_t max_delay() const { return max_delay_; }
    /// Start of a run: the history is the rest position 0.
    void reset(float inv_ts);
    /// Shape one sample in place: position -> the FIR, velocity, accel -> backward differences.
    void apply(float* position, float* velocity, float* accel);
    /// After apply(): the delayed taps' sum for the next sample.
    void prepare();

private:
    // (JL_ZERO: 0 initially, jl_fixed.h; the shaper is a member of the sketch's static Device)
    uint8_t n_ JL_ZERO, max_delay_ JL_ZERO, pos_ JL_ZERO;
    float a_[kShaperMaxTaps];
    uint8_t d_[kShaperMaxTaps];
    float a0_ JL_ZERO;                 // the sum of the delay-0 taps
    float partial_ JL_ZERO;            // sum over the delayed taps of a_i r(k - d_i)
    float ring_[kShaperRing];
    float inv_ts_ JL_ZERO, prev_pos_ JL_ZERO, prev_vel_ JL_ZERO;
};
#else
/// Built without the shaper (JL_WITH_SHAPER 0): never on, no RAM, calls compile to nothing.
class Shaper {
public:
    void set(uint8_t, const float*, const uint8_t*) {}
    bool on() const { return false; }
    uint8_t max_delay() const { return 0; }
    void reset(float) {}
    void apply(float*, float*, float*) {}
    void prepare() {}
};
#endif

}  // namespace jl
#endif
