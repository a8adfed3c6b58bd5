"""Motor profiles: the gearmotors a rig can be built with, from their datasheets and measurements.

A :class:`MotorProfile` holds what the host must know about a rig's motor: the H-bridge supply,
the gear ratio, the encoder's counts per motor revolution and per output revolution, the
first-order model's K and τ (Stojčić eq. 1, ASCII Stojcic eq. 1: τ θ'' + θ' = K u) with the
ranges a bought unit falls in, the Coulomb friction (as input volts) and where every number
comes from. The built-in profiles live in ``jerklab/rig/profiles.json``:

======================== ========================================================== ======
name                     motor                                                      counts
======================== ========================================================== ======
``paper``                the paper's motor (K = 32.4 rad/(V s), τ = 25 ms)          448
``pololu-37d-30``        Pololu 37D 30:1 12 V, 64 CPR encoder (item 4752)           1920
``pololu-25d-47-hp``     Pololu 25D 47:1 HP 12 V, 48 CPR encoder (item 4845)        2248
``jgb37-520-30``         JGB37-520 12 V 1:30, 11-PPR Hall encoder                   1320
``pololu-micro-30-hpcb`` Pololu micro metal 30:1 HPCB 12 V, 12 CPR magnetic encoder 360
======================== ========================================================== ======

(counts: per output revolution as the firmware counts them: the paper's x1 (one edge of
channel A), the geared motors' x4 (both edges of both channels; ``counts_per_rev`` = 4 ×
``JL_ENCODER_PPR``, the integer pulses of one channel per output revolution: within 0.04 % and
0.5 % of the 25D's 2248.86 and the micro gearmotor's 358.3). At x1 one count of a
3 rad/(V s) motor is too coarse for its loop: through the derivative gain a count kicks the
voltage by volts. Their edge rates at top speed, 1.2–11 kHz, are far below the encoder
interrupt's limit.)

From a datasheet's no-load speed ω₀ (rad/s at the rated voltage V), no-load current I₀ and
stall current I_s (Stojčić eq. 1 at rest of the transient, ω = K (u − f_c)):

* the friction torque is k_t I₀, as input volts f_c = R I₀ = V I₀ / I_s;
* the gain is K = ω₀ / (V − f_c).

Where the datasheet does not state I₀ or I_s, the profile gives the friction itself (an
estimate, to be measured by ``jerklab rig check``). No datasheet gives τ (it needs the
rotor's inertia): its range is an estimate that lab 1 replaces with the identified value. The
micro gearmotor's τ and friction come from the measured records in ``data/real/micromouse``.

A rig check report (``jerklab rig check PORT --profile NAME --save rig.json``) is a profile
file: :func:`load_profile` reads a built-in name, such a file, or a profile.

>>> from jerklab.rig.profiles import load_profile
>>> p = load_profile("pololu-37d-30")
>>> p.counts_per_rev, round(p.K, 2), round(p.top_speed(), 1)
(1920, 2.99, 34.6)
"""

from __future__ import annotations

import datetime
import functools
import itertools
import json
import math
import os
from dataclasses import asdict, dataclass, field, replace
from importlib import resources
from pathlib import Path

from jerklab._validate import as_positive
from jerklab.plant import DCMotor

__all__ = [
    "MotorProfile",
    "load_profile",
    "profile_from_dict",
    "profile_names",
    "PROFILE_FILE_FORMAT",
    "builtin_profiles",
]

#: the ``format`` field of a single-profile file (a rig check report)
PROFILE_FILE_FORMAT = "jerklab-motor-profile"


@dataclass(frozen=True)
class MotorProfile:
    """One motor as a rig runs it (SI units; counts per *output* revolution).

    Attributes
    ----------
    name, title : str
        Short name (``"pololu-37d-30"``) and what to buy.
    supply_voltage : float
        H-bridge supply (V).
    gear_ratio : float or None
        Motor revolutions per output revolution (None: not stated, the paper's motor).
    counts_per_motor_rev : int or None
        The encoder's counts per motor revolution as its vendor counts them (both edges of
        both channels, "CPR").
    counts_per_rev : int
        Counts per output revolution as the rig counts them (the host's ``counts_per_rev``).
    counts_options : tuple of int
        The encoders a class may have (hidden motors draw one).
    K, tau : float
        The nominal model, rad/(V s) and s.
    K_range, tau_range, friction_range : (float, float)
        Where a unit of this motor falls.
    coulomb_friction : float
        Nominal Coulomb friction, input referred (V).
    part, datasheet, measured, wires : dict
        Vendor and item; the datasheet numbers and their source; a measurement (or None); the
        colour of each wire of the motor's 6-wire lead (or None).
    """

    name: str
    title: str
    supply_voltage: float
    gear_ratio: float | None
    counts_per_motor_rev: int | None
    counts_per_rev: int
    counts_options: tuple
    K: float
    K_range: tuple
    tau: float
    tau_range: tuple
    coulomb_friction: float
    friction_range: tuple
    part: dict = field(default_factory=dict)
    datasheet: dict = field(default_factory=dict)
    measured: dict | None = None
    wires: dict | None = None

    def __post_init__(self):
        as_positive("supply_voltage", self.supply_voltage)
        as_positive("K", self.K)
        as_positive("tau", self.tau)
        if not (isinstance(self.counts_per_rev, int) and self.counts_per_rev > 0):
            raise ValueError(
                f"counts_per_rev must be a positive integer, got {self.counts_per_rev!r}"
            )
        for name in ("K_range", "tau_range", "friction_range"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
                raise ValueError(
                    f"{name} must be (low, high) with 0 <= low <= high, got {(lo, hi)!r}"
                )
        if not self.K_range[0] <= self.K <= self.K_range[1]:
            raise ValueError(f"K = {self.K:g} lies outside K_range {self.K_range}")
        if not self.tau_range[0] <= self.tau <= self.tau_range[1]:
            raise ValueError(f"tau = {self.tau:g} lies outside tau_range {self.tau_range}")
        if self.coulomb_friction >= self.supply_voltage:
            raise ValueError("coulomb_friction must be below the supply voltage")

    # ------------------------------------------------------------------ derived
    @property
    def counts_per_rad(self) -> float:
        return self.counts_per_rev / (2.0 * math.pi)

    def top_speed(self, K=None, friction=None) -> float:
        """Steady speed at full supply (rad/s): K (V − f_c) (Stojčić eq. 1 at rest of the
        transient), for the nominal motor or the given K and friction."""
        K = self.K if K is None else K
        fc = self.coulomb_friction if friction is None else friction
        return K * (self.supply_voltage - fc)

    def top_accel(self, K=None, tau=None, friction=None) -> float:
        """Acceleration from rest at full supply (rad/s²): K (V − f_c) / τ (Stojčić eq. 1)."""
        tau = self.tau if tau is None else tau
        return self.top_speed(K, friction) / tau

    def weakest(self) -> dict:
        """The corner of the ranges with the lowest top speed and acceleration: the smallest
        K, the largest τ and friction."""
        return {
            "K": self.K_range[0],
            "tau": self.tau_range[1],
            "coulomb_friction": self.friction_range[1],
        }

    def corners(self) -> list:
        """The 8 corners of (K, τ, friction) ranges, as dicts."""
        return [
            {"K": K, "tau": tau, "coulomb_friction": fc}
            for K, tau, fc in itertools.product(self.K_range, self.tau_range, self.friction_range)
        ]

    def motor(self, **changes) -> DCMotor:
        """A :class:`jerklab.plant.DCMotor` of this profile (nominal K, τ, friction, its supply
        and encoder; 10-bit PWM as the firmware), with ``changes`` to its arguments."""
        kw = dict(
            K=self.K,
            tau=self.tau,
            supply_voltage=self.supply_voltage,
            pwm_bits=10,
            encoder_ppr=self.counts_per_rev,
            decoding=1,
            coulomb_friction=self.coulomb_friction,
        )
        kw.update(changes)
        return DCMotor(**kw)

    def replace(self, **changes) -> MotorProfile:
        """A copy with some fields changed."""
        return replace(self, **changes)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("counts_options", "K_range", "tau_range", "friction_range"):
            d[k] = list(d[k])
        return d

    def save(self, path) -> Path:
        """Write this profile as a profile file (JSON) that :func:`load_profile` reads."""
        path = Path(path)
        data = {
            "format": PROFILE_FILE_FORMAT,
            "version": 1,
            "written": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "profile": self.to_dict(),
        }
        path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
        return path


def _from_entry(name: str, e: dict) -> MotorProfile:
    """A profile from an entry of profiles.json: K and friction from the datasheet where it
    states the no-load current and the stall current (the module docstring's formulas)."""
    V = float(e["supply_voltage"])
    ds = e.get("datasheet") or {}
    meas = e.get("measured") or {}
    w0 = ds["no_load_rpm"] * 2.0 * math.pi / 60.0 if ds.get("no_load_rpm") else None
    if "coulomb_friction" in meas:
        fc = float(meas["coulomb_friction"])
    elif "coulomb_friction" in e:
        fc = float(e["coulomb_friction"])
    elif ds.get("no_load_current") and ds.get("stall_current"):
        fc = V * ds["no_load_current"] / ds["stall_current"]
    else:
        raise ValueError(f"profile {name!r}: no friction (give coulomb_friction or I0 and Is)")
    K = float(e["K"]) if "K" in e else w0 / (V - fc)
    if "K_range" in e:
        K_range = tuple(float(x) for x in e["K_range"])
    else:
        s = float(e["K_spread"])
        K_range = (K * (1 - s), K * (1 + s))
    if "friction_range" in e:
        f_range = tuple(float(x) for x in e["friction_range"])
    else:
        lo, hi = e["friction_spread"]
        f_range = (fc * lo, fc * hi)
    tau_range = tuple(float(x) for x in e["tau_range"])
    tau = float(meas.get("tau", e.get("tau", math.sqrt(tau_range[0] * tau_range[1]))))
    return MotorProfile(
        name=name,
        title=e["title"],
        supply_voltage=V,
        gear_ratio=None if e.get("gear_ratio") is None else float(e["gear_ratio"]),
        counts_per_motor_rev=e.get("counts_per_motor_rev"),
        counts_per_rev=int(e["counts_per_rev"]),
        counts_options=tuple(int(c) for c in e.get("counts_options", [e["counts_per_rev"]])),
        K=K,
        K_range=K_range,
        tau=tau,
        tau_range=tau_range,
        coulomb_friction=fc,
        friction_range=f_range,
        part=dict(e.get("part") or {}),
        datasheet=dict(ds),
        measured=dict(meas) if meas else None,
        wires=dict(e["wires"]) if e.get("wires") else None,
    )


@functools.lru_cache(maxsize=1)
def _builtin() -> dict:
    text = resources.files("jerklab.rig").joinpath("profiles.json").read_text(encoding="utf-8")
    data = json.loads(text)
    return {name: _from_entry(name, e) for name, e in data["profiles"].items()}


def builtin_profiles() -> dict:
    """The built-in profiles by name (a new dict; the profiles are frozen)."""
    return dict(_builtin())


def profile_names() -> list:
    """The built-in profiles' names, ``"paper"`` first."""
    return list(_builtin())


def _from_file(path: Path) -> MotorProfile:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"profile file {str(path)!r} cannot be read as JSON: {exc}") from exc
    if not isinstance(data, dict) or data.get("format") != PROFILE_FILE_FORMAT:
        raise ValueError(
            f"profile file {str(path)!r} is not a jerklab motor profile (no format "
            f"{PROFILE_FILE_FORMAT!r}); write one with `jerklab rig check PORT --save FILE`"
        )
    d = dict(data["profile"])
    for k in ("counts_options", "K_range", "tau_range", "friction_range"):
        d[k] = tuple(d[k])
    try:
        return MotorProfile(**d)
    except TypeError as exc:
        raise ValueError(f"profile file {str(path)!r}: {exc}") from exc


def profile_from_dict(d) -> MotorProfile:
    """The :class:`MotorProfile` of ``d`` (:meth:`MotorProfile.to_dict`, e.g. as the class rig
    service sends it); ValueError if it is not one."""
    if not isinstance(d, dict):
        raise ValueError(f"a motor profile must be a dict, got {type(d).__name__}")
    d = dict(d)
    try:
        for k in ("counts_options", "K_range", "tau_range", "friction_range"):
            d[k] = tuple(d[k])
        return MotorProfile(**d)
    except (KeyError, TypeError) as exc:
        raise ValueError(f"not a motor profile ({exc})") from None


def load_profile(profile) -> MotorProfile:
    """A :class:`MotorProfile` from a built-in name, a profile file's path, or a profile.

    Raises
    ------
    ValueError
        ``profile`` names no built-in profile and no file (the message lists the names), or
        the file is not a profile file.
    TypeError
        ``profile`` is neither a string, a path nor a MotorProfile.
    """
    if isinstance(profile, MotorProfile):
        return profile
    if isinstance(profile, os.PathLike):
        profile = os.fspath(profile)
    if not isinstance(profile, str):
        raise TypeError(
            f"profile must be a name, a profile file's path or a MotorProfile, got {type(profile).__name__}"
        )
    builtin = _builtin()
    if profile in builtin:
        return builtin[profile]
    path = Path(profile).expanduser()
    if path.is_file():
        return _from_file(path)
    raise ValueError(
        f"profile {profile!r} is neither a built-in profile ({', '.join(builtin)}) nor a file"
    )
