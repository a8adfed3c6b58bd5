#include "jl_frame.h"
#include "jl_crc.h"

namespace jl {

uint8_t encode_frame(uint8_t* out, uint8_t type, uint8_t seq, const uint8_t* payload,
                     uint8_t payload_len) {
    if (payload_len > kMaxPayload) return 0;
    out[0] = kSync0;
    out[1] = kSync1;
    out[2] = static_cast<uint8_t>(payload_len + 2);
    out[3] = type;
    out[4] = seq;
    if (payload_len) memcpy(out + 5, payload, payload_len);
    uint16_t crc = crc16(out + 2, payload_len + 3u);
    out[5 + payload_len] = static_cast<uint8_t>(crc & 0xFF);
    out[6 + payload_len] = static_cast<uint8_t>(crc >> 8);
    return static_cast<uint8_t>(payload_len + 7);
}

// The ring is walked with a pointer and a count of the bytes left before its end (a store, a
// decrement, a branch per byte; a frame wraps at most once); the CRC update is inlined in the
// payload loop.
uint8_t encode_frame_ring(uint8_t* ring, uint8_t mask, uint8_t head, uint8_t type, uint8_t seq,
                          const uint8_t* payload, uint8_t payload_len) {
    const uint8_t hdr[5] = {kSync0, kSync1, static_cast<uint8_t>(payload_len + 2), type, seq};
    uint8_t* p = ring + head;
    uint8_t room = static_cast<uint8_t>(mask + 1 - head);   // 1..mask + 1
    for (uint8_t i = 0; i < 5; ++i) {
        *p++ = hdr[i];
        if (--room == 0) p = ring;
    }
    uint16_t crc = crc16(hdr + 2, 3);
    const uint8_t* src = payload;
    for (uint8_t i = payload_len; i != 0; --i) {
        const uint8_t b = *src++;
        *p++ = b;
        if (--room == 0) p = ring;
        crc = crc16_update(crc, b);
    }
    *p++ = static_cast<uint8_t>(crc & 0xFF);
    if (--room == 0) p = ring;
    *p++ = static_cast<uint8_t>(crc >> 8);
    if (--room == 0) p = ring;
    return static_cast<uint8_t>((p - ring) & mask);
}

// buf_[0..n_) holds the bytes not yet consumed. A frame is emitted as soon as it is
// complete; a false sync (impossible length, bad CRC) is counted and dropped one byte at a
// time, so the scan restarts at the next sync inside the rejected bytes.
bool FrameParser::feed(uint8_t byte) {
    if (n_ >= kMaxFrame) shift(1);  // cannot happen (a full frame is always resolved)
    buf_[n_++] = byte;
    return process();
}

void FrameParser::shift(uint8_t k) {
    if (k >= n_) { n_ = 0; return; }
    memmove(buf_, buf_ + k, n_ - k);
    n_ = static_cast<uint8_t>(n_ - k);
}

bool FrameParser::process() {
    for (;;) {
        if (n_ == 0) return false;
        if (buf_[0] != kSync0) { shift(1); continue; }          // noise between frames
        if (n_ < 2) return false;
        if (buf_[1] != kSync1) { shift(1); continue; }
        if (n_ < 3) return false;
        const uint8_t len = buf_[2];
        if (len < 2 || len > kMaxPayload + 2) { ++dropped_; shift(1); continue; }
        const uint8_t total = static_cast<uint8_t>(len + 5);
        if (n_ < total) return false;
        const uint16_t crc = crc16(buf_ + 2, len + 1u);
        const uint16_t got = static_cast<uint16_t>(buf_[total - 2] | (buf_[total - 1] << 8));
        if (crc != got) { ++dropped_; shift(1); continue; }
        frame_.type = buf_[3];
        frame_.seq = buf_[4];
        frame_.len = static_cast<uint8_t>(len - 2);
        memcpy(frame_.payload, buf_ + 5, frame_.len);
        shift(total);
        return true;
    }
}

}  // namespace jl
