// Portability shims: the same core compiles with avr-g++ (AVR, float == double,
// constant tables in flash) and with g++ on the host (float32 arithmetic, as on the AVR).
#ifndef JL_PORT_H
#define JL_PORT_H
#include <stdint.h>
#include <math.h>
#include <string.h>

#if defined(__AVR__)
#include <avr/pgmspace.h>
#define JL_PROGMEM PROGMEM
#define JL_READ_U16(p) pgm_read_word(p)
#define JL_READ_U8(p) pgm_read_byte(p)
#define jl_memcpy_P(d, s, n) memcpy_P(d, s, n)
// avr-libc's float functions are the double ones (double is 32 bit on the AVR).
#define jl_sinf(x) sin(x)
#define jl_cosf(x) cos(x)
#define jl_sqrtf(x) sqrt(x)
#define jl_fabsf(x) fabs(x)
#define jl_lroundf(x) lround(x)
#else
#define JL_PROGMEM
#define JL_READ_U16(p) (*(p))
#define JL_READ_U8(p) (*(p))
#define jl_memcpy_P(d, s, n) memcpy(d, s, n)
#define jl_sinf(x) sinf(x)
#define jl_cosf(x) cosf(x)
#define jl_sqrtf(x) sqrtf(x)
#define jl_fabsf(x) fabsf(x)
#define jl_lroundf(x) lroundf(x)
#endif

// Assembly on the AVR (the host build is C++ throughout):
// - the control law (jl_law.h) is C++ in the default build; make -C firmware
//   EXTRA_DEFS=-DJL_ASM=1 swaps in its hand-written assembly twin (jl_asm_pid.cpp, JL_AVR_ASM);
// - the law's multiply-accumulate mac_g (jl_fixed.h) is, on the AVR, the assembly primitive of
//   jl_asm_mac.cpp (JL_AVR_MAC: twelve MULs, ~100 cycles; like avr-gcc's own 64-bit multiply,
//   a library routine in assembly), unless EXTRA_DEFS=-DJL_PURE_C=1 selects its C++ form
//   (avr-gcc's 64-bit library multiply: ~300 cycles more a product, ~850 a control step).
#ifndef JL_ASM
#define JL_ASM 0
#endif
#ifndef JL_PURE_C
#define JL_PURE_C 0
#endif
#if defined(__AVR__) && JL_ASM
#define JL_AVR_ASM 1
#else
#define JL_AVR_ASM 0
#endif
#if defined(__AVR__) && (JL_ASM || !JL_PURE_C)
#define JL_AVR_MAC 1
#else
#define JL_AVR_MAC 0
#endif

// Cycle profiling (measurement builds only, make EXTRA_DEFS=-DJL_PROBE_PART=n): the probe pin
// D13 (PB5) is high during part n of the control step instead of the whole step, so the simavr
// harness's control_step_cycles report that part (firmware/README.md "Cycle budget").
#if defined(__AVR__) && defined(JL_PROBE_PART)
#include <avr/io.h>
#define JL_PART_BEGIN(n) do { if ((n) == JL_PROBE_PART) PORTB |= _BV(PB5); } while (0)
#define JL_PART_END(n) do { if ((n) == JL_PROBE_PART) PORTB &= ~_BV(PB5); } while (0)
#else
#define JL_PART_BEGIN(n) do { } while (0)
#define JL_PART_END(n) do { } while (0)
#endif

// An optimisation barrier on a pointer: the compiler forgets that it is the constant address of
// a member of the (global) device, so it reaches the fields through it with the short
// displacement loads and stores rather than an absolute 4-byte access each (flash).
#define JL_OPAQUE(p) __asm__("" : "+r"(p))

namespace jl {
/// True for a finite float (NaN - NaN and inf - inf are NaN; needs no -ffast-math).
bool finite_f(float x);
static const float kPi = 3.14159265358979f;
static const float kTwoPi = 6.28318530717959f;
}
#endif
