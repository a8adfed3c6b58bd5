"""The paper's literal call, MATLAB ``pem(data, 'P2')``: a two-pole model with no integrator.

Kept to reproduce Stojčić §4A (ASCII: Stojcic) and show where it goes
(notebooks/02_identification.ipynb), not to be used: the motor of Stojčić eq. 1 has an integrator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize, signal

from jerklab._lazy import lazy_module
from jerklab._validate import as_positive
from jerklab.ident._common import _check_excitation, _pair, fit_percent
from jerklab.ident.oe import tau_grid_start

control = lazy_module("control")  # python-control imports matplotlib: import it on first use


@dataclass
class P2Fit:
    """The paper's literal structure, MATLAB ``pem(data, 'P2')``: K / ((T1 s + 1)(T2 s + 1)).

    ``K`` is in rad/V (a DC gain: the model has no integrator), ``T1 >= T2`` in s. ``at_bound`` is
    True when 1/T1 ran to (nearly) 0 — T1 over 100 times the record — i.e. the data asked for an
    integrator (then T1 = K = inf and ``model`` is the integrator model g/(s(T2 s + 1)) the bound
    reached).
    """

    K: float
    T1: float
    T2: float
    fit_percent: float
    model: control.TransferFunction
    Ts: float
    theta0: float
    y_sim: np.ndarray = field(repr=False)
    at_bound: bool = False
    integrator_gain: float = float("nan")  #: K/T1 (rad/(V s)), comparable to the K of Stojčić eq. 1


def _p2_response(g, lam, T2, Ts, u):
    """Exact ZOH response of g / ((s + lam)(T2 s + 1)) to u (zero initial state).

    States theta' = -lam theta + v, T2 v' = -v + g u; with b = 1/T2 the one-sample transition is
    a1 = exp(-lam Ts), a2 = exp(-b Ts), phi12 = (a1 - a2)/(b - lam),
    gamma2 = g (1 - a2), gamma1 = g b (E(lam) - E(b))/(b - lam), E(c) = (1 - exp(-c Ts))/c.
    """
    b = 1.0 / T2
    if abs(b - lam) * Ts < 1e-5:  # (nearly) a double pole: the matrix exponential
        A = np.array([[-lam, 1.0, 0.0], [0.0, -b, g * b], [0.0, 0.0, 0.0]])
        E = linalg.expm(A * Ts)
        a1, phi12, g1 = E[0, 0], E[0, 1], E[0, 2]
        a2, g2 = E[1, 1], E[1, 2]
    else:

        def integral(c):
            return Ts if c == 0.0 else -math.expm1(-c * Ts) / c

        a1, a2 = math.exp(-lam * Ts), math.exp(-b * Ts)
        phi12 = (a1 - a2) / (b - lam)
        g2 = -g * math.expm1(-b * Ts)
        g1 = g * b * (integral(lam) - integral(b)) / (b - lam)
    num = [0.0, g1, phi12 * g2 - g1 * a2]
    den = [1.0, -(a1 + a2), a1 * a2]
    return signal.lfilter(num, den, u)


def fit_p2(u, theta, Ts) -> P2Fit:
    """Fit the two-pole process model Stojčić §4A names, ``pem(data, 'P2')``, for comparison.

    Output-error least squares of K / ((T1 s + 1)(T2 s + 1)) (exact ZOH simulation) on the angle,
    parametrised as g / ((s + lambda)(T2 s + 1)) with g = K/T1, lambda = 1/T1 >= 0, so that the
    integrator (lambda = 0, T1 = inf) is inside the search space instead of at infinity.
    This is kept to reproduce the paper's call, not to be used: the motor has an integrator, so on
    a step the fit drives lambda to (or next to) 0 — T1 and K run away together with K/T1 -> the K
    of Stojčić eq. 1 — and ``at_bound`` is set. Over the record the two models are
    indistinguishable; beyond it
    the P2 model settles at K u while the motor keeps turning. Use :func:`fit_dc_motor`
    (a pole plus an integrator, MATLAB's 'P1I').

    Parameters
    ----------
    u, theta, Ts
        As :func:`fit_dc_motor`.
    """
    Ts = as_positive("Ts", Ts)
    u, theta = _pair(u, theta, "u", "theta")
    _check_excitation(u, theta, "u", "theta")
    span = u.size * Ts
    _, tau0, _ = tau_grid_start(u, theta, Ts)
    ones = np.ones(u.size)

    def linear_part(q):
        # variable projection: for fixed (lambda, T2) the angle is linear in g and theta0
        h = _p2_response(1.0, q[0], math.exp(q[1]), Ts, u)
        M = np.column_stack([h, ones])
        coef, *_ = np.linalg.lstsq(M, theta, rcond=None)
        return coef, M @ coef

    best = None
    for lam0 in (0.0, 1.0 / span, 10.0 / span):  # integrator, slow, and faster starts
        q0 = np.array([lam0, math.log(tau0)])
        sol = optimize.least_squares(
            lambda q: linear_part(q)[1] - theta,
            q0,
            method="trf",
            bounds=([0.0, math.log(Ts / 50)], [20.0 / Ts, math.log(1e3 * span)]),
            x_scale=[1.0 / span, 1.0],
            xtol=1e-10,
            ftol=1e-12,
            max_nfev=200,
        )
        if best is None or sol.cost < best.cost:
            best = sol
    (g, th0), y_sim = linear_part(best.x)
    lam, T2 = best.x[0], math.exp(best.x[1])
    at_bound = lam * span < 1e-2
    if lam > 0.0:
        T1, K = 1.0 / lam, g / lam
        if T2 > T1:
            T1, T2 = T2, T1
        model = control.tf([K], np.convolve([T1, 1.0], [T2, 1.0]))
    else:
        T1, K = math.inf, math.inf * np.sign(g)
        model = control.tf([g], [T2, 1.0, 0.0])
    return P2Fit(
        float(K),
        float(T1),
        float(T2),
        fit_percent(theta, y_sim),
        model,
        Ts,
        float(th0),
        y_sim,
        bool(at_bound),
        float(g),
    )
