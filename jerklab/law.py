"""The control law in one place: PID with clamp and anti-windup, PWM quantizer, encoder, ZOH.

Stojčić (ASCII: Stojcic) 2015, §3–§4: the discrete PID of Stojčić eqs. 17, 18 with
the feedforward of Stojčić eq. 16, run at ``Ts`` on encoder readings and applied through a
PWM H-bridge; the motor of Stojčić eq. 1 sampled with a zero-order hold. In ASCII, for grep:
Stojcic eqs. 1, 16–18.

Every Python user of the law calls these functions: :class:`jerklab.controller.DigitalController`
(one sample at a time), the compiled kernels of :mod:`jerklab.sim` (one run, and many plants
at once), the numpy batch engine (:func:`pid_step_vec`) and the virtual rig
(:mod:`jerklab.rig.virtual`). The C++ firmware (``firmware/jerklab_rig/src/jl_control.cpp``) is the
intended second implementation; golden vectors pin the two together.

Forms
-----
* scalar, compiled with numba when it is installed (``HAVE_NUMBA``), plain Python otherwise:
  :func:`pid_step`, :func:`amplifier`, :func:`pwm_duty`, :func:`encoder`,
  :func:`encoder_counts`. The same functions as plain Python are ``pid_step.py_func`` etc.
  when compiled (``SCALAR`` maps each name to its Python form).
* vector (numpy, element-wise over plants): :func:`pid_step_vec`, :func:`amplifier_vec`,
  :func:`encoder_vec`.
* :func:`zoh_coefficients`: the one home of the exact ZOH coefficients of Stojčić eq. 1.

The rules
---------
PID (Stojčić eqs. 17, 18, feedforward Stojčić eq. 16)::

    p(k) = kpd e(k)
    i(k) = i(k-1) + kid e(k)
    d(k) = γ d(k-1) + kdd (e(k) - e(k-1))          (γ = 0: Stojčić eq. 17)
    u    = ff + p + i + d

Clamp and anti-windup (not in the paper): if ``u > limit`` the output is saturated; if the
error also points further into that limit (``e > 0``), the integrator keeps ``i(k-1)``
(conditional integration) and ``u`` is recomputed without the new increment. Mirror image for
``u < -limit`` and ``e < 0``. The output is then clamped to ``[-limit, limit]``. An error
pointing out of the saturation integrates normally (it pulls the output back).

PWM (the firmware's ``lround``): the duty is ``lround(u / supply · levels)``, rounded half away
from zero, clamped to ``±levels`` (or a lower ``±top``); the sign is the direction pin; the
motor sees ``duty / levels · supply``.

Encoder: the counter holds ``floor(θ · counts_per_rad)`` (floor, not truncation toward zero:
-0.2 counts reads -1); a ``1e-9`` count guards against ``θ`` computed a rounding error below
an exact count. The controller sees ``counts / counts_per_rad``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jerklab._validate import as_positive, as_real

__all__ = [
    "HAVE_NUMBA",
    "pid_step",
    "pid_step_vec",
    "amplifier",
    "amplifier_vec",
    "voltage_vec",
    "pwm_duty",
    "encoder",
    "encoder_counts",
    "encoder_vec",
    "zoh_coefficients",
    "ZOH",
    "SCALAR",
    "ENCODER_EPS",
    "CTL_FIELDS",
    "pack",
]

try:
    from numba import njit as _njit

    HAVE_NUMBA = True

    def _jit(f):
        return _njit(cache=True, nogil=True)(f)
except ImportError:  # pragma: no cover - pure-Python fallback
    HAVE_NUMBA = False

    def _jit(f):
        return f


#: counts added before the encoder's floor (guards an angle a rounding error below a count)
ENCODER_EPS = 1e-9


# ---------------------------------------------------------------------------
# scalar forms (compiled when numba is there)
# ---------------------------------------------------------------------------
@_jit
def pid_step(e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, limit, anti_windup):
    """One sample of the PID with output clamp and conditional integration.

    Stojčić eq. 17 (``p``, ``i``, ``d`` parts, with an optional derivative filter ``gamma``),
    Stojčić eq. 18 (their sum) plus the feedforward ``ff`` of Stojčić eq. 16.

    Parameters
    ----------
    e, e_prev : float
        Error now and at the previous sample.
    i_prev, d_prev : float
        Integrator and derivative states after the previous sample.
    ff : float
        Feedforward (V).
    kpd, kid, kdd, gamma : float
        Discrete gains and derivative-filter pole (γ = 0: the paper's backward derivative).
    limit : float
        Output clamp (V), > 0; ``inf`` for none.
    anti_windup : bool
        Conditional integration while clamped.

    Returns
    -------
    (u, p, i, d, saturated)
        Output after the clamp, the three parts and the new integrator, and whether the
        unclamped output exceeded the limit.
    """
    p = kpd * e
    i_new = i_prev + kid * e
    d = gamma * d_prev + kdd * (e - e_prev)
    u = ff + p + i_new + d
    sat = False
    if u > limit:
        sat = True
        if anti_windup and e > 0.0:
            u -= i_new - i_prev
            i_new = i_prev
    elif u < -limit:
        sat = True
        if anti_windup and e < 0.0:
            u -= i_new - i_prev
            i_new = i_prev
    if u > limit:
        u = limit
    elif u < -limit:
        u = -limit
    return u, p, i_new, d, sat


@_jit
def pwm_duty(u, supply, levels, top):
    """Signed PWM duty for a commanded voltage: ``lround(u / supply · levels)`` clamped to ``±top``.

    Rounded half away from zero (C ``lround``, as the firmware); returned as a float holding
    an integer. ``top`` (≤ ``levels``) is the duty of the firmware's voltage limit.
    """
    q = u / supply * levels
    if q >= 0.0:
        q = np.floor(q + 0.5)
    else:
        q = -np.floor(-q + 0.5)
    if q > top:
        q = top
    elif q < -top:
        q = -top
    return q


@_jit
def amplifier(u, supply, levels):
    """Supply clamp then PWM quantization → (voltage the motor sees, clamped).

    ``supply`` ≤ 0 switches the amplifier off (ideal: ``u`` passes); ``levels`` ≤ 0 keeps the
    clamp but not the quantization. See :func:`pwm_duty` for the rounding.
    """
    if supply <= 0.0:
        return u, False
    clamped = False
    v = u
    if v > supply:
        v = supply
        clamped = True
    elif v < -supply:
        v = -supply
        clamped = True
    if levels > 0.0:
        q = v / supply * levels
        if q >= 0.0:
            q = np.floor(q + 0.5)
        else:
            q = -np.floor(-q + 0.5)
        v = q / levels * supply
    return v, clamped


@_jit
def encoder_counts(theta, counts_per_rad):
    """Counter reading ``floor(θ · counts_per_rad)`` (a float holding an integer)."""
    return np.floor(theta * counts_per_rad + ENCODER_EPS)


@_jit
def encoder(theta, counts_per_rad):
    """The angle the controller reads: ``floor(θ · cpr) / cpr`` (``cpr`` ≤ 0: ideal sensor)."""
    if counts_per_rad > 0.0:
        return np.floor(theta * counts_per_rad + ENCODER_EPS) / counts_per_rad
    return theta


def _py(f):
    return getattr(f, "py_func", f)


#: the plain-Python scalar forms (the same source, not compiled)
SCALAR = {
    "pid_step": _py(pid_step),
    "pwm_duty": _py(pwm_duty),
    "amplifier": _py(amplifier),
    "encoder_counts": _py(encoder_counts),
    "encoder": _py(encoder),
}


# ---------------------------------------------------------------------------
# vector forms (numpy, element-wise)
# ---------------------------------------------------------------------------
def pid_step_vec(
    e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, limit, anti_windup, want_saturated=True
):
    """:func:`pid_step` over arrays (many plants at once); the same rule, element-wise.

    Returns ``(u, p, i, d, saturated)`` as arrays (``anti_windup`` is one bool for all;
    ``saturated`` is None when ``want_saturated`` is False, which saves a pass).
    """
    p = kpd * e
    i_new = i_prev + kid * e
    d = gamma * d_prev + kdd * (e - e_prev)
    u = ff + p + i_new + d
    hi = u > limit
    lo = u < -limit
    if anti_windup:
        freeze = (hi & (e > 0.0)) | (lo & (e < 0.0))
        u = np.where(freeze, u - (i_new - i_prev), u)
        i_new = np.where(freeze, i_prev, i_new)
    u = np.clip(u, -limit, limit)
    return u, p, i_new, d, (hi | lo) if want_saturated else None


def amplifier_vec(u, supply, levels):
    """:func:`amplifier` over an array → (voltages, clamped)."""
    u = np.asarray(u, dtype=float)
    if supply <= 0.0:
        return u.copy(), np.zeros(u.shape, dtype=bool)
    return voltage_vec(u, supply, levels), (u > supply) | (u < -supply)


def voltage_vec(u, supply, levels):
    """The voltage part of :func:`amplifier_vec` alone (no clamp flags): what the motor sees."""
    u = np.asarray(u, dtype=float)
    if supply <= 0.0:
        return u.copy()
    v = np.clip(u, -supply, supply)
    if levels > 0.0:
        q = v / supply * levels
        v = np.sign(q) * np.floor(np.abs(q) + 0.5) / levels * supply
    return v


def encoder_vec(theta, counts_per_rad):
    """:func:`encoder` over an array."""
    theta = np.asarray(theta, dtype=float)
    if counts_per_rad > 0.0:
        return np.floor(theta * counts_per_rad + ENCODER_EPS) / counts_per_rad
    return theta.copy()


# ---------------------------------------------------------------------------
# the parameters of one controller, packed for the compiled kernels
# ---------------------------------------------------------------------------
#: order of the packed controller parameters (``DigitalController.law_params()``)
CTL_FIELDS = (
    "kpd",
    "kid",
    "kdd",
    "gamma",
    "limit",
    "anti_windup",
    "ff_on",
    "ff_K",
    "ff_tau",
    "velocity",
    "error_scale",
    "bumpless",
    "Ts",
)
(
    C_KPD,
    C_KID,
    C_KDD,
    C_GAMMA,
    C_LIMIT,
    C_AW,
    C_FF_ON,
    C_FF_K,
    C_FF_TAU,
    C_VELOCITY,
    C_SCALE,
    C_BUMPLESS,
    C_TS,
) = range(len(CTL_FIELDS))


def pack(
    kpd,
    kid,
    kdd,
    gamma,
    limit,
    anti_windup,
    ff_on,
    ff_K,
    ff_tau,
    velocity,
    error_scale,
    bumpless,
    Ts,
):
    """The controller's parameters as one float array in the order of :data:`CTL_FIELDS`.

    Flags are stored as 1.0/0.0; ``limit`` may be ``inf`` (no clamp).
    """
    return np.array(
        [
            kpd,
            kid,
            kdd,
            gamma,
            limit,
            float(bool(anti_windup)),
            float(bool(ff_on)),
            ff_K,
            ff_tau,
            float(bool(velocity)),
            error_scale,
            float(bool(bumpless)),
            Ts,
        ],
        dtype=float,
    )


# ---------------------------------------------------------------------------
# the exact ZOH of Stojčić eq. 1
# ---------------------------------------------------------------------------
class ZOH(NamedTuple):
    """ZOH coefficients of P(s) = K/(s(τs+1)) (Stojčić eq. 1) at ``Ts``.

    ``P(z) = (b1 z + b0)/((z − 1)(z − a))``, ``a = e^{−Ts/τ}``, ``one_minus_a = 1 − a``
    (computed as ``−expm1(−Ts/τ)``, exact for small Ts/τ), ``b1 = K (Ts − τ(1 − a))``,
    ``b0 = K (τ(1 − a) − a Ts)``. State form over ``[θ, ω]``:
    ``Φ = [[1, τ(1 − a)], [0, a]]``, ``Γ = [[b1], [K (1 − a)]]``.
    """

    a: float
    one_minus_a: float
    b1: float
    b0: float


def zoh_coefficients(K, tau, Ts) -> ZOH:
    """The exact ZOH discretization of Stojčić eq. 1 (the one place it is computed).

    Parameters
    ----------
    K : float
        Gain, rad/(V·s) (any finite real: a fit may try a negative one).
    tau, Ts : float
        Time constant and sampling time (s), > 0.
    """
    K = as_real("K", K)
    tau = as_positive("tau", tau)
    Ts = as_positive("Ts", Ts)
    a = math.exp(-Ts / tau)
    em = -math.expm1(-Ts / tau)
    return ZOH(a, em, K * (Ts - tau * em), K * (tau * em - Ts * a))
