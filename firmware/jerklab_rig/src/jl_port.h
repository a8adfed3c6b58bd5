// Portability shims: the same core compiles with avr-g++ (AVR, float == double,
// constant tables in flash) and with g++ on the host (float32 arithmetic, as on the AVR).
#ifndef JL_PORT_H
#define JL_PORT_H
#include <stdint.h>
#include <math.h>

#if defined(__AVR__)
#include <avr/pgmspace.h>
#define JL_PROGMEM PROGMEM
#define JL_READ_U16(p) pgm_read_word(p)
// avr-libc's float functions are the double ones (double is 32 bit on the AVR).
#define jl_sinf(x) sin(x)
#define jl_cosf(x) cos(x)
#define jl_sqrtf(x) sqrt(x)
#define jl_cbrtf(x) cbrt(x)
#define jl_fabsf(x) fabs(x)
#define jl_lroundf(x) lround(x)
#else
#define JL_PROGMEM
#define JL_READ_U16(p) (*(p))
#define jl_sinf(x) sinf(x)
#define jl_cosf(x) cosf(x)
#define jl_sqrtf(x) sqrtf(x)
#define jl_cbrtf(x) cbrtf(x)
#define jl_fabsf(x) fabsf(x)
#define jl_lroundf(x) lroundf(x)
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

namespace jl {
/// True for a finite float (NaN - NaN and inf - inf are NaN; needs no -ffast-math).
bool finite_f(float x);
static const float kPi = 3.14159265358979f;
static const float kTwoPi = 6.28318530717959f;
}
#endif
