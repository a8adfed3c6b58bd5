"""The rig's wiring, as data and as a drawing (docs/RIG.md).

:data:`CONNECTIONS` lists every wire of the Stojčić (ASCII: Stojcic, 2015) positioning rig: an Arduino Uno,
an L298N dual H-bridge module, a 12 V supply and a DC gearmotor with a quadrature encoder.
:func:`wiring_diagram` draws exactly those wires with matplotlib (no extra dependency);
``tests/test_wiring.py`` reads the pins back from the drawing and checks them against the pin
map parsed from the firmware (``firmware/jerklab_rig/jerklab_rig.ino``).

Regenerate the pictures of docs/RIG.md (the wiring, and :func:`mechanics_drawing`: bracket, hub,
flexible load, guard) with::

    python -m jerklab.wiring docs/rig_wiring.png docs/rig_mechanics.png
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from jerklab.rig.flexload import DESIGN_RANGE, RulerLoad, predict
from jerklab.rig.profiles import builtin_profiles

__all__ = [
    "Wire",
    "CONNECTIONS",
    "PARTS",
    "PINS",
    "UNUSED",
    "wiring_diagram",
    "pin_positions",
    "lead_colours",
    "mechanics_drawing",
    "main",
]


@dataclass(frozen=True)
class Wire:
    """One wire: from ``a`` to ``b`` (each ``"Part.pin"``), carrying ``signal``."""

    a: str
    b: str
    signal: str
    kind: str  # "signal", "encoder", "power", "ground", "motor"


#: Every wire of the rig. Uno pins are Arduino names (D9 = ATmega328P PB1/OC1A, D2 = PD2/INT0,
#: D3 = PD3/INT1, D7 = PD7, D8 = PB0). The L298N's ENA jumper is removed so that D9's PWM
#: drives the enable; its 5V terminal stays open (the module's regulator feeds its logic from
#: the 12 V supply with the 5V-EN jumper fitted); the Uno is powered by USB.
#: The supply's + runs through a 2 A slow fuse and the switch (the emergency stop, within reach) to
#: the L298N's 12V terminal; its - and the Uno's GND share the L298N's GND screw terminal.
CONNECTIONS = (
    Wire("Uno.D9", "L298N.ENA", "PWM 7.8 kHz (OC1A)", "signal"),
    Wire("Uno.D8", "L298N.IN2", "direction IN2", "signal"),
    Wire("Uno.D7", "L298N.IN1", "direction IN1", "signal"),
    Wire("Uno.D2", "Encoder.A", "encoder A (INT0)", "encoder"),
    Wire("Uno.D3", "Encoder.B", "encoder B (INT1)", "encoder"),
    Wire("Uno.5V", "Encoder.VCC", "encoder supply 5 V", "power"),
    Wire("Uno.GND2", "Encoder.GND", "encoder ground", "ground"),
    Wire("Uno.GND1", "L298N.GND", "common ground", "ground"),
    Wire("Supply.+12V", "Fuse.in", "+12 V", "power"),
    Wire("Fuse.out", "Switch.in", "+12 V fused", "power"),
    Wire("Switch.out", "L298N.+12V", "motor supply 12 V", "power"),
    Wire("Supply.GND", "L298N.GND", "supply ground", "ground"),
    Wire("L298N.OUT1", "Motor.M+", "motor +", "motor"),
    Wire("L298N.OUT2", "Motor.M-", "motor -", "motor"),
)

#: Boxes of the drawing: name -> (x0, y0, x1, y1, title). The motor and its encoder are one part
#: with one 6-wire lead (the listed motors); the drawing frames them together.
PARTS = {
    "Uno": (0.0, -1.0, 3.0, 11.5, "Arduino Uno\n(USB to the PC)"),
    "L298N": (7.0, 4.6, 10.5, 10.0, "L298N module\nENA jumper REMOVED\n5V terminal: open"),
    "Supply": (17.0, 11.0, 20.5, 13.0, "12 V >= 2 A\nsupply"),
    "Fuse": (14.6, 11.9, 16.2, 12.9, "fuse 2 A T"),
    "Switch": (12.0, 11.9, 13.6, 12.9, "switch"),
    "Motor": (13.5, 6.6, 17.0, 10.0, "DC gearmotor"),
    "Encoder": (13.5, -1.0, 17.5, 4.6, "quadrature encoder\n(on the motor shaft)"),
}

#: Pins of the L298N's header drawn but not wired (its physical order: ENA IN1 IN2 IN3 IN4 ENB).
UNUSED = ("L298N.IN3", "L298N.IN4", "L298N.ENB")

#: Pin positions on the box edges: "Part.pin" -> (x, y).
PINS = {
    "Uno.GND1": (3.0, 10.6),
    "Uno.D9": (3.0, 9.3),
    "Uno.D7": (3.0, 8.5),
    "Uno.D8": (3.0, 7.7),
    "Uno.D2": (3.0, 3.9),
    "Uno.D3": (3.0, 3.1),
    "Uno.5V": (3.0, 2.1),
    "Uno.GND2": (3.0, 1.3),
    "L298N.ENA": (7.0, 9.3),
    "L298N.IN1": (7.0, 8.5),
    "L298N.IN2": (7.0, 7.7),
    "L298N.IN3": (7.0, 7.2),
    "L298N.IN4": (7.0, 6.7),
    "L298N.ENB": (7.0, 6.2),
    "L298N.GND": (8.0, 10.0),
    "L298N.+12V": (9.0, 10.0),
    "L298N.OUT1": (10.5, 9.3),
    "L298N.OUT2": (10.5, 8.5),
    "Supply.+12V": (17.0, 12.4),
    "Supply.GND": (17.0, 11.4),
    "Fuse.in": (16.2, 12.4),
    "Fuse.out": (14.6, 12.4),
    "Switch.in": (13.6, 12.4),
    "Switch.out": (12.0, 12.4),
    "Motor.M+": (13.5, 9.3),
    "Motor.M-": (13.5, 8.5),
    "Encoder.A": (13.5, 3.9),
    "Encoder.B": (13.5, 3.1),
    "Encoder.VCC": (13.5, 2.1),
    "Encoder.GND": (13.5, 1.3),
}

_COLOURS = {
    "signal": "tab:blue",
    "encoder": "tab:green",
    "power": "tab:red",
    "ground": "black",
    "motor": "tab:orange",
}


def _route(wire):
    """Polyline of a wire from pin ``a`` to pin ``b`` (horizontal/vertical segments)."""
    (xa, ya), (xb, yb) = PINS[wire.a], PINS[wire.b]
    if ya == yb or xa == xb:
        return [(xa, ya), (xb, yb)]
    if wire.a == "Uno.GND1":  # over the L298N to its ground terminal
        return [(xa, ya), (xb, ya), (xb, yb)]
    return [(xa, ya), (xb, ya), (xb, yb)]  # supply wires: across, then down to the terminal


#: the motor's and the encoder's pins on the lead -> the key of a profile's ``wires``
_LEAD = {
    "Motor.M+": "motor +",
    "Motor.M-": "motor -",
    "Encoder.VCC": "encoder VCC",
    "Encoder.GND": "encoder GND",
    "Encoder.A": "encoder A",
    "Encoder.B": "encoder B",
}


def _lead_profiles():
    return [p for p in builtin_profiles().values() if p.wires]


def _lead_titles():
    return [p.title for p in _lead_profiles()]


def lead_colours() -> dict:
    """``"Part.pin"`` -> the colour of its wire on each listed motor's lead (the built-in
    profiles with ``wires``, in their order; ``jerklab.rig.profiles``)."""
    profs = _lead_profiles()
    return {key: tuple(p.wires[w] for p in profs) for key, w in _LEAD.items()}


def pin_positions():
    """Copy of :data:`PINS` (``"Part.pin"`` -> ``(x, y)`` in drawing units)."""
    return dict(PINS)


def wiring_diagram(ax=None):
    """Draw the rig's wiring (:data:`CONNECTIONS`) with matplotlib.

    Every pin is a text artist with ``gid`` ``"pin:Part.pin"`` at its position; every wire is a
    ``Line2D`` with ``gid`` ``"wire:<a>|<b>"`` whose first and last points lie on its two pins,
    so the drawing can be checked against the firmware's pin map (``tests/test_wiring.py``).

    Parameters
    ----------
    ax : matplotlib.axes.Axes, optional
        Axes to draw into; a new 11 x 8 inch figure when omitted.

    Returns
    -------
    matplotlib.figure.Figure
        The figure holding the drawing.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    if ax is None:
        fig, ax = plt.subplots(figsize=(11, 8))
    else:
        from matplotlib.axes import Axes

        if not isinstance(ax, Axes):
            raise TypeError(f"ax must be a matplotlib Axes, got {type(ax).__name__}")
        fig = ax.figure
    for name, (x0, y0, x1, y1, title) in PARTS.items():
        ax.add_patch(
            Rectangle(
                (x0, y0),
                x1 - x0,
                y1 - y0,
                facecolor="#f4f4f4",
                edgecolor="0.3",
                lw=1.5,
                gid=f"part:{name}",
            )
        )
        ax.text(
            (x0 + x1) / 2, y0 + 0.25, title, ha="center", va="bottom", fontsize=9, weight="bold"
        )
    # the motor and its encoder: one part, one 6-wire lead
    ax.add_patch(
        Rectangle(
            (13.2, -1.3),
            4.6,
            11.6,
            fill=False,
            edgecolor="0.4",
            lw=1.2,
            ls="--",
            gid="part:Gearmotor",
        )
    )
    ax.text(
        15.5, 5.6, "one 6-wire lead\n(motor + encoder)", ha="center", fontsize=8, style="italic"
    )
    for key, colours in lead_colours().items():
        x, y = PINS[key]
        ax.text(x + 0.15, y - 0.42, " / ".join(colours), fontsize=6.5, color="0.25", ha="left")
    ax.text(
        18.0,
        8.0,
        "wire colours\n" + "\n".join(f"{i + 1}: {t}" for i, t in enumerate(_lead_titles())),
        fontsize=7,
        va="top",
        color="0.25",
    )
    ax.text(
        8.0,
        10.95,
        "two wires in the GND screw:\nsupply − and Uno GND\n(twist them, or a ferrule)",
        fontsize=7,
        ha="center",
        va="bottom",
    )
    for key, (x, y) in PINS.items():
        part, pin = key.split(".", 1)
        x0, _, x1, _, _ = PARTS[part]
        label = "GND" if pin.startswith("GND") else "" if part in ("Fuse", "Switch") else pin
        if x == x1:
            kw = dict(ha="right", va="center", xytext=(-3, 0))
        elif x == x0:
            kw = dict(ha="left", va="center", xytext=(3, 0))
        else:
            kw = dict(ha="center", va="top", xytext=(0, -3))
        ax.annotate(label, (x, y), textcoords="offset points", fontsize=8, gid=f"pin:{key}", **kw)
        ax.plot([x], [y], "o", ms=4, color="0.2")
    for wire in CONNECTIONS:
        pts = _route(wire)
        xs, ys = zip(*pts)
        ax.plot(
            xs,
            ys,
            "-",
            color=_COLOURS[wire.kind],
            lw=2,
            gid=f"wire:{wire.a}|{wire.b}",
            label=wire.kind,
            solid_capstyle="round",
        )
        (xa, ya), (xb, yb) = pts[0], pts[1]
        ax.text(
            (xa + xb) / 2,
            ya + 0.12,
            wire.signal,
            fontsize=7,
            ha="center",
            va="bottom",
            color=_COLOURS[wire.kind],
        )
    handles, labels = ax.get_legend_handles_labels()
    seen = {}
    for h, lab in zip(handles, labels):
        seen.setdefault(lab, h)
    ax.legend(
        seen.values(),
        seen.keys(),
        loc="lower center",
        ncol=5,
        fontsize=8,
        frameon=False,
        bbox_to_anchor=(0.5, -0.06),
    )
    ax.set_xlim(-0.5, 23.5)
    ax.set_ylim(-1.5, 13.5)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("jerklab rig wiring (Uno pins as in firmware/jerklab_rig/jerklab_rig.ino)")
    return fig


def mechanics_drawing(load=None):
    """Draw the mechanical set-up (docs/RIG.md), side view and top view, in millimetres.

    The motor stands shaft up in an L bracket screwed to the base plate; a hub on the shaft
    clamps the steel rule (the flexible load of :mod:`jerklab.rig.flexload`, free length and tip
    mass from ``load``, default ``RulerLoad()``; its build range dashed); a guard ring of the
    rule's swept radius plus 30 mm surrounds it; the supply switch sits on the plate.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    load = RulerLoad() if load is None else load
    if not isinstance(load, RulerLoad):
        raise TypeError(f"load must be a jerklab.rig.flexload.RulerLoad, got {type(load).__name__}")
    r0, L = 1000 * load.hub_radius, 1000 * load.length
    R = r0 + L
    guard = 1000 * (load.hub_radius + DESIGN_RANGE["length"][1]) + 30.0
    fig, (side, top) = plt.subplots(1, 2, figsize=(12, 6))
    # side view: base plate, bracket, motor (shaft up), hub, rule, tip mass, guard wall
    side.add_patch(Rectangle((-guard - 20, -12), 2 * guard + 40, 12, fc="#d9c9a3", ec="0.3"))
    side.add_patch(Rectangle((-25, 0), 50, 4, fc="0.7", ec="0.3"))  # bracket foot
    side.add_patch(Rectangle((-25, 0), 4, 75, fc="0.7", ec="0.3"))  # bracket web
    side.add_patch(Rectangle((-18.5, 4), 37, 68, fc="0.85", ec="0.2"))  # motor can + gearbox
    side.add_patch(Rectangle((-3, 72), 6, 18, fc="0.5", ec="0.2"))  # shaft
    side.add_patch(Rectangle((-r0, 82), 2 * r0, 10, fc="0.6", ec="0.2"))  # hub
    side.add_patch(
        Rectangle((-r0, 92), R + r0, 1000 * load.thickness * 2, fc="tab:blue", ec="tab:blue")
    )
    side.add_patch(Rectangle((R - 6, 86), 12, 14, fc="0.3", ec="0.1"))  # tip mass
    for x in (-guard, guard):
        side.add_patch(Rectangle((x - 1.5, 0), 3, 120, fc="#b3d9ff", ec="0.4"))  # guard wall
    side.annotate("", (R, 108), (0, 108), arrowprops=dict(arrowstyle="<->"))
    side.text(R / 2, 111, f"R = {R:.0f} mm (free length L = {L:.0f} mm)", ha="center", fontsize=8)
    for x, y, t in (
        (0, 20, "gear-\nmotor"),
        (-70, 80, "L bracket"),
        (R, 78, f"tip mass {1000 * load.tip_mass:.0f} g"),
        (0, -8, "base plate (plywood 18 mm), screwed to the bench"),
        (guard, 124, "guard (acrylic)"),
        (r0 + 20, 97, "steel rule (width vertical)"),
    ):
        side.text(x, y, t, ha="center", fontsize=8)
    side.set_xlim(-guard - 30, guard + 30)
    side.set_ylim(-20, 135)
    side.set_aspect("equal")
    side.set_xlabel("mm")
    side.set_title("side view")
    # top view: the rule's swept circle, the build range, the guard ring
    top.add_patch(Circle((0, 0), guard, fill=False, ec="0.4", lw=2))
    for Lx in DESIGN_RANGE["length"]:
        top.add_patch(
            Circle((0, 0), 1000 * (load.hub_radius + Lx), fill=False, ec="tab:blue", ls="--")
        )
    top.add_patch(Circle((0, 0), r0, fc="0.6", ec="0.2"))
    top.add_patch(
        Rectangle((0, -1000 * load.width / 2), R, 1000 * load.width, fc="tab:blue", alpha=0.5)
    )
    top.add_patch(Circle((R, 0), 8, fc="0.3"))
    f = predict(load)["mode_hz"]
    top.text(
        0,
        -guard - 18,
        f"mode with the hub held still: {f:.1f} Hz (Rayleigh)",
        ha="center",
        fontsize=8,
    )
    lo, hi = DESIGN_RANGE["length"]
    top.text(
        0,
        guard + 8,
        f"guard ring: radius {guard:.0f} mm; dashed: L = {1000 * lo:.0f}-{1000 * hi:.0f} mm",
        ha="center",
        fontsize=8,
    )
    top.set_xlim(-guard - 30, guard + 30)
    top.set_ylim(-guard - 30, guard + 30)
    top.set_aspect("equal")
    top.set_xlabel("mm")
    top.set_ylabel("mm")
    top.set_title("top view")
    fig.suptitle("jerklab rig: motor bracket, hub, flexible load (steel rule + tip mass), guard")
    return fig


def main(argv=None):
    """``python -m jerklab.wiring OUT.png``: save the drawing."""
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) not in (1, 2):
        print("usage: python -m jerklab.wiring OUT.png|OUT.svg [MECHANICS.png]", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    for out, draw in zip(argv, (wiring_diagram, mechanics_drawing)):
        fig = draw()
        fig.savefig(out, dpi=110, bbox_inches="tight")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
