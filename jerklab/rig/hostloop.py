"""Host-in-the-loop runs: your own Python law closes the loop through the rig.

The device samples the encoder on its own tick and sends HOST_SAMPLE; the host answers with
the voltage for the next tick (HOST_VOLTAGE); firmware/PROTOCOL.md "Host-in-the-loop" gives the
deadline rule (a late reply is a miss, the last voltage is held; ``max_misses`` in a row stop
the motor). :meth:`jerklab.rig.Rig.realtime` and :meth:`jerklab.rig.Rig.host_loop` are the two
forms a user writes; this module holds their machinery.
"""

from __future__ import annotations

import math
import numbers
import time

from jerklab import paper
from jerklab import protocol as P
from jerklab._validate import as_int, as_nonnegative, as_positive

__all__ = ["HostStep", "RealtimeLoop", "ControlLawError"]

#: shortest and longest Ts (s) of the host-in-the-loop mode
MIN_TS = P.HOST_LOOP_MIN_TS_US * 1e-6
MAX_TS = P.HOST_LOOP_MAX_TS_US * 1e-6


#: the smallest normal float32: a voltage below it reaches the device as 0 V
_FLOAT32_TINY = 1.1754943508222875e-38


class ControlLawError(RuntimeError):
    """The control law raised or returned a non-finite voltage; ``tick`` names the tick."""

    def __init__(self, message, tick=None, recording=None):
        super().__init__(message)
        self.tick = tick
        self.recording = recording


def _reference_table(reference, n, Ts):
    """The reference (rad) at ticks 0..n: None without one; from a number, a callable r(t) or a
    profile with ``sample(t).position``, computed once before the run (a tick has no time for
    it: a profile's ``sample`` takes milliseconds)."""
    if reference is None:
        return None
    times = [k * Ts for k in range(n + 1)]
    if hasattr(reference, "sample"):
        import numpy as np

        pos = np.broadcast_to(
            np.asarray(reference.sample(np.asarray(times)).position, float), n + 1
        )
        table = [float(x) for x in pos]
    elif callable(reference):
        table = [float(reference(t)) for t in times]
    elif isinstance(reference, numbers.Real) and not isinstance(reference, bool):
        table = [float(reference)] * (n + 1)
    else:
        raise TypeError(
            "reference must be None, a number (rad), a callable r(t) or a profile with "
            f"sample(t), got {type(reference).__name__}"
        )
    bad = [k for k, x in enumerate(table) if not math.isfinite(x)]
    if bad:
        raise ValueError(f"reference must be finite: r({bad[0] * Ts:g} s) = {table[bad[0]]!r}")
    return table


class HostStep:
    """One tick of a host-in-the-loop run.

    Attributes
    ----------
    index : int
        Tick number k; ``t = k Ts``.
    t : float
        Time of the encoder sample (s).
    position : float
        Encoder angle at ``t`` (rad, zeroed at tick 0).
    reference : float
        The reference at ``t`` (rad; nan without a reference).
    voltage : float
        The voltage the device applies during this tick (V): the previous tick's answer, or
        the held one after a miss.
    missed : bool
        The device held the last voltage at this tick (the previous answer came too late).
    """

    __slots__ = ("index", "t", "position", "reference", "voltage", "missed", "_loop", "_volts")

    def __init__(self, loop, index, t, position, reference, voltage, missed):
        self._loop = loop
        self.index = index
        self.t = t
        self.position = position
        self.reference = reference
        self.voltage = voltage
        self.missed = missed
        self._volts = None

    def apply(self, voltage):
        """The voltage (V) for the next tick; clamped to ±max_voltage (a magnitude below
        float32's smallest normal number, 1.2e-38 V, is sent as 0 V).

        Raises
        ------
        ControlLawError
            When ``voltage`` is not a finite number: the run stops (the motor is switched
            off) and the recording's status names the tick.
        """
        v = math.nan
        if getattr(voltage, "shape", None) == () and hasattr(voltage, "item"):
            voltage = voltage.item()  # a numpy scalar or 0-d array
        if isinstance(voltage, numbers.Real) and not isinstance(voltage, bool):
            v = float(voltage)
        if not math.isfinite(v):
            self._loop._refuse(self, f"the control law returned voltage = {voltage!r}")
        if abs(v) < _FLOAT32_TINY:
            v = 0.0  # below what the link's float32 carries: 0 V, as the board would apply
        vmax = self._loop.max_voltage
        self._volts = min(max(v, -vmax), vmax)

    def __repr__(self):
        return (
            f"HostStep(index={self.index}, t={self.t:.4g}, position={self.position:.6g}, "
            f"reference={self.reference:.6g}, voltage={self.voltage:.4g})"
        )


def run_law(loop, control):
    """Close ``loop`` (a :class:`RealtimeLoop`, or the class rig's) with the callable law
    ``control(t, position, reference) -> volts``: each step's answer is ``step.apply(v)``; a law
    that raises stops the motor, and :class:`ControlLawError` names the tick; Ctrl-C stops the
    motor too. Returns the loop's recording."""
    if not callable(control):
        raise TypeError(f"control must be callable, got {type(control).__name__}")
    steps = iter(loop)
    try:
        for step in steps:
            try:
                v = control(step.t, step.position, step.reference)
            except Exception as exc:
                status = (
                    f"error: the control law raised {type(exc).__name__}: {exc} at tick "
                    f"{step.index} (t={step.t:.3f} s); the motor is stopped"
                )
                loop._error = (status, step.index)
                loop.abort(status)
                raise ControlLawError(
                    status[len("error: ") :], tick=step.index, recording=loop.recording
                ) from exc
            step.apply(v)
    except KeyboardInterrupt:
        loop.abort("interrupted")
        raise
    finally:
        steps.close()
    return loop.recording


class EndsOnExit:
    """A real-time loop that runs once (``iter`` a second time is refused) and, used as
    ``with loop:``, ends the run with a final status whatever ends the block: Ctrl-C
    ("interrupted"), an exception (its name) or a block left before the run's end. Subclasses
    give ``_run()`` (the steps) and ``abort(status)``."""

    _used = False

    def __iter__(self):
        if self._used:
            raise RuntimeError("a realtime loop runs once: call board.realtime(...) again")
        self._used = True
        return self._run()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is KeyboardInterrupt:
            self.abort("interrupted")
        elif exc_type is not None:
            self.abort(f"error: {exc_type.__name__}: {exc}")
        else:
            self.abort("stopped: the loop ended before the run")
        return False


class RealtimeLoop(EndsOnExit):
    """The iterable of :meth:`jerklab.rig.Rig.realtime`: iterate it once for its steps;
    :attr:`recording` holds the run (its status final once the loop has ended, whatever the
    way: the end of the run, ``break``, an exception, Ctrl-C)."""

    def __init__(
        self,
        rig,
        Ts,
        duration,
        reference=None,
        *,
        max_misses=3,
        max_voltage=None,
        max_error=None,
        host_timeout=1.0,
        path=None,
        live=None,
        kind="hostloop",
        _describe_fault=None,
        _timeout_error=TimeoutError,
    ):
        Ts = as_positive("Ts", Ts)
        if not MIN_TS - 1e-12 <= Ts <= MAX_TS + 1e-12:
            raise ValueError(
                f"Ts must be between {MIN_TS * 1e3:g} ms and {MAX_TS * 1e3:g} ms in the "
                f"host-in-the-loop mode, got {Ts!r} s"
            )
        self.rig = rig
        self.Ts_us = rig._ts_us(Ts)
        self.Ts = self.Ts_us * 1e-6
        duration = as_positive("duration", duration)
        self.n = int(math.ceil(duration / self.Ts - 1e-9)) + 1
        if self.n > 0xFFFF:
            raise ValueError(f"duration must be <= {0xFFFE * self.Ts:g} s at Ts = {Ts} s")
        self.max_misses = as_int("max_misses", max_misses)
        if not 1 <= self.max_misses <= 255:
            raise ValueError(f"max_misses must be in 1..255, got {max_misses!r}")
        self.max_voltage = (
            rig.supply_voltage if max_voltage is None else as_positive("max_voltage", max_voltage)
        )
        if self.max_voltage > rig.supply_voltage:
            raise ValueError(
                f"max_voltage must be <= the supply {rig.supply_voltage} V, got {max_voltage}"
            )
        self._ref = _reference_table(reference, self.n, self.Ts)
        if max_error is None:
            max_error = P.DEFAULT_MAX_ERROR if self._ref is not None else 0.0
        self.max_error = as_nonnegative("max_error", max_error)
        self.host_timeout = as_nonnegative("host_timeout", host_timeout)
        self._describe_fault = _describe_fault  # the client's readable safety-stop status
        self._timeout_error = _timeout_error
        self._path = path
        if live is not None and not isinstance(live, bool):
            raise TypeError(f"live must be True, False or None, got {live!r}")
        self._live = live
        self._plot = None
        self._kind = kind
        self._used = False
        self._done = False
        self._error = None  # (status, tick) set when the law is refused
        self.recording = None
        self.misses = 0
        self.slack = []  # s per answered tick: deadline (sample + Ts) minus the send time

    # ------------------------------------------------------------------ helpers
    def reference_at(self, k):
        return math.nan if self._ref is None else self._ref[min(k, self.n)]

    def _refuse(self, step, what):
        status = (
            f"error: {what} at tick {step.index} (t={step.t:.3f} s); refused, the motor is stopped"
        )
        self._error = (status, step.index)
        self.abort(status)
        raise ControlLawError(status[len("error: ") :], tick=step.index, recording=self.recording)

    def _start(self):
        rig = self.rig
        rig._request(P.SetPlant(*rig.model, rig.supply_voltage, rig.counts_per_rev))
        rig._request(
            P.SetLimits(
                *paper.LIMITS,
                self.max_voltage,
                int(round(self.host_timeout * 1000)),
                self.max_error,
                P.DEFAULT_RUNAWAY_MS,
                P.DEFAULT_SATURATION_MS,
            )
        )
        meta = {
            "Ts": self.Ts,
            "duration": (self.n - 1) * self.Ts,
            "limits": {
                "max_voltage": self.max_voltage,
                "host_timeout": self.host_timeout,
                "max_error": self.max_error,
                "runaway_time": P.DEFAULT_RUNAWAY_MS / 1000.0,
                "saturation_time": P.DEFAULT_SATURATION_MS / 1000.0,
                "max_misses": self.max_misses,
            },
            "plant": {"supply_voltage": rig.supply_voltage, "counts_per_rev": rig.counts_per_rev},
        }
        self.recording = rig._new_recording(self._kind, meta, self._path)
        if hasattr(rig, "_plot"):  # the live plot, made before the run: a tick has no time
            self._plot = rig._plot(
                self.recording,
                self.n,
                f"{rig.port} {self._kind}",
                self._live,
                reference=None if self._ref is None else "rad",
                position_range=None if self._ref is None else max(self._ref, key=abs),
            )
        try:
            rig._request(P.HostLoop(self.Ts_us, self.n, self.max_misses))
        except BaseException:
            if self._plot is not None:
                self._plot.close("refused")
            raise

    def abort(self, status="stopped"):
        """Stop the motor now and finish the recording with ``status`` (once; later calls
        and the loop's own end do nothing)."""
        if self._done or self.recording is None:
            return
        self.rig._stop_after_error(False)
        self._finish(status)

    def _finish(self, status):
        self._done = True
        rec = self.recording
        rec.metadata["hostloop"] = {
            "misses": self.misses,
            "max_misses": self.max_misses,
            "slack": [round(s, 6) for s in self.slack],
        }
        try:
            rec.finish(status, misses=self.misses)
        finally:
            if self._plot is not None:
                self._plot.close(status if not status.startswith("error") else "error")

    # ------------------------------------------------------------------ the loop
    def _run(self):
        rig = self.rig
        self._start()
        rec = self.recording
        cpr = rig.counts_per_rad
        vpp = rig.supply_voltage / rig.info.pwm_max
        status = None
        ended = False
        try:
            last = time.monotonic()
            while not ended:
                frames = rig._read_frames(0.05)
                now = time.monotonic()
                if not frames:
                    if now - last > rig.timeout:
                        status = "timeout"
                        raise self._timeout_error(
                            f"{rig.port}: no sample from the device for {rig.timeout:g} s "
                            "in the host-in-the-loop run"
                        )
                    continue
                last = now
                for i, f in enumerate(frames):
                    if f.type == P.MsgType.END_OF_RUN:
                        end = P.parse(f)
                        ended = True
                        if end.reason == P.EndReason.DONE:
                            status = "complete"
                        elif end.reason == P.EndReason.HOST_MISSES:
                            status = (
                                f"fault: host missed {self.max_misses} deadlines in a row "
                                f"(Ts = {self.Ts * 1e3:g} ms) at "
                                f"t={max(0, end.samples - 1) * self.Ts:.3f} s"
                            )
                        elif end.reason == P.EndReason.HOST_TIMEOUT:
                            status = "fault: host timeout"
                        elif end.reason == P.EndReason.STOPPED:
                            status = "stopped"
                        elif self._describe_fault is not None:
                            status = self._describe_fault(end, rec.metadata)
                        else:
                            status = f"fault: {P.EndReason(end.reason).name.lower()}"
                        break
                    if f.type != P.MsgType.HOST_SAMPLE:
                        rig.ignored_frames += 1
                        continue
                    s = P.parse(f)
                    k = s.index
                    self.misses = s.misses
                    ref = self.reference_at(k)
                    # the recording's reference is 0 without one (as for an open-loop step)
                    rec.append(k, 0.0 if self._ref is None else ref, s.counts, s.pwm, s.flags)
                    if self._plot is not None:
                        self._plot.update(len(rec))  # background drawing: no wait here
                    if s.flags & P.TELEMETRY_FAULT or k >= self.n - 1:
                        continue  # END_OF_RUN follows: nothing to answer
                    step = HostStep(
                        self,
                        k,
                        k * self.Ts,
                        s.counts / cpr,
                        ref,
                        s.pwm * vpp,
                        bool(s.flags & P.HOST_SAMPLE_MISSED),
                    )
                    yield step
                    if step._volts is None:
                        continue  # not applied: the device holds the last voltage (a miss)
                    r1 = self.reference_at(k + 1)
                    flags = 0 if self._ref is None else P.HOST_VOLTAGE_REFERENCE
                    rig._write(P.HostVoltage(k, step._volts, 0.0 if flags == 0 else r1, flags))
                    self.slack.append(now + self.Ts - time.monotonic())
                    # later frames of this batch are older than the answer: read afresh
                    rig._frames = frames[i + 1 :] + rig._frames
                    break
        except BaseException as exc:
            if status is None or status == "complete":
                if self._error is not None:
                    status = self._error[0]
                elif isinstance(exc, KeyboardInterrupt):
                    status = "interrupted"
                elif isinstance(exc, GeneratorExit):
                    status = "stopped: the loop ended before the run"
                else:
                    status = f"error: {type(exc).__name__}: {exc}"
            if not self._done:
                if not ended:
                    rig._stop_after_error(isinstance(exc, KeyboardInterrupt))
                self._finish(status)
            raise
        if not self._done:
            self._finish(status)
