// The rig's run state machine (firmware/PROTOCOL.md "Device state machine"): command
// handling with parameter checks, closed-loop runs, open-loop steps, telemetry and the host
// watchdog. Portable: the hardware is reached only through the Hal interface, so the same
// code runs on the Uno and in the host test driver.
#ifndef JL_DEVICE_H
#define JL_DEVICE_H
#include <stddef.h>
#include <stdint.h>
#include "jl_control.h"
#include "jl_excite.h"
#include "jl_frame.h"
#include "jl_planner.h"
#include "jl_protocol.h"

namespace jl {

/// What the state machine needs from the board. On the AVR the functions of the one board the
/// firmware runs on, static and bound at link time (jerklab_rig.ino defines them: direct calls,
/// no vtable in the Uno's RAM); elsewhere an interface the host test driver implements
/// (firmware/host/jl_host.cpp).
#if defined(__AVR__)
#define JL_HAL_FN(decl) static decl
#else
#define JL_HAL_FN(decl) virtual decl = 0
#endif
class Hal {
public:
    /// Send one frame to the host (PROTOCOL.md framing: sync, len, type, seq, payload, CRC),
    /// payload_len <= kMaxPayload; may block until the transmit buffer has room. One call per
    /// frame: the Uno encodes it straight into its UART ring (encode_frame_ring), the host
    /// driver with encode_frame.
    JL_HAL_FN(void write_frame(uint8_t type, uint8_t seq, const uint8_t* payload, uint8_t payload_len));
    /// Encoder count (atomic read).
    JL_HAL_FN(int32_t counts());
    JL_HAL_FN(void zero_counts());
    /// Quadrature decoding: 1 (A rising), 2 (A both edges) or 4 (A and B both edges).
    JL_HAL_FN(void set_decoding(uint8_t decoding));
    /// Signed PWM output in ticks (-pwm_max..pwm_max); 0 stops the motor.
    JL_HAL_FN(void set_pwm(int16_t pwm));
    /// Control period in timer ticks; restarts the tick phase so sample 0 comes one period later.
    JL_HAL_FN(void set_period(uint16_t ticks));
    /// Milliseconds since boot (wraps).
    JL_HAL_FN(uint32_t millis());
    /// True when the motor is a model (simavr harness, host test driver).
    JL_HAL_FN(bool simulated_plant());
};
#undef JL_HAL_FN

/// A TELEMETRY payload as it goes on the wire (PROTOCOL.md: u32 index, f32 reference, i32 counts,
/// i16 pwm, u8 flags; little-endian, no padding, as the AVR and the hosts store them): the control
/// step fills it and sends its bytes as they are (no per-field copy into a buffer).
struct __attribute__((packed)) TelemetryPayload {
    uint32_t index;
    float ref;
    int32_t counts;
    int16_t pwm;
    uint8_t flags;
};
static_assert(sizeof(TelemetryPayload) == kLenTelemetry, "TELEMETRY's payload: 15 bytes");


struct DeviceConfig {
    uint16_t tick_us;        // hardware tick (1000 on the Uno)
    uint16_t pwm_max;        // PWM full scale in ticks (1023 for Timer1 10-bit)
    uint16_t encoder_ppr;    // pulses per revolution of one channel (448 on the paper's motor)
    uint8_t fw_major, fw_minor, fw_patch;
};

/// The device's settings (plant, limits, gains, safety stops) in one block: Device's
/// constructor copies their boot values (PROTOCOL.md: the defaults at boot, no gains, no plan)
/// from one image in flash, kBootSettings in jl_device.cpp (a fraction of the flash of a store
/// per member). Device's members, as its private base. Packed, with the plant in SET_PLANT's
/// layout and the limits in SET_LIMITS' (PROTOCOL.md; little-endian as the AVR and the hosts):
/// those commands copy their checked payloads as they are.
struct __attribute__((packed)) DeviceSettings {
    float K_, tau_, supply_;           // 32.4 rad/(V s), 0.025 s, 12 V
    uint16_t counts_per_rev_;          // 448
    int16_t pwm_top_;   // lround(max_voltage * pwm_max / supply), at most pwm_max (1023)
    float max_jerk_, max_accel_, max_velocity_, max_voltage_;   // 2e4, 300, 100, 12
    uint16_t host_timeout_ms_;         // 1000
    // Safety stops (PROTOCOL.md "Safety stops"): tracking-error limit (rad, 0 = off) and the
    // runaway / no-motion window (ms, 0 = off).
    uint32_t max_error_bits_;          // IEEE bits of max_error (0.5 rad at boot)
    uint16_t runaway_ms_;              // 200
    uint16_t saturation_ms_;           // saturation stop window (ms, 0 = off; 500)
    uint16_t Ts_us_;                   // 5000
    float Ts_;                         // 0.005
    uint8_t loop_;                     // kLoopPosition
    bool use_ff_;                      // true
};
static_assert(offsetof(DeviceSettings, counts_per_rev_) == kLenSetPlant - 2 &&
                  offsetof(DeviceSettings, saturation_ms_) - offsetof(DeviceSettings, max_jerk_) ==
                      kLenSetLimits - 2 &&
                  offsetof(DeviceSettings, max_error_bits_) - offsetof(DeviceSettings, max_jerk_) == 18,
              "DeviceSettings: SET_PLANT's and SET_LIMITS' payload layouts");

/// The safety stops' state during a run (PROTOCOL.md "Safety stops"), zeroed at its start
/// (Device::arm_safety, one memset): the count of the previous sample, the last PWM applied, the
/// runaway window (drive sign, samples in it, counts moved along the drive) and the saturation
/// level (counts up at a clamped sample, down at another). Device's members, as a private base.
struct SafetyState {
    int32_t prev_counts_ JL_ZERO;
    int16_t last_pwm_ JL_ZERO;
    int8_t run_sign_ JL_ZERO;
    uint16_t run_len_ JL_ZERO;
    int32_t moved_ JL_ZERO;
    uint16_t sat_level_ JL_ZERO;
};

/// HOST_LOOP's state (PROTOCOL.md "Host-in-the-loop"): the timely HOST_VOLTAGE for the next tick
/// (its reference in rad, its PWM, bits in `got`: 1 the reference is valid, 2 it arrived, 4 its
/// nonzero voltage is at the clamp), the one in effect (`ref`, `pwm`: held on a miss, bits in
/// `cur`), the misses so far and in a row (`run`) with their limit (`max`).
struct HostLoopState {
    float next_ref, ref;
    int16_t next_pwm, pwm;
    uint16_t misses;
    uint8_t got, cur, run, max;
};

class Device : private DeviceSettings, private SafetyState {
public:
    /// Stores the Hal's reference and a copy of cfg only (safe for a global object built before
    /// main()). cfg is read with jl_memcpy_P: on the AVR it is in flash (JL_PROGMEM, no RAM).
    __attribute__((noinline, noclone)) Device(Hal& hal, const DeviceConfig& cfg);
    /// Boot state (PROTOCOL.md): PWM 0, default plant, period Ts = 5 ms. Call from setup().
    void begin();
    /// Feed one received byte (from loop()).
    void on_byte(uint8_t b);
    /// No byte for a while (the firmware calls this after 20 ms of silence): abandon the
    /// partial frame and re-scan its bytes after the first sync byte.
    void on_rx_idle();
    /// The control computation of one tick (planner, controller, PWM write); returns true
    /// when a sample was produced and report() should be called.
    bool control();
    /// The reference of the next sample (position, velocity, feedforward: the planner's sample,
    /// SET_SHAPER's FIR): part of the timed control step, after control().
    void reference();
    /// Telemetry / end-of-run frames of the last control().
    void report();
    /// Work in the idle time after the control step (the next sample's reference in rad for its
    /// telemetry, the planner's next chunk, re-targeting, the shaper's delayed taps); call after
    /// report() and before the next control().
    void background();
    /// Host watchdog check (call often from loop()).
    void poll();
    /// A tick started before the previous one was handled.
    void count_overrun() { if (overruns_ < 0xFFFF) ++overruns_; }

    enum State : uint8_t { kIdle = 0, kRunning = 1, kStepping = 2, kHostLooping = 3 };
    State state() const { return state_; }
    uint16_t rx_errors() const { return parser_.dropped(); }

private:
    void dispatch();
    void handle(const Frame& f);
    void plan_frame(const Frame& f);
    void send(uint8_t type, uint8_t seq, const uint8_t* payload, uint8_t n);
    void ack(const Frame& f);
    void nack(const Frame& f, uint8_t err, uint8_t param = 0xFF);
    void end_run(uint8_t reason, float detail = 0.0f);
    uint8_t check_safety(int32_t c, int32_t pos_error, float* detail);
    void apply_plant();
    int16_t volts_to_pwm(float u) const;
    int16_t ticks_to_pwm(float u) const;
    void sample_ahead();
    void handle_retarget(const Frame& f);
    bool retarget_work();
    Plan* free_plan() { return cur_plan_ == &plan_ ? &plan_b_ : &plan_; }
    void update_pwm_top();
    // Version 3 (jl_excite): SEQUENCE and SET_SHAPER; false if the frame was not one of them.
    bool handle_v3(const Frame& f);
    // Version 4: HOST_LOOP, HOST_VOLTAGE (false if the frame was neither); a tick of the mode
    // is control()'s, as a run's sample, with host_tick() and send_host_sample().
    bool handle_v4(const Frame& f);
    // Version 5: PLAN_SEGMENT, PLAN_COMMIT (false if the frame was neither); the segments are
    // checked and stored by plan_frame(), as PLAN is planned there.
    bool handle_v5(const Frame& f);
    void plan_info(const Frame& f);
    int32_t host_tick(int32_t c, uint8_t* flags);
    void send_host_sample();
    // The safety stops' state for a RUN or a HOST_LOOP; the start of any run (STEP, SEQUENCE too).
    void arm_safety(uint16_t ts_us);
    void start(uint16_t ts_us, uint32_t n_total, uint8_t dec, uint8_t state);

    Hal& hal_;
    DeviceConfig cfg_;
    FrameParser parser_;
    State state_ JL_ZERO;
    uint8_t tx_seq_ JL_ZERO;
    // (plant, limits, the period of the gains, safety stops: DeviceSettings)
    float rad_per_count_ JL_ZERO, pwm_per_volt_ JL_ZERO;
    int32_t emax_q_ JL_ZERO;           // max_error in encoder counts, Q16.16 (set at RUN, HOST_LOOP)
    bool gains_ok_ JL_ZERO;
    float kpd_ JL_ZERO, kid_ JL_ZERO, kdd_ JL_ZERO, gamma_ JL_ZERO;

    bool plan_ok_ JL_ZERO;
    bool plan_pending_ JL_ZERO;   // a checked PLAN (PLAN_SEGMENT, PLAN_COMMIT) waits for plan_frame()
    Plan plan_;
    HostPlanner host_plan_ JL_ZERO;   // version 5: the host's segments received into plan_
    // Re-targeting (PROTOCOL.md "Re-targeting"): the host's new plan arrives during the run
    // (PLAN_SEGMENT, RETARGET) in the buffer the stepper does not use; rt_stage_ 0 none, 4 the
    // stepper prepares its first chunk (background()), 5 scheduled. rt_gen_: re-targeted plans
    // that took over in this run (mod 256, RETARGET's base); rt_hold_: the pending plan brakes
    // (the run holds at its end), rt_hold_run_: the running one does.
    // (plan_b_ is written and read in a RUN only, hl_ in a HOST_LOOP only, the open-loop state
    // in a STEP or SEQUENCE only: they share bytes; each mode sets its own at its start)
    union {
        Plan plan_b_;
        HostLoopState hl_;                 // HOST_LOOP's state (a HOST_LOOP only)
        // STEP and SEQUENCE (state kStepping; both set all of it at their start): seq_on_ a
        // SEQUENCE, then the PRBS, its two PWM levels and their commanded volts; else a STEP's
        // PWM (step_pwm_). (No initialisers: members of a union.)
        struct {
            bool seq_on_;
            Prbs prbs_;
            int16_t seq_pwm_[2];
            float seq_volts_[2];
            int16_t step_pwm_;
        };
    };
    const Plan* cur_plan_ = &plan_;
    uint32_t rt_switch_ JL_ZERO;           // the sample the pending plan takes over at
    uint8_t rt_stage_ JL_ZERO, rt_gen_ JL_ZERO;
    bool rt_hold_ JL_ZERO, rt_hold_run_ JL_ZERO;
    bool rt_active_ JL_ZERO;               // the run's plan buffers were written (PLAN again after it)
    uint16_t settle_ JL_ZERO;
    uint32_t plan_samples_ JL_ZERO;

    // The reference of the next sample (counts, Q32.32 as the planner samples it), its velocity
    // (counts per sample, the velocity loop only: the stepper's float, ref_vq_ in Q16.16, or the
    // shaper's) and feedforward (PWM ticks, Q16.16), computed ahead by reference() after the
    // previous step.
    Q32 refq_ JL_ZERO;
    int32_t ufq_ JL_ZERO;
    union {
        float ref_v_;       // (the stepper's, then converted in place: ref_vq_)
        int32_t ref_vq_;
    };
    bool ahead_ JL_ZERO;

    // Active run / step.
    PlanStepper stepper_;
    PidQ pid_;
    Feedforward ff_;
    uint32_t k_ JL_ZERO, n_total_ JL_ZERO;
    uint8_t decimation_ = 1;
    uint8_t dec_left_ JL_ZERO;
    uint32_t last_rx_ms_ JL_ZERO;
    uint16_t overruns_ JL_ZERO;
    // Runaway detector: the drive threshold and the window length in samples (the window's
    // state: SafetyState); the saturation stop's window.
    int16_t runaway_pwm_ = 512;
    uint16_t runaway_n_ JL_ZERO;
    uint16_t sat_n_ JL_ZERO;

    // Version 3: the input shaper of the run reference (SEQUENCE's state: the union above).
    Shaper shaper_;
    QGain shp_kv_ JL_ZERO, shp_ka_ JL_ZERO;   // feedforward ticks per (count/sample), per (count/sample^2)

    // Results of the last control() for report().
    bool have_sample_ JL_ZERO;
    bool finished_ JL_ZERO;
    // (the TELEMETRY payload itself: report() sends its bytes; ref: a run's reference in rad,
    // converted a period ahead by background(), by RUN for sample 0; SEQUENCE: V)
    // (HOST_LOOP: the HOST_SAMPLE's fields, sent by send_host_sample())
    TelemetryPayload rep_ JL_ZERO;
    uint8_t end_reason_ JL_ZERO;          // (kEndDone)
    float end_detail_ JL_ZERO;
};

}  // namespace jl
#endif
