"""Input validation shared by every jerklab module.

Every public function checks its arguments with these helpers so that bad input
(NaN, inf, a limit <= 0, a non-numeric value) raises a ``ValueError`` that names
the parameter, instead of propagating a silent NaN.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = ["as_real", "as_positive", "as_nonnegative", "as_finite_array", "as_int"]


def as_real(name: str, value) -> float:
    """Return ``value`` as a finite float or raise ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        if isinstance(value, np.ndarray) and value.shape == ():
            value = value.item()
            return as_real(name, value)
        raise ValueError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return x


def as_positive(name: str, value) -> float:
    """Return ``value`` as a finite float > 0 or raise ``ValueError`` naming ``name``."""
    x = as_real(name, value)
    if x <= 0.0:
        raise ValueError(f"{name} must be > 0, got {x!r}")
    return x


def as_nonnegative(name: str, value) -> float:
    """Return ``value`` as a finite float >= 0 or raise ``ValueError`` naming ``name``."""
    x = as_real(name, value)
    if x < 0.0:
        raise ValueError(f"{name} must be >= 0, got {x!r}")
    return x


def as_int(name: str, value, minimum: int | None = None) -> int:
    """Return ``value`` as an int (>= ``minimum`` if given) or raise ``ValueError``."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    n = int(value)
    if minimum is not None and n < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {n}")
    return n


def as_finite_array(name: str, value, ndim: int | None = None) -> np.ndarray:
    """Return ``value`` as a float ndarray with only finite entries, else ``ValueError``.

    Text (``"1.0"``, an array of strings) is refused, not parsed: a number read from a file
    must be converted by the caller, where a typo can be reported with its line.
    """
    if isinstance(value, (str, bytes)):
        raise ValueError(f"{name} must be numeric, got the text {value!r}")
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if (
        isinstance(value, (list, tuple))
        and a.size
        and any(isinstance(v, (str, bytes)) for v in value)
    ):
        raise ValueError(f"{name} must be numeric, got text in {value!r:.60}")
    if isinstance(value, np.ndarray) and value.dtype.kind in "USO" and value.dtype.kind != "O":
        raise ValueError(f"{name} must be numeric, got an array of {value.dtype}")
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-dimensional, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise ValueError(f"{name} contains {bad} non-finite value(s) (NaN or inf)")
    return a
