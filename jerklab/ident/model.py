"""The motor model the fits simulate: Stojčić eq. 1 by exact ZOH, and the full model of real
records (ASCII: Stojcic).

:func:`simulate_dc_motor` is Stojčić eq. 1 alone; :func:`simulate_motor` adds Coulomb friction by
the velocity (with sticking), an input offset, a dead zone, a pure delay and an open-drive
(coasting) mode. Both are exact between samples (``jerklab.plant.advance_em``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from jerklab._validate import as_int, as_nonnegative, as_positive, as_real
from jerklab.ident._common import _signal
from jerklab.law import zoh_coefficients
from jerklab.plant import _jit, advance_em


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


def _best_theta0(y, y_model_zero_ic):
    """Initial angle that best aligns a simulation started at 0 with y (least squares)."""
    return float(np.mean(y - y_model_zero_ic))


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


def _shift(u, delay):
    return _drive(u, 0.0, 0.0, delay)
