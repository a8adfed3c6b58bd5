"""The rig's wiring, as data and as a drawing (docs/RIG.md).

:data:`CONNECTIONS` lists every wire of the Stojčić (ASCII: Stojcic, 2015) positioning rig: an Arduino Uno,
an L298N dual H-bridge module, a 12 V supply and a DC gearmotor with a quadrature encoder.
:func:`wiring_diagram` draws exactly those wires with matplotlib (no extra dependency);
``tests/test_wiring.py`` reads the pins back from the drawing and checks them against the pin
map parsed from the firmware (``firmware/jerklab_rig/jerklab_rig.ino``).

Regenerate the picture of docs/RIG.md with::

    python -m jerklab.wiring docs/rig_wiring.png
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

__all__ = ["Wire", "CONNECTIONS", "PARTS", "PINS", "wiring_diagram", "pin_positions", "main"]


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
CONNECTIONS = (
    Wire("Uno.D9", "L298N.ENA", "PWM 7.8 kHz (OC1A)", "signal"),
    Wire("Uno.D8", "L298N.IN2", "direction IN2", "signal"),
    Wire("Uno.D7", "L298N.IN1", "direction IN1", "signal"),
    Wire("Uno.D2", "Encoder.A", "encoder A (INT0)", "encoder"),
    Wire("Uno.D3", "Encoder.B", "encoder B (INT1)", "encoder"),
    Wire("Uno.5V", "Encoder.VCC", "encoder supply 5 V", "power"),
    Wire("Uno.GND2", "Encoder.GND", "encoder ground", "ground"),
    Wire("Uno.GND1", "L298N.GND", "common ground", "ground"),
    Wire("Supply.+12V", "L298N.+12V", "motor supply 12 V", "power"),
    Wire("Supply.GND", "L298N.GND", "supply ground", "ground"),
    Wire("L298N.OUT1", "Motor.M+", "motor +", "motor"),
    Wire("L298N.OUT2", "Motor.M-", "motor -", "motor"),
)

#: Boxes of the drawing: name -> (x0, y0, x1, y1, title).
PARTS = {
    "Uno": (0.0, -1.0, 3.0, 11.5, "Arduino Uno\n(USB to the PC)"),
    "L298N": (7.0, 5.4, 10.5, 10.0, "L298N module\nENA jumper REMOVED\n5V terminal: open"),
    "Supply": (11.5, 11.0, 16.5, 13.0, "12 V >= 1 A\nsupply"),
    "Motor": (13.5, 6.6, 17.0, 10.0, "DC gearmotor"),
    "Encoder": (13.5, -1.0, 17.5, 4.6, "quadrature encoder\n(on the motor shaft)"),
}

#: Pin positions on the box edges: "Part.pin" -> (x, y).
PINS = {
    "Uno.GND1": (3.0, 10.6),
    "Uno.D9": (3.0, 9.3),
    "Uno.D8": (3.0, 8.5),
    "Uno.D7": (3.0, 7.7),
    "Uno.D2": (3.0, 3.9),
    "Uno.D3": (3.0, 3.1),
    "Uno.5V": (3.0, 2.1),
    "Uno.GND2": (3.0, 1.3),
    "L298N.ENA": (7.0, 9.3),
    "L298N.IN2": (7.0, 8.5),
    "L298N.IN1": (7.0, 7.7),
    "L298N.GND": (8.0, 10.0),
    "L298N.+12V": (9.0, 10.0),
    "L298N.OUT1": (10.5, 9.3),
    "L298N.OUT2": (10.5, 8.5),
    "Supply.+12V": (11.5, 11.4),
    "Supply.GND": (11.5, 12.4),
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
    for key, (x, y) in PINS.items():
        part, pin = key.split(".", 1)
        x0, _, x1, _, _ = PARTS[part]
        label = "GND" if pin.startswith("GND") else pin
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
        (xa, ya), (xb, _) = pts[0], pts[1]
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
    ax.set_xlim(-0.5, 18.0)
    ax.set_ylim(-1.5, 13.5)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("jerklab rig wiring (Uno pins as in firmware/jerklab_rig/jerklab_rig.ino)")
    return fig


def main(argv=None):
    """``python -m jerklab.wiring OUT.png``: save the drawing."""
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m jerklab.wiring OUT.png|OUT.svg", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    fig = wiring_diagram()
    fig.savefig(argv[0], dpi=110, bbox_inches="tight")
    print(f"wrote {argv[0]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
