"""The virtual rig: a Python model of the Uno firmware driving a simulated DC motor.

:class:`VirtualDevice` is the firmware's behaviour written in Python — the same
protocol state machine (``firmware/PROTOCOL.md``), the same control law at Ts on
encoder counts (``jerklab.controller.DigitalController``: Stojčić eqs. 16–18 — ASCII
Stojcic — with the output clamp and conditional-integration anti-windup), the same PWM
rounding and clamp, and the host-silence watchdog — in front of a ``jerklab.plant.DCMotor``
with its PWM and encoder quantization.  It is a byte-in / byte-out object with a
``tick()``; the transports move bytes and decide the pace:

* :class:`VirtualSerial` — in process, a pyserial-like object (``read``, ``write``,
  ``in_waiting``) that runs the device as fast as the host reads (or ``speed`` times
  real time).  ``jerklab.rig.connect()`` uses it.
* :mod:`jerklab.rig.server` — the same device behind a pseudo-terminal or a TCP port.

The safety stops of PROTOCOL.md (tracking-error limit, runaway / no-motion window) follow
the firmware's rules sample for sample; the reference is sampled in blocks of
:attr:`VirtualDevice.REF_BLOCK` samples as the run goes, so memory does not grow with the
plan (a plan of more than ``protocol.MAX_PLAN_SAMPLES`` samples is refused with NACK
TOO_LONG, as on the firmware).

Protocol version 3: SEQUENCE (the PRBS of ``jerklab.protocol.prbs_bits``, the commanded volts in
TELEMETRY's reference) and SET_SHAPER (the firmware's fixed-point FIR on the run reference,
bit for bit: :class:`FixedShaper`; velocity and acceleration by backward differences). The motor
may be a ``jerklab.plant.FlexibleDCMotor`` (state ``[θ_m, ω_m, θ_l, ω_l]``, the encoder on the
motor; ``connect(device=FlexibleDCMotor())``).

Protocol version 5: PLAN_SEGMENT and PLAN_COMMIT (a host-planned plan, checked as the firmware
checks it: ``jerklab.protocol.check_plan_segment`` and ``check_plan_commit``, sampled by
``jerklab.protocol.SegmentProfile``). The virtual rig keeps every planner of PLAN (capability bits
0–3), where the Uno's default build has only the published one (Stojčić eq. 4).

The board's delay from the tick to the new duty is modelled: in a run, the PWM of sample k
takes effect :attr:`VirtualDevice.compute_delay` after the encoder was read at t = k Ts (the
firmware's control step, encoder read to PWM write, plus the mean wait for Timer1's TOP, where
the double-buffered OCR1A takes the new duty; the reference of the sample is computed one tick
ahead, after the previous step), the previous sample's PWM driving the motor until then.

Differences from the real board, on purpose: the motor coasts to rest
instantly between runs (the encoder is zeroed at each RUN anyway), and the
watchdog counts wall-clock time, as a host's silence is a wall-clock fact.
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np

from jerklab import __version__, paper, planner
from jerklab import protocol as P
from jerklab.controller import DigitalController, DiscreteGains, Feedforward
from jerklab.law import ENCODER_EPS
from jerklab.law import SCALAR as _LAW
from jerklab.plant import DCMotor
from jerklab.rig import retarget as R

_pwm_duty, _encoder_counts = _LAW["pwm_duty"], _LAW["encoder_counts"]

__all__ = ["VirtualDevice", "VirtualSerial"]


#: planner id -> jerklab.planner function name
_PLANNERS = {
    P.Planner.SINE_JERK: "plan_sine_jerk",
    P.Planner.SINE_JERK_OPTIMAL: "plan_sine_jerk_optimal",
    P.Planner.SCURVE: "plan_scurve",
    P.Planner.TRAPEZOID: "plan_trapezoid",
}


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _finite(x) -> bool:
    return isinstance(x, float) and math.isfinite(x)


_I32_MIN, _I32_MAX = -(1 << 31), (1 << 31) - 1


def _sat32(x: int) -> int:
    return _I32_MIN if x < _I32_MIN else (_I32_MAX if x > _I32_MAX else x)


def _wrap32(x: int) -> int:
    return ((x + (1 << 31)) & 0xFFFFFFFF) - (1 << 31)


def _mac(acc: int, x: int, mant: int, shift: int) -> int:
    """The firmware's ``mac_g``: acc + floor(x mant / 2^(8 shift)), each saturated to int32."""
    return _sat32(acc + _sat32((x * mant) >> (8 * shift)))


def _tap_mac(acc: int, x: int, m: int) -> int:
    """acc + floor(a x) for the Q8.24 tap ``m`` as the firmware's ``tap_mac``: round(a) = k
    saturating adds of x, then the 24-bit remainder ``m - k 2^24`` by :func:`_mac` at shift 3."""
    t = m + (1 << 23)
    k = t >> 24
    step = x if k >= 0 else _wrap32(-x)
    for _ in range(abs(k)):
        acc = _sat32(acc + step)
    return _mac(acc, x, (t & 0xFFFFFF) - (1 << 23), 3)


def _q824(a: float) -> int:
    """round(a 2^24), halves away from 0 (the firmware's ``to_q16(a * 256)``), for float32 a."""
    x = abs(float(a)) * 16777216.0
    return int(math.copysign(math.floor(x + 0.5), a)) if x >= 0.5 else 0


class FixedShaper:
    """Bit-exact twin of the firmware's fixed-point SET_SHAPER FIR (``jl::Shaper``, jl_excite.h).

    The reference ``r`` in encoder counts as a Q32.32 integer (``R = r 2^32``), the taps in
    Q8.24 (``round(a 2^24)``, converted once by :meth:`set`), the ring of the last 32 samples as
    Q16.16 windows modulo 2^32. With ``a0`` the sum of the delay-0 taps and ``S`` of all taps
    (exact integer sums of the quantised taps), the shaped reference is

    ``r_s(k) = r(k) + (a0 - 1) D(k) + Q(k)``, ``D(k) = w(k) - w(k-1)``,
    ``Q(k) = (S - 1) r(k-1) + sum_{d_i > 1} a_i (w(k - d_i) - w(k-1))``,

    i.e. ``sum_i a_i r(k - d_i)`` with the quantised taps, each product floored to 2^-16 counts;
    its velocity and acceleration are Q16.16 backward differences (counts per sample, per
    sample^2). Against the FIR with the float32 taps the error is at most
    ``n 2^-25 max|r| + (2 sum|a_i| + n + 4) 2^-16`` counts (``n`` taps) while RUN's span check
    holds (:data:`jerklab.protocol.SHAPER_SPAN_COUNTS`: the reference then moves less than 2^14
    counts within the largest delay).

    Parameters
    ----------
    msg : jerklab.protocol.SetShaper, optional
        The shaper's taps (:meth:`set`); none: no taps until :meth:`set`.
    """

    RING = P.SHAPER_MAX_DELAY + 1

    def __init__(self, msg=None):
        self.taps = []  # (Q8.24 amplitude, delay)
        self.a0m1 = self.sm1 = 0
        self.span = 1.0
        if msg is not None:
            self.set(msg)
        self.reset()

    def set(self, msg) -> None:
        """Quantise the taps of a (checked) SET_SHAPER message, as the firmware's ``set``."""
        f32 = np.float32
        n = msg.n_taps
        self.taps = [(_q824(f32(a)), int(d)) for a, d in zip(msg.amplitudes[:n], msg.delays[:n])]
        self.a0m1 = sum(m for m, d in self.taps if d == 0) - (1 << 24)
        self.sm1 = sum(m for m, _ in self.taps) - (1 << 24)
        abs_sum = f32(0.0)
        for a in msg.amplitudes[:n]:
            abs_sum = f32(abs_sum + f32(abs(f32(a))))
        D = max((d for _, d in self.taps), default=0)
        self.span = float(f32(f32(abs_sum * f32(D)) + f32(1.0)))

    def fits(self, counts_per_sample: float) -> bool:
        """RUN's range check: the reference moves at most ``counts_per_sample`` a sample."""
        return bool(np.float32(self.span) * np.float32(counts_per_sample) < P.SHAPER_SPAN_COUNTS)

    def reset(self) -> None:
        """Start of a run: the history is the rest position 0."""
        self.ring = [0] * self.RING
        self.pos = 0
        self.q = 0
        self.prev_r = 0
        self.prev_s = 0
        self.prev_v = 0

    def apply(self, R: int):
        """Shape the Q32.32 reference ``R`` of the next sample; return ``(R_s, v, a)`` (Q32.32
        counts, Q16.16 counts per sample and per sample^2). Call :meth:`prepare` after it."""
        N = self.RING
        w = _wrap32(R >> 16)
        dk = _wrap32(w - self.ring[(self.pos - 1) % N])
        self.ring[self.pos] = w
        self.pos = (self.pos + 1) % N
        self.prev_r = R
        c = _tap_mac(self.q, dk, self.a0m1)
        Rs = R + (c << 16)
        s = _wrap32(Rs >> 16)
        v = _wrap32(s - self.prev_s)
        a = _wrap32(v - self.prev_v)
        self.prev_s, self.prev_v = s, v
        return Rs, v, a

    def prepare(self) -> None:
        """Q(k + 1), the delayed taps' part of the next sample (the firmware's idle time)."""
        N = self.RING
        w1 = self.ring[(self.pos - 1) % N]
        p = 0
        for m, d in self.taps:
            if d > 1:
                p = _tap_mac(p, _wrap32(self.ring[(self.pos - d) % N] - w1), m)
        hi = self.prev_r >> 32
        x = _wrap32(self.prev_r >> 24)  # the Q24.8 window, saturated from |r| >= 2^23 counts
        if not -(1 << 23) <= hi < (1 << 23):
            x = _I32_MIN if hi < 0 else _I32_MAX
        e = _mac(0, x, self.sm1, 2)
        self.q = _sat32(e + p)

    def run(self, R):
        """Shape a whole sequence of Q32.32 references from rest: ``(R_s, v, a)`` lists."""
        self.reset()
        out = []
        for r in R:
            out.append(self.apply(int(r)))
            self.prepare()
        return [list(x) for x in zip(*out)] if out else [[], [], []]


class VirtualDevice:
    """The firmware of ``firmware/PROTOCOL.md`` as a Python object, driving a simulated motor.

    Parameters
    ----------
    motor : jerklab.plant.DCMotor, optional
        The "hardware": its ``supply_voltage``, ``pwm_bits`` and encoder set the
        H-bridge and counter the firmware sees. Default: the paper's motor
        (K = 32.4 rad/(V s), tau = 25 ms, 12 V, 10-bit PWM, 448 counts/rev).
    clock : callable
        Wall clock in seconds for the host watchdog (``time.monotonic``).
    name : str
        Reported in HELLO_REPLY.
    tick_us : int
        Timer tick; Ts must be a multiple of it (1000 µs, as on the Uno).
    compute_delay : float, optional
        In a run, from the encoder read at t = k Ts to sample k's duty in effect (s):
        default :attr:`DUTY_DELAY`, the control step's :attr:`COMPUTE_DELAY` plus the PWM's
        :attr:`PWM_BUFFER_DELAY`; 0 holds each PWM over its whole sample.
    count_noise : float
        Standard deviation (counts) of a noise added to the encoder reading before it is
        floored to a count (0: the exact counter).
    noise_seed : int or sequence of int, optional
        Seed of that noise (``numpy.random.default_rng``).
    """

    STATE_IDLE, STATE_RUNNING, STATE_STEPPING, STATE_HOSTLOOP = 0, 1, 2, 3

    #: Encoder read to PWM write in a closed-loop run on the Uno firmware (s): ``Device::control()``
    #: measured on the simulated ATmega328P (``python -m benchmarks firmware``, parts table: mean
    #: ~1030, max ~1080 cycles at 16 MHz while moving with the fixed-point PID; 1080 cycles are
    #: 67.5 µs), plus the wake-up from the 1 ms tick.
    COMPUTE_DELAY = 70e-6
    #: The PWM's own delay (s): Timer1's phase-correct PWM takes a newly written duty at its next
    #: TOP (OCR1A is double-buffered), which comes 0 to 127.9 µs later (one PWM period, 2·1023
    #: cycles at 16 MHz) with no fixed phase to the 1 ms tick: 63.9 µs on average, modelled here
    #: by that mean (the simavr harness latches OCR1A at each TOP, as the chip does).
    PWM_BUFFER_DELAY = 1023 / 16e6
    #: The default ``compute_delay``: from the encoder read at t = k Ts to the new duty in effect.
    DUTY_DELAY = COMPUTE_DELAY + PWM_BUFFER_DELAY

    def __init__(
        self,
        motor=None,
        clock=time.monotonic,
        name="jerklab-virtual",
        tick_us=1000,
        compute_delay=None,
        count_noise=0.0,
        noise_seed=None,
    ):
        self.motor = DCMotor() if motor is None else motor
        if self.motor.supply_voltage is None or self.motor.counts_per_rad is None:
            raise ValueError(
                "motor must have a supply_voltage and an encoder (encoder_ppr) to be a rig"
            )
        self.clock = clock
        if compute_delay is None:
            compute_delay = self.DUTY_DELAY
        if (
            isinstance(compute_delay, bool)
            or not isinstance(compute_delay, (int, float))
            or not math.isfinite(compute_delay)
            or not 0.0 <= compute_delay < 1e-3
        ):
            raise ValueError(
                f"compute_delay must be a time in seconds in [0, 1e-3) (below the shortest Ts), "
                f"got {compute_delay!r}"
            )
        self.compute_delay = float(compute_delay)
        if not (isinstance(count_noise, (int, float)) and 0.0 <= count_noise < math.inf):
            raise ValueError(f"count_noise must be a finite number >= 0, got {count_noise!r}")
        self.count_noise = float(count_noise)
        self._noise_rng = np.random.default_rng(noise_seed) if count_noise else None
        self._applied_volts = 0.0
        self.name = str(name)[:16]
        self.tick_us = int(tick_us)
        bits = self.motor.pwm_bits or paper.PWM_BITS
        self.pwm_max = 2**bits - 1
        major, minor, patch = (int(x) for x in (__version__.split(".") + ["0", "0"])[:3])
        self.version = (major, minor, patch)
        self.capabilities = (
            P.Capability.PLANNER_SINE_JERK
            | P.Capability.PLANNER_SINE_JERK_OPTIMAL
            | P.Capability.PLANNER_SCURVE
            | P.Capability.PLANNER_TRAPEZOID
            | P.Capability.RETARGET
            | P.Capability.LOOP_POSITION
            | P.Capability.LOOP_VELOCITY
            | P.Capability.OPEN_LOOP_STEP
            | P.Capability.FEEDFORWARD
            | P.Capability.SIMULATED_PLANT
            | P.Capability.SEQUENCE
            | P.Capability.SHAPER
            | P.Capability.HOST_LOOP
            | P.Capability.HOST_SEGMENTS
        )
        self._decoder = P.Decoder()
        self._last_byte = self.clock()
        self._out = bytearray()
        self._seq = 0
        self.x = self.motor.initial_state()  # [theta, omega] (a FlexibleDCMotor: and the load's)
        self.t = 0.0  # simulated time (s)
        self.pwm = 0
        self.overruns = 0
        self.rejected = 0  # good frames answered by NACK
        # fault injection (tests of `jerklab rig check`; the encoder's is encoder_sign):
        # supply_fraction < 1 = a weak supply giving only that share of its volts
        self.supply_fraction = 1.0
        # lead_sign = -1: the motor leads reversed at the H-bridge (the motor sees -u);
        # hand = revolutions a hand turns the output shaft during a 0 V STEP (spread evenly
        # over its samples): the rig check's hand turn on the virtual rig
        self.lead_sign = 1
        self.hand = None
        self.motor.step_state(self.x, 0.0, 1e-3)  # warm up (a compiled kernel) before the first run
        # python-control (imported on first use since the layering change) is loaded now, at
        # power-on: importing it in the middle of a run stalls the served device for ~1 s,
        # long enough for its own host watchdog to end the run (HOST_TIMEOUT).
        import control  # noqa: F401

        self.boot()

    # ------------------------------------------------------------------ state
    def boot(self):
        """Power-on defaults of PROTOCOL.md ("Device state machine")."""
        self.plant = P.SetPlant(
            K=_f32(paper.MOTOR_K),
            tau=_f32(paper.MOTOR_TAU),
            supply_voltage=paper.SUPPLY_VOLTAGE,
            counts_per_rev=paper.ENCODER_PPR * paper.ENCODER_DECODING,
        )
        self.limits = P.SetLimits(
            max_jerk=paper.MAX_JERK,
            max_accel=paper.MAX_ACCEL,
            max_velocity=paper.MAX_VELOCITY,
            max_voltage=paper.SUPPLY_VOLTAGE,
            host_timeout_ms=1000,
            max_error=P.DEFAULT_MAX_ERROR,
            runaway_ms=P.DEFAULT_RUNAWAY_MS,
            saturation_ms=P.DEFAULT_SATURATION_MS,
        )
        self.gains = None
        self.plan = None
        self._hsegs = []  # version 5: the PLAN_SEGMENTs accepted since the last index 0
        self.shaper = P.SetShaper(0)  # version 3: no input shaper at boot
        self.state = self.STATE_IDLE
        self.pwm = 0
        self.last_rx = self.clock()

    @property
    def active(self) -> bool:
        return self.state != self.STATE_IDLE

    @property
    def period(self) -> float:
        """Length of the next tick (s): the running Ts, or the configured one."""
        if self.state in (self.STATE_STEPPING, self.STATE_HOSTLOOP):
            return self._step_Ts
        if self.gains is not None:
            return self.gains.Ts_us * 1e-6
        return 0.005

    @property
    def rx_errors(self) -> int:
        return min(self._decoder.stats.dropped, 0xFFFF)

    #: the encoder as wired: 1 as specified, -1 reversed (A and B swapped), 0 disconnected
    #: (fault injection for the safety stops)
    encoder_sign = 1

    def _raw_counts(self) -> int:
        if self._noise_rng is None:
            return int(_encoder_counts(float(self.x[0]), self.motor.counts_per_rad))
        jitter = self._noise_rng.normal(0.0, self.count_noise)
        return int(math.floor(float(self.x[0]) * self.motor.counts_per_rad + ENCODER_EPS + jitter))

    def _counts(self) -> int:
        return self.encoder_sign * self._raw_counts()

    # ------------------------------------------------------------------ bytes in / out
    #: a partial frame is abandoned after this much silence (s), as on the firmware
    RX_FRAME_TIMEOUT = 0.020

    def poll(self) -> None:
        """Call often while idle (the transports do): drops a partial frame after
        :attr:`RX_FRAME_TIMEOUT` of silence and handles a frame found inside it, as the
        firmware's main loop does."""
        self._expire_partial(self.clock())

    def receive(self, data: bytes) -> None:
        """Bytes from the host (any chunking)."""
        now = self.clock()
        self._expire_partial(now)
        if data:
            self._last_byte = now
        for frame in self._decoder.feed(data):
            self.last_rx = now
            self._handle(frame)

    def _expire_partial(self, now):
        """Drop a partial frame after RX_FRAME_TIMEOUT of silence (counted as truncated);
        a frame that starts inside it is still found."""
        if self._decoder.pending and now - self._last_byte > self.RX_FRAME_TIMEOUT:
            for frame in self._decoder.flush():
                self.last_rx = now
                self._handle(frame)

    def read_output(self, n: int | None = None) -> bytes:
        """Take up to ``n`` bytes the device has sent (all if None)."""
        if n is None or n >= len(self._out):
            out = bytes(self._out)
            self._out.clear()
            return out
        out = bytes(self._out[:n])
        del self._out[:n]
        return out

    @property
    def output_pending(self) -> int:
        return len(self._out)

    def _send(self, msg, seq=None):
        if seq is None:
            seq = self._seq
            self._seq = (self._seq + 1) & 0xFF
        self._out += P.encode(msg, seq)

    def _nack(self, frame, error, param=0xFF):
        self.rejected += 1
        self._send(P.Nack(frame.type, int(error), param), frame.seq)

    # ------------------------------------------------------------------ commands
    def _handle(self, frame: P.Frame) -> None:
        self._current_seq = frame.seq  # for handlers that reply themselves (PLAN)
        cls = P.MESSAGES.get(frame.type)
        if cls is None or frame.type >= 0x80:
            return self._nack(frame, P.ErrorCode.UNKNOWN_TYPE)
        try:
            msg = cls.unpack(frame.payload)
        except P.ProtocolError:
            return self._nack(frame, P.ErrorCode.BAD_LENGTH)
        if isinstance(msg, P.Hello):
            maj, mnr, pat = self.version
            return self._send(
                P.HelloReply(
                    P.PROTOCOL_VERSION,
                    maj,
                    mnr,
                    pat,
                    int(self.capabilities),
                    self.tick_us,
                    self.pwm_max,
                    self.name,
                ),
                frame.seq,
            )
        if isinstance(msg, P.Heartbeat):
            return self._send(P.Ack(frame.type), frame.seq)
        if isinstance(msg, P.Stop):
            was_active = self.active
            self.pwm = 0
            self._send(P.Ack(frame.type), frame.seq)
            if was_active:
                self._end(P.EndReason.STOPPED)
            return None
        if isinstance(msg, P.Retarget):
            return self._retarget(frame, msg)
        if isinstance(msg, P.PlanSegment) and self.state == self.STATE_RUNNING:
            return self._retarget_segment(frame, msg)
        if isinstance(msg, P.HostVoltage):
            return self._host_voltage(frame, msg)
        if self.active:
            return self._nack(frame, P.ErrorCode.BUSY)
        handler = getattr(self, "_cmd_" + type(msg).__name__)
        error, param = handler(msg)
        if error is None:
            return None  # the handler replied itself
        if error != P.ErrorCode.OK:
            return self._nack(frame, error, param)
        return self._send(P.Ack(frame.type), frame.seq)

    def _ts_ok(self, ts_us):
        return 0 < ts_us <= 65000 and ts_us % self.tick_us == 0

    def _cmd_SetPlant(self, m):
        checks = [
            _finite(m.K) and 0 < m.K <= 1e4,
            _finite(m.tau) and 0 < m.tau <= 10,
            _finite(m.supply_voltage) and 0 < m.supply_voltage <= 48,
            m.counts_per_rev >= 1,
        ]
        bad = _first_false(checks)
        if bad is not None:
            return P.ErrorCode.BAD_VALUE, bad
        self.plant = m
        return P.ErrorCode.OK, 0xFF

    def _cmd_SetGains(self, m):
        checks = [
            _finite(m.kpd),
            _finite(m.kid),
            _finite(m.kdd),
            self._ts_ok(m.Ts_us),
            m.loop in (P.LoopType.POSITION, P.LoopType.VELOCITY),
            (m.flags & ~P.GAINS_FEEDFORWARD) == 0,
            _finite(m.gamma) and abs(m.gamma) < 1.0,
        ]
        bad = _first_false(checks)
        if bad is not None:
            return P.ErrorCode.BAD_VALUE, bad
        self.gains = m
        self.plan = None
        return P.ErrorCode.OK, 0xFF

    def _cmd_SetLimits(self, m):
        checks = [
            _finite(m.max_jerk) and m.max_jerk > 0,
            _finite(m.max_accel) and m.max_accel > 0,
            _finite(m.max_velocity) and m.max_velocity > 0,
            _finite(m.max_voltage) and 0 < m.max_voltage <= self.plant.supply_voltage,
            True,
            _finite(m.max_error) and m.max_error >= 0,
            True,
            True,
        ]
        bad = _first_false(checks)
        if bad is not None:
            return P.ErrorCode.BAD_VALUE, bad
        self.limits = m
        self.plan = None
        return P.ErrorCode.OK, 0xFF

    def _cmd_Plan(self, m):
        if not (_finite(m.distance) and 0 < abs(m.distance) <= 1e6):
            return P.ErrorCode.BAD_VALUE, 0
        if m.planner not in _PLANNERS:
            return P.ErrorCode.BAD_VALUE, 1
        if not self.capabilities & (1 << m.planner):
            return P.ErrorCode.UNSUPPORTED, 1
        L = self.limits
        self._hsegs = []  # (the board plans into the buffer of the host's segments)
        fn = getattr(planner, _PLANNERS[m.planner])
        if m.planner == P.Planner.TRAPEZOID:
            prof = fn(m.distance, L.max_accel, L.max_velocity)
        else:
            prof = fn(m.distance, L.max_jerk, L.max_accel, L.max_velocity)
        Ts = self.period
        x = prof.duration / Ts - 1e-4
        if not math.isfinite(x) or x >= P.MAX_PLAN_SAMPLES:
            return P.ErrorCode.TOO_LONG, 0
        n = math.ceil(x) + 1
        pt = prof.phase_times
        if len(pt) == 3:
            accel_time, cruise = pt[0], pt[1]
        else:
            accel_time, cruise = sum(pt[:3]), pt[3]
        self.plan = (prof, n, m)
        self._plan_times = tuple(_f32(x) for x in (accel_time, cruise, prof.duration))
        self._send(P.PlanInfo(accel_time, cruise, prof.duration, n), self._current_seq)
        return None, None

    def _cmd_PlanSegment(self, m):
        """PLAN_SEGMENT (version 5): one segment of a host-planned plan, ACK or NACK BAD_VALUE
        naming the field (jerklab.protocol.check_plan_segment)."""
        bad = P.check_plan_segment(m, len(self._hsegs))
        if bad is not None:
            return P.ErrorCode.BAD_VALUE, bad
        if m.index == 0:
            self._hsegs = []
        self.plan = None  # the plan is rebuilt in place, as on the board
        self._hsegs.append(m)
        return P.ErrorCode.OK, 0xFF

    def _cmd_PlanCommit(self, m):
        """PLAN_COMMIT (version 5): the host's segments become the plan; PLAN_INFO as PLAN's."""
        bad = P.check_plan_commit(m, len(self._hsegs))
        if bad is not None:
            return P.ErrorCode.BAD_VALUE, bad
        # the segments' start times as the board sums them (float32)
        dur = np.float32(0.0)
        for s in self._hsegs:
            dur = np.float32(dur + np.float32(s.duration))
        x = float(dur) / self.period - 1e-4
        if not math.isfinite(x) or x >= P.MAX_PLAN_SAMPLES:
            self._hsegs = []  # (the plan dropped, as on the board)
            return P.ErrorCode.TOO_LONG, 0
        n = math.ceil(x) + 1
        self.plan = (P.SegmentProfile(self._hsegs, m.target), n, m)
        self._plan_times = (_f32(m.accel_time), _f32(m.cruise_time), float(dur))
        self._hsegs = []  # (the next plan starts at index 0, as on the board)
        self._send(P.PlanInfo(m.accel_time, m.cruise_time, float(dur), n), self._current_seq)
        return None, None

    def _cmd_Run(self, m):
        if m.decimation < 1:
            return P.ErrorCode.BAD_VALUE, 1
        if self.gains is None or self.plan is None:
            return P.ErrorCode.NOT_READY, 0xFF
        g = self.gains
        Ts = g.Ts_us * 1e-6
        # the firmware's fixed-point PID holds each gain, scaled to PWM ticks per count (per count
        # per sample in the velocity loop), below 2^23 (PROTOCOL.md "Parameter checks", RUN)
        limit = P.max_run_gain(
            self.plant.counts_per_rev,
            self.pwm_max,
            self.plant.supply_voltage,
            Ts if g.loop == P.LoopType.VELOCITY else None,
        )
        if any(abs(k) >= limit for k in (g.kpd, g.kid, g.kdd)):
            return P.ErrorCode.BAD_VALUE, 0xFF
        if self.shaper.n_taps:
            # the firmware's fixed-point FIR (FixedShaper): the reference's span over the ring,
            # and the feedforward of its differences as gains below 2^23 PWM ticks per count
            # per sample (^2)
            f32 = np.float32
            ts = f32(f32(g.Ts_us) * f32(1e-6))
            rpc = f32(f32(2.0 * math.pi) / f32(self.plant.counts_per_rev))
            shp = FixedShaper(self.shaper)
            if not shp.fits(float(f32(f32(f32(self.limits.max_velocity) * ts) / rpc))):
                return P.ErrorCode.BAD_VALUE, 0xFF
            if g.flags & P.GAINS_FEEDFORWARD:
                h = (
                    float(f32(self.pwm_max) / f32(self.plant.supply_voltage))
                    * float(rpc)
                    / float(ts)
                )
                kv = h / self.plant.K
                ka = h * self.plant.tau / self.plant.K / float(ts)
                if not (abs(kv) < P.RUN_GAIN_LIMIT and abs(ka) < P.RUN_GAIN_LIMIT):
                    return P.ErrorCode.BAD_VALUE, 0xFF
        loop = "velocity" if g.loop == P.LoopType.VELOCITY else "position"
        dg = DiscreteGains(g.kpd, g.kid, g.kdd, Ts, gamma=g.gamma, loop=loop)
        ff = Feedforward(self.plant.K, self.plant.tau) if g.flags & P.GAINS_FEEDFORWARD else None
        self._ctrl = DigitalController(
            dg, feedforward=ff, output_limit=self.limits.max_voltage, anti_windup=True
        )
        prof, n, plan_msg = self.plan
        self._profile = prof
        # re-targeting (jerklab.rig.retarget): the pieces of the reference, from their start time
        self._pieces = [(-math.inf, prof)]
        self._piece_k = [0]  # the sample each piece takes over at
        self._run_times = (0.0, *self._plan_times)  # t_start, accel, cruise, duration (float32)
        self._rt_segs = []  # PLAN_SEGMENTs received in this run (the second buffer)
        self._rt_gen = 0  # re-targeted plans that took over in this run (mod 256)
        self._plan_msg = plan_msg
        self._settle = m.settle_samples
        self._switch = None  # (k, n_profile, hold, times) when a new plan takes over
        self._hold = False  # a braking plan runs: the run holds at its end
        delay = self._shaper_delay if self.shaper.n_taps else 0
        self._shp_delay = delay  # SET_SHAPER: the move lasts the last delay longer
        self._n_profile = n + delay
        self._n_total = n + delay + m.settle_samples
        self._fir = FixedShaper(self.shaper)  # (the history at rest: reset)
        self._shp_Ts = g.Ts_us * 1e-6
        self._ref_k0 = 0
        self._ref = None  # block of samples from _ref_k0 (see _reference)
        self._decimation = m.decimation
        L = self.limits
        self._max_error = float(L.max_error)
        self._runaway_pwm = (self._pwm_top() + 1) // 2
        self._runaway_n = (int(L.runaway_ms) * 1000 + g.Ts_us - 1) // g.Ts_us
        self._run_sign = self._run_len = self._moved = 0
        self._sat_n = (int(L.saturation_ms) * 1000 + g.Ts_us - 1) // g.Ts_us
        self._sat_level = 0
        self._last_pwm = 0
        self._prev_counts = 0
        self._start(Ts)
        self.state = self.STATE_RUNNING
        return P.ErrorCode.OK, 0xFF

    def _cmd_Sequence(self, m):
        """SEQUENCE (version 3): the open-loop PRBS; checks in the firmware's order."""
        amp, off = m.amplitude, m.offset
        limit_ok = (
            _finite(off)
            and _finite(amp)
            and _f32(_f32(abs(off)) + amp) <= _f32(self.limits.max_voltage)
        )
        checks = [
            (0, _finite(amp) and amp >= 0),
            (1, limit_ok),
            (2, self._ts_ok(m.Ts_us)),
            (3, m.n_samples >= 1),
            (5, m.order in P.PRBS_TAPS),
            (4, m.seed & ((1 << m.order) - 1) != 0),
            (6, m.hold >= 1),
        ]
        for param, ok in checks:
            if not ok:
                return P.ErrorCode.BAD_VALUE, param
        self._step_Ts = m.Ts_us * 1e-6
        volts = P.sequence_voltages(m)
        self._seq_volts = volts
        self._seq_pwm = {v: self._to_pwm(v) for v in set(volts)}
        self._n_total = m.n_samples
        self._decimation = 1
        self._start(self._step_Ts)
        self.state = self.STATE_STEPPING
        return P.ErrorCode.OK, 0xFF

    def _cmd_SetShaper(self, m):
        """SET_SHAPER (version 3): the FIR taps of the run reference; checks as the firmware."""
        n = m.n_taps
        if n > P.SHAPER_MAX_TAPS:
            return P.ErrorCode.BAD_VALUE, 0
        total = np.float32(0.0)
        for i, a in enumerate(m.amplitudes):
            bad = not _finite(float(a)) or not abs(_f32(float(a))) <= P.SHAPER_MAX_AMPLITUDE
            if bad or (i >= n and a != 0.0):
                return P.ErrorCode.BAD_VALUE, 1
            total = np.float32(total + np.float32(a))
        if n and not abs(float(np.float32(total - np.float32(1.0)))) <= _f32(P.SHAPER_SUM_TOL):
            return P.ErrorCode.BAD_VALUE, 1
        for i, d in enumerate(m.delays):
            if (d > P.SHAPER_MAX_DELAY) if i < n else d != 0:
                return P.ErrorCode.BAD_VALUE, 2
        self.shaper = m
        return P.ErrorCode.OK, 0xFF

    @property
    def _shaper_delay(self) -> int:
        m = self.shaper
        return max(m.delays[: m.n_taps], default=0)

    def _shape(self, position):
        """The firmware's ``Shaper`` (:class:`FixedShaper`, bit for bit on the Q32.32 reference in
        counts): the shaped position (rad), its velocity (rad/s) and acceleration (rad/s^2)
        from the Q16.16 backward differences (PROTOCOL.md SET_SHAPER)."""
        cpr = self.plant.counts_per_rev / (2.0 * math.pi)
        Rs, v, a = self._fir.apply(int(round(position * cpr * 4294967296.0)))
        self._fir.prepare()
        Ts = self._shp_Ts
        return Rs / 4294967296.0 / cpr, v / 65536.0 / cpr / Ts, a / 65536.0 / cpr / (Ts * Ts)

    def _cmd_Step(self, m):
        checks = [
            _finite(m.voltage) and abs(m.voltage) <= self.limits.max_voltage,
            self._ts_ok(m.Ts_us),
            m.n_samples >= 1,
        ]
        bad = _first_false(checks)
        if bad is not None:
            return P.ErrorCode.BAD_VALUE, bad
        self._step_Ts = m.Ts_us * 1e-6
        self._step_pwm = self._to_pwm(m.voltage)
        self._seq_volts = None
        self._n_total = m.n_samples
        self._decimation = 1
        self._start(self._step_Ts)
        self.state = self.STATE_STEPPING
        return P.ErrorCode.OK, 0xFF

    def _cmd_HostLoop(self, m):
        """HOST_LOOP (PROTOCOL.md "Host-in-the-loop"): the host closes the loop every tick."""
        checks = [
            P.HOST_LOOP_MIN_TS_US <= m.Ts_us <= P.HOST_LOOP_MAX_TS_US and self._ts_ok(m.Ts_us),
            m.n_samples >= 1,
            m.max_misses >= 1,
        ]
        bad = _first_false(checks)
        if bad is not None:
            return P.ErrorCode.BAD_VALUE, bad
        self._step_Ts = m.Ts_us * 1e-6
        self._n_total = m.n_samples
        self._decimation = 1
        self._seq_volts = None
        self._hl_max_misses = m.max_misses
        self._hl_volts = 0.0  # the voltage in effect (V), held on a miss
        self._hl_next = None  # (volts, reference or None) for the next tick, if in time
        self._hl_ref = None
        self._hl_sent_at = None
        self._hl_misses = self._hl_run = 0
        L = self.limits
        self._max_error = float(L.max_error)
        self._runaway_pwm = (self._pwm_top() + 1) // 2
        self._runaway_n = (int(L.runaway_ms) * 1000 + m.Ts_us - 1) // m.Ts_us
        self._run_sign = self._run_len = self._moved = 0
        self._sat_n = (int(L.saturation_ms) * 1000 + m.Ts_us - 1) // m.Ts_us
        self._sat_level = 0
        self._last_pwm = 0
        self._prev_counts = 0
        self._start(self._step_Ts)
        self.state = self.STATE_HOSTLOOP
        return P.ErrorCode.OK, 0xFF

    def _host_voltage(self, frame, m):
        """HOST_VOLTAGE: kept for the next tick if it answers the last HOST_SAMPLE within Ts;
        a late or stale one is dropped (that tick is a miss), a non-finite one refused."""
        if self.state != self.STATE_HOSTLOOP:
            return self._nack(frame, P.ErrorCode.NOT_READY)
        if not _finite(m.voltage):
            return self._nack(frame, P.ErrorCode.BAD_VALUE, 1)
        if m.flags & P.HOST_VOLTAGE_REFERENCE and not _finite(m.reference):
            return self._nack(frame, P.ErrorCode.BAD_VALUE, 2)
        if m.index != self._k - 1 or self._hl_sent_at is None:
            return None  # not the answer to the last sample: too late
        if self.clock() - self._hl_sent_at > self._step_Ts:
            return None  # after the next tick's deadline
        ref = float(m.reference) if m.flags & P.HOST_VOLTAGE_REFERENCE else None
        self._hl_next = (float(m.voltage), ref)
        return None

    def _host_tick(self, k, counts):
        """One HOST_LOOP tick: the host's voltage (or the held one), the safety stops, the
        sample out. Returns ``(fault, detail)``."""
        flags = 0
        fault, detail = None, 0.0
        if k > 0:
            if self._hl_next is not None:
                self._hl_volts, self._hl_ref = self._hl_next
                self._hl_run = 0
            else:
                self._hl_misses = min(self._hl_misses + 1, 0xFFFF)
                self._hl_run = min(self._hl_run + 1, 0xFF)
                flags |= P.HOST_SAMPLE_MISSED
        self._hl_next = None
        cpr = self.plant.counts_per_rev / (2.0 * math.pi)
        err = 0.0 if self._hl_ref is None else self._hl_ref - counts / cpr
        fault, detail = self._check_safety(counts, err)
        if fault is None and self._hl_run >= self._hl_max_misses:
            fault, detail = P.EndReason.HOST_MISSES, float(self._hl_run)
        if fault is None:
            self.pwm = self._to_pwm(self._hl_volts)
            if abs(self.pwm) >= self._pwm_top() and self._hl_volts != 0.0:
                self._sat_level += 1
            elif self._sat_level:
                self._sat_level -= 1
            if self._sat_n and self._sat_level >= self._sat_n:
                fault, detail = P.EndReason.SATURATION, 0.0
        if fault is not None:
            self.pwm = 0
            flags |= P.TELEMETRY_FAULT
        self._last_pwm = self.pwm
        self._prev_counts = counts
        self._send(P.HostSample(k, counts, self.pwm, self._hl_misses, self._hl_run, flags))
        self._hl_sent_at = self.clock()
        return fault, detail

    def _start(self, Ts):
        self._Ts = Ts
        self._applied_volts = 0.0  # PWM 0 until the first sample's is written
        self._k = 0
        self._count0 = self._counts()
        self._prev_y = None

    # ------------------------------------------------------------------ control
    #: reference samples computed at a time (memory per run is bounded by this, not the plan)
    REF_BLOCK = 512

    def _reference(self, k):
        """Position, velocity, acceleration of the profile at t = k Ts (k counts up)."""
        i = k - self._ref_k0
        if self._ref is None or i >= len(self._ref[0]):
            self._ref_k0 = k
            n = max(1, min(self.REF_BLOCK, self._n_total - k))
            t = (k + np.arange(n)) * self._Ts
            s = self._profile.sample(t)
            ref = [
                np.atleast_1d(np.asarray(v, float)).copy()
                for v in (s.position, s.velocity, s.accel)
            ]
            kk = k + np.arange(n)
            for (t0, piece), k0 in zip(self._pieces[1:], self._piece_k[1:]):
                sel = kk >= k0  # re-targeted plans, from their first sample
                if sel.any():
                    x, v, a, _ = piece.sample(t[sel])
                    ref[0][sel], ref[1][sel], ref[2][sel] = x, v, a
            self._ref = tuple(ref)
            i = 0
        return self._ref[0][i], self._ref[1][i], self._ref[2][i]

    # ------------------------------------------------------------------ re-targeting
    def _retarget_segment(self, frame, m):
        """PLAN_SEGMENT during a run (PROTOCOL.md "Re-targeting"): into the second buffer;
        index 0 cancels a switch not yet taken over."""
        bad = P.check_plan_segment(m, len(self._rt_segs))
        if bad is not None:
            return self._nack(frame, P.ErrorCode.BAD_VALUE, bad)
        if m.index == 0:
            self._rt_segs = []
            self._retargeted = True  # (the plan's buffer is written: consumed at the end)
            if self._switch is not None:  # the pending plan's buffer is rewritten
                self._pieces.pop()
                self._piece_k.pop()
                self._switch = None
                self._ref = None
                # the run ends with the running plan again
                self._n_total = 2**62 if self._hold else self._n_profile + self._settle
        self._rt_segs.append(m)
        return self._send(P.Ack(frame.type), frame.seq)

    def _retarget(self, frame, m):
        """RETARGET (PROTOCOL.md "Re-targeting"): the host's plan takes over at the sample it
        names, checked in the firmware's order."""
        if self.state != self.STATE_RUNNING:
            return self._nack(frame, P.ErrorCode.NOT_READY)
        bad = P.check_retarget(m, len(self._rt_segs))
        if bad is not None:
            return self._nack(frame, P.ErrorCode.BAD_VALUE, bad)
        if m.base != self._rt_gen:
            return self._nack(frame, P.ErrorCode.LATE, 2)
        t0, acc, cruise, dur = self._run_times
        tc0 = _f32(np.float32(t0) + np.float32(acc))
        tc1 = _f32(np.float32(tc0) + np.float32(cruise))
        t_end = _f32(np.float32(t0) + np.float32(dur))
        ts = _f32(m.t_switch)
        if not (tc0 <= ts <= tc1 or ts >= t_end):
            return self._nack(frame, P.ErrorCode.BAD_VALUE, 1)
        Ts_us = self.gains.Ts_us
        Ts = _f32(np.float32(Ts_us) * np.float32(1e-6))
        if m.switch_index != R.first_sample(ts, Ts):
            return self._nack(frame, P.ErrorCode.BAD_VALUE, 0)
        if m.switch_index < self._k + R.RETARGET_LEAD:
            return self._nack(frame, P.ErrorCode.LATE, 0)
        self._send(P.Ack(frame.type), frame.seq)
        new = R.placed_segments(self._rt_segs, m.target, ts)
        self._rt_segs = []  # (the next plan starts at index 0)
        self._retargeted = True
        self._pieces.append((ts, new))
        self._piece_k.append(m.switch_index)
        self._ref = None  # re-sample from the current sample on
        n_profile = int(math.ceil((ts + new.duration) / (Ts_us * 1e-6) - 1e-4)) + 1
        times = (ts, _f32(m.accel_time), _f32(m.cruise_time), new.duration)
        self._switch = (m.switch_index, n_profile + self._shp_delay, bool(m.flags & 1), times)
        self._n_total = 2**62  # the run lasts until the new plan's end
        return None

    def _pwm_top(self) -> int:
        """lround(max_voltage * pwm_max / supply), at most pwm_max (PROTOCOL.md step 4)."""
        top = int(
            math.floor(self.limits.max_voltage * self.pwm_max / self.plant.supply_voltage + 0.5)
        )
        return min(top, self.pwm_max)

    def _to_pwm(self, u: float) -> int:
        return int(
            _pwm_duty(u, self.plant.supply_voltage, self.pwm_max, self._pwm_top())
        )  # lround, clamp (jerklab.law)

    def _check_safety(self, counts: int, pos_error: float):
        """The safety stops of PROTOCOL.md at one run sample: ``(reason, detail)``, or
        ``(None, 0.0)`` when the run goes on."""
        if self._max_error > 0 and not abs(pos_error) <= self._max_error:
            return P.EndReason.TRACKING_ERROR, pos_error
        if self._runaway_n == 0:
            return None, 0.0
        lp = self._last_pwm
        sign = 1 if lp >= self._runaway_pwm else (-1 if lp <= -self._runaway_pwm else 0)
        if sign == 0:
            self._run_sign = self._run_len = self._moved = 0
            return None, 0.0
        if sign != self._run_sign:
            self._run_sign, self._run_len, self._moved = sign, 0, 0
        self._moved += sign * (counts - self._prev_counts)
        self._run_len += 1
        if self._run_len < self._runaway_n:
            return None, 0.0
        moved = self._moved
        self._run_len = self._moved = 0
        if moved > 0:
            return None, 0.0
        return (P.EndReason.RUNAWAY if moved < 0 else P.EndReason.NO_MOTION), float(moved)

    def tick(self) -> None:
        """One control period: watchdog, sample, control, telemetry, then the motor moves."""
        self._expire_partial(self.clock())
        if not self.active:
            return
        tmo = self.limits.host_timeout_ms
        if tmo and (self.clock() - self.last_rx) * 1000.0 > tmo:
            self.pwm = 0
            self._end(P.EndReason.HOST_TIMEOUT)
            return
        k = self._k
        if self.state == self.STATE_RUNNING and self._switch is not None and k >= self._switch[0]:
            _, n_profile, hold, self._run_times = self._switch  # the re-targeted plan took over
            self._switch = None
            self._rt_gen = (self._rt_gen + 1) & 0xFF
            self._n_profile = n_profile
            # a braking plan holds the run at its end for the RETARGET that follows
            self._n_total = 2**62 if hold else n_profile + self._settle
            self._hold = hold
        counts = self._counts() - self._count0
        flags = 0
        fault = None
        if self.state == self.STATE_RUNNING:
            cpr = self.plant.counts_per_rev / (2.0 * math.pi)
            y = counts / cpr
            rp, rv, ra = self._reference(k)
            if self.shaper.n_taps:
                rp, rv, ra = self._shape(rp)
            if k >= self._n_profile:
                flags |= P.TELEMETRY_SETTLING
            fault, detail = self._check_safety(counts, rp - y)
            if fault is not None:
                self.pwm = 0  # stopped in this very sample
                flags |= P.TELEMETRY_FAULT
            else:
                u = self._ctrl.step(rp, rv, ra, y)
                if self._ctrl.last_parts["saturated"]:
                    flags |= P.TELEMETRY_SATURATED
                    self._sat_level += 1
                elif self._sat_level:
                    self._sat_level -= 1
                if self._sat_n and self._sat_level >= self._sat_n:
                    fault, detail = P.EndReason.SATURATION, 0.0  # PROTOCOL.md stop 3
                    self.pwm = 0
                    flags |= P.TELEMETRY_FAULT
                else:
                    self.pwm = self._to_pwm(u)
            self._last_pwm = self.pwm
            self._prev_counts = counts
            ref = float(rp)
        elif self.state == self.STATE_HOSTLOOP:
            fault, detail = self._host_tick(k, counts)
            ref = None
        elif self._seq_volts is not None:
            ref = self._seq_volts[k]  # SEQUENCE: the commanded volts as the reference
            self.pwm = self._seq_pwm[ref]
        else:
            self.pwm = self._step_pwm
            ref = 0.0
        if ref is not None and (k % self._decimation == 0 or fault is not None):
            self._send(P.Telemetry(k, ref, counts, self.pwm, flags))
        if fault is not None:
            self._k = k + 1
            self._end(fault, detail)
            return
        volts = (
            self.lead_sign
            * self.pwm
            / self.pwm_max
            * self.motor.supply_voltage
            * self.supply_fraction
        )  # H-bridge
        if (
            self.hand
            and self.state == self.STATE_STEPPING
            and self.pwm == 0
            and k < self._n_total - 1
        ):
            # between the first and the last sample's reading (a hair more than the turn: a count
            # is floored, and the sum of the steps may round down)
            turn = 2.0 * math.pi * float(self.hand) / max(1, self._n_total - 1) * (1.0 + 1e-9)
            self.x[0] += turn  # the motor's angle (and a flexible load's, turned with it)
            if self.motor.n_states == 4:
                self.x[2] += turn
        d = self.compute_delay if self.state == self.STATE_RUNNING else 0.0
        if d > 0.0:
            # the previous sample's PWM until the board has written the new one
            self.x = self.motor.step_state(self.x, self._applied_volts, d, t=self.t)
        self.x = self.motor.step_state(self.x, volts, self._Ts - d, t=self.t + d)
        self._applied_volts = volts
        self.t += self._Ts
        self._k = k + 1
        if self._k >= self._n_total:
            self.pwm = 0
            self._end(P.EndReason.DONE)

    def host_gone(self) -> None:
        """The host went away (a TCP client closed its socket): stop the motor, end an
        active run, and forget the output and any partial frame of that host, so that
        nothing of its run reaches the next client."""
        if self.active:
            self.pwm = 0
            self._end(P.EndReason.STOPPED)
        self._decoder.flush()
        self._out.clear()

    def _end(self, reason, detail=0.0):
        samples = self._k
        if getattr(self, "_retargeted", False):
            self.plan = None  # consumed, as on the board (PLAN again before RUN)
            self._retargeted = False
        self.state = self.STATE_IDLE
        self._ref = None
        self._send(P.EndOfRun(int(reason), samples, self.rx_errors, self.overruns, float(detail)))
        # between runs the motor coasts to rest (PWM 0 for 1 s of model time)
        self.x = self.motor.step_state(self.x, 0.0, 1.0, t=self.t)
        self.t += 1.0
        if len(self.x) == 4:
            # a flexible load still rings after 1 s of a lightly damped mode: at rest at once
            self.x = np.array([self.x[0], 0.0, self.x[0], 0.0])


def _first_false(checks):
    for i, ok in enumerate(checks):
        if not ok:
            return i
    return None


class VirtualSerial:
    """A pyserial-like link to an in-process :class:`VirtualDevice`.

    ``read`` runs the device's control ticks when the host waits for bytes, so a run
    goes as fast as the host reads (``speed=None``) or at ``speed`` times real time.

    Fault injection (for tests and teaching): ``pull_cable_after`` bytes received by
    the host, then every call raises ``serial.SerialException`` like a USB cable
    pulled out; ``freeze_after`` bytes, then the device goes silent (a hung board).
    """

    #: the device's motor coasts to rest at once between runs (the client need not wait)
    instant_coast = True

    def __init__(
        self,
        device: VirtualDevice | None = None,
        speed: float | None = None,
        timeout=1.0,
        pull_cable_after: int | None = None,
        freeze_after: int | None = None,
        port="virtual",
    ):
        self.device = VirtualDevice() if device is None else device
        if speed is not None and not (isinstance(speed, (int, float)) and speed > 0):
            raise ValueError(f"speed must be > 0 or None (as fast as possible), got {speed!r}")
        self.speed = None if speed is None or math.isinf(speed) else float(speed)
        self.timeout = timeout
        self.port = port
        self.is_open = True
        self._delivered = 0
        self._pull_after = pull_cable_after
        self._freeze_after = freeze_after
        self._t0_wall = time.monotonic()
        self._t0_model = self.device.t
        self._paced = False  # the anchor above belongs to the run going on

    # pyserial API -------------------------------------------------------------
    def _check(self):
        import serial

        if not self.is_open:
            raise serial.SerialException("port is closed")
        if self._pull_after is not None and self._delivered >= self._pull_after:
            raise serial.SerialException("device disconnected (cable pulled)")

    def write(self, data) -> int:
        self._check()
        self.device.receive(bytes(data))
        return len(data)

    def flush(self):
        self._check()

    @property
    def in_waiting(self) -> int:
        self._check()
        self.device.poll()
        return self._limit(self.device.output_pending)

    def _limit(self, n):
        for cap in (self._pull_after, self._freeze_after):
            if cap is not None:
                n = min(n, max(0, cap - self._delivered))
        return n

    def _produce(self, deadline):
        """Run ticks until the device has output or the deadline passes.

        At ``speed``, each run is paced from its own start: the model's clock stands still
        while the device is idle, so an anchor kept from before would let a run after a
        pause go as fast as the host reads until it caught up with the pause (as
        :class:`jerklab.rig.server.DeviceServer` does, a run starts in real time).
        """
        dev = self.device
        if self.speed is not None and dev.active and not self._paced:
            self._t0_wall, self._t0_model = time.monotonic(), dev.t
        self._paced = dev.active
        while dev.output_pending == 0 and dev.active:
            if self.speed is not None:
                due = self._t0_wall + (dev.t - self._t0_model) / self.speed
                wait = due - time.monotonic()
                if wait > 0:
                    if time.monotonic() + wait > deadline:
                        time.sleep(max(0.0, deadline - time.monotonic()))
                        return
                    time.sleep(wait)
            else:
                self._t0_wall, self._t0_model = time.monotonic(), dev.t
            dev.tick()
        self._paced = dev.active

    def read(self, size: int = 1) -> bytes:
        self._check()
        timeout = 1e9 if self.timeout is None else self.timeout
        deadline = time.monotonic() + timeout
        frozen = self._freeze_after is not None and self._delivered >= self._freeze_after
        if not frozen:
            self._produce(deadline)
        n = self._limit(min(size, self.device.output_pending))
        while n == 0:
            # a blocking read: wait for output (a frame the device finds once a partial one
            # expires) or the timeout
            left = deadline - time.monotonic()
            if left <= 0:
                self._check()
                return b""
            time.sleep(min(left, 0.005))
            self._check()
            if not frozen:
                self.device.poll()
            n = self._limit(min(size, self.device.output_pending))
        self._delivered += n
        return self.device.read_output(n)

    def reset_input_buffer(self):
        self._check()
        self.device.read_output()

    def close(self):
        self.is_open = False

    def __repr__(self):
        return f"VirtualSerial(speed={self.speed!r}, device={self.device.name!r})"
