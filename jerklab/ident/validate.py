"""Validation with MATLAB's semantics: fit %, residual tests, ``compare`` and ``resid``.

:func:`compare` runs a fitted model on a record (simulation or k-step prediction) and returns a
:class:`CompareResult` that carries its data; :func:`resid` and :func:`residual_analysis` return a
:class:`ResidualAnalysis`. Both draw themselves with ``.plot()`` (``jerklab.plots``). The k-step
predictor is that of the ARX form of Stojčić eq. 1 (ASCII: Stojcic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize, stats

from jerklab._validate import as_int, as_positive, as_real
from jerklab._vocab import aliases
from jerklab.ident._common import _pair, _signal, fit_percent
from jerklab.ident.data import IdentData
from jerklab.ident.model import _coast_mask, _coast_step, _drive
from jerklab.ident.motorfit import MotorFit
from jerklab.plant import _jit, advance_em


@dataclass
class ResidualAnalysis:
    """Whiteness and independence tests of residuals (MATLAB's ``resid``).

    ``autocorr[k]`` is the normalised autocorrelation of e at lag k = 0..max_lag;
    ``crosscorr[i]`` the normalised cross-correlation of u(t - lag) and e(t) at
    ``cross_lags[i]`` = -max_lag..max_lag. ``auto_bound`` and ``cross_bound`` are the
    two-sided per-lag confidence bounds at ``confidence`` under the hypothesis "e white and
    independent of u" (what ``resid`` draws). With 25 lags a few excursions are expected by chance,
    so the verdicts are joint tests over all lags: ``white`` is the Ljung-Box portmanteau test
    (Q = N(N+2) sum r_k^2/(N-k) ~ chi2(max_lag)), ``independent`` the test
    zeta = N r^T R_u^+ r ~ chi2(rank R_u) (Ljung §16.6), each passed when its p-value exceeds
    1 - ``confidence``. Checked by simulation on white residuals: the whiteness test holds its level,
    the cross-correlation test is slightly conservative (about 3 % rejections at a nominal 5 %).
    Without an input (``residual_analysis(e)``) there is no independence test: ``crosscorr`` and
    ``independent`` are None and ``cross_bound`` is NaN.
    """

    lags: np.ndarray
    autocorr: np.ndarray
    cross_lags: np.ndarray
    crosscorr: np.ndarray | None
    auto_bound: float
    cross_bound: float
    confidence: float
    white: bool
    independent: bool | None
    auto_pvalue: float = float("nan")
    cross_pvalue: float | None = None

    def plot(self, axes=None, title: str | None = None):
        """The two panels of MATLAB's ``resid``: :func:`jerklab.plots.plot_residuals`."""
        from jerklab.plots import plot_residuals  # drawing is imported when a figure is asked for

        return plot_residuals(self, axes, title)


def _xcorr_norm(x, y, lags):
    """Normalised sample cross-correlation r(l) = sum x(t-l) y(t) / (N sx sy)."""
    x = x - x.mean()
    y = y - y.mean()
    N = x.size
    den = N * x.std() * y.std()
    out = np.empty(len(lags))
    for i, lag in enumerate(lags):
        if lag >= 0:
            out[i] = np.dot(x[: N - lag], y[lag:])
        else:
            out[i] = np.dot(x[-lag:], y[: N + lag])
    return out / den


def residual_analysis(
    residuals, u=None, max_lag: int = 25, confidence: float = 0.99
) -> ResidualAnalysis:
    """Residual autocorrelation and input-residual cross-correlation with confidence bounds.

    Under "e is white", each normalised autocorrelation at lag >= 1 is approximately N(0, 1/N); the
    cross-correlation of e with a coloured input u has variance sum_k r_e(k) r_u(k) / N (Ljung
    §16.6), which this uses over the computed lags. Defaults as MATLAB's ``resid`` (25 lags, 99 %).

    Parameters
    ----------
    residuals : array_like
        Model residuals e(t) = y(t) - yhat(t).
    u : array_like, optional
        The input, same length, for the independence test.
    max_lag : int
        Largest lag (>= 1, < len(residuals)/2).
    confidence : float
        Level of the two-sided bounds, in (0, 1).
    """
    e = _signal("residuals", residuals)
    max_lag = as_int("max_lag", max_lag, minimum=1)
    if 2 * max_lag >= e.size:
        raise ValueError(f"max_lag must be < len(residuals)/2 = {e.size / 2:g}, got {max_lag}")
    confidence = as_real("confidence", confidence)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if np.std(e) == 0.0:
        raise ValueError("residuals are constant: nothing to test")
    N = e.size
    z = stats.norm.ppf(0.5 + confidence / 2)
    lags = np.arange(max_lag + 1)
    ac = _xcorr_norm(e, e, lags)
    auto_bound = z / math.sqrt(N)
    k = lags[1:]
    Q = N * (N + 2) * float(np.sum(ac[1:] ** 2 / (N - k)))
    p_auto = float(stats.chi2.sf(Q, max_lag))
    white = p_auto > 1.0 - confidence
    cl = np.arange(-max_lag, max_lag + 1)
    if u is None:
        return ResidualAnalysis(
            lags, ac, cl, None, auto_bound, float("nan"), confidence, white, None, p_auto, None
        )
    u = _signal("u", u)
    if u.size != N:
        raise ValueError(f"u and residuals must have the same length, got {u.size} and {N}")
    if np.std(u) == 0.0:
        raise ValueError("u is constant: the independence test is undefined")
    cc = _xcorr_norm(u, e, cl)
    ru = _xcorr_norm(u, u, cl)
    re = _xcorr_norm(e, e, cl)
    P = max(float(np.sum(ru * re)), 1.0 / N)
    cross_bound = z * math.sqrt(P / N)
    # joint test: under independence r ~ N(0, R_u / N), R_u the Toeplitz matrix of u's correlation
    ru_pos = _xcorr_norm(u, u, np.arange(cl.size))
    Ru = linalg.toeplitz(ru_pos)
    w, V = np.linalg.eigh(Ru)
    keep = w > 1e-8 * w.max()
    proj = V[:, keep].T @ cc
    zeta = N * float(np.sum(proj**2 / w[keep]))
    p_cross = float(stats.chi2.sf(zeta, int(np.count_nonzero(keep))))
    independent = p_cross > 1.0 - confidence
    return ResidualAnalysis(
        lags, ac, cl, cc, auto_bound, cross_bound, confidence, white, independent, p_auto, p_cross
    )


@dataclass
class Validation:
    """A fitted model run on a (validation) record: simulated angle, fit %, residual tests."""

    y_sim: np.ndarray
    fit_percent: float
    residuals: np.ndarray
    analysis: ResidualAnalysis
    theta0: float
    omega0: float = 0.0


def validate(
    fit: MotorFit,
    u,
    theta,
    Ts=None,
    max_lag: int = 25,
    confidence: float = 0.99,
    initial: str = "estimate",
) -> Validation:
    """Simulate ``fit`` on a record (ideally not the one it was estimated on) and test the residuals.

    Parameters
    ----------
    fit : MotorFit
    u, theta : array_like
        The validation record (V, rad).
    Ts : float, optional
        Checked against ``fit.Ts`` if given.
    max_lag, confidence
        Passed to :func:`residual_analysis`; on a record shorter than 2 ``max_lag`` + 1 samples the
        tests use (n - 1) // 2 lags.
    initial : {"estimate", "rest"}
        "estimate" (default, as ``compare`` with ``InitialCondition='e'``): the initial angle and
        velocity are fitted by linear least squares — the response is linear in both, the free
        response to omega0 being omega0 tau (1 - a^k) — so a record may start while the motor turns
        (e.g. the second half of a PRBS). "rest": omega0 = 0, only the angle is fitted.
    """
    if not isinstance(fit, MotorFit):
        raise ValueError(f"fit must be a MotorFit, got {type(fit).__name__}")
    if initial not in ("estimate", "rest"):
        raise ValueError(f"initial must be 'estimate' or 'rest', got {initial!r}")
    u, theta = _pair(u, theta, "u", "theta")
    if Ts is not None and abs(as_positive("Ts", Ts) - fit.Ts) > 1e-9 * fit.Ts:
        raise ValueError(f"Ts = {Ts:g} s differs from the fit's Ts = {fit.Ts:g} s")
    if fit.is_linear:
        g = fit.simulate(u)
        if initial == "rest":
            M = np.ones((u.size, 1))
        else:
            k = np.arange(u.size)
            M = np.column_stack([np.ones(u.size), -fit.tau * np.expm1(-k * fit.Ts / fit.tau)])
        coef, *_ = np.linalg.lstsq(M, theta - g, rcond=None)
        th0 = float(coef[0])
        w0 = float(coef[1]) if initial == "estimate" else 0.0
        y_sim = g + M @ coef
    else:
        th0, w0 = _initial_state(fit, u, theta, initial)
        y_sim = fit.simulate(u, th0, w0)
    r = theta - y_sim
    max_lag = min(as_int("max_lag", max_lag, minimum=1), (u.size - 1) // 2)
    an = residual_analysis(r, u if np.std(u) > 0 else None, max_lag, confidence)
    return Validation(y_sim, fit_percent(theta, y_sim), r, an, th0, w0)


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
    """Output of :func:`compare`: a record, the model's output on it and the fit %.

    ``time`` (older name ``t``, s), the measured output ``y`` and the model's ``y_hat``, in
    ``unit``: the angle, or with ``output="speed"`` the mean speed over each sample period.
    ``horizon`` is None for simulation (MATLAB ``compare(data, sys)``, an infinite horizon) or
    k for the k-step-ahead prediction (``compare(data, sys, k)``); ``theta0``, ``omega0`` the
    initial state of the simulation; ``label`` names the model in a legend.
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

    def plot(self, ax=None, unit: str | None = None):
        """Measured and model output, fit % in the legend: :func:`jerklab.plots.plot_compare`
        (``unit`` overrides the axis label's unit)."""
        from jerklab.plots import plot_compare_result  # imported when a figure is asked for

        return plot_compare_result(self, ax, unit)


class CompareResults(list):
    """Several :class:`CompareResult` of one record (different models), drawn on one axes."""

    def plot(self, ax=None):
        """The record once and each model's output: :func:`jerklab.plots.plot_compare`."""
        from jerklab.plots import plot_compare  # imported when a figure is asked for

        return plot_compare(*self, ax=ax)


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
    unit = "rad"
    if isinstance(data, IdentData):
        u, y, Ts, unit = data.voltage, data.position, data.Ts, data.output_unit
    elif isinstance(data, (tuple, list)) and len(data) == 2:
        u, y = _pair(data[0], data[1], "u", "y", min_len=3)
        Ts = fit.Ts
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
        unit = unit[:-2] if unit.endswith("*s") else f"{unit}/s"  # y_cc*s -> y_cc, rad -> rad/s
    return CompareResult(t, y, y_hat, fit_percent(y, y_hat), horizon, th0, om0, label, output, unit)


def resid(
    data,
    fit,
    max_lag: int = 25,
    confidence: float = 0.99,
    initial: str = "estimate",
    output: str = "angle",
) -> "ResidualAnalysis":
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
    """Measured angle against each fitted model's output, with fit % in the legend.

    ``CompareResults([compare(data, f, horizon, label=...) for f in fits]).plot(ax)``: the
    comparisons are computed here and drawn by :func:`jerklab.plots.plot_compare`.

    Parameters
    ----------
    data : IdentData
        The record to compare on.
    *fits : MotorFit
        Models to simulate.
    ax : matplotlib Axes, optional
    labels : list of str, optional
        Legend names (default: the method, with K and tau).
    horizon : None or int
        None: simulation; k: k-step-ahead prediction (see :func:`compare`).
    """
    if not isinstance(data, IdentData):
        raise ValueError(f"data must be an IdentData, got {type(data).__name__}")
    if labels is not None and len(labels) != len(fits):
        raise ValueError(f"labels must name each of the {len(fits)} fits, got {len(labels)}")
    results = CompareResults()
    for i, f in enumerate(fits):
        if not isinstance(f, MotorFit):
            raise ValueError(f"fits[{i}] must be a MotorFit, got {type(f).__name__}")
        name = labels[i] if labels else f.method.upper()
        label = f"{name}: K={f.K:.3g}, τ={f.tau * 1e3:.3g} ms"
        results.append(compare(data, f, horizon, label=label))
    return results.plot(ax=ax)


def plot_residuals(analysis, axes=None, title: str | None = None):
    """The two panels of MATLAB's ``resid`` for a :class:`ResidualAnalysis`: ``analysis.plot``."""
    if not isinstance(analysis, ResidualAnalysis):
        raise ValueError(f"analysis must be a ResidualAnalysis, got {type(analysis).__name__}")
    return analysis.plot(axes, title)
