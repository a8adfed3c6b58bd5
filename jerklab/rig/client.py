"""The rig client: one API for the virtual rig, the firmware on simavr and a real Uno.

It speaks ``jerklab.protocol`` over anything with pyserial's ``read``/``write``
(a ``serial.Serial``, a ``socket://`` URL, a pseudo-terminal, the in-process
:class:`~jerklab.rig.virtual.VirtualSerial`), like TCLab's hardware/model swap. The control law
it configures is Stojčić's (ASCII: Stojcic eqs. 16–18). Progress
bars: :mod:`jerklab.rig.progress` (tqdm); live plots of the runs: :mod:`jerklab.rig.live`.
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import datetime as _dt
import json
import math
import sys
import time
import warnings
from pathlib import Path

from jerklab import paper
from jerklab import planner as _planner
from jerklab import protocol as P
from jerklab._validate import as_int, as_nonnegative, as_positive, as_real
from jerklab.controller import DiscreteGains, Gains, max_pole_radius
from jerklab.rig import retarget as _R
from jerklab.rig.hostloop import RealtimeLoop, run_law
from jerklab.rig.live import Tee as _Tee
from jerklab.rig.live import live_plot as _live_plot
from jerklab.rig.options import F32_MAX as _F32_MAX
from jerklab.rig.options import RunSpec
from jerklab.rig.progress import NoProgress as _NoProgress
from jerklab.rig.progress import progress as _progress
from jerklab.rig.recording import Recording, RecordingIOError, recordings_dir

__all__ = [
    "Rig",
    "RigError",
    "RigConnectionError",
    "RigTimeoutError",
    "RigCommandError",
    "RigRunError",
    "RigBusyError",
    "UnstableDesignError",
    "UnknownPortError",
    "PortBusyError",
]


class RigError(RuntimeError):
    """Anything that went wrong talking to a rig."""


class UnknownPortError(RigError, ValueError):
    """The port could not be opened (no such device, bad URL, nothing listening)."""


class RigConnectionError(RigError, ConnectionError):
    """The link broke (cable pulled, pty or socket closed)."""


class RigTimeoutError(RigError, TimeoutError):
    """The device did not answer in time."""


class RigCommandError(RigError, ValueError):
    """The device refused a command (NACK); the message names the parameter."""

    def __init__(self, message, command=None, error=None, param=None):
        super().__init__(message)
        self.command, self.error, self.param = command, error, param


class RigRunError(RigError):
    """A run ended early on the device (STOP, host watchdog, fault).

    ``status`` is the recording's final status, e.g. ``"fault: tracking error 0.52 rad >
    limit 0.5 rad at t=0.84 s"``; ``recording`` the samples received.
    """

    def __init__(self, message, status=None, recording=None):
        super().__init__(message)
        self.status, self.recording = status, recording


class RigBusyError(RigConnectionError):
    """The rig is already in use by another client (a served rig answers a second client so)."""


class PortBusyError(UnknownPortError, RigBusyError):
    """The port is held by another program (opened exclusively, or locked by another jerklab
    process); ``holder`` says who (pid, host, program), if known. Both an
    :class:`UnknownPortError` (the port could not be opened) and a :class:`RigBusyError`."""

    def __init__(self, message, port=None, holder=None):
        super().__init__(message)
        self.port, self.holder = port, holder


class UnstableDesignError(RigError, ValueError):
    """``run_move`` refused a design whose sampled closed loop has a pole with ``|z| >= 1``."""


_KIND_TO_PLANNER = {
    "sine_jerk": P.Planner.SINE_JERK,
    "sine_jerk_optimal": P.Planner.SINE_JERK_OPTIMAL,
    "scurve": P.Planner.SCURVE,
    "trapezoid": P.Planner.TRAPEZOID,
}
#: END_OF_RUN reasons that are faults (the run's status then reads "fault: ...")
_FAULTS = (
    P.EndReason.FAULT,
    P.EndReason.TRACKING_ERROR,
    P.EndReason.RUNAWAY,
    P.EndReason.NO_MOTION,
    P.EndReason.SATURATION,
)


class _Retargeter:
    """The host side of re-targeting one run (firmware/PROTOCOL.md "Re-targeting"): the plan
    the device steps, the switch sent and not yet taken over, and the retries of a late one.

    The margin between the host's latest sample and the switch it names is
    :func:`jerklab.rig.retarget.margin_samples`: the device's lead, the line time of the
    largest set of frames (:data:`jerklab.protocol.MAX_PLAN_SEGMENTS` PLAN_SEGMENTs and the
    RETARGET) at the link's baud rate, and an allowance of 50 ms doubled at each retry.
    """

    def __init__(self, running, limits, Ts, decimation, baudrate):
        self.running, self.limits, self.Ts = running, limits, float(Ts)
        self.decimation, self.baudrate = int(decimation), float(baudrate)
        self.gen = 0  # re-targeted plans that took over (the device's count, mod 256)
        self.pending = None  # the SwitchPlan sent, not yet taken over
        self.maybe = None  # a pending one whose buffer a new plan rewrote (taken over first?)
        self.target = None  # the newest target
        self.todo = []  # targets to send
        self.late = []  # the switch samples the device refused as late (then retried)
        self.switches = []  # [k_earliest, target, k_switch] of each switch the device took
        seg = len(P.encode(P.PlanSegment(0, 0, 1.0, 0.0, 0.0, 0.0, 0.0)))
        self.n_bytes = P.MAX_PLAN_SEGMENTS * seg + len(P.encode(P.Retarget(0, 0.0, 0, 1, 0.0)))

    def on_index(self, index):
        """A TELEMETRY of sample ``index``: True when a braking plan just took over."""
        if self.pending is not None and index >= self.pending.k_switch:
            self.running, self.pending = self.pending.running, None
            self.gen = (self.gen + 1) & 0xFF
            return self.running.hold
        return False

    def send(self, target, index, reply_to, refused):
        """Plan the switch to ``target`` (``index()``: the next sample the host expects) and
        send it; retried later on NACK LATE (at most
        :data:`jerklab.rig.retarget.RETARGET_TRIES` times), refusals recorded by ``refused``."""
        self.target = target
        for attempt in range(_R.RETARGET_TRIES):
            k = index() + _R.margin_samples(
                self.n_bytes, self.Ts, self.baudrate, attempt, self.decimation
            )
            try:
                sw = _R.plan_switch(self.running, k, target, self.Ts, *self.limits, base=self.gen)
            except ValueError as exc:
                refused("NOT_PLANNED", str(exc))
                return
            for seg in sw.segments:
                if seg.index == 0 and self.pending is not None:
                    self.maybe, self.pending = self.pending, None  # rewritten unless taken over
                r = reply_to(seg)
                if r is None:
                    return  # the run ended
                if isinstance(r, P.Nack):
                    refused(_error_name(r.error), P.payload_field_name(seg.TYPE, r.param))
                    return
            r = reply_to(sw.message)
            if r is None:
                return
            if isinstance(r, P.Ack):
                self.pending, self.maybe = sw, None
                self.switches.append([k, float(target), sw.k_switch])
                return
            if r.error == P.ErrorCode.LATE:
                self.late.append(sw.k_switch)
            if r.error == P.ErrorCode.LATE and r.param == 2 and self.maybe is not None:
                # the plan sent before had taken over: plan from it
                self.running, self.maybe = self.maybe.running, None
                self.gen = (self.gen + 1) & 0xFF
            elif r.error == P.ErrorCode.LATE:
                self.maybe = None  # (the device's plan is the host's: it was rewritten)
            else:
                refused(_error_name(r.error), P.payload_field_name(sw.message.TYPE, r.param))
                return
        refused(
            "LATE",
            f"the device refused the switch as late {_R.RETARGET_TRIES} times (the last at "
            f"sample {sw.k_switch}): the move goes on to its previous target",
        )
        warnings.warn(
            f"retarget({target!r}) was refused as late {_R.RETARGET_TRIES} times: the link or "
            f"the host is too slow for the margin; the move goes on to its previous target",
            RuntimeWarning,
            stacklevel=2,
        )


def _error_name(code):
    return P.ErrorCode(code).name if code in iter(P.ErrorCode) else int(code)


class Rig:
    """A connected rig (use :func:`jerklab.rig.connect` to make one).

    Parameters
    ----------
    link : pyserial-like
        Open link with ``read``, ``write``, ``in_waiting``, ``close``.
    port : str
        Name shown in messages and stored in recordings.
    supply_voltage : float
        H-bridge supply (V): PWM full scale. 12 V on the paper's rig.
    counts_per_rev : int
        Encoder counts per revolution after decoding (448: channel A edges of the paper's encoder).
    model : (K, tau)
        Motor model used for the feedforward (Stojčić eq. 8); update it after identification
        with :meth:`set_model`.
    timeout : float
        Seconds to wait for a reply or the next telemetry frame.
    hello_timeout : float
        Seconds to keep repeating HELLO after opening (an Uno reboots when the port opens).
    progress : bool
        Show a progress bar during runs: an ipywidgets bar inside a Jupyter kernel (JupyterLab,
        Notebook, Voilà), a one-line text bar in a terminal; False shows nothing.
    live : bool or None
        Live plot of every run (:mod:`jerklab.rig.live`): None (default) or True draws one in
        a Jupyter kernel as the samples arrive (nothing outside a kernel); False draws none;
        None follows ``$JERKLAB_LIVE_PLOT`` (``0`` turns it off). Each run's ``live=``
        overrides it.
    recordings : path or None
        Directory for recordings (default ``$JERKLAB_RECORDINGS`` or ``./recordings``).
    metadata : mapping, optional
        Fields of the rig's owner (JSON-able, string keys) that every recording carries in its
        metadata under ``"caller"`` (e.g. who ran it); the rig does not read them.
    """

    def __init__(
        self,
        link,
        port="?",
        *,
        supply_voltage=paper.SUPPLY_VOLTAGE,
        counts_per_rev=paper.ENCODER_PPR * paper.ENCODER_DECODING,
        model=(paper.MOTOR_K, paper.MOTOR_TAU),
        timeout=2.0,
        hello_timeout=3.0,
        progress=True,
        recordings=None,
        on_close=None,
        metadata=None,
        live=None,
    ):
        self.link = link
        #: True when the device's motor is at rest at once after every run (the virtual rig:
        #: :meth:`step` and :meth:`record_prbs` then skip :meth:`wait_still`); a served virtual
        #: rig, whose link is a pty, says so through its owner (the grader's rig)
        self.instant_coast = bool(getattr(link, "instant_coast", False))
        self.port = str(port)
        self.supply_voltage = as_positive("supply_voltage", supply_voltage)
        if int(counts_per_rev) != counts_per_rev or counts_per_rev < 1:
            raise ValueError(f"counts_per_rev must be a positive integer, got {counts_per_rev!r}")
        self.counts_per_rev = int(counts_per_rev)
        self.set_model(*model)
        self._shaper = None  # SetShaper sent before each move (set_shaper)
        self.timeout = as_positive("timeout", timeout)
        self.progress = bool(progress)
        self.live = _as_live("live", live)
        #: where a live plot goes: None (the cell's output), or ``display(widget)`` putting
        #: the plot's widget in a page of one's own (the tuning panel's live box)
        self.live_display = None
        self.recordings = Path(recordings) if recordings is not None else None
        #: the :class:`Recording` of the run in progress (else of the last run, or None): a
        #: callback of the run (``on_telemetry``) or another thread may read its rows as they
        #: arrive (:meth:`Recording.rows`), e.g. to forward them to the run's owner
        self.recording = None
        self.metadata = _caller_metadata(metadata)
        self._on_close = on_close
        self._decoder = P.Decoder()
        self._last_byte = time.monotonic()
        self._seq = 0
        self._frames: list[P.Frame] = []
        self.ignored_frames = 0
        self._retargets = collections.deque()  # RETARGETs waiting for the run loop to send
        self._streaming = False
        self._host_planned = False  # the last move: segments of no planner's own result
        self._rt = None  # the running move's re-targeting state (_Retargeter)
        self.closed = False
        try:
            self.info = self._hello(as_positive("hello_timeout", hello_timeout))
        except BaseException:
            self.close()
            raise
        if self.info.protocol_version != P.PROTOCOL_VERSION:
            self.close()
            raise RigError(
                f"{self.port}: device speaks protocol version {self.info.protocol_version}, "
                f"jerklab speaks {P.PROTOCOL_VERSION}: update the firmware or jerklab"
            )
        try:
            self.stop()  # a run left over from a host that went away ends here
        except BaseException:
            self.close()
            raise

    # ---------------------------------------------------------------- basics
    @property
    def counts_per_rad(self) -> float:
        return self.counts_per_rev / (2.0 * math.pi)

    @property
    def firmware_version(self) -> str:
        return self.info.firmware_version

    @property
    def name(self) -> str:
        return self.info.name

    @property
    def capabilities(self) -> P.Capability:
        return P.Capability(self.info.capabilities)

    @property
    def is_virtual(self) -> bool:
        return bool(self.capabilities & P.Capability.SIMULATED_PLANT)

    def set_model(self, K, tau):
        """Motor model for the feedforward: K rad/(V s), tau s (Stojčić eqs. 1, 8)."""
        self.model = (as_positive("K", K), as_positive("tau", tau))

    def device_info(self) -> dict:
        i = self.info
        return {
            "name": i.name,
            "firmware_version": i.firmware_version,
            "protocol_version": i.protocol_version,
            "capabilities": [c.name for c in P.Capability if c & i.capabilities],
            "tick_us": i.tick_us,
            "pwm_max": i.pwm_max,
            "port": self.port,
        }

    def __repr__(self):
        state = "closed" if self.closed else "open"
        return (
            f"Rig(port={self.port!r}, device={self.info.name!r}, firmware={self.firmware_version}, "
            f"{state})"
        )

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Close the link (and stop a server or simulator the rig started)."""
        if self.closed:
            return
        self.closed = True
        try:
            self.link.close()
        except Exception:
            pass
        if self._on_close is not None:
            self._on_close()

    # ---------------------------------------------------------------- I/O
    def _io_error(self, exc, what):
        return RigConnectionError(f"{self.port}: connection lost while {what}: {exc}")

    def _write(self, msg) -> int:
        import serial

        if self.closed:
            raise RigError(f"{self.port}: rig is closed")
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFF
        try:
            self.link.write(P.encode(msg, seq))
        except (serial.SerialException, OSError) as exc:
            raise self._io_error(exc, f"sending {type(msg).__name__}") from exc
        return seq

    def _read_frames(self, wait: float) -> list[P.Frame]:
        """Frames that arrive within ``wait`` seconds (returns as soon as there are some)."""
        import serial

        if self._frames:
            out, self._frames = self._frames, []
            return out
        deadline = time.monotonic() + wait
        while True:
            try:
                n = self.link.in_waiting
                data = self.link.read(n if n > 0 else 1)
            except (serial.SerialException, OSError) as exc:
                raise self._io_error(exc, "reading") from exc
            now = time.monotonic()
            if data:
                self._last_byte = now
                frames = self._decoder.feed(data)
                if frames:
                    return frames
            elif self._decoder.pending and now - self._last_byte > 0.02:
                # A truncated frame must not hold back a good one behind it: after 20 ms of
                # silence look for a frame inside the held bytes, and give up the head only if
                # one is there. A frame whose sender merely stalled (a loaded simulator, a TCP
                # segment held back) is kept and completes when its bytes come.
                probe = copy.deepcopy(self._decoder)
                frames = probe.flush()
                if frames:
                    self._decoder = probe
                    return frames
            if now >= deadline:
                return []

    def _request(self, msg, replies=(P.MsgType.ACK,), timeout=None):
        """Send a command and wait for its reply (same seq); NACK raises RigCommandError."""
        seq = self._write(msg)
        timeout = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise RigTimeoutError(
                    f"{self.port}: no reply to {type(msg).__name__} within {timeout:g} s"
                )
            frames = self._read_frames(min(left, 0.05))
            for i, f in enumerate(frames):
                self._check_busy(f)
                if f.seq == seq and f.type in (P.MsgType.NACK, *replies):
                    self._frames = frames[i + 1 :] + self._frames
                    reply = P.parse(f)
                    if isinstance(reply, P.Nack):
                        raise self._nack_error(msg, reply)
                    return reply
                self.ignored_frames += 1

    def _check_busy(self, frame):
        """A served rig that already has a client answers ERROR(BUSY) and closes."""
        if frame.type == P.MsgType.ERROR:
            try:
                e = P.DeviceError.unpack(frame.payload)
            except P.ProtocolError:
                return
            if e.code == P.ErrorCode.BUSY:
                raise RigBusyError(f"{self.port}: rig busy: already in use by another client")

    def _nack_error(self, msg, nack):
        try:
            err = P.ErrorCode(nack.error).name
        except ValueError:
            err = f"error {nack.error}"
        name = type(msg).__name__
        if nack.error == P.ErrorCode.TOO_LONG:
            text = (
                f"{self.port}: device refused {name}: the move needs more than "
                f"{P.MAX_PLAN_SAMPLES:,} samples (the device's limit) at this Ts; "
                f"use a shorter move, higher limits or a longer Ts"
            )
            return RigCommandError(text, command=msg.TYPE, error=nack.error, param=nack.param)
        if nack.param != 0xFF:
            field = P.payload_field_name(msg.TYPE, nack.param)
            value = getattr(msg, field, None)
            text = f"{self.port}: device refused {name}: {err} for parameter {field!r} (sent {value!r})"
        else:
            text = f"{self.port}: device refused {name}: {err}"
        return RigCommandError(text, command=msg.TYPE, error=nack.error, param=nack.param)

    _HELLO_EVERY = 0.25

    def _hello(self, hello_timeout):
        """Say HELLO every 0.25 s until a HELLO_REPLY answers any of them, or ``hello_timeout``.

        An Uno resets when its port opens and its bootloader listens for about a second before
        the sketch starts (bytes sent meanwhile go to the bootloader), so one HELLO is not
        enough. Sets ``hello_attempts`` (HELLOs sent) and ``hello_answered`` (which one was
        answered, 1 = the first).
        """
        import serial

        deadline = time.monotonic() + hello_timeout
        sent = {}  # seq -> attempt number
        self.hello_attempts = self.hello_answered = 0
        other = 0
        skipped0 = self._decoder.stats.skipped_bytes
        next_hello = time.monotonic()
        while True:
            now = time.monotonic()
            if now >= next_hello and now < deadline:
                self.hello_attempts += 1
                sent[self._write(P.Hello())] = self.hello_attempts
                next_hello = now + self._HELLO_EVERY
            frames = self._read_frames(max(0.0, min(0.05, deadline - now)))
            for i, f in enumerate(frames):
                if f.type == P.MsgType.HELLO_REPLY and f.seq in sent:
                    self._frames = frames[i + 1 :] + self._frames
                    self.hello_answered = sent[f.seq]
                    return P.parse(f)
                self._check_busy(f)  # a served rig that has a client: BUSY
                other += 1
                self.ignored_frames += 1
            if time.monotonic() >= deadline:
                break
        baud = getattr(self.link, "baudrate", None)
        junk = self._decoder.stats.skipped_bytes - skipped0
        heard = (
            f"; it sent {other} frame(s) that were not a HELLO_REPLY"
            if other
            else f"; it sent {junk} byte(s) that were no jerklab frame (another sketch, or a wrong "
            "baud rate?)"
            if junk
            else "; nothing came back"
        )
        checks = [
            "the port is the rig's (list candidates: python -m jerklab.rig ports)",
            "the jerklab firmware is flashed (with the Arduino IDE: open "
            "firmware/jerklab_rig/jerklab_rig.ino and press Upload, docs/RIG.md; from a clone: "
            "make -C firmware upload PORT=...)",
            "the baud rate (the jerklab firmware runs at 115200"
            + (f", this link at {baud})" if baud else ")"),
            f"the firmware speaks protocol version {P.PROTOCOL_VERSION} (a newer or older "
            "jerklab needs the matching firmware)",
        ]
        if isinstance(self.link, serial.Serial) and sys.platform.startswith("linux"):
            checks.append("no other program (serial monitor, another kernel) talks to it")
        raise RigTimeoutError(
            f"{self.port}: no jerklab rig answered HELLO: sent {self.hello_attempts} HELLO(s) over "
            f"{hello_timeout:g} s"
            + (f" at {baud} baud" if baud else "")
            + heard
            + ". Check: "
            + "; ".join(checks)
            + "."
        )

    def stop(self):
        """Stop the motor now (STOP)."""
        self._request(P.Stop())

    def hello(self) -> P.HelloReply:
        """Ask the device for its identity again."""
        self.info = self._request(P.Hello(), replies=(P.MsgType.HELLO_REPLY,))
        return self.info

    # ---------------------------------------------------------------- configuration
    def _ts_us(self, Ts):
        Ts = as_positive("Ts", Ts)
        tick = self.info.tick_us or 1
        if Ts > 0.065:
            raise ValueError(
                f"Ts must be at most 65 ms (a multiple of the device tick {tick} µs), got {Ts!r} s"
            )
        us = int(round(Ts * 1e6))
        if abs(us - Ts * 1e6) > 1e-3 or us % tick or us < tick:
            raise ValueError(
                f"Ts must be a multiple of the device tick {tick} µs and at most 65 ms, "
                f"got {Ts!r} s"
            )
        return us

    def configure(self, gains, spec=None, limits=None):
        """Send plant, gains and limits (SET_PLANT, SET_GAINS, SET_LIMITS); return them as a dict.

        ``spec`` (a :class:`jerklab.rig.RunSpec`) gives the period, the feedforward, the clamp,
        the host watchdog and the device's safety stops (``max_error`` in rad, 0 = off;
        ``runaway_time`` and ``saturation_time`` in s, 0 = off: firmware/PROTOCOL.md "Safety
        stops"); ``limits`` the planner's (max_jerk, max_accel, max_velocity), default the
        paper's.
        """
        spec = _run_spec(spec)
        us = self._ts_us(spec.period(gains))
        Ts = us * 1e-6
        if isinstance(gains, Gains):
            gains = gains.discretize(Ts)
        if not isinstance(gains, DiscreteGains):
            raise ValueError(
                f"gains must be jerklab.controller Gains or DiscreteGains, got {type(gains).__name__}"
            )
        if abs(gains.Ts - Ts) > 1e-9:
            raise ValueError(
                f"gains were discretized for Ts = {gains.Ts!r} s, the run uses Ts = {Ts!r} s"
            )
        feedforward = spec.feedforward
        K, tau = self.model
        if not isinstance(feedforward, bool):  # a Feedforward (RunSpec checked K and tau)
            K, tau = float(feedforward.K), float(feedforward.tau)
        ff_on = feedforward is not False
        vmax = self.supply_voltage if spec.max_voltage is None else spec.max_voltage
        if vmax > self.supply_voltage:
            raise ValueError(
                f"max_voltage must be <= supply_voltage {self.supply_voltage} V, got {vmax}"
            )
        tmo, emax = spec.host_timeout, spec.max_error
        runaway, sat = spec.runaway_time, spec.saturation_time
        J, E, W = limits if limits is not None else paper.LIMITS
        J = min(as_positive("max_jerk", J), _F32_MAX)
        E, W = as_positive("max_accel", E), as_positive("max_velocity", W)
        loop = P.LoopType.VELOCITY if gains.loop == "velocity" else P.LoopType.POSITION
        # the device's fixed-point PID holds a gain below RUN_GAIN_LIMIT PWM ticks per count (per
        # count per sample in the velocity loop); RUN would be refused without naming the gain
        limit = P.max_run_gain(
            self.counts_per_rev,
            self.info.pwm_max,
            self.supply_voltage,
            Ts if loop == P.LoopType.VELOCITY else None,
        )
        for name in ("kpd", "kid", "kdd"):
            k = getattr(gains, name)
            if math.isfinite(k) and abs(k) >= limit:
                raise ValueError(
                    f"gains.{name} = {k:g} is beyond what the device's PID can hold: |{name}| must be "
                    f"< {limit:.4g} ({P.RUN_GAIN_LIMIT:.0f} PWM ticks per encoder "
                    f"count{' per sample' if loop == P.LoopType.VELOCITY else ''})"
                )
        msgs = [
            P.SetPlant(K, tau, self.supply_voltage, self.counts_per_rev),
            P.SetGains(
                gains.kpd,
                gains.kid,
                gains.kdd,
                us,
                int(loop),
                P.GAINS_FEEDFORWARD if ff_on else 0,
                gains.gamma,
            ),
            P.SetLimits(
                J,
                E,
                W,
                vmax,
                int(round(tmo * 1000)),
                emax,
                int(round(runaway * 1000)),
                int(round(sat * 1000)),
            ),
        ]
        for m in msgs:
            self._request(m)
        return {
            "Ts": Ts,
            "gains": {
                "kpd": gains.kpd,
                "kid": gains.kid,
                "kdd": gains.kdd,
                "gamma": gains.gamma,
                "loop": gains.loop,
                "design": _jsonable(gains.design),
            },
            "feedforward": {"on": ff_on, "K": K, "tau": tau},
            "limits": {
                "max_jerk": J,
                "max_accel": E,
                "max_velocity": W,
                "max_voltage": vmax,
                "host_timeout": tmo,
                "max_error": emax,
                "runaway_time": int(round(runaway * 1000)) / 1000.0,
                "saturation_time": int(round(sat * 1000)) / 1000.0,
            },
            "plant": {"supply_voltage": self.supply_voltage, "counts_per_rev": self.counts_per_rev},
        }

    def _new_recording(self, kind, meta, path):
        meta = dict(meta)
        meta.update(
            kind=kind,
            device=self.device_info(),
            counts_per_rad=self.counts_per_rad,
            volts_per_pwm=self.supply_voltage / self.info.pwm_max,
        )
        if self.metadata:
            meta["caller"] = copy.deepcopy(self.metadata)
        if path is None:
            folder = self.recordings if self.recordings is not None else recordings_dir()
            stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
            base = folder / f"{stamp}_{kind}"
            k = 1
            while base.with_name(base.name + ".csv").exists():
                k += 1
                base = folder / f"{stamp}_{kind}_{k}"
            path = base
        elif path is False:
            path = None
        self.recording = Recording(meta, path)
        return self.recording

    # ---------------------------------------------------------------- runs
    def run_move(
        self,
        profile,
        gains,
        Ts=None,
        *,
        spec=None,
        path=None,
        progress=None,
        live=None,
        on_telemetry=None,
        **spec_fields,
    ) -> Recording:
        """Run a planned move on the rig; return the :class:`Recording` (saved as it arrives).

        When the device has the profile's planner (its capability bit) and the profile is that
        planner's unmodified result, the device re-plans the move from ``profile``'s distance
        and limits (``PLAN``); otherwise, on a device of protocol version 5 with capability
        :attr:`~jerklab.protocol.Capability.HOST_SEGMENTS`, the host sends the profile's
        segments (``PLAN_SEGMENT`` ..., ``PLAN_COMMIT``: any planner, synchronized or from a
        moving start, see :func:`jerklab.protocol.profile_segments`). Either way the host
        checks that PLAN_INFO's duration agrees; the device then runs the feedforward +
        discrete PID of Stojčić eqs. 16–18 at ``Ts`` on encoder counts. Any of these moves can
        be re-targeted while it runs (:meth:`retarget`).

        Before anything is sent, the design is checked on the rig's model (:meth:`set_model`):
        a sampled closed loop (ZOH plant and discrete PID,
        :func:`jerklab.controller.closed_loop_poles`) with a pole at ``|z| >= 1`` is refused
        unless ``force=True``. On the device, the safety stops end a run whose tracking error
        exceeds ``max_error``, whose encoder does not follow a large drive for
        ``runaway_time``, or whose output sits at the clamp most of the time for
        ``saturation_time`` (firmware/PROTOCOL.md "Safety stops").

        Parameters
        ----------
        profile : jerklab.planner.Profile
            A move from ``plan_sine_jerk`` (or another planner the device supports).
        gains : jerklab.controller.Gains or DiscreteGains
            Continuous gains are discretized at the run's period (Stojčić eq. 13).
        Ts : float, optional
            Control period (s), short for ``spec.Ts``: a multiple of the device's tick (1 ms on
            the Uno); default the gains' own period (``DiscreteGains.Ts``), else 5 ms.
        spec : jerklab.rig.RunSpec, optional
            How the move runs: feedforward, output clamp, settle time, decimation, host
            watchdog, the safety stops (``max_error``, ``runaway_time``, ``saturation_time``)
            and ``force`` (see :class:`jerklab.rig.RunSpec` for each, with its default).
        **spec_fields
            RunSpec fields given one by one (``settle=0.4, force=True``): they change ``spec``
            (or the default RunSpec) for this run.
        path : path, None or False
            Where to write the recording (None: a new file in the recordings folder;
            False: keep it in memory only).
        progress : bool
            Progress bar (default: the rig's setting): ipywidgets in a Jupyter kernel, text in a
            terminal, nothing if False.
        live : bool, optional
            Live plot of the run in a Jupyter kernel (default: the rig's ``live``); False: none.
        on_telemetry : callable, optional
            Called as ``on_telemetry(k, reference, position)`` (sample index, rad, rad) for each
            sample as it arrives, in the thread of this call; it may call :meth:`retarget`.

        Raises
        ------
        UnstableDesignError
            The design's sampled loop has a pole with ``|z| >= 1`` (the message names the
            largest ``|z|`` and the design); nothing was sent.
        RigConnectionError, RigTimeoutError
            The link broke or the device fell silent; every sample received is on disk.
        RigCommandError
            The device refused a parameter (the message names it).
        RigRunError
            The run ended early on the device; ``exc.status`` says why, e.g. ``"fault: tracking
            error 0.52 rad > limit 0.5 rad at t=0.84 s"``.
        """
        kind = getattr(profile, "kind", None)
        if kind not in _KIND_TO_PLANNER:
            raise ValueError(
                f"profile must be a jerklab.planner Profile, got {type(profile).__name__}"
            )
        planner = _KIND_TO_PLANNER[kind]
        host_plan = None  # (PLAN_SEGMENTs, PLAN_COMMIT): the host plans the move
        segments_ok = bool(self.capabilities & P.Capability.HOST_SEGMENTS)
        try:
            _check_replannable(profile)
            replannable = True
        except ValueError:
            if not segments_ok:
                raise
            replannable = False
        if not (replannable and self.capabilities & (1 << planner)):
            if not segments_ok:
                raise RigError(
                    f"{self.port}: firmware {self.firmware_version} has no {kind!r} planner "
                    f"(capabilities: {self.device_info()['capabilities']})"
                )
            segs, commit = P.profile_segments(profile)
            gap = P.check_plan_continuity(segs, commit)
            if gap is not None:  # (the device checks each field, the host that they join)
                raise ValueError(f"profile: segment {gap[0]}'s {gap[1]} does not join the previous")
            if not replannable:  # (not the planner's own result: re-targeted from its segments)
                commit = dataclasses.replace(commit, planner=P.PLANNER_NONE)
            host_plan = (segs, commit)
        spec = _run_spec(spec, Ts, spec_fields)
        distance = as_real("profile.distance", profile.distance)
        if distance == 0.0:
            raise ValueError("profile.distance must be nonzero for a rig move")
        settle, decimation, host_timeout = spec.settle, spec.decimation, spec.host_timeout
        limits = (
            profile.max_jerk if profile.max_jerk is not None else _F32_MAX,
            profile.max_accel,
            profile.max_velocity,
        )
        if not spec.force:
            self._check_stable(gains, spec.period(gains))
        cfg = self.configure(gains, spec, limits)
        Ts = cfg["Ts"]
        if host_plan is None:
            info = self._request(P.Plan(distance, int(planner)), replies=(P.MsgType.PLAN_INFO,))
        else:
            for seg in host_plan[0]:
                self._request(seg)
            info = self._request(host_plan[1], replies=(P.MsgType.PLAN_INFO,))
        self._host_planned = host_plan is not None and host_plan[1].planner == P.PLANNER_NONE
        if abs(info.duration - profile.duration) > 1e-4 * profile.duration + 2e-5:
            raise RigError(
                f"{self.port}: the device planned a {info.duration:.6f} s move but the profile lasts "
                f"{profile.duration:.6f} s. The device re-plans from the distance and the limits, "
                f"so only an unmodified planner result can be run (not .synchronized() or edited)."
            )
        settle_n = int(math.ceil(settle / Ts - 1e-9))
        if settle_n > 0xFFFF:
            raise ValueError(f"settle must be <= {0xFFFF * Ts:g} s at Ts = {Ts} s, got {settle}")
        shaper_delay = self._send_shaper(Ts)
        meta = dict(
            cfg,
            profile=_jsonable(profile.to_dict()),
            plan={
                "accel_time": info.accel_time,
                "cruise_time": info.cruise_time,
                "duration": info.duration,
                "n_samples": info.n_samples,
                "planned_by": "board" if host_plan is None else "host",
            },
            settle_samples=settle_n,
            decimation=int(decimation),
        )
        if self._shaper is not None:
            msg, shaper_Ts, what = self._shaper
            meta["shaper"] = {
                "taps": list(msg.amplitudes[: msg.n_taps]),
                "delays": list(msg.delays[: msg.n_taps]),
                "Ts": shaper_Ts,
                "source": what,
            }
        rec = self._new_recording("move", meta, path)
        total = info.n_samples + shaper_delay + settle_n
        if on_telemetry is not None and not callable(on_telemetry):
            raise TypeError(f"on_telemetry must be callable, got {on_telemetry!r}")
        bar = self._bar(total, "move", progress, live, rec, position_range=distance)
        # the host re-plans re-targetings of this move (PROTOCOL.md "Re-targeting") from the
        # plan the device steps: this planner's rest-to-rest profile with PLAN_INFO's times, or
        # the host's own segments (a synchronized profile, a moving start) with their window
        J = None if planner == P.Planner.TRAPEZOID else _R._f32(limits[0])
        lim = (J, _R._f32(limits[1]), _R._f32(limits[2]))
        if self._host_planned:
            running = _R.host_running_plan(*host_plan, int(planner))
        else:
            first = _R.rest_plan(int(planner), _R._f32(distance), *lim)
            running = _R.RunningPlan(
                first, 0.0, info.accel_time, info.cruise_time, info.duration, int(planner)
            )
        rt = _Retargeter(
            running, lim, Ts, int(decimation), getattr(self.link, "baudrate", None) or 115200
        )
        self._rt = rt
        try:
            return self._stream(
                P.Run(settle_n, int(decimation)),
                rec,
                total,
                host_timeout,
                bar,
                on_telemetry=on_telemetry,
            )
        finally:
            self._rt = None

    def _bar(self, total, what, progress, live, rec, **plot):
        """The progress bar of a run and, in a Jupyter kernel, its live plot, as one object
        with ``update(n)`` and ``close(status)``."""
        label = f"{self.port} {what}"
        bar = _progress(total, label, self.progress if progress is None else progress)
        if (self.live if live is None else _as_live("live", live)) is False:
            return bar
        return _Tee(bar, self._plot(rec, total, label, live, **plot))

    def _plot(self, rec, total, label, live=None, **plot):
        """The live plot of a run (:func:`jerklab.rig.live.live_plot`), or an object that
        draws nothing when ``live`` (default the rig's) is False or outside a kernel."""
        live = self.live if live is None else _as_live("live", live)
        if live is False:
            return _NoProgress()
        return _live_plot(rec, total, label, live, display=self.live_display, **plot)

    def retarget(self, new_distance):
        """Change the target of the move that runs to ``new_distance`` rad from its start.

        Usable during :meth:`run_move` -- from its ``on_telemetry`` callback or from another
        thread: the request is queued and handled by the run loop (so frames never interleave).
        The host plans the new move (:func:`jerklab.rig.retarget.plan_switch`): the switch
        where the reference has jerk and acceleration 0, far enough ahead for its frames to
        arrive, the plan from the state there (a move the host planned itself -- synchronized,
        from a moving start -- likewise, from its segments' window:
        :func:`jerklab.rig.retarget.host_running_plan`); it sends it as PLAN_SEGMENTs and a RETARGET
        naming the switch sample, and plans again later when the device finds it late (at
        most :data:`jerklab.rig.retarget.RETARGET_TRIES` times; firmware/PROTOCOL.md
        "Re-targeting", docs/THEORY.md). The run then ends on the new target; the recording's
        metadata lists the requests under ``retargets``, the switches taken under
        ``retarget_switches``, late ones under ``retargets_late`` and refusals under
        ``retargets_refused``.

        Raises
        ------
        ValueError
            ``new_distance`` not a finite number with ``|new_distance| <= 1e6``.
        RigError
            No move is running, or the device cannot re-target (protocol version < 3).
        """
        d = as_real("new_distance", new_distance)
        if not abs(d) <= 1e6:
            raise ValueError(f"new_distance must be within +-1e6 rad, got {d!r}")
        if not self.capabilities & P.Capability.RETARGET:
            raise RigError(
                f"{self.port}: firmware {self.firmware_version} cannot re-target "
                f"(capabilities: {self.device_info()['capabilities']})"
            )
        if not self._streaming:
            raise RigError(
                "retarget() changes a running move: call it during run_move(), from its "
                "on_telemetry callback or another thread"
            )
        self._retargets.append(float(d))

    def _check_stable(self, gains, Ts):
        """UnstableDesignError unless the sampled loop of ``gains`` on the rig's model is stable."""
        Ts = self._ts_us(Ts) * 1e-6
        if isinstance(gains, Gains):
            gains = gains.discretize(Ts)
        if not isinstance(gains, DiscreteGains):
            return  # configure() names the bad type
        K, tau = self.model
        r = max_pole_radius(K, tau, gains)
        if not r < 1.0:
            raise UnstableDesignError(
                f"{self.port}: refusing an unstable design: its sampled closed loop has a pole at "
                f"|z| = {r:.4g} >= 1 ({_describe_design(gains)}; on the model K = {K:g} rad/(V s), "
                f"tau = {tau:g} s, Ts = {gains.Ts:g} s). Choose a smaller wn, a shorter Ts or another "
                f"design, or pass force=True to run it anyway (the safety stops will end it)."
            )

    def step(
        self,
        voltage,
        seconds,
        Ts=paper.TS,
        *,
        rest=0.05,
        coast=None,
        max_voltage=None,
        host_timeout=1.0,
        path=None,
        progress=None,
        live=None,
    ) -> Recording:
        """Open-loop step of ``voltage`` V for ``seconds`` (identification); returns the Recording.

        Samples are taken every ``Ts``; ``rec.voltage`` is the PWM-quantized voltage applied
        (held from each sample to the next), ``rec.position`` the encoder angle (zeroed at the
        start). With ``rest`` > 0 the record starts with that many seconds at 0 V (a STEP of
        0 V, then the STEP of ``voltage``, joined into one record): a step *from rest*, as an
        identification needs (``jerklab.ident.fit_dc_motor``). After the step the motor is
        switched off and coasts; :meth:`wait_still` then checks (up to ``max(2 s, 4·coast)``,
        ``coast`` default 8·tau of the rig's model) that the encoder has stopped, so that the
        next run starts from rest (not needed with the in-process virtual rig, whose motor
        stops at once between runs). ``progress`` and ``live`` (the live plot) are as for
        :meth:`run_move`.
        """
        voltage = as_real("voltage", voltage)
        seconds = as_positive("seconds", seconds)
        us = self._ts_us(Ts)
        Ts = us * 1e-6
        if not self.capabilities & P.Capability.OPEN_LOOP_STEP:
            raise RigError(f"{self.port}: firmware {self.firmware_version} has no open-loop STEP")
        vmax = (
            self.supply_voltage if max_voltage is None else as_positive("max_voltage", max_voltage)
        )
        if abs(voltage) > vmax:
            raise ValueError(f"voltage must be within ±max_voltage = ±{vmax} V, got {voltage}")
        n = max(1, int(math.ceil(seconds / Ts - 1e-9)))
        if n > 0xFFFF:
            raise ValueError(f"seconds must be <= {0xFFFF * Ts:g} s at Ts = {Ts} s, got {seconds}")
        n_rest = int(math.ceil(as_nonnegative("rest", rest) / Ts - 1e-9))
        if n_rest > 0xFFFF:
            raise ValueError(f"rest must be <= {0xFFFF * Ts:g} s at Ts = {Ts} s, got {rest}")
        tmo = as_nonnegative("host_timeout", host_timeout)
        # limits: keep the planner limits at their defaults, set the clamp and the watchdog
        self._request(P.SetPlant(*self.model, self.supply_voltage, self.counts_per_rev))
        self._request(P.SetLimits(*paper.LIMITS, vmax, int(round(tmo * 1000))))
        meta = {
            "Ts": Ts,
            "voltage": voltage,
            "seconds": n * Ts,
            "rest": n_rest * Ts,
            "limits": {"max_voltage": vmax, "host_timeout": tmo},
            "plant": {"supply_voltage": self.supply_voltage, "counts_per_rev": self.counts_per_rev},
        }
        rec = self._new_recording("step", meta, path)
        bar = self._bar(
            n_rest + n,
            "step",
            progress,
            live,
            rec,
            reference=None,
            position_range=self.model[0] * voltage * n * Ts,
            voltage_range=voltage,
        )
        if n_rest:
            self._stream(P.Step(0.0, us, n_rest), rec, n_rest, host_timeout, bar, final=False)
        offset = (len(rec) and int(rec.counts[-1]), n_rest)
        coast = 8.0 * self.model[1] if coast is None else as_nonnegative("coast", coast)
        rec = self._stream(P.Step(voltage, us, n), rec, n, host_timeout, bar, offset=offset)
        if not self.instant_coast:
            self.wait_still(timeout=max(2.0, 4 * coast), Ts=Ts)
        return rec

    def record_prbs(
        self,
        amplitude,
        seconds=None,
        Ts=paper.TS,
        *,
        order=8,
        seed=1,
        hold=1,
        offset=0.0,
        rest=0.05,
        coast=None,
        max_voltage=None,
        host_timeout=1.0,
        path=None,
        progress=None,
        live=None,
    ) -> Recording:
        """Open-loop PRBS record for identification (SEQUENCE, protocol version 3); returns the
        :class:`Recording`, like :meth:`step`.

        The device applies ``offset ± amplitude`` V, the sign the bits of a maximal-length
        PRBS (:func:`jerklab.protocol.prbs_bits` of ``order`` and ``seed``), each bit held
        ``hold`` samples of ``Ts``; it generates the sequence itself (nothing streams to it)
        and reports every sample, with the commanded voltage in the ``reference`` column (V,
        not rad, for this kind) and the PWM-quantized applied voltage in ``rec.voltage``, so
        the input is recorded exactly. With ``rest`` > 0 the record starts with that many
        seconds at 0 V, as :meth:`step`. A pulled cable or a silent device ends it with every
        sample received saved (the recording's status says why).

        Parameters
        ----------
        amplitude : float
            Half the PRBS swing (V), > 0.
        seconds : float, optional
            Length; default one period of the PRBS, ``(2**order - 1) * hold * Ts``.
        Ts : float
            Sample period (s), a multiple of the device tick.
        order : int
            LFSR order 2..16 (period ``2**order - 1`` bits).
        seed : int
            LFSR start state 1..65535 (its low ``order`` bits nonzero).
        hold : int
            Samples per bit, 1..255 (a longer bit puts more power at low frequencies).
        offset : float
            Voltage the PRBS swings around (V); ``|offset| + amplitude <= max_voltage``.
        rest, coast, max_voltage, host_timeout, path, progress, live
            As for :meth:`step`.

        Raises
        ------
        ValueError
            A parameter out of range (the message names it).
        RigError
            The device has no SEQUENCE (capability bit 12).
        RigConnectionError, RigTimeoutError, RigRunError
            As for :meth:`step`; the samples received are saved.
        """
        amplitude = as_positive("amplitude", amplitude)
        offset = as_real("offset", offset)
        for name, v, lo, hi in (
            ("order", order, 2, 16),
            ("seed", seed, 1, 0xFFFF),
            ("hold", hold, 1, 255),
        ):
            if (
                isinstance(v, bool)
                or not isinstance(v, (int,))
                and not (isinstance(v, float) and v.is_integer())
                or not lo <= v <= hi
            ):
                raise ValueError(f"{name} must be an integer in {lo}..{hi}, got {v!r}")
        order, seed, hold = int(order), int(seed), int(hold)
        if seed & ((1 << order) - 1) == 0:
            raise ValueError(
                f"seed must have a nonzero low {order} bits (order {order}), got {seed}"
            )
        us = self._ts_us(Ts)
        Ts = us * 1e-6
        if not self.capabilities & P.Capability.SEQUENCE:
            raise RigError(
                f"{self.port}: firmware {self.firmware_version} has no SEQUENCE (PRBS); "
                f"it needs protocol version 3 with capability bit 12"
            )
        vmax = (
            self.supply_voltage if max_voltage is None else as_positive("max_voltage", max_voltage)
        )
        if abs(offset) + amplitude > vmax:
            raise ValueError(
                f"amplitude + |offset| must be <= max_voltage = {vmax} V, got "
                f"amplitude {amplitude} V, offset {offset} V"
            )
        if seconds is None:
            n = ((1 << order) - 1) * hold
        else:
            n = max(1, int(math.ceil(as_positive("seconds", seconds) / Ts - 1e-9)))
        if n > 0xFFFF:
            raise ValueError(
                f"seconds must be <= {0xFFFF * Ts:g} s at Ts = {Ts} s (65535 samples), got "
                f"{n} samples" + (" (one period of this order and hold)" if seconds is None else "")
            )
        n_rest = int(math.ceil(as_nonnegative("rest", rest) / Ts - 1e-9))
        if n_rest > 0xFFFF:
            raise ValueError(f"rest must be <= {0xFFFF * Ts:g} s at Ts = {Ts} s, got {rest}")
        tmo = as_nonnegative("host_timeout", host_timeout)
        self._request(P.SetPlant(*self.model, self.supply_voltage, self.counts_per_rev))
        self._request(P.SetLimits(*paper.LIMITS, vmax, int(round(tmo * 1000))))
        msg = P.Sequence(amplitude, offset, us, n, seed, order, hold)
        meta = {
            "Ts": Ts,
            "amplitude": amplitude,
            "offset": offset,
            "order": order,
            "seed": seed,
            "hold": hold,
            "seconds": n * Ts,
            "rest": n_rest * Ts,
            "reference_unit": "V",
            "limits": {"max_voltage": vmax, "host_timeout": tmo},
            "plant": {"supply_voltage": self.supply_voltage, "counts_per_rev": self.counts_per_rev},
        }
        rec = self._new_recording("prbs", meta, path)
        bar = self._bar(
            n_rest + n,
            "prbs",
            progress,
            live,
            rec,
            reference="V",
            voltage_range=abs(offset) + amplitude,
        )
        if n_rest:
            self._stream(P.Step(0.0, us, n_rest), rec, n_rest, host_timeout, bar, final=False)
        offset_ = (len(rec) and int(rec.counts[-1]), n_rest)
        coast = 8.0 * self.model[1] if coast is None else as_nonnegative("coast", coast)
        rec = self._stream(msg, rec, n, host_timeout, bar, offset=offset_)
        if not self.instant_coast:
            self.wait_still(timeout=max(2.0, 4 * coast), Ts=Ts)
        return rec

    def set_shaper(self, shaper, Ts=paper.TS):
        """Shape the reference of the following moves with an input shaper (SET_SHAPER,
        protocol version 3); ``None`` switches it off.

        ``shaper`` is an object with ``.fir(Ts)`` (e.g. ``jerklab.shaping.input_shaper(...)``)
        or the taps themselves on the ``Ts`` grid (a 1-D sequence, tap ``i`` delayed ``i``
        samples). The device keeps the nonzero taps: at most 10, delays up to 31 samples (155 ms at 5 ms),
        summing to 1. Its reference becomes the FIR of the planned position; velocity and
        acceleration references (the feedforward, the velocity loop) are the backward
        differences of that, and the move lasts the last delay longer. Moves run at ``Ts``
        then (:meth:`run_move` refuses another Ts while the shaper is on). Returns the
        ``SetShaper`` message sent.
        """
        import numpy as np

        us = self._ts_us(Ts)
        Ts = us * 1e-6
        if not self.capabilities & P.Capability.SHAPER:
            raise RigError(
                f"{self.port}: firmware {self.firmware_version} has no input shaper; it needs "
                f"protocol version 3 with capability bit 13"
            )
        if shaper is None:
            msg, what = P.SetShaper(0), None
        else:
            what = type(shaper).__name__
            taps = shaper.fir(Ts) if hasattr(shaper, "fir") else shaper
            try:
                taps = np.asarray(taps, dtype=float)
            except (TypeError, ValueError):
                raise TypeError(
                    f"shaper must be an object with .fir(Ts) or a sequence of taps, got "
                    f"{type(shaper).__name__}"
                ) from None
            if taps.ndim != 1 or taps.size == 0 or not np.all(np.isfinite(taps)):
                raise ValueError(
                    f"shaper taps must be a nonempty 1-D sequence of finite numbers, got shape "
                    f"{taps.shape}"
                )
            delays = np.flatnonzero(taps)
            if delays.size > P.SHAPER_MAX_TAPS:
                raise ValueError(
                    f"shaper has {delays.size} nonzero taps on the Ts = {Ts:g} s grid; the "
                    f"device takes at most {P.SHAPER_MAX_TAPS}"
                )
            if delays.size and delays[-1] > P.SHAPER_MAX_DELAY:
                raise ValueError(
                    f"shaper lasts {delays[-1]} samples ({delays[-1] * Ts:g} s) at Ts = {Ts:g} s; "
                    f"the device delays at most {P.SHAPER_MAX_DELAY} samples "
                    f"({P.SHAPER_MAX_DELAY * Ts:g} s): a longer Ts or a faster mode"
                )
            amps = taps[delays]
            if np.abs(amps).max(initial=0.0) > P.SHAPER_MAX_AMPLITUDE:
                raise ValueError(
                    f"shaper taps must be at most {P.SHAPER_MAX_AMPLITUDE:g} in magnitude (the "
                    f"device's fixed-point FIR), got {np.abs(amps).max():.6g}"
                )
            if not abs(amps.sum() - 1.0) <= P.SHAPER_SUM_TOL:
                raise ValueError(
                    f"shaper taps must sum to 1 (the move must end at its distance), got "
                    f"{amps.sum():.6g}"
                )
            msg = P.SetShaper(
                int(delays.size), tuple(float(a) for a in amps), tuple(int(d) for d in delays)
            )
        self._request(msg)
        self._shaper = None if msg.n_taps == 0 else (msg, Ts, what)
        return msg

    def _send_shaper(self, Ts) -> int:
        """Before a move: the rig's shaper (or none) to the device; returns its last delay."""
        if not self.capabilities & P.Capability.SHAPER:
            return 0
        if self._shaper is None:
            self._request(P.SetShaper(0))
            return 0
        msg, shaper_Ts, _ = self._shaper
        if abs(shaper_Ts - Ts) > 1e-9:
            raise ValueError(
                f"the shaper was set for Ts = {shaper_Ts:g} s, the move runs at Ts = {Ts:g} s: "
                f"call set_shaper(..., Ts={Ts:g}) again"
            )
        self._request(msg)
        return max(msg.delays[: msg.n_taps])

    def wait_still(self, timeout=2.0, Ts=paper.TS, window=10, tolerance=0) -> bool:
        """Wait until the motor is at rest: repeat a 0 V STEP of ``window`` samples until the
        encoder moves by at most ``tolerance`` counts during it, or ``timeout`` s pass.

        Measured, not guessed: a simulated Uno may run slower than the wall clock, a real
        motor may coast longer than its time constant says. Returns True once still.
        ``window`` is 2 to 65535 samples (one sample cannot show motion), ``tolerance`` an
        integer >= 0 (counts).
        """
        timeout = as_positive("timeout", timeout)
        window = as_int("window", window, minimum=2)
        if window > 0xFFFF:
            raise ValueError(f"window must be <= 65535 samples (one STEP), got {window}")
        tolerance = as_int("tolerance", tolerance, minimum=0)
        us = self._ts_us(Ts)
        deadline = time.monotonic() + timeout
        while True:
            rec = Recording(
                {
                    "Ts": us * 1e-6,
                    "counts_per_rad": self.counts_per_rad,
                    "volts_per_pwm": self.supply_voltage / self.info.pwm_max,
                }
            )
            bar = _NoProgress()
            self._stream(P.Step(0.0, us, int(window)), rec, int(window), 1.0, bar)
            c = rec.counts
            if len(c) and int(c.max() - c.min()) <= tolerance:
                return True
            if time.monotonic() >= deadline:
                return False

    def _stream(
        self, command, rec, total, host_timeout, bar, final=True, offset=(0, 0), on_telemetry=None
    ):
        """Start a run/step and record telemetry until END_OF_RUN (or an error).

        ``offset = (counts, index)`` is added to the telemetry (a record made of two steps);
        ``final=False`` leaves the recording open after a successful end.
        """
        count_off, index_off = offset
        lost = 0
        received = 0
        next_index = 0
        hb_every = max(0.05, host_timeout / 4.0) if host_timeout > 0 else 0.5
        dropped0 = self._decoder.stats.dropped
        status, error, end = "recording", None, None
        self._retargets.clear()
        retargets = []
        try:
            self._request(command)
            self._streaming = isinstance(command, P.Run)
            last_rx = last_hb = time.monotonic()
            rt = self._rt if self._streaming else None

            def on_frame(f):
                nonlocal end, lost, next_index, received
                if f.type == P.MsgType.TELEMETRY:
                    try:
                        t = P.Telemetry.unpack(f.payload)
                    except P.ProtocolError:
                        self.ignored_frames += 1
                        return
                    if t.index > next_index:
                        lost += (t.index - next_index) // max(1, getattr(command, "decimation", 1))
                    next_index = t.index + getattr(command, "decimation", 1)
                    received += 1
                    rec.append(
                        t.index + index_off, t.reference, t.counts + count_off, t.pwm, t.flags
                    )
                    if rt is not None and rt.on_index(t.index):
                        rt.todo.append(rt.target)  # braked: now the move to the target
                    if on_telemetry is not None:
                        on_telemetry(t.index, t.reference, t.counts / self.counts_per_rad)
                elif f.type == P.MsgType.END_OF_RUN:
                    end = P.EndOfRun.unpack(f.payload)
                elif f.type == P.MsgType.ERROR:
                    self._check_busy(f)
                    e = P.DeviceError.unpack(f.payload)
                    rec.metadata.setdefault("device_errors", []).append([e.code, e.detail])
                else:
                    self.ignored_frames += 1  # ACKs of heartbeats, stray replies

            def refused(what, detail):
                rec.metadata.setdefault("retargets_refused", []).append([what, detail])

            def reply_to(msg):
                """Send msg, handle the frames until its ACK/NACK (None: the run ended)."""
                seq = self._write(msg)
                deadline = time.monotonic() + self.timeout
                while end is None:
                    if time.monotonic() > deadline:
                        raise RigTimeoutError(
                            f"{self.port}: no reply to {type(msg).__name__} within "
                            f"{self.timeout:g} s during the run"
                        )
                    frames = self._read_frames(0.05)
                    for i, f in enumerate(frames):
                        if (
                            f.seq == seq
                            and f.type in (P.MsgType.ACK, P.MsgType.NACK)
                            and f.payload[:1] == bytes([msg.TYPE])
                        ):
                            self._frames = frames[i + 1 :] + self._frames
                            return P.parse(f)
                        on_frame(f)
                return None

            while end is None:
                while self._retargets:
                    d = self._retargets.popleft()
                    retargets.append([next_index, d])
                    rec.metadata["retargets"] = retargets
                    if rt is not None:
                        rt.todo.append(d)
                if rt is not None and rt.todo:
                    d = rt.todo[-1]  # the newest target replaces the others
                    rt.todo.clear()
                    rt.send(d, lambda: next_index, reply_to, refused)
                    if rt.late:
                        rec.metadata["retargets_late"] = list(rt.late)
                    if rt.switches:
                        rec.metadata["retarget_switches"] = [list(x) for x in rt.switches]
                now = time.monotonic()
                if now - last_hb >= hb_every:
                    self._write(P.Heartbeat())
                    last_hb = now
                frames = self._read_frames(min(0.05, hb_every))
                now = time.monotonic()
                if frames:
                    last_rx = now
                elif now - last_rx > self.timeout:
                    raise RigTimeoutError(
                        f"{self.port}: no data from the rig for {self.timeout:g} s after {len(rec)} "
                        f"samples of {total}"
                    )
                for f in frames:
                    on_frame(f)
                rec.flush()
                bar.update(len(rec))
            if final is False and end.reason == P.EndReason.DONE:
                return rec
        except RigConnectionError as exc:
            status, error = "disconnected", exc
        except RigTimeoutError as exc:
            status, error = "timeout", exc
        except RigCommandError as exc:
            status, error = "refused", exc
        except KeyboardInterrupt as exc:
            status, error = "interrupted", exc
        except RecordingIOError as exc:
            status, error = f"error: {exc}", exc
        except BaseException as exc:
            status, error = f"error: {type(exc).__name__}: {exc}", exc
        self._streaming = False
        stopped = None
        if error is not None and not isinstance(error, (RigConnectionError, RigTimeoutError)):
            stopped = self._stop_after_error(isinstance(error, KeyboardInterrupt))
        if end is not None:
            # every sample the device sent: k % decimation == 0, and the sample of a safety stop
            dec = max(1, getattr(command, "decimation", 1))
            expected = -(-end.samples // dec)
            if end.reason in _FAULTS and end.samples and (end.samples - 1) % dec:
                expected += 1
            lost = max(lost, expected - received)
        stats = {
            "lost_samples": lost,
            "host_dropped_frames": self._decoder.stats.dropped - dropped0,
        }
        if end is not None:
            reason = (
                P.EndReason(end.reason).name if end.reason in iter(P.EndReason) else str(end.reason)
            )
            stats.update(
                end_reason=reason,
                device_samples=end.samples,
                device_rx_errors=end.rx_errors,
                device_overruns=end.overruns,
            )
            if error is not None:
                pass  # the host-side error is the status
            elif end.reason == P.EndReason.DONE:
                status = "complete"
            elif end.reason in _FAULTS:
                status = _fault_status(end, rec.metadata)
                stats["fault_detail"] = end.detail
            else:
                status = reason.lower()
        if stopped is not None:
            stats["rig_stopped"] = stopped
        if lost:
            warnings.warn(
                f"{self.port}: {lost} telemetry samples were lost on the link (the host did not "
                f"read fast enough, or a noisy line); the recording's metadata says "
                f"lost_samples={lost}",
                RuntimeWarning,
                stacklevel=3,
            )
        try:
            rec.finish(status, **stats, **({"error": str(error)} if error is not None else {}))
        except RecordingIOError as exc:
            if error is None:
                error = exc
                if stopped is None and end is None:
                    stopped = self._stop_after_error(False)
        bar.close(status if not status.startswith("error") else "error")
        where = (
            f"; the {len(rec)} samples received are saved in {rec.csv_path}" if rec.csv_path else ""
        )
        if error is not None:
            if isinstance(error, KeyboardInterrupt):
                raise error
            if isinstance(error, RigError):
                raise type(error)(f"{error}{where}") from error
            if isinstance(error, RecordingIOError):
                note = (
                    "the rig was stopped"
                    if stopped
                    else "the rig did not confirm the STOP: call rig.stop()"
                    if stopped is False
                    else "the run had ended on the rig"
                )
                err = RecordingIOError(
                    error.errno,
                    f"{error}; all {len(rec)} samples received are in "
                    f"memory (the exception's .recording); {note}",
                    error.filename,
                    error.samples_saved,
                )
                err.recording = rec
                raise err from error
            raise error
        if end.reason != P.EndReason.DONE:
            what = status if status.startswith("fault") else stats["end_reason"]
            raise RigRunError(
                f"{self.port}: run ended early on the device ({what}) after "
                f"{end.samples} samples{where}",
                status=status,
                recording=rec,
            )
        return rec

    def realtime(self, Ts, duration, reference=None, **options):
        """Host-in-the-loop: iterate the ticks of a run whose law the user writes in Python.

        ::

            loop = board.realtime(Ts=0.01, duration=2.0, reference=profile)
            for step in loop:
                step.apply(my_law(step.reference - step.position))
            rec = loop.recording

        Each ``step`` (:class:`jerklab.rig.hostloop.HostStep`) carries ``t``, ``position``,
        ``reference`` and the previous ``voltage``; ``step.apply(v)`` sends the voltage for the
        next tick (clamped to ``max_voltage``; a non-finite one stops the run with an error
        naming the tick). A step not answered within Ts is a *miss*: the device holds the last
        voltage; ``max_misses`` in a row stop the motor (firmware/PROTOCOL.md
        "Host-in-the-loop").

        Parameters
        ----------
        Ts : float
            Sampling period (s), 5 to 50 ms, a multiple of the device tick.
        duration : float
            Length of the run (s); ``ceil(duration / Ts) + 1`` ticks.
        reference : None, float, callable or profile, optional
            The position reference r(t) (rad) reported in each step and checked by the
            tracking-error stop (``max_error``, default 0.5 rad with a reference).
        **options
            ``max_misses`` (3), ``max_voltage`` (the supply), ``max_error``,
            ``host_timeout`` (1 s), ``path`` and ``live`` (the live plot; as for :meth:`step`).

        Returns
        -------
        jerklab.rig.hostloop.RealtimeLoop
            Iterable once; its ``recording`` (a :class:`Recording`) has its final status on
            every exit path (the end, ``break``, an exception, Ctrl-C: the motor stops), its
            ``misses`` and the deadline slack per tick (``metadata["hostloop"]``).
        """
        if not self.capabilities & P.Capability.HOST_LOOP:
            raise RigError(
                f"{self.port}: firmware {self.firmware_version} has no host-in-the-loop mode"
            )
        return RealtimeLoop(
            self,
            Ts,
            duration,
            reference,
            _describe_fault=_fault_status,
            _timeout_error=RigTimeoutError,
            **options,
        )

    def host_loop(self, control, Ts, duration, reference=None, **options) -> Recording:
        """Host-in-the-loop with a callable law ``control(t, position, reference) -> volts``.

        As :meth:`realtime` (same parameters and options); returns the :class:`Recording`.

        Raises
        ------
        jerklab.rig.hostloop.ControlLawError
            When the law raises or returns a non-finite voltage: the motor is stopped, the
            message and the recording's status name the tick.
        """
        return run_law(self.realtime(Ts, duration, reference, **options), control)

    def _stop_after_error(self, interrupted: bool):
        """Send STOP after a run was abandoned on the host (write error, Ctrl-C, a bug), so that
        the device does not stay BUSY; True if the device acknowledged it."""
        try:
            if interrupted:
                self._write(P.Stop())  # Ctrl-C: do not wait
                return None
            self._request(P.Stop(), timeout=min(self.timeout, 1.0))
            return True
        except (RigError, OSError):
            return False


def _as_live(name, value):
    """``live=``: None (a live plot in a Jupyter kernel), True or False."""
    if value is None or isinstance(value, bool):
        return value
    raise TypeError(f"{name} must be True, False or None, got {value!r}")


def _describe_design(gains) -> str:
    """``"eq13 design, wn = 60, zeta = 1, loop position, kpd = ..."`` for messages."""
    d = dict(getattr(gains, "design", None) or {})
    parts = [f"{d.pop('method')} design" if "method" in d else "design"]
    for key in ("wn", "zeta", "sigma"):
        if key in d and isinstance(d[key], (int, float)):
            parts.append(f"{key} = {d[key]:g}")
    parts.append(f"{gains.loop} loop")
    parts.append(f"kpd = {gains.kpd:.4g}, kid = {gains.kid:.4g}, kdd = {gains.kdd:.4g}")
    if gains.gamma:
        parts.append(f"gamma = {gains.gamma:.4g}")
    return ", ".join(parts)


def _fault_status(end, meta) -> str:
    """The readable status of a run that ended on a safety stop (PROTOCOL.md "Safety stops")."""
    Ts = meta.get("Ts") or 0.0
    t = max(0, end.samples - 1) * Ts
    limits = meta.get("limits") or {}
    if end.reason == P.EndReason.TRACKING_ERROR:
        lim = limits.get("max_error")
        lim = f"{lim:.4g} rad" if isinstance(lim, (int, float)) else "the limit"
        return f"fault: tracking error {abs(end.detail):.4g} rad > limit {lim} at t={t:.3f} s"
    window = limits.get("runaway_time")
    window = f"{window:g} s" if isinstance(window, (int, float)) else "the runaway window"
    if end.reason == P.EndReason.RUNAWAY:
        return (
            f"fault: runaway — encoder reversed? (the encoder counted {-end.detail:.0f} counts against "
            f"a drive of at least half the clamp for {window}) at t={t:.3f} s"
        )
    if end.reason == P.EndReason.NO_MOTION:
        return (
            f"fault: no motion — encoder disconnected or motor stalled? (no counts under a drive of at "
            f"least half the clamp for {window}) at t={t:.3f} s"
        )
    if end.reason == P.EndReason.SATURATION:
        sw = limits.get("saturation_time")
        sw = f"{sw:g} s" if isinstance(sw, (int, float)) else "the saturation window"
        return (
            "fault: output saturated — unstable loop? (the output sat at the "
            f"±{limits.get('max_voltage', '?')} V "
            f"clamp in most samples for {sw}) at t={t:.3f} s"
        )
    if end.reason == P.EndReason.HOST_MISSES:
        return f"fault: host missed {end.detail:.0f} deadlines in a row at t={t:.3f} s"
    return f"fault: device fault at t={t:.3f} s"


def _jsonable(d):
    """A copy of a dict with numpy / odd values made JSON-friendly."""
    import numpy as np

    if isinstance(d, dict):
        return {str(k): _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, (np.floating, np.integer)):
        return d.item()
    if isinstance(d, np.ndarray):
        return d.tolist()
    if isinstance(d, (str, int, float, bool)) or d is None:
        return d
    return repr(d)


def _check_replannable(profile) -> None:
    """Refuse, before anything is sent, a profile the device's own re-plan (``PLAN``) cannot
    reproduce: one from a moving start, or one changed after planning (``.synchronized()``,
    edited phase times). The device plans rest-to-rest from the distance and the limits."""
    if any(
        getattr(profile, name, 0.0)
        for name in ("initial_velocity", "initial_accel", "final_velocity")
    ):
        raise ValueError(
            f"profile starts or ends moving (initial_velocity={profile.initial_velocity!r}, "
            f"initial_accel={profile.initial_accel!r}, final_velocity={profile.final_velocity!r}); "
            f"the rig runs rest-to-rest moves only (use Rig.retarget for a move in motion)"
        )
    kind = profile.kind
    distance = as_real("profile.distance", profile.distance)
    jerk, accel, velocity = profile.max_jerk, profile.max_accel, profile.max_velocity
    try:
        if kind == "trapezoid":
            fresh = _planner.plan_trapezoid(distance, accel, velocity)
        else:
            fresh = getattr(_planner, "plan_" + kind)(distance, jerk, accel, velocity)
    except ValueError as exc:
        raise ValueError(f"profile: its limits do not plan again ({exc})") from None
    if abs(fresh.duration - profile.duration) > 1e-9 * max(fresh.duration, 1e-9):
        raise ValueError(
            f"profile lasts {profile.duration:.6f} s but its distance and limits plan a "
            f"{fresh.duration:.6f} s move: it was changed after planning (.synchronized(Ts) or "
            f"edited). The device re-plans every move from the distance and the limits at its own "
            f"period, so run the planner's result itself (plan_{kind}(...)), unmodified"
        )


def _run_spec(spec, Ts=None, fields=None) -> RunSpec:
    """``spec`` (default ``RunSpec()``) with ``Ts`` and ``fields`` filled in (the short forms
    of :meth:`Rig.run_move`)."""
    if spec is None:
        spec = RunSpec()
    elif not isinstance(spec, RunSpec):
        raise TypeError(f"spec must be a jerklab.rig.RunSpec, got {type(spec).__name__}")
    changes = dict(fields or {})
    if Ts is not None:
        if "Ts" in changes:
            raise TypeError("Ts given twice")
        if spec.Ts is not None and spec.Ts != Ts:
            raise ValueError(f"Ts = {Ts!r} s disagrees with spec.Ts = {spec.Ts!r} s")
        changes["Ts"] = Ts
    return spec.replace(**changes) if changes else spec


def _caller_metadata(metadata) -> dict:
    """The owner's fields for every recording: a JSON-able mapping with string keys."""
    if metadata is None:
        return {}
    if not isinstance(metadata, dict):
        raise TypeError(f"metadata must be a dict, got {type(metadata).__name__}")
    try:
        json.dumps(metadata, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"metadata must be JSON-able (str keys, finite numbers): {exc}") from None
    bad = [k for k in metadata if not isinstance(k, str)]
    if bad:
        raise ValueError(f"metadata keys must be strings, got {bad!r}")
    return copy.deepcopy(metadata)
