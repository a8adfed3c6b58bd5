"""Parameter covariance of a least-squares fit whose residuals are coloured (Newey & West 1987).

The textbook covariance of a least-squares estimate, s^2 (J^T J)^-1, holds when the residuals
are white. The residuals of a motor record are not: the encoder's quantization error stays
nearly the same for several samples while the motor turns slowly (and for the whole of a rest),
and whatever the model leaves out (the start of a step, a friction transition) leaves a slow
wave. :func:`newey_west` keeps the least-squares estimate and replaces the middle of the
sandwich (J^T J)^-1 (J^T Omega J) (J^T J)^-1 by the Newey-West estimate of the long-run
covariance of the scores g_t = J_t r_t: the Bartlett-weighted sum of their autocovariances up
to a lag chosen from the data (:func:`bartlett_lags`, the plug-in of Andrews 1991 for an AR(1)).
Records that are separate experiments are independent: no lag crosses from one to the next.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import sparse

#: the largest lag the plug-in may choose, as a fraction of the shortest record's length
MAX_LAG_FRACTION = 0.25
#: Jacobians with more entries than this are handled as sparse matrices (the shooting fit's
#: segment states each touch their own samples only); smaller ones are faster dense
SPARSE_ABOVE = 200_000

#: and in samples: each lag costs a pass over the record (the encoder's slow beats, which need
#: more, are simulated instead: :func:`quantization_covariance`)
MAX_LAGS = 50


def _matrix(J):
    """``J`` as a sparse (CSR) matrix when it is large, else as a dense array."""
    if sparse.issparse(J):
        return J.tocsr()
    J = np.asarray(J, dtype=float)
    return sparse.csr_matrix(J) if J.size > SPARSE_ABOVE else J


def _dense(M) -> np.ndarray:
    return M.toarray() if sparse.issparse(M) else np.asarray(M)


def _rows(v, M):
    """Each row of M times the entry of v."""
    return sparse.diags(v) @ M if sparse.issparse(M) else v[:, None] * M


def _colsum_of_product(A, B) -> np.ndarray:
    """sum_t A_t B_t for each column (A and B of one kind, dense or sparse)."""
    return np.ravel(A.multiply(B).sum(axis=0)) if sparse.issparse(A) else np.sum(A * B, axis=0)


def bartlett_lags(scores, groups) -> int:
    """The Newey-West lag for ``scores`` by the AR(1) plug-in of Andrews (1991), §6.

    Each column of the scores is fitted an AR(1) coefficient rho_a within each record (lags do not
    cross records); with sigma_a^2 the variance of its innovation, the Bartlett kernel's optimal
    lag is 1.1447 (alpha n)^(1/3), alpha = sum 4 rho^2 sigma^4 / ((1 - rho)^6 (1 + rho)^2) /
    sum sigma^4 / (1 - rho)^4 (Andrews 1991, §6, unit weights). ``rho`` is held within
    [0, 0.97]. The lag is at most :data:`MAX_LAG_FRACTION` of the shortest record and at most
    :data:`MAX_LAGS`.

    Parameters
    ----------
    scores : ndarray, shape (n, p)
        The scores J_t r_t of the n samples (one column per parameter).
    groups : ndarray of int, shape (n,)
        The record each sample belongs to (equal labels are one contiguous record).

    Returns
    -------
    int
        The lag L >= 0 of :func:`newey_west`.

    References
    ----------
    D. W. K. Andrews, "Heteroskedasticity and autocorrelation consistent covariance matrix
    estimation", Econometrica 59(3), 817-858, 1991, §6.
    """
    G = _matrix(scores)
    n = G.shape[0]
    same = (groups[1:] == groups[:-1]).astype(float)
    now, before = _rows(same, G[1:]), _rows(same, G[:-1])
    num = _colsum_of_product(now, before)
    den = _colsum_of_product(before, before)
    keep = den > 0.0
    if not np.any(keep):
        return 0
    rho = np.clip(num[keep] / den[keep], 0.0, 0.97)
    s2 = _colsum_of_product(G, G)[keep] / n * (1.0 - rho**2)
    top = np.sum(4.0 * rho**2 * s2**2 / ((1.0 - rho) ** 6 * (1.0 + rho) ** 2))
    bottom = np.sum(s2**2 / (1.0 - rho) ** 4)
    alpha = top / bottom if bottom > 0.0 else 0.0
    _, sizes = np.unique(groups, return_counts=True)
    cap = max(min(int(MAX_LAG_FRACTION * int(sizes.min())), MAX_LAGS), 0)
    return int(min(math.ceil(1.1447 * (alpha * n) ** (1.0 / 3.0)), cap))


def newey_west(J, r, groups=None, lags=None):
    """Newey-West (HAC) covariance of the least-squares estimate with Jacobian ``J``, residuals ``r``.

    cov = n/(n - p) (J^T J)^-1 S (J^T J)^-1,  S = sum_{-L <= l <= L} (1 - abs(l)/(L + 1)) Gamma_l,
    Gamma_l = sum_t g_t g_{t-l}^T,  g_t = J_t r_t  (Newey & West 1987),

    the lag products taken only within a record. With L = 0 this is White's heteroskedasticity-
    consistent sandwich; with white residuals of one variance it tends to s^2 (J^T J)^-1.

    What the interval it gives covers: the spread of the estimate over records whose
    residuals have the same (short-memory) correlation as this one, the quantization of the
    encoder and the noise included. What it does not: a bias from a model that misses part of
    the plant (friction not fitted, a wrong delay): that is not a spread over records, and no
    covariance covers it; look at the residuals (:func:`jerklab.ident.residual_analysis`).

    Parameters
    ----------
    J : ndarray, shape (n, p)
        Jacobian of the residuals (or of the model) at the estimate.
    r : ndarray, shape (n,)
        Residuals at the estimate.
    groups : ndarray of int, shape (n,), optional
        The record (experiment) of each sample, contiguous; default one record.
    lags : int, optional
        The Bartlett lag L; default :func:`bartlett_lags` of the scores.

    Returns
    -------
    cov : ndarray, shape (p, p)
        The covariance of the p parameters (pseudo-inverse where J is rank deficient).
    lags : int
        The lag used.

    Raises
    ------
    ValueError
        ``J`` and ``r`` (or ``groups``) of different lengths, or a negative ``lags``.

    References
    ----------
    W. K. Newey and K. D. West, "A simple, positive semi-definite, heteroskedasticity and
    autocorrelation consistent covariance matrix", Econometrica 55(3), 703-708, 1987;
    D. W. K. Andrews, Econometrica 59(3), 1991 (the lag, :func:`bartlett_lags`).
    """
    J = np.asarray(J, dtype=float)
    r = np.asarray(r, dtype=float)
    if J.ndim != 2 or r.ndim != 1 or J.shape[0] != r.size:
        raise ValueError(
            f"J must be (n, p) and r (n,) with the same n, got {J.shape} and {r.shape}"
        )
    n, p = J.shape
    groups = np.zeros(n, int) if groups is None else np.asarray(groups)
    if groups.shape != (n,):
        raise ValueError(f"groups must have one label per residual ({n}), got {groups.shape}")
    # the shooting fit's Jacobian is sparse (each segment's state touches its own samples only):
    # every product below costs O(n (nonzeros per row)^2), not O(n p^2)
    Js = _matrix(J)
    G = _rows(r, Js)
    if lags is None:
        lags = bartlett_lags(G, groups)
    elif not (isinstance(lags, (int, np.integer)) and lags >= 0):
        raise ValueError(f"lags must be an integer >= 0, got {lags!r}")
    S = _dense(G.T @ G)
    for lag in range(1, int(lags) + 1):
        same = (groups[lag:] == groups[:-lag]).astype(float)
        Gl = _dense(_rows(same, G[lag:]).T @ G[:-lag])
        S += (1.0 - lag / (lags + 1.0)) * (Gl + Gl.T)
    bread = np.linalg.pinv(_dense(Js.T @ Js))
    cov = bread @ S @ bread * (n / max(n - p, 1))
    return 0.5 * (cov + cov.T), int(lags)


#: how far (in counts) an angle sample may lie off the encoder's grid (:func:`grid_step`), on top
#: of the rounding of a float
GRID_TOL = 1e-6


def grid_step(theta, groups=None):
    """The encoder step q of an angle record that lies on a grid of whole counts, else None.

    q is the greatest common divisor of the changes between samples; the record is on the grid
    when every sample, less the first of its record, is a whole multiple of q (within
    :data:`GRID_TOL` counts and the rounding of a float). A record with noise added after the
    encoder (or a continuous sensor) is not.

    Parameters
    ----------
    theta : ndarray, shape (n,)
        The measured angle (rad), records concatenated.
    groups : ndarray of int, shape (n,), optional
        The record of each sample; default one record.

    Returns
    -------
    float or None
        The step q (rad per count), or None when the samples are not whole counts.
    """
    theta = np.asarray(theta, dtype=float)
    groups = np.zeros(theta.size, int) if groups is None else np.asarray(groups)
    rel = np.empty_like(theta)
    for g in np.unique(groups):
        sel = groups == g
        rel[sel] = theta[sel] - theta[sel][0]
    steps = np.abs(np.diff(theta))[groups[1:] == groups[:-1]]
    scale = max(float(np.max(np.abs(rel))), 1e-300)
    steps = np.unique(steps[steps > 1e-9 * scale])
    if steps.size == 0:
        return None
    # the greatest common divisor of the steps (Euclid on floats): a fast motor moves many counts
    # a sample and may never move by one
    tol = 1e-9 * float(steps[-1])
    q = float(steps[0])
    for d in steps[1:]:
        a, b = float(d), q
        while b > tol:
            a, b = b, math.fmod(a, b)
            if b > a - tol:
                b = 0.0
        q = a
        if q < 1e-6 * scale:
            return None
    k = rel / q
    kmax = float(np.max(np.abs(k)))
    if np.max(np.abs(k - np.round(k))) > GRID_TOL + 64 * np.finfo(float).eps * kmax:
        return None
    return q


def quantization_covariance(J, y_model, groups, step, noise_std=0.0, replicates=100, seed=0):
    """Covariance of a least-squares estimate whose residual is the encoder's quantization.

    An encoder reports ``step * floor(theta / step + phi + n_t)``: the phase phi of the shaft
    against the code wheel is arbitrary (uniform over one count, one per record) and n_t a
    count jitter. The quantization error follows the motion: it is nearly constant while the
    motor creeps and beats slowly when the motor turns an almost whole number of counts per
    sample, so it is far from white, and its lag structure outlasts any short HAC window.
    This draws ``replicates`` records of that error about the fitted angle ``y_model``
    (phases and jitter from a generator seeded by ``seed``: the result is deterministic) and
    takes the covariance of the linearized estimate (J^T J)^-1 J^T e over them: a parametric
    bootstrap of the encoder, linearized (Efron & Tibshirani 1993, §6.5).

    Parameters
    ----------
    J : ndarray, shape (n, p)
        Jacobian of the model at the estimate.
    y_model : ndarray, shape (n,)
        The fitted (simulated) angle (rad).
    groups : ndarray of int, shape (n,)
        The record of each sample: one phase per record.
    step : float
        The encoder step (rad per count), :func:`grid_step`.
    noise_std : float
        Standard deviation (rad) of a jitter added before the encoder's floor.
    replicates : int
        Number of simulated quantization errors.
    seed : int
        Seed of their generator.

    Returns
    -------
    ndarray, shape (p, p)

    References
    ----------
    B. Efron and R. J. Tibshirani, *An Introduction to the Bootstrap*, Chapman & Hall, 1993,
    §6.5 (the parametric bootstrap); B. Widrow and I. Kollár, *Quantization Noise*, Cambridge
    University Press, 2008, ch. 4-5 (the quantization error with and without dither).
    """
    J = np.asarray(J, dtype=float)
    y = np.asarray(y_model, dtype=float)
    n = y.size
    labels, inverse = np.unique(groups, return_inverse=True)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 1.0, (labels.size, replicates))[inverse]
    jitter = rng.normal(0.0, noise_std / step, (n, replicates)) if noise_std > 0 else 0.0
    E = step * np.floor(y[:, None] / step + phase + jitter) - y[:, None]
    Js = _matrix(J)
    D = np.linalg.pinv(_dense(Js.T @ Js)) @ _dense(Js.T @ E)
    return np.cov(D)
