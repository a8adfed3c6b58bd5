"""The motor model of identification and its exact ZOH simulation, and the fitted model.

Stojčić eq. 1 (ASCII: Stojcic), P(s) = K / (s (tau s + 1)) (volts -> rad), sampled with a
zero-order hold: :func:`dc_motor_zoh_coefficients`, :func:`simulate_dc_motor`. Real records need
more: :func:`simulate_motor` adds Coulomb friction against the velocity (with sticking), an input
offset, a dead zone, a pure delay and an open drive at u = 0 (coasting), solved exactly between
samples by ``jerklab.plant.advance_em``. :class:`MotorFit` is what every estimator of
:mod:`jerklab.ident` returns: the parameters, their uncertainty, and the model simulated on the
estimation record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal, stats

from jerklab._lazy import lazy_module
from jerklab._validate import as_int, as_nonnegative, as_positive, as_real
from jerklab.ident._checks import _signal
from jerklab.law import zoh_coefficients
from jerklab.plant import DCMotor, _jit, advance_em

control = lazy_module("control")  # python-control imports matplotlib: import it on first use

__all__ = ["dc_motor_zoh_coefficients", "simulate_dc_motor", "simulate_motor", "MotorFit"]


# ----------------------------------------------------------------------------------------------
# Stojčić eq. 1 and its exact ZOH simulation
# ----------------------------------------------------------------------------------------------
def dc_motor_zoh_coefficients(K, tau, Ts):
    """Exact ZOH discretization of Stojčić eq. 1, P(s) = K/(s(tau s + 1)).

    Returns ``(a, b1, b2)`` with a = exp(-Ts/tau) and

        theta(z)/u(z) = (b1 z^-1 + b2 z^-2) / ((1 - z^-1)(1 - a z^-1)),
        b1 = K (Ts - tau (1 - a)),     b2 = K (tau (1 - a) - a Ts),

    so the differenced angle obeys v(k) = a v(k-1) + (b1 u(k-1) + b2 u(k-2)) / Ts with
    v(k) = (theta(k) - theta(k-1)) / Ts, and b1 + b2 = K Ts (1 - a).
    """
    z = zoh_coefficients(K, tau, Ts)  # the one home: jerklab.law
    return z.a, z.b1, z.b0


def _unit_response(tau, Ts, u, omega0=0.0):
    """theta(k) of K=1, theta0=0 under ZOH input u (plus the free response to omega0 scaled by K=1)."""
    one_minus_a = -math.expm1(-Ts / tau)
    a = 1.0 - one_minus_a
    c = tau * one_minus_a
    # omega(k+1) = a omega(k) + (1-a) u(k)
    omega = signal.lfilter([0.0, one_minus_a], [1.0, -a], u)
    if omega0:
        omega = omega + omega0 * a ** np.arange(u.size)
    inc = c * omega + (Ts - c) * u
    theta = np.empty(u.size)
    theta[0] = 0.0
    np.cumsum(inc[:-1], out=theta[1:])
    return theta


def simulate_dc_motor(K, tau, Ts, u, theta0=0.0, omega0=0.0) -> np.ndarray:
    """Exact ZOH simulation of Stojčić eq. 1 (volts in, angle out), sample by sample.

    States [theta, omega] advance over one sample with u held (the exact solution)::

        omega(k+1) = a omega(k) + K (1 - a) u(k),                    a = exp(-Ts/tau)
        theta(k+1) = theta(k) + tau (1 - a) omega(k) + K (Ts - tau (1 - a)) u(k)

    This is the model the output-error fit simulates; it is ideal (no quantization, friction or
    noise: those belong to ``jerklab.plant.DCMotor``).

    Parameters
    ----------
    K : float
        Gain, rad/(V s).
    tau : float
        Mechanical time constant, s (> 0).
    Ts : float
        Sample period, s (> 0).
    u : array_like
        Input voltage samples (V), held over each period.
    theta0, omega0 : float
        Initial angle (rad) and angular velocity (rad/s).

    Returns
    -------
    ndarray
        theta(k), k = 0 .. len(u) - 1 (rad).
    """
    K = as_real("K", K)
    tau = as_positive("tau", tau)
    Ts = as_positive("Ts", Ts)
    u = _signal("u", u, min_len=1)
    theta0 = as_real("theta0", theta0)
    omega0 = as_real("omega0", omega0)
    w0 = omega0 / K if K != 0.0 else 0.0
    th = K * _unit_response(tau, Ts, u, w0) + theta0
    if K == 0.0 and omega0:
        th = th + _unit_response(tau, Ts, np.zeros_like(u), omega0)
    return th


# ----------------------------------------------------------------------------------------------
# the full motor model: Coulomb friction by the velocity, input offset, dead zone, delay
# ----------------------------------------------------------------------------------------------
def _drive(u, offset=0.0, dead_zone=0.0, delay=0):
    """The voltage the motor sees: ``dz(u(k - delay) + offset)``; before the record, u(0) is held."""
    if delay:
        u = (
            np.concatenate([np.full(delay, u[0]), u[:-delay]])
            if delay < u.size
            else np.full(u.size, u[0])
        )
    x = u + offset
    if dead_zone:
        x = np.sign(x) * np.maximum(np.abs(x) - dead_zone, 0.0)
    return x


@_jit
def _coast_step(th, om, fc, K, tau, rc, dt, emc):
    """One period with the drive open: omega' = -rc omega - (K fc / tau) sign(omega), sticking at 0.

    ``rc`` = 1/tau_coast >= 0; ``emc`` = 1 - exp(-rc dt). rc > 0 is plant.advance_em with no voltage,
    time constant 1/rc and gain K/(tau rc) (the same Coulomb torque); rc = 0 is the pure Coulomb
    run-down at the constant deceleration K fc / tau, solved exactly."""
    if rc > 0.0:
        return advance_em(th, om, 0.0, fc, K / (tau * rc), 1.0 / rc, dt, emc)
    dec = K * fc / tau
    if om == 0.0:
        return th, 0.0
    s = 1.0 if om > 0.0 else -1.0
    if dec > 0.0 and abs(om) <= dec * dt:
        t_star = abs(om) / dec
        return th + 0.5 * om * t_star, 0.0
    return th + om * dt - 0.5 * s * dec * dt * dt, om - s * dec * dt


@_jit
def _sim_kernel(v, coast, fc, K, tau, rc, Ts, starts, th0, om0, out):
    """Exact ZOH simulation with Coulomb friction (plant.advance_em), restarted at each segment start.

    Where ``coast[k]`` the drive is open (:func:`_coast_step`, ``rc`` = 1/tau_coast): no voltage and
    no back-EMF braking, so the motor runs down on its mechanical friction alone."""
    em = -math.expm1(-Ts / tau)
    emc = -math.expm1(-Ts * rc)
    j = 0
    nseg = starts.size
    th = 0.0
    om = 0.0
    for k in range(v.size):
        if j < nseg and k == starts[j]:
            th = th0[j]
            om = om0[j]
            j += 1
        out[k] = th
        if coast[k]:
            th, om = _coast_step(th, om, fc, K, tau, rc, Ts, emc)
        else:
            th, om = advance_em(th, om, v[k], fc, K, tau, Ts, em)
    return out


def _simulate_segments(v, fc, K, tau, Ts, starts, th0, om0, coast=None, coast_rate=0.0):
    out = np.empty(v.size)
    if coast is None:
        coast, coast_rate = np.zeros(v.size, dtype=np.bool_), 0.0
    return _sim_kernel(
        np.ascontiguousarray(v, dtype=float),
        np.ascontiguousarray(coast, dtype=np.bool_),
        float(fc),
        float(K),
        float(tau),
        float(coast_rate),
        float(Ts),
        np.asarray(starts, dtype=np.int64),
        np.asarray(th0, dtype=float),
        np.asarray(om0, dtype=float),
        out,
    )


def _coast_mask(u, delay=0):
    """Samples at which the drive is open: the (delayed) *commanded* voltage is exactly 0."""
    return _drive(u, 0.0, 0.0, delay) == 0.0


def simulate_motor(
    K,
    tau,
    Ts,
    u,
    theta0=0.0,
    omega0=0.0,
    friction=0.0,
    offset=0.0,
    dead_zone=0.0,
    delay=0,
    tau_coast=None,
) -> np.ndarray:
    """Exact ZOH simulation of Stojčić eq. 1 with friction by velocity, offset, dead zone and delay.

    The motor obeys

        tau omega' = K (v(t) - friction sign(omega)) - omega,     theta' = omega,
        v(t) = dz(u(k - delay) + offset) on [k Ts, (k+1) Ts),  dz(x) = sign(x) max(|x| - dead_zone, 0),

    and sticks at omega = 0 while |v| <= friction (static = kinetic Coulomb friction). Between
    samples it is solved exactly (``jerklab.plant.advance_em``: the linear ZOH solution, the zero
    crossing of omega found analytically). With every extra term 0 it equals
    :func:`simulate_dc_motor`. Before the record, ``u[0]`` is held (for the delay).

    With ``tau_coast`` the drive is *open* wherever the commanded u(k - delay) is exactly 0 (a
    switch or a bridge that floats its outputs, not one that shorts the motor): no current flows,
    so there is neither a voltage nor the back-EMF braking that makes up most of 1/tau. For a motor
    with inertia J, viscous friction b, Coulomb torque T_c, torque constant k_t, back-EMF constant
    k_e and armature resistance R (inductance neglected, Stojčić eq. 1),

        driven:  J omega' = k_t (u - k_e omega)/R - b omega - T_c sign(omega)
                 -> tau = J/(b + k_t k_e/R), K = (k_t/R) tau/J, friction = T_c R/k_t;
        open:    J omega' = -b omega - T_c sign(omega)
                 -> omega' = -omega/tau_coast - (K friction/tau) sign(omega),  tau_coast = J/b,

    so the coasting motor runs down with the mechanical time constant ``tau_coast`` (>= tau) and
    the *same* Coulomb deceleration K friction / tau, and sticks when it reaches 0 (the DC motor
    model of Stojčić eq. 1 with the electrical circuit opened; see e.g. Franklin, Powell &
    Emami-Naeini, *Feedback Control of Dynamic Systems*, §2.3).

    Parameters
    ----------
    K, tau, Ts : float
        Gain rad/(V s), time constant s, sample period s.
    u : array_like
        Commanded voltage samples (V).
    theta0, omega0 : float
        Initial angle (rad) and velocity (rad/s).
    friction, offset, dead_zone : float
        Coulomb friction voltage (V, >= 0), input offset (V), dead zone (V, >= 0).
    delay : int
        Input delay in whole samples (>= 0).
    tau_coast : float, optional
        Mechanical time constant (s, > 0) while the drive is open (u = 0); ``math.inf``: no
        viscous drag, the open motor runs down at the constant Coulomb deceleration
        K friction / tau alone. None (default): the drive always holds u (u = 0 is a short
        across the motor, Stojčić eq. 1).

    Returns
    -------
    ndarray
        theta(k), k = 0 .. len(u) - 1 (rad), sampled before u[k] acts.
    """
    K = as_real("K", K)
    tau = as_positive("tau", tau)
    Ts = as_positive("Ts", Ts)
    u = _signal("u", u, min_len=1)
    theta0 = as_real("theta0", theta0)
    omega0 = as_real("omega0", omega0)
    friction = as_nonnegative("friction", friction)
    offset = as_real("offset", offset)
    dead_zone = as_nonnegative("dead_zone", dead_zone)
    delay = as_int("delay", delay, minimum=0)
    v = _drive(u, offset, dead_zone, delay)
    if tau_coast is None:
        return _simulate_segments(v, friction, K, tau, Ts, [0], [theta0], [omega0])
    if not (isinstance(tau_coast, (int, float, np.floating, np.integer)) and tau_coast == math.inf):
        tau_coast = as_positive("tau_coast", tau_coast)
    return _simulate_segments(
        v, friction, K, tau, Ts, [0], [theta0], [omega0], _coast_mask(u, delay), 1.0 / tau_coast
    )


# ----------------------------------------------------------------------------------------------
# the fitted model
# ----------------------------------------------------------------------------------------------
@dataclass
class MotorFit:
    """K and tau of P(s) = K/(s(tau s + 1)) (Stojčić eq. 1) with their uncertainty.

    Attributes
    ----------
    K, tau : float
        Gain rad/(V s) and time constant s.
    K_std, tau_std : float
        One-sigma standard errors (from the Jacobian for PEM, from the regression covariance for
        ARX and the inverse-dynamics fits).
    fit_percent : float
        Simulation fit (NRMSE %, as MATLAB ``compare``) of the angle on the estimation data.
    model : control.TransferFunction
        K / (tau s^2 + s), volts -> rad.
    method : str
        The estimator: "pem", "arx", "idim" or "idim-iv" (see ``fit_dc_motor``).
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
    arx_result: object = field(default=None, repr=False)  #: the velocity ARXResult (``arx``)
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


def _initial_state(fit, u, y, initial):
    """Initial (theta0, omega0) of ``fit`` that best matches ``y`` (least squares, as compare's 'e')."""
    if initial == "rest":
        g = fit.simulate(u)
        return float(np.mean(y - g)), 0.0
    if fit.is_linear:
        g = fit.simulate(u)
        k = np.arange(u.size)
        M = np.column_stack([np.ones(u.size), -fit.tau * np.expm1(-k * fit.Ts / fit.tau)])
        coef, *_ = np.linalg.lstsq(M, y - g, rcond=None)
        return float(coef[0]), float(coef[1])
    w0 = (y[min(2, y.size - 1)] - y[0]) / (min(2, y.size - 1) * fit.Ts)

    def r(x):
        return fit.simulate(u, x[0], x[1]) - y

    best = None
    for start in (w0, 0.0):
        sol = optimize.least_squares(
            r, [y[0], start], method="lm", x_scale=[1.0, max(abs(w0), 1.0)]
        )
        if best is None or sol.cost < best.cost:
            best = sol
    return float(best.x[0]), float(best.x[1])


def _initial_speed(fit, u, y):
    """Initial (theta0, omega0) for a speed comparison: omega0 minimises the speed error over the
    record (the angle offset does not enter the speed; a fit of the *angle* would pick omega0 to
    cancel the drift of the integrated error, far from the measured initial speed)."""
    w = np.diff(y) / fit.Ts

    def r(x):
        return np.diff(fit.simulate(u, 0.0, x[0])) / fit.Ts - w

    best = None
    for start in (w[0], 0.0):
        sol = optimize.least_squares(r, [start], method="lm", x_scale=[max(abs(w[0]), 1.0)])
        if best is None or sol.cost < best.cost:
            best = sol
    om0 = float(best.x[0])
    return float(np.mean(y - fit.simulate(u, 0.0, om0))), om0
