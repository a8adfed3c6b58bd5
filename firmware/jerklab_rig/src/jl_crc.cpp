#include "jl_crc.h"

namespace jl {

uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc) {
    for (size_t i = 0; i < n; ++i) crc = crc16_update(crc, data[i]);
    return crc;
}

}  // namespace jl
