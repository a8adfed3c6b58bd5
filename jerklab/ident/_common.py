"""Input checks shared by the estimators, and the fit percent every one of them reports.

Private to :mod:`jerklab.ident`; :func:`fit_percent` is public through :mod:`jerklab.ident.validate`.
"""

from __future__ import annotations

import numpy as np

from jerklab._validate import as_finite_array

#: fewest samples a record must hold to be fitted (a handful per parameter, plus transients)
MIN_SAMPLES = 10


#: largest |sample| an identification takes: the fits sum squares of the samples over up to
#: 10**7 of them, which must stay finite (1e300 data gave an infinite noise estimate)
MAX_SIGNAL = 1e150


def _signal(name: str, value, min_len: int = MIN_SAMPLES) -> np.ndarray:
    """``value`` as a 1-D float array of at least ``min_len`` finite samples, each of magnitude
    at most ``MAX_SIGNAL`` (``ValueError`` naming ``name`` otherwise)."""
    a = as_finite_array(name, value)
    if a.size and not float(np.max(np.abs(a))) <= MAX_SIGNAL:
        raise ValueError(
            f"{name} reaches |{name}| = {float(np.max(np.abs(a))):.3g}, above "
            f"ident MAX_SIGNAL = {MAX_SIGNAL:g} (its squares would overflow): scale the units"
        )
    if a.ndim != 1:
        a = np.squeeze(a)
        if a.ndim != 1:
            raise ValueError(
                f"{name} must be a 1-D sequence of samples, got shape {np.shape(value)}"
            )
    if a.size < min_len:
        raise ValueError(f"{name} is too short: {a.size} samples, need at least {min_len}")
    return a


def _pair(u, y, u_name: str = "u", y_name: str = "y", min_len: int = MIN_SAMPLES):
    u = _signal(u_name, u, min_len)
    y = _signal(y_name, y, min_len)
    if u.size != y.size:
        raise ValueError(
            f"{u_name} and {y_name} must have the same length, got {u.size} and {y.size}"
        )
    return u, y


def _check_excitation(u: np.ndarray, y: np.ndarray, u_name: str, y_name: str) -> None:
    scale = max(1.0, float(np.max(np.abs(u))))
    if np.ptp(u) <= 1e-12 * scale:
        raise ValueError(
            f"{u_name} is constant ({u[0]:g}): it does not excite the motor; record a step from rest "
            f"(u = 0 first) or a PRBS (see step_input, prbs)"
        )
    yscale = max(1.0, float(np.max(np.abs(y))))
    if np.ptp(y) <= 1e-12 * yscale:
        raise ValueError(
            f"{y_name} is constant ({y[0]:g}): the motor did not move (check the supply, "
            f"the encoder, or a voltage below the friction threshold)"
        )


def fit_percent(y, y_hat) -> float:
    """Normalised-RMSE fit in percent, as MATLAB's ``compare``: 100 (1 - |y - yhat| / |y - mean y|).

    100 is a perfect fit, 0 is no better than the mean, it can be negative.
    """
    y, y_hat = _pair(y, y_hat, "y", "y_hat", min_len=2)
    den = np.linalg.norm(y - y.mean())
    if den == 0.0:
        raise ValueError("y is constant: fit percent is undefined")
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / den))
