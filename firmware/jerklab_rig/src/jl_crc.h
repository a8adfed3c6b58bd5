// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor).
// Portable C++: used by the Uno firmware and by the host test driver.
#ifndef JL_CRC_H
#define JL_CRC_H
#include <stdint.h>
#include <stddef.h>

namespace jl {

/// Update a running CRC-16/CCITT-FALSE with one byte, without a table. With x = top byte ^ data
/// and x ^= x >> 4 (the two nibble reductions at once), the update is
/// (crc << 8) ^ (x << 12) ^ (x << 5) ^ x; written here byte by byte (high byte:
/// lo ^ (x << 4) ^ (x >> 3), low byte: x ^ (x << 5)), which avr-gcc turns into ~18 cycles
/// (swap / shift / and / xor on 8-bit registers) against 27 for avr-libc's _crc_xmodem_update.
/// Inline: the frame encoder calls it once per byte inside the 1 ms control step.
static inline __attribute__((always_inline)) uint16_t crc16_update(uint16_t crc, uint8_t byte) {
    uint8_t x = static_cast<uint8_t>(static_cast<uint8_t>(crc >> 8) ^ byte);
    x ^= static_cast<uint8_t>(x >> 4);
    const uint8_t hi = static_cast<uint8_t>(static_cast<uint8_t>(crc) ^ static_cast<uint8_t>(x << 4) ^
                                            static_cast<uint8_t>(x >> 3));
    const uint8_t lo = static_cast<uint8_t>(x ^ static_cast<uint8_t>(x << 5));
    return static_cast<uint16_t>((static_cast<uint16_t>(hi) << 8) | lo);
}

/// CRC-16/CCITT-FALSE of a buffer ("123456789" -> 0x29B1).
uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc = 0xFFFFu);

}  // namespace jl
#endif
