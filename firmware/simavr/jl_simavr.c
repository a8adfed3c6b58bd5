/*
 * jl_simavr: the jerklab rig firmware on a simulated Arduino Uno (simavr), with a DC motor
 * and a quadrature encoder attached to its pins and UART0 on a pseudo-terminal.
 *
 *   jl_simavr [options] build/jerklab_rig.elf
 *
 * Prints "PTY /dev/pts/N" on stdout once the UART is bridged, then "READY <sim seconds>" once
 * the firmware has switched its receiver on (RXEN0), then closes stdout (later chatter goes to
 * stderr); a serial client (pyserial, jerklab.rig.connect) opens that path as it would a board
 * on a USB port. Bytes the host writes before RXEN0 is set wait in the bridge, as they would in
 * the Uno's USB-serial chip, instead of being discarded by the simulated UART.
 *
 * Pins (docs/INTERFACES.md): OC1A (D9) duty = OCR1A / TOP read from the data space
 * (0x88..0x89; simavr does not drive OC1A in the phase-correct modes, the register is
 * exact), in the phase-correct modes the value latched at Timer1's TOP (double-buffered, as
 * on the chip: timer1_top_cb), direction from PORTD7 (IN1) and PORTB0 (IN2) like an L298 (IN1 = IN2: brake,
 * volts 0); encoder A on PD2 (INT0), B on PD3 (INT1), driven as external inputs
 * (AVR_IOCTL_IOPORT_SET_EXTERNAL, so firmware writes to PORTD cannot create spurious edges);
 * D12 (PB4) held low tells the firmware its plant is simulated; D13 (PB5) is the firmware's
 * control-step probe, timed here in CPU cycles.
 *
 * Motor (Stojčić eq. 1): tau omega' = K (v - fc sign(omega)) - omega, theta' = omega, solved
 * exactly (ZOH over each step, zero crossings of omega located analytically, sticking while
 * |v| <= fc) every --step-us of simulated time; the encoder edges inside a step are placed at
 * their interpolated times (cycle timers), so no edge is bunched up even at top speed.
 *
 * Flexible load (--load-ratio R > 0; jerklab.plant.FlexibleDCMotor, the encoder on the motor):
 * the motor drives a load through a compliant shaft, in units where the motor's damping is 1
 * (J_m + J_l = tau, J_l / J_m = R, k = w_r^2 J_l, c = 2 zeta_r w_r J_l):
 *   J_m theta_m'' = K v - theta_m' - k (theta_m - theta_l) - c (theta_m' - theta_l')
 *   J_l theta_l'' =                   k (theta_m - theta_l) + c (theta_m' - theta_l')
 * integrated by classical Runge-Kutta (4th order) over each --step-us (no Coulomb friction,
 * as in the Python model: --friction must then be 0).
 *
 * Options:
 *   --K 32.4 --tau 0.025 --supply 12 --friction 0 (Coulomb, volts) --load 0 (volts)
 *   --ppr 448 (pulses per revolution of one channel) --step-us 20
 *   --fast (as fast as possible; default: paced to the wall clock, as a real board)
 *   --stats FILE (JSON, written on SIGUSR1 and at exit) --max-seconds S (simulated time)
 *   --bootloader HEX (Intel hex loaded at its address, e.g. Optiboot at 0x7E00, and made the
 *                     reset vector; started with MCUSR = EXTRF as after the reset that opening
 *                     the port causes on an Uno; --no-app instead of the ELF: empty application)
 *   --counts-addr ADDR (data address of the firmware's encoder count, from avr-nm: reported
 *                       as "firmware_counts" so a test can compare it with the ideal count)
 *   --load-ratio R --mode-hz F --mode-zeta Z (the flexible load: J_l/J_m, the shaft's mode with
 *                       the motor held still in Hz, its damping ratio; default R = 0: rigid)
 *   --trace FILE (every 1 ms of simulated time a line "t theta_m theta_l volts": the load's
 *                 motion, which no encoder sees; theta_l = theta_m for a rigid motor)
 *
 * SIGTERM/SIGINT: write the stats and exit.
 * JL_TRACE_COUNTS=1 in the environment: trace encoder disagreements, late or missed INT0.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <time.h>
#include <unistd.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_irq.h"
#include "sim_time.h"
#include "sim_cycle_timers.h"
#include "sim_core.h"
#include "sim_interrupts.h"
#include "avr_ioport.h"
#include "avr_extint.h"
#include "avr_uart.h"
#include "sim_hex.h"
#include <fcntl.h>
#include <pty.h>
#include <termios.h>

#define OCR1AL 0x88
#define OCR1AH 0x89
#define ICR1L 0x86
#define ICR1H 0x87
#define TCCR1A 0x80
#define TCCR1B 0x81
#define PORTB 0x25
#define PORTD 0x2B
#define UCSR0B 0xC1
#define MCUSR 0x54
#define EXTRF_BIT 1
#define RXEN0_BIT 4

static struct {
    double K, tau, supply, friction, load;
    int ppr, step_us, fast;
    double max_seconds;
    const char *stats_path, *elf;
    long counts_addr;                 /* data address of the firmware's int32 encoder count */
    const char *bootloader;           /* Intel hex loaded at its address and started first */
    int no_app;                       /* --no-app: empty application flash (bootloader only) */
    double load_ratio, mode_hz, mode_zeta;   /* flexible load (load_ratio 0: rigid) */
    const char *trace_path;
} opt = {32.4, 0.025, 12.0, 0.0, 0.0, 448, 20, 0, 0.0, NULL, NULL, -1, NULL, 0, 0.0, 8.0, 0.02, NULL};
static avr_flashaddr_t boot_start;    /* byte address of the bootloader (0: none) */
static uint64_t board_resets;         /* resets into the bootloader (watchdog) after the start */

static avr_t *avr;
/* UART0 <-> pty bridge, run inside the simulation thread (no thread, no lock: simavr's
 * uart_pty part ignores short writes to the pty and races on its FIFOs, which lost telemetry
 * frames on a loaded host; it also always relinks /tmp/simavr-uart0 and can hang at exit). */
static int pty_master = -1, pty_slave = -1;
static char pty_name[128];
static avr_irq_t *uart_in_irq;
static volatile int uart_xon = 1;
#define TXQ 65536
static uint8_t txq[TXQ];              /* AVR -> host bytes not yet taken by the pty */
static size_t txq_head, txq_tail;
#define RXQ 4096
static uint8_t rxq[RXQ];              /* host -> AVR bytes not yet taken by the UART */
static size_t rxq_head, rxq_tail;
static uint64_t uart_tx_bytes, uart_rx_bytes, uart_tx_dropped;
static avr_irq_t *irq_a, *irq_b;

/* motor (and the flexible load's angle and velocity) */
static double theta, omega, volts;
static double theta_l, omega_l;
static FILE *trace_file;
static double trace_next;             /* simulated time of the next trace line */
static double quads_per_rad;          /* 4 ppr / 2 pi */
static avr_cycle_count_t step_cycles;

/* encoder: x4 state q (A,B) = q mod 4 -> 00 10 11 01; q = floor(theta quads_per_rad) + 1, so
 * that with x1 decoding the first forward A rise comes after one full pulse. */
static int64_t q_now;                 /* state on the pins */
static int64_t ideal_x1, ideal_x4;    /* what a perfect decoder counts */
static uint64_t edges;
#define QLEN 4096
static struct { avr_cycle_count_t when; int64_t q; } queue[QLEN];
static unsigned q_head, q_tail;       /* pending edges [head, tail) */
static int edge_timer_on;
static uint64_t queue_overflow;
static uint64_t missed_interrupts;
/* INT0 latency: cycles from an A edge that triggers INT0 to the ISR's first instruction */
static avr_cycle_count_t int0_edge_cycle;
static int int0_armed;
static uint64_t int0_lat_max, int0_lat_n, int0_late;   /* late: > 120 cycles */
static double int0_lat_sum;
static int last_running_vector;   /* edge emitted while its INTn flag was still pending */
#define EIFR 0x3C
#define EIMSK 0x3D
#define EICRA 0x69

/* cycle budget of the control step (PB5 high) */
typedef struct { uint64_t n; double sum; uint64_t min, max; } budget_t;
static budget_t b_moving = {0, 0, UINT64_MAX, 0}, b_all = {0, 0, UINT64_MAX, 0};
static avr_cycle_count_t probe_start;
static int probe_high;

static volatile sig_atomic_t want_stats, want_exit;
static struct timespec wall0;
static unsigned stats_seq;

static double wall_seconds(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (t.tv_sec - wall0.tv_sec) + 1e-9 * (t.tv_nsec - wall0.tv_nsec);
}

static double sim_seconds(void) { return (double)avr->cycle / (double)avr->frequency; }

static void lin(double *th, double *om, double winf, double t) {
    double em = -expm1(-t / opt.tau);
    *th += winf * t + (*om - winf) * opt.tau * em;
    *om = winf + (*om - winf) * (1.0 - em);
}

static double sgn(double x) { return (x > 0) - (x < 0); }

/* The two-mass load (see the header): x = theta_m, omega_m, theta_l, omega_l -> dx/dt. */
static void flex_deriv(const double *x, double v, double *dx) {
    double Jm = opt.tau / (1.0 + opt.load_ratio), Jl = opt.tau - Jm;
    double wr = 2.0 * M_PI * opt.mode_hz;
    double k = wr * wr * Jl, c = 2.0 * opt.mode_zeta * wr * Jl;
    double shaft = k * (x[0] - x[2]) + c * (x[1] - x[3]);
    dx[0] = x[1];
    dx[1] = (opt.K * v - x[1] - shaft) / Jm;
    dx[2] = x[3];
    dx[3] = shaft / Jl;
}

/* One classical Runge-Kutta step of the flexible load under the held voltage v. */
static void advance_flex(double v, double dt) {
    double x[4] = {theta, omega, theta_l, omega_l}, k1[4], k2[4], k3[4], k4[4], t[4];
    flex_deriv(x, v, k1);
    for (int i = 0; i < 4; ++i) t[i] = x[i] + 0.5 * dt * k1[i];
    flex_deriv(t, v, k2);
    for (int i = 0; i < 4; ++i) t[i] = x[i] + 0.5 * dt * k2[i];
    flex_deriv(t, v, k3);
    for (int i = 0; i < 4; ++i) t[i] = x[i] + dt * k3[i];
    flex_deriv(t, v, k4);
    for (int i = 0; i < 4; ++i) x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    theta = x[0]; omega = x[1]; theta_l = x[2]; omega_l = x[3];
}

/* Exact motion over dt under the held net voltage v with Coulomb friction fc (jerklab.plant). */
static void advance(double v, double dt) {
    if (opt.load_ratio > 0.0) { advance_flex(v, dt); return; }
    double fc = opt.friction;
    if (omega == 0.0 && fabs(v) <= fc) return;                       /* stuck */
    double s = omega != 0.0 ? sgn(omega) : sgn(v);
    double winf = opt.K * (v - s * fc);
    if (omega != 0.0 && winf * s < 0.0) {                            /* omega reaches 0 */
        double tstar = opt.tau * log1p(-omega / winf);
        if (tstar < dt) {
            lin(&theta, &omega, winf, tstar);
            omega = 0.0;
            dt -= tstar;
            if (fabs(v) <= fc) return;
            winf = opt.K * (v - sgn(v) * fc);
        }
    }
    lin(&theta, &omega, winf, dt);
    theta_l = theta;
    omega_l = omega;
}

static void set_pins(int64_t q) {
    static const uint8_t A[4] = {0, 1, 1, 0}, B[4] = {0, 0, 1, 1};
    int s = (int)(((q % 4) + 4) % 4);
    int sp = (int)(((q_now % 4) + 4) % 4);
    avr_ioport_external_t ext = {0};
    ext.name = 'D';
    ext.mask = (1 << 2) | (1 << 3);
    ext.value = (A[s] << 2) | (B[s] << 3);
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('D'), &ext);
    /* An edge that triggers INTn while INTFn is still set (the previous edge's interrupt
     * not yet served) is lost on a real ATmega328P: count those. */
    uint8_t eicra = avr->data[EICRA], eimsk = avr->data[EIMSK], eifr = avr->data[EIFR];
    if (A[s] != A[sp]) {
        int isc0 = eicra & 3;   /* 1: any change, 2: falling, 3: rising */
        int trig = (eimsk & 1) && (isc0 == 1 || (isc0 == 3 && A[s]) || (isc0 == 2 && !A[s]));
        if (trig && (eifr & 1)) {
            missed_interrupts++;
            if (getenv("JL_TRACE_COUNTS"))
                fprintf(stderr, "missed INT0 at %llu (q %lld -> %lld, sreg I %d, state %d)\n",
                        (unsigned long long)avr->cycle, (long long)q_now, (long long)q, avr->sreg[S_I], avr->state);
        }
        if (trig && !int0_armed) { int0_armed = 1; int0_edge_cycle = avr->cycle; }
        if (A[s]) ideal_x1 += B[s] ? -1 : 1;
        avr_raise_irq(irq_a, A[s]);
    }
    if (B[s] != B[sp]) {
        int isc1 = (eicra >> 2) & 3;
        int trig = (eimsk & 2) && (isc1 == 1 || (isc1 == 3 && B[s]) || (isc1 == 2 && !B[s]));
        if (trig && (eifr & 2)) missed_interrupts++;
        avr_raise_irq(irq_b, B[s]);
    }
    ideal_x4 += (q > q_now) ? 1 : -1;
    q_now = q;
    edges++;
}

static avr_cycle_count_t edge_cb(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a; (void)param;
    while (q_head != q_tail && queue[q_head % QLEN].when <= when) {
        set_pins(queue[q_head % QLEN].q);
        q_head++;
    }
    if (q_head == q_tail) { edge_timer_on = 0; return 0; }
    return queue[q_head % QLEN].when;
}

static void push_edge(avr_cycle_count_t when, int64_t q) {
    if (q_tail - q_head >= QLEN) { queue_overflow++; return; }
    queue[q_tail % QLEN].when = when;
    queue[q_tail % QLEN].q = q;
    q_tail++;
}

static uint16_t timer1_top(void) {
    int wgm = (avr->data[TCCR1A] & 3) | (((avr->data[TCCR1B] >> 3) & 3) << 2);
    switch (wgm) {
    case 1: case 5: return 0x00FF;
    case 2: case 6: return 0x01FF;
    case 3: case 7: return 0x03FF;
    case 8: case 10: case 12: case 14: return avr->data[ICR1L] | (avr->data[ICR1H] << 8);
    case 9: case 11: case 15: return avr->data[OCR1AL] | (avr->data[OCR1AH] << 8);
    default: return 0x03FF;
    }
}

/* Phase-correct PWM (WGM 1-3, 10, 11): OCR1A is double-buffered and the compare unit takes a
 * new value at TOP (ATmega328P datasheet, "Phase Correct PWM Mode"), so a duty written at a tick
 * is in effect up to one PWM period later (2 TOP prescale cycles: 128 us at 10 bits, prescaler 1).
 * simavr 1.6 does not run Timer1 in these modes: the harness counts Timer1 itself from the moment
 * its clock is seen switched on (TCCR1B's CS bits, at a motor step: the phase to within
 * --step-us) and latches OCR1A at every TOP (a cycle timer); in the other modes OCR1A is used as
 * it is written. */
static int t1_running;                  /* Timer1's clock is on: its TOPs are being timed */
static uint16_t ocr1a_latched;          /* the compare value in effect (phase-correct modes) */
static uint64_t ocr1a_tops, ocr1a_changes;
static avr_cycle_count_t ocr1a_write_cycle; /* when the firmware last wrote a new OCR1A value */
static uint16_t ocr1a_seen;
static double pwm_delay_sum, pwm_delay_max; /* written value -> in effect, seconds */
static uint64_t pwm_delay_n;

static int timer1_phase_correct(void) {
    int wgm = (avr->data[TCCR1A] & 3) | (((avr->data[TCCR1B] >> 3) & 3) << 2);
    return wgm == 1 || wgm == 2 || wgm == 3 || wgm == 10 || wgm == 11;
}

static unsigned timer1_prescale(void) {
    static const unsigned pre[8] = {0, 1, 8, 64, 256, 1024, 0, 0};
    return pre[avr->data[TCCR1B] & 7];
}

static uint16_t ocr1a_register(void) { return avr->data[OCR1AL] | (avr->data[OCR1AH] << 8); }

static uint16_t timer1_top(void);

/* At each TOP: the buffered OCR1A becomes the compare value; the next TOP one period later. */
static avr_cycle_count_t timer1_top_cb(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)param;
    unsigned pre = timer1_prescale();
    if (!pre) { t1_running = 0; return 0; }
    uint16_t v = ocr1a_register();
    ocr1a_tops++;
    /* a write since the last motor step: seen here first (its delay counts as 0) */
    if (v != ocr1a_seen) { ocr1a_seen = v; ocr1a_write_cycle = when; }
    if (v != ocr1a_latched) {
        ocr1a_changes++;
        ocr1a_latched = v;
        if (ocr1a_write_cycle) {
            double d = (double)(when - ocr1a_write_cycle) / a->frequency;
            pwm_delay_sum += d;
            if (d > pwm_delay_max) pwm_delay_max = d;
            pwm_delay_n++;
        }
    }
    return when + 2 * (avr_cycle_count_t)timer1_top() * pre;
}

/* Called at every motor step: notices Timer1 starting and when OCR1A changes (for the stats). */
static void timer1_watch(void) {
    uint16_t v = ocr1a_register();
    if (v != ocr1a_seen) { ocr1a_seen = v; ocr1a_write_cycle = avr->cycle; }
    if (!t1_running && timer1_prescale()) {
        t1_running = 1;
        ocr1a_latched = v;
        avr_cycle_timer_register(avr, (avr_cycle_count_t)timer1_top() * timer1_prescale(),
                                 timer1_top_cb, NULL);
    }
}

/* The L298 bridge: enable = OC1A (PWM duty) or PB1 as a plain output, IN1/IN2 direction. */
static double bridge_volts(void) {
    double duty;
    if (avr->data[TCCR1A] & 0x80) {                                  /* COM1A1: OC1A is PWM */
        uint16_t top = timer1_top();
        uint16_t ocr = (t1_running && timer1_phase_correct()) ? ocr1a_latched : ocr1a_register();
        duty = top ? (double)(ocr > top ? top : ocr) / top : 0.0;
    } else {
        duty = (avr->data[PORTB] >> 1) & 1;
    }
    int in1 = (avr->data[PORTD] >> 7) & 1, in2 = avr->data[PORTB] & 1;
    int dir = (in1 && !in2) ? 1 : (in2 && !in1) ? -1 : 0;
    return dir * duty * opt.supply;
}

/* The CPU sleeps (idle) between interrupts; simavr's default sleep hook usleeps each nap in
 * full, which both loses time to overheads and forbids --fast. Pace to the wall clock instead. */
/* Real-time pacing. When the host starves the simulation and it falls behind the wall clock,
 * the lag is forgiven rather than caught up: a catch-up burst would run the firmware's clock
 * faster than the host's, and its host watchdog would see the heartbeats spaced too far. */
static double wall_offset;
static void pace(void) {
    if (opt.fast) return;
    double ahead = sim_seconds() - (wall_seconds() - wall_offset);
    if (ahead > 0.001) usleep((useconds_t)(ahead * 1e6));
    else if (ahead < -0.02) wall_offset += -ahead;
}

static void sleep_hook(avr_t *a, avr_cycle_count_t how_long) {
    (void)a; (void)how_long;
    pace();
}

/* simavr 1.6's run loop, with one fix: when a cycle timer (an encoder edge) raises an
 * interrupt while the CPU sleeps, the stock loop first jumps the clock to the *next* timer and
 * only then serves the interrupt, so the ISR runs up to one timer period late (here: it read
 * channel B after B had changed at top speed and counted backwards). A real ATmega328P wakes
 * from idle in a few cycles: serve the interrupt now. */
static uint64_t resets;               /* jumps to the reset vector after boot */
/* The lowest stack pointer of the run (SPL/SPH at data 0x5D/0x5E), counted once it held for three
 * instructions (a write of SP is two OUTs: the value between them is not a stack), and the pc
 * there: the stack's deepest point, to compare with the end of .bss. */
static unsigned sp_min = 0xFFFF, sp_min_pc;
static void run_hook(avr_t *a) {
    avr_flashaddr_t new_pc = a->pc;
    if (a->state == cpu_Running) new_pc = avr_run_one(a);
    {
        static unsigned sp1 = 0xFFFF, sp2 = 0xFFFF;
        const unsigned sp = a->data[0x5D] | (a->data[0x5E] << 8);
        if (sp == sp1 && sp == sp2 && sp < sp_min && a->cycle > 100) {
            sp_min = sp;
            sp_min_pc = a->pc;
        }
        sp2 = sp1;
        sp1 = sp;
    }
    if (new_pc == 0 && a->cycle > 16 && !(boot_start && a->pc >= boot_start)) {
        resets++;
        if (getenv("JL_TRACE_COUNTS")) fprintf(stderr, "reset: jump to 0 from pc 0x%x at cycle %llu\n", a->pc, (unsigned long long)a->cycle);
    }
    avr_cycle_count_t sleep = avr_cycle_timer_process(a);
    a->pc = new_pc;
    if (a->state == cpu_Sleeping) {
        if (!a->sreg[S_I]) {
            a->state = cpu_Done;             /* cli; sleep: the firmware stopped */
            return;
        }
        if (a->interrupt_state) {
            a->cycle += 1;                   /* woken by a pending interrupt */
        } else {
            a->sleep(a, sleep);
            a->cycle += 1 + sleep;
        }
    }
    if ((a->state == cpu_Running || a->state == cpu_Sleeping) && a->interrupt_state)
        avr_service_interrupts(a);
}

static void uart_out_cb(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)param;
    if (txq_tail - txq_head >= TXQ) { uart_tx_dropped++; return; }
    txq[txq_tail++ % TXQ] = (uint8_t)value;
    uart_tx_bytes++;
}

static void uart_xon_cb(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)value; (void)param;
    uart_xon = 1;
}

static void uart_xoff_cb(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)value; (void)param;
    uart_xon = 0;
}

/* The receiver was switched on for the first time: tell the launcher ("READY" on the fd that
 * carried the "PTY" line), so that launch() returns once the firmware can receive. */
static avr_cycle_count_t uart_ready_cycle;
static int ready_fd = -1;
static void uart_ready(avr_t *a) {
    uart_ready_cycle = a->cycle ? a->cycle : 1;
    if (ready_fd >= 0) {
        char line[64];
        int n = snprintf(line, sizeof line, "READY %.6f\n", sim_seconds());
        if (write(ready_fd, line, (size_t)n) < 0) { /* launcher gone: nothing to tell */ }
        close(ready_fd);
        ready_fd = -1;
    }
}

/* Every 50 us of simulated time: hand the AVR's bytes to the pty (keeping what it does not
 * take), read the host's bytes, and feed them to the UART while it signals XON. */
static avr_cycle_count_t uart_cb(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a; (void)param;
    while (txq_head != txq_tail) {
        size_t start = txq_head % TXQ, n = txq_tail - txq_head;
        if (start + n > TXQ) n = TXQ - start;
        ssize_t w = write(pty_master, txq + start, n);
        if (w <= 0) break;                     /* pty full (EAGAIN): try again later */
        txq_head += (size_t)w;
    }
    if (rxq_tail - rxq_head < RXQ / 2) {
        uint8_t buf[256];
        ssize_t r = read(pty_master, buf, sizeof buf);
        for (ssize_t i = 0; i < r; ++i) rxq[rxq_tail++ % RXQ] = buf[i];
    }
    /* simavr's UART discards a byte while RXEN0 is clear (as the ATmega328P does), and the
     * Arduino core's init() clears UCSR0B: bytes the host wrote right after the pty appeared
     * would be lost until setup() enables the receiver. A USB-serial chip holds them in its
     * buffer; so does this bridge. */
    int rx_on = (a->data[UCSR0B] >> RXEN0_BIT) & 1;
    if (rx_on && !uart_ready_cycle) uart_ready(a);
    while (rx_on && uart_xon && rxq_head != rxq_tail) {
        avr_raise_irq(uart_in_irq, rxq[rxq_head++ % RXQ]);
        uart_rx_bytes++;
    }
    return when + avr_usec_to_cycles(a, 50);
}

static int uart_bridge_init(void) {
    if (openpty(&pty_master, &pty_slave, pty_name, NULL, NULL) != 0) {
        fprintf(stderr, "jl_simavr: cannot create a pty: %s\n", strerror(errno));
        return -1;
    }
    struct termios t;
    if (tcgetattr(pty_slave, &t) == 0) {     /* raw bytes, no echo, no line discipline */
        cfmakeraw(&t);
        tcsetattr(pty_slave, TCSANOW, &t);
    }
    /* we keep the slave open: the master then never sees EIO while no host is connected */
    fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
    uint32_t f = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &f);
    f &= ~AVR_UART_FLAG_STDIO;                 /* binary protocol: no console dump */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &f);
    uart_in_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out_cb, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_cb, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_cb, NULL);
    avr_cycle_timer_register_usec(avr, 50, uart_cb, NULL);
    return 0;
}

static avr_cycle_count_t motor_cb(avr_t *a, avr_cycle_count_t when, void *param);
static avr_cycle_count_t edge_cb(avr_t *a, avr_cycle_count_t when, void *param);

/* Optiboot ends a session (and its 1 s wait) with a watchdog reset. simavr's avr_reset() clears
 * the cycle timers (the UART bridge, the motor, pending encoder edges): put them back. */
static void after_reset(void) {
    if (!avr_cycle_timer_status(avr, uart_cb, NULL)) {
        board_resets++;
        avr_cycle_timer_register_usec(avr, 50, uart_cb, NULL);
        avr_cycle_timer_register(avr, step_cycles, motor_cb, NULL);
        edge_timer_on = 0;
        t1_running = 0;                           /* Timer1 stopped by the reset */
        q_head = q_tail;                          /* edges already on the pins stay there */
        uart_ready_cycle = 0;                     /* the receiver is off again until enabled */
        if (getenv("JL_TRACE_COUNTS")) fprintf(stderr, "board reset at cycle %llu\n", (unsigned long long)avr->cycle);
    }
}

/* Load an Intel-hex bootloader into flash at its own address and make it the reset vector
 * (BOOTRST programmed, as on an Uno). */
static int load_bootloader(const char *path) {
    ihex_chunk_p chunks = NULL;
    int n = read_ihex_chunks(path, &chunks);
    if (n <= 0) {
        fprintf(stderr, "jl_simavr: cannot read bootloader hex %s\n", path);
        return -1;
    }
    uint32_t lo = UINT32_MAX;
    for (int i = 0; i < n; ++i) {
        if (chunks[i].baseaddr + chunks[i].size > avr->flashend + 1) {
            fprintf(stderr, "jl_simavr: bootloader chunk at 0x%x does not fit the flash\n", chunks[i].baseaddr);
            free_ihex_chunks(chunks);
            return -1;
        }
        memcpy(avr->flash + chunks[i].baseaddr, chunks[i].data, chunks[i].size);
        if (chunks[i].baseaddr < lo) lo = chunks[i].baseaddr;
    }
    free_ihex_chunks(chunks);
    boot_start = lo;
    avr->reset_pc = lo;
    avr->pc = lo;
    avr->codeend = avr->flashend;
    return 0;
}

static avr_cycle_count_t motor_cb(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)param;
    timer1_watch();
    volts = bridge_volts();
    double th0 = theta;
    advance(volts + opt.load, (double)step_cycles / a->frequency);
    if (trace_file && sim_seconds() >= trace_next) {
        fprintf(trace_file, "%.6f %.9g %.9g %.6g\n", sim_seconds(), theta, theta_l, volts);
        trace_next += 1e-3;
    }
    /* encoder edges between th0 and theta at their interpolated cycles */
    int64_t q_new = (int64_t)floor(theta * quads_per_rad) + 1;
    int64_t q_last = q_tail != q_head ? queue[(q_tail - 1) % QLEN].q : q_now;
    if (q_new != q_last) {
        int64_t dir = q_new > q_last ? 1 : -1;
        for (int64_t q = q_last + dir; ; q += dir) {
            double boundary = (double)((dir > 0 ? q : q + 1) - 1) / quads_per_rad;
            double f = (theta != th0) ? (boundary - th0) / (theta - th0) : 1.0;
            if (f < 0) f = 0;
            if (f > 1) f = 1;
            push_edge(when + (avr_cycle_count_t)(f * step_cycles), q);
            if (q == q_new) break;
        }
        if (!edge_timer_on && q_head != q_tail) {
            edge_timer_on = 1;
            avr_cycle_count_t first = queue[q_head % QLEN].when;
            avr_cycle_timer_register(a, first > a->cycle ? first - a->cycle : 1, edge_cb, NULL);
        }
    }
    if (getenv("JL_TRACE_COUNTS") && opt.counts_addr >= 0) {
        static long last = 0x7fffffff;
        const uint8_t *c = a->data + opt.counts_addr;
        int32_t v = (int32_t)((uint32_t)c[0] | ((uint32_t)c[1] << 8) | ((uint32_t)c[2] << 16) | ((uint32_t)c[3] << 24));
        long d = (long)(ideal_x1 - v);
        if (d != last) fprintf(stderr, "trace t=%.6f cyc=%llu diff=%ld omega=%.1f eifr=%02x\n", sim_seconds(), (unsigned long long)a->cycle, d, omega, a->data[EIFR]);
        last = d;
    }
    /* pace to the wall clock (every ~1 ms of simulated time) */
    if ((when / step_cycles) % 50 == 0) pace();
    return when + step_cycles;
}

static void isr_cb(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)param;
    if (value == 1 && int0_armed) {
        uint64_t lat = avr->cycle - int0_edge_cycle;
        int0_armed = 0;
        int0_lat_n++;
        int0_lat_sum += (double)lat;
        if (lat > int0_lat_max) int0_lat_max = lat;
        if (lat > 120) {
            int0_late++;
            if (getenv("JL_TRACE_COUNTS"))
                fprintf(stderr, "late INT0: %llu cycles at %llu (last vector %d, state %d)\n",
                        (unsigned long long)lat, (unsigned long long)avr->cycle, last_running_vector, avr->state);
        }
    }
}

static void any_isr_cb(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)param;
    if (value) last_running_vector = (int)value;
}

static void probe_cb(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)param;
    if (value && !probe_high) {
        probe_high = 1;
        probe_start = avr->cycle;
    } else if (!value && probe_high) {
        probe_high = 0;
        uint64_t d = avr->cycle - probe_start;
        budget_t *bs[2] = {&b_all, &b_moving};
        int moving = fabs(omega) > 1.0 || volts != 0.0;
        for (int i = 0; i < 1 + moving; ++i) {
            budget_t *b = bs[i];
            b->n++;
            b->sum += (double)d;
            if (d < b->min) b->min = d;
            if (d > b->max) b->max = d;
        }
    }
}

static void write_budget(FILE *f, const char *name, const budget_t *b) {
    fprintf(f, "\"%s\": {\"n\": %llu, \"min\": %llu, \"mean\": %.1f, \"max\": %llu}", name,
            (unsigned long long)b->n, (unsigned long long)(b->n ? b->min : 0),
            b->n ? b->sum / b->n : 0.0, (unsigned long long)b->max);
}

static void write_stats(void) {
    if (!opt.stats_path) return;
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp%d", opt.stats_path, (int)getpid());
    FILE *f = fopen(tmp, "w");
    if (!f) return;
    double sim = sim_seconds(), wall = wall_seconds();
    fprintf(f, "{\"seq\": %u, \"sim_seconds\": %.6f, \"wall_seconds\": %.3f, \"realtime_factor\": %.3f, "
               "\"lag_forgiven_seconds\": %.3f, \"missed_interrupts\": %llu, \"firmware_resets\": %llu, "
               "\"board_resets\": %llu, "
               "\"cycles\": %llu, \"theta\": %.9g, \"omega\": %.9g, \"theta_load\": %.9g, \"volts\": %.6g, "
               "\"ideal_counts_x1\": %lld, \"ideal_counts_x4\": %lld, \"edges\": %llu, "
               "\"edge_queue_overflow\": %llu, \"pty\": \"%s\", \"uart_tx_bytes\": %llu, "
               "\"uart_rx_bytes\": %llu, \"uart_tx_dropped\": %llu, \"uart_ready_seconds\": %.6f, "
               "\"uart_rx_pending\": %llu, \"pwm_tops\": %llu, \"pwm_changes\": %llu, "
               "\"pwm_delay_us\": {\"n\": %llu, \"mean\": %.3f, \"max\": %.3f}, ",
            ++stats_seq, sim, wall, wall > 0 ? sim / wall : 0.0, wall_offset,
            (unsigned long long)missed_interrupts, (unsigned long long)resets,
            (unsigned long long)board_resets, (unsigned long long)avr->cycle,
            theta, omega, theta_l, volts, (long long)ideal_x1, (long long)ideal_x4,
            (unsigned long long)edges, (unsigned long long)queue_overflow, pty_name,
            (unsigned long long)uart_tx_bytes, (unsigned long long)uart_rx_bytes,
            (unsigned long long)uart_tx_dropped,
            uart_ready_cycle ? (double)uart_ready_cycle / avr->frequency : -1.0,
            (unsigned long long)(rxq_tail - rxq_head), (unsigned long long)ocr1a_tops,
            (unsigned long long)ocr1a_changes, (unsigned long long)pwm_delay_n,
            pwm_delay_n ? 1e6 * pwm_delay_sum / pwm_delay_n : 0.0, 1e6 * pwm_delay_max);
    if (opt.counts_addr >= 0 && opt.counts_addr + 3 <= (long)avr->ramend) {
        const uint8_t *c = avr->data + opt.counts_addr;
        int32_t v = (int32_t)((uint32_t)c[0] | ((uint32_t)c[1] << 8) | ((uint32_t)c[2] << 16) | ((uint32_t)c[3] << 24));
        fprintf(f, "\"firmware_counts\": %ld, ", (long)v);
    }
    fprintf(f, "\"stack_min_sp\": %u, \"stack_min_pc\": %u, ", sp_min, sp_min_pc);
    fprintf(f, "\"int0_latency_cycles\": {\"n\": %llu, \"mean\": %.1f, \"max\": %llu, \"over_120\": %llu}, ",
            (unsigned long long)int0_lat_n, int0_lat_n ? int0_lat_sum / int0_lat_n : 0.0,
            (unsigned long long)int0_lat_max, (unsigned long long)int0_late);
    write_budget(f, "control_step_cycles_moving", &b_moving);
    fprintf(f, ", ");
    write_budget(f, "control_step_cycles_all", &b_all);
    fprintf(f, ", \"params\": {\"K\": %g, \"tau\": %g, \"supply\": %g, \"friction\": %g, \"load\": %g, "
               "\"ppr\": %d, \"step_us\": %d, \"fast\": %d, \"load_ratio\": %g, \"mode_hz\": %g, "
               "\"mode_zeta\": %g}}\n",
            opt.K, opt.tau, opt.supply, opt.friction, opt.load, opt.ppr, opt.step_us, opt.fast,
            opt.load_ratio, opt.mode_hz, opt.mode_zeta);
    if (trace_file) fflush(trace_file);
    fclose(f);
    rename(tmp, opt.stats_path);
}

static void on_signal(int sig) {
    if (sig == SIGUSR1) want_stats = 1;
    else want_exit = 1;
}

static void usage(void) {
    fprintf(stderr, "usage: jl_simavr [--K v] [--tau v] [--supply v] [--friction v] [--load v] [--ppr n] "
                    "[--step-us n] [--fast] [--stats FILE] [--max-seconds s] [--counts-addr a] "
                    "[--bootloader optiboot.hex] [--load-ratio r --mode-hz f --mode-zeta z] [--trace FILE] "
                    "firmware.elf | --no-app\n");
    _exit(2);
}

static double num(const char *name, const char *s, double lo, double hi) {
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || *end || !isfinite(v) || v < lo || v > hi) {
        fprintf(stderr, "jl_simavr: %s must be a number in [%g, %g], got '%s'\n", name, lo, hi, s);
        _exit(2);
    }
    return v;
}

int main(int argc, char **argv) {
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--fast")) { opt.fast = 1; continue; }
        if (!strcmp(a, "--no-app")) { opt.no_app = 1; continue; }
        if (a[0] == '-' && a[1] == '-') {
            if (!v) usage();
            if (!strcmp(a, "--K")) opt.K = num("K", v, 1e-9, 1e6);
            else if (!strcmp(a, "--tau")) opt.tau = num("tau", v, 1e-6, 100);
            else if (!strcmp(a, "--supply")) opt.supply = num("supply", v, 0, 1000);
            else if (!strcmp(a, "--friction")) opt.friction = num("friction", v, 0, 1000);
            else if (!strcmp(a, "--load")) opt.load = num("load", v, -1000, 1000);
            else if (!strcmp(a, "--ppr")) opt.ppr = (int)num("ppr", v, 1, 1e6);
            else if (!strcmp(a, "--step-us")) opt.step_us = (int)num("step-us", v, 1, 1000);
            else if (!strcmp(a, "--stats")) opt.stats_path = v;
            else if (!strcmp(a, "--max-seconds")) opt.max_seconds = num("max-seconds", v, 0, 1e9);
            else if (!strcmp(a, "--counts-addr")) opt.counts_addr = strtol(v, NULL, 0);
            else if (!strcmp(a, "--bootloader")) opt.bootloader = v;
            else if (!strcmp(a, "--load-ratio")) opt.load_ratio = num("load-ratio", v, 0, 1e3);
            else if (!strcmp(a, "--mode-hz")) opt.mode_hz = num("mode-hz", v, 1e-3, 1e4);
            else if (!strcmp(a, "--mode-zeta")) opt.mode_zeta = num("mode-zeta", v, 0, 10);
            else if (!strcmp(a, "--trace")) opt.trace_path = v;
            else usage();
            ++i;
            continue;
        }
        opt.elf = a;
    }
    if (!opt.elf && !(opt.no_app && opt.bootloader)) usage();
    if (opt.load_ratio > 0.0 && opt.friction != 0.0) {
        fprintf(stderr, "jl_simavr: the flexible load (--load-ratio) has no Coulomb friction: --friction must be 0\n");
        _exit(2);
    }
    if (opt.trace_path && !(trace_file = fopen(opt.trace_path, "w"))) {
        fprintf(stderr, "jl_simavr: cannot write the trace %s: %s\n", opt.trace_path, strerror(errno));
        _exit(2);
    }
    /* Handlers first: a stats request (SIGUSR1) may come as soon as the pty is printed. */
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    sigaction(SIGHUP, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);                  /* a launcher that stopped reading must not kill us */
    prctl(PR_SET_PDEATHSIG, SIGTERM);          /* never outlive the process that started us */

    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (opt.no_app) {
        strcpy(fw.mmcu, "atmega328p");
        fw.frequency = 16000000;
    } else if (elf_read_firmware(opt.elf, &fw) != 0) {
        fprintf(stderr, "jl_simavr: cannot read firmware %s\n", opt.elf);
        _exit(1);
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) { fprintf(stderr, "jl_simavr: no atmega328p core in simavr\n"); _exit(1); }
    avr_init(avr);
    avr->frequency = 16000000;
    avr->sleep = sleep_hook;
    avr->run = run_hook;
    avr_load_firmware(avr, &fw);
    avr->frequency = 16000000;
    if (opt.bootloader && load_bootloader(opt.bootloader) != 0) _exit(1);

    /* pitfall: a low INT0/INT1 pin would start a level-trigger poll every cycle */
    avr_extint_set_strict_lvl_trig(avr, 0, 0);
    avr_extint_set_strict_lvl_trig(avr, 1, 0);

    irq_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    irq_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3);
    quads_per_rad = 4.0 * opt.ppr / (2.0 * M_PI);
    theta = omega = theta_l = omega_l = 0.0;
    q_now = 1;                                   /* A high, B low at theta = 0 */
    avr_ioport_external_t ext = {0};
    ext.name = 'D';
    ext.mask = (1 << 2) | (1 << 3);
    ext.value = (1 << 2);
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('D'), &ext);
    avr_raise_irq(irq_a, 1);
    avr_raise_irq(irq_b, 0);
    avr_ioport_external_t extb = {0};
    extb.name = 'B';
    extb.mask = 1 << 4;                          /* D12 low: "simulated plant" */
    extb.value = 0;
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('B'), &extb);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 4), 0);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 5), probe_cb, NULL);
    avr_irq_register_notify(avr_get_interrupt_irq(avr, 1) + AVR_INT_IRQ_RUNNING, isr_cb, NULL);
    avr_irq_register_notify(avr_get_interrupt_irq(avr, AVR_INT_ANY) + AVR_INT_IRQ_RUNNING, any_isr_cb, NULL);

    if (uart_bridge_init() != 0) _exit(1);
    printf("PTY %s\n", pty_name);
    fflush(stdout);
    ready_fd = dup(1);                           /* "READY" once the firmware's UART receives */
    dup2(2, 1);                                  /* later chatter goes to stderr */

    step_cycles = avr_usec_to_cycles(avr, opt.step_us);
    avr_cycle_timer_register(avr, step_cycles, motor_cb, NULL);
    if (boot_start) {
        /* As after the reset that opening the port causes on an Uno (DTR pulses RESET): Optiboot
         * sees EXTRF and waits for avrdude (about 1 s) before it starts the application. */
        avr->data[MCUSR] = 1 << EXTRF_BIT;
    }

    clock_gettime(CLOCK_MONOTONIC, &wall0);

    int state = cpu_Running;
    avr_cycle_count_t limit = opt.max_seconds > 0 ? (avr_cycle_count_t)(opt.max_seconds * avr->frequency) : 0;
    while (!want_exit) {
        state = avr_run(avr);
        if (boot_start && avr->pc == boot_start) after_reset();
        if (state == cpu_Done || state == cpu_Crashed) break;
        if (want_stats) { want_stats = 0; write_stats(); }
        if (limit && avr->cycle >= limit) break;
    }
    write_stats();
    fprintf(stderr, "jl_simavr: stopped after %.3f s simulated (%s)\n", sim_seconds(),
            state == cpu_Crashed ? "firmware crashed" : state == cpu_Done ? "firmware stopped" : "signal/limit");
    fflush(stderr);
    _exit(state == cpu_Crashed ? 3 : 0);
}
