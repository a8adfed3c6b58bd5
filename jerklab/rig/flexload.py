"""A flexible load anyone can make: a steel rule clamped to the motor's hub, a tip mass on it.

The design (:class:`RulerLoad`): a stainless-steel rule (a 300 mm × 25 mm × 1 mm shop rule,
or spring-steel strip) clamped flat between two washers on the hub, its width along the motor
shaft so that it bends in the plane of rotation, with a free length ``L`` and a tip mass ``M``
(a bolt, nuts and washers clamped through a hole at the tip). Stand the motor shaft up: the
rule then turns in a horizontal plane and gravity loads it across its stiff width.

:func:`predict` gives, from the dimensions:

* the first bending mode with the hub held still, an Euler–Bernoulli cantilever with a tip
  mass by Rayleigh's method — tip stiffness k = 3 E I / L³, I = b h³ / 12, and the rule's
  mass counted as 33/140 of it at the tip: ω_r = √(k / (M + 33 m / 140)) (Rayleigh's
  correction, as in Timoshenko's *Vibration Problems in Engineering* and Blevins' *Formulas
  for Natural Frequency and Mode Shape*, ch. 8; the exact root of the frequency equation is in
  :func:`exact_frequency`);
* the two-mass model of ``jerklab.plant.FlexibleDCMotor`` on a motor profile: the load's
  inertia J_l = (M + 33 m / 140) R² at the tip radius R, the motor side's J_m (the motor's
  own inertia at the output, τ / (K² R_a) from its K, τ and winding resistance R_a = V / I_stall,
  plus the hub and the rest of the rule), their ratio, and the loaded rigid-body time constant
  τ (J_m + J_l) / J_motor.

docs/THEORY.md ("A flexible load you can make") derives these and states what is neglected
(the rule's rotary inertia, centrifugal stiffening, the clamp's compliance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jerklab._validate import as_nonnegative, as_positive

__all__ = [
    "RulerLoad",
    "predict",
    "exact_frequency",
    "design_loads",
    "mode_ranges",
    "DESIGN_RANGE",
    "motor_inertia",
    "STEEL",
]

#: stainless steel (AISI 304/420 shop rules): Young's modulus (Pa), density (kg/m^3)
STEEL = {"E": 193e9, "rho": 7900.0}

#: the build range of the design: free length (m) and tip mass (kg) an instructor sets
DESIGN_RANGE = {"length": (0.16, 0.23), "tip_mass": (0.020, 0.060)}


@dataclass(frozen=True)
class RulerLoad:
    """The rule and its tip mass (SI units).

    Parameters
    ----------
    length : float
        Free length L from the clamp's edge to the tip mass's centre (m).
    tip_mass : float
        Tip mass M: bolt, nuts and washers (kg).
    width, thickness : float
        The rule's cross-section b × h (m): 25 mm × 1.0 mm by default (measure h with calipers:
        the frequency goes as h^1.5).
    hub_radius : float
        From the shaft's axis to the clamp's edge (m).
    hub_inertia : float
        The hub, clamp and washers about the shaft (kg m²).
    damping : float
        Damping ratio of the mode (a bolted steel rule: 0.005–0.02).
    E, rho : float
        Young's modulus (Pa) and density (kg/m³) of the rule.
    """

    length: float = 0.18
    tip_mass: float = 0.040
    width: float = 0.025
    thickness: float = 0.0010
    hub_radius: float = 0.012
    hub_inertia: float = 2.0e-6
    damping: float = 0.01
    E: float = STEEL["E"]
    rho: float = STEEL["rho"]

    def __post_init__(self):
        for name in ("length", "width", "thickness", "E", "rho"):
            as_positive(name, getattr(self, name))
        for name in ("tip_mass", "hub_radius", "hub_inertia", "damping"):
            as_nonnegative(name, getattr(self, name))

    @property
    def EI(self) -> float:
        """Bending stiffness E b h³ / 12 (N m²)."""
        return self.E * self.width * self.thickness**3 / 12.0

    @property
    def beam_mass(self) -> float:
        """Mass of the free length ρ b h L (kg)."""
        return self.rho * self.width * self.thickness * self.length

    @property
    def tip_radius(self) -> float:
        """The tip mass's distance from the shaft axis (m)."""
        return self.hub_radius + self.length


def motor_inertia(profile) -> float:
    """A motor's inertia at the gearbox output (kg m²) from its first-order model: with
    k_t = k_e = 1/K (SI) and the winding resistance R_a = V / I_stall, τ = J R_a / (k_t k_e)
    gives J = τ / (K² R_a). ValueError when the profile has no stall current."""
    stall = (profile.datasheet or {}).get("stall_current")
    if not stall:
        raise ValueError(
            f"profile {profile.name!r} states no stall current: the motor's inertia cannot be "
            "derived; give motor_inertia= (kg m^2) measured or from its datasheet"
        )
    R_a = profile.supply_voltage / stall
    return profile.tau / (profile.K**2 * R_a)


def predict(load: RulerLoad, profile=None, motor_inertia_=None) -> dict:
    """The load's mode and two-mass parameters from its dimensions.

    Parameters
    ----------
    load : RulerLoad
    profile : jerklab.rig.profiles.MotorProfile, optional
        The motor; without it only the mode (hub held still) is given.
    motor_inertia_ : float, optional
        The motor's inertia at the output (kg m²), default :func:`motor_inertia` of the profile.

    Returns
    -------
    dict
        ``mode_hz`` and ``mode_frequency`` (rad/s) with the hub held still (Rayleigh),
        ``stiffness`` k (N/m at the tip), ``effective_mass`` (kg), ``torsional_stiffness``
        k R² (N m/rad), ``load_inertia`` J_l (kg m²), ``damping``; with a profile also
        ``motor_inertia``, ``motor_side_inertia`` J_m, ``load_ratio`` J_l/J_m, ``tau`` (the
        loaded rigid-body τ), ``K`` (unchanged) and ``coupled_hz`` (the mode the motor's
        encoder sees, from the two-mass model's poles).
    """
    if not isinstance(load, RulerLoad):
        raise TypeError(f"load must be a RulerLoad, got {type(load).__name__}")
    k = 3.0 * load.EI / load.length**3
    m_eff = load.tip_mass + 33.0 / 140.0 * load.beam_mass
    w = math.sqrt(k / m_eff)
    R = load.tip_radius
    J_l = m_eff * R**2
    out = {
        "mode_frequency": w,
        "mode_hz": w / (2.0 * math.pi),
        "stiffness": k,
        "effective_mass": m_eff,
        "torsional_stiffness": k * R**2,
        "load_inertia": J_l,
        "damping": load.damping,
    }
    if profile is None:
        return out
    J_mot = (
        motor_inertia(profile)
        if motor_inertia_ is None
        else as_positive("motor_inertia_", motor_inertia_)
    )
    # the whole rule and tip mass turning rigidly about the axis; the share not in J_l rides
    # with the motor (a lumped split: the two-mass model keeps the total rigid inertia)
    r0, L, mb = load.hub_radius, load.length, load.beam_mass
    J_rule = mb * ((r0 + L) ** 3 - r0**3) / (3.0 * L)
    J_rigid = load.hub_inertia + J_rule + load.tip_mass * R**2
    J_m = J_mot + J_rigid - J_l
    tau = profile.tau * (J_m + J_l) / J_mot
    out.update(
        motor_inertia=J_mot,
        motor_side_inertia=J_m,
        load_ratio=J_l / J_m,
        tau=tau,
        K=profile.K,
    )
    out["coupled_hz"] = _coupled_hz(tau, J_l / J_m, w, load.damping)
    return out


def _coupled_hz(tau, load_ratio, w, zeta) -> float:
    """The complex pole pair's frequency (Hz) of the two-mass model of
    ``jerklab.plant.FlexibleDCMotor`` (units where the electrical damping is 1)."""
    Jm = tau / (1.0 + load_ratio)
    Jl = tau - Jm
    k = w**2 * Jl
    c = 2.0 * zeta * w * Jl
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-k / Jm, -(1.0 + c) / Jm, k / Jm, c / Jm],
            [0.0, 0.0, 0.0, 1.0],
            [k / Jl, c / Jl, -k / Jl, -c / Jl],
        ]
    )
    ev = np.linalg.eigvals(A)
    ev = ev[np.abs(ev.imag) > 0]
    return float(abs(ev[np.argmax(ev.imag)]) / (2.0 * math.pi)) if ev.size else float("nan")


def exact_frequency(load: RulerLoad) -> float:
    """The first bending mode (rad/s, hub held still) from the exact frequency equation of an
    Euler–Bernoulli cantilever with a tip point mass (no rotary inertia),
    1 + cos β cosh β + μ β (cos β sinh β − sin β cosh β) = 0 with μ = M / (ρ b h L),
    ω = β² √(EI / (ρ b h L⁴)): the reference :func:`predict` is checked against."""
    mu = load.tip_mass / load.beam_mass

    def f(b):
        return (
            1.0
            + math.cos(b) * math.cosh(b)
            + mu * b * (math.cos(b) * math.sinh(b) - math.sin(b) * math.cosh(b))
        )

    lo, hi = 1e-6, 1.8751040687  # the first root lies below the bare cantilever's
    if f(hi) == 0.0:
        beta = hi
    else:
        for _ in range(200):  # bisection: f(lo) > 0 >= f(hi) for mu >= 0
            mid = 0.5 * (lo + hi)
            if f(mid) > 0:
                lo = mid
            else:
                hi = mid
        beta = 0.5 * (lo + hi)
    return beta**2 * math.sqrt(load.EI / (load.rho * load.width * load.thickness * load.length**4))


def design_loads(n=3):
    """The corners and middle of :data:`DESIGN_RANGE` as RulerLoads (``n`` per axis, log spaced)."""
    Ls = np.geomspace(*DESIGN_RANGE["length"], n)
    Ms = np.geomspace(*DESIGN_RANGE["tip_mass"], n)
    return [RulerLoad(length=float(L), tip_mass=float(M)) for L in Ls for M in Ms]


def mode_ranges(profile, damping=(0.01, 0.04)) -> dict:
    """The hidden loads of lab 4 on ``profile``'s motor, over the build range
    (:data:`DESIGN_RANGE`): ``mode_hz`` (hub held still) and ``load_ratio`` (J_l / J_m) from the
    smallest to the largest of the design's corners, and the ``mode_damping`` range given."""
    loads = design_loads(2)
    preds = [predict(ld, profile) for ld in loads]
    f = [p["mode_hz"] for p in preds]
    lr = [p["load_ratio"] for p in preds]
    return {
        "mode_hz": (min(f), max(f)),
        "mode_damping": tuple(damping),
        "load_ratio": (min(lr), max(lr)),
    }
