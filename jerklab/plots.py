"""Result figures (matplotlib, imported when a function is called).

Compute-then-plot, as python-control: the analysis lives in the modules that compute it
(``controller``, ``sim``, ``ident`` ...) and returns numbers; a function here draws them on
an ``Axes`` and returns it, so a notebook or a widget can compose several on one figure.

* :func:`zplane` — poles and zeros in the z-plane with the unit circle (the stability
  boundary of a sampled loop; notebook 03, the tuning panel).
* :func:`plot_simulation` — a closed-loop run (``jerklab.sim.SimResult.plot``).
* :func:`plot_ident_data`, :func:`plot_compare`, :func:`plot_compare_result`,
  :func:`plot_residuals` — identification records, model against record (MATLAB's
  ``compare``: ``jerklab.ident.compare`` computes a ``CompareResult``, these draw it) and the
  residual tests (MATLAB's ``resid``); ``jerklab.ident``'s ``.plot()``. This module imports
  nothing of ``jerklab.ident``: the results carry what is drawn.
* :func:`plot_tradeoff` — residual vibration against the frequency ratio for profiles,
  input shapers and robust LP commands (``jerklab.shaping.tradeoff``, notebook 09).
* :func:`plot_recording`, :func:`plot_comparison` — a rig recording, and a recording against
  a simulation (``jerklab.rig.Recording.plot``, ``jerklab.rig.plot_comparison``).

The result objects keep their ``.plot()`` methods as one-line calls of these. Importing this
module does not import matplotlib (nor does any module below the face: planner, plant,
controller, sim, ident, protocol, rig, law); the functions import it when called.
"""

from __future__ import annotations

import numpy as np

from jerklab._validate import as_finite_array

__all__ = [
    "zplane",
    "plot_simulation",
    "plot_ident_data",
    "plot_compare",
    "plot_compare_result",
    "plot_residuals",
    "plot_recording",
    "plot_comparison",
    "plot_tradeoff",
]

_CIRCLE_GID = "jerklab-unit-circle"


def _roots(name, values):
    if values is None:
        return np.zeros(0, dtype=complex)
    a = np.asarray(values)
    if a.dtype.kind not in "biufc" or a.ndim > 1:
        raise TypeError(f"{name} must be a 1-D sequence of numbers, got {type(values).__name__}")
    a = a.astype(complex).ravel()
    as_finite_array(name, np.r_[a.real, a.imag])  # NaN / inf -> ValueError naming it
    return a


def zplane(
    poles=None,
    zeros=None,
    ax=None,
    *,
    label=None,
    color=None,
    marker="x",
    title=None,
    unit_circle=True,
):
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
                raise ValueError(
                    "poles: a continuous-time system has no z-plane poles; "
                    "discretize it first (e.g. control.c2d)"
                )
            poles = system.poles()
            if zeros is None and hasattr(system, "zeros"):
                zeros = system.zeros()
        else:
            raise TypeError(
                f"poles must be an array of roots or a system, got {type(system).__name__}"
            )
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
        (line,) = ax.plot(
            p.real,
            p.imag,
            ls="none",
            marker=marker,
            ms=8,
            mew=2,
            color=color,
            label=label,
            **({"mfc": "none"} if hollow else {}),
        )
        color = line.get_color()
    if z.size:
        ax.plot(
            z.real,
            z.imag,
            ls="none",
            marker="o",
            ms=8,
            mew=1.5,
            color=color,
            mfc="none",
            label=None if label is None else f"{label} zeros",
        )
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


# ----------------------------------------------------------------------------------------------
# simulation
# ----------------------------------------------------------------------------------------------
def plot_simulation(result, fig=None, title=None):
    """Reference and output, tracking error, and the control parts (3 stacked axes).

    Parameters
    ----------
    result : jerklab.sim.SimResult
    fig : matplotlib.figure.Figure, optional
        Figure to draw in (three axes are added); default: a new one.
    title : str, optional
        Default: the loop and the error metrics.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    res = result
    if fig is None:
        fig = plt.figure(figsize=(9, 7))
    ax = fig.subplots(3, 1, sharex=True)
    ax[0].plot(res.time, res.reference, "k--", lw=1, label="reference")
    ax[0].plot(res.time, res.position, label="motor (true)")
    ax[0].plot(res.time, res.measured, ".", ms=2, label="encoder")
    if res.load_position is not None:
        ax[0].plot(res.time, res.load_position, label="load")
    ax[0].set_ylabel("angle (rad)")
    ax[0].legend(loc="best", fontsize=8)
    ax[1].plot(res.time, res.error * 1e3)
    ax[1].set_ylabel("tracking error (mrad)")
    for name in ("ff", "p", "i", "d"):
        ax[2].plot(res.time, res.parts[name], lw=1, label=name)
    ax[2].plot(res.time, res.voltage, "k", lw=1.2, label="u applied")
    if np.any(res.saturated):
        ax[2].fill_between(
            res.time,
            0,
            1,
            where=res.saturated,
            color="r",
            alpha=0.1,
            transform=ax[2].get_xaxis_transform(),
            label="saturated",
        )
    ax[2].set_ylabel("voltage (V)")
    ax[2].set_xlabel("time (s)")
    ax[2].legend(loc="best", fontsize=8, ncol=3)
    m = res.metrics
    ax[0].set_title(
        title
        or (
            f"{res.loop} loop: max |e| = {m['peak_error'] * 1e3:.3g} mrad, "
            f"RMS {m['rms_error'] * 1e3:.3g} mrad, final {m['final_error'] * 1e3:.3g} mrad"
        )
    )
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------------------------------------
# identification
# ----------------------------------------------------------------------------------------------
def plot_ident_data(data, axes=None):
    """Two stacked panels of an ``IdentData``: input and output against time (s)."""
    import matplotlib.pyplot as plt

    if axes is None:
        _, axes = plt.subplots(2, 1, sharex=True, figsize=(8, 4.5))
    axes[0].step(data.time, data.voltage, where="post")
    axes[0].set_ylabel(f"input u ({data.input_unit})")
    axes[1].plot(data.time, data.position, ".", ms=2)
    axes[1].set_ylabel(f"output y ({data.output_unit})")
    axes[1].set_xlabel("time (s)")
    return axes


_COMPARE_FIELDS = ("time", "y", "y_hat", "fit_percent", "horizon", "label")


def _check_compare_result(i, result):
    missing = [f for f in _COMPARE_FIELDS if not hasattr(result, f)]
    if missing:
        raise ValueError(
            f"results[{i}] must be a jerklab.ident.CompareResult (compare(data, fit)), "
            f"got {type(result).__name__}"
        )


def plot_compare(*results, ax=None, unit: str | None = None):
    """Measured output and each model's output against time, with fit % in the legend.

    Parameters
    ----------
    *results : jerklab.ident.CompareResult
        ``compare(data, fit, ...)`` of one or more models on the *same* record: the record is
        drawn once (from the first), then each model's output.
    ax : matplotlib Axes, optional
    unit : str, optional
        Unit of the output axis; default the results' ``unit`` ("rad", or "rad/s" for speed).

    Returns
    -------
    matplotlib.axes.Axes
    """
    import matplotlib.pyplot as plt

    if not results:
        raise ValueError("results: give at least one CompareResult")
    for i, r in enumerate(results):
        _check_compare_result(i, r)
    first = results[0]
    for i, r in enumerate(results[1:], 1):
        if not (np.array_equal(r.time, first.time) and np.array_equal(r.y, first.y)):
            raise ValueError(f"results[{i}] compares on another record than results[0]")
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(first.time, first.y, ".", color="0.3", ms=3, label="measured")
    for r in results:
        what = "simulation" if r.horizon is None else f"{r.horizon}-step prediction"
        name = f"{r.label}: " if r.label else ""
        ax.plot(r.time, r.y_hat, "-", lw=1.5, label=f"{name}{what}, fit {r.fit_percent:.2f} %")
    output = getattr(first, "output", "angle")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{output} ({unit or getattr(first, 'unit', 'rad')})")
    ax.legend(loc="best", fontsize=8)
    return ax


def plot_compare_result(result, ax=None, unit: str | None = None):
    """One ``jerklab.ident.CompareResult``: :func:`plot_compare` of it alone."""
    return plot_compare(result, ax=ax, unit=unit)


_RESIDUAL_FIELDS = ("lags", "autocorr", "auto_bound", "confidence", "crosscorr", "cross_lags")


def plot_residuals(analysis, axes=None, title: str | None = None):
    """Two panels as MATLAB's ``resid``: autocorrelation of e, cross-correlation of u and e.

    ``analysis`` is a ``jerklab.ident.ResidualAnalysis``; one panel when it has no input.
    """
    import matplotlib.pyplot as plt

    if not all(hasattr(analysis, f) for f in _RESIDUAL_FIELDS):
        raise ValueError(
            f"analysis must be a jerklab.ident.ResidualAnalysis, got {type(analysis).__name__}"
        )
    n = 1 if analysis.crosscorr is None else 2
    if axes is None:
        _, axes = plt.subplots(n, 1, figsize=(8, 2.4 * n))
    axes = np.atleast_1d(axes)
    ax = axes[0]
    ax.stem(analysis.lags, analysis.autocorr)
    ax.axhspan(
        -analysis.auto_bound,
        analysis.auto_bound,
        color="C1",
        alpha=0.2,
        label=f"{analysis.confidence:.0%} bound",
    )
    ax.set_xlabel("lag (samples)")
    ax.set_ylabel("autocorr. of e (–)")
    ax.legend(loc="upper right", fontsize=8)
    if title:
        ax.set_title(title)
    if n == 2:
        ax = axes[1]
        ax.stem(analysis.cross_lags, analysis.crosscorr)
        ax.axhspan(-analysis.cross_bound, analysis.cross_bound, color="C1", alpha=0.2)
        ax.set_xlabel("lag (samples)")
        ax.set_ylabel("cross-corr. u, e (–)")
    return axes


# ----------------------------------------------------------------------------------------------
# rig recordings
# ----------------------------------------------------------------------------------------------
def plot_recording(rec, ax=None):
    """Reference and measured position (rad) and voltage (V) of a rig ``Recording`` against time (s).

    ``ax`` is a pair of axes (default: a new figure); returns the figure.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    else:
        fig = ax[0].figure
    t = rec.time
    if rec.metadata.get("kind") == "move":
        ax[0].plot(t, rec.reference, label="reference")
    ax[0].plot(t, rec.position, label="measured")
    ax[0].set_ylabel("position (rad)")
    ax[0].legend()
    ax[1].step(t, rec.voltage, where="post")
    ax[1].set_ylabel("voltage (V)")
    ax[1].set_xlabel("time (s)")
    ax[0].set_title(
        f"rig recording: {rec.metadata.get('kind', '')} ({rec.metadata.get('status', '')})"
    )
    return fig


def plot_comparison(rec, sim, title="Measured vs simulated sine-jerk move"):
    """Overlay a rig recording and a simulation: position, tracking error, control voltage.

    Both tracking errors are ``reference − encoder reading`` (what the controller sees).
    ``sim`` is a ``jerklab.sim.SimResult`` sampled at the recording's ``Ts`` from t = 0.
    """
    import matplotlib.pyplot as plt

    n = min(len(rec), len(sim.time))
    idx = rec.index[rec.index < len(sim.time)][:n]
    t = rec.time[: len(idx)]
    fig, ax = plt.subplots(3, 1, sharex=True, figsize=(8, 7.5))
    ax[0].plot(t, rec.reference[: len(idx)], "k--", lw=1, label="reference")
    ax[0].plot(t, rec.position[: len(idx)], label="measured (rig)")
    ax[0].plot(t, np.asarray(sim.measured)[idx], ":", label="simulated")
    ax[0].set_ylabel("position (rad)")
    ax[0].legend(loc="lower right")
    ax[1].plot(
        t, 1e3 * (rec.reference[: len(idx)] - rec.position[: len(idx)]), label="measured (rig)"
    )
    ax[1].plot(
        t,
        1e3 * (np.asarray(sim.reference)[idx] - np.asarray(sim.measured)[idx]),
        ":",
        label="simulated",
    )
    ax[1].set_ylabel("tracking error (mrad)")
    ax[1].legend(loc="upper right")
    ax[2].step(t, rec.voltage[: len(idx)], where="post", label="measured (rig)")
    ax[2].step(t, np.asarray(sim.voltage)[idx], ":", where="post", label="simulated")
    ax[2].set_ylabel("voltage (V)")
    ax[2].set_xlabel("time (s)")
    ax[2].legend(loc="upper right")
    ax[0].set_title(title)
    fig.tight_layout()
    return fig


_FAMILY_STYLE = {"profile": "-", "shaper": "--", "robust LP": ":"}


def plot_tradeoff(tradeoff, ax=None, floor=1e-2):
    """Residual vibration (%, log scale, clipped at ``floor``) against the frequency ratio, one line
    per method of ``jerklab.shaping.Tradeoff``: profiles solid, shapers dashed, robust LP dotted,
    with the 5 % tolerance as a grey line."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(10, 5), layout="constrained")
    fams = {r["name"]: r["family"] for r in tradeoff.rows}
    for name, v in tradeoff.curves.items():
        ax.semilogy(
            tradeoff.ratios,
            np.maximum(v, floor),
            _FAMILY_STYLE.get(fams.get(name), "-"),
            label=name,
            lw=1.4,
        )
    ax.axhline(5.0, color="0.5", lw=0.8)
    ax.set_xlabel(f"mode frequency / nominal {tradeoff.frequency_hz:.2f} Hz (–)")
    ax.set_ylabel("residual vibration (% of a step)")
    ax.set_title(
        f"Residual vibration, mode ζ = {tradeoff.damping:.3f}, move {tradeoff.distance:.2f} rad"
    )
    ax.set_xlim(tradeoff.ratios[0], tradeoff.ratios[-1])
    ax.set_ylim(floor, 300)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return ax
