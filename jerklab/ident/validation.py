"""Validation of a fitted motor model: fit %, residual tests, a fresh record (MATLAB semantics).

:func:`fit_percent` is the NRMSE fit of MATLAB's ``compare``; :func:`residual_analysis` the
whiteness and independence tests of MATLAB's ``resid`` (Ljung, *System Identification*, §16.6);
:func:`validate` runs a :class:`~jerklab.ident.model.MotorFit` of Stojčić eq. 1 (ASCII: Stojcic)
on a record it was not estimated on and tests what is left. The figures are drawn by
``jerklab.plots`` from the results (``ResidualAnalysis.plot``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg, stats

from jerklab._validate import as_int, as_positive, as_real
from jerklab.ident._checks import _pair, _signal
from jerklab.ident.model import MotorFit, _initial_state

__all__ = [
    "fit_percent",
    "ResidualAnalysis",
    "residual_analysis",
    "Validation",
    "validate",
    "plot_residuals",
]


def fit_percent(y, y_hat) -> float:
    """Normalised-RMSE fit in percent, as MATLAB's ``compare``: 100 (1 - |y - yhat| / |y - mean y|).

    100 is a perfect fit, 0 is no better than the mean, it can be negative.
    """
    y, y_hat = _pair(y, y_hat, "y", "y_hat", min_len=2)
    den = np.linalg.norm(y - y.mean())
    if den == 0.0:
        raise ValueError("y is constant: fit percent is undefined")
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / den))


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
        """The two panels of MATLAB's ``resid``: :func:`jerklab.plots.plot_residuals` of this."""
        from jerklab.plots import plot_residuals as draw  # the result hands itself to the plots

        return draw(self, axes, title)


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


def plot_residuals(analysis, axes=None, title: str | None = None):
    """Draw a :class:`ResidualAnalysis` (the call form of earlier versions of ``analysis.plot``).

    Parameters
    ----------
    analysis : ResidualAnalysis
        From :func:`residual_analysis`, :func:`validate` (``.analysis``) or ``resid``.
    axes : sequence of matplotlib Axes, optional
        One or two axes (two when the analysis has an input).
    title : str, optional

    Returns
    -------
    The axes, from ``jerklab.plots.plot_residuals``.
    """
    if not isinstance(analysis, ResidualAnalysis):
        raise ValueError(f"analysis must be a ResidualAnalysis, got {type(analysis).__name__}")
    return analysis.plot(axes, title)
