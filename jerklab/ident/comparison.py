"""A fitted model against a record, as MATLAB's ``compare`` and ``resid``.

:func:`compare` simulates a :class:`~jerklab.ident.model.MotorFit` of Stojčić eq. 1 (ASCII:
Stojcic) on a record from its estimated initial state, or predicts it k steps ahead, and returns
a :class:`CompareResult` that carries the measured and the model output; :func:`resid` tests the
residuals. The figures are drawn by ``jerklab.plots`` from these results (``CompareResult.plot``);
:func:`plot_compare` keeps the call form of earlier versions (a record and several fits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jerklab._validate import as_int
from jerklab._vocab import aliases
from jerklab.ident._checks import _pair, _signal
from jerklab.ident.data import IdentData
from jerklab.ident.model import (
    MotorFit,
    _coast_mask,
    _coast_step,
    _drive,
    _initial_speed,
    _initial_state,
)
from jerklab.ident.validation import ResidualAnalysis, fit_percent, residual_analysis
from jerklab.plant import _jit, advance_em

__all__ = ["CompareResult", "compare", "resid", "plot_compare"]


@_jit
def _predict_kernel(v, coast, y, fc, K, tau, rc, Ts, k, out):
    """k-step-ahead prediction: at t - k restart from the state the two measured angles
    y(t-k-1), y(t-k) imply (the angle from y, the velocity from the exact one-sample relation),
    then simulate k samples. Where ``coast`` the drive is open (``_coast_step``, rc = 1/tau_coast)."""
    em = -math.expm1(-Ts / tau)
    emc = -math.expm1(-Ts * rc)
    for t in range(k + 1, y.size):
        s = t - k
        d = y[s] - y[s - 1]
        if coast[s - 1]:
            # open drive: d = om_prev T - (K fc/tau) sgn T^2/2 (rc = 0), or the linear relation
            sg = 1.0 if d > 0.0 else (-1.0 if d < 0.0 else 0.0)
            dec = K * fc / tau
            if rc > 0.0:
                tc = 1.0 / rc
                w_inf = -dec * tc * sg
                om_prev = w_inf + (d - w_inf * Ts) / (tc * emc)
                om = w_inf + (om_prev - w_inf) * (1.0 - emc)
            else:
                om_prev = d / Ts + 0.5 * sg * dec * Ts
                om = om_prev - sg * dec * Ts
            if sg == 0.0 or om * sg < 0.0:
                om = 0.0
        else:
            vv = v[s - 1]
            if fc > 0.0:
                if d > 0.0:
                    vv = vv - fc
                elif d < 0.0:
                    vv = vv + fc
                else:
                    vv = 0.0
            c = tau * em
            om_prev = (d - K * (Ts - c) * vv) / c
            om = (1.0 - em) * om_prev + K * em * vv
            if fc > 0.0 and d == 0.0:
                om = 0.0
        th = y[s]
        for j in range(s, t):
            if coast[j]:
                th, om = _coast_step(th, om, fc, K, tau, rc, Ts, emc)
            else:
                th, om = advance_em(th, om, v[j], fc, K, tau, Ts, em)
        out[t] = th
    return out


@aliases(t="time")
@dataclass
class CompareResult:
    """Output of :func:`compare`: the measured and the model's output on a record, and the fit %.

    ``horizon`` is None for simulation (MATLAB ``compare(data, sys)``, an infinite horizon) or
    k for the k-step-ahead prediction (``compare(data, sys, k)``).

    Attributes
    ----------
    time : ndarray
        Sample instants (s; older name ``t``); for ``output="speed"`` the midpoints of the periods.
    y, y_hat : ndarray
        Measured and model output, in ``unit``.
    fit_percent : float
        100 (1 - ||y - y_hat|| / ||y - mean y||).
    horizon : int or None
        The prediction horizon (samples), None for simulation.
    theta0, omega0 : float
        The initial angle (rad) and velocity (rad/s) of the simulation.
    label : str
        The model's name in a legend.
    output : {"angle", "speed"}
        What ``y`` is.
    unit : str
        Its unit: the record's ``output_unit`` (rad), per second for the speed.
    """

    time: np.ndarray
    y: np.ndarray
    y_hat: np.ndarray
    fit_percent: float
    horizon: int | None
    theta0: float
    omega0: float
    label: str = ""
    output: str = "angle"
    unit: str = "rad"

    def plot(self, ax=None, unit: str | None = None, measured: bool = True):
        """Measured and model output, fit % in the legend: :func:`jerklab.plots.plot_compare`.

        ``unit`` overrides the unit of the axis label (default: :attr:`unit`); ``measured=False``
        adds only the model's line (to draw several models on one axes)."""
        from jerklab.plots import plot_compare as draw  # the result hands itself to the plots

        return draw(self, ax=ax, unit=unit, measured=measured)


def compare(
    data, fit, horizon=None, initial: str = "estimate", label: str = "", output: str = "angle"
) -> CompareResult:
    """Model output against a record and the fit %, as MATLAB's ``compare``.

    fit % = 100 (1 - ||y - yhat|| / ||y - mean(y)||) over every sample of the record.

    Parameters
    ----------
    data : IdentData or (u, y) pair
        The record (ideally not the one ``fit`` was estimated on).
    fit : MotorFit
    horizon : None or int
        None (or ``math.inf``): simulation from the estimated initial state, MATLAB's default
        infinite horizon. k >= 1: the k-step-ahead prediction yhat(t | t - k): at t - k the model is
        restarted from the state the measured angles y(t-k-1), y(t-k) imply and run k samples;
        for the linear model this is exactly the k-step predictor of the ARX form of Stojčić eq. 1,
        (1 - q^-1)(1 - a q^-1) theta = (b1 q^-1 + b2 q^-2) u + e (Ljung §3.2), i.e. MATLAB's
        ``compare(data, arx_model, k)``. The first k + 1 samples take the simulation.
    initial : {"estimate", "rest"}
        Initial state of the simulation: fitted (MATLAB's ``InitialCondition='e'``) or at rest.
    label : str
        Name of the model in the plot's legend.
    output : {"angle", "speed"}
        "angle" (default): the record's y. "speed": the mean speed over each sample period,
        diff(y)/Ts, against the model's (the angle simulation differenced; n - 1 samples), so
        a record of an integrating plant is judged on what it shows, not on its integral (whose
        fit % is always high). Only for simulation (``horizon`` None).

    Returns
    -------
    CompareResult
    """
    if not isinstance(fit, MotorFit):
        raise ValueError(f"fit must be a MotorFit, got {type(fit).__name__}")
    if initial not in ("estimate", "rest"):
        raise ValueError(f"initial must be 'estimate' or 'rest', got {initial!r}")
    if not (fit.tau > 0 and math.isfinite(fit.K)):
        raise ValueError(
            f"fit has tau = {fit.tau:.4g} s, K = {fit.K:.4g}: no motor to simulate "
            f"(see fit.warnings: {'; '.join(fit.warnings) or 'none'})"
        )
    if isinstance(data, IdentData):
        u, y, Ts, unit = data.voltage, data.position, data.Ts, data.output_unit
    elif isinstance(data, (tuple, list)) and len(data) == 2:
        u, y = _pair(data[0], data[1], "u", "y", min_len=3)
        Ts, unit = fit.Ts, "rad"
    else:
        raise ValueError(f"data must be an IdentData or a (u, y) pair, got {type(data).__name__}")
    if abs(Ts - fit.Ts) > 1e-9 * fit.Ts:
        raise ValueError(f"data.Ts = {Ts:g} s differs from the fit's Ts = {fit.Ts:g} s")
    if horizon is not None and horizon != math.inf:
        horizon = as_int("horizon", horizon, minimum=1)
    else:
        horizon = None
    if output not in ("angle", "speed"):
        raise ValueError(f"output must be 'angle' or 'speed', got {output!r}")
    if output == "speed" and horizon is not None:
        raise ValueError("horizon: output='speed' compares the simulation only (horizon=None)")
    if output == "speed" and initial == "estimate":
        th0, om0 = _initial_speed(fit, u, y)
    else:
        th0, om0 = _initial_state(fit, u, y, initial)
    y_hat = fit.simulate(u, th0, om0)
    if horizon is not None and y.size > horizon + 1:
        v = _drive(u, fit.offset, fit.dead_zone, fit.delay)
        cm = _coast_mask(u, fit.delay) if fit.tau_coast else np.zeros(u.size, dtype=np.bool_)
        rc = 1.0 / fit.tau_coast if fit.tau_coast else 0.0
        pred = _predict_kernel(
            np.ascontiguousarray(v),
            cm,
            np.ascontiguousarray(y),
            float(fit.friction),
            float(fit.K),
            float(fit.tau),
            rc,
            float(fit.Ts),
            int(horizon),
            y_hat.copy(),
        )
        y_hat = pred
    t = np.arange(y.size) * Ts
    if output == "speed":
        y, y_hat, t = np.diff(y) / Ts, np.diff(y_hat) / Ts, t[:-1] + 0.5 * Ts
        unit = unit[:-2] if unit.endswith("*s") else f"{unit}/s"  # the integral's unit, per s
    return CompareResult(t, y, y_hat, fit_percent(y, y_hat), horizon, th0, om0, label, output, unit)


def resid(
    data,
    fit,
    max_lag: int = 25,
    confidence: float = 0.99,
    initial: str = "estimate",
    output: str = "angle",
) -> ResidualAnalysis:
    """Residual tests of a model on a record, as MATLAB's ``resid``.

    The residuals are the output errors y - yhat of the simulation (the prediction errors of an
    output-error model, which is what the fits of this module are), from the estimated initial
    state. Returns :func:`residual_analysis` of them with the input: autocorrelation over lags
    0..``max_lag``, cross-correlation with u over -``max_lag``..``max_lag``, ``confidence`` bands
    (99 % by default), the whiteness and independence tests. ``result.plot()`` draws the two panels.
    ``output="speed"``: the residuals of the mean speed over each period (see :func:`compare`).
    """
    c = compare(data, fit, None, initial, output=output)
    u = data.voltage if isinstance(data, IdentData) else _signal("u", data[0])
    u = u[: c.y.size]
    e = c.y - c.y_hat
    max_lag = min(as_int("max_lag", max_lag, minimum=1), (e.size - 1) // 2)
    return residual_analysis(e, u if np.std(u) > 0 else None, max_lag, confidence)


def plot_compare(data, *fits, ax=None, labels=None, horizon=None):
    """A record against each fitted model, fit % in the legend (the call form of earlier versions).

    ``compare(data, fit, horizon)`` for each fit, drawn on one axes by
    :func:`jerklab.plots.plot_compare` (through ``CompareResult.plot``).

    Parameters
    ----------
    data : IdentData
        The record to compare on.
    *fits : MotorFit
        Models to simulate.
    ax : matplotlib Axes, optional
    labels : list of str, optional
        Their names in the legend (default: the method, "PEM", "ARX", ...).
    horizon : None or int
        None: simulation; k: k-step-ahead prediction (see :func:`compare`).

    Returns
    -------
    matplotlib.axes.Axes
    """
    if not isinstance(data, IdentData):
        raise ValueError(f"data must be an IdentData, got {type(data).__name__}")
    if labels is not None and len(labels) != len(fits):
        raise ValueError(f"labels must name each of the {len(fits)} fits, got {len(labels)}")
    for i, f in enumerate(fits):
        name = labels[i] if labels else f.method.upper()
        label = f"{name}: K={f.K:.3g}, τ={f.tau * 1e3:.3g} ms"
        ax = compare(data, f, horizon, label=label).plot(ax=ax, measured=i == 0)
    return ax
