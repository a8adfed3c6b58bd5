"""The rig's options in three small groups, each with its defaults and its checks in one place.

* :class:`Link` — how the host talks to the rig: reply timeout, HELLO timeout, baud rate and
  any other pyserial option (``jerklab.rig.connect(port, link=Link(timeout=5.0))``).
* :class:`Device` — the hardware behind the port: the simulated motor or plant of the virtual
  rig and of ``"simavr"``, the virtual rig's speed and encoder count noise, the H-bridge supply
  and the encoder's counts per revolution (``connect(device=Device(motor, speed=1.0))``; a bare
  ``jerklab.plant`` motor is short for ``Device(motor)``).
* :class:`RunSpec` — how :meth:`jerklab.rig.Rig.run_move` runs a move (the control law of
  Stojčić eqs. 16–18; ASCII Stojcic): control period,
  feedforward, output clamp, settle time, telemetry decimation, the host watchdog and the
  device's safety stops, and ``force``. ``run_move(profile, gains, Ts, settle=0.4)`` is short
  for ``run_move(profile, gains, spec=RunSpec(Ts=Ts, settle=0.4))``.

Every field is checked when the group is made (ValueError naming the field), so a typo fails
before anything is sent; what depends on the rig (Ts a multiple of its tick, the clamp within
its supply) is checked by the rig.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass

from jerklab import paper
from jerklab import protocol as P
from jerklab._validate import as_int, as_nonnegative, as_positive
from jerklab.plant import DCMotor, FlexibleDCMotor

__all__ = ["Link", "Device", "RunSpec", "BAUDRATE", "MIN_TIMEOUT", "F32_MAX"]

BAUDRATE = 115200
#: the shortest reply ``timeout`` / ``hello_timeout`` accepted (s): an ACK frame takes about 1 ms at
#: 115 200 baud, so a shorter wait cannot be met by any rig
MIN_TIMEOUT = 1e-3
#: the largest float32 (the wire format of the limits)
F32_MAX = 3.4028234663852886e38
#: the longest window the device counts in milliseconds (a uint16)
_MAX_MS = 65.535


def _replace(obj, changes):
    names = {f.name for f in dataclasses.fields(obj)}
    unknown = sorted(set(changes) - names)
    if unknown:
        raise TypeError(
            f"{type(obj).__name__} has no field {', '.join(map(repr, unknown))} "
            f"(its fields: {', '.join(sorted(names))})"
        )
    return dataclasses.replace(obj, **changes)


def _timeout(name, value):
    if value is not None and as_positive(name, value) < MIN_TIMEOUT:
        raise ValueError(
            f"{name} must be >= MIN_TIMEOUT = {MIN_TIMEOUT:g} s (one frame at {BAUDRATE} baud), "
            f"got {value!r}"
        )
    return None if value is None else float(value)


@dataclass(frozen=True)
class Link:
    """How the host talks to the rig.

    Parameters
    ----------
    timeout : float
        Seconds to wait for a reply or the next telemetry frame (>= ``MIN_TIMEOUT``).
    hello_timeout : float, optional
        Seconds to keep saying HELLO (every 0.25 s) after opening; default 3 s for a port (an
        Uno reboots when the port opens and its bootloader listens for about 1 s), 1 s for the
        virtual rig.
    baudrate : int
        Serial speed (115200, as the firmware).
    serial : mapping
        More keyword arguments for pyserial's ``serial_for_url`` (e.g. ``write_timeout``);
        kept as sorted ``(name, value)`` pairs, so a Link is hashable.
    """

    timeout: float = 2.0
    hello_timeout: float | None = None
    baudrate: int = BAUDRATE
    serial: tuple = ()

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "timeout", _timeout("timeout", self.timeout))
        set_(self, "hello_timeout", _timeout("hello_timeout", self.hello_timeout))
        set_(self, "baudrate", as_int("baudrate", self.baudrate, minimum=1))
        items = self.serial.items() if isinstance(self.serial, Mapping) else self.serial
        try:
            pairs = tuple(sorted((str(k), v) for k, v in items))
        except (TypeError, ValueError):
            raise ValueError(
                f"serial must be a mapping of pyserial options, got {self.serial!r}"
            ) from None
        for k, _ in pairs:
            if k in ("port", "url", "baudrate"):
                raise ValueError(f"serial must not set {k!r}: give it as connect's port or Link's")
        set_(self, "serial", pairs)

    @property
    def serial_options(self) -> dict:
        """The pyserial options as a dict."""
        return dict(self.serial)

    def replace(self, **changes) -> Link:
        """A copy with some fields changed (checked again)."""
        return _replace(self, changes)


@dataclass(frozen=True)
class Device:
    """The hardware behind the port.

    Parameters
    ----------
    motor : jerklab.plant.DCMotor or FlexibleDCMotor, optional
        The simulated motor (or two-mass load) of the virtual rig and of ``"simavr"``; default
        the paper's motor (K = 32.4 rad/(V s), tau = 25 ms). A real board has its own: giving
        one there is refused.
    speed : float, optional
        Virtual rig only: that many times real time (None: as fast as possible).
    supply_voltage : float, optional
        The H-bridge supply (V, PWM full scale); default the motor's, else the paper's 12 V.
    counts_per_rev : int, optional
        Encoder counts per revolution after decoding; default the motor's, else 448.
    count_noise : float
        Virtual rig only: standard deviation (counts) of a noise added to the encoder reading
        before it is floored to a count (0: none).
    noise_seed : int or sequence of int, optional
        Virtual rig only: the seed of that noise (``numpy.random.default_rng``).
    """

    motor: object = None
    speed: float | None = None
    supply_voltage: float | None = None
    counts_per_rev: int | None = None
    count_noise: float = 0.0
    noise_seed: object = None

    def __post_init__(self):
        set_ = object.__setattr__
        if self.motor is not None and not isinstance(self.motor, (DCMotor, FlexibleDCMotor)):
            raise TypeError(
                f"motor must be a jerklab.plant.DCMotor or FlexibleDCMotor, got "
                f"{type(self.motor).__name__}"
            )
        if self.speed is not None:
            set_(self, "speed", as_positive("speed", self.speed))
        if self.supply_voltage is not None:
            set_(self, "supply_voltage", as_positive("supply_voltage", self.supply_voltage))
        if self.counts_per_rev is not None:
            set_(self, "counts_per_rev", as_int("counts_per_rev", self.counts_per_rev, minimum=1))
        set_(self, "count_noise", as_nonnegative("count_noise", self.count_noise))
        if isinstance(self.noise_seed, list):
            set_(self, "noise_seed", tuple(self.noise_seed))

    @property
    def simulated_only(self) -> list[str]:
        """The fields set here that only a simulated device (virtual rig, simavr) can take."""
        return [
            name
            for name, on in (
                ("motor", self.motor is not None),
                ("speed", self.speed is not None),
                ("count_noise", self.count_noise > 0),
            )
            if on
        ]

    def replace(self, **changes) -> Device:
        """A copy with some fields changed (checked again)."""
        return _replace(self, changes)


def _ms_window(name, value):
    v = as_nonnegative(name, value)
    if v > _MAX_MS:
        raise ValueError(f"{name} must be <= {_MAX_MS} s, got {v}")
    return v


@dataclass(frozen=True)
class RunSpec:
    """How a move runs (:meth:`jerklab.rig.Rig.run_move`).

    Parameters
    ----------
    Ts : float, optional
        Control period (s), a multiple of the device's tick (1 ms on the Uno), at most 65 ms;
        default the gains' own (``DiscreteGains.Ts``), else ``jerklab.paper.TS`` (5 ms).
    feedforward : bool or Feedforward
        True: u_F from the rig's model (``Rig.set_model``, Stojčić eq. 8); a
        ``jerklab.controller.Feedforward``: its K, tau; False: PID only.
    max_voltage : float, optional
        Output clamp (V), default the supply voltage.
    settle : float
        Seconds recorded after the profile ends (holding the final position).
    decimation : int
        Telemetry every ``decimation`` samples (1..255).
    host_timeout : float
        The device stops the motor if the host is silent longer than this (s, <= 65.535);
        0 = off.
    max_error : float
        Tracking-error limit (rad): the device ends the run with a fault when
        ``|reference − position|`` exceeds it; 0 = off.
    runaway_time : float
        Runaway / no-motion window (s, <= 65.535): a drive of at least half the clamp for this
        long that moves the encoder against it or not at all ends the run; 0 = off.
    saturation_time : float
        Saturation window (s, <= 65.535): an output at the clamp in clearly more than half the
        samples for this long ends the run; 0 = off.
    force : bool
        Run a design even if its sampled closed loop is unstable (the safety stops still apply).
    """

    Ts: float | None = None
    feedforward: object = True
    max_voltage: float | None = None
    settle: float = 0.25
    decimation: int = 1
    host_timeout: float = 1.0
    max_error: float = P.DEFAULT_MAX_ERROR
    runaway_time: float = P.DEFAULT_RUNAWAY_MS / 1000.0
    saturation_time: float = P.DEFAULT_SATURATION_MS / 1000.0
    force: bool = False

    def __post_init__(self):
        set_ = object.__setattr__
        if self.Ts is not None:
            Ts = as_positive("Ts", self.Ts)
            if Ts > 0.065:
                raise ValueError(f"Ts must be at most 65 ms, got {self.Ts!r} s")
            set_(self, "Ts", Ts)
        ff = self.feedforward
        if ff is None:
            set_(self, "feedforward", False)
        elif not isinstance(ff, bool):
            if not (hasattr(ff, "K") and hasattr(ff, "tau")):
                raise ValueError(
                    f"feedforward must be True, False or a jerklab.controller.Feedforward, got {ff!r}"
                )
            as_positive("feedforward.K", ff.K)
            as_positive("feedforward.tau", ff.tau)
        if self.max_voltage is not None:
            set_(self, "max_voltage", as_positive("max_voltage", self.max_voltage))
        set_(self, "settle", as_nonnegative("settle", self.settle))
        d = self.decimation
        if (
            isinstance(d, bool)
            or not isinstance(d, numbers.Real)
            or not math.isfinite(d)
            or int(d) != d
            or not 1 <= d <= 255
        ):
            raise ValueError(f"decimation must be an integer in 1..255, got {d!r}")
        set_(self, "decimation", int(d))
        set_(self, "host_timeout", _ms_window("host_timeout", self.host_timeout))
        emax = as_nonnegative("max_error", self.max_error)
        if emax > F32_MAX:
            raise ValueError(f"max_error must be a float32 (<= {F32_MAX:g} rad), got {emax!r}")
        set_(self, "max_error", emax)
        set_(self, "runaway_time", _ms_window("runaway_time", self.runaway_time))
        set_(self, "saturation_time", _ms_window("saturation_time", self.saturation_time))
        if not isinstance(self.force, bool):
            raise ValueError(f"force must be True or False, got {self.force!r}")

    def period(self, gains) -> float:
        """The control period for ``gains``: ``Ts`` if set, else the gains' own, else
        ``jerklab.paper.TS``."""
        if self.Ts is not None:
            return self.Ts
        Ts = getattr(gains, "Ts", None)
        if isinstance(Ts, numbers.Real) and not isinstance(Ts, bool):
            return float(Ts)
        return paper.TS

    def replace(self, **changes) -> RunSpec:
        """A copy with some fields changed (checked again)."""
        return _replace(self, changes)
