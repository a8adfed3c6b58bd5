"""Interactive tuning panels for the notebooks and the standalone class page (issue 9).

:func:`pole_placement_panel` builds the pole-placement tuning panel of
``notebooks/03_pole_placement.ipynb`` and of the standalone page served by
``python -m jerklab.app``: sliders for ζ, ωn, σ (as a multiple of ωn) and Ts, a choice
between the paper's continuous design (Stojčić eq. 11, discretized by eq. 12-13) and the
direct z-domain design, and one figure with the poles in s and z, the step and
disturbance responses, the tracking error and the voltage of a sine-jerk move.

Design choices
--------------
* The figure is a plain :class:`matplotlib.figure.Figure` drawn with the Agg canvas (no
  pyplot, no front-end extension beyond ipywidgets' own): its artists are created once and
  only their data is changed on a slider move; the PNG goes into an
  :class:`ipywidgets.Image`. This works the same in JupyterLab, Voilà and headless
  (ipympl would add a front-end extension to every server and draws with Agg anyway).
* Redraw within 0.3 s (issue 9): the axes, ticks and labels sit in a cached background;
  a slider move restores it and draws the data lines only. Axis ranges are rounded to
  1-2-5 values with hysteresis, so a range rarely changes; when one does, only that axes
  is repainted inside its own slot. ``python -m benchmarks widgets`` measures it against a
  full redraw and a new figure per move.
* The panel's rich representation carries, beside the widget view, a ``image/png`` of the
  current figure, so headless execution (nbclient, nbconvert, a notebook viewer) keeps the
  default-value figure, while a widget front end shows the live panel.
* Every number comes from the library (``jerklab.controller``, ``jerklab.plant``,
  ``jerklab.sim``, ``jerklab.planner``); the panel only lays it out. Those modules are
  imported when the panel computes, so importing this module never fails.
"""
from __future__ import annotations

import base64
import io
import math
import time
from dataclasses import dataclass, field

import numpy as np

from jerklab._validate import as_nonnegative, as_positive

__all__ = [
    "DESIGNS",
    "TuningResult",
    "compute_pole_placement",
    "stability_verdict",
    "PolePlacementFigure",
    "PolePlacementPanel",
    "pole_placement_panel",
]

#: The two designs the panel offers: label -> key.
DESIGNS = {
    "continuous (eq. 11) discretized by eq. 13": "continuous",
    "direct z-domain (poles at z = exp(s Ts))": "z-domain",
}

#: Default move for the tracking plot: Stojčić's sine-jerk planner, rad and s.
DEFAULT_MOVE = dict(distance=10.0, max_jerk=5000.0, max_accel=300.0, max_velocity=60.0)

#: Input-referred step load disturbance of the disturbance plot (V), eq. 9 with W = P.
DISTURBANCE_VOLTS = 1.0

#: Diverging responses are clipped to this (mrad) in the plots (the verdict says why).
CLIP_MRAD = 2000.0

#: A loop whose largest |z| is above this is flagged as "near instability".
NEAR_UNSTABLE_RADIUS = 0.98


# --------------------------------------------------------------------------------------
# computation (no widgets): one design -> every curve of the panel
# --------------------------------------------------------------------------------------
@dataclass
class TuningResult:
    """Everything the panel plots for one setting of the sliders.

    Attributes
    ----------
    params : dict
        ``K, tau, zeta, wn, sigma_ratio, sigma, Ts, design``.
    gains : object
        The discrete gains (``kpd, kid, kdd, Ts``) of the chosen design.
    continuous_gains : object or None
        The eq. 11 gains (``kp, ki, kd``) when the continuous design is chosen.
    poles_s_desired : ndarray
        Roots of (s + σ)(s² + 2ζωn s + ωn²), the designed closed-loop poles (footnote of eq. 13).
    poles_z : ndarray
        Closed-loop poles of the sampled loop (ZOH plant + discrete PID).
    poles_z_desired : ndarray
        ``exp(s Ts)`` of the designed poles.
    poles_s_equivalent : ndarray
        ``log(z) / Ts`` of the achieved poles (where the sampled loop really puts them).
    max_radius, desired_radius : float
        Largest |z| achieved and designed.
    stable : bool
    level, message : str
        ``"ok" | "near" | "unstable"`` and the sentence shown to the student.
    t_step, y_step : ndarray
        Unit step response reference -> position of the sampled loop (no feedforward).
    t_dist, y_dist : ndarray
        Position (rad) after a step load disturbance of ``DISTURBANCE_VOLTS`` at the plant input.
        Both responses run to 3 × ``t_view``. For a loop with ``level == "unstable"`` they grow
        without bound and may overflow to inf/NaN (the plots clip them).
    t_move, err_move, u_move : ndarray
        Tracking error (rad) and voltage (V) of the sine-jerk move simulated by
        :func:`jerklab.sim.simulate` (feedforward + PID, 10-bit PWM, 12 V, 448-line encoder).
    t_view : float
        Time span (s) that shows the step and disturbance responses (12 / (min(ζ, 1) ωn)).
    timings : dict
        Seconds spent in the design, the linear responses and the move simulation.
    """

    params: dict
    gains: object
    continuous_gains: object
    poles_s_desired: np.ndarray
    poles_z: np.ndarray
    poles_z_desired: np.ndarray
    poles_s_equivalent: np.ndarray
    max_radius: float
    desired_radius: float
    stable: bool
    level: str
    message: str
    t_step: np.ndarray
    y_step: np.ndarray
    t_dist: np.ndarray
    y_dist: np.ndarray
    t_move: np.ndarray
    err_move: np.ndarray
    u_move: np.ndarray
    t_view: float = 1.0
    timings: dict = field(default_factory=dict)


def stability_verdict(max_radius, desired_radius, Ts=None, sigma=None):
    """Classify a sampled loop from its largest closed-loop pole radius.

    Parameters
    ----------
    max_radius : float
        Largest |z| of the closed-loop poles actually obtained.
    desired_radius : float
        Largest |z| of the designed poles mapped by z = exp(s Ts).
    Ts, sigma : float, optional
        Used only to add the σ·Ts figure to the message.

    Returns
    -------
    level : {"ok", "near", "unstable"}
        ``"unstable"`` when |z| >= 1; ``"near"`` when |z| > ``NEAR_UNSTABLE_RADIUS`` and the
        sampled loop lost more than half of the stability margin (1 - |z|) that the design
        asked for (a slow design is not flagged just because its poles are slow).
    message : str
    """
    r = as_nonnegative("max_radius", max_radius)          # |z| of a pole: never negative
    rd = as_nonnegative("desired_radius", desired_radius)
    extra = ""
    if Ts is not None and sigma is not None:
        extra = f" (σ·Ts = {sigma * Ts:.2f})"
    if r >= 1.0:
        return "unstable", (f"UNSTABLE: the sampled loop has a pole at |z| = {r:.3f} ≥ 1{extra}. "
                            "The continuous design does not survive this Ts: lower ωn or σ, "
                            "sample faster, or use the direct z-domain design.")
    margin, margin_designed = 1.0 - r, 1.0 - rd
    if r > NEAR_UNSTABLE_RADIUS and margin < 0.5 * margin_designed:
        return "near", (f"Near instability: largest |z| = {r:.3f} (designed {rd:.3f}){extra}. "
                        "A smooth reference with feedforward hides it; a step or a disturbance "
                        "rings for a long time.")
    return "ok", f"Stable: largest |z| = {r:.3f} (designed {rd:.3f}){extra}."


def _clip_for_plot(y, scale):
    """Keep a diverging response plottable: clip to ±``scale``, NaN/inf -> clipped."""
    y = np.nan_to_num(np.asarray(y, dtype=float), nan=0.0, posinf=scale, neginf=-scale)
    return np.clip(y, -scale, scale)


_MOVE_CACHE: dict = {}


def _move_profile(move):
    from jerklab.planner import plan_sine_jerk

    key = tuple(sorted(move.items()))
    if key not in _MOVE_CACHE:
        _MOVE_CACHE[key] = plan_sine_jerk(move["distance"], move["max_jerk"], move["max_accel"],
                                          move["max_velocity"])
    return _MOVE_CACHE[key]


def compute_pole_placement(K=32.4, tau=0.025, zeta=1.0, wn=20.0, sigma_ratio=7.0, Ts=0.005,
                           design="continuous", move=None, simulate_move=True):
    """Design the position-loop PID for one setting and compute every curve of the panel.

    Parameters
    ----------
    K, tau : float
        Plant P(s) = K / (s (τ s + 1)) (Stojčić eq. 1), rad/(V·s) and s.
    zeta, wn : float
        Damping ratio and natural frequency (rad/s) of the dominant pair.
    sigma_ratio : float
        The real pole σ as a multiple of ωn (the paper: σ ≥ 7 ωn).
    Ts : float
        Sampling period (s).
    design : {"continuous", "z-domain"}
        ``"continuous"``: :func:`jerklab.controller.pole_placement_pid` (eq. 11) then
        ``.discretize(Ts)`` (eq. 12-13), as the paper. ``"z-domain"``:
        :func:`jerklab.controller.discrete_pole_placement_pid`, the gains solved on the ZOH
        plant so the poles land at z = exp(s Ts).
    move : dict, optional
        ``distance, max_jerk, max_accel, max_velocity`` of the sine-jerk move (default
        :data:`DEFAULT_MOVE`).
    simulate_move : bool
        Skip the move simulation (empty arrays) when False.

    Returns
    -------
    TuningResult
    """
    from jerklab import controller as ctl

    t0 = time.perf_counter()
    K = as_positive("K", K)
    tau = as_positive("tau", tau)
    zeta = as_positive("zeta", zeta)
    wn = as_positive("wn", wn)
    sigma_ratio = as_positive("sigma_ratio", sigma_ratio)
    Ts = as_positive("Ts", Ts)
    if design not in ("continuous", "z-domain"):
        raise ValueError(f"design must be 'continuous' or 'z-domain', got {design!r}")
    sigma = sigma_ratio * wn

    g = None
    if design == "continuous":
        g = ctl.pole_placement_pid(K, tau, wn, zeta=zeta, sigma=sigma)
        d = g.discretize(Ts)
    else:
        d = ctl.discrete_pole_placement_pid(K, tau, wn, zeta=zeta, sigma=sigma, Ts=Ts)
    loop = ctl.PositionLoop(K, tau, d)
    poles_z = np.asarray(loop.poles_z(), dtype=complex)
    max_radius = float(loop.max_pole_radius())
    stable = bool(loop.is_stable())

    poles_s_desired = np.roots(np.polymul([1.0, sigma], [1.0, 2.0 * zeta * wn, wn * wn]))
    poles_z_desired = np.exp(poles_s_desired * Ts)
    desired_radius = float(np.max(np.abs(poles_z_desired)))
    poles_s_equivalent = np.asarray(loop.poles_s(), dtype=complex)
    poles_s_equivalent = poles_s_equivalent[np.isfinite(poles_s_equivalent)]   # z = 0 has no s image
    level, message = stability_verdict(max_radius, desired_radius, Ts, sigma)
    t1 = time.perf_counter()

    # step and disturbance responses of the linear sampled loop (controller's own recursions)
    # t_view: the span worth looking at (~12 time constants of the dominant pair); the
    # responses run 3x longer so a figure can keep a wider axis without a gap
    t_view = float(np.clip(12.0 / (min(zeta, 1.0) * wn), 0.2, 4.0))
    t_end = min(3.0 * t_view, 10.0)
    with np.errstate(over="ignore", invalid="ignore"):
        t_lin, y_step = loop.step_response(t_end)
        _, y_dist = loop.disturbance_response(t_end, amplitude=DISTURBANCE_VOLTS)
    t2 = time.perf_counter()

    # sine-jerk move on the full nonlinear simulation (PWM, saturation, encoder)
    if simulate_move:
        from jerklab.plant import DCMotor
        from jerklab.sim import simulate

        profile = _move_profile(dict(move or DEFAULT_MOVE))
        motor = DCMotor(K, tau)
        c = ctl.DigitalController(d, feedforward=ctl.Feedforward(K, tau),
                                  output_limit=motor.supply_voltage)
        r = simulate(profile, motor, c, Ts=Ts, t_end=profile.duration + 0.3)
        t_move = np.asarray(r.t, dtype=float)
        err_move = np.asarray(r.error, dtype=float)
        u_move = np.asarray(r.u, dtype=float)
    else:
        t_move = err_move = u_move = np.zeros(0)
    t3 = time.perf_counter()

    return TuningResult(
        params=dict(K=K, tau=tau, zeta=zeta, wn=wn, sigma_ratio=sigma_ratio, sigma=sigma, Ts=Ts,
                    design=design),
        gains=d, continuous_gains=g, poles_s_desired=poles_s_desired, poles_z=poles_z,
        poles_z_desired=poles_z_desired, poles_s_equivalent=poles_s_equivalent,
        max_radius=max_radius, desired_radius=desired_radius, stable=stable, level=level,
        message=message, t_step=t_lin, y_step=np.asarray(y_step), t_dist=t_lin,
        y_dist=np.asarray(y_dist), t_move=t_move, err_move=err_move, u_move=u_move,
        t_view=t_view,
        timings=dict(design=t1 - t0, responses=t2 - t1, move=t3 - t2),
    )


# --------------------------------------------------------------------------------------
# the figure: artists made once, data updated
# --------------------------------------------------------------------------------------
_LEVEL_COLORS = {"ok": "#1a7f37", "near": "#b35900", "unstable": "#c62828"}


_NICE_STEPS = (1.0, 2.0, 5.0, 10.0)


def nice_ceil(x):
    """Smallest number of the form m·10^k (m in 1, 2, 5) that is >= ``x`` > 0.

    Axis limits are rounded up this way so that most slider moves leave them unchanged
    and the figure can be redrawn by blitting only its data lines.
    """
    x = float(x)
    if not x > 0.0 or not math.isfinite(x):
        return 1.0
    k = math.floor(math.log10(x))
    for m in _NICE_STEPS:
        v = m * 10.0 ** k
        if v >= x * (1 - 1e-12):
            return v
    return 10.0 ** (k + 1)


def _nice_range(y, include=(), pad=0.06):
    """Axis limits covering ``y`` and ``include`` with nice bounds (0 kept as a bound)."""
    y = np.concatenate([np.asarray(y, dtype=float).ravel(), np.asarray(include, dtype=float)])
    y = y[np.isfinite(y)]
    if y.size == 0:
        return (-1.0, 1.0)
    lo, hi = float(np.min(y)), float(np.max(y))
    top = nice_ceil(hi) if hi > 0 else 0.0
    bot = -nice_ceil(-lo) if lo < 0 else 0.0
    if top == bot:
        top, bot = 1.0, -1.0
    span = top - bot
    return (bot - pad * span, top + pad * span)


class PolePlacementFigure:
    """One matplotlib figure with the six plots of the panel, redrawn by changing line data.

    The axes, ticks and labels are drawn once into a cached background; a redraw restores
    it and draws only the data lines and the title (blitting), unless a slider move changed
    an axis range (limits are rounded by :func:`nice_ceil`, so that is rare), which
    redraws everything once. The PNG is encoded from the Agg buffer.

    Parameters
    ----------
    figsize : (float, float)
        Inches.
    dpi : float
        Pixels per inch of the PNG.
    """

    def __init__(self, figsize=(11.0, 6.6), dpi=80):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.ticker import MaxNLocator

        self.fig = Figure(figsize=figsize, dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        ax = self.fig.subplots(2, 3)
        self.ax_s, self.ax_z, self.ax_step = ax[0]
        self.ax_dist, self.ax_err, self.ax_u = ax[1]
        self.dpi = dpi
        self._background = None
        self.full_redraws = 0

        a = self.ax_s
        a.axhline(0, color="0.7", lw=0.8)
        a.axvline(0, color="0.7", lw=0.8)
        (self.s_des,) = a.plot([], [], "x", ms=9, mew=2, color="C0", label="designed")
        (self.s_eq,) = a.plot([], [], "o", ms=7, mfc="none", mew=1.5, color="C3",
                              label="sampled loop, ln(z)/Ts")
        a.set_xlabel("Re s [1/s]")
        a.set_ylabel("Im s [rad/s]")
        a.set_title("Closed-loop poles in s", y=1.0)

        a = self.ax_z
        th = np.linspace(0, 2 * np.pi, 361)
        a.plot(np.cos(th), np.sin(th), color="0.5", lw=1)
        a.axhline(0, color="0.8", lw=0.8)
        a.axvline(0, color="0.8", lw=0.8)
        (self.z_des,) = a.plot([], [], "x", ms=9, mew=2, color="C0", label="designed exp(s Ts)")
        (self.z_ach,) = a.plot([], [], "o", ms=7, mfc="none", mew=1.5, color="C3",
                               label="sampled loop")
        a.set_aspect("equal", adjustable="box")
        a.set_xlabel("Re z [-]")
        a.set_ylabel("Im z [-]")
        a.set_title("Closed-loop poles in z", y=1.0)
        a.legend(loc="lower left", fontsize=7)

        a = self.ax_step
        a.axhline(1.0, color="0.6", lw=1, ls="--")
        (self.step_line,) = a.plot([], [], color="C0", drawstyle="steps-post")
        a.set_xlabel("time [s]")
        a.set_ylabel("position [rad]")
        a.set_title("Unit step response (no feedforward)", y=1.0)

        a = self.ax_dist
        a.axhline(0, color="0.7", lw=0.8)
        (self.dist_line,) = a.plot([], [], color="C1", drawstyle="steps-post")
        a.set_xlabel("time [s]")
        a.set_ylabel("position [mrad]")
        a.set_title(f"Step load disturbance {DISTURBANCE_VOLTS:g} V (eq. 9)", y=1.0)

        a = self.ax_err
        a.axhline(0, color="0.7", lw=0.8)
        (self.err_line,) = a.plot([], [], color="C2", drawstyle="steps-post", label="simulation")
        (self.rig_line,) = a.plot([], [], color="C4", drawstyle="steps-post", label="rig")
        a.set_xlabel("time [s]")
        a.set_ylabel("tracking error [mrad]")
        a.set_title("Sine-jerk move: tracking error", y=1.0)

        a = self.ax_u
        (self.u_line,) = a.plot([], [], color="C5", drawstyle="steps-post")
        a.axhline(12.0, color="0.6", lw=0.8, ls=":")
        a.axhline(-12.0, color="0.6", lw=0.8, ls=":")
        a.set_xlabel("time [s]")
        a.set_ylabel("voltage [V]")
        a.set_title("Sine-jerk move: control voltage", y=1.0)

        self.suptitle = self.fig.suptitle("", fontsize=11, fontweight="bold")
        self.fig.subplots_adjust(left=0.07, right=0.985, bottom=0.08, top=0.88, wspace=0.38,
                                 hspace=0.45)
        for a in self.fig.axes:
            a.xaxis.set_major_locator(MaxNLocator(5))
            a.yaxis.set_major_locator(MaxNLocator(5))
            # fixed label positions: matplotlib then skips measuring every tick label
            a.xaxis.set_label_coords(0.5, -0.13)
            a.yaxis.set_label_coords(-0.19, 0.5)
        self.ax_s.legend(handles=[self.s_des, self.s_eq], loc="upper left", fontsize=7)
        self._dynamic = [self.s_des, self.s_eq, self.z_des, self.z_ach, self.step_line,
                         self.dist_line, self.err_line, self.rig_line, self.u_line]
        for art in self._dynamic + [self.suptitle]:
            art.set_animated(True)
        from matplotlib.patches import Rectangle
        from matplotlib.transforms import IdentityTransform

        # paints over one axes (in pixels) before it is redrawn with new limits
        self._eraser = Rectangle((0, 0), 1, 1, transform=IdentityTransform(), animated=True,
                                 facecolor=self.fig.get_facecolor(), edgecolor="none")
        self.fig.add_artist(self._eraser)
        self._limits = {}
        self._drawn_limits = {}
        self._slots = self._axes_slots()
        self.axes_redraws = 0

    def _axes_slots(self):
        """Disjoint pixel rectangles (x0, y0, x1, y1), one per axes, each holding all it draws.

        Columns split just right of an axes' right spine (room for the last x tick label);
        rows split below the upper axes' x label. Repainting one slot never touches another
        axes' ticks, labels or title.
        """
        grid = [[self.ax_s, self.ax_z, self.ax_step], [self.ax_dist, self.ax_err, self.ax_u]]
        W, H = self.fig.bbox.width, self.fig.bbox.height
        pt = self.dpi / 72.0                                   # pixels per point
        box = {ax: ax.get_position(original=True).transformed(self.fig.transFigure)
               for row in grid for ax in row}
        cols = [max(box[grid[i][j]].x1 for i in range(2)) + 12 * pt for j in range(2)]
        upper = min(box[ax].y0 for ax in grid[0])
        h = min(box[ax].height for ax in grid[0])
        row = upper - 0.13 * h - 16 * pt                       # below the x label (10 pt)
        slots = {}
        for i in range(2):
            y0, y1 = (row, H) if i == 0 else (0.0, row)
            for j in range(3):
                x0 = 0.0 if j == 0 else cols[j - 1]
                x1 = W if j == 2 else cols[j]
                slots[grid[i][j]] = (x0, y0, x1, y1)
        return slots

    def _keep(self, ax, i, proposed, lo, hi, fill=0.3):
        """Keep axis ``i`` (0: x, 1: y) of ``ax`` if [lo, hi] still fits and fills ``fill`` of it.

        This hysteresis makes most slider moves leave every axis range unchanged, so the
        redraw is a blit of the data lines only.
        """
        prev = self._limits.get(ax)
        if prev is not None:
            plo, phi = prev[i]
            if plo <= lo and hi <= phi and (hi - lo) >= fill * (phi - plo):
                return prev[i]
        return proposed

    def update(self, res: TuningResult, rig_error=None):
        """Put the curves of ``res`` into the existing artists and choose the axis ranges."""
        p = res.params
        lim = {}
        self.s_des.set_data(res.poles_s_desired.real, res.poles_s_desired.imag)
        self.s_eq.set_data(res.poles_s_equivalent.real, res.poles_s_equivalent.imag)
        pts = np.concatenate([res.poles_s_desired, res.poles_s_equivalent])
        xr = max(float(np.max(np.abs(pts.real))), 1.0)
        yr = max(float(np.max(np.abs(pts.imag))), 0.25 * xr)
        nx, ny = nice_ceil(xr), nice_ceil(yr)
        lim[self.ax_s] = (self._keep(self.ax_s, 0, (-1.08 * nx, 0.25 * nx), -xr, 0.25 * xr, 0.4),
                          self._keep(self.ax_s, 1, (-1.1 * ny, 1.1 * ny), -yr, yr, 0.4))

        self.z_des.set_data(res.poles_z_desired.real, res.poles_z_desired.imag)
        self.z_ach.set_data(res.poles_z.real, res.poles_z.imag)
        rmax = float(np.max(np.abs(res.poles_z))) if res.poles_z.size else 1.0
        zr = 1.2 if rmax <= 1.1 else min(nice_ceil(1.1 * rmax), 5.0)
        lim[self.ax_z] = ((-zr, zr), (-zr, zr))

        t_need = float(res.t_view)
        t_lim = self._keep(self.ax_step, 0, (0.0, nice_ceil(t_need)), 0.0, t_need, 0.35)
        y = _clip_for_plot(res.y_step, 5.0)
        self.step_line.set_data(res.t_step, y)
        # past instability the responses only say "it diverges": fixed ranges (the clip
        # levels) instead of ranges chasing a growing oscillation
        diverges = res.level == "unstable"
        yv = np.concatenate([y[res.t_step <= t_lim[1]], [0.0, 1.0]])
        lim[self.ax_step] = (t_lim, (-5.3, 5.3) if diverges else self._keep(
            self.ax_step, 1, _nice_range(yv), yv.min(), yv.max()))

        yd = _clip_for_plot(1e3 * np.asarray(res.y_dist), CLIP_MRAD)
        self.dist_line.set_data(res.t_dist, yd)
        yv = np.concatenate([yd[res.t_dist <= t_lim[1]], [0.0]])
        lim[self.ax_dist] = (t_lim, (-1.06 * CLIP_MRAD, 1.06 * CLIP_MRAD) if diverges else
                             self._keep(self.ax_dist, 1, _nice_range(yv), yv.min(), yv.max()))

        t_mv = float(res.t_move[-1]) if res.t_move.size else 1.0
        e = _clip_for_plot(1e3 * res.err_move, CLIP_MRAD)
        self.err_line.set_data(res.t_move, e)
        ys = [e, [0.0]]
        if rig_error is not None:
            tr, er = rig_error
            er = _clip_for_plot(1e3 * np.asarray(er, dtype=float), CLIP_MRAD)
            self.rig_line.set_data(tr, er)
            ys.append(er)
            t_mv = max(t_mv, float(np.max(tr)) if np.size(tr) else t_mv)
        else:
            self.rig_line.set_data([], [])
        has_legend = self.ax_err.get_legend() is not None
        if (rig_error is not None) != has_legend:
            if rig_error is not None:
                self.ax_err.legend(handles=[self.err_line, self.rig_line], loc="upper right",
                                   fontsize=7)
            else:
                self.ax_err.get_legend().remove()
        ev = np.concatenate(ys)
        t_mlim = (0.0, nice_ceil(t_mv))
        lim[self.ax_err] = (t_mlim, (-1.06 * CLIP_MRAD, 1.06 * CLIP_MRAD) if diverges else
                            self._keep(self.ax_err, 1, _nice_range(ev), ev.min(), ev.max()),
                            rig_error is not None)

        u = _clip_for_plot(res.u_move, 1e3)
        self.u_line.set_data(res.t_move, u)
        um = max(float(np.max(np.abs(u))) if u.size else 1.0, 0.5)
        nu = nice_ceil(um)
        lim[self.ax_u] = (t_mlim, (-15.0, 15.0) if diverges else
                          self._keep(self.ax_u, 1, (-1.06 * nu, 1.06 * nu), -um, um))

        name = "eq. 11 + eq. 13" if p["design"] == "continuous" else "direct z-domain"
        self.suptitle.set_text(
            f"Stojčić position loop, {name}: ζ = {p['zeta']:.2f}, ωn = {p['wn']:.1f} rad/s, "
            f"σ = {p['sigma_ratio']:.1f}·ωn, Ts = {1e3 * p['Ts']:.2f} ms — max |z| = "
            f"{res.max_radius:.3f} ({res.level})")
        self.suptitle.set_color(_LEVEL_COLORS[res.level])
        self._limits = lim

    def _draw_dynamic(self, title=False):
        for art in self._dynamic:
            art.axes.draw_artist(art)
        if title:
            self.fig.draw_artist(self.suptitle)

    @staticmethod
    def _apply_limits(ax, key):
        ax.set_xlim(*key[0])
        ax.set_ylim(*key[1])

    def render(self, title=False):
        """Draw the current state into the Agg buffer.

        The first call draws everything but the data lines and caches the result. Later
        calls restore that background, redraw only the axes whose ranges changed (painting
        over their old extent first), and draw the data lines on top.
        """
        r = self.canvas.get_renderer()
        if self._background is None:
            for ax, key in self._limits.items():
                self._apply_limits(ax, key)
            self.canvas.draw()                      # animated artists are skipped
            self._drawn_limits = dict(self._limits)
            self._background = self.canvas.copy_from_bbox(self.fig.bbox)
            self.full_redraws += 1
        else:
            self.canvas.restore_region(self._background)
            todo = [ax for ax in self._limits if self._limits[ax] != self._drawn_limits.get(ax)]
            for ax in todo:
                self._apply_limits(ax, self._limits[ax])
                x0, y0, x1, y1 = self._slots[ax]
                self._eraser.set_bounds(x0, y0, x1 - x0, y1 - y0)
                self.fig.draw_artist(self._eraser)
                ax.draw(r)
                self._drawn_limits[ax] = self._limits[ax]
                self.axes_redraws += 1
            if todo:
                self._background = self.canvas.copy_from_bbox(self.fig.bbox)
        self._draw_dynamic(title)

    def png(self, compress_level=1, title=False):
        """Render and return the PNG bytes (Pillow, fast compression).

        ``title=True`` adds the parameter line as a figure title (for the static copy).
        """
        from PIL import Image

        self.render(title=title)
        w, h = self.canvas.get_width_height()
        img = Image.frombuffer("RGBA", (w, h), self.canvas.buffer_rgba(), "raw", "RGBA", 0, 1)
        buf = io.BytesIO()
        img.convert("RGB").save(buf, format="png", compress_level=compress_level)
        return buf.getvalue()

    def savefig(self, path, **kwargs):
        """Save the whole figure, data and title included (:meth:`Figure.savefig`).

        Axes draw their animated artists (the data lines) when saving; the figure does not,
        so the title is switched to a normal artist meanwhile. The cached background is
        dropped (the canvas may have changed size).
        """
        for ax, key in self._limits.items():
            self._apply_limits(ax, key)
        self.suptitle.set_animated(False)
        try:
            self.fig.savefig(path, **kwargs)
        finally:
            self.suptitle.set_animated(True)
            self._background = None


# --------------------------------------------------------------------------------------
# the widget
# --------------------------------------------------------------------------------------
def _panel_base():
    import ipywidgets as widgets

    return widgets.VBox


class PolePlacementPanel(_panel_base()):
    """The pole-placement tuning panel (an :class:`ipywidgets.VBox`).

    Build it with :func:`pole_placement_panel`. Attributes for scripts and tests:
    ``controls`` (dict of the widgets by name: ``zeta, wn, sigma_ratio, Ts_ms, design``),
    ``image`` (the :class:`ipywidgets.Image` holding the figure), ``status`` (the warning),
    ``result`` (the last :class:`TuningResult`), ``last_redraw_s`` (seconds spent by the
    last recompute + redraw), ``error`` (the last exception text or None).
    """

    def __init__(self, K=32.4, tau=0.025, zeta=1.0, wn=20.0, sigma_ratio=7.0, Ts=0.005,
                 design="continuous", move=None, rig=None, dpi=80):
        import ipywidgets as widgets

        self.K = as_positive("K", K)
        self.tau = as_positive("tau", tau)
        self.move = dict(move or DEFAULT_MOVE)
        self.rig = rig
        self.result = None
        self.error = None
        self.last_redraw_s = float("nan")
        self._rig_error = None
        self._png = b""

        style = {"description_width": "70px"}
        layout = widgets.Layout(width="330px")
        c = dict(
            zeta=widgets.FloatSlider(value=as_positive("zeta", zeta), min=0.3, max=2.0, step=0.05,
                                     description="ζ", readout_format=".2f",
                                     continuous_update=False, style=style, layout=layout),
            wn=widgets.FloatSlider(value=as_positive("wn", wn), min=2.0, max=100.0, step=1.0,
                                   description="ωn [rad/s]", readout_format=".0f",
                                   continuous_update=False, style=style, layout=layout),
            sigma_ratio=widgets.FloatSlider(value=as_positive("sigma_ratio", sigma_ratio), min=1.0,
                                            max=15.0, step=0.5, description="σ / ωn",
                                            readout_format=".1f", continuous_update=False,
                                            style=style, layout=layout),
            Ts_ms=widgets.FloatSlider(value=1e3 * as_positive("Ts", Ts), min=1.0, max=20.0,
                                      step=1.0, description="Ts [ms]", readout_format=".1f",
                                      continuous_update=False, style=style, layout=layout),
            design=widgets.ToggleButtons(options=list(DESIGNS.items()),
                                         value=design if design in DESIGNS.values() else None,
                                         description="design", style={"button_width": "300px",
                                                                      **style}),
        )
        if c["design"].value is None:
            raise ValueError(f"design must be one of {sorted(DESIGNS.values())}, got {design!r}")
        self.controls = c
        for w in c.values():
            w.add_class("jerklab-control")
        self.status = widgets.HTML(layout=widgets.Layout(width="100%"))
        self.status.add_class("jerklab-status")
        self.timing = widgets.HTML()
        self.timing.add_class("jerklab-timing")
        self.figure = PolePlacementFigure(dpi=dpi)
        width_px = self.figure.canvas.get_width_height()[0]
        # shown at its own pixel size (no blurry upscaling), narrower on a small screen
        self.image = widgets.Image(format="png", layout=widgets.Layout(width=f"{width_px}px",
                                                                       max_width="100%"))
        self.image.add_class("jerklab-figure")

        rows = [widgets.HBox([widgets.VBox([c["zeta"], c["wn"]]),
                              widgets.VBox([c["sigma_ratio"], c["Ts_ms"]])]),
                c["design"]]
        if rig is not None:
            self.rig_button = widgets.Button(description="Run this move on the rig",
                                             button_style="primary", icon="play",
                                             layout=widgets.Layout(width="260px"))
            self.rig_button.add_class("jerklab-rig-button")
            self.rig_status = widgets.HTML()
            self.rig_status.add_class("jerklab-rig-status")
            self.rig_button.on_click(self._run_on_rig)
            rows.append(widgets.HBox([self.rig_button, self.rig_status]))
        super().__init__(rows + [self.status, self.image, self.timing])
        self.add_class("jerklab-panel")

        for w in c.values():
            w.observe(self._on_change, names="value")
        self.update()

    # -- parameters ------------------------------------------------------------------
    def params(self):
        """The current slider values as keyword arguments of :func:`compute_pole_placement`."""
        c = self.controls
        return dict(K=self.K, tau=self.tau, zeta=c["zeta"].value, wn=c["wn"].value,
                    sigma_ratio=c["sigma_ratio"].value, Ts=c["Ts_ms"].value * 1e-3,
                    design=c["design"].value, move=self.move)

    def _on_change(self, change):
        self._rig_error = None
        self.update()

    def update(self):
        """Recompute the design for the current sliders and redraw the figure in place.

        An error is shown in the panel (red box, class ``jerklab-error``) and re-raised.
        """
        t0 = time.perf_counter()
        try:
            res = compute_pole_placement(**self.params())
            t1 = time.perf_counter()
            self.figure.update(res, self._rig_error)
            png = self.figure.png()
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            self.status.value = (
                '<div class="jerklab-error" style="background:#fdecea;color:#b71c1c;'
                'border:2px solid #c62828;padding:6px;font-weight:bold">'
                f"Panel error — {_html_escape(self.error)}</div>")
            self.status.add_class("jerklab-error")
            raise
        self.error = None
        self.status.remove_class("jerklab-error")
        self.result = res
        self._png = png
        self.image.value = png
        self.status.value = _status_html(res)
        self.last_redraw_s = time.perf_counter() - t0
        self.timing.value = (
            f'<span style="color:#666;font-size:90%">redraw {1e3 * self.last_redraw_s:.0f} ms '
            f"(design {1e3 * res.timings['design']:.0f}, responses "
            f"{1e3 * res.timings['responses']:.0f}, move {1e3 * res.timings['move']:.0f}, "
            f"figure {1e3 * (self.last_redraw_s - (t1 - t0)):.0f})</span>")
        return res

    # -- the rig -----------------------------------------------------------------------
    def _run_on_rig(self, _button=None):
        """Run the current move with the current discrete gains on the rig, overlay the error."""
        try:
            self.rig_button.disabled = True
            self.rig_status.value = "running…"
            res = self.result
            profile = _move_profile(self.move)
            rec = self.rig.run_move(profile, res.gains, Ts=res.params["Ts"], path=False,
                                    progress=False)   # the panel shows its own status
            t = np.asarray(rec.time, dtype=float)
            err = np.asarray(rec.reference, dtype=float) - np.asarray(rec.position, dtype=float)
            self._rig_error = (t, err)
            self.figure.update(res, self._rig_error)
            self._png = self.figure.png()
            self.image.value = self._png
            self.rig_status.value = (
                f"rig: max |error| = {1e3 * float(np.max(np.abs(err))):.2f} mrad over "
                f"{t.size} samples")
        except Exception as exc:
            self.rig_status.value = (
                '<span class="jerklab-error" style="color:#b71c1c;font-weight:bold">rig error — '
                f"{_html_escape(f'{type(exc).__name__}: {exc}')}</span>")
            raise
        finally:
            self.rig_button.disabled = False

    def run_on_rig(self):
        """Script form of the "Run this move on the rig" button; returns the tracking error."""
        if self.rig is None:
            raise ValueError("rig: this panel was built without a rig (pole_placement_panel(rig=...))")
        self._run_on_rig()
        return self._rig_error

    # -- static fallback ---------------------------------------------------------------
    def png(self):
        """PNG bytes of the figure currently shown."""
        return self._png

    def _repr_mimebundle_(self, **kwargs):
        """Widget view plus a PNG of the current figure for front ends without widgets."""
        data = super()._repr_mimebundle_(**kwargs)
        if data is None:
            data = {"text/plain": repr(self)}
        if self.result is not None:
            data["image/png"] = base64.b64encode(self.figure.png(title=True)).decode("ascii")
        return data


def _html_escape(s):
    import html

    return html.escape(str(s))


def _status_html(res):
    color = _LEVEL_COLORS[res.level]
    bg = {"ok": "#e8f5e9", "near": "#fff3e0", "unstable": "#fdecea"}[res.level]
    icon = {"ok": "✔", "near": "⚠", "unstable": "⛔"}[res.level]
    g = res.gains
    gains = f"kpd = {g.kpd:.4g}, kid = {g.kid:.4g}, kdd = {g.kdd:.4g} (V/rad)"
    return (f'<div class="jerklab-verdict jerklab-{res.level}" style="background:{bg};'
            f'color:{color};border-left:6px solid {color};padding:4px 8px">'
            f"<b>{icon} {_html_escape(res.message)}</b><br>"
            f'<span style="color:#333">{gains}</span></div>')


def pole_placement_panel(K=32.4, tau=0.025, *, zeta=1.0, wn=20.0, sigma_ratio=7.0, Ts=0.005,
                         design="continuous", move=None, rig=None, dpi=80):
    """The interactive pole-placement tuning panel of notebook 03 and the class page.

    Sliders for ζ, ωn, σ/ωn and Ts and a choice of design (Stojčić eq. 11 discretized by
    eq. 12-13, or the direct z-domain design); one figure with the closed-loop poles in s
    and z, the unit-step and step-disturbance (eq. 9) responses of the sampled loop, and
    the tracking error and voltage of a sine-jerk move simulated with the rig's
    imperfections; a coloured verdict that turns orange near and red past instability.

    Parameters
    ----------
    K, tau : float
        Plant of eq. 1 (defaults: the paper's identified motor).
    zeta, wn, sigma_ratio, Ts, design
        Initial values (see :func:`compute_pole_placement`).
    move : dict, optional
        The sine-jerk move (default :data:`DEFAULT_MOVE`).
    rig : object, optional
        A rig from :func:`jerklab.rig.connect`; adds a "Run this move on the rig" button that
        calls ``rig.run_move(profile, gains, Ts)`` and overlays the measured tracking error.
    dpi : float
        Resolution of the figure.

    Returns
    -------
    PolePlacementPanel
        An ``ipywidgets.VBox``. Displaying it shows the live panel where widgets render
        and the default-value figure (PNG) where they do not (headless execution).

    Examples
    --------
    >>> from jerklab.widgets import pole_placement_panel
    >>> panel = pole_placement_panel()            # doctest: +SKIP
    >>> panel.controls["wn"].value = 50           # doctest: +SKIP
    >>> panel.result.level                        # doctest: +SKIP
    'unstable'
    """
    return PolePlacementPanel(K=K, tau=tau, zeta=zeta, wn=wn, sigma_ratio=sigma_ratio, Ts=Ts,
                              design=design, move=move, rig=rig, dpi=dpi)
