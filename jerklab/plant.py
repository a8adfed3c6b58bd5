"""DC-motor plant of Stojčić (2015) §2A, with the real rig's imperfections.

ASCII spelling for grep: Stojcic eqs. 1, 9.

The linear model is Stojčić eq. 1,

    P(s) = Θ(s)/U(s) = K / (s (τ s + 1)),      P_v(s) = Ω(s)/U(s) = K / (τ s + 1),

with the paper's identified motor K = 32.4 rad/(V·s), τ = 0.025 s as defaults.
In state form (states ``[theta, omega]``)::

    theta' = omega
    omega' = (K (u + w - f_c sign(omega)) - omega) / τ

Disturbances are *input referred* (volts), as in Stojčić eq. 9 where W(s) = P(s):
a step load disturbance ``w`` and the Coulomb friction ``f_c`` are voltages added to
(subtracted from) the terminal voltage. A load torque T_L corresponds to
``w = -T_L R_a / k_t``.

Every imperfection is optional and named: supply saturation (``supply_voltage``),
PWM quantization (``pwm_bits``), encoder quantization (``encoder_ppr``, ``decoding``),
Coulomb friction with sticking (``coulomb_friction``), a step load disturbance
(``load_disturbance``) and measurement noise (``noise_std``).

Between samples the plant is integrated exactly: the linear part has a closed-form
ZOH solution and a sign change of the velocity under Coulomb friction is located
analytically (an event), after which the motor either sticks (``|u + w|`` <= f_c) or
moves on in the other direction. No numerical ODE solver is involved.

:class:`FlexibleDCMotor` adds a lightly damped mode (motor + shaft + load inertia);
it shows why jerk matters: a jerk step excites the mode, a smooth jerk does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from jerklab import paper
from jerklab._lazy import lazy_module
from jerklab._validate import (
    as_finite_array,
    as_int,
    as_nonnegative,
    as_positive,
    as_real,
    as_seed,
)
from jerklab.law import encoder_vec, voltage_vec, zoh_coefficients

ct = lazy_module("control")  # python-control imports matplotlib: import it on first use

__all__ = [
    "DCMotor",
    "FlexibleDCMotor",
    "StepDisturbance",
    "advance",
    "advance_scalar",
    "advance_em",
    "quantize_voltage",
    "measure_angle",
]


try:  # numba compiles the scalar kernels (jerklab.sim calls them from compiled code)
    from numba import njit as _njit

    def _jit(f):
        return _njit(cache=True, nogil=True)(f)
except ImportError:  # pragma: no cover - pure-Python fallback

    def _jit(f):
        return f


# ---------------------------------------------------------------------------
# exact inter-sample solution (shared by the plant, the simulator and the rig)
# ---------------------------------------------------------------------------
@_jit
def _lin(theta, omega, w_inf, tau, t, em):
    """Exact solution of theta' = omega, tau omega' = w_inf - omega after time t.

    ``em`` = 1 - exp(-t/tau) (``-expm1(-t/tau)``), passed in so a simulator can
    compute it once per sampling period.
    """
    return theta + w_inf * t + (omega - w_inf) * tau * em, w_inf + (omega - w_inf) * (1.0 - em)


@_jit
def advance_em(theta, omega, v, fc, K, tau, dt, em_dt):
    """:func:`advance_scalar` with ``em_dt = -expm1(-dt/tau)`` precomputed (the hot path)."""
    if fc <= 0.0:
        return _lin(theta, omega, K * v, tau, dt, em_dt)
    if omega == 0.0:
        if abs(v) <= fc:
            return theta, 0.0
        s = 1.0 if v > 0.0 else -1.0
    else:
        s = 1.0 if omega > 0.0 else -1.0
    w_inf = K * (v - s * fc)
    th1, om1 = _lin(theta, omega, w_inf, tau, dt, em_dt)
    if s * om1 > 0.0 or w_inf * s >= 0.0 or omega == 0.0:
        # no sign change of omega within dt (it heads to a speed of its own sign, or
        # decays but does not reach zero)
        return th1, om1
    # omega reaches 0 at t_star <= dt (event), then sticks or moves the other way
    t_star = tau * math.log1p(-omega / w_inf)
    if t_star > dt:
        t_star = dt
    theta, _ = _lin(theta, omega, w_inf, tau, t_star, -math.expm1(-t_star / tau))
    rest = dt - t_star
    if abs(v) <= fc or rest <= 0.0:
        return theta, 0.0
    s = 1.0 if v > 0.0 else -1.0
    return _lin(theta, 0.0, K * (v - s * fc), tau, rest, -math.expm1(-rest / tau))


@_jit
def _advance_scalar(theta, omega, v, fc, K, tau, dt):
    """The compiled kernel of :func:`advance_scalar`, without argument checks (the hot path)."""
    return advance_em(theta, omega, v, fc, K, tau, dt, -math.expm1(-dt / tau))


def advance_scalar(theta, omega, v, fc, K, tau, dt):
    """Advance the rigid motor by ``dt`` under a held net voltage ``v`` (scalar floats).

    Exact solution of ``tau omega' = K (v - fc sign(omega)) - omega``: the linear
    part in closed form, the zero crossing of ``omega`` found analytically (an event),
    and sticking at ``omega = 0`` while ``|v| <= fc`` (static = kinetic friction).
    Written in plain arithmetic so :mod:`jerklab.sim` compiles it with numba.

    The arguments are checked (finite reals; ``fc``, ``dt`` >= 0; ``K``, ``tau`` > 0,
    else a ``ValueError`` naming the argument); the simulators call the unchecked
    compiled kernel.

    Returns
    -------
    (theta, omega) after ``dt``.
    """
    theta, omega, v = as_real("theta", theta), as_real("omega", omega), as_real("v", v)
    fc, dt = as_nonnegative("fc", fc), as_nonnegative("dt", dt)
    K, tau = as_positive("K", K), as_positive("tau", tau)
    return _advance_scalar(theta, omega, v, fc, K, tau, dt)


def _checked_array(name, value, low=None, strict=False):
    """``as_finite_array`` with every entry ``> low`` (``strict``) or ``>= low``."""
    a = as_finite_array(name, value)
    if low is not None and a.size:
        bad = a <= low if strict else a < low
        if np.any(bad):
            raise ValueError(
                f"{name} must be {'>' if strict else '>='} {low:g}, got {a[bad].ravel()[0]!r}"
            )
    return a


def advance(theta, omega, v, fc, K, tau, dt):
    """Vectorized :func:`advance_scalar`: every argument broadcasts (numpy arrays).

    Used by the batch simulation over many perturbed plants. The arguments are checked
    as in :func:`advance_scalar`, entry by entry (a ``ValueError`` naming the argument).
    """
    checked = (
        _checked_array("theta", theta),
        _checked_array("omega", omega),
        _checked_array("v", v),
        _checked_array("fc", fc, 0.0),
        _checked_array("K", K, 0.0, strict=True),
        _checked_array("tau", tau, 0.0, strict=True),
        _checked_array("dt", dt, 0.0),
    )
    try:
        np.broadcast_shapes(*(a.shape for a in checked))
    except ValueError as exc:
        raise ValueError(
            f"theta, omega, v, fc, K, tau, dt must broadcast together: {exc}"
        ) from None
    return _advance(*checked)


def _advance(theta, omega, v, fc, K, tau, dt):
    """The kernel of :func:`advance`, without argument checks (the batch simulator's hot path)."""
    theta, omega, v, fc, K, tau, dt = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (theta, omega, v, fc, K, tau, dt))
    )

    def lin(th, om, winf, t):
        em = -np.expm1(-t / tau)
        return th + winf * t + (om - winf) * tau * em, winf + (om - winf) * (1.0 - em)

    at_rest = omega == 0.0
    s = np.where(at_rest, np.sign(v), np.sign(omega))
    w_inf = K * (v - s * fc)
    stuck0 = at_rest & (np.abs(v) <= fc)
    crossing = (~at_rest) & (w_inf * s < 0.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t_star = np.where(crossing, tau * np.log1p(np.where(crossing, -omega / w_inf, 0.0)), np.inf)
    crossing &= t_star < dt
    t1 = np.where(crossing, t_star, dt)
    th1, om1 = lin(theta, omega, w_inf, t1)
    # second segment after the zero crossing
    s2 = np.sign(v)
    stuck2 = np.abs(v) <= fc
    rest = np.where(crossing, dt - t1, 0.0)
    th2, om2 = lin(th1, np.zeros_like(om1), K * (v - s2 * fc), rest)
    th_out = np.where(crossing & ~stuck2, th2, th1)
    om_out = np.where(crossing, np.where(stuck2, 0.0, om2), om1)
    th_out = np.where(stuck0, theta, th_out)
    om_out = np.where(stuck0, 0.0, om_out)
    return th_out, om_out


def quantize_voltage(u, supply_voltage=None, pwm_bits=None):
    """Supply saturation then PWM quantization of a commanded voltage.

    The H-bridge applies ``±supply_voltage`` with a duty cycle ``d/(2**bits - 1)``,
    ``d`` an integer (10-bit phase-correct PWM on Timer 1: TOP = 1023), the sign set
    by the direction pins; the duty is rounded half away from zero (C ``lround``, as the
    firmware). ``None`` switches the effect off.
    """
    u = as_finite_array("u", u)
    if supply_voltage is None:
        return u
    supply_voltage = as_positive("supply_voltage", supply_voltage)
    if pwm_bits is not None:
        pwm_bits = as_int("pwm_bits", pwm_bits, minimum=1)
        if pwm_bits > 32:
            raise ValueError(f"pwm_bits must be <= 32, got {pwm_bits}")
    return voltage_vec(u, supply_voltage, 0.0 if pwm_bits is None else float(2**pwm_bits - 1))


def measure_angle(theta, counts_per_rad=None):
    """Encoder quantization: the counter holds ``floor(theta * counts_per_rad)``."""
    theta = as_finite_array("theta", theta)
    if counts_per_rad is None:
        return theta
    counts_per_rad = as_positive("counts_per_rad", counts_per_rad)
    return encoder_vec(theta, counts_per_rad)


@dataclass(frozen=True)
class StepDisturbance:
    """Step load disturbance ``w(t) = amplitude · 1(t - time)`` in volts (Stojčić eq. 9).

    Input referred (W(s) = P(s)): a negative amplitude acts like a braking load torque.
    """

    amplitude: float
    time: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "amplitude", as_real("load_disturbance amplitude", self.amplitude))
        object.__setattr__(self, "time", as_real("load_disturbance time", self.time))

    def __call__(self, t):
        t = np.asarray(t, dtype=float)
        out = np.where(t >= self.time, self.amplitude, 0.0)
        return float(out) if out.ndim == 0 else out


def _as_disturbance(value):
    if value is None:
        return None
    if isinstance(value, StepDisturbance):
        return value
    if isinstance(value, (tuple, list)) and len(value) == 2:
        return StepDisturbance(amplitude=value[1], time=value[0])
    if isinstance(value, dict):
        return StepDisturbance(**value)
    try:
        return StepDisturbance(amplitude=value)
    except ValueError:
        raise ValueError(
            "load_disturbance must be None, an amplitude in V, a (time, amplitude) "
            f"pair or a StepDisturbance, got {value!r}"
        ) from None


class _MotorBase:
    """Imperfections shared by the rigid and the flexible motor."""

    def _init_common(
        self, supply_voltage, pwm_bits, encoder_ppr, decoding, load_disturbance, noise_std, seed
    ):
        self.supply_voltage = (
            None if supply_voltage is None else as_positive("supply_voltage", supply_voltage)
        )
        self.pwm_bits = None if pwm_bits is None else as_int("pwm_bits", pwm_bits, minimum=1)
        if self.pwm_bits is not None and self.supply_voltage is None:
            raise ValueError("pwm_bits needs a supply_voltage (the PWM quantizes a fraction of it)")
        self.encoder_ppr = (
            None if encoder_ppr is None else as_int("encoder_ppr", encoder_ppr, minimum=1)
        )
        self.decoding = as_int("decoding", decoding)
        if self.decoding not in (1, 2, 4):
            raise ValueError(f"decoding must be 1, 2 or 4, got {self.decoding}")
        self.load_disturbance = _as_disturbance(load_disturbance)
        self.noise_std = as_nonnegative("noise_std", noise_std)
        self.seed = as_seed("seed", seed)
        self.rng = np.random.default_rng(seed)

    @property
    def counts_per_rad(self):
        """Encoder counts per radian, ``encoder_ppr * decoding / (2π)`` (None: ideal sensor)."""
        if self.encoder_ppr is None:
            return None
        return self.encoder_ppr * self.decoding / (2.0 * math.pi)

    def quantize_voltage(self, u):
        """Supply saturation + PWM quantization → the voltage the motor actually sees."""
        return quantize_voltage(u, self.supply_voltage, self.pwm_bits)

    def measure(self, theta):
        """Encoder quantization (floor of the count) plus Gaussian noise ``noise_std`` (rad)."""
        y = measure_angle(theta, self.counts_per_rad)
        if self.noise_std > 0.0:
            y = y + self.rng.normal(0.0, self.noise_std, size=np.shape(y))
        return y

    def disturbance(self, t):
        """Input-referred load disturbance w(t) in volts (0 without one)."""
        if self.load_disturbance is None:
            return np.zeros_like(np.asarray(t, dtype=float)) if np.ndim(t) else 0.0
        return self.load_disturbance(t)

    def ideal(self):
        """A copy with every imperfection off (the linear model of Stojčić eq. 1)."""
        raise NotImplementedError

    def open_loop(self, u, Ts, x0=None):
        """Open-loop response to an input sequence held for ``Ts`` each (ZOH).

        Each ``u[k]`` passes through :meth:`quantize_voltage` and is held on
        ``[k Ts, (k+1) Ts)``. Returns ``(theta_true, theta_measured)`` sampled at
        ``k Ts`` for ``k = 0 … len(u)``: the first sample is the initial state, so both
        arrays have ``len(u) + 1`` entries (the measurement at ``k Ts`` is what a
        controller would read before choosing ``u[k]``).
        """
        u = as_finite_array("u", u, ndim=1)
        Ts = as_positive("Ts", Ts)
        v = self.quantize_voltage(u)
        x = self._x0(x0)
        theta = np.empty(len(u) + 1)
        theta[0] = x[0]
        for k in range(len(u)):
            x = self.step_state(x, v[k], Ts, t=k * Ts)
            theta[k + 1] = x[0]
        return theta, self.measure(theta)


class DCMotor(_MotorBase):
    """Permanent-magnet DC motor with load, Stojčić eq. 1, plus the rig's imperfections.

    Parameters
    ----------
    K : float
        Static gain, rad/(V·s) (paper: 32.4).
    tau : float
        Mechanical time constant, s (paper: 0.025).
    supply_voltage : float or None
        H-bridge supply: the applied voltage saturates at ±supply_voltage (V).
    pwm_bits : int or None
        PWM resolution (10 in the paper); None for an ideal amplifier.
    encoder_ppr : int or None
        Encoder pulses per revolution (448); None for a perfect angle sensor.
    decoding : {1, 2, 4}
        Edges counted per pulse (1: channel A only, as the paper; 4: quadrature).
    coulomb_friction : float
        Coulomb friction as an equivalent voltage f_c ≥ 0 (V); the motor sticks while
        ``|u + w| <= f_c``. The paper neglects it (models it as disturbance, §2A).
    load_disturbance : None, float, (time, amplitude) or StepDisturbance
        Step load disturbance, input referred in volts (Stojčić eq. 9 with W = P).
    noise_std : float
        Standard deviation of Gaussian measurement noise added to the angle (rad).
    seed : int or None
        Seed of the noise generator.
    offset : float
        Input offset (V): the driver adds it to every command, so the motor sees ``u + offset``
        (a bias of the amplifier or of the PWM zero). Default 0.
    dead_zone : float
        Input dead zone (V) ≥ 0 after the offset: the motor sees
        ``dz(x) = sign(x) max(|x| - dead_zone, 0)`` of ``x = u + offset`` (a driver that needs a
        minimum duty before it switches). Default 0. Offset and dead zone act in
        :meth:`step_state` (and so in :meth:`open_loop` and the virtual rig); the compiled loop of
        ``jerklab.sim`` does not model them.
    """

    def __init__(
        self,
        K=paper.MOTOR_K,
        tau=paper.MOTOR_TAU,
        supply_voltage=paper.SUPPLY_VOLTAGE,
        pwm_bits=paper.PWM_BITS,
        encoder_ppr=paper.ENCODER_PPR,
        decoding=paper.ENCODER_DECODING,
        coulomb_friction=0.0,
        load_disturbance=None,
        noise_std=0.0,
        seed=None,
        offset=0.0,
        dead_zone=0.0,
    ):
        self.K = as_positive("K", K)
        self.tau = as_positive("tau", tau)
        self.coulomb_friction = as_nonnegative("coulomb_friction", coulomb_friction)
        self.offset = as_real("offset", offset)
        self.dead_zone = as_nonnegative("dead_zone", dead_zone)
        self._init_common(
            supply_voltage, pwm_bits, encoder_ppr, decoding, load_disturbance, noise_std, seed
        )

    def __repr__(self):
        return (
            f"DCMotor(K={self.K!r}, tau={self.tau!r}, supply_voltage={self.supply_voltage!r}, "
            f"pwm_bits={self.pwm_bits!r}, encoder_ppr={self.encoder_ppr!r}, "
            f"decoding={self.decoding!r}, coulomb_friction={self.coulomb_friction!r}, "
            f"load_disturbance={self.load_disturbance!r}, noise_std={self.noise_std!r}"
            + (f", offset={self.offset!r}" if self.offset else "")
            + (f", dead_zone={self.dead_zone!r}" if self.dead_zone else "")
            + ")"
        )

    n_states = 2

    def ideal(self):
        """The same K, τ with every imperfection switched off."""
        return DCMotor(self.K, self.tau, supply_voltage=None, pwm_bits=None, encoder_ppr=None)

    def replace(self, **changes):
        """A copy with some constructor arguments changed (e.g. ``m.replace(K=30)``)."""
        kw = dict(
            K=self.K,
            tau=self.tau,
            supply_voltage=self.supply_voltage,
            pwm_bits=self.pwm_bits,
            encoder_ppr=self.encoder_ppr,
            decoding=self.decoding,
            coulomb_friction=self.coulomb_friction,
            load_disturbance=self.load_disturbance,
            noise_std=self.noise_std,
            seed=self.seed,
            offset=self.offset,
            dead_zone=self.dead_zone,
        )
        kw.update(changes)
        return DCMotor(**kw)

    def drive_voltage(self, u):
        """The voltage the motor sees for an applied ``u``: ``dz(u + offset)``.

        ``dz(x) = sign(x) max(|x| - dead_zone, 0)``; the identity with the default offset 0 and
        dead zone 0.
        """
        x = np.asarray(u, dtype=float) + self.offset
        if self.dead_zone:
            x = np.sign(x) * np.maximum(np.abs(x) - self.dead_zone, 0.0)
        return float(x) if x.ndim == 0 else x

    # --- linear models (python-control) ---------------------------------
    def tf(self):
        """``K / (s (τ s + 1))`` from volts to rad (Stojčić eq. 1, P(s))."""
        return ct.tf([self.K], [self.tau, 1.0, 0.0])

    def velocity_tf(self):
        """``K / (τ s + 1)`` from volts to rad/s (Stojčić eq. 1, P_v(s))."""
        return ct.tf([self.K], [self.tau, 1.0])

    def ss(self, outputs="theta"):
        """State space with states ``[theta, omega]``.

        ``outputs="theta"`` (default) gives the angle, ``"omega"`` the velocity,
        ``"both"`` both.
        """
        A = np.array([[0.0, 1.0], [0.0, -1.0 / self.tau]])
        B = np.array([[0.0], [self.K / self.tau]])
        C = {
            "theta": np.array([[1.0, 0.0]]),
            "omega": np.array([[0.0, 1.0]]),
            "both": np.eye(2),
        }.get(outputs)
        if C is None:
            raise ValueError(f"outputs must be 'theta', 'omega' or 'both', got {outputs!r}")
        return ct.ss(A, B, C, np.zeros((C.shape[0], 1)))

    def zoh(self, Ts):
        """Exact ZOH discretization ``x[k+1] = Phi x[k] + Gamma u[k]`` in closed form (Stojčić eq. 1,
        coefficients from :func:`jerklab.law.zoh_coefficients`)."""
        z = zoh_coefficients(self.K, self.tau, Ts)
        Phi = np.array([[1.0, self.tau * z.one_minus_a], [0.0, z.a]])
        Gamma = np.array([[z.b1], [self.K * z.one_minus_a]])
        return Phi, Gamma

    def discrete_tf(self, Ts):
        """ZOH-discretized P(z) as a python-control transfer function (dt = Ts)."""
        Ts = as_positive("Ts", Ts)
        try:
            return ct.c2d(self.tf(), Ts, "zoh")
        except (np.linalg.LinAlgError, ValueError, OverflowError) as exc:
            raise ValueError(
                f"Ts = {Ts!r} s cannot be discretized for tau = {self.tau!r} s: {exc}"
            ) from None

    # --- exact simulation --------------------------------------------------
    def initial_state(self, x0=None):
        """``x0`` checked and copied as the state ``[theta, omega]`` (None: rest at 0)."""
        if x0 is None:
            return np.zeros(2)
        x = as_finite_array("x0", x0, ndim=1)
        if x.shape != (2,):
            raise ValueError(f"x0 must be [theta, omega], got shape {x.shape}")
        return x.copy()

    _x0 = initial_state

    def step_state(self, x, u, dt, t=0.0):
        """Next state ``[theta, omega]`` after ``dt`` with the terminal voltage ``u`` held.

        ``u`` is the voltage the amplifier applies (apply :meth:`quantize_voltage` first to
        model the PWM); the motor sees ``dz(u + offset)`` (:meth:`drive_voltage`). The load
        disturbance is evaluated on ``[t, t + dt)``;
        a step inside the interval splits it. Exact: closed-form ZOH for the linear
        part, analytic zero-crossing event and sticking for Coulomb friction.
        """
        x = as_finite_array("x", x, ndim=1)
        if x.shape != (2,):
            raise ValueError(f"x must be [theta, omega], got shape {x.shape}")
        u = as_real("u", u)
        dt = as_nonnegative("dt", dt)
        t = as_real("t", t)
        th, om = float(x[0]), float(x[1])
        if self.offset or self.dead_zone:
            u = float(self.drive_voltage(u))
        d = self.load_disturbance
        if d is not None and t < d.time < t + dt:
            first = d.time - t
            th, om = _advance_scalar(
                th, om, u + float(d(t)), self.coulomb_friction, self.K, self.tau, first
            )
            th, om = _advance_scalar(
                th, om, u + d.amplitude, self.coulomb_friction, self.K, self.tau, dt - first
            )
        else:
            w = 0.0 if d is None else float(d(t))
            th, om = _advance_scalar(th, om, u + w, self.coulomb_friction, self.K, self.tau, dt)
        return np.array([th, om])


class FlexibleDCMotor(_MotorBase):
    """DC motor driving a load through a compliant shaft: a lightly damped mode.

    Two inertias share the rigid motor's total inertia, so that the rigid-body
    behaviour is exactly Stojčić eq. 1 (same K, τ); the shaft adds a resonance::

        J_m θ_m'' = K u − θ_m' − k (θ_m − θ_l) − c (θ_m' − θ_l')
        J_l θ_l'' =              k (θ_m − θ_l) + c (θ_m' − θ_l')

    in units where the viscous/back-EMF damping is 1 (then J_m + J_l = τ).
    ``J_l/J_m = load_ratio``. The shaft is set by the load's own mode with the motor
    held still: ``mode_frequency`` ω_r = √(k/J_l) (rad/s) and ``mode_damping``
    ζ_r = c/(2 ω_r J_l). For a light load (small ``load_ratio``) the coupled mode sits at
    ω_r with damping ζ_r; a heavier load reacts on the electrically damped motor and
    the coupled mode gets stiffer and better damped (ζ ≈ 0.03 at the default
    ``load_ratio = 0.05``, 0.24 at 1). States ``[theta_m, omega_m, theta_l, omega_l]``;
    the encoder sits on the motor.

    Parameters
    ----------
    K, tau : float
        Rigid-body gain and time constant (Stojčić eq. 1).
    load_ratio : float
        Load to motor inertia ratio J_l/J_m (> 0). Extremes stay legal: 1e-300 is a load of
        no inertia (a decoupled mode), 1e300 a locked motor; a ratio whose inertia underflows
        to 0 raises ``ValueError`` naming ``load_ratio``.
    mode_frequency : float
        Resonance of the load on the shaft with the motor held still, rad/s.
    mode_damping : float
        Damping ratio of the shaft mode (lightly damped: ~0.01–0.05).
    supply_voltage, pwm_bits, encoder_ppr, decoding, load_disturbance, noise_std, seed
        As for :class:`DCMotor`. Coulomb friction is not modelled here.
    """

    n_states = 4
    coulomb_friction = 0.0

    def __init__(
        self,
        K=paper.MOTOR_K,
        tau=paper.MOTOR_TAU,
        load_ratio=0.05,
        mode_frequency=2 * math.pi * 8.0,
        mode_damping=0.02,
        supply_voltage=paper.SUPPLY_VOLTAGE,
        pwm_bits=paper.PWM_BITS,
        encoder_ppr=paper.ENCODER_PPR,
        decoding=paper.ENCODER_DECODING,
        load_disturbance=None,
        noise_std=0.0,
        seed=None,
    ):
        self.K = as_positive("K", K)
        self.tau = as_positive("tau", tau)
        self.load_ratio = as_positive("load_ratio", load_ratio)
        self.mode_frequency = as_positive("mode_frequency", mode_frequency)
        self.mode_damping = as_nonnegative("mode_damping", mode_damping)
        self._init_common(
            supply_voltage, pwm_bits, encoder_ppr, decoding, load_disturbance, noise_std, seed
        )
        self._zoh_cache = {}

    def ideal(self):
        return FlexibleDCMotor(
            self.K,
            self.tau,
            self.load_ratio,
            self.mode_frequency,
            self.mode_damping,
            supply_voltage=None,
            pwm_bits=None,
            encoder_ppr=None,
        )

    def rigid(self):
        """The rigid motor with the same K, τ and imperfections (Stojčić eq. 1)."""
        return DCMotor(
            self.K,
            self.tau,
            self.supply_voltage,
            self.pwm_bits,
            self.encoder_ppr,
            self.decoding,
            0.0,
            self.load_disturbance,
            self.noise_std,
            self.seed,
        )

    def _matrices(self):
        r = self.load_ratio
        Jm = self.tau / (1.0 + r)
        Jl = self.tau * r / (1.0 + r) if r < 1.0 else self.tau / (1.0 + 1.0 / r)  # no cancellation
        if not (Jm > 0.0 and Jl > 0.0):
            raise ValueError(
                f"load_ratio = {r!r}: an inertia underflows to 0 (J_m = {Jm!r}, J_l = {Jl!r}); "
                f"use a ratio between 1e-300 and 1e300"
            )
        k = self.mode_frequency**2 * Jl
        c = 2.0 * self.mode_damping * self.mode_frequency * Jl
        A = np.array(
            [
                [0.0, 1.0, 0.0, 0.0],
                [-k / Jm, -(1.0 + c) / Jm, k / Jm, c / Jm],
                [0.0, 0.0, 0.0, 1.0],
                [k / Jl, c / Jl, -k / Jl, -c / Jl],
            ]
        )
        B = np.array([[0.0], [self.K / Jm], [0.0], [0.0]])
        return A, B

    def ss(self, outputs="motor"):
        """State space; ``outputs`` is ``"motor"`` (θ_m), ``"load"`` (θ_l) or ``"both"``."""
        A, B = self._matrices()
        C = {
            "motor": np.array([[1.0, 0, 0, 0]]),
            "load": np.array([[0, 0, 1.0, 0]]),
            "both": np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]),
        }.get(outputs)
        if C is None:
            raise ValueError(f"outputs must be 'motor', 'load' or 'both', got {outputs!r}")
        return ct.ss(A, B, C, np.zeros((C.shape[0], 1)))

    def tf(self):
        """Volts → motor angle θ_m (what the encoder measures)."""
        return ct.ss2tf(self.ss("motor"))

    def load_tf(self):
        """Volts → load angle θ_l."""
        return ct.ss2tf(self.ss("load"))

    def velocity_tf(self):
        """Volts → motor velocity."""
        return ct.minreal(self.tf() * ct.tf([1.0, 0.0], [1.0]), verbose=False)

    def zoh(self, Ts):
        """Exact ZOH discretization (Phi, Gamma) via the matrix exponential."""
        Ts = as_positive("Ts", Ts)
        if Ts not in self._zoh_cache:
            A, B = self._matrices()
            M = np.zeros((5, 5))
            M[:4, :4] = A * Ts
            M[:4, 4:] = B * Ts
            E = scipy.linalg.expm(M)
            if not np.all(np.isfinite(E)):
                raise ValueError(
                    f"Ts = {Ts!r} s is too long for this model (tau = {self.tau!r} s, "
                    f"load_ratio = {self.load_ratio!r}, mode_frequency = "
                    f"{self.mode_frequency!r} rad/s): the matrix exponential overflows"
                )
            self._zoh_cache[Ts] = (E[:4, :4], E[:4, 4:])
        return self._zoh_cache[Ts]

    def initial_state(self, x0=None):
        """``x0`` checked and copied as the state ``[theta_m, omega_m, theta_l, omega_l]`` (None: rest)."""
        if x0 is None:
            return np.zeros(4)
        x = as_finite_array("x0", x0, ndim=1)
        if x.shape != (4,):
            raise ValueError(
                f"x0 must be [theta_m, omega_m, theta_l, omega_l], got shape {x.shape}"
            )
        return x.copy()

    _x0 = initial_state

    def step_state(self, x, u, dt, t=0.0):
        """Next state after ``dt`` with the voltage ``u`` held (exact ZOH)."""
        x = self._x0(x)
        u = as_real("u", u)
        dt = as_nonnegative("dt", dt)
        t = as_real("t", t)
        d = self.load_disturbance
        if dt == 0.0:
            return x
        if d is not None and t < d.time < t + dt:
            x = self.step_state(x, u, d.time - t, t)
            return self.step_state(x, u, t + dt - d.time, d.time)
        w = 0.0 if d is None else float(d(t))
        Phi, Gamma = self.zoh(dt)
        return Phi @ x + Gamma[:, 0] * (u + w)

    def open_loop(self, u, Ts, x0=None, output="motor"):
        """As :meth:`DCMotor.open_loop`; ``output="load"`` returns the load angle instead."""
        u = as_finite_array("u", u, ndim=1)
        Ts = as_positive("Ts", Ts)
        v = self.quantize_voltage(u)
        x = self._x0(x0)
        X = np.empty((len(u) + 1, 4))
        X[0] = x
        for k in range(len(u)):
            x = self.step_state(x, v[k], Ts, t=k * Ts)
            X[k + 1] = x
        theta = X[:, 2] if output == "load" else X[:, 0]
        if output not in ("motor", "load"):
            raise ValueError(f"output must be 'motor' or 'load', got {output!r}")
        return theta, self.measure(X[:, 0])
