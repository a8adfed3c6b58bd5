"""Block diagrams and the planner flowchart of the three papers, drawn by code (schemdraw).

The figures of Stojčić (Stojcic), Xu & Meckl and Yang that are drawings, not data, are redrawn
here so that a notebook or the book shows them next to the code they describe:

* :func:`stojcic_fig2` — the planner's flowchart (Stojčić Fig. 2). Its boxes and branches come
  from :data:`PLANNER_FLOWCHART`, an *executable* description of the published algorithm
  (:func:`run_flowchart` walks it); a test checks the walk against
  :func:`jerklab.planner.plan_sine_jerk` on random moves, so the drawing cannot drift from the code.
* :func:`stojcic_fig3`, :func:`stojcic_fig5`, :func:`stojcic_fig6` — overall system
  (Stojčić eq. 5), feedforward realisation (Stojčić eq. 16), feedback realisation (Stojčić eq. 17).
* :func:`xu_fig1`, :func:`xu_fig3`, :func:`xu_fig8` — the PZT actuator model (hysteresis H then
  linear G, Xu & Meckl eq. 1), the velocity-tracking input feature (Xu & Meckl eq. 11, drawn from
  a shaped cycle), and the closed-loop framework (pole-placement feedback around the shaped command
  and the CNIA inverse).
* :func:`yang_fig1`, :func:`yang_fig3`, :func:`yang_fig4`, :func:`yang_fig5` — the S-curve system
  structure and the module symbols of the FPGA design (ports as in ``firmware/fpga/*.v``).

Every function returns a ``schemdraw.Drawing`` (shown inline by Jupyter; ``.draw()`` renders it
with matplotlib, ``.save(path)`` writes SVG/PNG). schemdraw and matplotlib are imported only when a
drawing function is called.

Naming in the Xu & Meckl diagrams follows the paper (Fig. 1): ``u_r`` is the reference of the
hysteresis (the voltage the linear design asks for), ``u_c`` the compensated command that the CNIA
inverse puts on the actuator, ``H(u_c) ≈ u_r``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from jerklab._validate import as_positive

__all__ = [
    "FlowStep",
    "PLANNER_FLOWCHART",
    "PLANNER_BRANCH_CASES",
    "FlowchartRun",
    "run_flowchart",
    "flowchart_branches",
    "drawing_labels",
    "stojcic_fig2",
    "stojcic_fig3",
    "stojcic_fig5",
    "stojcic_fig6",
    "xu_fig1",
    "xu_fig3",
    "xu_fig8",
    "yang_fig1",
    "yang_fig3",
    "yang_fig4",
    "yang_fig5",
    "ALL_DIAGRAMS",
]


# ----------------------------------------------------------------------------------------------
# Stojčić Fig. 2: the planner as data that both runs and draws
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlowStep:
    """One box of the planner flowchart.

    ``kind`` is ``"process"`` (``action(state)`` updates the state dict) or ``"decision"``
    (``test(state)`` returns the branch taken; ``action`` is the "yes" box beside the diamond).
    ``label`` is what the box says (matplotlib mathtext), ``yes_label`` the "yes" box's text.
    """

    key: str
    kind: str
    label: str
    equation: str
    action: Callable[[dict], None] | None = None
    test: Callable[[dict], bool] | None = None
    yes_label: str = ""


def _t_theta(s):
    s["T"] = (2.0 * math.pi * s["theta"] / s["J"]) ** (1.0 / 3.0)


def _t_accel(s):
    s["T"] = s["E"] * math.pi / s["J"]


def _w_peak(s):
    s["w"] = s["J"] * s["T"] ** 2 / (2.0 * math.pi)


def _t_velocity(s):
    s["T"] = math.sqrt(2.0 * math.pi * s["W"] / s["J"])
    s["w"] = s["W"]


def _cruise(s):
    s["tv"] = max((s["theta"] - s["w"] * s["T"]) / s["w"], 0.0)
    s["tu"] = 2.0 * s["T"] + s["tv"]


#: Stojčić's planner (Stojčić Fig. 2, Stojčić eq. 4) step by step. ``run_flowchart`` executes it and
#: ``stojcic_fig2`` draws it; the same lambdas do both.
PLANNER_FLOWCHART: tuple[FlowStep, ...] = (
    FlowStep("T_theta", "process", "T = ∛(2πΘ/J)", "Stojčić eq. 4", action=_t_theta),
    FlowStep(
        "accel_test",
        "decision",
        "JT/π > E ?",
        "Stojčić eq. 3",
        test=lambda s: s["J"] * s["T"] / math.pi > s["E"],
        action=_t_accel,
        yes_label="T = Eπ/J",
    ),
    FlowStep("w_peak", "process", "ω̄ = JT²/(2π)", "Stojčić eq. 3", action=_w_peak),
    FlowStep(
        "velocity_test",
        "decision",
        "ω̄ > Ω ?",
        "Stojčić eq. 3",
        test=lambda s: s["w"] > s["W"],
        action=_t_velocity,
        yes_label="T = √(2πΩ/J), ω̄ = Ω",
    ),
    FlowStep(
        "cruise", "process", "tᵥ = (Θ − ω̄T)/ω̄,  tᵤ = 2T + tᵥ", "Stojčić eq. 2", action=_cruise
    ),
)

#: One move per branch of the flowchart, ``name: (Theta, J, E, Omega)``, and the decisions it takes
#: (accel_test, velocity_test). Notebook 01 plots their velocity shapes.
PLANNER_BRANCH_CASES: dict[str, tuple[float, float, float, float]] = {
    "distance binds (no cruise)": (1.0, 1000.0, 1e3, 1e3),
    "acceleration binds (T = Eπ/J)": (100.0, 1000.0, 100.0, 1e3),
    "velocity binds (T = √(2πΩ/J))": (100.0, 1000.0, 1e3, 20.0),
    "both tests fire, Ω decides": (100.0, 1000.0, 100.0, 5.0),
}


@dataclass(frozen=True)
class FlowchartRun:
    """Result of walking :data:`PLANNER_FLOWCHART`: times in s, decisions taken in order."""

    accel_time: float
    cruise_time: float
    duration: float
    peak_velocity: float
    branches: tuple[bool, ...]


def run_flowchart(distance, max_jerk, max_accel, max_velocity) -> FlowchartRun:
    """Walk the flowchart of Stojčić Fig. 2 (Stojčić eq. 4) for one move.

    Parameters
    ----------
    distance : float
        Move length Θ (> 0; its magnitude is used, as the planner does).
    max_jerk, max_accel, max_velocity : float
        J, E, Ω (> 0).

    Returns
    -------
    FlowchartRun
        T, t_v, t_u, ω̄ and the outcome of each decision box.
    """
    theta = abs(float(distance))
    if theta == 0.0 or not math.isfinite(theta):
        raise ValueError(f"distance must be a nonzero finite number, got {distance!r}")
    s = {
        "theta": theta,
        "J": as_positive("max_jerk", max_jerk),
        "E": as_positive("max_accel", max_accel),
        "W": as_positive("max_velocity", max_velocity),
    }
    taken = []
    for step in PLANNER_FLOWCHART:
        if step.kind == "process":
            step.action(s)
        else:
            yes = bool(step.test(s))
            taken.append(yes)
            if yes:
                step.action(s)
    return FlowchartRun(s["T"], s["tv"], s["tu"], s["w"], tuple(taken))


def flowchart_branches() -> list[tuple[bool, ...]]:
    """Every combination of decision outcomes the flowchart can take (2 decisions: 4 paths)."""
    n = sum(st.kind == "decision" for st in PLANNER_FLOWCHART)
    return [tuple(bool((i >> k) & 1) for k in range(n)) for i in range(2**n)]


# ----------------------------------------------------------------------------------------------
# drawing helpers
# ----------------------------------------------------------------------------------------------
def _schemdraw():
    try:
        import schemdraw
        import schemdraw.dsp as dsp
        import schemdraw.flow as flow
    except ImportError as exc:  # pragma: no cover - dependency
        raise ImportError("jerklab.diagrams needs schemdraw (pip install schemdraw)") from exc
    return schemdraw, dsp, flow


def _new(title, unit=1.6, fontsize=11):
    # schemdraw's own SVG backend: no matplotlib, fast, and the text stays text (searchable in the book)
    schemdraw, _, _ = _schemdraw()
    d = schemdraw.Drawing(canvas="svg", show=False)
    d.config(unit=unit, fontsize=fontsize)
    d.jerklab_title = title
    return d


def _finish(d):
    """Put the title above the drawing, left-aligned, and widen the box to hold it."""
    import schemdraw.elements as elm

    bbox = d.get_bbox()
    y = bbox.ymax + 0.7
    d.add(elm.Label().at((bbox.xmin, y)).label(d.jerklab_title, fontsize=11, halign="left"))
    # the SVG backend sizes the page from the elements, not from label text: an invisible line as
    # wide as the title (≈ 0.16 drawing units per character at 11 pt) keeps it on the page
    width = 0.16 * len(d.jerklab_title)
    if bbox.xmin + width > bbox.xmax:
        d.add(elm.Line().at((bbox.xmin, y + 0.3)).to((bbox.xmin + width, y + 0.3)).color("white"))
    return d


def drawing_labels(d) -> list[str]:
    """All label strings of a schemdraw drawing (for tests and the figure index)."""
    out = []
    for e in d.elements:
        for lab in getattr(e, "_userlabels", []):
            out.append(str(lab.label))
    return out


# ----------------------------------------------------------------------------------------------
# Stojčić
# ----------------------------------------------------------------------------------------------
def stojcic_fig2():
    """Stojčić Fig. 2: flowchart of the trajectory planner, drawn from :data:`PLANNER_FLOWCHART`."""
    _, dsp, flow = _schemdraw()
    d = _new(
        "Stojčić Fig. 2 — flowchart of the planner (drawn from jerklab's executable steps)",
        unit=0.8,
        fontsize=10,
    )
    d.add(start := flow.Start(w=3.2, h=1.1).label("Θ, J, E, Ω"))
    prev = start
    for step in PLANNER_FLOWCHART:
        d.add(flow.Arrow().down(0.8).at(prev.S))
        if step.kind == "process":
            box = (
                flow.Box(w=5.2, h=1.1)
                .anchor("N")
                .label(step.label + f"\n({step.equation})", fontsize=9)
            )
            d.add(box)
            prev = box
        else:
            dec = (
                flow.Decision(w=4.2, h=1.8, E="yes", S="no", fontsize=9)
                .anchor("N")
                .label(step.label)
            )
            d.add(dec)
            d.add(flow.Arrow().right(1.2).at(dec.E))
            yes = flow.Box(w=4.4, h=1.1).anchor("W").label(step.yes_label, fontsize=9)
            d.add(yes)
            # the "yes" box rejoins the main path below the diamond
            d.add(flow.Line().down(1.3).at(yes.S))
            join = d.here
            d.add(flow.Arrow().tox(dec.S[0]).at(join))
            d.add(flow.Line().at(dec.S).toy(join[1]))
            prev = _Anchor(S=(dec.S[0], join[1]))
    d.add(flow.Arrow().down(0.8).at(prev.S))
    d.add(flow.Start(w=3.2, h=1.1).anchor("N").label("T, tᵥ, tᵤ"))
    return _finish(d)


class _Anchor:
    def __init__(self, S):
        self.S = S


def stojcic_fig3():
    """Stojčić Fig. 3: overall system, feedback B(s) and feedforward F(s) around P(s) (Stojčić eq. 5)."""
    _, dsp, _ = _schemdraw()
    d = _new("Stojčić Fig. 3 — overall system: y = PF/(1+PB)·r + W/(1+PB)·w (Stojčić eq. 5)")
    d.add(dsp.Line().right(0.8).label("r(s)", "left"))
    d.add(split := dsp.Dot())
    d.add(dsp.Arrow().right(1.0))
    d.add(se := dsp.Sum().anchor("W").label("+", "left", ofst=(0.15, 0.05), fontsize=9))
    d.add(dsp.Arrow().right(1.0).at(se.E).label("e(s)"))
    d.add(b := dsp.Box(w=1.8, h=1.1).anchor("W").label("B(s)"))
    d.add(dsp.Arrow().right(1.0).at(b.E).label(r"$u_B$"))
    d.add(su := dsp.Sum().anchor("W"))
    d.add(dsp.Arrow().right(1.0).at(su.E).label("u(s)"))
    d.add(p := dsp.Box(w=1.8, h=1.1).anchor("W").label("P(s)"))
    d.add(dsp.Arrow().right(1.0).at(p.E))
    d.add(sy := dsp.Sum().anchor("W"))
    d.add(dsp.Line().right(1.0).at(sy.E))
    d.add(out := dsp.Dot())
    d.add(dsp.Arrow().right(0.8).label("y(s)", "right"))
    # feedforward above
    d.add(dsp.Line().up(2.0).at(split.center))
    d.add(dsp.Arrow().right(2.0))
    d.add(f := dsp.Box(w=1.8, h=1.1).anchor("W").label("F(s)"))
    d.add(dsp.Line().tox(su.N).at(f.E).label(r"$u_F$"))
    d.add(dsp.Arrow().to(su.N))
    # disturbance
    d.add(dsp.Arrow().down(1.0).at((sy.N[0], sy.N[1] + 2.2)))
    import schemdraw.elements as elm

    d.add(elm.Label().at((sy.N[0] + 0.6, sy.N[1] + 2.0)).label("w(s)"))
    d.add(wb := dsp.Box(w=1.3, h=0.9).anchor("N").label("W(s)"))
    d.add(dsp.Arrow().to(sy.N).at(wb.S))
    # feedback below
    d.add(dsp.Line().down(1.8).at(out.center))
    d.add(dsp.Line().tox(se.S))
    d.add(dsp.Arrow().to(se.S).label("−", "right", ofst=(0.1, -0.3), fontsize=11))
    return _finish(d)


def stojcic_fig5():
    """Stojčić Fig. 5: feedforward realisation, the Stojčić eq. 15 recursion and u_F(k) (Stojčić eq. 16)."""
    _, dsp, _ = _schemdraw()
    d = _new(
        "Stojčić Fig. 5 — feedforward: accumulators of Stojčić eq. 15, "
        "u_F(k) = (τ/K)ε(k) + (1/K)ω(k) (Stojčić eq. 16)"
    )
    d.add(dsp.Arrow().right(1.2).label("j(k)", "left"))
    d.add(a1 := dsp.Box(w=2.2, h=1.2).anchor("W").label(r"$T_s/(1-z^{-1})$"))
    d.add(dsp.Line().right(1.0).at(a1.E).label(r"$\varepsilon(k)$"))
    d.add(s1 := dsp.Dot())
    d.add(dsp.Arrow().right(1.0))
    d.add(a2 := dsp.Box(w=2.2, h=1.2).anchor("W").label(r"$T_s/(1-z^{-1})$"))
    d.add(dsp.Line().right(1.0).at(a2.E).label(r"$\omega(k)$"))
    d.add(s2 := dsp.Dot())
    d.add(dsp.Arrow().right(1.0))
    d.add(a3 := dsp.Box(w=2.2, h=1.2).anchor("W").label(r"$T_s/(1-z^{-1})$"))
    d.add(dsp.Arrow().right(1.0).at(a3.E).label(r"$\theta(k)$", "right"))
    d.add(dsp.Line().down(1.0).at(s1.center))
    d.add(g1 := dsp.Box(w=1.3, h=0.9).anchor("N").label(r"$\tau/K$"))
    d.add(dsp.Line().down(1.0).at(s2.center))
    d.add(g2 := dsp.Box(w=1.3, h=0.9).anchor("N").label(r"$1/K$"))
    d.add(dsp.Arrow().down(0.8).at(g2.S))
    d.add(ssum := dsp.Sum().anchor("N"))
    d.add(dsp.Line().at(g1.S).toy(ssum.W[1]))
    d.add(dsp.Arrow().tox(ssum.W[0]).label("+", "top", fontsize=9))
    d.add(dsp.Arrow().right(1.6).at(ssum.E).label(r"$u_F(k)$", "right"))
    return _finish(d)


def stojcic_fig6():
    """Stojčić Fig. 6: feedback realisation, p(k), i(k), d(k) and u_B(k) (Stojčić eq. 17)."""
    _, dsp, _ = _schemdraw()
    d = _new("Stojčić Fig. 6 — feedback: p(k) + i(k) + d(k) = u_B(k) (Stojčić eq. 18)")
    d.add(dsp.Arrow().right(1.4).label(r"$\omega_{Td}(k)$", "left"))
    d.add(se := dsp.Sum().anchor("W").label("+", "left", ofst=(0.15, 0.05), fontsize=9))
    d.add(
        dsp.Arrow()
        .up(1.0)
        .at((se.S[0], se.S[1] - 1.0))
        .label(r"$\omega_T(k)$ (encoder)", "left")
        .label("−", "right", fontsize=11)
    )
    d.add(dsp.Line().right(1.0).at(se.E).label("e(k)"))
    d.add(br := dsp.Dot())
    d.add(dsp.Arrow().right(1.4))
    d.add(bi := dsp.Box(w=2.6, h=1.1).anchor("W").label(r"$k_{id}/(1-z^{-1})$"))
    d.add(dsp.Line().up(1.8).at(br.center))
    d.add(dsp.Arrow().right(1.4))
    d.add(bp := dsp.Box(w=2.6, h=1.1).anchor("W").label(r"$k_{pd}$"))
    d.add(dsp.Line().down(1.8).at(br.center))
    d.add(dsp.Arrow().right(1.4))
    d.add(bd := dsp.Box(w=2.6, h=1.1).anchor("W").label(r"$k_{dd}(1-z^{-1})$"))
    d.add(dsp.Arrow().right(1.5).at(bi.E).label("i(k)"))
    d.add(ss := dsp.Sum().anchor("W"))
    d.add(dsp.Line().at(bp.E).tox(ss.N[0]).label("p(k)"))
    d.add(dsp.Arrow().to(ss.N))
    d.add(dsp.Line().at(bd.E).tox(ss.S[0]).label("d(k)", "bottom"))
    d.add(dsp.Arrow().to(ss.S))
    d.add(dsp.Arrow().right(1.4).at(ss.E).label(r"$u_B(k)$", "right"))
    return _finish(d)


# ----------------------------------------------------------------------------------------------
# Xu & Meckl
# ----------------------------------------------------------------------------------------------
def xu_fig1():
    """Xu & Meckl Fig. 1: PZT model, hysteresis H then linear G (Xu & Meckl eq. 1), with the CNIA inverse."""
    _, dsp, _ = _schemdraw()
    d = _new(
        "Xu and Meckl Fig. 1 — PZT actuator model: H⁻¹ (CNIA) · H (hysteresis) · G(s) of Table I"
    )
    d.add(dsp.Arrow().right(1.4).label(r"$u_r$", "left"))
    d.add(hi := dsp.Box(w=2.2, h=1.2).anchor("W").label(r"$H^{-1}$" + "\n(CNIA)", fontsize=10))
    d.add(dsp.Arrow().right(1.6).at(hi.E).label(r"$u_c$"))
    d.add(h := dsp.Box(w=2.2, h=1.2).anchor("W").label("H\n(Preisach)", fontsize=10))
    d.add(dsp.Arrow().right(1.6).at(h.E).label("f ≈ u_r"))
    d.add(g := dsp.Box(w=2.2, h=1.2).anchor("W").label("G(s)\n4th order", fontsize=10))
    d.add(dsp.Arrow().right(1.4).at(g.E).label(r"$y$ (µm)", "right"))
    return _finish(d)


def xu_fig3(cycle=None, ax=None):
    """Xu & Meckl Fig. 3: input feature of velocity tracking, u_T(t) on [0, T], then the ramp
    u_∞(t) = u_T(T) + w_ss (t − T) (Xu & Meckl eq. 11).

    A plot, not a schematic: drawn from a shaped ramp-up when ``cycle`` (a
    :class:`jerklab.piezo.ScanCycle`) is given, else from a schematic smooth rise.

    Returns
    -------
    matplotlib.axes.Axes
    """
    import matplotlib.pyplot as plt
    import numpy as np

    if ax is None:
        _, ax = plt.subplots(figsize=(6.5, 3.2))
    if cycle is not None:
        n = cycle.N + cycle.S
        u = cycle.command()[:n]
        t = np.arange(n) * cycle.spec.Ts * 1e3
        T = cycle.N * cycle.spec.Ts * 1e3
        ax.step(t, u, where="post", lw=1.2, label=r"shaped $u_T(t)$, $t < T$, then the scan ramp")
        tt = np.linspace(T, t[-1], 50)
        ax.plot(
            tt,
            u[cycle.N] + cycle.w / (cycle.spec.Ts * 1e3) * (tt - T),
            "k--",
            lw=0.9,
            label=r"$u_\infty(t) = u_T(T) + w_{ss}(t-T)$ (Xu & Meckl eq. 11)",
        )
        ax.set_ylabel("input u (V)")
        ax.set_xlabel("time t (ms)")
    else:
        T = 1.0
        t = np.linspace(0, T, 200)
        ax.plot(
            t,
            0.4 * (1 - np.cos(np.pi * t)) + 0.15 * np.sin(3 * np.pi * t),
            lw=1.2,
            label=r"$u_T(t)$ (time-bounded part)",
        )
        tt = np.linspace(T, 2.2, 50)
        ax.plot(
            tt, 0.8 + 0.6 * (tt - T), "k--", lw=0.9, label=r"$u_\infty(t) = u_T(T) + w_{ss}(t-T)$"
        )
        ax.set_ylabel("input u (arbitrary units)")
        ax.set_xlabel("time t / T (–)")
    ax.axvline(T, color="gray", lw=0.8)
    ax.annotate("T", (T, ax.get_ylim()[0]), xytext=(3, 3), textcoords="offset points")
    ax.set_title(
        "Xu & Meckl Fig. 3 — input feature of velocity tracking (Xu & Meckl eq. 12)", fontsize=9
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    return ax


def xu_fig8():
    """Xu & Meckl Fig. 8: closed-loop framework, shaped command + pole-placement feedback + CNIA."""
    _, dsp, _ = _schemdraw()
    d = _new(
        "Xu and Meckl Fig. 8 — closed loop: shaped command, feedback, CNIA (jerklab.piezo.closed_loop)"
    )
    d.add(dsp.Arrow().right(1.2).label(r"$u_{ff}$ (shaped)", "left"))
    d.add(s1 := dsp.Sum().anchor("W").label("+", "left", ofst=(0.15, 0.05), fontsize=9))
    d.add(dsp.Arrow().right(1.3).at(s1.E).label(r"$u_r$"))
    d.add(hi := dsp.Box(w=1.9, h=1.1).anchor("W").label(r"$H^{-1}$ (CNIA)", fontsize=10))
    d.add(dsp.Arrow().right(1.3).at(hi.E).label(r"$u_c$"))
    d.add(h := dsp.Box(w=1.6, h=1.1).anchor("W").label("H", fontsize=10))
    d.add(dsp.Arrow().right(1.3).at(h.E).label("f"))
    d.add(g := dsp.Box(w=1.9, h=1.1).anchor("W").label("G(s)\n(perturbed)", fontsize=9))
    d.add(dsp.Line().right(1.0).at(g.E))
    d.add(out := dsp.Dot())
    d.add(dsp.Arrow().right(0.9).label("y", "right"))
    d.add(dsp.Line().down(2.0).at(out.center))
    d.add(dsp.Arrow().left(2.0))
    d.add(se := dsp.Sum().anchor("E").label("+", "top", fontsize=9))
    d.add(
        dsp.Arrow()
        .up(1.0)
        .at((se.S[0], se.S[1] - 1.0))
        .label(r"$y_d$ (nominal)", "left")
        .label("−", "right", fontsize=11)
    )
    d.add(dsp.Arrow().left(1.3).at(se.W))
    d.add(
        c := dsp.Box(w=3.4, h=1.1)
        .anchor("E")
        .label("pole placement\nobserver + integrator", fontsize=9)
    )
    d.add(dsp.Line().at(c.W).tox(s1.S[0] - 0.0))
    d.add(dsp.Arrow().to(s1.S).label("−", "right", ofst=(0.1, -0.3), fontsize=11))
    return _finish(d)


# ----------------------------------------------------------------------------------------------
# Yang et al.
# ----------------------------------------------------------------------------------------------
def yang_fig1():
    """Yang Fig. 1: S-curve system structure (speed dissociation -> pulse module -> drive -> motor)."""
    _, dsp, _ = _schemdraw()
    d = _new("Yang Fig. 1 — S-curve system structure (FPGA modules, drive, motor)")
    d.add(dsp.Arrow().right(1.0).label("V, T", "left"))
    d.add(a := dsp.Box(w=3.0, h=1.4).anchor("W").label("S-curve speed\ndissociation", fontsize=9))
    d.add(dsp.Arrow().right(1.6).at(a.E).label("f = v/k"))
    d.add(
        b := dsp.Box(w=3.0, h=1.4).anchor("W").label("PWM speed\nregulation\n(divider)", fontsize=9)
    )
    d.add(dsp.Arrow().right(1.6).at(b.E).label("pulses"))
    d.add(c := dsp.Box(w=2.4, h=1.4).anchor("W").label("motor drive\n(position mode)", fontsize=9))
    d.add(dsp.Arrow().right(1.2).at(c.E))
    d.add(dsp.Box(w=1.6, h=1.4).anchor("W").label("motor", fontsize=9))
    return _finish(d)


def _module(title, left, right, top_label):
    _, dsp, _ = _schemdraw()
    d = _new(title)
    pins = [dsp.IcPin(name=n, side="left", pin="") for n in left]
    pins += [dsp.IcPin(name=n, side="right", pin="") for n in right]
    d.add(
        dsp.Ic(
            pins=pins, size=(4.6, max(len(left), len(right)) * 0.75 + 0.8), pinspacing=0.75
        ).label(top_label, "top", fontsize=10)
    )
    return d


def yang_fig3():
    """Yang Fig. 3: the S-curve module instantiated in the FPGA (ports of ``scurve_gen.v``)."""
    return _finish(
        _module(
            "Yang Fig. 3 — S-curve module instantiation (ports of firmware/fpga/scurve_gen.v)",
            ["clk", "reset_n"],
            ["m", "n", "speed", "freq", "cycle"],
            "scurve_gen",
        )
    )


def yang_fig4():
    """Yang Fig. 4: the basic pulse (PWM) model, reset, clk, cycle in and clkout (Yang eq. 8)."""
    return _finish(
        _module(
            "Yang Fig. 4 — basic pulse-frequency model: cycle = f_clk / f, 50 % duty",
            ["reset", "clk", "cycle"],
            ["clkout"],
            "PWM model",
        )
    )


def yang_fig5():
    """Yang Fig. 5: the pulse divider instantiated in the FPGA (ports of ``pulse_divider.v``)."""
    return _finish(
        _module(
            "Yang Fig. 5 — pulse divider instantiation (ports of firmware/fpga/pulse_divider.v, "
            "corrected: cycle latched)",
            ["clk", "reset_n", "cycle[31:0]"],
            ["clkout", "count[31:0]"],
            "pulse_divider",
        )
    )


#: The schematic drawings, ``figure id: function`` (xu_fig3 is a plot and takes a cycle).
ALL_DIAGRAMS = {
    "Stojčić Fig. 2": stojcic_fig2,
    "Stojčić Fig. 3": stojcic_fig3,
    "Stojčić Fig. 5": stojcic_fig5,
    "Stojčić Fig. 6": stojcic_fig6,
    "Xu & Meckl Fig. 1": xu_fig1,
    "Xu & Meckl Fig. 8": xu_fig8,
    "Yang Fig. 1": yang_fig1,
    "Yang Fig. 3": yang_fig3,
    "Yang Fig. 4": yang_fig4,
    "Yang Fig. 5": yang_fig5,
}
