"""Feedforward + pole-placement PID of Stojčić (2015) §3 and §4B, and its analysis.

ASCII spelling for grep: Stojcic (Stojcic eqs. 11, 13, 16).

* :func:`pole_placement_pid` — Stojčić eq. 11: PID on the **position** plant
  P(s) = K/(s(τs+1)); the closed loop ``τs³ + (1+K kd)s² + K kp s + K ki`` is matched to
  ``τ (s+σ)(s² + 2ζωn s + ωn²)``.
* :func:`velocity_pole_placement_pid` — the same idea done correctly for the
  **velocity** plant P_v(s) = K/(τs+1) that §4B actually controls: there a PID gives the
  second-order loop ``(τ + K kd)s² + (1 + K kp)s + K ki``, so Stojčić eq. 11's gains do not put
  the poles where Stojčić eq. 11 says (the paper does not notice).
* :meth:`Gains.discretize` — Stojčić eqs. 12, 13 (trapezoidal integral, backward derivative).
  At Ts = 5 ms this "continuous design, then discretize" route leaves the designed
  poles and goes unstable near ωn = 50 rad/s (``|z|`` = 1.16).
* :func:`discrete_pole_placement_pid` — design directly in z: the desired s-poles are
  mapped by z = e^{s Ts} and the gains solved on the exact ZOH plant, so the closed-loop
  poles land where asked at any Ts.
* :class:`Feedforward` (Stojčić eqs. 8, 16) and :class:`DigitalController`
  (Stojčić eqs. 16–18) with the
  output limit, anti-windup and bumpless start the paper leaves out.
* :class:`PositionLoop`, :class:`VelocityLoop` — open/closed loop as python-control
  systems, poles in s and z, margins and fast responses (used by the tuning widgets).

SI units inside. The paper's velocity loop measures the error in encoder pulses per Ts;
that is the ``error_scale`` of the controller (:func:`paper_error_scale`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from jerklab import law, paper
from jerklab._lazy import lazy_module
from jerklab._validate import as_int, as_nonnegative, as_positive, as_real

ct = lazy_module("control")  # python-control imports matplotlib: import it on first use

__all__ = [
    "Gains",
    "DiscreteGains",
    "pole_placement_pid",
    "velocity_pole_placement_pid",
    "discrete_pole_placement_pid",
    "paper_error_scale",
    "paper_velocity_controller",
    "Feedforward",
    "DigitalController",
    "PositionLoop",
    "VelocityLoop",
    "desired_poles",
    "closed_loop_poles",
    "max_pole_radius",
    "is_stable",
]


# ---------------------------------------------------------------------------
# gains
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class DiscreteGains:
    """Discrete PID gains of Stojčić eqs. 12–14 at sampling time ``Ts``.

    ``B(z) = kpd + kid/(1 − z⁻¹) + kdd (1 − z⁻¹)/(1 − γ z⁻¹)``; ``gamma`` = 0 is the paper's
    backward derivative, a non-zero ``gamma`` (``|γ|`` < 1) is a first-order derivative filter
    ``d(k) = γ d(k−1) + kdd (e(k) − e(k−1))`` used by the full z-domain placement.
    """

    kpd: float
    kid: float
    kdd: float
    Ts: float
    gamma: float = 0.0
    loop: str = "position"
    design: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        for name in ("kpd", "kid", "kdd", "gamma"):
            object.__setattr__(self, name, as_real(name, getattr(self, name)))
        object.__setattr__(self, "Ts", as_positive("Ts", self.Ts))
        if not abs(self.gamma) < 1.0:
            raise ValueError(
                f"gamma (derivative filter pole) must satisfy |gamma| < 1, got {self.gamma}"
            )
        if self.loop not in ("position", "velocity"):
            raise ValueError(f"loop must be 'position' or 'velocity', got {self.loop!r}")

    def tf(self):
        """``B(z)`` as a python-control transfer function with ``dt = Ts``."""
        num, den = self._polys()
        return ct.tf(num, den, self.Ts)

    def _polys(self):
        # B(z) = [kpd (z-1)(z-g) + kid z (z-g) + kdd (z-1)^2] / ((z-1)(z-g))
        g = self.gamma
        num = (
            self.kpd * np.array([1.0, -1.0 - g, g])
            + self.kid * np.array([1.0, -g, 0.0])
            + self.kdd * np.array([1.0, -2.0, 1.0])
        )
        den = np.array([1.0, -1.0 - g, g])
        return num, den


@dataclass(frozen=True)
class Gains:
    """Continuous PID gains, Stojčić eq. 10: ``B(s) = kp + ki/s + kd s``.

    ``Ti = kp/ki`` and ``Td = kd/kp`` (Stojčić eq. 10); ``design`` records how they were obtained.
    """

    kp: float
    ki: float
    kd: float
    loop: str = "position"
    design: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        for name in ("kp", "ki", "kd"):
            object.__setattr__(self, name, as_real(name, getattr(self, name)))
        if self.loop not in ("position", "velocity"):
            raise ValueError(f"loop must be 'position' or 'velocity', got {self.loop!r}")

    @property
    def Ti(self) -> float:
        """Integral time kp/ki (s); inf without integral action."""
        return math.inf if self.ki == 0.0 else self.kp / self.ki

    @property
    def Td(self) -> float:
        """Derivative time kd/kp (s)."""
        if self.kp == 0.0:
            raise ValueError("Td = kd/kp is undefined for kp = 0")
        return self.kd / self.kp

    def discretize(self, Ts) -> DiscreteGains:
        """Stojčić eq. 13: ``kpd = kp(1 − Ts/(2Ti))``, ``kid = kp Ts/Ti``, ``kdd = kp Td/Ts``.

        Trapezoidal integral, backward derivative (Stojčić eq. 12). Written as
        ``kp − ki Ts/2``, ``ki Ts``, ``kd/Ts`` (the same algebra, safe for ki = 0 or kp = 0).
        """
        Ts = as_positive("Ts", Ts)
        return DiscreteGains(
            self.kp - self.ki * Ts / 2.0,
            self.ki * Ts,
            self.kd / Ts,
            Ts,
            loop=self.loop,
            design=dict(self.design, method="eq13", Ts=Ts),
        )

    def tf_polys(self):
        """Numerator and denominator of ``B(s) = (kd s² + kp s + ki)/s``."""
        return np.array([self.kd, self.kp, self.ki]), np.array([1.0, 0.0])


def _check_design(K, tau, wn, zeta):
    return (
        as_positive("K", K),
        as_positive("tau", tau),
        as_positive("wn", wn),
        as_positive("zeta", zeta),
    )


def desired_poles(wn, zeta=1.0, sigma=None):
    """The s-poles of ``(s + σ)(s² + 2ζωn s + ωn²)`` (σ omitted: the pair only)."""
    wn = as_positive("wn", wn)
    zeta = as_positive("zeta", zeta)
    if not math.isfinite(wn * wn * zeta):
        raise ValueError(f"wn={wn} (with zeta={zeta}) is too large: wn² overflows")
    pair = np.roots([1.0, 2.0 * zeta * wn, wn * wn]).astype(complex)
    if sigma is None:
        return pair
    return np.r_[-as_positive("sigma", sigma) + 0j, pair]


#: smallest real pole sigma / wn a design takes: a slower pole would leave the integral action
#: idle for 1/sigma seconds (1e-300 rad/s: forever) and its sampled pole e^(-sigma Ts) rounds to 1
SIGMA_MIN_RATIO = 1e-6


def _check_sigma(sigma, wn) -> float:
    """``sigma`` (default ``paper.SIGMA_RATIO wn``) checked against ``SIGMA_MIN_RATIO wn``."""
    if sigma is None:
        return paper.SIGMA_RATIO * wn
    sigma = as_positive("sigma", sigma)
    if sigma < SIGMA_MIN_RATIO * wn:
        raise ValueError(
            f"sigma must be >= controller.SIGMA_MIN_RATIO * wn = {SIGMA_MIN_RATIO * wn:g} rad/s, "
            f"got {sigma!r}: a real pole that slow leaves the integral action idle (the paper "
            f"asks sigma >= 7 wn)"
        )
    return sigma


def pole_placement_pid(K, tau, wn, zeta=1.0, sigma=None) -> Gains:
    """PID gains for the position loop P(s) = K/(s(τs+1)), Stojčić eq. 11.

    ``kp = ωn τ(2ζσ + ωn)/K``, ``ki = τσωn²/K``, ``kd = (τ(2ζωn + σ) − 1)/K`` place the
    closed-loop poles at ``−σ`` and the roots of ``s² + 2ζωn s + ωn²``.

    Parameters
    ----------
    K, tau : float
        Plant gain (rad/(V·s)) and time constant (s).
    wn : float
        Natural frequency of the dominant pair (rad/s). The paper never states it.
    zeta : float
        Damping of the pair (the paper uses 1).
    sigma : float, optional
        Real pole (rad/s), default ``7 wn`` (the paper asks σ ≥ 7ωn); at least
        ``SIGMA_MIN_RATIO wn`` (1e-6 ωn), a slower pole raises ValueError.
    """
    K, tau, wn, zeta = _check_design(K, tau, wn, zeta)
    sigma = _check_sigma(sigma, wn)
    kp = wn * tau * (2.0 * zeta * sigma + wn) / K
    ki = tau * sigma * wn * wn / K
    kd = (tau * (2.0 * zeta * wn + sigma) - 1.0) / K
    if not (math.isfinite(kp) and math.isfinite(ki) and math.isfinite(kd)):
        raise ValueError(
            f"wn={wn}, sigma={sigma} (K={K}, tau={tau}) give gains that overflow "
            f"(kp={kp}, ki={ki}, kd={kd}); choose a smaller wn"
        )
    return Gains(
        kp,
        ki,
        kd,
        loop="position",
        design=dict(method="eq11", K=K, tau=tau, wn=wn, zeta=zeta, sigma=sigma),
    )


def velocity_pole_placement_pid(K, tau, wn, zeta=1.0, kd=0.0) -> Gains:
    """PID gains placing the poles of the velocity loop on P_v(s) = K/(τs+1) (§4B done right).

    With ``B = kp + ki/s + kd s`` the characteristic polynomial is
    ``(τ + K kd)s² + (1 + K kp)s + K ki`` — second order, so only the pair
    ``s² + 2ζωn s + ωn²`` can be placed and ``kd`` is a free choice (default 0, a PI):
    ``kp = (2ζωn(τ + K kd) − 1)/K``, ``ki = (τ + K kd)ωn²/K``. Applying Stojčić eq. 11's gains to
    this loop, as the paper does, puts its poles elsewhere.
    """
    K, tau, wn, zeta = _check_design(K, tau, wn, zeta)
    kd = as_real("kd", kd)
    lead = tau + K * kd
    if lead <= 0.0:
        raise ValueError(f"kd must satisfy tau + K*kd > 0, got kd={kd}")
    kp = (2.0 * zeta * wn * lead - 1.0) / K
    ki = lead * wn * wn / K
    if not (math.isfinite(kp) and math.isfinite(ki)):
        raise ValueError(
            f"wn={wn} (K={K}, tau={tau}, kd={kd}) gives gains that overflow "
            f"(kp={kp}, ki={ki}); choose a smaller wn"
        )
    return Gains(
        kp, ki, kd, loop="velocity", design=dict(method="velocity", K=K, tau=tau, wn=wn, zeta=zeta)
    )


def _zoh_position(K, tau, Ts):
    """ZOH P(z) = (b1 z + b0)/((z − 1)(z − a)) of Stojčić eq. 1 (:func:`jerklab.law.zoh_coefficients`)."""
    z = law.zoh_coefficients(K, tau, Ts)
    return np.array([z.b1, z.b0]), np.array([1.0, -1.0 - z.a, z.a])


def _plant_polys(K, tau, Ts, loop):
    """Discrete plant from u(k) to the measured loop variable.

    Position: the ZOH P(z). Velocity: the velocity the firmware measures, encoder
    pulses counted over the last sample, ``(θ(k) − θ(k−1))/Ts = (1 − z⁻¹)/Ts · P(z)
    = (b1 z + b0)/(Ts z (z − a))``.
    """
    num, den = _zoh_position(K, tau, Ts)
    if loop == "position":
        return num, den
    a = den[2]
    return num / Ts, np.array([1.0, -a, 0.0])


def discrete_pole_placement_pid(
    K, tau, wn, zeta=paper.ZETA, sigma=None, Ts=paper.TS, loop="position", extra_pole=None
) -> DiscreteGains:
    """Pole placement directly in z on the exact ZOH plant.

    The desired s-poles ``−σ`` and the roots of ``s² + 2ζωn s + ωn²`` are mapped by
    ``z = e^{s Ts}``; the gains of Stojčić eq. 12 are then solved from the closed-loop
    characteristic polynomial ``den_P(z)·den_B(z) + num_P(z)·num_B(z)`` (linear in the
    gains), so those poles land exactly where asked at any Ts.

    The sampled loop has four poles (plant 2 + integrator + derivative) and Stojčić eq. 12 has
    three gains: with ``extra_pole=None`` (default, the paper's controller structure,
    runs unchanged on the firmware) three poles are placed and the fourth lands where
    the algebra puts it (``design["fourth_pole"]``). With ``extra_pole=z4`` a derivative
    filter pole ``gamma`` is added and all four poles are placed (the fourth at ``z4``).

    For ``loop="velocity"`` the plant is the velocity measured as pulses per sample
    (see :func:`_plant_polys`); σ then sets the third pole.
    """
    K, tau, wn, zeta = _check_design(K, tau, wn, zeta)
    sigma = _check_sigma(sigma, wn)
    Ts = as_positive("Ts", Ts)
    if loop not in ("position", "velocity"):
        raise ValueError(f"loop must be 'position' or 'velocity', got {loop!r}")
    zp = np.exp(desired_poles(wn, zeta, sigma) * Ts)
    d3 = np.real(np.poly(zp))  # monic cubic
    B, A = _plant_polys(K, tau, Ts, loop)  # plant num (deg 1), den (deg 2)
    Q = np.polymul(A, [1.0, -1.0])  # plant den × integrator (deg 3)
    # unknowns x = (n0, n1, n2, c): controller numerator n(z) and either
    #   (gamma fixed 0)  A(z)(z-1) z + B(z) n(z) = d3(z) (z - c)       [c = fourth pole]
    #   (extra pole z4)  A(z)(z-1)(z - c) + B(z) n(z) = d3(z) (z - z4)  [c = gamma]
    M = np.zeros((5, 4))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        M[:, j] = np.r_[np.zeros(5), np.polymul(B, e)][-5:]
    if extra_pole is None:
        M[:, 3] = np.r_[0.0, d3]
        rhs = np.r_[d3, 0.0] - np.r_[Q, 0.0]
    else:
        z4 = as_real("extra_pole", extra_pole)
        if not abs(z4) < 1.0:
            raise ValueError(f"extra_pole must lie inside the unit circle, got {z4}")
        M[:, 3] = -np.r_[0.0, Q]
        rhs = np.polymul(d3, [1.0, -z4]) - np.r_[Q, 0.0]
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(rhs))):
        raise ValueError(
            f"wn={wn}, sigma={sigma}, Ts={Ts}: the sampled design overflows (poles e^(s Ts) "
            "not representable); choose a smaller wn or Ts"
        )
    try:
        x = np.linalg.solve(M[1:], rhs[1:])
    except np.linalg.LinAlgError:
        raise ValueError(
            f"wn={wn}, sigma={sigma}, Ts={Ts} (K={K}, tau={tau}): the pole-placement equations "
            "are singular "
            "(poles e^(s Ts) coincide with the plant's); choose another wn or Ts"
        ) from None
    n = x[:3]
    if extra_pole is None:
        gamma, fourth = 0.0, float(x[3])
    else:
        gamma, fourth = float(x[3]), float(extra_pole)
        if not abs(gamma) < 1.0:
            raise ValueError(
                f"extra_pole={extra_pole}: placing all four poles needs a derivative filter "
                f"pole gamma = {gamma:.4g} outside the unit circle (an unstable controller); "
                "choose another extra_pole or extra_pole=None"
            )
    # decompose n(z) = kpd (z-1)(z-g) + kid z (z-g) + kdd (z-1)^2
    T = np.array([[1.0, 1.0, 1.0], [-(1.0 + gamma), -gamma, -2.0], [gamma, 0.0, 1.0]])
    kpd, kid, kdd = np.linalg.solve(T, n)
    return DiscreteGains(
        float(kpd),
        float(kid),
        float(kdd),
        Ts,
        gamma=gamma,
        loop=loop,
        design=dict(
            method="z-domain",
            K=K,
            tau=tau,
            wn=wn,
            zeta=zeta,
            sigma=sigma,
            Ts=Ts,
            poles_z=zp,
            fourth_pole=fourth,
        ),
    )


def paper_error_scale(Ts=paper.TS, encoder_ppr=paper.ENCODER_PPR, decoding=paper.ENCODER_DECODING):
    """Pulses per sample per rad/s: ``encoder_ppr·decoding·Ts/(2π)`` (≈ 0.357 = 1/2.80).

    Stojčić §4B feeds the PID the velocity error as encoder pulses counted per Ts; with
    SI gains that equals a controller ``error_scale`` of this value.
    """
    Ts = as_positive("Ts", Ts)
    encoder_ppr = as_int("encoder_ppr", encoder_ppr, minimum=1)
    decoding = as_int("decoding", decoding)
    if decoding not in (1, 2, 4):
        raise ValueError(f"decoding must be 1, 2 or 4, got {decoding}")
    return encoder_ppr * decoding * Ts / (2.0 * math.pi)


# ---------------------------------------------------------------------------
# feedforward and the digital controller
# ---------------------------------------------------------------------------
class Feedforward:
    """Plant-inverse feedforward, Stojčić eqs. 7, 8, 16: ``u_F = (τ ε + ω)/K``.

    The inverse of P_v(s), so the same for the position and the velocity loop.
    """

    def __init__(self, K, tau):
        self.K = as_positive("K", K)
        self.tau = as_nonnegative("tau", tau)

    def __call__(self, velocity, accel):
        """Feedforward voltage for the reference velocity (rad/s) and acceleration (rad/s²)."""
        return (
            self.tau * np.asarray(accel, dtype=float) + np.asarray(velocity, dtype=float)
        ) / self.K

    def __repr__(self):
        return f"Feedforward(K={self.K!r}, tau={self.tau!r})"


_pid_step = law.SCALAR["pid_step"]  # the law's Python form: faster than a compiled call from Python

_LOOPS = ("position", "velocity")


class DigitalController:
    """Feedforward + discrete PID run sample by sample (Stojčić eqs. 16–18).

    ``p(k) = kpd e(k)``, ``i(k) = i(k−1) + kid e(k)``, ``d(k) = γ d(k−1) + kdd (e(k) − e(k−1))``
    (γ = 0: Stojčić eq. 17), ``u = u_F + p + i + d`` (Stojčić eq. 18 plus the feedforward of
    Stojčić eq. 16), then clamped to ``±output_limit``. The paper has no limit and no
    anti-windup; here, when the output is clamped and the error drives it further into the
    limit, the integrator keeps its previous value (conditional integration, as the
    firmware). The law itself is :func:`jerklab.law.pid_step`, shared with the simulation
    kernels and the virtual rig.

    A non-finite measurement (NaN or inf from a broken sensor or a diverged model) is not
    fed to the law: the controller **holds its last output**, leaves its state untouched,
    counts the sample in :attr:`nonfinite_count`, sets :attr:`fault` and warns once per run
    (``RuntimeWarning``); ``last_parts["held"]`` is True for such a sample. The next finite
    measurement resumes the law. :meth:`reset` clears the fault.

    Parameters
    ----------
    gains : DiscreteGains
    feedforward : Feedforward or None
    output_limit : float or None
        Output clamp (V), the supply voltage; None for none.
    anti_windup : bool
        Conditional integration while clamped (False: the paper's plain integrator).
    loop : {"position", "velocity"} or None
        Position loop: ``e = r_θ − θ_m``. Velocity loop (§4B): ``e = ω_r − (θ_m(k) −
        θ_m(k−1))/Ts``, the measured velocity being pulses counted over the last sample.
        Default: ``gains.loop``.
    error_scale : float
        Multiplies the error before the PID (1 for SI; :func:`paper_error_scale` for the
        paper's pulses-per-Ts error).
    bumpless : bool
        On the first sample after :meth:`reset`, take ``e(k−1) = e(k)`` (no derivative
        kick) and, if ``reset(last_output=u0)`` was given, preload the integrator so
        that ``u(0) = u0``. False: the paper's zero initial conditions.

    Attributes
    ----------
    fault : str or None
        ``"non-finite measurement"`` once a NaN/inf measurement was held in this run.
    nonfinite_count : int
        Samples held because of a non-finite measurement since :meth:`reset`.
    """

    def __init__(
        self,
        gains,
        feedforward=None,
        output_limit=paper.SUPPLY_VOLTAGE,
        anti_windup=True,
        loop=None,
        error_scale=1.0,
        bumpless=False,
    ):
        if not isinstance(gains, DiscreteGains):
            raise ValueError(
                f"gains must be DiscreteGains (use Gains.discretize(Ts)), got {type(gains).__name__}"
            )
        if feedforward is not None and not isinstance(feedforward, Feedforward):
            raise ValueError(
                f"feedforward must be a Feedforward or None, got {type(feedforward).__name__}"
            )
        self.gains = gains
        self.feedforward = feedforward
        self.output_limit = (
            None if output_limit is None else as_positive("output_limit", output_limit)
        )
        self.anti_windup = bool(anti_windup)
        self.loop = gains.loop if loop is None else loop
        if self.loop not in _LOOPS:
            raise ValueError(f"loop must be 'position' or 'velocity', got {self.loop!r}")
        self.error_scale = as_positive("error_scale", error_scale)
        self.bumpless = bool(bumpless)
        self.reset()

    @property
    def Ts(self):
        return self.gains.Ts

    def reset(self, last_output=None):
        """Clear the state (``i = 0``, ``e(−1) = 0``, ``d(−1) = 0``) and the fault before a run.

        ``last_output`` (V) asks for a bumpless start from that output (implies
        ``bumpless`` for the next sample).
        """
        self._i = 0.0
        self._e = 0.0
        self._d = 0.0
        self._y_prev = None
        self._first = True
        self._u0 = None if last_output is None else as_real("last_output", last_output)
        self.fault = None
        self.nonfinite_count = 0
        self.last_parts = {
            "p": 0.0,
            "i": 0.0,
            "d": 0.0,
            "ff": 0.0,
            "u": 0.0,
            "e": 0.0,
            "saturated": False,
            "held": False,
        }

    def params(self):
        """The law's parameters as a dict (the names of :data:`jerklab.law.CTL_FIELDS`)."""
        g = self.gains
        ff = self.feedforward
        return dict(
            kpd=g.kpd,
            kid=g.kid,
            kdd=g.kdd,
            gamma=g.gamma,
            Ts=g.Ts,
            ff_on=ff is not None,
            ff_K=1.0 if ff is None else ff.K,
            ff_tau=0.0 if ff is None else ff.tau,
            limit=math.inf if self.output_limit is None else self.output_limit,
            anti_windup=self.anti_windup,
            velocity=self.loop == "velocity",
            error_scale=self.error_scale,
            bumpless=self.bumpless,
        )

    def law_params(self):
        """:meth:`params` packed as the float array the compiled kernels take (:func:`jerklab.law.pack`)."""
        return law.pack(**self.params())

    def _hold(self, y):
        self.nonfinite_count += 1
        if self.fault is None:
            self.fault = "non-finite measurement"
            warnings.warn(
                f"DigitalController: non-finite measurement {y!r}; holding the last output "
                f"{self.last_parts['u']!r} V (counted in nonfinite_count, fault set)",
                RuntimeWarning,
                stacklevel=3,
            )
        parts = dict(self.last_parts)
        parts["held"] = True
        self.last_parts = parts
        return parts["u"]

    def step(self, ref_position, ref_velocity=0.0, ref_accel=0.0, measured_position=0.0):
        """One sample: references (rad, rad/s, rad/s²) and the measured angle → u (V).

        Non-finite references raise ``ValueError``; a non-finite measurement holds the last
        output (see the class notes).
        """
        for name, val in (
            ("ref_position", ref_position),
            ("ref_velocity", ref_velocity),
            ("ref_accel", ref_accel),
            ("measured_position", measured_position),
        ):
            if isinstance(val, (str, bytes)):
                raise TypeError(f"{name} must be a real number, got the text {val!r}")
        try:
            r = float(ref_position)
            v = float(ref_velocity)
            a = float(ref_accel)
            y = float(measured_position)
        except (TypeError, ValueError):
            for name, val in (
                ("ref_position", ref_position),
                ("ref_velocity", ref_velocity),
                ("ref_accel", ref_accel),
                ("measured_position", measured_position),
            ):
                try:
                    float(val)
                except (TypeError, ValueError):
                    raise TypeError(
                        f"{name} must be a real number, got {val!r} ({type(val).__name__})"
                    ) from None
            raise
        if not (math.isfinite(r) and math.isfinite(v) and math.isfinite(a)):
            name, val = next(
                (n, x)
                for n, x in (("ref_position", r), ("ref_velocity", v), ("ref_accel", a))
                if not math.isfinite(x)
            )
            raise ValueError(f"{name} must be finite, got {val!r}")
        if not math.isfinite(y):
            return self._hold(y)
        g = self.gains
        saved = (self._first, self._y_prev, self._e, self._i)
        if self.loop == "position":
            e = self.error_scale * (r - y)
        else:
            y_prev = y if self._y_prev is None else self._y_prev
            e = self.error_scale * (v - (y - y_prev) / g.Ts)
        self._y_prev = y
        ff = (
            0.0 if self.feedforward is None else (self.feedforward.tau * a + v) / self.feedforward.K
        )
        if self._first and (self.bumpless or self._u0 is not None):
            self._e = e
            if self._u0 is not None:
                self._i = self._u0 - ff - g.kpd * e - g.kid * e
        self._first = False
        lim = math.inf if self.output_limit is None else self.output_limit
        u, p, i_new, d, sat = _pid_step(
            e, self._e, self._i, self._d, ff, g.kpd, g.kid, g.kdd, g.gamma, lim, self.anti_windup
        )
        if not (u - u == 0.0 and i_new - i_new == 0.0 and d - d == 0.0):  # NaN or inf
            self._first, self._y_prev, self._e, self._i = saved
            raise ValueError(
                f"ref_position={r!r}, ref_velocity={v!r}, ref_accel={a!r}, "
                f"measured_position={y!r}: the law overflows (error {e!r}, output {u!r}); "
                f"the controller's state is unchanged: scale the units"
            )
        self._i = i_new
        self._e = e
        self._d = d
        self.last_parts = {
            "p": p,
            "i": i_new,
            "d": d,
            "ff": ff,
            "u": u,
            "e": e,
            "saturated": sat,
            "held": False,
        }
        return u


def paper_velocity_controller(
    K=paper.MOTOR_K,
    tau=paper.MOTOR_TAU,
    wn=10.0,
    zeta=paper.ZETA,
    sigma=None,
    Ts=paper.TS,
    encoder_ppr=paper.ENCODER_PPR,
    decoding=paper.ENCODER_DECODING,
    output_limit=paper.SUPPLY_VOLTAGE,
):
    """Stojčić §4B exactly as published, to reproduce it (not to use it).

    Stojčić eq. 11 gains designed for the *position* loop, discretized by Stojčić eq. 13, run on the
    *velocity* loop with the error in encoder pulses per ``Ts`` (``error_scale`` =
    :func:`paper_error_scale`), Stojčić eq. 16 feedforward, no anti-windup (the paper has
    none). :class:`VelocityLoop` shows that this sampled loop is unstable for all but
    small ``wn``; :func:`velocity_pole_placement_pid` or
    ``discrete_pole_placement_pid(..., loop="velocity")`` place it correctly.
    """
    g = pole_placement_pid(K, tau, wn, zeta, sigma).discretize(Ts)
    d = DiscreteGains(
        g.kpd, g.kid, g.kdd, g.Ts, loop="velocity", design=dict(g.design, paper="§4B")
    )
    return DigitalController(
        d,
        Feedforward(K, tau),
        output_limit=output_limit,
        anti_windup=False,
        loop="velocity",
        error_scale=paper_error_scale(Ts, encoder_ppr, decoding),
    )


# ---------------------------------------------------------------------------
# loop analysis
# ---------------------------------------------------------------------------
def _lf(num, den, x):
    """Filter ``x`` by ``num(z)/den(z)`` (polynomials in z, highest power first)."""
    num = np.r_[np.zeros(len(den) - len(num)), num]
    return lfilter(num, den, x)


class _Loop:
    """Shared machinery of :class:`PositionLoop` and :class:`VelocityLoop`."""

    loop = "position"

    def __init__(self, K, tau, gains, Ts=None, error_scale=1.0):
        self.K = as_positive("K", K)
        self.tau = as_positive("tau", tau)
        self.error_scale = as_positive("error_scale", error_scale)
        if isinstance(gains, DiscreteGains):
            if Ts is not None and not math.isclose(as_positive("Ts", Ts), gains.Ts):
                raise ValueError(f"Ts={Ts} differs from gains.Ts={gains.Ts}")
            self.gains, self.Ts = gains, gains.Ts
        elif isinstance(gains, Gains):
            if Ts is None:
                self.gains, self.Ts = gains, None
            else:
                self.gains = gains.discretize(Ts)
                self.Ts = self.gains.Ts
        else:
            raise ValueError(f"gains must be Gains or DiscreteGains, got {type(gains).__name__}")
        self._build()
        if not (np.all(np.isfinite(self._char)) and np.all(np.isfinite(self._Ln))):
            raise ValueError(
                f"Ts={self.Ts} (K={self.K}, tau={self.tau}): the loop's polynomials overflow; "
                "choose a smaller Ts"
            )

    @property
    def discrete(self) -> bool:
        return self.Ts is not None

    def _build(self):
        k = self.error_scale
        if self.discrete:
            self._Pn, self._Pd = _plant_polys(self.K, self.tau, self.Ts, self.loop)
            self._Cn, self._Cd = self.gains._polys()
        else:
            if self.loop == "position":
                self._Pn, self._Pd = np.array([self.K]), np.array([self.tau, 1.0, 0.0])
            else:
                self._Pn, self._Pd = np.array([self.K]), np.array([self.tau, 1.0])
            self._Cn, self._Cd = self.gains.tf_polys()
        self._Cn = self._Cn * k
        self._Ln = np.polymul(self._Pn, self._Cn)
        self._Ld = np.polymul(self._Pd, self._Cd)
        self._char = np.polyadd(self._Ld, self._Ln)

    def _tf(self, num, den):
        return ct.tf(num, den) if not self.discrete else ct.tf(num, den, self.Ts)

    # --- python-control systems --------------------------------------------
    def plant(self):
        """Plant seen by the controller (continuous, or exact ZOH / pulse-count model)."""
        return self._tf(self._Pn, self._Pd)

    def controller(self):
        """B(s) (improper, kd s) or B(z) as a transfer function."""
        return self._tf(self._Cn, self._Cd)

    def open_loop(self):
        """L = B P."""
        return self._tf(self._Ln, self._Ld)

    def closed_loop(self):
        """Reference → output without feedforward, ``T = L/(1 + L)``."""
        return self._tf(self._Ln, self._char)

    def disturbance_tf(self):
        """Input-referred disturbance w (V) → output: ``P/(1 + L)`` (Stojčić eqs. 6, 9)."""
        return self._tf(np.polymul(self._Pn, self._Cd), self._char)

    def sensitivity(self):
        """``S = 1/(1 + L)``: reference → error."""
        return self._tf(self._Ld, self._char)

    # --- poles and margins ---------------------------------------------------
    def characteristic(self):
        """Closed-loop characteristic polynomial (highest power first)."""
        return self._char.copy()

    def poles(self):
        """Closed-loop poles (s for a continuous loop, z for a sampled one)."""
        return np.roots(self._char)

    def poles_z(self):
        """Closed-loop poles in z (a continuous loop needs Ts: not available)."""
        if not self.discrete:
            raise ValueError("poles_z needs a sampled loop (give Ts or DiscreteGains)")
        return self.poles()

    def poles_s(self):
        """Closed-loop poles in s; for a sampled loop the equivalent ``ln(z)/Ts``."""
        p = self.poles()
        if not self.discrete:
            return p
        with np.errstate(divide="ignore"):
            return np.log(p.astype(complex)) / self.Ts

    def max_pole_radius(self) -> float:
        """Largest ``|z|`` (sampled loop) — stable iff < 1."""
        return float(np.max(np.abs(self.poles_z())))

    def max_pole_real(self) -> float:
        """Largest real part of the s-poles (continuous loop) — stable iff < 0."""
        return float(np.max(np.real(self.poles_s())))

    def is_stable(self) -> bool:
        if self.discrete:
            return self.max_pole_radius() < 1.0
        return self.max_pole_real() < 0.0

    def margins(self):
        """Gain margin (abs), phase margin (deg) and their crossover frequencies (rad/s)."""
        gm, pm, wcg, wcp = ct.margin(self.open_loop())
        return dict(gain_margin=gm, phase_margin=pm, gain_crossover=wcp, phase_crossover=wcg)

    # --- fast responses (sampled loop) -----------------------------------------
    def _need_discrete(self):
        if not self.discrete:
            raise ValueError("time responses here are for a sampled loop; give Ts")

    #: the longest time response computed (samples); beyond it the request is refused
    MAX_SAMPLES = 20_000_000

    def _t(self, t_end):
        n = int(round(as_positive("t_end", t_end) / self.Ts)) + 1
        if n > self.MAX_SAMPLES:
            raise ValueError(
                f"t_end={t_end} at Ts={self.Ts} is {n} samples, more than {self.MAX_SAMPLES}"
            )
        return np.arange(n) * self.Ts

    def step_response(self, t_end=0.5):
        """Unit reference step, no feedforward: ``(t, y)`` at the samples."""
        self._need_discrete()
        t = self._t(t_end)
        y = _lf(self._Ln, self._char, np.ones_like(t))
        return t, y

    def disturbance_response(self, t_end=0.5, amplitude=1.0):
        """Output after an input-referred step disturbance of ``amplitude`` V (Stojčić eq. 9)."""
        self._need_discrete()
        t = self._t(t_end)
        y = _lf(
            np.polymul(self._Pn, self._Cd),
            self._char,
            np.full_like(t, as_real("amplitude", amplitude)),
        )
        return t, y


class PositionLoop(_Loop):
    """Position loop of Stojčić Fig. 3: PID ``gains`` on P(s) = K/(s(τs+1)).

    ``gains``: :class:`Gains` (continuous loop, or discretized by Stojčić eq. 13 when ``Ts`` is
    given) or :class:`DiscreteGains` (sampled loop on the exact ZOH plant).

    Examples
    --------
    >>> g = pole_placement_pid(32.4, 0.025, wn=50.0)
    >>> round(PositionLoop(32.4, 0.025, g, Ts=0.005).max_pole_radius(), 2)
    1.16
    """

    loop = "position"

    def tracking_error(self, profile, t_end=None, feedforward=True):
        """Tracking error ``r(kTs) − θ(kTs)`` of a move with Stojčić eq. 16 feedforward (linear loop).

        ``profile`` has ``duration`` and ``sample(t)`` (jerklab.planner). Returns
        ``(t, e)``.
        """
        self._need_discrete()
        if not (hasattr(profile, "duration") and callable(getattr(profile, "sample", None))):
            raise ValueError(
                "profile must have .duration and .sample(t) (a jerklab.planner Profile), "
                f"got {type(profile).__name__}"
            )
        t_end = (
            as_real("profile.duration", profile.duration) * 1.2 + 0.1 if t_end is None else t_end
        )
        t = self._t(t_end)
        s = profile.sample(t)
        r = np.asarray(s.position, dtype=float)
        y = _lf(self._Ln, self._char, r)
        if feedforward:
            uff = (
                self.tau * np.asarray(s.accel, dtype=float) + np.asarray(s.velocity, dtype=float)
            ) / self.K
            y = y + _lf(np.polymul(self._Pn, self._Cd), self._char, uff)
        return t, r - y


class VelocityLoop(_Loop):
    """Velocity loop of Stojčić §4B: PID ``gains`` on P_v(s) = K/(τs+1).

    Sampled, the measured velocity is pulses counted per sample (the averaged velocity
    ``(θ(k) − θ(k−1))/Ts``). ``error_scale`` = :func:`paper_error_scale` reproduces the
    paper's error in pulses per Ts.
    """

    loop = "velocity"


# ---------------------------------------------------------------------------
# stability of a design on the rig
# ---------------------------------------------------------------------------
def _sampled_gains(gains, Ts):
    if isinstance(gains, DiscreteGains):
        if Ts is not None and not math.isclose(as_positive("Ts", Ts), gains.Ts):
            raise ValueError(f"Ts={Ts} differs from gains.Ts={gains.Ts}")
        return gains
    if isinstance(gains, Gains):
        if Ts is None:
            raise ValueError(
                "Ts is required for continuous Gains (they are discretized by Stojčić eq. 13)"
            )
        return gains.discretize(Ts)
    raise TypeError(f"gains must be Gains or DiscreteGains, got {type(gains).__name__}")


def closed_loop_poles(K, tau, gains, Ts=None) -> np.ndarray:
    """Closed-loop poles in z of the loop the rig runs: the ZOH plant and the discrete PID.

    The plant is the exact zero-order-hold sampling of the motor of Stojčić eq. 1,
    ``K/(s(τs+1))`` (position loop) or the velocity measured as counts per sample
    (velocity loop, ``gains.loop``); the controller is the PID of Stojčić eq. 17 with the
    derivative filter ``gamma``. Feedforward, clamp and quantization do not move the poles.

    Parameters
    ----------
    K : float
        Motor gain (rad/(V·s)), > 0.
    tau : float
        Motor time constant (s), > 0.
    gains : Gains or DiscreteGains
        Continuous gains are discretized at ``Ts`` by Stojčić eq. 13.
    Ts : float, optional
        Sampling time (s); required for ``Gains``, checked against ``DiscreteGains.Ts``.

    Returns
    -------
    numpy.ndarray
        The complex poles in z; the loop is stable iff all ``|z| < 1``.

    Examples
    --------
    >>> g = pole_placement_pid(32.4, 0.025, wn=60.0)
    >>> round(float(max(abs(closed_loop_poles(32.4, 0.025, g, Ts=0.005)))), 2)
    1.33
    """
    d = _sampled_gains(gains, Ts)
    cls = PositionLoop if d.loop == "position" else VelocityLoop
    return cls(K, tau, d).poles_z()


def max_pole_radius(K, tau, gains, Ts=None) -> float:
    """Largest ``|z|`` of :func:`closed_loop_poles` (stable iff < 1); parameters as there."""
    return float(np.max(np.abs(closed_loop_poles(K, tau, gains, Ts))))


def is_stable(K, tau, gains, Ts=None) -> bool:
    """True when every closed-loop pole of the sampled loop (:func:`closed_loop_poles`) lies
    strictly inside the unit circle; parameters as there."""
    return max_pole_radius(K, tau, gains, Ts) < 1.0
