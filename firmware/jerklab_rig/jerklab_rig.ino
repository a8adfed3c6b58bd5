// jerklab rig firmware for an Arduino Uno (ATmega328P, 16 MHz): the Stojčić (2015) positioning
// rig -- sine-jerk planner, feedforward + discrete PID at Ts = 5 ms, 10-bit PWM on Timer1 to an
// L298, quadrature encoder on INT0/INT1, binary serial protocol (firmware/PROTOCOL.md).
//
// Pin map (docs/INTERFACES.md): encoder A D2 (PD2/INT0), B D3 (PD3/INT1); PWM D9 (OC1A);
// L298 IN1 D7 (PD7), IN2 D8 (PB0). Extra: D13 (PB5) is high during each control step (encoder
// read to PWM write, the next reference, TELEMETRY: the cycle budget probe, also on a scope); D12 (PB4, pull-up) held low by a simulator
// announces a simulated plant in HELLO_REPLY.
//
// Serial: a small interrupt-driven UART0 driver (115200 baud 8N1, U2X; JL_BAUD below) instead of the
// Arduino HardwareSerial, whose ~110-cycle transmit ISR could hold off the encoder interrupt
// past a quarter encoder period at top speed (channel B then read after it changed, a count
// in the wrong direction). Every ISR here is short, so INT0 is served within ~70 cycles. A frame
// is encoded straight into the transmit ring (jl::Hal::write_frame); in the 1 Mbaud build the
// transmit interrupt is held while the control step runs and the bytes leave after it (JL_TX_HOLD).
//
// Timing: Timer2 CTC gives an exact 1 ms tick (16 MHz / 64 / 250); every Ts/1 ms ticks it
// raises a flag, and loop() runs the control step (never inside the ISR, so encoder edges
// are served during the float math). Timer0 (millis) is switched off: Timer2 keeps the time.
// PWM: Timer1 phase-correct 10-bit, no prescaler: 16 MHz / 2046 = 7.8 kHz (the paper's
// "8 kHz"); build with -DJL_FAST_PWM for fast PWM 10-bit (15.6 kHz).
//
// Build: make -C firmware (avr-g++ over the Debian Arduino core).
#include <Arduino.h>
#include <avr/interrupt.h>
#include <avr/sleep.h>
#include <util/atomic.h>

#include "src/jl_device.h"
#include "src/jl_port.h"

#ifndef JL_ENCODER_PPR
#define JL_ENCODER_PPR 448
#endif
#ifndef JL_FW_MAJOR
#define JL_FW_MAJOR 1
#define JL_FW_MINOR 0
#define JL_FW_PATCH 0
#endif

static const uint8_t kIn1 = _BV(PD7);    // D7
static const uint8_t kIn2 = _BV(PB0);    // D8
static const uint8_t kPwm = _BV(PB1);    // D9 / OC1A
static const uint8_t kProbe = _BV(PB5);  // D13
static const uint8_t kSimPin = _BV(PB4); // D12

// (not static: the simavr harness reads the count by its symbol, g_counts, which an LTO
// partition would rename)
volatile int32_t g_counts = 0;
static volatile uint32_t g_ms = 0;
static volatile uint8_t g_tick_div = 5;
static volatile uint8_t g_tick_n = 0;
static volatile uint8_t g_tick_flag = 0;
static volatile uint8_t g_overrun = 0;

// ---------------------------------------------------------------- UART0
static const uint8_t kRxSize = 64, kTxSize = 64;   // powers of two
static volatile uint8_t rx_buf[kRxSize];
// The transmit ring: a frame is encoded straight into it (jl::Hal::write_frame), then published by
// moving tx_head; the UDRE interrupt sends bytes tail..head. It holds the largest frame the device
// sends (HELLO_REPLY, 33 bytes) with room to spare.
static uint8_t tx_buf[kTxSize];
static volatile uint8_t rx_head = 0, rx_tail = 0, tx_head = 0, tx_tail = 0;
static volatile uint8_t rx_overflow = 0;
static_assert(jl::kLenHelloReply + 7 <= kTxSize - 1, "the transmit ring must hold the largest frame sent");

// Receive, in assembly (ISR_NAKED, like the encoder ISRs): ~52 cycles from the interrupt to the
// end of reti against ~72 for avr-gcc's code of the same C (its prologue saves r0, r1, r18, r24,
// r25, r30, r31 and clears r1): a HEARTBEAT's 7 bytes landing in a control step cost ~140 cycles
// less. Only r24, r30, r31 and SREG are used. The status is read before the data (FE0 belongs to
// the byte in UDR0); UDR0 is read on every path (that clears RXC0). A byte with a framing error is
// dropped; a byte that finds the ring full (head + 1 == tail) is dropped and sets rx_overflow (the
// parser then sees a bad frame). The free space is (tail - head - 1) mod kRxSize: 0 means full.
// The byte is stored before the head moves (the main code reads bytes tail..head).
static_assert(kRxSize == 64, "the receive ISR masks with 0x3F");
ISR(USART_RX_vect, ISR_NAKED) {
    __asm__ __volatile__(
        "push r24"              "\n\t"
        "in   r24, __SREG__"    "\n\t"
        "push r24"              "\n\t"
        "push r30"              "\n\t"
        "push r31"              "\n\t"
        "lds  r24, %[ucsra]"    "\n\t"
        "sbrc r24, %[fe]"       "\n\t"
        "rjmp 8f"               "\n\t"   /* framing error: drop */
        "lds  r30, %[head]"     "\n\t"
        "lds  r24, %[tail]"     "\n\t"
        "sub  r24, r30"         "\n\t"
        "dec  r24"              "\n\t"
        "andi r24, 0x3F"        "\n\t"   /* free bytes */
        "breq 7f"               "\n\t"
        "lds  r24, %[udr]"      "\n\t"
        "clr  r31"              "\n\t"
        "subi r30, lo8(-(%[buf]))" "\n\t"
        "sbci r31, hi8(-(%[buf]))" "\n\t"
        "st   Z+, r24"          "\n\t"
        "subi r30, lo8(%[buf])" "\n\t"   /* head + 1 */
        "andi r30, 0x3F"        "\n\t"
        "sts  %[head], r30"     "\n\t"
        "9: pop r31"            "\n\t"
        "pop  r30"              "\n\t"
        "pop  r24"              "\n\t"
        "out  __SREG__, r24"    "\n\t"
        "pop  r24"              "\n\t"
        "reti"                  "\n\t"
        "7: ldi r24, 1"         "\n\t"   /* full: drop, flag the overflow */
        "sts  %[ovf], r24"      "\n\t"
        "8: lds r24, %[udr]"    "\n\t"
        "rjmp 9b"               "\n\t"
        :: [ucsra] "n"(_SFR_MEM_ADDR(UCSR0A)), [udr] "n"(_SFR_MEM_ADDR(UDR0)), [fe] "I"(FE0),
           [head] "i"(&rx_head), [tail] "i"(&rx_tail), [buf] "i"(rx_buf), [ovf] "i"(&rx_overflow));
}

// Enabled only while the ring holds bytes (uart_tx_start sets UDRIE0 with interrupts off, after
// publishing the head; the ISR clears it when the ring runs empty), so it never sends a stale byte.
ISR(USART_UDRE_vect) {
    uint8_t t = tx_tail;
    UDR0 = tx_buf[t];
    t = (t + 1) & (kTxSize - 1);
    tx_tail = t;
    if (t == tx_head) UCSR0B &= ~_BV(UDRIE0);
}

// Serial speed: 115200 by default (UBRR 16: 117647 baud, +2.1 %); build with
// -DJL_BAUD=1000000UL (UBRR 1) or 500000UL (UBRR 3), both exact with U2X, for telemetry at
// every sample of a 1 ms loop (a 22-byte TELEMETRY per ms needs > 220 000 baud; 115200 carries
// ~11.8 bytes/ms, i.e. a TELEMETRY every 3rd sample at Ts = 1 ms).
#ifndef JL_BAUD
#define JL_BAUD 115200UL
#endif
// Transmit held during the control step (uart_tx_hold / uart_tx_release around it in loop()):
// at 1 Mbaud a byte leaves every 160 cycles, and a UDRE interrupt per byte (~57 cycles) inside
// the step cost ~1250 cycles a TELEMETRY; held, the bytes go out in the idle time after the step
// (the line idles during the step, which 1 Mbaud can spare: a 22-byte frame needs 3520 of the
// 16000 cycles of a 1 ms period). At 500000 a frame needs 7040 cycles of line time, close to
// what a slow step leaves (16000 - ~8000), and at 115200 (a byte ~1390 cycles, interrupt load
// ~4 %) the line needs every byte time at Ts = 1 ms: not held there.
#ifndef JL_TX_HOLD
#define JL_TX_HOLD (JL_BAUD > 500000UL)
#endif
static uint8_t tx_hold = 0;                            // main code only

static void uart_begin() {
    UCSR0A = _BV(U2X0);
    UBRR0 = static_cast<uint16_t>((F_CPU + 4UL * JL_BAUD) / (8UL * JL_BAUD) - 1UL);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);                 // 8N1
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

// Let the UDRE interrupt send what the ring holds. Interrupts off around the read-modify-write
// of UCSR0B: the ISR clears UDRIE0 when the ring runs empty, and setting it back after that
// would send a stale byte.
static void uart_tx_start() {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        if (tx_head != tx_tail) UCSR0B |= _BV(UDRIE0);
    }
}

static inline void uart_tx_hold() {
#if JL_TX_HOLD
    tx_hold = 1;
    UCSR0B &= ~_BV(UDRIE0);                             // the ISR only ever clears it too
#endif
}

static inline void uart_tx_release() {
#if JL_TX_HOLD
    tx_hold = 0;
    uart_tx_start();
#endif
}

// Wait until the ring has room for n bytes (n <= kTxSize - 1). While it is full, send by polling
// UDRE0 (the interrupt may be held): bytes leave in order, at the line's speed.
static void uart_room(uint8_t n) {
    while (static_cast<uint8_t>((tx_tail - tx_head - 1) & (kTxSize - 1)) < n) {
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
            if (UCSR0A & _BV(UDRE0)) {
                const uint8_t t = tx_tail;
                UDR0 = tx_buf[t];
                tx_tail = (t + 1) & (kTxSize - 1);
            }
        }
    }
}

// One frame into the ring in one pass (jl::encode_frame_ring: header, payload, CRC as the bytes
// are written), then published by one store of the head.
static void uart_write_frame(uint8_t type, uint8_t seq, const uint8_t* payload, uint8_t n) {
    uart_room(static_cast<uint8_t>(n + 7));
    const uint8_t h = jl::encode_frame_ring(tx_buf, kTxSize - 1, tx_head, type, seq, payload, n);
    __asm__ __volatile__("" ::: "memory");              // the bytes are in before the head moves
    tx_head = h;
    if (!tx_hold) uart_tx_start();
}

static inline bool uart_available() { return rx_head != rx_tail; }

static uint8_t uart_read() {
    const uint8_t c = rx_buf[rx_tail];
    rx_tail = (rx_tail + 1) & (kRxSize - 1);
    return c;
}

// Encoder ISRs, in assembly: ~39 cycles from the edge's interrupt to the end of reti (avr-gcc's
// code of the same two lines took ~80: nine register pushes, a 32-bit load, add and store). At
// top speed (~27 A edges per ms) that is ~1000 cycles a ms less, ~40 an edge inside the control
// step. PIND is read by the second instruction (B must be sampled within a quarter encoder period
// of the A edge); (pd >> 1) moves B (bit 3) onto A's bit 2, so bit 2 of pd ^ (pd >> 1) is A != B.
// The 32-bit count is stepped byte by byte and stops at the first byte that does not carry
// (borrow): the main code reads it with interrupts off (jl::Hal::counts), so it never sees a
// partial update, and the ISRs cannot interrupt each other. Only r24, r25 and SREG are used.
// INT1 inverts the direction bit and shares INT0's count code (jl_encoder_step).
#define JL_ENCODER_ISR_ENTRY                                                                   \
        "push r24"              "\n\t"                                                         \
        "in   r24, %[pind]"     "\n\t"                                                         \
        "push r25"              "\n\t"                                                         \
        "in   r25, __SREG__"    "\n\t"                                                         \
        "push r25"              "\n\t"                                                         \
        "mov  r25, r24"         "\n\t"                                                         \
        "lsr  r25"              "\n\t"                                                         \
        "eor  r24, r25"         "\n\t"   /* bit 2: A != B */

// Channel A edge. Forward (A leads B): at an A edge A != B -> +1. With x1 decoding only the
// rising edge interrupts; B is stable for a quarter period around it.
ISR(INT0_vect, ISR_NAKED) {
    __asm__ __volatile__(
        JL_ENCODER_ISR_ENTRY
        ".global jl_encoder_step" "\n\t"   /* INT1 jumps here (another LTO partition maybe) */
        "jl_encoder_step:"      "\n\t"   /* r24 bit 2 set: +1, clear: -1 */
        "lds  r25, %[c]"        "\n\t"
        "sbrs r24, 2"           "\n\t"
        "rjmp 3f"               "\n\t"
        "subi r25, 0xFF"        "\n\t"   /* +1 */
        "sts  %[c], r25"        "\n\t"
        "brne 9f"               "\n\t"
        "lds  r25, %[c]+1"      "\n\t"
        "subi r25, 0xFF"        "\n\t"
        "sts  %[c]+1, r25"      "\n\t"
        "brne 9f"               "\n\t"
        "lds  r25, %[c]+2"      "\n\t"
        "subi r25, 0xFF"        "\n\t"
        "sts  %[c]+2, r25"      "\n\t"
        "brne 9f"               "\n\t"
        "lds  r25, %[c]+3"      "\n\t"
        "subi r25, 0xFF"        "\n\t"
        "sts  %[c]+3, r25"      "\n\t"
        "rjmp 9f"               "\n\t"
        "3: subi r25, 1"        "\n\t"   /* -1: carry set on a borrow */
        "sts  %[c], r25"        "\n\t"
        "brcc 9f"               "\n\t"
        "lds  r25, %[c]+1"      "\n\t"
        "subi r25, 1"           "\n\t"
        "sts  %[c]+1, r25"      "\n\t"
        "brcc 9f"               "\n\t"
        "lds  r25, %[c]+2"      "\n\t"
        "subi r25, 1"           "\n\t"
        "sts  %[c]+2, r25"      "\n\t"
        "brcc 9f"               "\n\t"
        "lds  r25, %[c]+3"      "\n\t"
        "subi r25, 1"           "\n\t"
        "sts  %[c]+3, r25"      "\n\t"
        "9: pop r25"            "\n\t"
        "out  __SREG__, r25"    "\n\t"
        "pop  r25"              "\n\t"
        "pop  r24"              "\n\t"
        "reti"                  "\n\t"
        :: [pind] "I"(_SFR_IO_ADDR(PIND)), [c] "i"(&g_counts));
}

// Channel B edge (x4 decoding only). Forward: at a B edge A == B -> +1.
ISR(INT1_vect, ISR_NAKED) {
    __asm__ __volatile__(
        JL_ENCODER_ISR_ENTRY
        "com  r24"              "\n\t"   /* bit 2 set: A == B */
        "jmp  jl_encoder_step"  "\n\t"   /* jmp: LTO may place INT0 anywhere */
        :: [pind] "I"(_SFR_IO_ADDR(PIND)));
}

// Interruptible (the compare flag is cleared on entry): an encoder edge never waits for it.
ISR(TIMER2_COMPA_vect, ISR_NOBLOCK) {
    ++g_ms;
    if (++g_tick_n >= g_tick_div) {
        g_tick_n = 0;
        if (g_tick_flag) g_overrun = 1;
        g_tick_flag = 1;
    }
}

// The board's functions for the state machine (jl::Hal: static on the AVR, direct calls).
void jl::Hal::write_frame(uint8_t type, uint8_t seq, const uint8_t* payload, uint8_t n) {
    uart_write_frame(type, seq, payload, n);
}
int32_t jl::Hal::counts() {
    int32_t c;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { c = g_counts; }
    return c;
}
void jl::Hal::zero_counts() {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { g_counts = 0; }
}
void jl::Hal::set_decoding(uint8_t decoding) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        EIMSK &= ~(_BV(INT0) | _BV(INT1));
        if (decoding == 1) {
            EICRA = _BV(ISC01) | _BV(ISC00);            // INT0 rising
        } else {
            EICRA = _BV(ISC00) | _BV(ISC10);            // INT0, INT1 any change
        }
        EIFR = _BV(INTF0) | _BV(INTF1);
        EIMSK |= (decoding == 4) ? (_BV(INT0) | _BV(INT1)) : _BV(INT0);
    }
}
void jl::Hal::set_pwm(int16_t pwm) {
    if (pwm > 0) {
        PORTB &= ~kIn2;
        PORTD |= kIn1;
        OCR1A = static_cast<uint16_t>(pwm);
    } else if (pwm < 0) {
        PORTD &= ~kIn1;
        PORTB |= kIn2;
        OCR1A = static_cast<uint16_t>(-pwm);
    } else {
        OCR1A = 0;
        PORTD &= ~kIn1;
        PORTB &= ~kIn2;
    }
}
void jl::Hal::set_period(uint16_t ticks) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        g_tick_div = static_cast<uint8_t>(ticks);
        g_tick_n = 0;
        g_tick_flag = 0;
        g_overrun = 0;
    }
}
uint32_t jl::Hal::millis() {
    uint32_t m;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { m = g_ms; }
    return m;
}
bool jl::Hal::simulated_plant() { return (PINB & kSimPin) == 0; }

static jl::Hal hal;
static const jl::DeviceConfig JL_PROGMEM kConfig = {1000, 1023, JL_ENCODER_PPR, JL_FW_MAJOR, JL_FW_MINOR,
                                         JL_FW_PATCH};
static jl::Device device(hal, kConfig);
static uint32_t last_rx_ms = 0;

// The sketch's own main(), in place of the Arduino core's (a sketch may define it; the core's is
// then not linked): the core's init() starts Timer0 for millis() and delay(), which this firmware
// does not use (Timer2 keeps the time, setup() programs every peripheral it uses), and brings in
// Timer0's overflow interrupt and counters (~250 bytes of flash, 9 of RAM). Interrupts on first,
// as init() does, then setup() and loop() as in any sketch.
int main() {
    sei();
    setup();
    for (;;) loop();
}

void setup() {
    // Outputs low first: the motor must not move while the timers are set up.
    PORTD &= ~kIn1;
    PORTB &= ~(kIn2 | kProbe);
    DDRD |= kIn1;
    DDRB |= kIn2 | kPwm | kProbe;
    DDRB &= ~kSimPin;
    PORTB |= kSimPin;                                  // pull-up: high unless a simulator drives it
    DDRD &= ~(_BV(PD2) | _BV(PD3));
    PORTD |= _BV(PD2) | _BV(PD3);                      // encoder pull-ups (open-collector outputs)

    // Timer1: 10-bit PWM on OC1A, no prescaler.
    TCCR1A = _BV(COM1A1) | _BV(WGM11) | _BV(WGM10);
#ifdef JL_FAST_PWM
    TCCR1B = _BV(WGM12) | _BV(CS10);                   // mode 7, 15.6 kHz
#else
    TCCR1B = _BV(CS10);                                // mode 3, phase correct, 7.8 kHz
#endif
    OCR1A = 0;

    // Timer2: CTC, /64, 250 counts -> 1 kHz.
    TIMSK0 = 0;                                        // Timer0 (millis) off
    TCCR2A = _BV(WGM21);
    TCCR2B = _BV(CS22);
    OCR2A = 249;
    TCNT2 = 0;
    TIFR2 = _BV(OCF2A);
    TIMSK2 = _BV(OCIE2A);

    set_sleep_mode(SLEEP_MODE_IDLE);
    uart_begin();
    device.begin();                                     // PWM 0, decoding, Ts = 5 ms
}

void loop() {
    if (g_tick_flag) {
        g_tick_flag = 0;
        if (device.state() != jl::Device::kIdle) {
            // The control step (probe D13 high; probe build 10 the same span): encoder read ->
            // PWM write, the next sample's reference, the TELEMETRY frame. Then, in the idle
            // time before the next tick, the work ahead (probe build 7).
            JL_PART_BEGIN(10);
#ifndef JL_PROBE_PART
            PORTB |= kProbe;
#endif
            uart_tx_hold();                             // no UDRE interrupt inside the step
            JL_PART_BEGIN(3);
            const bool produced = device.control();
            JL_PART_END(3);
            device.reference();
            JL_PART_BEGIN(6);
            if (produced) device.report();
            JL_PART_END(6);
#ifndef JL_PROBE_PART
            PORTB &= ~kProbe;
#endif
            JL_PART_END(10);
            uart_tx_release();                          // the frame leaves in the idle time
            JL_PART_BEGIN(7);
            device.background();
            JL_PART_END(7);
        }
    }
    if (g_overrun) {
        g_overrun = 0;
        if (device.state() != jl::Device::kIdle) device.count_overrun();
    }
    // At most one frame's worth of bytes per pass keeps the tick latency bounded.
    for (uint8_t i = 0; i < 16 && uart_available(); ++i) {
        device.on_byte(uart_read());
        last_rx_ms = hal.millis();
    }
    if (static_cast<uint32_t>(hal.millis() - last_rx_ms) > 20) device.on_rx_idle();
    device.poll();
    // Nothing to do until the next interrupt (1 ms tick, a received byte, an encoder edge):
    // idle sleep. sei; sleep is atomic, so a wake-up cannot slip in between the test and
    // the sleep. (It also lets simavr skip the idle cycles.)
    cli();
    if (!g_tick_flag && !uart_available()) {
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
    sei();
}
