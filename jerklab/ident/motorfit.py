"""The result of the motor fit: :class:`MotorFit`, Stojčić eq. 1 (ASCII: Stojcic) with friction,
offset, dead zone, delay and coasting, and the uncertainty of each estimate."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from jerklab._lazy import lazy_module
from jerklab._validate import as_real
from jerklab.ident._common import _signal
from jerklab.ident.arx import ARXResult
from jerklab.ident.model import simulate_dc_motor, simulate_motor
from jerklab.plant import DCMotor

control = lazy_module("control")  # python-control imports matplotlib: import it on first use


@dataclass
class MotorFit:
    """K and tau of P(s) = K/(s(tau s + 1)) (Stojčić eq. 1) with their uncertainty.

    Attributes
    ----------
    K, tau : float
        Gain rad/(V s) and time constant s.
    K_std, tau_std : float
        One-sigma standard errors. PEM: the sandwich of :meth:`jerklab.ident.oe.ShootingProblem.covariance`
        (Newey-West for coloured residuals, the encoder's quantization simulated), the spread
        over records of the same motor; not a bias of a model that leaves part of the plant
        out. ARX: the textbook covariance of its least squares (white equation error).
    fit_percent : float
        Simulation fit (NRMSE %, as MATLAB ``compare``) of the angle on the estimation data.
    model : control.TransferFunction
        K / (tau s^2 + s), volts -> rad.
    method : str
        "pem", "arx", "idim" or "idim-iv" (see :func:`~jerklab.ident.fit_dc_motor`).
    Ts : float
        Sample period of the data (s).
    theta0 : float
        Initial angle of the simulation (estimated).
    cov : ndarray
        2x2 covariance of (K, tau).
    y_sim, residuals : ndarray
        Simulated angle on the estimation data and measured - simulated.
    noise_std : float
        Residual standard deviation (rad for PEM; the equation-error scale for ARX).
    friction, friction_std : float
        Coulomb friction voltage f_c (V) by the sign of the velocity, with sticking, and its standard
        error (``friction=True``; 0.0 and 0.0 when not estimated).
    offset, offset_std : float
        Input offset (V): the motor sees ``u + offset`` (``offset=True``; else 0.0, 0.0).
    dead_zone, dead_zone_std : float
        Input dead zone (V) after the offset (``dead_zone=True``; else 0.0, 0.0).
    delay : int
        Pure input delay in whole samples (given or estimated with ``delay=True``).
    tau_coast, tau_coast_std : float
        Time constant (s) while the drive is open at u = 0 (``coast=True``; :func:`simulate_motor`),
        and its standard error; 0.0 and 0.0 when the drive always holds u.
    estimated : tuple of str
        The estimated parameters, in the order of ``covariance``.
    warnings : list of str
        The diagnostics the fit raised (also issued as :class:`IdentificationWarning`).
    reversed : bool
        ``K < 0`` (a reversed encoder or motor leads): the sign flag a script can test
        instead of reading the warnings.

    The full model (:func:`simulate_motor`) is
    ``tau omega' = K (dz(u(t - delay Ts) + offset) - friction sign(omega)) - omega``, sticking at
    omega = 0 while ``|dz(u + offset)| <= friction``; ``dz(x) = sign(x) max(|x| - dead_zone, 0)``.
    """

    K: float
    tau: float
    K_std: float
    tau_std: float
    fit_percent: float
    model: control.TransferFunction
    method: str
    Ts: float
    theta0: float
    cov: np.ndarray
    y_sim: np.ndarray = field(repr=False)
    residuals: np.ndarray = field(repr=False)
    noise_std: float = float("nan")
    arx_result: ARXResult | None = field(default=None, repr=False)
    nfev: int = 0
    friction: float = 0.0  #: Coulomb friction voltage f_c (V); 0.0 when not estimated
    friction_std: float = 0.0  #: its standard error (V); 0.0 when fixed
    offset: float = 0.0  #: input offset (V): the motor sees u + offset
    offset_std: float = 0.0
    dead_zone: float = 0.0  #: input dead zone (V), after the offset
    dead_zone_std: float = 0.0
    delay: int = 0  #: pure input delay (whole samples)
    estimated: tuple = ("K", "tau")  #: names of the estimated parameters, in ``covariance`` order
    covariance: np.ndarray | None = field(default=None, repr=False)  #: covariance of ``estimated``
    warnings: list = field(default_factory=list, repr=False)  #: diagnostics raised by the fit
    n_segments: int = 1  #: shooting segments of the output-error fit
    n_experiments: int = 1  #: experiments merged in the estimation data
    omega0: float = 0.0  #: initial velocity of the first segment (rad/s)
    tau_coast: float = 0.0  #: time constant (s) with the drive open at u = 0; 0.0: no coasting
    tau_coast_std: float = 0.0

    def simulate(self, u, theta0=0.0, omega0=0.0) -> np.ndarray:
        """The fitted model's ZOH response to ``u`` (see :func:`simulate_dc_motor`).

        With friction, offset, dead zone or delay, the full model of :func:`simulate_motor`
        (friction by the sign of the velocity, with sticking).
        """
        u = _signal("u", u, min_len=1)
        if not self.is_linear:
            return simulate_motor(
                self.K,
                self.tau,
                self.Ts,
                u,
                theta0,
                omega0,
                self.friction,
                self.offset,
                self.dead_zone,
                self.delay,
                self.tau_coast or None,
            )
        return simulate_dc_motor(self.K, self.tau, self.Ts, u, theta0, omega0)

    @property
    def reversed(self) -> bool:
        """True when the fitted gain is negative: the angle falls when the voltage rises.

        The sign flag of a reversed encoder (channels A/B swapped), reversed motor leads or a
        voltage logged with the wrong sign. ``K`` stays the estimate as fitted (negative, not
        flipped); the fit also issues an :class:`IdentificationWarning` saying so. Flip the
        sign of theta (or of u) and fit again for the motor's K.
        """
        return bool(self.K < 0.0)

    @property
    def is_linear(self) -> bool:
        """True when the model is Stojčić eq. 1 alone (no friction, offset, dead zone or delay)."""
        return not (self.friction or self.offset or self.dead_zone or self.delay or self.tau_coast)

    @property
    def std(self) -> dict:
        """Standard errors by name: K, tau, friction, offset, dead_zone, tau_coast (0.0 when fixed)."""
        return {
            "K": self.K_std,
            "tau": self.tau_std,
            "friction": self.friction_std,
            "offset": self.offset_std,
            "dead_zone": self.dead_zone_std,
            "tau_coast": self.tau_coast_std,
        }

    def confidence_interval(self, level: float = 0.95):
        """Normal-approximation intervals ``{"K": (lo, hi), "tau": (lo, hi), ...}`` for every
        estimated parameter (friction, offset, dead_zone, tau_coast when estimated)."""
        level = as_real("level", level)
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must be in (0, 1), got {level}")
        z = stats.norm.ppf(0.5 + level / 2)
        out = {}
        for name in ("K", "tau", "friction", "offset", "dead_zone", "tau_coast"):
            if name in ("K", "tau") or name in self.estimated:
                v, sd = getattr(self, name), self.std[name]
                out[name] = (v - z * sd, v + z * sd)
        return out

    def to_motor(self, **kwargs):
        """A ``jerklab.plant.DCMotor`` with the fitted K and tau (other arguments passed on).

        The plant has no open-drive (coasting) mode: a fit with ``tau_coast`` raises ValueError
        (simulate it with :meth:`simulate` or :func:`simulate_motor`)."""
        if self.tau_coast:
            raise ValueError(
                "tau_coast: jerklab.plant.DCMotor has no open-drive (coasting) mode; "
                "use fit.simulate or ident.simulate_motor(..., tau_coast=fit.tau_coast)"
            )

        kw = dict(
            coulomb_friction=max(self.friction, 0.0),
            offset=self.offset,
            dead_zone=max(self.dead_zone, 0.0),
        )
        kw.update(kwargs)
        return DCMotor(K=self.K, tau=self.tau, **kw)

    def summary(self) -> str:
        """One line: K ± std, tau ± std, (friction ± std), fit %."""
        fr = ""
        if "friction" in self.estimated:
            fr += f", f_c = {self.friction:.3g} ± {self.friction_std:.2g} V"
        if "offset" in self.estimated:
            fr += f", offset = {self.offset:.3g} ± {self.offset_std:.2g} V"
        if "dead_zone" in self.estimated:
            fr += f", dead zone = {self.dead_zone:.3g} ± {self.dead_zone_std:.2g} V"
        if self.delay:
            fr += f", delay = {self.delay} sample{'s' if self.delay > 1 else ''}"
        if "tau_coast" in self.estimated:
            fr += f", tau_coast = {self.tau_coast * 1e3:.4g} ± {self.tau_coast_std * 1e3:.2g} ms"
        elif self.tau_coast == math.inf:
            fr += ", coasting on Coulomb friction (tau_coast = inf)"
        return (
            f"{self.method.upper():>3}: K = {self.K:.4g} ± {self.K_std:.2g} rad/(V s), "
            f"tau = {self.tau * 1e3:.4g} ± {self.tau_std * 1e3:.2g} ms{fr}, "
            f"fit = {self.fit_percent:.2f} %"
        )


def _motor_tf(K, tau):
    return control.tf([K], [tau, 1.0, 0.0])
