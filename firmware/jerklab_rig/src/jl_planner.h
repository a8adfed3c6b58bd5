// The rig's planners in float32: Stojčić's published sine-jerk (eqs. 2-4, Fig. 2), the
// time-optimal half-sine-jerk profile, the linear-jerk S-curve and the trapezoid, rest to rest
// (re-targeting's moving start is planned on the host: jerklab.rig.retarget.plan_switch). They mirror
// jerklab.planner (plan_sine_jerk, plan_sine_jerk_optimal, plan_scurve, plan_trapezoid) and the
// closed form of its Profile (docs/THEORY.md; Stojčić eq. 15 is the recursion they replace).
//
// Every plan is a list of at most 7 segments on which the jerk is a constant (linear-jerk,
// plateau, cruise) or a half-sine pulse J sin(w u), w = pi / tj, then the rest at the target;
// each segment stores its start time and start state (the rest: the plan's end and target), so
// a sample needs no search through the past (see Plan).
#ifndef JL_PLANNER_H
#define JL_PLANNER_H
#include <stddef.h>
#include <stdint.h>
#include "jl_fixed.h"   // (JL_ZERO)

namespace jl {

enum PlanStatus : uint8_t {
    kPlanOk = 0,
    kPlanBadDistance = 1,   // not finite
    kPlanBadJerk = 2,       // not finite or <= 0
    kPlanBadAccel = 3,
    kPlanBadVelocity = 4,
    kPlanBadTime = 5,       // phase time not finite, T <= 0 or t_v < 0
    kPlanOvershoot = 6,     // (protocol version 4: the moving start could not stop in time)
};

struct Sample {
    float jerk, accel, velocity, position;
};

/// Shape of the jerk pulses (as jerklab.planner's _SINE, _LINEAR, _STEP).
enum PulseShape : uint8_t { kShapeSine = 0, kShapeLinear = 1, kShapeStep = 2 };

/// One piece of a plan: from time t0 the state (x0, v0, a0) evolves under the jerk jp
/// (kShapeLinear: constant jp; kShapeSine: jp sin(w (t - t0)); plateaus and cruise: jp = 0).
/// A half-sine pulse has w = pi / its duration > 0, every other segment w = 0 (is_pulse()).
struct Segment {
    float t0, x0, v0, a0, jp, w;
};
/// The segment is a half-sine pulse (w != 0).
inline bool is_pulse(const Segment& s) { return s.w != 0.0f; }

/// A planned move: its segments and what PLAN_INFO and RETARGET read (the board plans rest to
/// rest; a moving start, re-targeting, is planned on the host).
struct Plan {
    float x_start;        // absolute start position (0 for PLAN; the switch point for RETARGET)
    float t_start;        // absolute start time (0 for PLAN)
    float duration;       // from t_start to rest at the target
    // PLAN_INFO fields: acceleration phase 2 tj + ta (the published planner: T) and t_v.
    float accel_time, cruise_time;
    float cruise_velocity;  // cruise velocity (>= 0, along the move; the published omega_bar)
    float target;         // absolute rest position at the end
    uint8_t nseg;         // segments, the rest at the target (the last) included
    /// seg[i], i < nseg: segment i (a copy). The last one, the rest at the target, is not stored
    /// (t0 = t_start + duration, x0 = target, v0 = a0 = jp = w = 0): at[] holds the others.
    struct Segments {
        Segment at[7];
        Segment operator[](uint8_t i) const;
    } seg;
};

inline Segment Plan::Segments::operator[](uint8_t i) const {
    // (the Plan whose member this is: the rest is made from its fields)
    const Plan& p = *reinterpret_cast<const Plan*>(reinterpret_cast<const char*>(this) - offsetof(Plan, seg));
    if (i + 1 < p.nseg) return at[i];
    const Segment rest = {p.t_start + p.duration, p.target, 0.0f, 0.0f, 0.0f, 0.0f};
    return rest;
}

/// The cube root of x >= 0 (0 and inf as cbrt gives them; a subnormal x scaled by 2^24 first),
/// the same code on the AVR and on the host, in place of avr-libc's cbrt (418 B of flash; this
/// is about 150). A first guess from the IEEE bits (the exponent divided by 3, within 4 % of the
/// root for a normal x), then four of Newton's steps for y^3 = x, y <- y - (y - x / y^2) / 3, each
/// of which squares the relative error (0.04 -> 2e-3 -> 4e-6 -> 1e-11 -> float rounding): within
/// 2 ulp of the true root (the golden vectors' R records check it against numpy in float64).
float cube_root(float x);

/// Stojčić eq. 4 / Fig. 2 exactly as published: T = cbrt(2 pi |d| / J), shortened to
/// E pi / J if J T / pi > E, then to sqrt(2 pi Omega / J) if J T^2 / (2 pi) > Omega;
/// t_v = (|d| - wbar T) / wbar clamped at 0 (rounding). Peak jerk is always J.
/// distance == 0 gives an empty plan (duration 0).
PlanStatus plan_sine_jerk(float distance, float max_jerk, float max_accel, float max_velocity,
                          Plan* out);

/// The time-optimal half-sine-jerk profile: the phase times of the S-curve with jerk 2J/pi
/// (jerklab.planner.plan_sine_jerk_optimal).
PlanStatus plan_sine_jerk_optimal(float distance, float max_jerk, float max_accel,
                                  float max_velocity, Plan* out);

/// The time-optimal 7-segment linear-jerk S-curve (jerklab.planner.plan_scurve).
PlanStatus plan_scurve(float distance, float max_jerk, float max_accel, float max_velocity,
                       Plan* out);

/// Constant acceleration, cruise, constant deceleration (jerklab.planner.plan_trapezoid).
PlanStatus plan_trapezoid(float distance, float max_accel, float max_velocity, Plan* out);

/// Dispatch on the PLAN planner byte (kPlannerSineJerk .. kPlannerTrapezoid).
PlanStatus plan_kind(uint8_t kind, float distance, float max_jerk, float max_accel,
                     float max_velocity, Plan* out);

/// PLAN_SEGMENT's payload (protocol version 5) as it goes on the wire: segment `index` of a
/// host-planned plan, `kind` 0 constant jerk / 1 half-sine pulse jerk sin(pi u / duration), its
/// duration (s) and start state (little-endian, no padding, as the AVR and the hosts store them).
struct __attribute__((packed)) HostSegment {
    uint8_t index, kind;
    float duration, x0, v0, a0, jerk;
};
/// PLAN_COMMIT's payload: the number of segments, the rest position at the end, the
/// acceleration and cruise times PLAN_INFO echoes (the window where a re-targeting may take
/// over: PROTOCOL.md "Re-targeting"), the cruise velocity and the planner whose rest-to-rest
/// profile the segments are (0..3; kPlannerHost 0xFF: none, a synchronized or moving start,
/// which the host re-targets from its own segments).
struct __attribute__((packed)) HostCommit {
    uint8_t n_segments;
    float target, accel_time, cruise_time, cruise_velocity;
    uint8_t planner;
};

/// A host-planned plan being received into a Plan: the segments accepted so far. The device
/// checks each field's range (jerklab.protocol.check_plan_segment, check_plan_commit); that the
/// segments join (position and velocity continuous, at rest at the target) is the host's check
/// (jerklab.protocol.check_plan_continuity: the soft-float arithmetic would cost ~1.3 kB of flash).
static_assert(sizeof(HostSegment) == 22 && sizeof(HostCommit) == 18,
              "HostSegment, HostCommit: PLAN_SEGMENT's and PLAN_COMMIT's payloads");

struct HostPlanner {
    uint8_t count;
    /// PLAN_SEGMENT s into p: 0xFF accepted (index 0 starts a new plan in p), else the payload
    /// field at fault, p unchanged: 0 index (not 0 nor `count`, or >= kMaxHostSegments), 1 kind,
    /// 2 duration (not in (0, 1e7] s), 3 x0 (not finite or |x0| > 1e6), 4 v0, 5 a0, 6 jerk (not
    /// finite).
    uint8_t add(Plan* p, const HostSegment& s);
    /// PLAN_COMMIT c: 0xFF when the plan may be committed, else the field at fault: 0
    /// n_segments (0 or not `count`), 1 target (not finite or |target| > 1e6), 2 accel_time,
    /// 3 cruise_time, 4 cruise_velocity (not finite or < 0), 5 planner (not 0..3 nor 0xFF).
    uint8_t check(const HostCommit& c) const;
    /// Ends p with the rest at the target (after check()); the next plan starts at index 0.
    void commit(Plan* p, const HostCommit& c);
};

/// Move a plan made at (t = 0, x = 0) to start at (t_start, x_start).
void place(Plan* p, float t_start, float x_start);

/// RETARGET's payload (protocol version 5) as it goes on the wire: the host-planned plan sent
/// as PLAN_SEGMENTs during the run takes over at sample switch_index, the first at or after
/// t_switch; base: the re-targeted plans that took over in the run so far (mod 256).
struct __attribute__((packed)) RetargetCommit {
    uint32_t switch_index;
    float t_switch;
    uint8_t base, n_segments;
    float target, accel_time, cruise_time;
    uint8_t flags;
};
static_assert(sizeof(RetargetCommit) == 23, "RetargetCommit: RETARGET's payload");

/// The smallest k with (float)k * Ts >= t (the stepper's first sample of a plan starting at t).
uint32_t first_sample_at(float t, float Ts);

/// Closed-form sample at absolute time t (rest at x_start before t_start, at the target after
/// the end).
void sample(const Plan& p, float t, Sample* s);

/// Fixed point of the control loop (docs/THEORY.md "the fixed-point control step"): a Q32.32 is
/// the 64-bit two's complement value * 2^32 as two words (counts, PWM ticks; its integer part hi,
/// |value| < 2^31 as the encoder count's own int32 range). The loop's hot arithmetic is 64-bit
/// adds done as eight add-with-carry steps (avr-gcc's 64-bit arithmetic is library calls); the
/// float -> Q32.32 conversions run in the preparation, one Q32.32 -> float per quantity a sample.
struct Q32 {
    uint32_t lo;
    int32_t hi;
};
/// a += b (two 32-bit adds and the carry).
void q32_add(Q32* a, const Q32& b);
/// a += y 2^s (s = 0..31; y in units 2^(s - 32) of the Q32.32), sign-extended through the top.
void q32_add_units(Q32* a, int32_t y, uint8_t s);
/// The Q24.8 window of x (its bytes 3..6, little-endian), saturated to INT32_MIN / INT32_MAX
/// from |x| >= 2^23 on (one out-of-line copy: TELEMETRY's reference and the shaper).
int32_t q32_window24(const Q32& x);
/// x * 2^32 (exact from 2^-8 up, truncated toward 0 to 2^-32 below), |x| < 2^31 (saturated beyond).
Q32 to_q32(float x);
/// A Q32.32 as a float: its widest 32-bit window (Q16.16 below 2^15, else Q24.8, saturated at 2^23),
/// converted once and scaled by the exponent (rounded to float32 once, truncated to the window).
float q32_to_float(const Q32& x);

/// Samples at t = k Ts, k = 0, 1, 2, ... for the control loop. The segment is cut into chunks of
/// at most kChunk samples; on each chunk the position (Q32.32, scaled by sx) and the
/// feedforward alpha a + beta v (Q32.32) are polynomials in n = k - k0 advanced by integer forward
/// differences (exact adds: the only error is the rounding of the chunk's coefficients to 2^-32,
/// |error| <= 2^-32 (n + n^2 + n^3) < 6.2e-5 at n < 64, on top of the float32 closed form at the
/// chunk's first sample, where they are re-anchored). On a half-sine pulse the position's and the
/// feedforward's cosine terms are each a sinusoid y(n) of the one angle step theta = w Ts, advanced
/// in int32 (units 2^-f of a count / PWM tick, f per chunk) by the difference form
/// D(n+1) = D(n) - eps y(n), y(n+1) = y(n) + D(n+1), eps = 4 sin^2(theta/2): one 32 x 32 MUL
/// product a sample each, |error| < 1 + n (1 + eps/2) + n(n+1)/2 units 2^-f (< 2206 at n < 64;
/// f with amplitude 2^f < 2^28: < 1.6e-5 of the amplitude, or 5.1e-7 count when f = 32;
/// docs/THEORY.md).
/// The velocity (velocity loop only) is a float Horner polynomial plus, on a pulse, a third such
/// sinusoid converted to float. The coefficients of a chunk are prepared before it
/// starts (prepare(), in stages, in the idle time after the control step).
class PlanStepper {
public:
    /// Chunk length in samples (re-anchoring to the closed form; bounds the cubic's rounding).
    static const uint16_t kChunk = 64;
    /// Start at k = 0. The fast samples come scaled: position x sx (e.g. counts per rad),
    /// velocity x sv, feedforward alpha a + beta v (e.g. alpha = tau/K in PWM ticks per V).
    void start(const Plan& p, float Ts, float alpha = 0.0f, float beta = 0.0f, float sx = 1.0f,
               float sv = 1.0f);
    /// Continue with the plan `p` (same Ts, same k) from its first sample on: p.t_start must be
    /// after the last sample taken (re-targeting).
    void switch_plan(const Plan& p);
    /// Re-targeting: prepare (one stage per call, like prepare()) the first chunk of `p`,
    /// which takes over at its first sample; true once scheduled. next_fast() then switches.
    bool prepare_switch(const Plan& p);
    void cancel_switch() { pend_p_ = nullptr; }
    bool switch_scheduled() const { return pend_p_ != nullptr && pend_.seg < 0xFD; }
    const Plan* plan() const { return p_; }
    /// The control loop's sample at t = k Ts, then k++: position x sx, velocity x sv and
    /// feedforward as floats (velocity, ff nullptr: not computed). The polynomial parts come
    /// from the Q32.32 differences (the position's 32-bit window, the feedforward's Q16.16, each
    /// converted once), the pulse terms from the integer sinusoids. Returns false once the move is over.
    bool next_fast(float* position, float* velocity, float* ff);
    /// next_fast() in fixed point (the control step's form): position x sx in Q32.32 (the
    /// polynomial part plus a sine pulse's), the feedforward in Q16.16 PWM ticks (saturated to
    /// +-(2^31 - 1); ff nullptr: not computed), the velocity (x sv) as next_fast(). Ask for the
    /// feedforward and the velocity each on every sample of a run or on none (they are advanced
    /// only when asked for).
    bool next_q(Q32* position, int32_t* ff, float* velocity);
    /// The sample at t = k Ts, then k++, for the golden vectors: position and velocity (x sx,
    /// x sv) from next_fast(), jerk and acceleration from the closed form sample() at t = k Ts.
    bool next(Sample* s);
    /// Work ahead: one stage (of up to 10, each <= ~5000 AVR cycles) of the coefficients of the
    /// next chunk, if not ready yet, or more when the current chunk ends before the rest
    /// would be done (call after each step, in the idle time; nothing to do most of the time).
    void prepare();
    /// The chunk changes within 14 samples (the stages a chunk can take, 12 for a pulse, and
    /// the two steps before them): the idle time's work should go to prepare() (the device's
    /// re-targeting yields to it while its switch can wait).
    bool pressed() const;
    uint32_t index() const { return k_; }
    bool done() const { return seg_ + 1 >= p_->nseg; }
    /// Index of the current segment in the plan.
    uint8_t segment() const { return seg_; }
    /// First sample index of segment i of the current plan.
    uint32_t first_sample(uint8_t i) const;
    /// Chunk changes that found the next chunk unprepared (computed inside the sample: a
    /// scheduling fault; the device counts it as an overrun). 0 when prepare() keeps up.
    uint16_t misses() const { return misses_; }

    // (the hot fields first: the AVR reaches a structure's first 64 bytes with one instruction)
    struct Coef {
        uint8_t seg;      // segment index (0xFF: not prepared, 0xFE: in preparation, 0xFD: k0, k_end known)
        uint8_t sine;
        uint8_t eb;       // sine: eps = E 2^(-8 eb)
        uint8_t xs, fs;   // sine: the sinusoids' units 2^(xs - 32) counts, 2^(fs - 32) ticks
        uint8_t vs;       // sine: the velocity's sinusoid in units 2^(vs - 32) (x sv)
        int32_t yv, Dv;   // sine: the velocity's sinusoid and its difference
        int32_t E;        // sine: eps's mantissa (exactly the float eps)
        // During the preparation some outputs' bytes hold the scratch values (stages write each
        // output only after its scratch was read, see compute_stage).
        union {
            struct { float v0, v1, v2; };   // v = v0 + n (v1 + n v2) [+ the sinusoid]
            struct { float s_x, s_v, s_a; };   // (scratch) the state at the chunk's first sample
                                                // (sine: of the polynomial part, s_a = 2 q2)
        };
        uint32_t k0;      // first sample of the chunk
        uint32_t k_end;   // first sample after the chunk (0xFFFFFFFF: none)
        union {
            struct { Q32 X, X1, X2; };     // position x sx and its forward differences
            struct {                       // (scratch)
                float s_cw, s_sw, s_B;     // sine: cos, sin of w delta; B = jp / w^3
                float s_delta, s_s2, s_c2; // k0 Ts - t0; sine: sin, cos of w Ts / 2
            };
        };
        union {
            Q32 X3;                        // polynomial: the third difference
            struct { int32_t yx, Dx; };    // sine: the position's sinusoid and its difference
        };
        Q32 F, F1;                         // feedforward and its forward differences
        union {
            Q32 F2;                        // polynomial
            struct { int32_t yf, Df; };    // sine: the feedforward's sinusoid and its difference
        };
    };
    /// The current chunk's coefficients (the golden vectors check the sinusoids' bound on them).
    const Coef& chunk() const { return buf_[ci_]; }
private:
    void compute(uint8_t i, Coef* c, uint32_t k0) const;
    void __attribute__((noinline)) begin_coef(uint8_t i, Coef* c, uint32_t k0, uint32_t k_end) const;
    bool compute_stage(uint8_t i, Coef* c, uint8_t stage) const;
    uint32_t __attribute__((noinline)) chunk_end(uint8_t i, uint32_t k0) const;
    void advance_segment();
    /// From segment j on, the last one of the plan whose first sample is at or before k.
    uint8_t segment_at(uint8_t j, uint32_t k) const;
    bool prepare_stage();
    /// The next chunk is to be prepared afresh (from seg_ on).
    void reset_next() { buf_[ci_ ^ 1].seg = 0xFF; prep_seg_ = seg_; prep_stage_ = 0; }
    // (JL_ZERO: members whose initial value is 0, see jl_fixed.h; the stepper is a member of
    // the sketch's static Device)
    const Plan* p_ JL_ZERO;
    float Ts_ = 0.005f, alpha_ JL_ZERO, beta_ JL_ZERO, sx_ = 1.0f, sv_ = 1.0f;
    uint32_t k_ JL_ZERO;
    uint16_t misses_ JL_ZERO;
    uint8_t seg_ JL_ZERO, prep_seg_ JL_ZERO, prep_stage_ JL_ZERO, pend_stage_ JL_ZERO;
    uint8_t ci_ JL_ZERO;       // buf_[ci_]: the current chunk, buf_[ci_ ^ 1]: the next one
    Coef buf_[2], pend_;
    const Plan* pend_p_ JL_ZERO;
};

}  // namespace jl
#endif
