"""Tuning-panel redraw time against plain matplotlib redraws, in the same process.

The panel (``jerklab.widgets.pole_placement_panel``) must redraw within 0.3 s of a slider
move (issue 9). It changes only line data, keeps axis ranges with 1-2-5 limits and
hysteresis, restores a cached background and repaints just the axes whose range changed.
Peers on the same six-plot figure and the same slider sweep:

* ``full redraw``: the same artists, every axis rescaled, ``canvas.draw()`` + PNG
  (what ``set_data`` + ``relim``/``autoscale`` + ``draw`` costs);
* ``new figure``: a fresh ``Figure`` with six axes drawn and saved on every move (what
  re-running a plotting cell costs).

The class page also draws the phone-width figure on every move (``narrow_figure=True``);
its row shows what that costs. Every row starts from empty caches
(:func:`jerklab.tuning.clear_cache`), so each computes every design.

Run: ``python -m benchmarks widgets``.
"""

from __future__ import annotations

import io
import time

import numpy as np

from benchmarks._record import table
from jerklab.tuning import clear_cache, compute_pole_placement
from jerklab.widgets import PolePlacementFigure, pole_placement_panel

SWEEP = (
    [("wn", w) for w in np.arange(21.0, 45.0, 1.0)]
    + [("zeta", z) for z in np.arange(0.95, 0.6, -0.05)]
    + [("sigma_ratio", s) for s in np.arange(6.5, 3.5, -0.5)]
    + [("Ts_ms", t) for t in np.arange(6.0, 9.0, 1.0)]
)


def _panel_times(narrow=False):
    clear_cache()
    p = pole_placement_panel(narrow_figure=narrow)
    out = []
    for name, value in SWEEP:
        t0 = time.perf_counter()
        p.controls[name].value = float(value)
        out.append(time.perf_counter() - t0)
    return np.array(out), p


def _full_redraw_times(params):
    f = PolePlacementFigure()
    out = []
    for prm in params:
        t0 = time.perf_counter()
        res = compute_pole_placement(**prm)
        f.update(res)
        f._background = None  # no cached background: draw everything
        f.png()
        out.append(time.perf_counter() - t0)
    return np.array(out)


def _new_figure_times(params):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    out = []
    for prm in params:
        t0 = time.perf_counter()
        res = compute_pole_placement(**prm)
        fig = Figure(figsize=(11.0, 6.6), dpi=80)
        FigureCanvasAgg(fig)
        ax = fig.subplots(2, 3).ravel()
        ax[0].plot(res.poles_s_desired.real, res.poles_s_desired.imag, "x")
        ax[0].plot(res.poles_s_equivalent.real, res.poles_s_equivalent.imag, "o")
        ax[1].plot(res.poles_z.real, res.poles_z.imag, "o")
        ax[2].step(res.t_step, np.clip(res.y_step, -5, 5), where="post")
        ax[3].step(res.t_dist, np.clip(1e3 * res.y_dist, -2e3, 2e3), where="post")
        ax[4].step(res.t_move, np.clip(1e3 * res.err_move, -2e3, 2e3), where="post")
        ax[5].step(res.t_move, res.u_move, where="post")
        for a, t in zip(ax, ("s", "z", "step", "disturbance", "error", "voltage")):
            a.set_title(t)
            a.set_xlabel("x")
            a.set_ylabel("y")
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        out.append(time.perf_counter() - t0)
    return np.array(out)


def main():
    panel_t, p = _panel_times()
    phone_t, _ = _panel_times(narrow=True)
    # the same parameter sequence for the peers
    params, prm = [], dict(p.params())
    prm.update(zeta=1.0, wn=20.0, sigma_ratio=7.0, Ts=0.005, design="continuous")
    for name, value in SWEEP:
        key = {"Ts_ms": "Ts"}.get(name, name)
        prm[key] = float(value) * (1e-3 if name == "Ts_ms" else 1.0)
        params.append(dict(prm))
    clear_cache()  # the peers compute every design again, as the panel did
    full_t = _full_redraw_times(params)
    clear_cache()
    new_t = _new_figure_times(params)
    ref = np.median(panel_t)
    rows = [
        (name, 1e3 * np.median(t), 1e3 * np.percentile(t, 90), 1e3 * np.max(t), np.median(t) / ref)
        for name, t in (
            ("panel (blit + partial axes)", panel_t),
            ("class page: + phone figure", phone_t),
            ("full redraw, same artists", full_t),
            ("new figure every move", new_t),
        )
    ]
    table(
        f"{len(SWEEP)} slider moves (wn 21..44, zeta 0.95..0.65, sigma/wn 6.5..4, Ts 6..8 ms), "
        "each: design + responses + move simulation + figure + PNG",
        ["method", "median ms", "p90 ms", "max ms", "median ratio"],
        rows,
        note=f"panel moves within 0.3 s: {np.mean(panel_t < 0.3) * 100:.0f} %; "
        f"axes repainted per move: {p.figure.axes_redraws / len(SWEEP):.2f} of 6",
    )


if __name__ == "__main__":
    main()
