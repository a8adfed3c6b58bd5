#include "jl_crc.h"
#include "jl_port.h"
#if defined(__AVR__)
#include <util/crc16.h>
#endif

namespace jl {

// One byte through the MSB-first CRC with poly 0x1021, without a table: on the AVR avr-libc's
// _crc_xmodem_update (the same update, ~20 cycles of inline assembly, no 512-byte table in
// flash); elsewhere the equivalent shift-and-xor form (x = top byte ^ data; x ^= x >> 4 makes
// the two nibble reductions, whose poly multiples are x << 12, x << 5 and x).
uint16_t crc16_update(uint16_t crc, uint8_t byte) {
#if defined(__AVR__)
    return _crc_xmodem_update(crc, byte);
#else
    uint8_t x = static_cast<uint8_t>((crc >> 8) ^ byte);
    x ^= static_cast<uint8_t>(x >> 4);
    return static_cast<uint16_t>((crc << 8) ^ (static_cast<uint16_t>(x) << 12) ^
                                 (static_cast<uint16_t>(x) << 5) ^ x);
#endif
}

uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc) {
    for (size_t i = 0; i < n; ++i) crc = crc16_update(crc, data[i]);
    return crc;
}

}  // namespace jl
