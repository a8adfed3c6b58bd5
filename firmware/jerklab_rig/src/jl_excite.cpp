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
void Shaper::set(uint8_t n, const float* a, const uint8_t* d) {
    n_ = n;
    max_delay_ = 0;
    a0_ = 0.0f;
    for (uint8_t i = 0; i < n; ++i) {
        a_[i] = a[i];
        d_[i] = d[i];
        if (d[i] > max_delay_) max_delay_ = d[i];
        if (d[i] == 0) a0_ += a[i];
    }
}

void Shaper::reset(float inv_ts) {
    memset(ring_, 0, sizeof(ring_));
    pos_ = 0;
    inv_ts_ = inv_ts;
    partial_ = 0.0f;
    prev_pos_ = 0.0f;
    prev_vel_ = 0.0f;
}

void Shaper::apply(float* position, float* velocity, float* accel) {
    ring_[pos_] = *position;
    pos_ = (pos_ + 1) & (kShaperRing - 1);
    const float r = a0_ * *position + partial_;
    const float v = (r - prev_pos_) * inv_ts_;
    *accel = (v - prev_vel_) * inv_ts_;
    *velocity = v;
    *position = r;
    prev_pos_ = r;
    prev_vel_ = v;
}

void Shaper::prepare() {
    float s = 0.0f;
    for (uint8_t i = 0; i < n_; ++i) {
        if (d_[i]) s += a_[i] * ring_[(pos_ - d_[i]) & (kShaperRing - 1)];
    }
    partial_ = s;
}
#endif

}  // namespace jl
