"""Interactive tuning panels for the notebooks and the standalone class page (issue 9).

Stojčić (ASCII: Stojcic) position loop, plant of Stojčić eq. 1.

:func:`pole_placement_panel` builds the pole-placement tuning panel of
``notebooks/03_pole_placement.ipynb`` and of the standalone page served by
``python -m jerklab.app``: sliders for ζ, ωn, σ (as a multiple of ωn) and Ts, a choice
between the paper's continuous design (Stojčić eq. 11, discretized by Stojčić eq. 13), the
direct z-domain design and the z-domain design with a derivative filter, and one figure
with the poles in s and z, the step and disturbance responses, the tracking error and the
voltage of a sine-jerk move.

This module only builds widgets and draws; every number comes from :mod:`jerklab.tuning`
(design, stability, advice, simulation, units), which needs neither ipywidgets nor
matplotlib.

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
* On a phone (``narrow_figure=True``, the class page) a second, narrow figure (3 rows of 2
  plots, 384 px wide) is drawn beside the wide one and CSS shows the one that fits the
  screen, so tick labels stay at their drawn size instead of being scaled down.
* The panel's rich representation carries, beside the widget view, a ``image/png`` of the
  current figure, so headless execution (nbclient, nbconvert, a notebook viewer) keeps the
  default-value figure, while a widget front end shows the live panel.
"""

from __future__ import annotations

import base64
import hashlib
import html
import io
import math
import re
import time
import unicodedata
import warnings
from pathlib import Path

import numpy as np

from jerklab import paper, tuning
from jerklab._validate import as_positive
from jerklab.broker import unique_run_name
from jerklab.controller import Feedforward
from jerklab.rig.recording import recordings_dir
from jerklab.tuning import (
    CLIP_MRAD,
    DEFAULT_MOVE,
    DESIGNS,
    DISTURBANCE_VOLTS,
    TuningResult,
    angle_unit,
    format_angle,
    stability_verdict,
)

__all__ = [
    "DESIGNS",
    "TuningResult",
    "compute_pole_placement",
    "stability_verdict",
    "sanitize_student_id",
    "PolePlacementFigure",
    "PolePlacementPanel",
    "pole_placement_panel",
]


def compute_pole_placement(*args, **kwargs):
    """Deprecated alias of :func:`jerklab.tuning.compute_pole_placement` (moved there)."""
    warnings.warn(
        "jerklab.widgets.compute_pole_placement moved to jerklab.tuning.compute_pole_placement",
        DeprecationWarning,
        stacklevel=2,
    )
    return tuning.compute_pole_placement(*args, **kwargs)


def _clip_for_plot(y, scale):
    """Keep a diverging response plottable: clip to ±``scale``, NaN/inf -> clipped."""
    y = np.nan_to_num(np.asarray(y, dtype=float), nan=0.0, posinf=scale, neginf=-scale)
    return np.clip(y, -scale, scale)


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
        v = m * 10.0**k
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


#: Figure geometry of the two layouts: grid of the six plots, size (inches), ticks per axis,
#: label offsets (axes fractions) and subplot margins.
_LAYOUTS = {
    "wide": dict(
        grid=(("s", "z", "step"), ("dist", "err", "u")),
        figsize=(11.0, 6.6),
        ticks=5,
        xlabel=-0.13,
        ylabel=-0.19,
        font=10.0,
        title=11.0,
        adjust=dict(left=0.07, right=0.985, bottom=0.08, top=0.88, wspace=0.38, hspace=0.45),
    ),
    "narrow": dict(
        grid=(("s", "z"), ("step", "dist"), ("err", "u")),
        figsize=(4.8, 8.0),
        ticks=4,
        xlabel=-0.17,
        ylabel=-0.34,
        font=8.5,
        title=8.5,
        adjust=dict(left=0.17, right=0.975, bottom=0.065, top=0.96, wspace=0.62, hspace=0.55),
    ),
}

_TITLES = {
    "wide": dict(
        s="Closed-loop poles in s",
        z="Closed-loop poles in z",
        step="Unit step response (no feedforward)",
        dist=f"Step load disturbance {DISTURBANCE_VOLTS:g} V (Stojčić eq. 9)",
        err="Sine-jerk move: tracking error",
        u="Sine-jerk move: control voltage",
    ),
    "narrow": dict(
        s="Poles in s",
        z="Poles in z",
        step="Unit step",
        dist=f"{DISTURBANCE_VOLTS:g} V load step",
        err="Move: tracking error",
        u="Move: voltage",
    ),
}


class PolePlacementFigure:
    """One matplotlib figure with the six plots of the panel, redrawn by changing line data.

    The axes, ticks and labels are drawn once into a cached background; a redraw restores
    it and draws only the data lines and the title (blitting), unless a slider move changed
    an axis range or unit (limits are rounded by :func:`nice_ceil`, so that is rare), which
    redraws that axes once. The PNG is encoded from the Agg buffer.

    Angles are shown in mrad below 1 rad and in rad above (:func:`jerklab.tuning.angle_unit`).
    The tracking-error plot shows reference − encoder reading for the simulation and for the
    rig alike, the quantity a rig can measure.

    Parameters
    ----------
    figsize : (float, float), optional
        Inches (default: the layout's).
    dpi : float
        Pixels per inch of the PNG.
    layout : {"wide", "narrow"}
        Two rows of three plots (a screen), or three rows of two (a phone, 384 px wide).
    """

    def __init__(self, figsize=None, dpi=80, layout="wide"):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.ticker import MaxNLocator

        if layout not in _LAYOUTS:
            raise ValueError(f"layout must be one of {sorted(_LAYOUTS)}, got {layout!r}")
        L = _LAYOUTS[layout]
        self.layout = layout
        self.fig = Figure(figsize=figsize or L["figsize"], dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        rows, cols = len(L["grid"]), len(L["grid"][0])
        ax = self.fig.subplots(rows, cols)
        by_name = {name: ax[i][j] for i, row in enumerate(L["grid"]) for j, name in enumerate(row)}
        self.ax_s, self.ax_z, self.ax_step = by_name["s"], by_name["z"], by_name["step"]
        self.ax_dist, self.ax_err, self.ax_u = by_name["dist"], by_name["err"], by_name["u"]
        self._grid = [[by_name[n] for n in row] for row in L["grid"]]
        self.dpi = dpi
        self._background = None
        self.full_redraws = 0
        T = _TITLES[layout]
        fs = L["font"]
        small = max(fs - 3, 6.5)

        a = self.ax_s
        a.axhline(0, color="0.7", lw=0.8)
        a.axvline(0, color="0.7", lw=0.8)
        (self.s_des,) = a.plot([], [], "x", ms=9, mew=2, color="C0", label="designed")
        (self.s_eq,) = a.plot(
            [], [], "o", ms=7, mfc="none", mew=1.5, color="C3", label="sampled loop, ln(z)/Ts"
        )
        a.set_xlabel("Re s [1/s]")
        a.set_ylabel("Im s [rad/s]")
        a.set_title(T["s"], y=1.0)

        a = self.ax_z
        th = np.linspace(0, 2 * np.pi, 361)
        a.plot(np.cos(th), np.sin(th), color="0.5", lw=1)
        a.axhline(0, color="0.8", lw=0.8)
        a.axvline(0, color="0.8", lw=0.8)
        (self.z_des,) = a.plot([], [], "x", ms=9, mew=2, color="C0", label="designed exp(s Ts)")
        (self.z_ach,) = a.plot(
            [], [], "o", ms=7, mfc="none", mew=1.5, color="C3", label="sampled loop"
        )
        a.set_aspect("equal", adjustable="box")
        a.set_xlabel("Re z [-]")
        a.set_ylabel("Im z [-]")
        a.set_title(T["z"], y=1.0)
        if layout == "wide":
            a.legend(loc="lower left", fontsize=7)

        a = self.ax_step
        a.axhline(1.0, color="0.6", lw=1, ls="--")
        (self.step_line,) = a.plot([], [], color="C0", drawstyle="steps-post")
        a.set_xlabel("time [s]")
        a.set_ylabel("position [rad]")
        a.set_title(T["step"], y=1.0)

        a = self.ax_dist
        a.axhline(0, color="0.7", lw=0.8)
        (self.dist_line,) = a.plot([], [], color="C1", drawstyle="steps-post")
        a.set_xlabel("time [s]")
        a.set_ylabel("position [mrad]")
        a.set_title(T["dist"], y=1.0)

        a = self.ax_err
        a.axhline(0, color="0.7", lw=0.8)
        (self.err_line,) = a.plot([], [], color="C2", drawstyle="steps-post", label="simulation")
        (self.rig_line,) = a.plot([], [], color="C4", drawstyle="steps-post", label="rig")
        a.set_xlabel("time [s]")
        a.set_ylabel("ref. − encoder [mrad]")
        a.set_title(T["err"], y=1.0)

        a = self.ax_u
        (self.u_line,) = a.plot([], [], color="C5", drawstyle="steps-post")
        a.axhline(paper.SUPPLY_VOLTAGE, color="0.6", lw=0.8, ls=":")
        a.axhline(-paper.SUPPLY_VOLTAGE, color="0.6", lw=0.8, ls=":")
        a.set_xlabel("time [s]")
        a.set_ylabel("voltage [V]")
        a.set_title(T["u"], y=1.0)

        self.suptitle = self.fig.suptitle("", fontsize=L["title"], fontweight="bold")
        self.fig.subplots_adjust(**L["adjust"])
        for a in self.fig.axes:
            a.xaxis.set_major_locator(MaxNLocator(L["ticks"]))
            a.yaxis.set_major_locator(MaxNLocator(L["ticks"]))
            a.tick_params(labelsize=fs)
            a.xaxis.label.set_size(fs)
            a.yaxis.label.set_size(fs)
            a.title.set_size(fs + 1)
            # fixed label positions: matplotlib then skips measuring every tick label
            a.xaxis.set_label_coords(0.5, L["xlabel"])
            a.yaxis.set_label_coords(L["ylabel"], 0.5)
        self.ax_s.legend(handles=[self.s_des, self.s_eq], loc="upper left", fontsize=small)
        self._dynamic = [
            self.s_des,
            self.s_eq,
            self.z_des,
            self.z_ach,
            self.step_line,
            self.dist_line,
            self.err_line,
            self.rig_line,
            self.u_line,
        ]
        for art in self._dynamic + [self.suptitle]:
            art.set_animated(True)
        from matplotlib.patches import Rectangle
        from matplotlib.transforms import IdentityTransform

        # paints over one axes (in pixels) before it is redrawn with new limits
        self._eraser = Rectangle(
            (0, 0),
            1,
            1,
            transform=IdentityTransform(),
            animated=True,
            facecolor=self.fig.get_facecolor(),
            edgecolor="none",
        )
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
        grid = self._grid
        R, C = len(grid), len(grid[0])
        W, H = self.fig.bbox.width, self.fig.bbox.height
        pt = self.dpi / 72.0  # pixels per point
        box = {
            ax: ax.get_position(original=True).transformed(self.fig.transFigure)
            for row in grid
            for ax in row
        }
        cols = [max(box[grid[i][j]].x1 for i in range(R)) + 12 * pt for j in range(C - 1)]
        xl = -_LAYOUTS[self.layout]["xlabel"]
        rows = []
        for i in range(R - 1):
            lower = min(box[ax].y0 for ax in grid[i])
            h = min(box[ax].height for ax in grid[i])
            rows.append(lower - xl * h - 16 * pt)  # below the x label
        slots = {}
        for i in range(R):
            y1 = H if i == 0 else rows[i - 1]
            y0 = 0.0 if i == R - 1 else rows[i]
            for j in range(C):
                x0 = 0.0 if j == 0 else cols[j - 1]
                x1 = W if j == C - 1 else cols[j]
                slots[grid[i][j]] = (x0, y0, x1, y1)
        return slots

    def _keep(self, ax, i, proposed, lo, hi, fill=0.3):
        """Keep axis ``i`` (0: x, 1: y) of ``ax`` if [lo, hi] still fits and fills ``fill`` of it.

        This hysteresis makes most slider moves leave every axis range unchanged, so the
        redraw is a blit of the data lines only. A change of unit never keeps the range.
        """
        prev = self._limits.get(ax)
        if prev is not None and prev[-1] == self._unit_now.get(ax):
            plo, phi = prev[i]
            if plo <= lo and hi <= phi and (hi - lo) >= fill * (phi - plo):
                return prev[i]
        return proposed

    def update(self, res: TuningResult, rig_error=None):
        """Put the curves of ``res`` into the existing artists and choose the axis ranges.

        ``rig_error`` is ``(t, reference − encoder angle)`` of a rig run (s, rad), or None.
        """
        p = res.params
        lim = {}
        self._unit_now = {}
        self.s_des.set_data(res.poles_s_desired.real, res.poles_s_desired.imag)
        self.s_eq.set_data(res.poles_s_equivalent.real, res.poles_s_equivalent.imag)
        pts = np.concatenate([res.poles_s_desired, res.poles_s_equivalent])
        xr = max(float(np.max(np.abs(pts.real))), 1.0)
        yr = max(float(np.max(np.abs(pts.imag))), 0.25 * xr)
        nx, ny = nice_ceil(xr), nice_ceil(yr)
        lim[self.ax_s] = (
            self._keep(self.ax_s, 0, (-1.08 * nx, 0.25 * nx), -xr, 0.25 * xr, 0.4),
            self._keep(self.ax_s, 1, (-1.1 * ny, 1.1 * ny), -yr, yr, 0.4),
            None,
        )

        self.z_des.set_data(res.poles_z_desired.real, res.poles_z_desired.imag)
        self.z_ach.set_data(res.poles_z.real, res.poles_z.imag)
        rmax = float(np.max(np.abs(res.poles_z))) if res.poles_z.size else 1.0
        zr = 1.2 if rmax <= 1.1 else min(nice_ceil(1.1 * rmax), 5.0)
        lim[self.ax_z] = ((-zr, zr), (-zr, zr), None)

        t_need = float(res.t_view)
        t_lim = self._keep(self.ax_step, 0, (0.0, nice_ceil(t_need)), 0.0, t_need, 0.35)
        y = _clip_for_plot(res.y_step, 5.0)
        self.step_line.set_data(res.t_step, y)
        # past instability the responses only say "it diverges": fixed ranges (the clip
        # levels) instead of ranges chasing a growing oscillation
        diverges = res.level == "unstable"
        yv = np.concatenate([y[res.t_step <= t_lim[1]], [0.0, 1.0]])
        lim[self.ax_step] = (
            t_lim,
            (-5.3, 5.3)
            if diverges
            else self._keep(self.ax_step, 1, _nice_range(yv), yv.min(), yv.max()),
            None,
        )

        clip = CLIP_MRAD * 1e-3  # rad
        yd = _clip_for_plot(res.y_dist, clip)
        f, unit = angle_unit(np.max(np.abs(yd[res.t_dist <= t_lim[1]]), initial=0.0))
        self._unit_now[self.ax_dist] = unit
        yd = f * yd
        self.dist_line.set_data(res.t_dist, yd)
        yv = np.concatenate([yd[res.t_dist <= t_lim[1]], [0.0]])
        lim[self.ax_dist] = (
            t_lim,
            (-1.06 * clip * f, 1.06 * clip * f)
            if diverges
            else self._keep(self.ax_dist, 1, _nice_range(yv), yv.min(), yv.max()),
            unit,
        )

        t_mv = float(res.t_move[-1]) if res.t_move.size else 1.0
        e = _clip_for_plot(res.err_move_measured, clip)
        ys = [e, [0.0]]
        er = None
        if rig_error is not None:
            tr, er = rig_error
            er = _clip_for_plot(er, clip)
            ys.append(er)
            t_mv = max(t_mv, float(np.max(tr)) if np.size(tr) else t_mv)
        f, unit = angle_unit(max(float(np.max(np.abs(v), initial=0.0)) for v in ys))
        self._unit_now[self.ax_err] = unit
        self.err_line.set_data(res.t_move, f * e)
        if er is not None:
            self.rig_line.set_data(tr, f * er)
        else:
            self.rig_line.set_data([], [])
        has_legend = self.ax_err.get_legend() is not None
        if (rig_error is not None) != has_legend:
            if rig_error is not None:
                self.ax_err.legend(
                    handles=[self.err_line, self.rig_line], loc="upper right", fontsize=7
                )
            else:
                self.ax_err.get_legend().remove()
        ev = f * np.concatenate([np.asarray(v, dtype=float) for v in ys])
        t_mlim = (0.0, nice_ceil(t_mv))
        lim[self.ax_err] = (
            t_mlim,
            (-1.06 * clip * f, 1.06 * clip * f)
            if diverges
            else self._keep(self.ax_err, 1, _nice_range(ev), ev.min(), ev.max()),
            rig_error is not None,
            unit,
        )

        u = _clip_for_plot(res.u_move, 1e3)
        self.u_line.set_data(res.t_move, u)
        um = max(float(np.max(np.abs(u))) if u.size else 1.0, 0.5)
        nu = nice_ceil(um)
        lim[self.ax_u] = (
            t_mlim,
            (-15.0, 15.0)
            if diverges
            else self._keep(self.ax_u, 1, (-1.06 * nu, 1.06 * nu), -um, um),
            None,
        )

        name = {
            "continuous": "Stojčić eq. 11 + Stojčić eq. 13",
            "z-domain": "direct z-domain",
            "z-domain-filter": "z-domain + γ filter",
        }[p["design"]]
        if self.layout == "wide":
            self.suptitle.set_text(
                f"{name}: ζ = {p['zeta']:.2f}, ωn = {p['wn']:.1f} rad/s, "
                f"σ = {p['sigma_ratio']:.1f}·ωn, Ts = {1e3 * p['Ts']:.2f} ms — max |z| = "
                f"{res.max_radius:.3f} ({res.level})"
            )
        else:
            self.suptitle.set_text(
                f"{name}: ζ = {p['zeta']:.2f}, ωn = {p['wn']:.0f} rad/s,\n"
                f"σ = {p['sigma_ratio']:.1f}·ωn, Ts = {1e3 * p['Ts']:.0f} ms — max |z| = "
                f"{res.max_radius:.3f} ({res.level})"
            )
        self.suptitle.set_color(_LEVEL_COLORS[res.level])
        self._limits = lim

    def _draw_dynamic(self, title=False):
        for art in self._dynamic:
            art.axes.draw_artist(art)
        if title:
            self.fig.draw_artist(self.suptitle)

    _ANGLE_LABELS = {"dist": "position [{}]", "err": "ref. − encoder [{}]"}

    def _apply_limits(self, ax, key):
        ax.set_xlim(*key[0])
        ax.set_ylim(*key[1])
        unit = key[-1]
        if ax is self.ax_dist and unit:
            ax.set_ylabel(self._ANGLE_LABELS["dist"].format(unit))
        elif ax is self.ax_err and unit:
            ax.set_ylabel(self._ANGLE_LABELS["err"].format(unit))

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
            self.canvas.draw()  # animated artists are skipped
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
#: Windows refuses these as file names (with any extension).
_WINDOWS_RESERVED = {
    "CON",
    "PRN",
    "AUX",
    "NUL",
    *(f"COM{i}" for i in range(1, 10)),
    *(f"LPT{i}" for i in range(1, 10)),
}


def sanitize_student_id(student_id, max_length=48):
    """A folder name for a student ID, valid on Windows, macOS and Linux.

    Accents are dropped (``"Stojčić"`` -> ``"Stojcic"``), anything but ASCII letters, digits,
    ``-``, ``_`` and ``.`` becomes ``_``, leading and trailing dots, spaces and underscores
    go, Windows' reserved names (``CON``, ``NUL``, ``COM1``, ...) get a leading ``_`` and the
    length is capped. If any of that changed the ID, a short hash of the original is
    appended, so two different IDs never share a folder.

    Raises
    ------
    ValueError
        ``student_id`` is empty (or only spaces).
    TypeError
        ``student_id`` is not a string.
    """
    if not isinstance(student_id, str):
        raise TypeError(f"student_id must be a string, got {type(student_id).__name__}")
    raw = student_id.strip()
    if not raw:
        raise ValueError("student_id is empty: enter your student ID")
    ascii_ = unicodedata.normalize("NFKD", raw).encode("ascii", "ignore").decode("ascii")
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", ascii_).strip(" ._")
    if name.split(".")[0].upper() in _WINDOWS_RESERVED:
        name = "_" + name
    name = name[:max_length]
    if name != raw:
        digest = hashlib.sha1(raw.encode("utf-8")).hexdigest()[:6]
        name = f"{name}-{digest}" if name else f"id-{digest}"
    return name


#: CSS of the panel: sliders wrap (one column on a phone, readouts visible), the design
#: buttons wrap, and the wide or the narrow figure is shown, whichever fits the screen.
_PANEL_CSS = """<style>
.jerklab-sliders { display: flex; flex-flow: row wrap; gap: 0 12px; }
.jerklab-panel .jerklab-control.widget-slider { max-width: 100%; }
.jerklab-design { flex-wrap: wrap; max-width: 100%; }
.jerklab-design .widget-toggle-button { max-width: 100%; white-space: normal; height: auto;
  min-height: var(--jp-widgets-inline-height, 28px); }
.jerklab-design > div { flex-wrap: wrap; }
.jerklab-rig-row { flex-wrap: wrap; align-items: center; }
.jerklab-figure-narrow { display: none !important; }
@media (max-width: 640px) {
  .jerklab-panel .jerklab-control.widget-slider { width: 100% !important; }
  .jerklab-design .widget-toggle-button { width: 100% !important; }
  .jerklab-panel.jerklab-has-narrow .jerklab-figure { display: none !important; }
  .jerklab-panel.jerklab-has-narrow .jerklab-figure-narrow { display: block !important; }
}
</style>"""


def _panel_base():
    import ipywidgets as widgets

    return widgets.VBox


class PolePlacementPanel(_panel_base()):
    """The pole-placement tuning panel (an :class:`ipywidgets.VBox`).

    Build it with :func:`pole_placement_panel`. Attributes for scripts and tests:
    ``controls`` (dict of the widgets by name: ``zeta, wn, sigma_ratio, Ts_ms, design``),
    ``gains`` (the discrete gains of the current design, what ``rig.run_move`` accepts),
    ``image`` (the :class:`ipywidgets.Image` holding the figure; ``image_narrow`` the phone
    figure or None), ``status`` (the verdict, advice and gains), ``result`` (the last
    :class:`~jerklab.tuning.TuningResult`), ``last_redraw_s`` (seconds spent by the last
    recompute + redraw), ``error`` (the last exception text or None), ``student`` (the
    student ID field or None), ``last_recording`` (the last rig run's Recording).
    """

    def __init__(
        self,
        K=paper.MOTOR_K,
        tau=paper.MOTOR_TAU,
        zeta=paper.ZETA,
        wn=20.0,
        sigma_ratio=paper.SIGMA_RATIO,
        Ts=paper.TS,
        design="continuous",
        move=None,
        rig=None,
        dpi=80,
        student=False,
        narrow_figure=False,
        recordings=None,
    ):
        import ipywidgets as widgets

        self.K = as_positive("K", K)
        self.tau = as_positive("tau", tau)
        self.move = dict(move or DEFAULT_MOVE)
        tuning.move_profile(self.move)  # a bad move fails here, named
        self.rig = rig
        self.recordings = recordings
        self.result = None
        self.error = None
        self.last_redraw_s = float("nan")
        self.last_recording = None
        self._rig_error = None
        self._png = b""

        style = {"description_width": "70px"}

        def lay():
            return widgets.Layout(width="330px", max_width="100%")

        R = tuning.SLIDER_RANGES
        c = dict(
            zeta=widgets.FloatSlider(
                value=as_positive("zeta", zeta),
                min=R["zeta"][0],
                max=R["zeta"][1],
                step=R["zeta"][2],
                description="ζ",
                readout_format=".2f",
                continuous_update=False,
                style=style,
                layout=lay(),
            ),
            wn=widgets.FloatSlider(
                value=as_positive("wn", wn),
                min=R["wn"][0],
                max=R["wn"][1],
                step=R["wn"][2],
                description="ωn [rad/s]",
                readout_format=".0f",
                continuous_update=False,
                style=style,
                layout=lay(),
            ),
            sigma_ratio=widgets.FloatSlider(
                value=as_positive("sigma_ratio", sigma_ratio),
                min=R["sigma_ratio"][0],
                max=R["sigma_ratio"][1],
                step=R["sigma_ratio"][2],
                description="σ / ωn",
                readout_format=".1f",
                continuous_update=False,
                style=style,
                layout=lay(),
            ),
            Ts_ms=widgets.FloatSlider(
                value=1e3 * as_positive("Ts", Ts),
                min=R["Ts_ms"][0],
                max=R["Ts_ms"][1],
                step=R["Ts_ms"][2],
                description="Ts [ms]",
                readout_format=".1f",
                continuous_update=False,
                style=style,
                layout=lay(),
            ),
            design=widgets.ToggleButtons(
                options=list(DESIGNS.items()),
                value=design if design in DESIGNS.values() else None,
                description="design",
                style={"button_width": "auto", **style},
                layout=widgets.Layout(max_width="100%"),
            ),
        )
        if c["design"].value is None:
            raise ValueError(f"design must be one of {sorted(DESIGNS.values())}, got {design!r}")
        self.controls = c
        for w in c.values():
            w.add_class("jerklab-control")
        c["design"].add_class("jerklab-design")
        self.status = widgets.HTML(layout=widgets.Layout(width="100%"))
        self.status.add_class("jerklab-status")
        self.figure = PolePlacementFigure(dpi=dpi)
        width_px = self.figure.canvas.get_width_height()[0]
        # shown at its own pixel size (no blurry upscaling), narrower on a small screen
        self.image = widgets.Image(
            format="png", layout=widgets.Layout(width=f"{width_px}px", max_width="100%")
        )
        self.image.add_class("jerklab-figure")
        self.figure_narrow = self.image_narrow = None
        if narrow_figure:
            self.figure_narrow = PolePlacementFigure(dpi=dpi, layout="narrow")
            w_n = self.figure_narrow.canvas.get_width_height()[0]
            self.image_narrow = widgets.Image(
                format="png", layout=widgets.Layout(width=f"{w_n}px", max_width="100%")
            )
            self.image_narrow.add_class("jerklab-figure-narrow")

        sliders = widgets.Box([c["zeta"], c["wn"], c["sigma_ratio"], c["Ts_ms"]])
        sliders.add_class("jerklab-sliders")
        rows = [widgets.HTML(_PANEL_CSS), sliders, c["design"]]
        self.student = None
        if rig is not None:
            self.rig_button = widgets.Button(
                description="Run this move on the rig",
                button_style="primary",
                layout=widgets.Layout(width="260px", max_width="100%"),
            )
            self.rig_button.add_class("jerklab-rig-button")
            self.rig_status = widgets.HTML()
            self.rig_status.add_class("jerklab-rig-status")
            self.rig_button.on_click(self._run_on_rig)
            items = [self.rig_button, self.rig_status]
            if student:
                self.student = widgets.Text(
                    description="student ID",
                    placeholder="your ID",
                    continuous_update=True,
                    style=style,
                    layout=widgets.Layout(width="260px", max_width="100%"),
                )
                self.student.add_class("jerklab-student-id")
                self.student.observe(lambda _c: self._update_rig_button(), names="value")
                items.insert(0, self.student)
            row = widgets.Box(items)
            row.add_class("jerklab-rig-row")
            rows.append(row)
            # a run on a rig of this kernel draws live here (jerklab.rig.live) while the
            # telemetry arrives; the panel's figure then overlays the run
            self.live_box = widgets.VBox([])
            self.live_box.add_class("jerklab-rig-live")
        images = [self.image] + ([self.image_narrow] if self.image_narrow is not None else [])
        live = [self.live_box] if rig is not None else []
        super().__init__(rows + [self.status] + live + images)
        self.add_class("jerklab-panel")
        if self.image_narrow is not None:
            self.add_class("jerklab-has-narrow")

        for w in c.values():
            w.observe(self._on_change, names="value")
        self.update()

    # -- parameters ------------------------------------------------------------------
    def params(self):
        """The current slider values as keyword arguments of :func:`jerklab.tuning.compute_pole_placement`."""
        c = self.controls
        return dict(
            K=self.K,
            tau=self.tau,
            zeta=c["zeta"].value,
            wn=c["wn"].value,
            sigma_ratio=c["sigma_ratio"].value,
            Ts=c["Ts_ms"].value * 1e-3,
            design=c["design"].value,
            move=self.move,
        )

    @property
    def gains(self):
        """The discrete gains (:class:`jerklab.controller.DiscreteGains`) of the current design.

        Exactly what ``rig.run_move(profile, panel.gains, Ts=panel.gains.Ts)`` accepts, so a
        worksheet can take the tuned gains to its rig cell.
        """
        return self.result.gains

    @property
    def student_id(self):
        """The sanitized student ID (a folder name), or None when there is no valid ID."""
        if self.student is None:
            return None
        try:
            return sanitize_student_id(self.student.value)
        except ValueError:
            return None

    def _on_change(self, change):
        self._rig_error = None
        live = getattr(self, "live_box", None)
        if live is not None:
            live.children = ()  # the last run's live plot is stale with the new design
        self.update()

    def update(self):
        """Recompute the design for the current sliders and redraw the figure in place.

        An error is shown in the panel (red box, class ``jerklab-error``) and re-raised.
        """
        t0 = time.perf_counter()
        try:
            res = tuning.compute_pole_placement(**self.params())
            self.figure.update(res, self._rig_error)
            png = self.figure.png()
            if self.figure_narrow is not None:
                self.figure_narrow.update(res, self._rig_error)
                png_narrow = self.figure_narrow.png()
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            self.status.value = (
                '<div class="jerklab-error" style="background:#fdecea;color:#b71c1c;'
                'border:2px solid #c62828;padding:6px;font-weight:bold">'
                f"Panel error: {html.escape(self.error)}</div>"
            )
            self.status.add_class("jerklab-error")
            raise
        self.error = None
        self.status.remove_class("jerklab-error")
        self.result = res
        self._png = png
        self.image.value = png
        if self.figure_narrow is not None:
            self.image_narrow.value = png_narrow
        self.status.value = _status_html(res)
        self._update_rig_button()
        self.last_redraw_s = time.perf_counter() - t0
        return res

    # -- the rig -----------------------------------------------------------------------
    def _refusal(self):
        """Why the rig button is disabled now (None: it may run)."""
        res = self.result
        if res is None:
            return "no design yet"
        if not res.stable:
            advice = f" {res.advice_text}" if res.advice_text else ""
            return (
                f"Not run on the rig: the sampled loop of the {res.design_name} has a pole "
                f"at |z| = {res.max_radius:.3f} ≥ 1, it would run away.{advice}"
            )
        if self.student is not None and self.student_id is None:
            return "Enter your student ID to run on the rig (your runs are saved under it)."
        return None

    def _update_rig_button(self):
        if self.rig is None:
            return
        why = self._refusal()
        self.rig_button.disabled = why is not None
        if why is not None:
            self.rig_status.value = (
                f'<span class="jerklab-rig-refused" style="color:#8a1c1c">{html.escape(why)}</span>'
            )
        elif "jerklab-rig-refused" in self.rig_status.value or self._rig_error is None:
            self.rig_status.value = ""

    def _recording_path(self):
        """recordings/<student>/<stamp>_move for a class page, else False (memory only)."""
        sid = self.student_id
        if self.student is None or sid is None:
            return False
        folder = (Path(self.recordings) if self.recordings is not None else recordings_dir()) / sid
        base = folder / unique_run_name()  # two runs in one second never share a file
        while base.with_name(base.name + ".csv").exists():
            base = folder / unique_run_name()
        return base

    def _show_live(self, widget):
        """Put a run's live plot (:mod:`jerklab.rig.live`) in the panel's live box."""
        self.live_box.children = (widget,)
        return None  # no display handle: the plot updates its own widgets

    def _show_rig_status(self, text):
        self.rig_status.value = text

    def _run_on_rig(self, _button=None, force=False):
        """Run the current move with the current discrete gains on the rig, overlay the error."""
        res = self.result
        try:
            self.rig_button.disabled = True
            tuning.check_runnable(
                self.K, self.tau, res.gains, force=force, design=res.params["design"]
            )
            if self.student is not None and self.student_id is None:
                raise ValueError("student_id: enter your student ID before running on the rig")
            self.rig_status.value = "running…"
            kwargs = dict(
                Ts=res.params["Ts"],
                feedforward=Feedforward(self.K, self.tau),
                path=self._recording_path(),
                progress=False,
            )
            if getattr(self.rig, "queues_runs", False):
                kwargs["on_status"] = lambda msg: self._show_rig_status(html.escape(msg))
                if self.student_id is not None:
                    self.rig.client = self.student_id  # names the run in the broker's queue
            if force and _accepts(self.rig.run_move, "force"):
                kwargs["force"] = True
            if _names(self.rig.run_move, "live") and hasattr(self.rig, "live_display"):
                # a rig of this kernel, or the shared rig streaming through its broker: the
                # run draws live in the panel's own box (a callback has no cell output), then
                # the panel's figure overlays it
                self.live_box.children = ()
                self.rig.live_display = self._show_live
                kwargs["live"] = True
            elif _names(self.rig.run_move, "live"):
                kwargs["live"] = False
            rec = self.rig.run_move(tuning.move_profile(self.move), res.gains, **kwargs)
            self.last_recording = rec
            t = np.asarray(rec.time, dtype=float)
            # the same quantity as the simulated curve: reference − encoder reading
            err = np.asarray(rec.reference, dtype=float) - np.asarray(rec.position, dtype=float)
            self._rig_error = (t, err)
            self.figure.update(res, self._rig_error)
            self._png = self.figure.png()
            self.image.value = self._png
            if self.figure_narrow is not None:
                self.figure_narrow.update(res, self._rig_error)
                self.image_narrow.value = self.figure_narrow.png()
            sim = (
                float(np.max(np.abs(res.err_move_measured))) if res.err_move_measured.size else 0.0
            )
            saved = ""
            if getattr(rec, "csv_path", None) is not None:
                # the student's folder and file, not the server's absolute path
                shown = Path(rec.csv_path)
                shown = f"{shown.parent.name}/{shown.name}" if self.student is not None else shown
                saved = f"; saved as {html.escape(str(shown))}"
            self.rig_status.value = (
                f"rig: max |ref. − encoder| = {format_angle(np.max(np.abs(err)))} over "
                f"{t.size} samples (simulation: {format_angle(sim)}){saved}"
            )
        except Exception as exc:
            self.rig_status.value = (
                '<span class="jerklab-error" style="color:#b71c1c;font-weight:bold">rig error: '
                f"{html.escape(f'{type(exc).__name__}: {exc}')}</span>"
            )
            raise
        finally:
            self.rig_button.disabled = self._refusal() is not None

    def run_on_rig(self, force=False):
        """Script form of the "Run this move on the rig" button; returns (t, ref. − encoder).

        Refuses (:class:`jerklab.tuning.UnstableDesignError`) a design whose sampled loop has
        ``|z|`` ≥ 1 unless ``force=True``.
        """
        if self.rig is None:
            raise ValueError(
                "rig: this panel was built without a rig (pole_placement_panel(rig=...))"
            )
        self._run_on_rig(force=force)
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


def _names(func, name):
    """Whether ``func`` has a parameter called ``name`` (not only through ``**kwargs``)."""
    import inspect

    try:
        return name in inspect.signature(func).parameters
    except (TypeError, ValueError):
        return False


def _accepts(func, name):
    """Whether ``func`` takes the keyword ``name`` (by name or through ``**kwargs``, as
    ``Rig.run_move`` takes the RunSpec fields)."""
    import inspect

    try:
        params = inspect.signature(func).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def _fmt_gain(v):
    return f"{v:.4g}"


def _status_html(res):
    color = _LEVEL_COLORS[res.level]
    bg = {"ok": "#e8f5e9", "near": "#fff3e0", "unstable": "#fdecea"}[res.level]
    tag = {"ok": "OK", "near": "WARNING", "unstable": "UNSTABLE"}[res.level]
    message = res.message
    if message.startswith(tag + ": "):
        message = message[len(tag) + 2 :]
    rows = tuning.gain_table(res.gains, res.continuous_gains)
    disc = ", ".join(f"{n} = {_fmt_gain(v)} {u}".rstrip() for n, v, u in rows[:-3])
    cont = ", ".join(f"{n} = {_fmt_gain(v)} {u}" for n, v, u in rows[-3:])
    how = "Stojčić eq. 11" if res.continuous_gains is not None else "Stojčić eq. 13 equivalent"
    advice = (
        f'<br><span class="jerklab-advice">{html.escape(res.advice_text)}</span>'
        if res.advice_text
        else ""
    )
    return (
        f'<div class="jerklab-verdict jerklab-{res.level}" style="background:{bg};'
        f'color:{color};border-left:6px solid {color};padding:4px 8px">'
        f'<b><span style="border:1px solid {color};border-radius:3px;padding:0 4px;'
        f'margin-right:6px">{tag}</span>{html.escape(res.design_name)}: '
        f"{html.escape(message)}</b>{advice}<br>"
        f'<span style="color:#333">discrete (Stojčić eq. 12): {html.escape(disc)}<br>'
        f"continuous ({how}): {html.escape(cont)}</span></div>"
    )


def pole_placement_panel(
    K=paper.MOTOR_K,
    tau=paper.MOTOR_TAU,
    *,
    zeta=paper.ZETA,
    wn=20.0,
    sigma_ratio=paper.SIGMA_RATIO,
    Ts=paper.TS,
    design="continuous",
    move=None,
    rig=None,
    dpi=80,
    student=False,
    narrow_figure=False,
    recordings=None,
):
    """The interactive pole-placement tuning panel of notebook 03, the labs and the class page.

    Sliders for ζ, ωn, σ/ωn and Ts and a choice of design (Stojčić eq. 11 discretized by
    Stojčić eq. 13, the direct z-domain design, or the z-domain design with a derivative
    filter); one figure with the closed-loop poles in s and z, the unit-step and
    step-disturbance (Stojčić eq. 9) responses of the sampled loop, and the tracking error and
    voltage of a sine-jerk move simulated with the rig's imperfections; a verdict that turns
    orange near and red past instability, with advice checked for the selected design, and
    the gains with their units.

    Parameters
    ----------
    K, tau : float
        Plant of Stojčić eq. 1 in rad/(V·s) and s: your identified motor (defaults: the
        paper's). The design, the simulation and the rig run's feedforward all use them.
    zeta, wn, sigma_ratio, Ts, design
        Initial values (see :func:`jerklab.tuning.compute_pole_placement`).
    move : dict, optional
        The sine-jerk move (default :data:`jerklab.tuning.DEFAULT_MOVE`).
    rig : object, optional
        A rig from :func:`jerklab.rig.connect` (or the class page's queue,
        :class:`jerklab.broker.BrokerRig`); adds a "Run this move on the rig" button that
        calls ``rig.run_move(profile, gains, Ts)`` and overlays the measured tracking
        error. The button is disabled while the sampled loop is unstable (``|z|`` ≥ 1).
    dpi : float
        Resolution of the figure.
    student : bool
        Add a student ID field; rig runs are then refused without an ID and saved to
        ``recordings/<student ID>/`` (the class page).
    narrow_figure : bool
        Also draw a phone-width figure, shown instead of the wide one below 640 px.
    recordings : path, optional
        Folder of the per-student folders (default ``$JERKLAB_RECORDINGS`` or ``./recordings``).

    Returns
    -------
    PolePlacementPanel
        An ``ipywidgets.VBox``. ``panel.gains`` are the discrete gains of the current
        design. Displaying it shows the live panel where widgets render and the
        default-value figure (PNG) where they do not (headless execution).

    Examples
    --------
    >>> from jerklab.widgets import pole_placement_panel
    >>> panel = pole_placement_panel(K=27.5, tau=0.034)     # doctest: +SKIP
    >>> panel.controls["wn"].value = 50                     # doctest: +SKIP
    >>> panel.result.level, panel.gains.Ts                  # doctest: +SKIP
    ('unstable', 0.005)
    """
    return PolePlacementPanel(
        K=K,
        tau=tau,
        zeta=zeta,
        wn=wn,
        sigma_ratio=sigma_ratio,
        Ts=Ts,
        design=design,
        move=move,
        rig=rig,
        dpi=dpi,
        student=student,
        narrow_figure=narrow_figure,
        recordings=recordings,
    )
