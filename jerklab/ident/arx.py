"""ARX of any order (MATLAB's ``arx``), the velocity ARX fit of Stojčić eq. 1
(ASCII: Stojcic), and its bias.

The ZOH discretization of Stojčić eq. 1 gives, for v(k) = (theta(k) - theta(k-1)) / Ts, the
*exact* difference equation

    v(k) = a v(k-1) + b1 u(k-1) + b2 u(k-2),    a = exp(-Ts/tau),

with K = (b1 + b2) / (1 - a) and tau = -Ts / ln a. It is exact on noise-free data, but the
regressor v(k-1) carries the measurement noise, so under output noise or encoder quantization the
estimate is biased (:func:`arx_asymptotic_bias` predicts by how much).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jerklab._lazy import lazy_module
from jerklab._validate import as_int, as_nonnegative, as_positive, as_real
from jerklab.ident._common import _pair, _signal
from jerklab.ident.model import dc_motor_zoh_coefficients, simulate_dc_motor

control = lazy_module("control")  # python-control imports matplotlib: import it on first use


@dataclass
class ARXResult:
    """Least-squares ARX estimate ``A(q) y(t) = B(q) u(t - nk) + e(t)`` (MATLAB's ``arx``).

    ``A = [1, a1, ..., a_na]`` and ``B = [b0, ..., b_{nb-1}]`` are polynomials in the delay q^-1:
    y(t) + a1 y(t-1) + ... = b0 u(t-nk) + b1 u(t-nk-1) + ...
    """

    A: np.ndarray
    B: np.ndarray
    na: int
    nb: int
    nk: int
    params: np.ndarray  #: [a1..a_na, b0..b_{nb-1}]
    cov: np.ndarray  #: parameter covariance lambda (Phi^T Phi)^-1
    noise_variance: float  #: lambda = SSR / (N - n_params)
    residuals: np.ndarray  #: equation errors e(t) for t = n0 .. N-1
    n_used: int  #: number of equations (rows of Phi)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of ``params`` (valid when e(t) is white)."""
        return np.sqrt(np.diag(self.cov))

    def tf(self, Ts) -> control.TransferFunction:
        """The model B(z^-1) z^-nk / A(z^-1) as a discrete python-control transfer function."""
        Ts = as_positive("Ts", Ts)
        n = max(self.na, self.nk + self.nb - 1)
        num = np.zeros(n + 1)
        num[self.nk : self.nk + self.nb] = self.B
        den = np.zeros(n + 1)
        den[: self.na + 1] = self.A
        return control.tf(num, den, Ts)

    def predict(self, y, u) -> np.ndarray:
        """One-step-ahead prediction yhat(t) for t = n0 .. N-1."""
        u, y = _pair(u, y, "u", "y", min_len=2)
        Phi, _, _ = _arx_regressors(y, u, self.na, self.nb, self.nk)
        return Phi @ self.params


def _arx_regressors(y, u, na, nb, nk):
    n0 = max(na, nk + nb - 1)
    N = y.size
    rows = N - n0
    Phi = np.empty((rows, na + nb))
    for i in range(1, na + 1):
        Phi[:, i - 1] = -y[n0 - i : N - i]
    for j in range(nb):
        d = nk + j
        Phi[:, na + j] = u[n0 - d : N - d]
    return Phi, y[n0:], n0


def arx(y, u, na, nb, nk=1) -> ARXResult:
    """Least-squares ARX fit of any order, with the parameter covariance.

    Model (MATLAB's ``arx(data, [na nb nk])``)::

        y(t) + a1 y(t-1) + ... + a_na y(t-na) = b0 u(t-nk) + ... + b_{nb-1} u(t-nk-nb+1) + e(t)

    Parameters
    ----------
    y, u : array_like
        Output and input, same length.
    na : int
        Number of poles (>= 0).
    nb : int
        Number of B coefficients (>= 0; na + nb >= 1).
    nk : int
        Input delay in samples (>= 0).

    Returns
    -------
    ARXResult
        ``cov = lambda (Phi^T Phi)^-1`` with ``lambda = SSR/(N_eq - n_params)``: the textbook
        covariance, correct when e(t) is white (Ljung, *System Identification*, §7.3, eq. 9.19).

    Raises
    ------
    ValueError
        On non-finite or mismatched data, too few samples for the orders, or a rank-deficient
        regression (the input does not excite the model: e.g. a constant input with nb >= 2).
    """
    na = as_int("na", na, minimum=0)
    nb = as_int("nb", nb, minimum=0)
    nk = as_int("nk", nk, minimum=0)
    if na + nb == 0:
        raise ValueError("na + nb must be >= 1 (nothing to estimate)")
    npar = na + nb
    u, y = _pair(u, y, "u", "y", min_len=2)
    n0 = max(na, nk + nb - 1)
    if y.size - n0 < npar + 1:
        raise ValueError(
            f"y is too short: {y.size} samples for na={na}, nb={nb}, nk={nk} "
            f"(need at least {n0 + npar + 1})"
        )
    Phi, target, n0 = _arx_regressors(y, u, na, nb, nk)
    # column scaling keeps the QR well conditioned when u and y differ by orders of magnitude
    scale = np.sqrt(np.sum(Phi**2, axis=0))
    if np.any(scale == 0.0):
        bad = int(np.flatnonzero(scale == 0.0)[0])
        which = "y" if bad < na else "u"
        raise ValueError(f"{which} is zero over the fitted window: the regression is singular")
    Q, R = np.linalg.qr(Phi / scale)
    sv = np.linalg.svd(R, compute_uv=False)
    if sv[-1] <= 1e-10 * sv[0]:
        raise ValueError(
            f"u does not excite an ARX({na},{nb},{nk}) model: the regression is rank deficient "
            f"(condition {sv[0] / max(sv[-1], 1e-300):.3g}); use a richer input (step from rest, PRBS) "
            f"or lower orders"
        )
    theta_s = np.linalg.solve(R, Q.T @ target)
    params = theta_s / scale
    res = target - Phi @ params
    dof = max(target.size - npar, 1)
    lam = float(res @ res) / dof
    Rinv = np.linalg.solve(R, np.eye(npar))
    cov = lam * (Rinv @ Rinv.T) / np.outer(scale, scale)
    A = np.concatenate([[1.0], params[:na]])
    B = params[na:].copy()
    return ARXResult(A, B, na, nb, nk, params, cov, lam, res, int(target.size))


def velocity_arx(u, theta, Ts):
    """The ARX fit of Stojčić eq. 1 on the differenced angle (``fit_dc_motor(method="arx")``).

    Least squares (:func:`arx` with na = 1, nb = 2, nk = 0) on
    v(k) = a v(k-1) + b1 u(k-1) + b2 u(k-2), v(k) = (theta(k) - theta(k-1)) / Ts, exact for the
    ZOH model; then K = (b1 + b2)/(1 - a), tau = -Ts/ln a, their covariance by the delta method.

    Parameters
    ----------
    u, theta : ndarray
        Checked input (V) and angle (rad) of one record.
    Ts : float
        Sample period (s).

    Returns
    -------
    (K, tau, cov, result) : (float, float, ndarray, ARXResult)
        ``cov`` is the 2x2 covariance of (K, tau), ``result`` the ARX fit of the velocity.

    Raises
    ------
    ValueError
        When the pole a falls outside (0, 1) (no motor gives it: too noisy or too coarse data).
    """
    v = np.diff(theta) / Ts
    res = arx(v, u[:-1], na=1, nb=2, nk=0)
    a = -res.A[1]
    b1, b2 = res.B
    if not 0.0 < a < 1.0:
        raise ValueError(
            f"theta: the ARX velocity fit found a pole a = {a:.4g} outside (0, 1), which no motor "
            f"K/(s(tau s+1)) gives; the data are too noisy or too coarse for ARX (try method='pem')"
        )
    bs = b1 + b2
    K = bs / (1.0 - a)
    tau = -Ts / math.log(a)
    # delta method on (a, b1, b2) -> (K, tau)
    J = np.array(
        [
            [bs / (1.0 - a) ** 2, 1.0 / (1.0 - a), 1.0 / (1.0 - a)],
            [Ts / (a * math.log(a) ** 2), 0.0, 0.0],
        ]
    )
    cov = J @ res.cov @ J.T
    return K, tau, cov, res


def arx_asymptotic_bias(u, K, tau, Ts, noise_std):
    """Predicted large-sample (K, tau) of the ARX velocity fit under white output noise.

    With theta_m = theta + e, e white with variance s^2, the differenced angle carries noise
    n(k) = (e(k) - e(k-1))/Ts with r_n(0) = 2 s^2/Ts^2, r_n(1) = -s^2/Ts^2, and the equation error
    n(k) - a n(k-1) is correlated with the regressor v(k-1). Least squares converges to

        p_hat = p + (Phi0^T Phi0 + N Sigma)^-1 N c,   c = [a r_n(0) - r_n(1), 0, 0],
        Sigma = diag(r_n(0), 0, 0),

    (Ljung §8.3, the "errors-in-variables" bias of equation-error methods). Here Phi0 is the
    noise-free regression built from the exact ZOH simulation of ``u``. Encoder quantization with
    step q acts, for a moving motor, like uniform noise of standard deviation q/sqrt(12).

    Returns
    -------
    (K_arx, tau_arx) : tuple of float
        What ``fit_dc_motor(..., method="arx")`` converges to on long records of this input.
    """
    K = as_real("K", K)
    tau = as_positive("tau", tau)
    Ts = as_positive("Ts", Ts)
    s = as_nonnegative("noise_std", noise_std)
    u = _signal("u", u)
    a, b1, b2 = dc_motor_zoh_coefficients(K, tau, Ts)
    theta = simulate_dc_motor(K, tau, Ts, u)
    v = np.diff(theta) / Ts
    # regression v(k) = -A1 v(k-1) + B0 u(k) + B1 u(k-1) in the indexing used by velocity_arx
    Phi, target, _ = _arx_regressors(v, u[:-1], 1, 2, 0)
    N = target.size
    r0 = 2.0 * s**2 / Ts**2
    r1 = -(s**2) / Ts**2
    Sigma = np.zeros((3, 3))
    Sigma[0, 0] = r0  # noise variance in the regressor -v(k-1)
    # E[phi_1 * eq_err] with phi_1 = -(v0(k-1) + n(k-1)), eq_err = n(k) - a n(k-1)
    c = np.array([-(r1 - a * r0), 0.0, 0.0])
    p_true = np.array([-a, b1 / Ts, b2 / Ts])
    p_lim = p_true + np.linalg.solve(Phi.T @ Phi + N * Sigma, N * c)
    a_l = -p_lim[0]
    if not 0.0 < a_l < 1.0:
        return float("nan"), float("nan")
    return float((p_lim[1] + p_lim[2]) / (1.0 - a_l)), float(-Ts / math.log(a_l))
