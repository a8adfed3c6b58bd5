"""The jerklab rig serial protocol: frames, CRC, message types, a streaming decoder.

This module is the one definition of the wire format; ``firmware/PROTOCOL.md``
documents it byte by byte and the Arduino firmware mirrors it.  Counts, PWM
ticks and microseconds appear only here and in the firmware: everything else
in jerklab speaks SI units.

Frame (Stojčić §4 — ASCII Stojcic — asks for a "remote interface"; this binary framing replaces
the paper's HTML page so that a 5 ms telemetry stream fits a 115200 baud link)::

    0xA5 0x5A | len | type | seq | payload (0..64 bytes) | crc16 (little-endian)

``len`` counts the bytes of ``type + seq + payload`` (2..66).  The CRC is
CRC-16/CCITT-FALSE (polynomial 0x1021, initial value 0xFFFF, no reflection, no
final XOR) over ``len .. payload``.  Multi-byte fields are little-endian,
floats are IEEE-754 float32.

Examples
--------
>>> frame = encode(SetPlant(K=32.4, tau=0.025, supply_voltage=12.0, counts_per_rev=448), seq=7)
>>> dec = Decoder()
>>> [parse(f) for f in dec.feed(b"junk" + frame)]  # doctest: +ELLIPSIS
[SetPlant(K=32.4..., tau=0.025..., supply_voltage=12.0, counts_per_rev=448)]
>>> dec.stats.skipped_bytes
4
"""

from __future__ import annotations

import binascii
import dataclasses
import enum
import math
import numbers
import struct
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from jerklab import planner as pl
from jerklab.planner import ProfileSample

__all__ = [
    "PROTOCOL_VERSION",
    "SYNC",
    "MAX_PAYLOAD",
    "MAX_FRAME",
    "MIN_FRAME",
    "MsgType",
    "ErrorCode",
    "EndReason",
    "Planner",
    "LoopType",
    "Capability",
    "GAINS_FEEDFORWARD",
    "TELEMETRY_SATURATED",
    "TELEMETRY_SETTLING",
    "TELEMETRY_FAULT",
    "MAX_PLAN_SAMPLES",
    "DEFAULT_MAX_ERROR",
    "DEFAULT_RUNAWAY_MS",
    "DEFAULT_SATURATION_MS",
    "crc16_ccitt_false",
    "encode_frame",
    "encode",
    "parse",
    "Frame",
    "Decoder",
    "DecoderStats",
    "ProtocolError",
    "MESSAGES",
    "payload_field_name",
    "Hello",
    "SetPlant",
    "SetGains",
    "SetLimits",
    "Plan",
    "Run",
    "Stop",
    "Step",
    "Heartbeat",
    "Sequence",
    "SetShaper",
    "PRBS_TAPS",
    "SHAPER_MAX_TAPS",
    "SHAPER_MAX_DELAY",
    "SHAPER_SUM_TOL",
    "SHAPER_MAX_AMPLITUDE",
    "SHAPER_SPAN_COUNTS",
    "RUN_GAIN_LIMIT",
    "max_run_gain",
    "prbs_bits",
    "sequence_voltages",
    "Retarget",
    "Ack",
    "Nack",
    "HelloReply",
    "PlanInfo",
    "Telemetry",
    "EndOfRun",
    "DeviceError",
    "HostLoop",
    "HostVoltage",
    "HostSample",
    "HOST_LOOP_MIN_TS_US",
    "HOST_LOOP_MAX_TS_US",
    "HOST_VOLTAGE_REFERENCE",
    "HOST_SAMPLE_MISSED",
    "PlanSegment",
    "PlanCommit",
    "RETARGET_HOLD",
    "check_retarget",
    "SegmentKind",
    "MAX_PLAN_SEGMENTS",
    "PLANNER_NONE",
    "SEGMENT_RTOL",
    "SegmentProfile",
    "segment_end",
    "check_plan_segment",
    "check_plan_commit",
    "check_plan_continuity",
    "profile_segments",
]

PROTOCOL_VERSION = 5
#: host-planned plans: at most this many PLAN_SEGMENTs (the board adds the rest at the target)
MAX_PLAN_SEGMENTS = 7
#: continuity of host-planned segments (the host's check, check_plan_continuity): each one
#: starts within this fraction of the previous segment's terms (``|x0| + u |v0| + ...``) of
#: where that one ends
SEGMENT_RTOL = 1e-4
#: the longest plan a device accepts (PLAN_INFO.n_samples); longer: NACK TOO_LONG
MAX_PLAN_SAMPLES = 2_000_000_000
#: boot defaults of the safety stops (SetLimits.max_error rad, .runaway_ms ms, .saturation_ms ms)
DEFAULT_MAX_ERROR = 0.5
DEFAULT_RUNAWAY_MS = 200
DEFAULT_SATURATION_MS = 500
SYNC = b"\xa5\x5a"
MAX_PAYLOAD = 64
#: smallest frame: sync(2) + len + type + seq + crc(2)
MIN_FRAME = 7
MAX_FRAME = MIN_FRAME + MAX_PAYLOAD


class ProtocolError(ValueError):
    """A frame or payload that does not follow the protocol."""


# --------------------------------------------------------------------------- CRC


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_table()


def crc16_ccitt_false(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF, no reflection, no xorout).

    Table-driven, one byte at a time, exactly as the firmware computes it.
    ``crc16_ccitt_false(b"123456789") == 0x29B1`` (the catalogue check value).
    The streaming decoder uses the equivalent C routine ``binascii.crc_hqx``.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"data must be bytes, got {type(data).__name__}")
    for b in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]
    return crc


def _crc(data: bytes) -> int:
    return binascii.crc_hqx(data, 0xFFFF)


# --------------------------------------------------------------------------- enums


class MsgType(enum.IntEnum):
    """Message type byte.  Host -> device below 0x80, device -> host from 0x80."""

    HELLO = 0x01
    SET_PLANT = 0x02
    SET_GAINS = 0x03
    SET_LIMITS = 0x04
    PLAN = 0x05
    RUN = 0x06
    STOP = 0x07
    STEP = 0x08
    HEARTBEAT = 0x09
    SEQUENCE = 0x0A
    SET_SHAPER = 0x0B
    RETARGET = 0x0C
    HOST_LOOP = 0x0D
    HOST_VOLTAGE = 0x0E
    PLAN_SEGMENT = 0x0F
    PLAN_COMMIT = 0x10
    ACK = 0x80
    NACK = 0x81
    HELLO_REPLY = 0x82
    PLAN_INFO = 0x83
    TELEMETRY = 0x90
    END_OF_RUN = 0x91
    ERROR = 0x92
    HOST_SAMPLE = 0x93


class ErrorCode(enum.IntEnum):
    """NACK error codes (``Nack.error``)."""

    OK = 0
    UNKNOWN_TYPE = 1  #: type byte not a command
    BAD_LENGTH = 2  #: payload length wrong for the type
    BAD_VALUE = 3  #: a field is out of range / not finite; ``Nack.param`` = field index
    BUSY = 4  #: a run or step is active (only STOP, HEARTBEAT, HELLO accepted)
    NOT_READY = 5  #: RUN without gains, or without a PLAN since the last SET_*
    UNSUPPORTED = 6  #: planner / loop type / feature not built into this firmware
    BAD_VERSION = 7  #: protocol version not supported
    TOO_LONG = 8  #: the plan needs more than MAX_PLAN_SAMPLES samples
    LATE = 9  #: RETARGET: its switch sample has passed, or another plan took over meanwhile


class EndReason(enum.IntEnum):
    """Why a run or step ended (``EndOfRun.reason``)."""

    DONE = 0
    STOPPED = 1  #: STOP from the host
    HOST_TIMEOUT = 2  #: no valid frame from the host for longer than host_timeout_ms
    FAULT = 3  #: internal fault (control tick overrun, numeric error)
    TRACKING_ERROR = 4  #: ``|reference - position|`` > SetLimits.max_error; detail = error (rad)
    RUNAWAY = 5  #: large drive, encoder moved against it (reversed?); detail = counts moved
    NO_MOTION = 6  #: large drive, encoder did not move (disconnected? stalled?); detail = 0
    SATURATION = 7  #: output at the clamp in most samples for saturation_ms (unstable loop?)
    HOST_MISSES = 8  #: HOST_LOOP: ``max_misses`` ticks in a row without a timely HOST_VOLTAGE


class Planner(enum.IntEnum):
    """``Plan.planner`` values; which ones a device supports is in its capabilities."""

    SINE_JERK = 0  #: Stojčić eqs. 2–4, as published
    SINE_JERK_OPTIMAL = 1
    SCURVE = 2
    TRAPEZOID = 3


class LoopType(enum.IntEnum):
    """``SetGains.loop``: which quantity the PID closes on."""

    POSITION = 0  #: Stojčić eq. 11 design, error in rad
    VELOCITY = 1  #: Stojčić §4B implementation, error in rad/s


class Capability(enum.IntFlag):
    """Bits of ``HelloReply.capabilities``."""

    PLANNER_SINE_JERK = 1 << 0
    PLANNER_SINE_JERK_OPTIMAL = 1 << 1
    PLANNER_SCURVE = 1 << 2
    PLANNER_TRAPEZOID = 1 << 3
    LOOP_POSITION = 1 << 4
    LOOP_VELOCITY = 1 << 5
    OPEN_LOOP_STEP = 1 << 6
    FEEDFORWARD = 1 << 7
    SIMULATED_PLANT = 1 << 8  #: the motor is a model (virtual rig, simavr harness)
    SEQUENCE = 1 << 12  #: open-loop PRBS excitation (SEQUENCE, version 3)
    SHAPER = 1 << 13  #: FIR input shaper on the run reference (SET_SHAPER, version 3)
    RETARGET = 1 << 9  #: RETARGET during a run (protocol version 3; host-planned from 5)
    HOST_LOOP = 1 << 14  #: host-in-the-loop mode (HOST_LOOP, HOST_VOLTAGE, HOST_SAMPLE)
    HOST_SEGMENTS = 1 << 10  #: host-planned plans (PLAN_SEGMENT, PLAN_COMMIT, version 5)


class SegmentKind(enum.IntEnum):
    """``PlanSegment.kind``: the jerk on a host-planned segment (protocol version 5)."""

    POLYNOMIAL = 0  #: constant jerk (0 on a plateau, a cruise or a trapezoid's step)
    HALF_SINE = 1  #: ``jerk * sin(pi u / duration)``, u the time into the segment


#: ``SetGains.flags`` bit: add the feedforward u_F = (tau*accel + vel)/K (Stojčić eqs. 8, 16)
GAINS_FEEDFORWARD = 0x01
#: ``Telemetry.flags`` bit: the control output hit the voltage clamp this sample
TELEMETRY_SATURATED = 0x01
#: ``Telemetry.flags`` bit: the profile has ended, the loop holds the final position
TELEMETRY_SETTLING = 0x02
#: ``Telemetry.flags`` bit: a safety stop tripped at this sample (PWM 0; END_OF_RUN follows)
TELEMETRY_FAULT = 0x04
#: HOST_LOOP: the shortest and longest Ts (µs) the mode accepts
HOST_LOOP_MIN_TS_US = 5000
HOST_LOOP_MAX_TS_US = 50000
#: ``HostVoltage.flags`` bit: the ``reference`` field is the position reference (rad) at the
#: tick the voltage is for, checked by the tracking-error stop (else that stop is off)
HOST_VOLTAGE_REFERENCE = 0x01
#: ``HostSample.flags`` bit: no timely HOST_VOLTAGE for this tick; the last voltage was held
HOST_SAMPLE_MISSED = 0x01


# --------------------------------------------------------------------------- messages

_INT_RANGES = {
    "B": (0, 0xFF),
    "H": (0, 0xFFFF),
    "I": (0, 0xFFFFFFFF),
    "h": (-0x8000, 0x7FFF),
    "i": (-0x80000000, 0x7FFFFFFF),
}
_F32_MAX = 3.4028234663852886e38


def _field_codes(fmt: str) -> list[str]:
    """One struct code per field of a ``FORMAT`` (``"16s"`` is one field)."""
    codes, digits = [], ""
    for ch in fmt.lstrip("<>=!@"):
        if ch.isdigit():
            digits += ch
            continue
        codes.append(ch if ch != "s" else digits + ch)
        digits = ""
    return codes


def _wire_value(msg: str, name: str, code: str, v):
    """``v`` checked against its wire type ``code`` (ProtocolError naming the field ``name``)."""
    what = f"{msg}: cannot pack {name} = {v!r}"
    if code.endswith("s"):
        size = int(code[:-1] or 1)
        if isinstance(v, str):
            try:
                v = v.encode("ascii")
            except UnicodeEncodeError:
                raise ProtocolError(f"{what}: must be ASCII text") from None
        if not isinstance(v, (bytes, bytearray)):
            raise ProtocolError(f"{what}: must be a str ({type(v).__name__} given)")
        if len(v) > size:
            raise ProtocolError(f"{what}: at most {size} characters")
        return bytes(v)
    if code == "f":
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise ProtocolError(f"{what}: must be a number ({type(v).__name__} given)")
        try:
            x = float(v)
        except OverflowError:
            x = math.copysign(math.inf, v)
        if math.isfinite(x) and abs(x) > _F32_MAX:
            raise ProtocolError(
                f"{what}: beyond the float32 range |x| <= {_F32_MAX:.6g} of the wire"
            )
        if (
            0.0 < abs(x) < 1.1754943508222875e-38
            and struct.unpack("<f", struct.pack("<f", x))[0] == 0.0
        ):
            raise ProtocolError(
                f"{what}: nonzero but below the float32 range (it would arrive as 0)"
            )
        return x
    lo, hi = _INT_RANGES[code]
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise ProtocolError(f"{what}: must be an integer in {lo}..{hi} ({type(v).__name__} given)")
    if not lo <= int(v) <= hi:
        raise ProtocolError(f"{what}: must be in {lo}..{hi}")
    return int(v)


@dataclass(frozen=True)
class _Message:
    TYPE: ClassVar[MsgType]
    FORMAT: ClassVar[str]

    def pack(self) -> bytes:
        """The payload bytes of this message.

        Raises
        ------
        ProtocolError
            (a ``ValueError``) naming the field whose value does not fit its wire type: an
            integer outside its range or not an integer, a finite number beyond the float32
            range, a name longer than its field (NaN and inf travel: the device refuses them
            with a NACK naming the field).
        """
        values = []
        for f, code in zip(dataclasses.fields(self), _field_codes(self.FORMAT)):
            values.append(_wire_value(type(self).__name__, f.name, code, getattr(self, f.name)))
        try:
            return struct.pack(self.FORMAT, *values)
        except (struct.error, OverflowError, TypeError) as exc:  # pragma: no cover - checked above
            raise ProtocolError(f"{type(self).__name__}: cannot pack {values!r}: {exc}") from None

    @classmethod
    def unpack(cls, payload: bytes):
        """Build the message from its payload bytes (ProtocolError if the length is wrong)."""
        size = struct.calcsize(cls.FORMAT)
        if len(payload) != size:
            raise ProtocolError(f"{cls.__name__} payload must be {size} bytes, got {len(payload)}")
        values = list(struct.unpack(cls.FORMAT, payload))
        for i, f in enumerate(dataclasses.fields(cls)):
            if isinstance(values[i], bytes):
                values[i] = values[i].rstrip(b"\x00").decode("ascii", "replace")
        return cls(*values)


# host -> device -------------------------------------------------------------


@dataclass(frozen=True)
class Hello(_Message):
    """Open a session; the device answers HELLO_REPLY (whatever the version)."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO
    FORMAT: ClassVar[str] = "<B"
    protocol_version: int = PROTOCOL_VERSION


@dataclass(frozen=True)
class SetPlant(_Message):
    """Motor model used by the feedforward (Stojčić eqs. 1, 8) and the I/O scaling.

    ``K`` rad/(V s), ``tau`` s, ``supply_voltage`` V (PWM full scale),
    ``counts_per_rev`` encoder counts per revolution after quadrature decoding.
    """

    TYPE: ClassVar[MsgType] = MsgType.SET_PLANT
    FORMAT: ClassVar[str] = "<fffH"
    K: float
    tau: float
    supply_voltage: float
    counts_per_rev: int


@dataclass(frozen=True)
class SetGains(_Message):
    """Discrete PID gains (Stojčić eqs. 12, 13) in SI units: V/rad (position loop) or V/(rad/s).

    ``Ts_us`` is the control period in µs (a multiple of ``HelloReply.tick_us``),
    ``loop`` a :class:`LoopType`, ``flags`` bit 0 = feedforward on, ``gamma`` the
    derivative filter pole ``d(k) = gamma d(k-1) + kdd (e(k) - e(k-1))`` (0 = the
    paper's backward difference, Stojčić eq. 17; ``|gamma|`` < 1).
    """

    TYPE: ClassVar[MsgType] = MsgType.SET_GAINS
    FORMAT: ClassVar[str] = "<fffHBBf"
    kpd: float
    kid: float
    kdd: float
    Ts_us: int
    loop: int = LoopType.POSITION
    flags: int = GAINS_FEEDFORWARD
    gamma: float = 0.0


@dataclass(frozen=True)
class SetLimits(_Message):
    """Planner limits (rad/s^3, rad/s^2, rad/s), the voltage clamp (V), the host watchdog
    (ms, 0 = off) and the safety stops: the tracking-error limit ``max_error`` (rad, 0 = off)
    the runaway / no-motion window ``runaway_ms`` (ms, 0 = off) and the saturation window
    ``saturation_ms`` (ms, 0 = off); PROTOCOL.md "Safety stops"."""

    TYPE: ClassVar[MsgType] = MsgType.SET_LIMITS
    FORMAT: ClassVar[str] = "<ffffHfHH"
    max_jerk: float
    max_accel: float
    max_velocity: float
    max_voltage: float
    host_timeout_ms: int = 1000
    max_error: float = DEFAULT_MAX_ERROR
    runaway_ms: int = DEFAULT_RUNAWAY_MS
    saturation_ms: int = DEFAULT_SATURATION_MS


@dataclass(frozen=True)
class Plan(_Message):
    """Plan a rest-to-rest move of ``distance`` rad (signed) with the current limits."""

    TYPE: ClassVar[MsgType] = MsgType.PLAN
    FORMAT: ClassVar[str] = "<fB"
    distance: float
    planner: int = Planner.SINE_JERK


@dataclass(frozen=True)
class Run(_Message):
    """Run the planned move from the current position (encoder zeroed at sample 0).

    ``settle_samples`` extra samples hold the final position after the profile;
    ``decimation`` sends one TELEMETRY frame every that many samples (>= 1).
    """

    TYPE: ClassVar[MsgType] = MsgType.RUN
    FORMAT: ClassVar[str] = "<HB"
    settle_samples: int = 0
    decimation: int = 1


@dataclass(frozen=True)
class Stop(_Message):
    """Stop the motor now; an active run ends with END_OF_RUN(STOPPED)."""

    TYPE: ClassVar[MsgType] = MsgType.STOP
    FORMAT: ClassVar[str] = "<"


@dataclass(frozen=True)
class Step(_Message):
    """Open-loop step for identification: ``voltage`` V for ``n_samples`` periods of ``Ts_us`` µs.

    Encoder zeroed at sample 0; TELEMETRY every sample with reference 0.
    """

    TYPE: ClassVar[MsgType] = MsgType.STEP
    FORMAT: ClassVar[str] = "<fHH"
    voltage: float
    Ts_us: int
    n_samples: int


@dataclass(frozen=True)
class Heartbeat(_Message):
    """Keeps the host watchdog fed; answered by ACK."""

    TYPE: ClassVar[MsgType] = MsgType.HEARTBEAT
    FORMAT: ClassVar[str] = "<"


#: maximal-length Galois LFSR masks by order (right-shifting: ``b = s & 1; s >>= 1; if b: s ^= mask``);
#: each gives the period 2**order - 1 (checked in tests/test_protocol.py)
PRBS_TAPS = {
    2: 0x3,
    3: 0x6,
    4: 0xC,
    5: 0x14,
    6: 0x30,
    7: 0x60,
    8: 0xB8,
    9: 0x110,
    10: 0x240,
    11: 0x500,
    12: 0x829,
    13: 0x100D,
    14: 0x2015,
    15: 0x6000,
    16: 0xD008,
}


def prbs_bits(order: int, seed: int, n: int) -> list[int]:
    """The first ``n`` bits of the maximal-length PRBS of ``order`` from ``seed`` (SEQUENCE).

    A right-shifting Galois LFSR with the mask :data:`PRBS_TAPS` ``[order]``: each bit is the
    state's lowest bit before the shift, ``b = s & 1; s >>= 1; if b: s ^= mask`` — exactly
    the firmware's loop. The period is ``2**order - 1`` bits, of which ``2**(order-1)`` are 1.
    """
    for name, v in (("order", order), ("seed", seed), ("n", n)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise TypeError(f"{name} must be an integer, got {type(v).__name__}")
    if order not in PRBS_TAPS:
        raise ValueError(f"order must be in 2..16, got {order!r}")
    state = int(seed) & ((1 << order) - 1)
    if state == 0 or not 0 < seed <= 0xFFFF:
        raise ValueError(f"seed must be in 1..65535 with a nonzero low {order} bits, got {seed!r}")
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n!r}")
    mask = PRBS_TAPS[order]
    out = []
    for _ in range(int(n)):
        b = state & 1
        out.append(b)
        state >>= 1
        if b:
            state ^= mask
    return out


def sequence_voltages(msg: "Sequence") -> list[float]:
    """The commanded voltage of each of the ``n_samples`` samples of a :class:`Sequence`:
    ``offset + amplitude`` for a 1 bit, ``offset - amplitude`` for a 0, each bit held
    ``hold`` samples (float32 arithmetic, as on the device)."""
    hi = _f32(_f32(msg.offset) + _f32(msg.amplitude))
    lo = _f32(_f32(msg.offset) - _f32(msg.amplitude))
    nbits = -(-int(msg.n_samples) // int(msg.hold))
    bits = prbs_bits(int(msg.order), int(msg.seed), nbits)
    return [hi if bits[k // msg.hold] else lo for k in range(int(msg.n_samples))]


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", float(x)))[0]


@dataclass(frozen=True)
class Sequence(_Message):
    """Open-loop excitation for identification (version 3): a maximal-length PRBS.

    ``n_samples`` periods of ``Ts_us`` µs; the voltage is ``offset ± amplitude`` (V), the sign
    the bits of :func:`prbs_bits` ``(order, seed)``, each bit held ``hold`` samples. As for
    STEP the encoder is zeroed at sample 0 and every sample is sent as TELEMETRY, its
    ``reference`` field the commanded voltage (V) and ``pwm`` the applied one, so the host
    records the input exactly.
    """

    TYPE: ClassVar[MsgType] = MsgType.SEQUENCE
    FORMAT: ClassVar[str] = "<ffHHHBB"
    amplitude: float
    offset: float
    Ts_us: int
    n_samples: int
    seed: int = 1
    order: int = 8
    hold: int = 1


#: RUN: each gain scaled to PWM ticks per encoder count (per count per sample in the velocity loop)
#: must be below this (the firmware's fixed-point PID keeps a 24-bit mantissa): NACK BAD_VALUE
RUN_GAIN_LIMIT = 2.0**23


def max_run_gain(counts_per_rev, pwm_max, supply_voltage, Ts=None):
    """The bound on ``|kpd|``, ``|kid|``, ``|kdd|`` that RUN accepts.

    See firmware/PROTOCOL.md, "Parameter checks".

    Parameters
    ----------
    counts_per_rev, pwm_max, supply_voltage : float
        The plant of SET_PLANT and the device's PWM range (HELLO_REPLY).
    Ts : float, optional
        The sampling period (s) of the velocity loop, whose gains are per count per sample;
        None for the position loop.

    Returns
    -------
    float
        :data:`RUN_GAIN_LIMIT` PWM ticks per encoder count, in the gains' units (V/rad in the
        position loop); a gain must be below it.
    """
    ticks_per_gain = 2.0 * math.pi / counts_per_rev * pwm_max / supply_voltage
    if Ts is not None:
        ticks_per_gain /= Ts
    return RUN_GAIN_LIMIT / ticks_per_gain


#: SET_SHAPER: at most this many taps, delays at most this many samples (the device's ring buffer
#: holds the last SHAPER_MAX_DELAY + 1 reference samples: 32 in the default firmware, whose RAM the
#: planners and re-targeting nearly fill; 155 ms at Ts = 5 ms), taps summing to 1 within SHAPER_SUM_TOL
SHAPER_MAX_TAPS = 10
SHAPER_MAX_DELAY = 31
SHAPER_SUM_TOL = 1e-3
#: SET_SHAPER: the largest amplitude magnitude the device takes (its FIR holds a tap in Q8.24 fixed point
#: as round(a) saturating adds and a 24-bit mantissa; firmware/PROTOCOL.md)
SHAPER_MAX_AMPLITUDE = 2.0
#: RUN with a shaper: ``(sum(abs(a_i)) * D + 1) * max_velocity * Ts * counts_per_rad`` (D the largest
#: delay) must be below this many counts, so that the device's ring of Q16.16 reference windows
#: spans the move exactly (NACK BAD_VALUE, ``param`` 0xFF, otherwise)
SHAPER_SPAN_COUNTS = 16384.0


@dataclass(frozen=True)
class SetShaper(_Message):
    """An input shaper on the run reference (version 3): a sparse FIR on the Ts grid.

    The device's reference at sample k becomes ``sum_i amplitudes[i] * r(k - delays[i])``
    (``r`` the planned position, ``r(j < 0) = 0``: the start), its velocity and acceleration
    references the backward differences of that shaped position; ``n_taps = 0`` switches the
    shaper off. Up to :data:`SHAPER_MAX_TAPS` taps, delays (samples) up to
    :data:`SHAPER_MAX_DELAY`; the amplitudes, each at most :data:`SHAPER_MAX_AMPLITUDE` in
    magnitude, must sum to 1 (within :data:`SHAPER_SUM_TOL`), so the move still ends at its
    distance. The payload is fixed, 51 bytes:
    ``u8 n_taps, f32 amplitudes[10], u8 delays[10]``; the taps past ``n_taps`` are 0.
    ``amplitudes`` and ``delays`` may be given shorter (padded with zeros).
    """

    TYPE: ClassVar[MsgType] = MsgType.SET_SHAPER
    FORMAT: ClassVar[str] = "<B10f10B"
    n_taps: int
    amplitudes: tuple = ()
    delays: tuple = ()

    def __post_init__(self):
        for name in ("amplitudes", "delays"):
            v = getattr(self, name)
            try:
                v = tuple(v)
            except TypeError:
                raise ProtocolError(
                    f"SetShaper: {name} must be a sequence, got {type(v).__name__}"
                ) from None
            if len(v) > SHAPER_MAX_TAPS:
                raise ProtocolError(
                    f"SetShaper: {name} has {len(v)} entries, at most {SHAPER_MAX_TAPS}"
                )
            object.__setattr__(self, name, v + (0,) * (SHAPER_MAX_TAPS - len(v)))

    def pack(self) -> bytes:
        n = _wire_value("SetShaper", "n_taps", "B", self.n_taps)
        a = [
            _wire_value("SetShaper", f"amplitudes[{i}]", "f", x)
            for i, x in enumerate(self.amplitudes)
        ]
        d = [_wire_value("SetShaper", f"delays[{i}]", "B", x) for i, x in enumerate(self.delays)]
        return struct.pack(self.FORMAT, n, *a, *d)

    @classmethod
    def unpack(cls, payload: bytes):
        size = struct.calcsize(cls.FORMAT)
        if len(payload) != size:
            raise ProtocolError(f"{cls.__name__} payload must be {size} bytes, got {len(payload)}")
        v = struct.unpack(cls.FORMAT, payload)
        return cls(v[0], tuple(v[1:11]), tuple(v[11:21]))


#: ``Retarget.flags`` bit 0: a braking plan; the run holds at its end for the RETARGET that
#: follows (the move to the target)
RETARGET_HOLD = 0x01


@dataclass(frozen=True)
class Retarget(_Message):
    """Switch the running move to the host-planned plan sent before it (version 5).

    During a run the host sends the new plan's PLAN_SEGMENTs (into the device's second
    buffer), then this frame: the new plan takes over at sample ``switch_index``, the first
    sample at or after ``t_switch`` s, an instant where the running plan's jerk and
    acceleration are 0 (``jerklab.rig.retarget.plan_switch``). ``base`` is the number of
    re-targeted plans that took over in this run (mod 256): the plan the host planned from.
    ``n_segments``, ``target``, ``accel_time`` and ``cruise_time`` end the new plan as
    PLAN_COMMIT does; ``flags`` bit 0 (:data:`RETARGET_HOLD`): a braking plan, the run holds
    at its end for the next RETARGET. The device answers ACK, NACK BAD_VALUE naming the
    field, NACK LATE (``param`` 0: the switch is too close or past, 2: another plan took over)
    or NOT_READY outside a run; see firmware/PROTOCOL.md "Re-targeting".
    """

    TYPE: ClassVar[MsgType] = MsgType.RETARGET
    FORMAT: ClassVar[str] = "<IfBBfffB"
    switch_index: int
    t_switch: float
    base: int
    n_segments: int
    target: float
    accel_time: float = 0.0
    cruise_time: float = 0.0
    flags: int = 0


@dataclass(frozen=True)
class HostLoop(_Message):
    """Start the host-in-the-loop mode: ``n_samples`` ticks of ``Ts_us`` µs (5000..50000).

    At each tick k the device samples the encoder and sends HOST_SAMPLE k (the voltage it
    applies during tick k, PWM 0 at k = 0); the host answers HOST_VOLTAGE k with the voltage
    for tick k + 1. A reply that has not arrived by tick k + 1 is a *miss*: the last voltage is
    held and counted; ``max_misses`` misses in a row (1..255) stop the motor with END_OF_RUN
    HOST_MISSES. The safety stops stay active (PROTOCOL.md "Host-in-the-loop").
    """

    TYPE: ClassVar[MsgType] = MsgType.HOST_LOOP
    FORMAT: ClassVar[str] = "<HHB"
    Ts_us: int
    n_samples: int
    max_misses: int = 3


@dataclass(frozen=True)
class HostVoltage(_Message):
    """The host's reply to HOST_SAMPLE ``index``: ``voltage`` (V) for tick ``index + 1``.

    Not acknowledged (a reply per tick would double the link's load); refused with NACK
    BAD_VALUE (param 1) when not finite, and then counted as a miss. The device clamps it to
    ``SetLimits.max_voltage``. With ``flags`` bit 0 (:data:`HOST_VOLTAGE_REFERENCE`),
    ``reference`` is the position reference (rad) at tick ``index + 1`` for the tracking-error
    stop.
    """

    TYPE: ClassVar[MsgType] = MsgType.HOST_VOLTAGE
    FORMAT: ClassVar[str] = "<IffB"
    index: int
    voltage: float
    reference: float = 0.0
    flags: int = 0


@dataclass(frozen=True)
class PlanSegment(_Message):
    """One segment of a host-planned plan (version 5; PROTOCOL.md "Host-planned segments").

    Segment ``index`` (0 starts a new plan, then 1, 2, ... in order, at most
    :data:`MAX_PLAN_SEGMENTS`) lasts ``duration`` s from the end of the previous one and starts in
    the state ``x0`` rad, ``v0`` rad/s, ``a0`` rad/s²; ``kind`` (:class:`SegmentKind`) says how
    ``jerk`` (rad/s³) acts on it: constant, or the peak of a half-sine pulse
    ``jerk sin(pi u / duration)``. The device answers ACK, or NACK BAD_VALUE naming the field.
    """

    TYPE: ClassVar[MsgType] = MsgType.PLAN_SEGMENT
    FORMAT: ClassVar[str] = "<BBfffff"
    index: int
    kind: int
    duration: float
    x0: float
    v0: float
    a0: float
    jerk: float


#: ``PlanCommit.planner`` of a plan that is no planner's rest-to-rest profile (a moving start,
#: a synchronized or edited profile): the host re-targets it from its own segments, in the
#: window its commit names (:func:`jerklab.rig.retarget.host_running_plan`)
PLANNER_NONE = 0xFF


@dataclass(frozen=True)
class PlanCommit(_Message):
    """The end of a host-planned plan (version 5): ``n_segments`` PLAN_SEGMENTs sent, the move
    ends at rest at ``target`` rad; ``accel_time`` and ``cruise_time`` (s, >= 0) are echoed in
    PLAN_INFO and name the window where a re-targeting may take over (PROTOCOL.md
    "Re-targeting": from ``accel_time`` to ``accel_time + cruise_time`` the move has jerk and
    acceleration 0, at the speed ``cruise_velocity``, rad/s >= 0). ``planner``
    (:class:`Planner`) says whose rest-to-rest profile the segments are; :data:`PLANNER_NONE`
    for any other plan (a synchronized or moving start, re-targeted by the host all the same).
    The device answers PLAN_INFO as for PLAN, or NACK (BAD_VALUE naming the field, TOO_LONG)."""

    TYPE: ClassVar[MsgType] = MsgType.PLAN_COMMIT
    FORMAT: ClassVar[str] = "<BffffB"
    n_segments: int
    target: float
    accel_time: float = 0.0
    cruise_time: float = 0.0
    cruise_velocity: float = 0.0
    planner: int = PLANNER_NONE


# device -> host -------------------------------------------------------------


@dataclass(frozen=True)
class Ack(_Message):
    """Command accepted; the frame's seq echoes the command's seq."""

    TYPE: ClassVar[MsgType] = MsgType.ACK
    FORMAT: ClassVar[str] = "<B"
    command: int


@dataclass(frozen=True)
class Nack(_Message):
    """Command refused: ``error`` an :class:`ErrorCode`, ``param`` the payload field index or 0xFF."""

    TYPE: ClassVar[MsgType] = MsgType.NACK
    FORMAT: ClassVar[str] = "<BBB"
    command: int
    error: int
    param: int = 0xFF


@dataclass(frozen=True)
class HelloReply(_Message):
    """Device identity: protocol and firmware versions, :class:`Capability` bits, timer tick,
    PWM full scale (ticks) and a name of up to 16 ASCII characters."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO_REPLY
    FORMAT: ClassVar[str] = "<BBBBHHH16s"
    protocol_version: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    capabilities: int
    tick_us: int
    pwm_max: int
    name: str

    @property
    def firmware_version(self) -> str:
        return f"{self.fw_major}.{self.fw_minor}.{self.fw_patch}"


@dataclass(frozen=True)
class PlanInfo(_Message):
    """Reply to PLAN: accel time T and cruise time t_v (Stojčić eq. 4), duration (s),
    and ``n_samples`` = ceil(duration/Ts - 1e-4) + 1 samples of the profile at the current Ts."""

    TYPE: ClassVar[MsgType] = MsgType.PLAN_INFO
    FORMAT: ClassVar[str] = "<fffI"
    accel_time: float
    cruise_time: float
    duration: float
    n_samples: int


@dataclass(frozen=True)
class Telemetry(_Message):
    """One control sample: index k (t = k Ts), position reference (rad), encoder count,
    signed PWM output (ticks, -pwm_max..pwm_max; volts = pwm/pwm_max * supply) and flags."""

    TYPE: ClassVar[MsgType] = MsgType.TELEMETRY
    FORMAT: ClassVar[str] = "<IfihB"
    index: int
    reference: float
    counts: int
    pwm: int
    flags: int = 0


@dataclass(frozen=True)
class EndOfRun(_Message):
    """A run or step ended: :class:`EndReason`, samples executed, corrupt frames the device
    dropped since boot (saturating u16), control ticks that overran, and ``detail`` for a
    safety stop (TRACKING_ERROR: the position error in rad; RUNAWAY / NO_MOTION: the counts
    moved along the drive during the window; 0 otherwise)."""

    TYPE: ClassVar[MsgType] = MsgType.END_OF_RUN
    FORMAT: ClassVar[str] = "<BIHHf"
    reason: int
    samples: int
    rx_errors: int = 0
    overruns: int = 0
    detail: float = 0.0


@dataclass(frozen=True)
class DeviceError(_Message):
    """Asynchronous error report (``code`` an :class:`ErrorCode` or EndReason-like fault, ``detail``)."""

    TYPE: ClassVar[MsgType] = MsgType.ERROR
    FORMAT: ClassVar[str] = "<BH"
    code: int
    detail: int = 0


@dataclass(frozen=True)
class HostSample(_Message):
    """HOST_LOOP tick ``index``: the encoder ``counts`` sampled at t = index Ts (zeroed at
    tick 0), the ``pwm`` applied during this tick, the misses so far (``misses``, saturating
    u16) and in a row (``miss_run``), ``flags`` (:data:`HOST_SAMPLE_MISSED`,
    :data:`TELEMETRY_FAULT`)."""

    TYPE: ClassVar[MsgType] = MsgType.HOST_SAMPLE
    FORMAT: ClassVar[str] = "<IihHBB"
    index: int
    counts: int
    pwm: int
    misses: int = 0
    miss_run: int = 0
    flags: int = 0


MESSAGES: dict[int, type] = {
    cls.TYPE: cls
    for cls in (
        Hello,
        SetPlant,
        SetGains,
        SetLimits,
        Plan,
        Run,
        Stop,
        Step,
        Heartbeat,
        Sequence,
        SetShaper,
        Retarget,
        HostLoop,
        HostVoltage,
        PlanSegment,
        PlanCommit,
        Ack,
        Nack,
        HelloReply,
        PlanInfo,
        Telemetry,
        EndOfRun,
        DeviceError,
        HostSample,
    )
}


def payload_field_name(command: int, index: int) -> str:
    """Name of field ``index`` of command type ``command`` (for NACK messages)."""
    for name, v in (("command", command), ("index", index)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 0 <= v <= 0xFF:
            raise ValueError(f"{name} must be a byte (0..255), got {v!r}")
    cls = MESSAGES.get(command)
    if cls is None:
        return f"field {index} of unknown type 0x{command:02X}"
    fields = dataclasses.fields(cls)
    if 0 <= index < len(fields):
        return fields[index].name
    return f"field {index}"


# --------------------------------------------------------------------------- frames


@dataclass(frozen=True)
class Frame:
    """A frame that passed the CRC: ``type`` byte, ``seq`` byte, raw ``payload``.

    ``offset`` is the position of its first sync byte in the decoder's input
    stream (for diagnostics; not compared).
    """

    type: int
    seq: int
    payload: bytes
    offset: int = dataclasses.field(default=-1, compare=False)

    @property
    def size(self) -> int:
        """Bytes of the whole frame on the wire."""
        return len(self.payload) + MIN_FRAME


def encode_frame(msg_type: int, seq: int, payload: bytes = b"") -> bytes:
    """Bytes on the wire for one frame (sync, len, type, seq, payload, CRC-16 LE)."""
    if (
        isinstance(msg_type, bool)
        or not isinstance(msg_type, numbers.Integral)
        or not 0 <= msg_type <= 0xFF
    ):
        raise ProtocolError(f"msg_type must be a byte (0..255), got {msg_type!r}")
    if isinstance(seq, bool) or not isinstance(seq, numbers.Integral) or not 0 <= seq <= 0xFF:
        raise ProtocolError(f"seq must be a byte (0..255), got {seq!r}")
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"payload must be bytes, got {type(payload).__name__}")
    payload = bytes(payload)
    if len(payload) > MAX_PAYLOAD:
        raise ProtocolError(f"payload must be <= {MAX_PAYLOAD} bytes, got {len(payload)}")
    body = bytes((len(payload) + 2, int(msg_type), int(seq))) + payload
    return SYNC + body + struct.pack("<H", _crc(body))


def encode(msg, seq: int = 0) -> bytes:
    """Bytes on the wire for a message object (``Hello(...)``, ``Telemetry(...)``, ...)."""
    return encode_frame(msg.TYPE, seq, msg.pack())


def parse(frame: Frame):
    """The message object carried by a good frame (ProtocolError for unknown type / bad length)."""
    cls = MESSAGES.get(frame.type)
    if cls is None:
        raise ProtocolError(f"unknown message type 0x{frame.type:02X}")
    return cls.unpack(frame.payload)


@dataclass
class DecoderStats:
    """What a :class:`Decoder` has seen.  ``dropped`` = frames lost to corruption."""

    frames: int = 0  #: good frames returned
    bad_crc: int = 0  #: candidate frames whose CRC failed (corrupt or truncated)
    bad_length: int = 0  #: candidate frames with len outside 2..66
    truncated: int = 0  #: incomplete frames discarded by ``flush`` (end of stream / timeout)
    skipped_bytes: int = 0  #: bytes outside any good frame (noise, garbage, lost frames)

    @property
    def dropped(self) -> int:
        return self.bad_crc + self.bad_length + self.truncated


class Decoder:
    """Streaming frame decoder: feed it bytes in any chunking, get good frames back.

    A candidate frame starts at every ``A5 5A``.  When its length byte is invalid
    or its CRC fails, the decoder counts it, drops only the first sync byte and
    searches again from the next byte, so a good frame that starts inside a
    corrupted or truncated one is still found (resynchronisation).  Memory is
    bounded by one maximal frame.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._base = 0  # stream offset of self._buf[0]
        self.stats = DecoderStats()

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        """Append ``data``; return the complete good frames, in order."""
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise TypeError(f"data must be bytes, got {type(data).__name__}")
        buf = self._buf
        buf += data
        out: list[Frame] = []
        stats = self.stats
        pos = 0
        n = len(buf)
        while True:
            i = buf.find(SYNC, pos)
            if i < 0:
                # keep a trailing 0xA5: it may be the first half of a sync
                keep = n - 1 if (n > pos and buf[n - 1] == 0xA5) else n
                stats.skipped_bytes += keep - pos
                pos = keep
                break
            stats.skipped_bytes += i - pos
            pos = i
            if n - i < 3:
                break  # need the length byte
            length = buf[i + 2]
            if length < 2 or length > MAX_PAYLOAD + 2:
                stats.bad_length += 1
                stats.skipped_bytes += 1
                pos = i + 1
                continue
            end = i + 3 + length + 2
            if end > n:
                break  # wait for more bytes
            body = bytes(buf[i + 2 : i + 3 + length])
            crc = buf[end - 2] | (buf[end - 1] << 8)
            if _crc(body) != crc:
                stats.bad_crc += 1
                stats.skipped_bytes += 1
                pos = i + 1
                continue
            out.append(Frame(body[1], body[2], body[3:], self._base + i))
            stats.frames += 1
            pos = end
        del buf[:pos]
        self._base += pos
        return out

    def flush(self) -> list[Frame]:
        """End of stream or receive timeout: give up on a partial frame at the head.

        The held bytes are re-scanned without the head candidate (a good frame
        may start inside it); returns any frames found, and counts the
        abandoned candidate as ``truncated``.
        """
        out: list[Frame] = []
        while self._buf:
            if self._buf[:2] == SYNC:
                self.stats.truncated += 1
            self.stats.skipped_bytes += 1
            rest = bytes(self._buf[1:])
            self._buf.clear()
            self._base += 1  # rest[0] is the next stream byte
            out += self.feed(rest)
        return out


# --------------------------------------------------------------------------- host-planned plans

_PI = math.pi
#: the largest |x0| of a PLAN_SEGMENT and |target| of a PLAN_COMMIT (as PLAN's distance)
_MAX_POSITION = 1e6
#: the longest PLAN_SEGMENT (s)
_MAX_SEGMENT_TIME = 1e7
#: segments shorter than this (s; jerklab.planner.MIN_SYNC_TS, below any sample time) are left
#: out of a host-planned plan (the solver's round-off pieces: the state moves by ~a 1e-9 s)
_MIN_SEGMENT_TIME = 1e-9
#: the smallest normal float32
_F32_TINY = 1.1754943508222875e-38


def segment_end(kind, duration, x0, v0, a0, jerk):
    """The state at the end of a segment and the sizes of its terms.

    Parameters
    ----------
    kind : SegmentKind
        Constant jerk, or a half-sine pulse of peak ``jerk`` over ``duration``.
    duration, x0, v0, a0, jerk : float
        As :class:`PlanSegment`.

    Returns
    -------
    tuple of float
        ``(x, v, a, sx, sv)``: the end state, and ``sx = |x0| + u (|v0| + u (|a0|/2 +
        u |jerk|/6))``, ``sv = |v0| + u (|a0| + u |jerk|/2)`` (``u = duration``), the scales of
        the continuity checks (they bound each term of the end state for both kinds).

    Notes
    -----
    A half-sine pulse ``j sin(pi r / u)`` (Stojčić eq. 2's pulse, integrated three times) ends
    with ``a = a0 + 2 j u / pi``, ``v = v0 + a0 u + j u^2 / pi`` and
    ``x = x0 + v0 u + a0 u^2 / 2 + j u^3 (1 / (2 pi) - 2 / pi^3)``.
    """
    u = duration
    if kind == SegmentKind.HALF_SINE:
        a = a0 + 2.0 * jerk * u / _PI
        v = v0 + a0 * u + jerk * u * u / _PI
        x = x0 + u * (v0 + 0.5 * a0 * u) + jerk * u**3 * (0.5 / _PI - 2.0 / _PI**3)
    else:
        a = a0 + jerk * u
        v = v0 + u * (a0 + 0.5 * jerk * u)
        x = x0 + u * (v0 + u * (0.5 * a0 + u * jerk / 6.0))
    aj = abs(jerk)
    sx = abs(x0) + u * (abs(v0) + u * (0.5 * abs(a0) + u * aj / 6.0))
    sv = abs(v0) + u * (abs(a0) + 0.5 * aj * u)
    return x, v, a, sx, sv


def _finite(x) -> bool:
    return isinstance(x, numbers.Real) and math.isfinite(x)


def check_plan_segment(seg: "PlanSegment", count: int):
    """The field of a PLAN_SEGMENT the device refuses (NACK BAD_VALUE), or ``None``.

    Parameters
    ----------
    seg : PlanSegment
        The segment received.
    count : int
        Segments of the plan accepted so far (index 0 starts afresh whatever the count).

    Returns
    -------
    int or None
        0 ``index`` (not 0 and not ``count``, or ``>= MAX_PLAN_SEGMENTS``), 1 ``kind``,
        2 ``duration`` (not finite, ``<= 0`` or above 1e7 s), 3 ``x0`` (not finite or
        ``|x0| > 1e6``), 4 ``v0``, 5 ``a0``, 6 ``jerk`` (not finite). That the segments join is
        the host's check (:func:`check_plan_continuity`).
    """
    if not (seg.index == 0 or seg.index == count) or seg.index >= MAX_PLAN_SEGMENTS:
        return 0
    if seg.kind not in (SegmentKind.POLYNOMIAL, SegmentKind.HALF_SINE):
        return 1
    if not (_finite(seg.duration) and 0.0 < seg.duration <= _MAX_SEGMENT_TIME):
        return 2
    if not (_finite(seg.x0) and abs(seg.x0) <= _MAX_POSITION):
        return 3
    for i, v in ((4, seg.v0), (5, seg.a0), (6, seg.jerk)):
        if not _finite(v):
            return i
    return None


def check_plan_commit(commit: "PlanCommit", count: int):
    """The field of a PLAN_COMMIT the device refuses (NACK BAD_VALUE), or ``None``.

    ``count`` is the number of PLAN_SEGMENTs accepted since the last index 0: 0 ``n_segments``
    (0, or not ``count``), 1 ``target`` (not finite or ``|target| > 1e6``), 2 ``accel_time``,
    3 ``cruise_time``, 4 ``cruise_velocity`` (not finite or negative), 5 ``planner`` (not a
    :class:`Planner` nor :data:`PLANNER_NONE`).
    """
    if commit.n_segments == 0 or commit.n_segments != count:
        return 0
    if not (_finite(commit.target) and abs(commit.target) <= _MAX_POSITION):
        return 1
    for i, t in ((2, commit.accel_time), (3, commit.cruise_time), (4, commit.cruise_velocity)):
        if not (_finite(t) and t >= 0.0):
            return i
    if commit.planner not in (*Planner, PLANNER_NONE):
        return 5
    return None


def check_retarget(msg: "Retarget", count: int):
    """The field of a RETARGET the device refuses as BAD_VALUE on its own, or ``None``.

    ``count`` is the number of PLAN_SEGMENTs accepted in this run since the last index 0.
    In this order: 3 ``n_segments`` (0, or not ``count``), 4 ``target`` (not finite or
    ``|target| > 1e6``), 5 ``accel_time``, 6 ``cruise_time`` (not finite or negative),
    7 ``flags`` (a bit other than :data:`RETARGET_HOLD`), 1 ``t_switch`` (not finite or
    negative). The checks against the running plan follow on the device (PROTOCOL.md
    "Parameter checks"): ``base`` (NACK LATE 2), ``t_switch`` where that plan allows a switch
    (BAD_VALUE 1), ``switch_index`` its first sample (BAD_VALUE 0) and far enough ahead
    (NACK LATE 0).
    """
    if msg.n_segments == 0 or msg.n_segments != count:
        return 3
    if not (_finite(msg.target) and abs(msg.target) <= _MAX_POSITION):
        return 4
    for i, t in ((5, msg.accel_time), (6, msg.cruise_time)):
        if not (_finite(t) and t >= 0.0):
            return i
    if msg.flags & ~RETARGET_HOLD:
        return 7
    if not (_finite(msg.t_switch) and msg.t_switch >= 0.0):
        return 1
    return None


def check_plan_continuity(segments, commit):
    """Where host-planned segments do not join, or ``None`` (the host's check before sending).

    Each segment must start where the previous one ends, within :data:`SEGMENT_RTOL` of the
    sizes of that one's terms (:func:`segment_end`): ``|x_end - x0| <= SEGMENT_RTOL (sx +
    |x0|)``, ``|v_end - v0| <= SEGMENT_RTOL (sv + |v0|)`` (the acceleration may step: a
    trapezoid's), and the last one end at rest at ``commit.target`` (``|x_end - target| <=
    SEGMENT_RTOL (sx + |target|)``, ``|v_end| <= SEGMENT_RTOL sv``), each plus 1e-12 of the
    plan's largest ``|x0|``, ``|target|`` (``|v0|``). The device checks only
    each field's range (:func:`check_plan_segment`): the soft-float arithmetic of these checks
    would not fit the Uno's flash.

    Returns
    -------
    tuple or None
        ``(i, field)``: segment ``i`` and its field (``"x0"``, ``"v0"``), or ``(n, "target")``
        for the end.
    """
    # (plus 1e-12 of the plan's largest position and velocity: a floor where every term is 0)
    fx = 1e-12 * max([abs(commit.target)] + [abs(s.x0) for s in segments])
    fv = 1e-12 * max([0.0] + [abs(s.v0) for s in segments])
    prev = None
    for i, seg in enumerate(segments):
        if prev is not None:
            x, v, _, sx, sv = segment_end(
                prev.kind, prev.duration, prev.x0, prev.v0, prev.a0, prev.jerk
            )
            if not abs(x - seg.x0) <= SEGMENT_RTOL * (sx + abs(seg.x0)) + fx:
                return i, "x0"
            if not abs(v - seg.v0) <= SEGMENT_RTOL * (sv + abs(seg.v0)) + fv:
                return i, "v0"
        prev = seg
    if prev is not None:
        x, v, _, sx, sv = segment_end(
            prev.kind, prev.duration, prev.x0, prev.v0, prev.a0, prev.jerk
        )
        if not (
            abs(x - commit.target) <= SEGMENT_RTOL * (sx + abs(commit.target)) + fx
            and abs(v) <= SEGMENT_RTOL * sv + fv
        ):
            return len(segments), "target"
    return None


class SegmentProfile:
    """A host-planned plan (PLAN_SEGMENTs and their PLAN_COMMIT) sampled in closed form.

    Each segment starts at the sum of the durations before it (float64); the move is at rest
    at the first segment's ``x0`` before 0 and at ``target`` from the end on, as on the device
    (``jl::sample``).

    Parameters
    ----------
    segments : sequence of PlanSegment
        In index order.
    target : float
        Where the move rests at the end (PlanCommit.target).
    """

    def __init__(self, segments, target):
        self.segments = tuple(segments)
        if not self.segments:
            raise ValueError("segments must hold at least one PlanSegment")
        self.target = float(target)
        starts = [0.0]
        for s in self.segments:
            starts.append(starts[-1] + float(s.duration))
        self.starts = tuple(starts)

    @property
    def duration(self) -> float:
        """The end of the last segment (s)."""
        return self.starts[-1]

    def sample(self, t):
        """Jerk, acceleration, velocity and position at the times ``t``.

        Returns
        -------
        jerklab.planner.ProfileSample
            Arrays of the shape of ``t``.
        """
        t_in = np.asarray(t, dtype=float)
        t = t_in.reshape(-1)
        j = np.zeros(t.shape)
        a = np.zeros(t.shape)
        v = np.zeros(t.shape)
        x = np.full(t.shape, float(self.segments[0].x0))
        for i, s in enumerate(self.segments):
            sel = (t >= self.starts[i]) & (t < self.starts[i + 1])
            if not sel.any():
                continue
            u = t[sel] - self.starts[i]
            if s.kind == SegmentKind.HALF_SINE:
                w = _PI / s.duration
                wu = w * u
                sn = np.sin(wu)
                omc = 2.0 * np.sin(0.5 * wu) ** 2
                c = s.jerk / w
                j[sel] = s.jerk * sn
                a[sel] = s.a0 + c * omc
                v[sel] = s.v0 + s.a0 * u + c * (u - sn / w)
                x[sel] = s.x0 + u * (s.v0 + 0.5 * s.a0 * u) + c * (0.5 * u * u - omc / (w * w))
            else:
                j[sel] = s.jerk
                a[sel] = s.a0 + s.jerk * u
                v[sel] = s.v0 + u * (s.a0 + 0.5 * s.jerk * u)
                x[sel] = s.x0 + u * (s.v0 + u * (0.5 * s.a0 + u * s.jerk / 6.0))
        x[t >= self.duration] = self.target
        shape = t_in.shape
        return ProfileSample(
            t_in.copy(), j.reshape(shape), a.reshape(shape), v.reshape(shape), x.reshape(shape)
        )


def profile_segments(profile):
    """The PLAN_SEGMENTs and the PLAN_COMMIT of a :mod:`jerklab.planner` profile.

    Any profile of the four planners (Stojčić eq. 4's published sine-jerk, the optimal sine
    jerk, the S-curve, the trapezoid; rest to rest, :meth:`~jerklab.planner.Profile.synchronized`
    or not) and any :class:`~jerklab.planner.AnyStateProfile` that ends at rest: one segment per
    phase of 1 ns or more (shorter ones, the solver's round-off, are left out), its start state
    integrated in closed form (float64) from the profile's own start (a value below float32's
    normal range travels as 0). ``planner`` is the profile's :class:`Planner` for a rest-to-rest
    profile (its ``accel_time`` the float32 sum of the acceleration phase's durations, as the
    device sums them), :data:`PLANNER_NONE` for a moving start. A moving start's
    ``accel_time``, ``cruise_time`` and ``cruise_velocity`` name its re-targeting window
    (PROTOCOL.md "Re-targeting") as a planner's do: the cruise (a segment of jerk and
    acceleration 0 before the final deceleration), or, with no cruise, the instant of
    acceleration 0 where the final deceleration starts; none (all 0) when the move is never
    at acceleration 0 in motion.

    Parameters
    ----------
    profile : jerklab.planner.Profile

    Returns
    -------
    tuple
        ``(segments, commit)``: a list of :class:`PlanSegment` (index 0, 1, ...) and the
        :class:`PlanCommit` ending them, at rest at ``profile.distance``.

    Raises
    ------
    TypeError
        ``profile`` is not a jerklab.planner Profile.
    ValueError
        The profile ends moving (``final_velocity``), has more than
        :data:`MAX_PLAN_SEGMENTS` segments, or a value that is not finite (each named).
    """
    if not isinstance(profile, pl.Profile):
        raise TypeError(f"profile must be a jerklab.planner Profile, got {type(profile).__name__}")
    poly, sine = SegmentKind.POLYNOMIAL, SegmentKind.HALF_SINE
    distance = float(profile.distance)
    if not math.isfinite(distance):
        raise ValueError(f"profile.distance must be finite, got {distance!r}")
    rows = []  # (kind, duration, x0, v0, a0, jerk)
    if isinstance(profile, pl.AnyStateProfile):
        if profile.final_velocity != 0.0:
            raise ValueError(
                f"profile.final_velocity = {profile.final_velocity!r}: a host-planned plan "
                f"ends at rest (final_velocity 0)"
            )
        jerk, times, _, P, V, A = profile._segments()
        half = profile.kind == "sine_jerk_optimal"
        for i, tau in enumerate(times.tolist()):
            if tau >= _MIN_SEGMENT_TIME:
                jk = float(jerk[i])
                kind = sine if half and jk != 0.0 else poly
                rows.append((kind, tau, float(P[i]), float(V[i]), float(A[i]), jk))
        # the re-targeting's window (PROTOCOL.md "Re-targeting"): the final deceleration starts
        # at the last boundary where the move has acceleration 0 and is moving; a segment of
        # jerk and acceleration 0 just before it is the cruise. Where none is moving, the window
        # is empty (accel_time = cruise_time = 0: a re-targeting takes over at rest at the end).
        a_tol = 1e-9 * max((abs(r[4]) for r in rows), default=0.0)
        v_tol = 1e-9 * max((abs(r[3]) for r in rows), default=0.0)
        dec = [i for i, r in enumerate(rows) if abs(r[4]) <= a_tol and abs(r[3]) > v_tol]
        cruise_time = cruise_velocity = 0.0
        n_accel = 0
        if dec:
            d = dec[-1]
            cruise_velocity = abs(rows[d][3])
            c = rows[d - 1] if d > 0 else None
            if c is not None and c[5] == 0.0 and abs(c[4]) <= a_tol:
                d -= 1  # (a cruise)
                cruise_time = c[1]
            n_accel = d
        planner = PLANNER_NONE
    else:
        tj, ta, tv, jp = (float(x) for x in (profile._tj, profile._ta, profile._tv, profile._jpar))
        shape = pl._SHAPE[profile.kind]
        sg = -1.0 if distance < 0.0 else 1.0
        if shape == pl._STEP:
            # acceleration steps: (duration, a0) with jerk 0
            phases = [(ta, jp), (tv, 0.0), (ta, -jp)]
            kinds = (poly,) * 3
            jerks = (0.0,) * 3
        else:
            phases = [(tj, 0.0), (ta, None), (tj, None), (tv, None), (tj, None), (ta, None)]
            phases.append((tj, None))
            jerks = (jp, 0.0, -jp, 0.0, -jp, 0.0, jp)
            k = sine if shape == pl._SINE else poly
            kinds = (k, poly, k, poly, k, poly, k)
        x = v = a = 0.0
        n_accel = 0  # the segments of the acceleration phase
        for i, ((tau, a_step), kind, jk) in enumerate(zip(phases, kinds, jerks)):
            if a_step is not None:
                a = a_step
            if tau >= _MIN_SEGMENT_TIME:
                rows.append((kind, tau, sg * x, sg * v, sg * a, sg * jk))
                n_accel += i < len(phases) // 2
            x, v, a, _, _ = segment_end(kind, tau, x, v, a, jk)
        cruise_time = tv
        cruise_velocity = float(profile.peak_velocity)
        planner = int(Planner[profile.kind.upper()])
    # where the cruise starts as the device sums the segments' durations (float32, in order):
    # the re-targeting rule switches there
    accel_time = 0.0
    for row in rows[:n_accel]:
        accel_time = _f32(accel_time + _f32(row[1]))
    if not rows:
        raise ValueError("profile has no segment of nonzero length (distance 0?)")
    if len(rows) > MAX_PLAN_SEGMENTS:
        raise ValueError(
            f"profile has {len(rows)} segments of nonzero length; a host-planned plan holds at "
            f"most MAX_PLAN_SEGMENTS = {MAX_PLAN_SEGMENTS}"
        )
    names = ("kind", "duration", "x0", "v0", "a0", "jerk")
    segs = []
    for i, row in enumerate(rows):
        for name, value in zip(names[1:], row[1:]):
            if not math.isfinite(value):
                raise ValueError(f"segment {i}: {name} = {value!r} is not finite")
        # a state below float32's normal range (the solver's round-off about 0) travels as 0
        values = [0.0 if abs(v) < _F32_TINY else v for v in row[2:]]
        segs.append(PlanSegment(i, int(row[0]), row[1], *values))
    commit = PlanCommit(
        len(segs), distance, float(accel_time), float(cruise_time), cruise_velocity, planner
    )
    return segs, commit
