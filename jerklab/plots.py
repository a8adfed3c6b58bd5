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
* :func:`plot_profile` — jerk, acceleration, velocity and position of a plan (Stojčić Fig. 1,
  ASCII Stojcic; Yang Fig. 2); :func:`plot_runs`, :func:`plot_control_parts` — several closed-loop runs
  overlaid, and the parts of one run's voltage (notebooks 04, 06).
* :func:`plot_scan_cycle`, :func:`plot_scan_closed_loop`, :func:`plot_table_ii` — the piezo
  scanner's shaped cycles, its closed loop and Table II (Xu & Meckl Figs. 5, 6, 9, notebook 07).
* :func:`plot_preisach_weight`, :func:`plot_preisach_memory`, :func:`plot_forc` — a Preisach
  model's weight, its memory in the Preisach plane, reversal curves (notebook 08).
* :func:`plot_speed_register`, :func:`plot_pulse_speed` — Yang's speed register and the speed
  its pulses command (Yang Figs. 2, 7, notebook 06).
* :func:`plot_sensitivity` — the sensitivity curves of input shapers and robust moves
  (notebook 09).

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


# ----------------------------------------------------------------------------------------------
# planned moves
# ----------------------------------------------------------------------------------------------
#: quantity of a profile sample -> (axis name, unit suffix after the length unit)
_PROFILE_QUANTITIES = {
    "jerk": ("jerk", "/s³"),
    "accel": ("acceleration", "/s²"),
    "velocity": ("velocity", "/s"),
    "position": ("position", ""),
}


def _axes(axes, n, figsize):
    import matplotlib.pyplot as plt

    if axes is None:
        _, axes = plt.subplots(n, 1, sharex=True, figsize=figsize, squeeze=False)
        return list(axes[:, 0])
    axes = list(np.atleast_1d(axes).ravel())
    if len(axes) != n:
        raise ValueError(f"axes must hold {n} Axes, got {len(axes)}")
    return axes


def plot_profile(
    profile,
    t=None,
    axes=None,
    *,
    quantities=("jerk", "accel", "velocity", "position"),
    unit="rad",
    scale=1.0,
    label=None,
    boundaries=False,
    **style,
):
    """Jerk, acceleration, velocity and position of a planned move against time, one panel each.

    Parameters
    ----------
    profile : jerklab.planner.Profile or jerklab.planner.ProfileSample
        A plan (anything with ``duration`` and ``sample(t)``; its closed form is drawn at ``t``) or
        samples of one (a ``discretize`` recursion, say), drawn as they are.
    t : array, optional
        Times (s) at which to draw a plan; default 1000 points over ``[0, duration]``.
    axes : sequence of matplotlib Axes, optional
        One per quantity (default: a new figure); pass the same axes again to overlay moves.
    quantities : sequence of {"jerk", "accel", "velocity", "position"}
    unit : str
        Length unit of the plotted values (after ``scale``): "rad", "µm", "mm" ...
    scale : float
        Factor applied to every value (``1e-3`` shows a plan in µm as mm).
    label : str, optional
        Legend entry (the legend is drawn on the first axes).
    boundaries : bool
        Mark the plan's phase boundaries and its end (the sums of ``phase_times``) with dashed
        lines.
    **style
        Passed to ``Axes.plot`` (``ls``, ``color``, ``lw`` ...).

    Returns
    -------
    list of matplotlib Axes
    """
    names = tuple(quantities)
    bad = [q for q in names if q not in _PROFILE_QUANTITIES]
    if bad or not names:
        raise ValueError(f"quantities must be among {tuple(_PROFILE_QUANTITIES)}, got {names}")
    if hasattr(profile, "sample"):
        if t is None:
            t = np.linspace(0.0, float(profile.duration), 1000)
        s = profile.sample(as_finite_array("t", t, ndim=1))
    elif all(hasattr(profile, q) for q in ("t", *names)):
        s = profile
    else:
        raise TypeError(
            "profile must be a planner Profile (sample(t)) or a ProfileSample, "
            f"got {type(profile).__name__}"
        )
    axes = _axes(axes, len(names), (7, 1.9 * len(names) + 0.6))
    for ax, q in zip(axes, names):
        name, suffix = _PROFILE_QUANTITIES[q]
        ax.plot(s.t, scale * np.asarray(getattr(s, q)), label=label, **style)
        ax.set_ylabel(f"{name} ({unit}{suffix})")
        ax.grid(alpha=0.3)
        if boundaries and hasattr(profile, "phase_times"):
            for x in np.cumsum(profile.phase_times):
                ax.axvline(x, color="0.6", ls="--", lw=0.8)
    axes[-1].set_xlabel("time (s)")
    if label is not None:
        axes[0].legend(fontsize=8)
    return axes


# ----------------------------------------------------------------------------------------------
# several closed-loop runs
# ----------------------------------------------------------------------------------------------
#: signal of a SimResult -> (attribute, axis label, factor)
_RUN_SIGNALS = {
    "reference": ("reference", "reference (rad)", 1.0),
    "ref_velocity": ("ref_velocity", "reference velocity (rad/s)", 1.0),
    "position": ("position", "motor angle (rad)", 1.0),
    "measured": ("measured", "encoder reading (rad)", 1.0),
    "load_position": ("load_position", "load angle (rad)", 1.0),
    "error": ("error", "tracking error (mrad)", 1e3),
    "u_applied": ("u_applied", "motor voltage (V)", 1.0),
}


def plot_runs(results, signals=("error",), axes=None, *, labels=None, **style):
    """Several closed-loop runs overlaid, one panel per signal, against time (s).

    Parameters
    ----------
    results : mapping of str to jerklab.sim.SimResult, or a sequence of SimResult
        The runs; a mapping's keys are the legend entries.
    signals : sequence of str
        Among "reference", "ref_velocity", "position", "measured", "load_position" (rad, rad/s),
        "error" (``reference − position``, mrad) and "u_applied" (V).
    axes : sequence of matplotlib Axes, optional
        One per signal (default: a new figure).
    labels : sequence of str, optional
        Legend entries for a sequence of runs.
    **style
        Passed to ``Axes.plot``.

    Returns
    -------
    list of matplotlib Axes
    """
    if hasattr(results, "items"):
        labels, runs = list(results.keys()), list(results.values())
    else:
        runs = list(results)
        labels = [None] * len(runs) if labels is None else list(labels)
        if len(labels) != len(runs):
            raise ValueError(f"labels must name the {len(runs)} runs, got {len(labels)}")
    names = tuple(signals)
    bad = [s for s in names if s not in _RUN_SIGNALS]
    if bad or not names:
        raise ValueError(f"signals must be among {tuple(_RUN_SIGNALS)}, got {names}")
    axes = _axes(axes, len(names), (9, 2.6 * len(names) + 0.4))
    for ax, name in zip(axes, names):
        attr, ylabel, factor = _RUN_SIGNALS[name]
        for run, label in zip(runs, labels):
            y = getattr(run, attr)
            if y is None:
                raise ValueError(f"signal {name!r}: the run {label or ''} has no {attr}")
            ax.plot(run.t, factor * np.asarray(y), label=label, **{"lw": 1, **style})
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    if any(lb is not None for lb in labels):
        axes[0].legend(fontsize=8)
    return axes


def plot_control_parts(result, ax=None):
    """The parts of the control voltage of one run (feedforward ``ff`` and the PID's ``p``,
    ``i``, ``d``: the outputs of Stojčić Figs. 5 and 6) against time (s).

    Parameters
    ----------
    result : jerklab.sim.SimResult
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3.5))
    for name in ("ff", "p", "i", "d"):
        ax.plot(result.t, result.parts[name], lw=1, label=name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("voltage (V)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return ax


# ----------------------------------------------------------------------------------------------
# the piezo scanner (Xu & Meckl)
# ----------------------------------------------------------------------------------------------
def _shade_scan(axes, cycle, factor):
    Ts = cycle.spec.Ts
    for a in axes:
        a.axvspan(cycle.N * Ts * factor, (cycle.N + cycle.S) * Ts * factor, color="g", alpha=0.1)


def plot_scan_cycle(evaluation, cycle, axes=None, *, title=None):
    """A shaped scan cycle under the frequency perturbation: input, nominal and perturbed output,
    and their difference against time (ms), the scan shaded (Xu & Meckl Figs. 5, 6).

    Parameters
    ----------
    evaluation : jerklab.piezo.CycleEvaluation
        From :func:`jerklab.piezo.evaluate_cycle`.
    cycle : jerklab.piezo.ScanCycle
        The cycle evaluated (its ramp-up, scan and limit ``spec.F_max``).
    axes : three matplotlib Axes, optional
    title : str, optional
        Prefix of the title, which gives the cycle time, ``e_m`` and ``e_r``.

    Returns
    -------
    list of matplotlib Axes
    """
    ev, c = evaluation, cycle
    axes = _axes(axes, 3, (8, 7))
    t = ev.t * 1e3
    axes[0].step(t, ev.u, where="post")
    for sign in (1, -1):
        axes[0].axhline(sign * c.spec.F_max, color="k", lw=0.5, ls=":")
    axes[0].set_ylabel("input u (V)")
    axes[1].plot(t, ev.y_nominal, label="nominal")
    axes[1].plot(t, ev.y_perturbed, "--", label="perturbed")
    axes[1].set_ylabel("output y (µm)")
    axes[1].legend(fontsize=8)
    axes[2].plot(t, ev.y_perturbed - ev.y_nominal, color="C3")
    axes[2].set_ylabel("y_pert − y_nom (µm)")
    axes[2].set_xlabel("time (ms)")
    axes[2].set_xlim(0, c.cycle_time * 1e3 + 15)
    _shade_scan(axes, c, 1e3)
    axes[0].set_title(
        (f"{title}: " if title else "")
        + f"cycle {c.cycle_time * 1e3:.1f} ms, e_m = {ev.e_m:.3f} µm, e_r = {ev.e_r:.3f} µm "
        "(scan shaded)",
        fontsize=9,
    )
    return axes


def plot_scan_closed_loop(result, cycle, axes=None, *, title=None):
    """The closed loop with hysteresis compensation (Xu & Meckl Fig. 9): the shaped command and
    the compensated actuator voltage with the limit, the desired and obtained output, and the
    tracking error against time (ms), the scan shaded.

    Parameters
    ----------
    result : jerklab.piezo.ClosedLoopResult
        From :func:`jerklab.piezo.closed_loop`.
    cycle : jerklab.piezo.ScanCycle
        The cycle run.
    axes : three matplotlib Axes, optional
    title : str, optional

    Returns
    -------
    list of matplotlib Axes
    """
    cl, c = result, cycle
    axes = _axes(axes, 3, (8, 7.5))
    t = cl.t * 1e3
    axes[0].plot(t, cl.u_ff, label="shaped command u_ff")
    axes[0].plot(t, cl.u_c, "--", label="actuator voltage u_c (after CNIA)")
    for sign in (1, -1):
        axes[0].axhline(
            sign * c.spec.F_max,
            color="r",
            lw=0.8,
            ls=":",
            label=f"actuator limit ±F_max = {c.spec.F_max:g} V" if sign > 0 else None,
        )
    axes[0].set_ylabel("voltage (V)")
    axes[0].legend(fontsize=8)
    axes[1].plot(t, cl.y_desired, label="desired (nominal response)")
    axes[1].plot(t, cl.y, "--", label="closed loop")
    axes[1].set_ylabel("output y (µm)")
    axes[1].legend(fontsize=8)
    axes[2].plot(t, cl.y - cl.y_desired, color="C3")
    axes[2].set_ylabel("tracking error (µm)")
    axes[2].set_xlabel("time (ms)")
    _shade_scan(axes, c, 1e3)
    if title:
        axes[0].set_title(title, fontsize=9)
    return axes


def plot_table_ii(rows, axes=None, *, title="Xu & Meckl Table II: computed vs published"):
    """Cycle time, ``e_m`` and ``e_r`` of each input of :func:`jerklab.piezo.table_ii`, beside
    the published values (bars; the errors on a log scale).

    Parameters
    ----------
    rows : dict
        ``{input name: {"cycle_time", "e_m", "e_r", "paper": (cycle, e_m, e_r)}}``.
    axes : three matplotlib Axes side by side, optional

    Returns
    -------
    list of matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if axes is None:
        fig, axes = plt.subplots(1, 3, figsize=(11, 3.3))
    axes = list(np.atleast_1d(axes).ravel())
    names = list(rows)
    x = np.arange(len(names))
    for a, key, idx, unit, factor in (
        (axes[0], "cycle_time", 0, "ms", 1e3),
        (axes[1], "e_m", 1, "µm", 1.0),
        (axes[2], "e_r", 2, "µm", 1.0),
    ):
        a.bar(x - 0.2, [rows[n][key] * factor for n in names], 0.4, label="jerklab")
        a.bar(x + 0.2, [rows[n]["paper"][idx] * factor for n in names], 0.4, label="paper")
        a.set_xticks(
            x, [n.replace(" robust", "").replace("-robust", "") for n in names], rotation=20
        )
        a.set_ylabel(f"{key} ({unit})")
        if key != "cycle_time":
            a.set_yscale("log")
    axes[0].legend()
    if title:
        axes[0].figure.suptitle(title)
    return axes


# ----------------------------------------------------------------------------------------------
# hysteresis (Preisach)
# ----------------------------------------------------------------------------------------------
def plot_preisach_weight(model, ax=None, *, colorbar=True, title="Preisach weight μ(α, β)"):
    """The weight ``μ(α, β)`` of a :class:`jerklab.hysteresis.Preisach` model on its half plane
    ``α >= β`` (an image; switch-off input β across, switch-on input α up).

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4.3))
    extent = [model.u_min, model.u_max, model.u_min, model.u_max]
    im = ax.imshow(model.masked_density(), origin="lower", extent=extent, cmap="viridis")
    ax.set_xlabel("β, switch-off input (V)")
    ax.set_ylabel("α, switch-on input (V)")
    if title:
        ax.set_title(title)
    if colorbar:
        ax.figure.colorbar(im, ax=ax, label="μ (1/V)", shrink=0.85)
    return ax


def plot_preisach_memory(model, ax=None, *, title=None):
    """The memory of a :class:`jerklab.hysteresis.Preisach` model: the region ``S+`` of the
    relays that are on, bounded by the staircase of its alternating extrema, in the Preisach
    plane.

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(4.5, 4.5))
    b, a = model.interface()
    ax.fill(np.r_[model.u_min, b], np.r_[model.u_min, a], color="C1", alpha=0.4, label="S+ (on)")
    ax.plot(b, a, "k.-", lw=1)
    ax.plot([model.u_min, model.u_max], [model.u_min, model.u_max], "k", lw=0.6)
    ax.set_xlabel("β (V)")
    ax.set_ylabel("α (V)")
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)
    if title:
        ax.set_title(title)
    return ax


def plot_forc(data, ax=None, **style):
    """First-order reversal curves (:class:`jerklab.hysteresis.ForcData`): the output along each
    descent from its turning point ``α``, against the input (V).

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4.3))
    for alpha in np.unique(data.alpha):
        sel = data.alpha == alpha
        ax.plot(data.beta[sel], data.f[sel], **{"lw": 0.8, "color": "C0", **style})
    ax.set_xlabel("input u (V)")
    ax.set_ylabel("output (V)")
    return ax


# ----------------------------------------------------------------------------------------------
# the FPGA S-curve (Yang et al.)
# ----------------------------------------------------------------------------------------------
def plot_speed_register(generator, ax=None, *, scale=1e-3, unit="mm/s", **style):
    """The speed register of a :class:`jerklab.fpga.YangSCurve` (Yang eqs. 5–8) tick by tick,
    as the step it holds between refreshes, against time (s).

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3))
    speed = generator.speed_table().speed
    ax.step(
        generator.tick_times(),
        scale * speed,
        where="post",
        **{"lw": 0.8, "label": "speed register", **style},
    )
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"speed ({unit})")
    return ax


def plot_pulse_speed(train, ax=None, *, scale=1e-3, unit="mm/s", **style):
    """The speed a pulse train commands, ``k / Δt`` between rising edges (a
    :class:`jerklab.fpga.PulseTrain`, or ``(t, v)`` in s and µm/s), one dot per pulse period.

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3))
    t, v = train.speed() if hasattr(train, "speed") else train
    ax.plot(t, scale * np.asarray(v), **{"ls": "", "marker": ".", "ms": 2, **style})
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"speed k/Δt ({unit})")
    return ax


# ----------------------------------------------------------------------------------------------
# vibration: sensitivity of shapers and robust commands
# ----------------------------------------------------------------------------------------------
def plot_sensitivity(commands, ratios, ax=None, *, tolerance=5.0, frequency_hz=None):
    """Residual vibration (% of a step's) against the mode frequency ratio, one line per command:
    the sensitivity curves of input shapers (:class:`jerklab.shaping.InputShaper`) or robust
    moves (:class:`jerklab.shaping.RobustMove`), from each one's ``sensitivity_curve``.

    Parameters
    ----------
    commands : mapping of str to an object with ``sensitivity_curve(ratios)``
    ratios : array
        Mode frequency over the design frequency.
    ax : matplotlib Axes, optional
    tolerance : float or None
        A grey line at this residual (%), the usual 5 %.
    frequency_hz : float, optional
        The design frequency, named in the axis label.

    Returns
    -------
    matplotlib Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4))
    r = as_finite_array("ratios", ratios, ndim=1)
    for name, c in commands.items():
        ax.plot(r, c.sensitivity_curve(r), label=name)
    if tolerance is not None:
        ax.axhline(tolerance, color="0.5", lw=0.8)
    design = (
        "design frequency" if frequency_hz is None else f"design frequency {frequency_hz:.2f} Hz"
    )
    ax.set_xlabel(f"mode frequency / {design} (–)")
    ax.set_ylabel("residual vibration (%)")
    ax.grid(alpha=0.3)
    return ax


__all__ += [
    "plot_profile",
    "plot_runs",
    "plot_control_parts",
    "plot_scan_cycle",
    "plot_scan_closed_loop",
    "plot_table_ii",
    "plot_preisach_weight",
    "plot_preisach_memory",
    "plot_forc",
    "plot_speed_register",
    "plot_pulse_speed",
    "plot_sensitivity",
]
