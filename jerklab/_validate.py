"""Input validation shared by every jerklab module.

Every public function checks its arguments with these helpers so that bad input
(NaN, inf, a limit <= 0, a non-numeric value) raises a ``ValueError`` that names
the parameter, instead of propagating a silent NaN.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = [
    "as_real",
    "as_positive",
    "as_nonnegative",
    "as_finite_array",
    "as_int",
    "BadInput",
    "BadIndex",
    "as_instance",
    "as_having",
    "as_path",
    "as_index",
    "as_seed",
    "at_most",
    "as_choice",
    "at_least",
]


class BadInput(TypeError, ValueError):
    """A value of the wrong type or shape: both a ``TypeError`` and a ``ValueError``.

    Raised by :func:`as_instance`, :func:`as_having` and :func:`as_path`; code that catches
    ``ValueError`` for every bad argument (the rule of this module) still catches it.
    """


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


class BadIndex(IndexError, ValueError):
    """An index out of range (:func:`as_index`): both an ``IndexError`` and a ``ValueError``."""


def _describe(value) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def as_instance(name: str, value, types, expected: str | None = None):
    """Return ``value`` if it is an instance of ``types``, else raise :class:`BadInput`.

    ``expected`` says what was expected in words (default: the class names), e.g.
    ``"a jerklab.piezo.ScanCycle"``; the message names ``name`` and what was given.
    """
    if isinstance(value, types):
        return value
    if expected is None:
        tt = types if isinstance(types, tuple) else (types,)
        expected = " or ".join(f"a {t.__module__}.{t.__qualname__}" for t in tt)
    raise BadInput(f"{name} must be {expected}, got {_describe(value)}")


def as_having(name: str, value, attributes, expected: str):
    """Return ``value`` if it has every attribute in ``attributes`` (duck typing), else
    raise :class:`BadInput` naming ``name``, ``expected`` and the first attribute missing.
    """
    for attr in attributes:
        if not hasattr(value, attr):
            raise BadInput(f"{name} must be {expected} (with .{attr}), got {_describe(value)}")
    return value


def as_path(name: str, value):
    """Return ``value`` as a :class:`pathlib.Path` (from ``str`` or ``os.PathLike``), else
    raise :class:`BadInput`; an empty string is refused too."""
    import os
    from pathlib import Path

    if isinstance(value, bytes) or not isinstance(value, (str, os.PathLike)):
        raise BadInput(f"{name} must be a path (str or os.PathLike), got {_describe(value)}")
    if isinstance(value, str) and not value:
        raise ValueError(f"{name} must be a path, got an empty string")
    return Path(value)


def as_index(name: str, value, n: int) -> int:
    """Return ``value`` as an int in ``0 <= i < n`` (no negative indexing from the end)."""
    i = as_int(name, value)
    if not 0 <= i < n:
        raise BadIndex(
            f"{name} must be in 0..{n - 1} (counted from 0, no negative index; there are {n}), "
            f"got {i}"
        )
    return i


def as_seed(name: str, value):
    """Return ``value`` if numpy can seed a generator with it: None, an int ``>= 0``, a
    ``numpy.random.SeedSequence`` or a ``numpy.random.Generator``; else ``ValueError``."""
    if value is None or isinstance(value, (np.random.SeedSequence, np.random.Generator)):
        return value
    return as_int(name, value, minimum=0)


def at_most(name: str, value, limit, what: str = "") -> float:
    """Return ``value`` if ``value <= limit``; else raise ``ValueError`` naming the limit.

    For requests whose cost grows with the value (ticks to simulate, LP orders, samples of a
    plan): refused up front instead of running for minutes. ``what`` says what the limit
    protects (e.g. ``"FPGA clock ticks"``).
    """
    if value > limit:
        extra = f" ({what})" if what else ""
        raise ValueError(f"{name} must be <= {limit:g}{extra}, got {value:g}")
    return value


def as_choice(name: str, value, choices):
    """Return ``value`` if it is one of ``choices`` (compared with ``==``), else ``ValueError``
    listing them."""
    try:
        if value in choices:
            return value
    except TypeError:  # an unhashable value against a set
        pass
    raise ValueError(
        f"{name} must be one of {', '.join(map(repr, choices))}; got {_describe(value)}"
    )


def at_least(name: str, value, limit, what: str = "") -> float:
    """Return ``value`` if ``value >= limit``; else raise ``ValueError`` naming the limit
    (``what`` says what it stands for, e.g. ``"planner.MIN_SYNC_TS"``)."""
    if value < limit:
        extra = f" ({what})" if what else ""
        raise ValueError(f"{name} must be >= {limit:g}{extra}, got {value:g}")
    return value
