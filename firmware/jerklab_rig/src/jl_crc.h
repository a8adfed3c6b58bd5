// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor).
// Portable C++: used by the Uno firmware and by the host test driver.
#ifndef JL_CRC_H
#define JL_CRC_H
#include <stdint.h>
#include <stddef.h>

namespace jl {

/// Update a running CRC-16/CCITT-FALSE with one byte (no table: avr-libc's
/// _crc_xmodem_update on the AVR).
uint16_t crc16_update(uint16_t crc, uint8_t byte);

/// CRC-16/CCITT-FALSE of a buffer ("123456789" -> 0x29B1).
uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc = 0xFFFFu);

}  // namespace jl
#endif
