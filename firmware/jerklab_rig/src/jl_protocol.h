// Message types, codes and payload sizes of the jerklab rig protocol, version 5.
// Mirrors jerklab/protocol.py and firmware/PROTOCOL.md (the reference definitions).
#ifndef JL_PROTOCOL_H
#define JL_PROTOCOL_H
#include <stdint.h>

namespace jl {

static const uint8_t kProtocolVersion = 5;

enum MsgType : uint8_t {
    kHello = 0x01, kSetPlant = 0x02, kSetGains = 0x03, kSetLimits = 0x04, kPlan = 0x05,
    kRun = 0x06, kStop = 0x07, kStep = 0x08, kHeartbeat = 0x09, kRetarget = 0x0C,
    kSequence = 0x0A, kSetShaper = 0x0B,   // version 3 (input shaping, identification)
    kHostLoop = 0x0D, kHostVoltage = 0x0E,  // version 4 (host-in-the-loop)
    kPlanSegment = 0x0F, kPlanCommit = 0x10,  // version 5 (host-planned segments)
    kAck = 0x80, kNack = 0x81, kHelloReply = 0x82, kPlanInfo = 0x83,
    kTelemetry = 0x90, kEndOfRun = 0x91, kError = 0x92, kHostSample = 0x93,
};

enum ErrorCode : uint8_t {
    kErrOk = 0, kErrUnknownType = 1, kErrBadLength = 2, kErrBadValue = 3, kErrBusy = 4,
    kErrNotReady = 5, kErrUnsupported = 6, kErrBadVersion = 7, kErrTooLong = 8, kErrLate = 9,
};

enum EndReason : uint8_t { kEndDone = 0, kEndStopped = 1, kEndHostTimeout = 2, kEndFault = 3,
                           kEndTrackingError = 4, kEndRunaway = 5, kEndNoMotion = 6,
                           kEndSaturation = 7, kEndHostMisses = 8 };

// A plan longer than this many samples is refused with NACK TOO_LONG (PROTOCOL.md).
static const uint32_t kMaxPlanSamples = 2000000000UL;

enum PlannerKind : uint8_t { kPlannerSineJerk = 0, kPlannerSineJerkOptimal = 1,
                             kPlannerScurve = 2, kPlannerTrapezoid = 3,
                             kPlannerHost = 0xFF };   // (Plan::kind of a host-planned plan)

// Build option JL_WITH_BOARD_PLANNERS (default 0): 1 builds the planners 1-3 (optimal sine
// jerk, S-curve, trapezoid) into the board; 0 leaves them to the host, which sends their
// segments (PLAN_SEGMENT, PLAN_COMMIT): PLAN with planner 1-3 is then NACKed UNSUPPORTED and
// capability bits 1-3 are clear. The published sine-jerk planner (Stojcic eq. 4) is always built.
#ifndef JL_WITH_BOARD_PLANNERS
#define JL_WITH_BOARD_PLANNERS 0
#endif

enum LoopType : uint8_t { kLoopPosition = 0, kLoopVelocity = 1 };

enum Capability : uint16_t {
    kCapSineJerk = 1u << 0, kCapSineJerkOptimal = 1u << 1, kCapScurve = 1u << 2,
    kCapTrapezoid = 1u << 3, kCapLoopPosition = 1u << 4, kCapLoopVelocity = 1u << 5,
    kCapOpenLoopStep = 1u << 6, kCapFeedforward = 1u << 7, kCapSimulatedPlant = 1u << 8,
    kCapRetarget = 1u << 9,
    kCapSequence = 1u << 12, kCapShaper = 1u << 13,   // version 3 (identification, input shaping)
    kCapHostLoop = 1u << 14,                           // version 4 (host-in-the-loop)
    kCapHostSegments = 1u << 10,                       // version 5 (PLAN_SEGMENT, PLAN_COMMIT)
};

static const uint8_t kGainsFeedforward = 0x01;
static const uint8_t kTelemetrySaturated = 0x01;
static const uint8_t kTelemetrySettling = 0x02;
static const uint8_t kTelemetryFault = 0x04;
// HOST_LOOP (version 4): the range of Ts, HOST_VOLTAGE's flag bit 0 (its reference is valid),
// HOST_SAMPLE's flag bit 0 (no timely HOST_VOLTAGE: the last voltage held; bit 2 as TELEMETRY's)
static const uint16_t kHostLoopMinTsUs = 5000, kHostLoopMaxTsUs = 50000;
static const uint8_t kHostVoltageReference = 0x01;
static const uint8_t kHostSampleMissed = 0x01;

// Payload sizes (bytes).
static const uint8_t kLenHello = 1, kLenSetPlant = 14, kLenSetGains = 20, kLenSetLimits = 26,
    kLenPlan = 5, kLenRun = 3, kLenStop = 0, kLenStep = 8, kLenHeartbeat = 0, kLenAck = 1,
    kLenNack = 3, kLenHelloReply = 26, kLenPlanInfo = 16, kLenTelemetry = 15, kLenEndOfRun = 13,
    kLenError = 3;
// RETARGET (version 5): u32 switch_index, f32 t_switch, u8 base, u8 n_segments, f32 target,
// f32 accel_time, f32 cruise_time, u8 flags (bit 0 kRetargetHold); the new plan's segments come
// before it as PLAN_SEGMENTs during the run. kRetargetLead: the samples the stepper needs from
// the frame to the switch (it prepares the new plan's first chunk, one stage a tick).
static const uint8_t kLenRetarget = 23;
static const uint8_t kRetargetHold = 1, kRetargetLead = 16;
static const uint8_t kLenSequence = 16, kLenSetShaper = 51;   // version 3
// Build option JL_WITH_HOST_LOOP (default 1; 0 leaves the mode out: HOST_LOOP and HOST_VOLTAGE
// are then NACKed UNSUPPORTED and capability bit 14 is clear).
#ifndef JL_WITH_HOST_LOOP
#define JL_WITH_HOST_LOOP 1
#endif
static const uint8_t kLenHostLoop = 5, kLenHostVoltage = 13, kLenHostSample = 14;   // version 4
static const uint8_t kLenPlanSegment = 22, kLenPlanCommit = 18;                     // version 5
// A host-planned plan holds at most this many PLAN_SEGMENTs (Plan::seg: and the rest at the target).
static const uint8_t kMaxHostSegments = 7;

}  // namespace jl
#endif
