"""Result figures (matplotlib, imported when a function is called).

Compute-then-plot, as python-control: the analysis lives in the modules that compute it
(``controller``, ``sim``, ``ident`` ...) and returns numbers; a function here draws them on
an ``Axes`` and returns it, so a notebook or a widget can compose several on one figure.

* :func:`zplane` — poles and zeros in the z-plane with the unit circle (the stability
  boundary of a sampled loop; notebook 03, the tuning panel).
"""
from __future__ import annotations

import numpy as np

from jerklab._validate import as_finite_array

__all__ = ["zplane"]

_CIRCLE_GID = "jerklab-unit-circle"


def _roots(name, values):
    if values is None:
        return np.zeros(0, dtype=complex)
    a = np.asarray(values)
    if a.dtype.kind not in "biufc" or a.ndim > 1:
        raise TypeError(f"{name} must be a 1-D sequence of numbers, got {type(values).__name__}")
    a = a.astype(complex).ravel()
    as_finite_array(name, np.r_[a.real, a.imag])          # NaN / inf -> ValueError naming it
    return a


def zplane(poles=None, zeros=None, ax=None, *, label=None, color=None, marker="x", title=None,
           unit_circle=True):
    """Draw poles (``marker``, default ×) and zeros (○) in the z-plane, with the unit circle.

    Call it once per system on the same ``ax`` to compare designs; the unit circle is drawn
    once per axes. The axes get equal aspect, a grid and the labels ``Re z`` / ``Im z`` (z is
    dimensionless), and the limits always show the whole unit circle.

    Parameters
    ----------
    poles, zeros : array_like of complex, or a system, optional
        The roots to draw. A system is accepted for ``poles``: an object with ``poles_z()``
        (``jerklab.controller.PositionLoop`` / ``VelocityLoop``) or a discrete python-control
        system (its ``poles()`` and, unless ``zeros`` is given, its ``zeros()``).
    ax : matplotlib.axes.Axes, optional
        Where to draw; default: a new figure's axes.
    label : str, optional
        Legend entry of the poles (the zeros get ``label + " zeros"``).
    color : str, optional
        Colour of the markers; default: the axes' next colour.
    marker : str
        Pole marker (matplotlib); hollow when it is a filled shape such as ``"o"``.
    title : str, optional
    unit_circle : bool
        Draw ``|z| = 1`` (once per axes).

    Returns
    -------
    matplotlib.axes.Axes

    Examples
    --------
    >>> import matplotlib; matplotlib.use("Agg")
    >>> ax = zplane([0.9 + 0.1j, 0.9 - 0.1j, 0.5], zeros=[-1.0], label="closed loop")
    >>> ax.get_xlabel(), ax.get_ylabel()
    ('Re z', 'Im z')
    """
    import matplotlib.pyplot as plt

    if poles is not None and not isinstance(poles, (list, tuple, np.ndarray)):
        system = poles
        if hasattr(system, "poles_z"):
            poles = system.poles_z()
        elif hasattr(system, "poles") and callable(system.poles):
            if getattr(system, "dt", None) in (None, 0):
                raise ValueError("poles: a continuous-time system has no z-plane poles; "
                                 "discretize it first (e.g. control.c2d)")
            poles = system.poles()
            if zeros is None and hasattr(system, "zeros"):
                zeros = system.zeros()
        else:
            raise TypeError(f"poles must be an array of roots or a system, got {type(system).__name__}")
    p = _roots("poles", poles)
    z = _roots("zeros", zeros)
    if ax is None:
        _, ax = plt.subplots(figsize=(4.6, 4.6))
    if unit_circle and not any(ln.get_gid() == _CIRCLE_GID for ln in ax.get_lines()):
        th = np.linspace(0.0, 2.0 * np.pi, 721)
        ax.plot(np.cos(th), np.sin(th), color="k", lw=0.8, gid=_CIRCLE_GID, label="_unit circle")
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.axvline(0.0, color="0.6", lw=0.5)
    hollow = marker in ("o", "s", "D", "^", "v", "p", "h", "*")
    if p.size:
        (line,) = ax.plot(p.real, p.imag, ls="none", marker=marker, ms=8, mew=2, color=color,
                          label=label, **({"mfc": "none"} if hollow else {}))
        color = line.get_color()
    if z.size:
        ax.plot(z.real, z.imag, ls="none", marker="o", ms=8, mew=1.5, color=color, mfc="none",
                label=None if label is None else f"{label} zeros")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("Re z")
    ax.set_ylabel("Im z")
    lo_x, hi_x = ax.get_xlim()
    lo_y, hi_y = ax.get_ylim()
    ax.set_xlim(min(lo_x, -1.1), max(hi_x, 1.1))
    ax.set_ylim(min(lo_y, -1.1), max(hi_y, 1.1))
    if title is not None:
        ax.set_title(title, fontsize=10)
    return ax
