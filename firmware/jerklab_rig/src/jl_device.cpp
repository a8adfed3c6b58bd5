#include "jl_device.h"
#include "jl_port.h"
#include "jl_fixed.h"

namespace jl {

static float q32_counts_to_rad(const Q32& x, float rad_per_count);

// (constant tables in flash: RAM is the Uno's scarcest resource)
static const char kName[16] JL_PROGMEM = {'j', 'e', 'r', 'k', 'l', 'a', 'b', '-', 'u', 'n', 'o', 0, 0, 0, 0, 0};

// (out of line, `this` a pointer: the members' initial values as indexed stores, about half
// the flash of the absolute stores of a static object's inlined initialisation)
// The settings' boot values (DeviceSettings, in its order).
static const DeviceSettings kBootSettings JL_PROGMEM = {
    32.4f, 0.025f, 12.0f,              // K, tau, supply
    448,                               // counts_per_rev
    1023,                              // pwm_top
    2e4f, 300.0f, 100.0f, 12.0f,       // max_jerk, max_accel, max_velocity, max_voltage
    1000,                              // host_timeout_ms
    0x3F000000UL,                      // max_error 0.5 rad
    200, 500,                          // runaway_ms, saturation_ms
    5000, 0.005f,                      // Ts_us, Ts
    kLoopPosition, true,               // loop, use_ff
};

__attribute__((noinline, noclone)) Device::Device(Hal& hal, const DeviceConfig& cfg) : hal_(hal) {
    jl_memcpy_P(&cfg_, &cfg, sizeof(cfg_));     // (in flash on the AVR)
    jl_memcpy_P(static_cast<DeviceSettings*>(this), &kBootSettings, sizeof(DeviceSettings));
}

void Device::begin() {
    apply_plant();
    hal_.set_pwm(0);
    hal_.set_period(static_cast<uint16_t>(Ts_us_ / cfg_.tick_us));
}

void Device::apply_plant() {
    rad_per_count_ = kTwoPi / static_cast<float>(counts_per_rev_);
    pwm_per_volt_ = static_cast<float>(cfg_.pwm_max) / supply_;
    update_pwm_top();
    ff_.set(K_, tau_);
    // counts_per_rev = ppr x decoding picks the decoding; any other value means a different
    // encoder, read with x1 decoding (its ppr is then counts_per_rev).
    uint8_t dec = 1;
    if (counts_per_rev_ == 2u * cfg_.encoder_ppr) dec = 2;
    else if (counts_per_rev_ == 4u * cfg_.encoder_ppr) dec = 4;
    hal_.set_decoding(dec);
}

void __attribute__((noinline)) Device::update_pwm_top() {
    // lround(max_voltage * pwm_max / supply), at most pwm_max (the rounding of ticks_to_pwm)
    pwm_top_ = static_cast<int16_t>(cfg_.pwm_max);
    pwm_top_ = volts_to_pwm(max_voltage_);
}

// lround(u) clamped to +-pwm_top (jl_fixed's byte-level rounding, no soft float)
int16_t Device::ticks_to_pwm(float u) const { return round_clamp(u, pwm_top_); }

int16_t __attribute__((noinline)) Device::volts_to_pwm(float u) const { return ticks_to_pwm(u * pwm_per_volt_); }

void Device::send(uint8_t type, uint8_t seq, const uint8_t* payload, uint8_t n) {
    hal_.write_frame(type, seq, payload, n);
}

void Device::ack(const Frame& f) { send(kAck, f.seq, &f.type, 1); }

void Device::nack(const Frame& f, uint8_t err, uint8_t param) {
    uint8_t p[3] = {f.type, err, param};
    send(kNack, f.seq, p, 3);
}

// The frame the parser holds (on_byte, on_rx_idle: one out-of-line copy).
void __attribute__((noinline)) Device::dispatch() {
    last_rx_ms_ = hal_.millis();
    handle(parser_.frame());
    if (plan_pending_) plan_frame(parser_.frame());
}

void Device::on_byte(uint8_t b) {
    if (!parser_.feed(b)) return;
    do dispatch(); while (parser_.process());
}

void Device::on_rx_idle() {
    while (parser_.pending()) {
        parser_.abandon();
        while (parser_.process()) dispatch();
    }
}

void Device::end_run(uint8_t reason, float detail) {
    hal_.set_pwm(0);
    uint8_t p[kLenEndOfRun];
    p[0] = reason;
    put_u32(p + 1, k_);
    put_u16(p + 5, parser_.dropped());
    // overruns: late ticks, and chunk changes the idle-time preparation did not keep up with
    put_u16(p + 7, static_cast<uint16_t>(overruns_ + (state_ == kRunning ? stepper_.misses() : 0u)));
    put_f32(p + 9, detail);
    state_ = kIdle;
    have_sample_ = false;
    finished_ = false;
    if (rt_active_) plan_ok_ = false;      // a re-targeted run may have planned into plan_
    rt_active_ = false;
    rt_stage_ = 0;
    send(kEndOfRun, tx_seq_++, p, kLenEndOfRun);
}

// d + frac / 2^32 counts (frac: a Q32.32's fraction word) in Q16.16, floored to 2^-16 count:
// d's low half and frac's high half; saturated to +-(2^31 - 1) beyond +-2^15 counts.
static inline int32_t counts_q16(int32_t d, uint32_t frac) {
    if (d >= 32768L) return 0x7FFFFFFFL;
    if (d < -32768L) return -0x7FFFFFFFL;
    return static_cast<int32_t>((static_cast<uint32_t>(d) << 16) | (frac >> 16));
}

// ceil(ms * 1000 / Ts_us): a safety window in samples (0 = off); at most 65535 as Ts >= 1 ms.
static uint16_t __attribute__((noinline)) window_samples(uint16_t ms, uint16_t ts_us) {
    return static_cast<uint16_t>((static_cast<uint32_t>(ms) * 1000u + ts_us - 1u) / ts_us);
}

static const float kFloatMax = 3.40282347e38f;

static bool valid_period(uint16_t ts_us, uint16_t tick_us) {
    return ts_us != 0 && ts_us <= 65000u && ts_us % tick_us == 0;
}

// The rest of PLAN, PLAN_SEGMENT and PLAN_COMMIT (the frame handle() checked): plan (or store
// the host's segment), then PLAN_INFO (ACK) or the NACK.
void __attribute__((noinline)) Device::plan_frame(const Frame& f) {
    plan_pending_ = false;
    const uint8_t* p = f.payload;
    if (f.type == kPlanSegment) {
        HostSegment s;
        memcpy(&s, p, sizeof(s));
        // idle: the plan is rebuilt in place; in a run (re-targeting): into the buffer the
        // stepper does not use, a pending switch to it cancelled by index 0
        const bool run = state_ == kRunning;
        const uint8_t bad = host_plan_.add(run ? free_plan() : &plan_, s);
        if (bad != 0xFF) { nack(f, kErrBadValue, bad); return; }
        if (run) {
            if (s.index == 0 && rt_stage_ != 0) {
                // the pending switch is cancelled: the run ends with its plan again
                stepper_.cancel_switch();
                rt_stage_ = 0;
                n_total_ = rt_hold_run_ ? 0xFFFFFFFFUL : plan_samples_ + shaper_.max_delay() + settle_;
            }
            rt_active_ = true;
        } else {
            plan_ok_ = false;
        }
        ack(f);
        return;
    }
    if (f.type == kPlanCommit) {
        HostCommit c;
        memcpy(&c, p, sizeof(c));
        const uint8_t bad = host_plan_.check(c);
        if (bad != 0xFF) { nack(f, kErrBadValue, bad); return; }
        host_plan_.commit(&plan_, c);
        plan_info(f);
        return;
    }
    host_plan_.count = 0;                 // (planned into the buffer of the host's segments)
    if (plan_kind(p[4], get_f32(p), max_jerk_, max_accel_, max_velocity_, &plan_) != kPlanOk) {
        nack(f, kErrBadValue, 0);
        return;
    }
    plan_info(f);
}

// A plan of duration t lasts ceil(x) + 1 samples, x = t / Ts - 1e-4 (PROTOCOL.md: PLAN's
// n_samples): samples_x(t, Ts) is x, samples_of(x) the count for a finite x below 2^32
// (PLAN_INFO's, and a re-targeted plan's when it takes over). Out of line: one copy each.
static float __attribute__((noinline)) samples_x(float t, float Ts) { return t / Ts - 1e-4f; }

static uint32_t __attribute__((noinline)) samples_of(float x) {
    uint32_t n = static_cast<uint32_t>(x < 0.0f ? 0.0f : x);
    if (static_cast<float>(n) < x) ++n;           // ceil
    return n + 1;
}

// PLAN_INFO of the plan in plan_ (PLAN, PLAN_COMMIT), or NACK TOO_LONG (the plan dropped).
void __attribute__((noinline)) Device::plan_info(const Frame& f) {
    const float x = samples_x(plan_.duration, Ts_);
    // n = ceil(x) + 1 must stay <= kMaxPlanSamples (float32 holds 2e9 - 1 as 2e9).
    if (!finite_f(x) || x >= static_cast<float>(kMaxPlanSamples)) { nack(f, kErrTooLong, 0); return; }
    plan_samples_ = samples_of(x);
    plan_ok_ = true;
    uint8_t r[kLenPlanInfo];
    static_assert(offsetof(Plan, cruise_time) == offsetof(Plan, accel_time) + 4,
                  "Plan: accel_time, cruise_time adjacent, as in PLAN_INFO");
    memcpy(r, &plan_.accel_time, 8);              // accel_time, cruise_time
    put_f32(r + 8, plan_.duration);
    put_u32(r + 12, plan_samples_);
    send(kPlanInfo, f.seq, r, kLenPlanInfo);
}

// (noinline, noclone: `this` stays a pointer, not the static Device's constant address, so that
// the settings' members are 2-byte displacement loads and stores, not 4-byte absolute ones)
void __attribute__((noinline, noclone)) Device::handle(const Frame& f) {
    if (handle_v3(f) || handle_v4(f) || handle_v5(f)) return;
    const uint8_t* p = f.payload;
    static const uint8_t kLen[10] JL_PROGMEM = {0, kLenHello, kLenSetPlant, kLenSetGains, kLenSetLimits,
                                     kLenPlan, kLenRun, kLenStop, kLenStep, kLenHeartbeat};
    if (f.type == kRetarget) { handle_retarget(f); return; }
    if (f.type == 0 || f.type > kHeartbeat) { nack(f, kErrUnknownType); return; }
    if (f.len != JL_READ_U8(&kLen[f.type])) { nack(f, kErrBadLength); return; }
    const bool active = state_ != kIdle;
    if (active && f.type != kHello && f.type != kStop && f.type != kHeartbeat) {
        nack(f, kErrBusy);
        return;
    }
    switch (f.type) {
    case kHello: {
        uint8_t r[kLenHelloReply];
        uint16_t caps = kCapSineJerk | kCapRetarget | kCapLoopPosition | kCapLoopVelocity |
                        kCapOpenLoopStep | kCapFeedforward | kCapHostSegments;
        if (JL_WITH_BOARD_PLANNERS) caps |= kCapSineJerkOptimal | kCapScurve | kCapTrapezoid;
        if (JL_WITH_SEQUENCE) caps |= kCapSequence;
        if (JL_WITH_SHAPER) caps |= kCapShaper;
        if (JL_WITH_HOST_LOOP) caps |= kCapHostLoop;
        if (hal_.simulated_plant()) caps |= kCapSimulatedPlant;
        r[0] = kProtocolVersion;
        r[1] = cfg_.fw_major;
        r[2] = cfg_.fw_minor;
        r[3] = cfg_.fw_patch;
        put_u16(r + 4, caps);
        put_u16(r + 6, cfg_.tick_us);
        put_u16(r + 8, cfg_.pwm_max);
        jl_memcpy_P(r + 10, kName, 16);
        send(kHelloReply, f.seq, r, kLenHelloReply);
        return;
    }
    case kSetPlant: {
        float K = get_f32(p), tau = get_f32(p + 4), vs = get_f32(p + 8);
        uint16_t cpr = get_u16(p + 12);
        if (!positive_le(K, 1e4f)) { nack(f, kErrBadValue, 0); return; }
        if (!positive_le(tau, 10.0f)) { nack(f, kErrBadValue, 1); return; }
        if (!positive_le(vs, 48.0f)) { nack(f, kErrBadValue, 2); return; }
        if (cpr < 1) { nack(f, kErrBadValue, 3); return; }
        memcpy(&K_, p, kLenSetPlant);    // K_, tau_, supply_, counts_per_rev_: the payload's layout
        apply_plant();
        ack(f);
        return;
    }
    case kSetGains: {
        float kpd = get_f32(p), kid = get_f32(p + 4), kdd = get_f32(p + 8);
        uint16_t ts = get_u16(p + 12);
        uint8_t loop = p[14], flags = p[15];
        float gamma = get_f32(p + 16);
        if (!finite_f(kpd)) { nack(f, kErrBadValue, 0); return; }
        if (!finite_f(kid)) { nack(f, kErrBadValue, 1); return; }
        if (!finite_f(kdd)) { nack(f, kErrBadValue, 2); return; }
        if (!valid_period(ts, cfg_.tick_us)) { nack(f, kErrBadValue, 3); return; }
        if (loop > kLoopVelocity) { nack(f, kErrBadValue, 4); return; }
        if (flags & ~kGainsFeedforward) { nack(f, kErrBadValue, 5); return; }
        if (!abs_lt(gamma, 1.0f)) { nack(f, kErrBadValue, 6); return; }
        gamma_ = gamma;
        kpd_ = kpd; kid_ = kid; kdd_ = kdd; Ts_us_ = ts;
        Ts_ = static_cast<float>(ts) * 1e-6f;
        loop_ = loop;
        use_ff_ = (flags & kGainsFeedforward) != 0;
        gains_ok_ = true;
        plan_ok_ = false;
        ack(f);
        return;
    }
    case kSetLimits: {
        float J = get_f32(p), E = get_f32(p + 4), W = get_f32(p + 8), vmax = get_f32(p + 12);
        float emax = get_f32(p + 18);
        if (!positive_le(J, kFloatMax)) { nack(f, kErrBadValue, 0); return; }
        if (!positive_le(E, kFloatMax)) { nack(f, kErrBadValue, 1); return; }
        if (!positive_le(W, kFloatMax)) { nack(f, kErrBadValue, 2); return; }
        if (!positive_le(vmax, supply_)) { nack(f, kErrBadValue, 3); return; }
        if (!nonneg_f(emax)) { nack(f, kErrBadValue, 5); return; }   // (0: the stop off)
        // max_jerk_ .. saturation_ms_ (max_error_bits_: emax >= 0, 0 (off) or the positive
        // pattern) in the payload's layout
        memcpy(&max_jerk_, p, kLenSetLimits);
        if (max_error_bits_ == 0x80000000UL) max_error_bits_ = 0;   // -0.0
        update_pwm_top();
        plan_ok_ = false;
        ack(f);
        return;
    }
    case kPlan: {
        float d = get_f32(p);
        uint8_t kind = p[4];
        if (!positive_le(jl_fabsf(d), 1e6f)) { nack(f, kErrBadValue, 0); return; }
        if (kind > kPlannerTrapezoid) { nack(f, kErrBadValue, 1); return; }
        // (built without the board planners 1-3: the host sends their segments)
        if (!JL_WITH_BOARD_PLANNERS && kind != kPlannerSineJerk) { nack(f, kErrUnsupported, 1); return; }
        plan_ok_ = false;            // planned in place (a Plan is ~220 bytes of RAM)
        // planned by plan_frame() once handle() has returned: the planners' deep float calls
        // then do not stack on handle()'s frame (PLAN is the deepest stack of the firmware)
        plan_pending_ = true;
        return;
    }
    case kRun: {
        uint16_t settle = get_u16(p);
        uint8_t dec = p[2];
        if (dec < 1) { nack(f, kErrBadValue, 1); return; }
        if (!gains_ok_ || !plan_ok_) { nack(f, kErrNotReady); return; }
        // The loop runs in encoder counts and PWM ticks (saves two float multiplies a sample):
        // the gains take rad per count (and 1/Ts in the velocity loop) and PWM ticks per volt.
        const float g_pos = rad_per_count_ * pwm_per_volt_;
        const float g = loop_ == kLoopVelocity ? g_pos / Ts_ : g_pos;
        if (!pid_.set(kpd_ * g, kid_ * g, kdd_ * g, gamma_, max_voltage_ * pwm_per_volt_)) {
            nack(f, kErrBadValue);
            return;
        }
        if (shaper_.on()) {
            // SET_SHAPER's fixed-point FIR (jl_excite.h): the reference moves at most
            // max_velocity Ts counts a sample, within the ring's Q16.16 windows; the
            // feedforward of its differences as gains of PWM ticks per count / sample (^2)
            const float h = g_pos / Ts_;
            if (!shaper_.fits(max_velocity_ * Ts_ / rad_per_count_) ||
                (use_ff_ && (!to_qgain(ff_.beta() * h, &shp_kv_) || !to_qgain(ff_.alpha() * h / Ts_, &shp_ka_)))) {
                nack(f, kErrBadValue);
                return;
            }
        }
        ack(f);
        pid_.reset();
        cur_plan_ = &plan_;
        rt_stage_ = 0;
        rt_gen_ = 0;
        rt_hold_ = rt_hold_run_ = false;
        rt_active_ = false;
        host_plan_.count = 0;
        settle_ = settle;
        {
            const float cpr = 1.0f / rad_per_count_;
            stepper_.start(plan_, Ts_, use_ff_ ? ff_.alpha() * pwm_per_volt_ : 0.0f,
                           use_ff_ ? ff_.beta() * pwm_per_volt_ : 0.0f, cpr, cpr * Ts_);
            ufq_ = 0;
            ref_vq_ = 0;
            // SET_SHAPER: the FIR runs on the reference in counts, its differences per sample;
            // the feedforward in PWM ticks from them: uf = ka (v_k - v_{k-1}) + kv v_k
            shaper_.reset();
            sample_ahead();                     // the reference of sample 0
            rep_.ref = q32_counts_to_rad(refq_, rad_per_count_);   // (then in background())
            shaper_.prepare();                  // (then in background() after each step)
        }
        arm_safety(Ts_us_);
        // the shaper lengthens the move
        start(Ts_us_, plan_samples_ + shaper_.max_delay() + settle, dec, kRunning);
        return;
    }
    case kStop:
        hal_.set_pwm(0);
        ack(f);
        if (active) end_run(kEndStopped);
        return;
    case kStep: {
        float v = get_f32(p);
        uint16_t ts = get_u16(p + 4), n = get_u16(p + 6);
        if (!abs_le(v, max_voltage_)) { nack(f, kErrBadValue, 0); return; }
        if (!valid_period(ts, cfg_.tick_us)) { nack(f, kErrBadValue, 1); return; }
        if (n < 1) { nack(f, kErrBadValue, 2); return; }
        ack(f);
        step_pwm_ = volts_to_pwm(v);
        seq_on_ = false;
        start(ts, n, 1, kStepping);
        return;
    }
    case kHeartbeat:
        ack(f);
        return;
    default:
        nack(f, kErrUnknownType);
        return;
    }
}

// Version 5 commands (PROTOCOL.md "Host-planned segments"): PLAN_SEGMENT and PLAN_COMMIT,
// checked (length, idle) here and handled by plan_frame() once handle() has returned.
bool Device::handle_v5(const Frame& f) {
    if (f.type != kPlanSegment && f.type != kPlanCommit) return false;
    if (f.len != (f.type == kPlanSegment ? kLenPlanSegment : kLenPlanCommit)) { nack(f, kErrBadLength); return true; }
    // (PLAN_SEGMENT also during a run: the plan of a RETARGET)
    if (state_ != kIdle && !(state_ == kRunning && f.type == kPlanSegment)) { nack(f, kErrBusy); return true; }
    plan_pending_ = true;
    return true;
}

// Version 3 commands (PROTOCOL.md "Version 3"): SEQUENCE (open-loop PRBS) and SET_SHAPER.
bool Device::handle_v3(const Frame& f) {
    if (f.type != kSequence && f.type != kSetShaper) return false;
    const uint8_t* p = f.payload;
    if (f.len != (f.type == kSequence ? kLenSequence : kLenSetShaper)) { nack(f, kErrBadLength); return true; }
    if (state_ != kIdle) { nack(f, kErrBusy); return true; }
    if ((f.type == kSequence && !JL_WITH_SEQUENCE) || (f.type == kSetShaper && !JL_WITH_SHAPER)) {
        nack(f, kErrUnsupported);
        return true;
    }
#if JL_WITH_SEQUENCE
    if (f.type == kSequence) {
        float amp = get_f32(p), off = get_f32(p + 4);
        uint16_t ts = get_u16(p + 8), n = get_u16(p + 10), seed = get_u16(p + 12);
        uint8_t order = p[14], hold = p[15];
        if (!nonneg_f(amp)) { nack(f, kErrBadValue, 0); return true; }
        if (!finite_f(off) || !(jl_fabsf(off) + amp <= max_voltage_)) { nack(f, kErrBadValue, 1); return true; }
        if (!valid_period(ts, cfg_.tick_us)) { nack(f, kErrBadValue, 2); return true; }
        if (n < 1) { nack(f, kErrBadValue, 3); return true; }
        if (prbs_mask(order) == 0) { nack(f, kErrBadValue, 5); return true; }
        if ((seed & ((1UL << order) - 1)) == 0) { nack(f, kErrBadValue, 4); return true; }
        if (hold < 1) { nack(f, kErrBadValue, 6); return true; }
        ack(f);
        prbs_.start(seed, order, hold);
        seq_volts_[0] = off - amp;
        seq_volts_[1] = off + amp;
        seq_pwm_[0] = volts_to_pwm(seq_volts_[0]);
        seq_pwm_[1] = volts_to_pwm(seq_volts_[1]);
        seq_on_ = true;
        start(ts, n, 1, kStepping);
        return true;
    }
#endif
#if JL_WITH_SHAPER
    // SET_SHAPER: u8 n_taps, f32 amplitudes[10], u8 delays[10]; taps past n_taps are 0.
    // Checked and quantised by Shaper::load (out of line: handle()'s frame stays small).
    const uint8_t bad = shaper_.load(p);
    if (bad != kShaperOk) { nack(f, kErrBadValue, bad); return true; }
    ack(f);
#endif
    return true;
}

// The start of a RUN, STEP, SEQUENCE or HOST_LOOP (the command checked and acknowledged): the
// encoder zeroed, n_total samples of ts_us from sample 0, TELEMETRY at every dec-th, the tick
// phase restarted (the last thing: sample 0 comes one period after the command's work).
__attribute__((noinline)) void Device::start(uint16_t ts_us, uint32_t n_total, uint8_t dec, uint8_t state) {
    hal_.zero_counts();
    k_ = 0;
    n_total_ = n_total;
    decimation_ = dec;
    dec_left_ = 0;
    have_sample_ = finished_ = false;
    state_ = static_cast<State>(state);
    hal_.set_period(static_cast<uint16_t>(ts_us / cfg_.tick_us));
}

// The safety stops' state (PROTOCOL.md "Safety stops") for a RUN or a HOST_LOOP at Ts = ts_us.
__attribute__((noinline)) void Device::arm_safety(uint16_t ts_us) {
    // the tracking-error limit in counts, Q16.16 (0 = off; from 2^15 counts on never hit)
    float emax_c;
    memcpy(&emax_c, &max_error_bits_, 4);
    emax_q_ = to_q16(emax_c * (1.0f / rad_per_count_));
    if (emax_q_ == 0 && max_error_bits_ != 0) emax_q_ = 1;
    memset(static_cast<void*>(static_cast<SafetyState*>(this)), 0, sizeof(SafetyState));
    runaway_pwm_ = static_cast<int16_t>((pwm_top_ + 1) / 2);
    runaway_n_ = window_samples(runaway_ms_, ts_us);
    sat_n_ = window_samples(saturation_ms_, ts_us);
}

// Version 4 commands (PROTOCOL.md "Host-in-the-loop"): HOST_LOOP starts the mode, HOST_VOLTAGE
// answers its last HOST_SAMPLE (no reply unless refused).
bool Device::handle_v4(const Frame& f) {
    if (f.type != kHostLoop && f.type != kHostVoltage) return false;
    if (f.len != (f.type == kHostLoop ? kLenHostLoop : kLenHostVoltage)) { nack(f, kErrBadLength); return true; }
    if (!JL_WITH_HOST_LOOP) { nack(f, kErrUnsupported); return true; }
#if JL_WITH_HOST_LOOP
    const uint8_t* p = f.payload;
    if (f.type == kHostVoltage) {
        if (state_ != kHostLooping) { nack(f, kErrNotReady); return true; }
        const float v = get_f32(p + 4), ref = get_f32(p + 8);
        const uint8_t fl = p[12] & kHostVoltageReference;
        if (!finite_f(v)) { nack(f, kErrBadValue, 1); return true; }
        if (fl && !finite_f(ref)) { nack(f, kErrBadValue, 2); return true; }
        // in time: it answers the last HOST_SAMPLE (k - 1) before tick k; else dropped
        if (k_ == 0 || get_u32(p) != k_ - 1) return true;
        const int16_t pwm = volts_to_pwm(v);
        // at the clamp: a nonzero voltage whose PWM is at the top (the saturation stop's count)
        const bool sat = v != 0.0f && (pwm >= pwm_top_ || pwm <= -pwm_top_);
        HostLoopState* h = &hl_;
        JL_OPAQUE(h);
        h->next_pwm = pwm;
        h->next_ref = ref;
        h->got = static_cast<uint8_t>(fl | 2u | (sat ? 4u : 0u));
        return true;
    }
    if (state_ != kIdle) { nack(f, kErrBusy); return true; }
    const uint16_t ts = get_u16(p), n = get_u16(p + 2);
    const uint8_t max_misses = p[4];
    if (ts < kHostLoopMinTsUs || ts > kHostLoopMaxTsUs || !valid_period(ts, cfg_.tick_us)) {
        nack(f, kErrBadValue, 0);
        return true;
    }
    if (n < 1) { nack(f, kErrBadValue, 1); return true; }
    if (max_misses < 1) { nack(f, kErrBadValue, 2); return true; }
    ack(f);
    memset(&hl_, 0, sizeof(hl_));       // PWM 0 until the first answer
    hl_.max = max_misses;
    arm_safety(ts);
    start(ts, n, 1, kHostLooping);
#endif
    return true;
}

// The start of a HOST_LOOP tick k (PROTOCOL.md "Host-in-the-loop", step 2): the HOST_VOLTAGE
// answering tick k - 1 in time becomes the voltage in effect, else the last one is held and the
// miss counted (flag bit 0 in *flags). Returns e = reference - c_k in Q16.16 counts when the
// answer in effect carried a reference, else 0 (the tracking-error stop off).
__attribute__((noinline)) int32_t Device::host_tick(int32_t c, uint8_t* flags) {
    HostLoopState* h = &hl_;
    JL_OPAQUE(h);
    if (k_ != 0) {
        if (h->got) {
            h->pwm = h->next_pwm;
            h->ref = h->next_ref;
            h->cur = h->got;
            h->run = 0;
        } else {
            // (neither saturates: misses <= n_samples - 1 < 2^16, and the mode stops when
            // miss_run reaches max_misses <= 255)
            ++h->misses;
            ++h->run;
            *flags = kHostSampleMissed;
        }
    }
    h->got = 0;
    if (!(h->cur & kHostVoltageReference)) return 0;
    return to_q16(h->ref / rad_per_count_ - static_cast<float>(c));
}

// HOST_SAMPLE (u32 index, i32 counts, i16 pwm, u16 misses, u8 miss_run, u8 flags) of the tick
// control() left in rep_, made in rep_'s bytes (the next tick writes all its fields again): the
// count and the PWM moved up over `ref`, the misses and the flags after them.
__attribute__((noinline)) void Device::send_host_sample() {
    uint8_t* b = reinterpret_cast<uint8_t*>(&rep_);
    JL_OPAQUE(b);
    const uint8_t flags = b[14];
    for (uint8_t i = 4; i < 10; ++i) b[i] = b[i + 4];
    put_u16(b + 10, hl_.misses);
    b[12] = hl_.run;
    b[13] = flags;
    send(kHostSample, tx_seq_++, b, kLenHostSample);
}

bool Device::control() {
    if (state_ == kIdle) return false;
    if (k_ >= n_total_) {               // the tick after the last sample
        hal_.set_pwm(0);
        finished_ = true;
        end_reason_ = kEndDone;
        end_detail_ = 0.0f;
        have_sample_ = false;
        return true;
    }
    const int32_t c = hal_.counts();
    int16_t pwm;
    uint8_t flags = 0;
    const bool host = JL_WITH_HOST_LOOP && state_ == kHostLooping;
    if (state_ == kRunning || host) {
        // A run's sample or a HOST_LOOP tick (PROTOCOL.md "Host-in-the-loop", steps 2-4): the
        // same safety stops, saturation count and PWM write
        int32_t pos_error;
        if (host) {
            pos_error = host_tick(c, &flags);
        } else {
            // ref, e in encoder counts (Q32.32, Q16.16); ref_v in counts per sample; uf in PWM
            // ticks (Q16.16): integer arithmetic from the count to the PWM write
            ahead_ = false;             // (sampled by reference() after the previous step, or RUN)
            const Q32 ref = refq_;
            if (k_ >= plan_samples_ + shaper_.max_delay()) flags |= kTelemetrySettling;
            // e = ref - c exactly (floored to 2^-16 count): the integer part's difference and the
            // fraction's top 16 bits, saturated beyond +-2^15 counts
            pos_error = counts_q16(sub_sat(ref.hi, c), ref.lo);
        }
        float detail = 0.0f;
        JL_PART_BEGIN(2);
        uint8_t fault = check_safety(c, pos_error, &detail);
        JL_PART_END(2);
        pwm = 0;
        if (fault == kEndDone && host && hl_.run >= hl_.max) {
            fault = kEndHostMisses;         // max_misses in a row
            detail = static_cast<float>(hl_.run);
        }
        if (fault == kEndDone) {
            bool saturated;
            int32_t u;
            if (host) {
                // the voltage in effect as the PWM write's Q16.16 (exact: within the clamp), so
                // that nothing after the PID depends on the mode
                saturated = (hl_.cur & 4u) != 0;   // a nonzero voltage at the clamp
                u = static_cast<int32_t>(hl_.pwm) * 65536L;
            } else {
                int32_t e;
                if (loop_ == kLoopPosition) {
                    e = pos_error;
                } else {
                    // Velocity loop (Stojčić §4B): counts over the last sample; y(-1) = y(0).
                    if (k_ == 0) prev_counts_ = c;
                    e = sub_sat(ref_vq_, counts_q16(c - prev_counts_, 0));
                }
                JL_PART_BEGIN(4);
                u = pid_.step(e, ufq_, &saturated);
                JL_PART_END(4);
                if (saturated) flags |= kTelemetrySaturated;
            }
            if (saturated) ++sat_level_;
            else if (sat_level_) --sat_level_;
            // Saturation stop (PROTOCOL.md): at the clamp in most samples for the window.
            if (sat_n_ && sat_level_ >= sat_n_) fault = kEndSaturation;
            else {
                JL_PART_BEGIN(5);
                pwm = q16_to_pwm(u, pwm_top_);
                JL_PART_END(5);
            }
        }
        if (fault != kEndDone) {
            // Safety stop: PWM 0 in this very sample; its telemetry goes out whatever the
            // decimation, then END_OF_RUN(reason, samples = k + 1, ..., detail).
            finished_ = true;
            end_reason_ = fault;
            end_detail_ = detail;
            flags |= kTelemetryFault;
        }
        prev_counts_ = c;
        last_pwm_ = pwm;
    } else if (seq_on_) {
        const uint8_t b = prbs_.next();   // SEQUENCE: the PRBS level, its volts as the reference
        pwm = seq_pwm_[b];
        rep_.ref = seq_volts_[b];         // volts, sent as they are (report)
    } else {
        pwm = step_pwm_;
        rep_.ref = 0.0f;
    }
    hal_.set_pwm(pwm);
    // k % decimation == 0, counted down (a 32-bit modulo costs ~600 cycles on the AVR)
    if (dec_left_ == 0) dec_left_ = decimation_;
    have_sample_ = finished_ || dec_left_ == decimation_;
    --dec_left_;
    rep_.index = k_;
    rep_.counts = c;
    rep_.pwm = pwm;
    rep_.flags = flags;
    ++k_;
    return true;
}


void Device::sample_ahead() {
    const bool shaped = shaper_.on();
    // (shaped: the feedforward and velocity come from the shaped reference, not the stepper's)
    stepper_.next_q(&refq_, use_ff_ && !shaped ? &ufq_ : nullptr,
                    loop_ == kLoopVelocity && !shaped ? &ref_v_ : nullptr);
    if (shaped) {
        // SET_SHAPER (PROTOCOL.md): the reference's FIR in fixed point (jl_excite.h: one product
        // here; the delayed taps' part for the next sample in background()) and its backward
        // differences in Q16.16 counts per sample (^2); the feedforward from them
        int32_t a;
        shaper_.apply(&refq_, &ref_vq_, &a);
        if (use_ff_) ufq_ = mac_g(mac_g(0, ref_vq_, shp_kv_), a, shp_ka_);
    } else if (loop_ == kLoopVelocity) {
        ref_vq_ = to_q16(ref_v_);
    }
    ahead_ = true;
    if (stepper_.plan() != cur_plan_) {
        // a re-targeted plan took over at this sample (k_): the run now ends with it
        cur_plan_ = stepper_.plan();
        plan_samples_ = samples_of(samples_x(cur_plan_->t_start + cur_plan_->duration, Ts_));
        // a braking plan (RETARGET flags bit 0) holds the run for the RETARGET that follows
        n_total_ = rt_hold_ ? 0xFFFFFFFFUL : plan_samples_ + shaper_.max_delay() + settle_;
        rt_hold_run_ = rt_hold_;
        rt_stage_ = 0;
        ++rt_gen_;
    }
}

// RETARGET (PROTOCOL.md "Re-targeting"): the host's plan, sent as PLAN_SEGMENTs during the
// run into the buffer the stepper does not use, takes over at the sample the frame names.
void Device::handle_retarget(const Frame& f) {
    if (f.len != kLenRetarget) { nack(f, kErrBadLength); return; }
    if (state_ != kRunning) { nack(f, kErrNotReady); return; }
    RetargetCommit r;
    memcpy(&r, f.payload, sizeof(r));
    // the end of the plan's fields as PLAN_COMMIT's (3 n_segments .. 6 cruise_time)
    const HostCommit c = {r.n_segments, r.target, r.accel_time, r.cruise_time, 0.0f, kPlannerHost};
    const uint8_t bad = host_plan_.check(c);
    if (bad != 0xFF) { nack(f, kErrBadValue, static_cast<uint8_t>(bad + 3)); return; }
    if (r.flags & ~kRetargetHold) { nack(f, kErrBadValue, 7); return; }
    if (!nonneg_f(r.t_switch)) { nack(f, kErrBadValue, 1); return; }
    if (r.base != rt_gen_) { nack(f, kErrLate, 2); return; }    // another plan took over meanwhile
    // where the running plan allows a switch: jerk and acceleration 0, in the cruise (its ends
    // included) or at rest after its end (jerklab.rig.retarget.plan_switch)
    const Plan& cp = *cur_plan_;
    const float tc0 = cp.t_start + cp.accel_time, tc1 = tc0 + cp.cruise_time;
    const float ts = r.t_switch;
    if (!((ts >= tc0 && ts <= tc1) || ts >= cp.t_start + cp.duration)) { nack(f, kErrBadValue, 1); return; }
    if (r.switch_index != first_sample_at(ts, Ts_)) { nack(f, kErrBadValue, 0); return; }
    if (r.switch_index < k_ + kRetargetLead) { nack(f, kErrLate, 0); return; }
    Plan* np = free_plan();
    host_plan_.commit(np, c);
    place(np, ts, 0.0f);                   // (the segments' start states are absolute)
    np->x_start = np->seg[0].x0;
    rt_hold_ = (r.flags & kRetargetHold) != 0;
    rt_active_ = true;
    rt_stage_ = 4;
    rt_switch_ = r.switch_index;
    n_total_ = 0xFFFFFFFFUL;               // the run lasts until the new plan's end
    ack(f);
}

// The re-targeting's work in the idle time: the new plan's first chunk, a stage a tick, then
// scheduled (the stepper switches at its first sample); true when it did something. It yields
// the tick to the running plan's next chunk when that one is pressed (stepper_.pressed()) and
// the switch is more than kRetargetLead samples ahead: from kRetargetLead on (RETARGET's
// least lead, >= the 13 stages of a first chunk) it has every tick, so it is always ready in
// time, and a short segment's chunk change during it is not computed in the tick (an overrun).
bool Device::retarget_work() {
    if (rt_stage_ != 4) return false;
    if (stepper_.pressed() && rt_switch_ > stepper_.index() + kRetargetLead) return false;
    if (stepper_.prepare_switch(*free_plan())) rt_stage_ = 5;
    return true;
}

// A Q32.32 in counts as a float in rad: the widest 32-bit window that holds it (Q16.16 below
// 2^15 counts, else Q24.8, saturated at 2^23 counts: the windows of q32_to_float, as four bytes of
// the little-endian Q32 at offset 2 or 3, no shifts), one int -> float conversion and one float
// multiply by rad_per_count 2^-16 (2^-8), that scale made by the exponent. Bit-exact with
// q32_to_float(x) * rad_per_count (its exponent adjust is the exact 2^-16 / 2^-8, which commutes
// with the one rounding of the multiply; rad_per_count >= 2 pi / 65535, so the scaled constant stays
// a normal float): ~100 cycles less on the AVR (one conversion and one multiply, not a conversion,
// a 32-bit shift-or and a multiply).
static float __attribute__((noinline)) q32_counts_to_rad(const Q32& x, float rad_per_count) {
    const uint8_t* b = reinterpret_cast<const uint8_t*>(&x);   // lo then hi, little-endian
    static_assert(sizeof(Q32) == 8, "Q32: two words, no padding");
    const int32_t hi = x.hi;
    uint32_t s;
    memcpy(&s, &rad_per_count, 4);
    int32_t w;
    s -= 16UL << 23;
    if (static_cast<uint32_t>(hi + 32768L) >= 65536UL) {        // Q24.8 (saturated)
        s += 8UL << 23;
        w = q32_window24(x);
    } else {                                                    // Q16.16
        memcpy(&w, b + 2, 4);
    }
    float scale;
    memcpy(&scale, &s, 4);
    return static_cast<float>(w) * scale;
}

void Device::reference() {
    if (state_ != kRunning || ahead_) return;
    JL_PART_BEGIN(8);
    sample_ahead();
    JL_PART_END(8);
}

void Device::background() {
    if (state_ != kRunning) return;
    JL_PART_BEGIN(9);
    // The next sample's reference (refq_, sampled by reference() in the step just ended) in rad
    // for its TELEMETRY: known a period ahead, so converted here in the idle time (report() of
    // this step has sent the previous one; RUN converts sample 0's). Every sample, whatever the
    // decimation: a safety stop sends the sample it stops at.
    rep_.ref = q32_counts_to_rad(refq_, rad_per_count_);
    shaper_.prepare();                   // the delayed taps' sum for the next sample
    // one more piece of work per tick: the re-targeting, else the next chunk
    if (!retarget_work()) stepper_.prepare();
    JL_PART_END(9);
}

void Device::report() {
    if (have_sample_) {
        have_sample_ = false;
        if (JL_WITH_HOST_LOOP && state_ == kHostLooping) send_host_sample();
        else send(kTelemetry, tx_seq_++, reinterpret_cast<const uint8_t*>(&rep_), kLenTelemetry);
    }
    if (finished_) end_run(end_reason_, end_detail_);
}

// PROTOCOL.md "Safety stops". Called at each run sample k with the count c_k (before the
// controller): the tracking-error limit, then the runaway / no-motion window over the PWM
// applied during the last period (last_pwm_) and the counts it produced (c_k - c_{k-1}).
uint8_t Device::check_safety(int32_t c, int32_t pos_error, float* detail) {
    // |e| > max_error, both in Q16.16 counts: integer compares (e saturates at +-2^15 counts,
    // so a limit from 2^15 counts on is never reached)
    const int32_t lim = emax_q_;
    if (lim != 0 && (pos_error > lim || pos_error < -lim)) {
        *detail = static_cast<float>(pos_error) * (rad_per_count_ * (1.0f / 65536.0f));
        return kEndTrackingError;
    }
    if (runaway_n_ == 0) return kEndDone;
    const int8_t sign = last_pwm_ >= runaway_pwm_ ? 1 : (last_pwm_ <= -runaway_pwm_ ? -1 : 0);
    if (sign == 0) {
        run_sign_ = 0;
        run_len_ = 0;
        moved_ = 0;
        return kEndDone;
    }
    if (sign != run_sign_) {
        run_sign_ = sign;
        run_len_ = 0;
        moved_ = 0;
    }
    moved_ += sign > 0 ? c - prev_counts_ : prev_counts_ - c;
    if (++run_len_ < runaway_n_) return kEndDone;
    const int32_t moved = moved_;
    run_len_ = 0;
    moved_ = 0;
    if (moved > 0) return kEndDone;
    *detail = static_cast<float>(moved);
    return moved < 0 ? kEndRunaway : kEndNoMotion;
}

void Device::poll() {
    if (state_ == kIdle || host_timeout_ms_ == 0) return;
    if (static_cast<uint32_t>(hal_.millis() - last_rx_ms_) > host_timeout_ms_) end_run(kEndHostTimeout);
}

}  // namespace jl
