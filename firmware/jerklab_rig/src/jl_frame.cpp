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

// Copy n1 >= 1 bytes from src1, then n2 >= 0 from src2, into the ring at p (room: bytes left
// before the ring's end; the frame wraps at most once) and run them through the CRC. On the AVR
// in assembly, 27 cycles a byte (load, store, wrap test, a 17-cycle update, loop) against ~40 for
// avr-gcc's code of the C loop (pointer copies and an extra move per byte); the same arithmetic as
// crc16_update: x = hi ^ b, x ^= x >> 4, hi' = lo ^ (x << 4) ^ (x >> 3), lo' = x ^ (x << 5), where
// x << 5 and x >> 3 are the two halves of x rotated left by 5 (swap, then lsl / adc of the zero
// register: 2 cycles fewer than three lsr). One loop for both pieces (the frame's len/type/seq,
// then its payload).
static inline __attribute__((always_inline)) void ring_copy_crc(uint8_t*& p, uint8_t& room, uint8_t* ring,
                                                                const uint8_t* src1, uint8_t n1,
                                                                const uint8_t* src2, uint8_t n2, uint16_t& crc) {
#if defined(__AVR__)
    uint8_t x, t;
    __asm__ __volatile__(
        "1:  ld   %[x], X+"           "\n\t"
        "    st   Z+, %[x]"           "\n\t"
        "    dec  %[room]"            "\n\t"
        "    brne 2f"                 "\n\t"
        "    movw %A[p], %A[ring]"    "\n\t"   // wrapped: back to the ring's start
        "2:  eor  %[x], %B[crc]"      "\n\t"   // x = hi ^ b
        "    mov  %[t], %[x]"         "\n\t"
        "    swap %[t]"               "\n\t"
        "    andi %[t], 0x0F"         "\n\t"
        "    eor  %[x], %[t]"         "\n\t"   // x ^= x >> 4
        "    mov  %[t], %[x]"         "\n\t"
        "    swap %[t]"               "\n\t"   // t = x rotated left by 4
        "    mov  %B[crc], %[t]"      "\n\t"
        "    andi %B[crc], 0xF0"      "\n\t"
        "    eor  %B[crc], %A[crc]"   "\n\t"   // hi' = lo ^ (x << 4) ...
        "    lsl  %[t]"               "\n\t"
        "    adc  %[t], __zero_reg__" "\n\t"   // t = x rotated left by 5: (x << 5) | (x >> 3)
        "    mov  %A[crc], %[t]"      "\n\t"
        "    andi %[t], 0x1F"         "\n\t"
        "    eor  %B[crc], %[t]"      "\n\t"   // ... ^ (x >> 3)
        "    andi %A[crc], 0xE0"      "\n\t"
        "    eor  %A[crc], %[x]"      "\n\t"   // lo' = x ^ (x << 5)
        "    dec  %[n]"               "\n\t"
        "    brne 1b"                 "\n\t"
        "    tst  %[n2]"              "\n\t"   // the second piece, once
        "    breq 3f"                 "\n\t"
        "    mov  %[n], %[n2]"        "\n\t"
        "    clr  %[n2]"              "\n\t"
        "    movw %A[src], %A[src2]"  "\n\t"
        "    rjmp 1b"                 "\n\t"
        "3:"                          "\n\t"
        : [p] "+z"(p), [src] "+x"(src1), [room] "+r"(room), [n] "+r"(n1), [n2] "+r"(n2),
          [crc] "+d"(crc), [x] "=&r"(x), [t] "=&d"(t)
        : [ring] "r"(ring), [src2] "r"(src2)
        : "memory");
#else
    for (uint8_t k = 0; k < 2; ++k) {
        const uint8_t* src = k ? src2 : src1;
        for (uint8_t n = k ? n2 : n1; n != 0; --n) {
            const uint8_t b = *src++;
            *p++ = b;
            if (--room == 0) p = ring;
            crc = crc16_update(crc, b);
        }
    }
#endif
}

// The ring is walked with a pointer and a count of the bytes left before its end (a store, a
// decrement, a branch per byte; a frame wraps at most once).
uint8_t encode_frame_ring(uint8_t* ring, uint8_t mask, uint8_t head, uint8_t type, uint8_t seq,
                          const uint8_t* payload, uint8_t payload_len) {
    const uint8_t hdr[3] = {static_cast<uint8_t>(payload_len + 2), type, seq};
    uint8_t* p = ring + head;
    uint8_t room = static_cast<uint8_t>(mask + 1 - head);   // 1..mask + 1
    *p++ = kSync0;
    if (--room == 0) p = ring;
    *p++ = kSync1;
    if (--room == 0) p = ring;
    uint16_t crc = 0xFFFFu;
    ring_copy_crc(p, room, ring, hdr, 3, payload, payload_len, crc);   // len, type, seq; payload
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
    release();
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
    release();
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
        frame_.payload = buf_ + 5;
        used_ = total;                                           // dropped on the next call
        return true;
    }
}

}  // namespace jl
