// Frame codec of the jerklab serial protocol (firmware/PROTOCOL.md, jerklab/protocol.py):
//   0xA5 0x5A | len | type | seq | payload (len-2 bytes, <= 64) | CRC16 lo | CRC16 hi
// len counts type+seq+payload; the CRC (CRC-16/CCITT-FALSE) covers len..payload.
#ifndef JL_FRAME_H
#define JL_FRAME_H
#include <stdint.h>
#include <stddef.h>
#include <string.h>
#include "jl_fixed.h"   // (JL_ZERO)

namespace jl {

static const uint8_t kSync0 = 0xA5;
static const uint8_t kSync1 = 0x5A;
static const uint8_t kMaxPayload = 64;
static const uint8_t kMaxFrame = kMaxPayload + 7;  // sync(2) len type seq payload crc(2)

/// A received frame. The payload is not copied: it points into the FrameParser's buffer and is
/// valid until the parser's next feed(), process() or abandon() (the handlers run before that).
struct Frame {
    uint8_t type;
    uint8_t seq;
    uint8_t len;                 // payload bytes
    const uint8_t* payload;
};

/// Encode a frame into out (at least payload_len + 7 bytes). Returns the frame length,
/// or 0 if payload_len exceeds kMaxPayload.
uint8_t encode_frame(uint8_t* out, uint8_t type, uint8_t seq, const uint8_t* payload,
                     uint8_t payload_len);

/// Encode a frame straight into a transmit ring of mask + 1 bytes (a power of two), starting at
/// index head, in one pass: header, payload, and the CRC accumulated as the bytes are written.
/// Returns the index after the frame (the caller publishes it as the ring's new head once the
/// bytes are in). The caller guarantees room for payload_len + 7 bytes and payload_len <=
/// kMaxPayload. Same bytes as encode_frame (tests/test_firmware.py: golden frames, wrapping).
uint8_t encode_frame_ring(uint8_t* ring, uint8_t mask, uint8_t head, uint8_t type, uint8_t seq,
                          const uint8_t* payload, uint8_t payload_len);

/// Byte-at-a-time decoder. A corrupt frame (bad CRC, bad length) is dropped and counted;
/// the decoder then resynchronises by rescanning the bytes after the false sync, so a good
/// frame that follows garbage (or starts inside a truncated one) is still found.
class FrameParser {
public:
    // (empty at construction: JL_ZERO members)
    void reset() { n_ = 0; used_ = 0; }
    /// Feed one byte; returns true when `frame()` holds a new good frame. After a true,
    /// call `process()` until it returns false: resynchronisation after a corrupt frame can
    /// leave a further complete frame in the buffer.
    bool feed(uint8_t byte);
    /// Look for a complete frame in the bytes already buffered (see `feed`).
    bool process();
    const Frame& frame() const { return frame_; }
    uint16_t dropped() const { return dropped_; }   // corrupt frames seen
    /// Drop a partial frame (e.g. after an inter-byte timeout); counted if bytes were pending.
    /// After a silence: give up the partial frame at the front (count it truncated) and drop
    /// only its first sync byte; the caller then calls process() to re-scan the rest, so a
    /// short frame held back behind a truncated long one is still found (PROTOCOL.md).
    void abandon() { release(); if (n_ > 0) { ++dropped_; shift(1); } }
    bool pending() const { return n_ > used_; }

private:
    void shift(uint8_t k);
    /// Drop the frame last emitted (its bytes stayed in buf_ for frame().payload).
    void release() { if (used_) { shift(used_); used_ = 0; } }
    uint8_t buf_[kMaxFrame];
    uint8_t n_ JL_ZERO;
    uint8_t used_ JL_ZERO;       // bytes at the front of buf_ of the frame last emitted
    uint16_t dropped_ JL_ZERO;
    Frame frame_;
};

// Little-endian field access (both the AVR and x86 hosts are little-endian; memcpy keeps
// the accesses alignment-safe).
static inline void put_f32(uint8_t* p, float v) { memcpy(p, &v, 4); }
static inline float get_f32(const uint8_t* p) { float v; memcpy(&v, p, 4); return v; }
static inline void put_u16(uint8_t* p, uint16_t v) { p[0] = v & 0xFF; p[1] = v >> 8; }
static inline uint16_t get_u16(const uint8_t* p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static inline void put_u32(uint8_t* p, uint32_t v) { memcpy(p, &v, 4); }
static inline uint32_t get_u32(const uint8_t* p) { uint32_t v; memcpy(&v, p, 4); return v; }
static inline void put_i32(uint8_t* p, int32_t v) { memcpy(p, &v, 4); }
static inline int32_t get_i32(const uint8_t* p) { int32_t v; memcpy(&v, p, 4); return v; }

}  // namespace jl
#endif
