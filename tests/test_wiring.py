"""The rig's wiring drawing (jerklab.wiring, docs/RIG.md) against the firmware's pin map.

The pins are parsed from the sketch (firmware/jerklab_rig/jerklab_rig.ino): the AVR port bits
of IN1, IN2 and the PWM output, which external interrupt reads which encoder channel, and the
Timer1 compare output that carries the PWM. The connections are read back from the drawing's
geometry (wire end points on pin positions), not from jerklab.wiring.CONNECTIONS.
"""

import pathlib
import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from jerklab import wiring  # noqa: E402

SKETCH = (
    pathlib.Path(__file__).resolve().parent.parent / "firmware" / "jerklab_rig" / "jerklab_rig.ino"
)

# ATmega328P on the Uno: port bit -> Arduino pin; INTn -> pin (datasheet / Uno schematic).
AVR_TO_ARDUINO = {
    **{f"PD{i}": f"D{i}" for i in range(8)},
    **{f"PB{i}": f"D{8 + i}" for i in range(6)},
}
INT_PIN = {"INT0": "PD2", "INT1": "PD3"}
OC1A = "PB1"


def firmware_pins():
    src = SKETCH.read_text(encoding="utf-8")
    consts = dict(re.findall(r"static const uint8_t (k\w+) = _BV\((P[BD]\d)\);", src))
    # IN1 is driven high for positive PWM, IN2 for negative (set_pwm)
    # (the Hal's function, jl::Hal::set_pwm on the AVR)
    body = src[re.search(r"void (?:\w+::)*set_pwm\(", src).start() :]
    body = body[: re.search(r"void (?:\w+::)*set_period\(", body).start()]
    pos = body[body.index("if (pwm > 0)") : body.index("else if (pwm < 0)")]
    high_pos = re.search(r"PORT[BD] \|= (k\w+);", pos).group(1)
    assert "OCR1A" in pos and "COM1A1" in src, "PWM must be Timer1's OC1A"
    assert consts["kPwm"] == OC1A
    # which channel each external interrupt reads: comments "Channel A edge" / "Channel B edge"
    chan = {}
    for m in re.finditer(
        r"// Channel (\w) edge[^\n]*\n(?:[^\n]*\n)*?ISR\((INT\d)_vect[^)]*\)", src
    ):
        chan[m.group(1)] = m.group(2)
    assert set(chan) == {"A", "B"}
    # both encoder inputs get pull-ups and are inputs
    assert re.search(r"PORTD \|= _BV\(PD2\) \| _BV\(PD3\)", src)
    return {
        "ENA": AVR_TO_ARDUINO[consts["kPwm"]],
        "IN1": AVR_TO_ARDUINO[consts[high_pos]],
        "IN2": AVR_TO_ARDUINO[consts["kIn2" if high_pos == "kIn1" else "kIn1"]],
        "A": AVR_TO_ARDUINO[INT_PIN[chan["A"]]],
        "B": AVR_TO_ARDUINO[INT_PIN[chan["B"]]],
    }


@pytest.fixture(scope="module")
def drawn():
    """Connections read back from the drawing: set of frozenset({pinA, pinB})."""
    fig = wiring.wiring_diagram()
    ax = fig.axes[0]
    pins = {}
    for t in ax.texts:
        gid = t.get_gid() or ""
        if gid.startswith("pin:"):
            pins[gid[4:]] = tuple(t.xy)
    assert pins, "no pins drawn"

    def at(pt):
        hits = [k for k, p in pins.items() if abs(p[0] - pt[0]) < 1e-9 and abs(p[1] - pt[1]) < 1e-9]
        assert len(hits) == 1, f"wire end {pt} is on {hits or 'no pin'}"
        return hits[0]

    conns = set()
    for line in ax.lines:
        gid = line.get_gid() or ""
        if not gid.startswith("wire:"):
            continue
        xs, ys = line.get_data()
        assert len(xs) >= 2
        # wires are horizontal/vertical runs
        for i in range(len(xs) - 1):
            assert xs[i] == xs[i + 1] or ys[i] == ys[i + 1], gid
        conns.add(frozenset((at((xs[0], ys[0])), at((xs[-1], ys[-1])))))
    plt.close(fig)
    return conns


def nets(conns):
    """Union-find of the drawn wires into electrical nets (sets of pins)."""
    parent = {}

    def find(x):
        parent.setdefault(x, x)
        while parent[x] != x:
            x = parent[x]
        return x

    for c in conns:
        a, b = tuple(c)
        parent[find(a)] = find(b)
    out = {}
    for x in list(parent):
        out.setdefault(find(x), set()).add(x)
    return [frozenset(s) for s in out.values()]


def test_firmware_pin_map_is_the_documented_one():
    # the sketch's header comment, docs/RIG.md and docs/INTERFACES.md name these; the parser must agree
    assert firmware_pins() == {"ENA": "D9", "IN1": "D7", "IN2": "D8", "A": "D2", "B": "D3"}


def test_drawn_signal_wires_match_firmware(drawn):
    fw = firmware_pins()
    expected = {
        frozenset((f"Uno.{fw['ENA']}", "L298N.ENA")),
        frozenset((f"Uno.{fw['IN1']}", "L298N.IN1")),
        frozenset((f"Uno.{fw['IN2']}", "L298N.IN2")),
        frozenset((f"Uno.{fw['A']}", "Encoder.A")),
        frozenset((f"Uno.{fw['B']}", "Encoder.B")),
    }
    uno_signal = {c for c in drawn if any(p.startswith("Uno.D") for p in c)}
    assert uno_signal == expected


def test_drawn_power_and_ground_nets(drawn):
    # the Uno's GND pins are one node on the board itself
    uno_gnd = sorted({p for c in drawn for p in c if p.startswith("Uno.GND")})
    board = {frozenset((uno_gnd[0], g)) for g in uno_gnd[1:]}
    ns = nets(drawn | board)

    def net_of(pin):
        (n,) = [n for n in ns if pin in n]
        return n

    gnd = net_of("L298N.GND")
    # common ground: supply, L298N, Uno and encoder on one net
    assert {"Supply.GND", "L298N.GND", "Encoder.GND"} <= gnd
    assert any(p.startswith("Uno.GND") for p in gnd)
    # encoder on the Uno's 5 V (the Uno's input pull-ups are to 5 V), never on 12 V
    assert net_of("Encoder.VCC") == {"Uno.5V", "Encoder.VCC"}
    # the 12 V through the fuse, then the switch, to the bridge
    assert net_of("Supply.+12V") == {"Supply.+12V", "Fuse.in"}
    assert net_of("Fuse.out") == {"Fuse.out", "Switch.in"}
    assert net_of("Switch.out") == {"Switch.out", "L298N.+12V"}
    # the motor only on the bridge outputs
    assert net_of("Motor.M+") == {"L298N.OUT1", "Motor.M+"}
    assert net_of("Motor.M-") == {"L298N.OUT2", "Motor.M-"}
    # nothing else: every drawn pin is in a net, the L298N 5V terminal is not drawn as used
    drawn_pins = set().union(*ns)
    assert not any(p == "L298N.5V" for p in drawn_pins)
    assert len(ns) == 5 + 7  # five signal nets, ground, 5 V, 12 V in three runs, M+, M-


def test_the_l298n_header_is_drawn_in_its_physical_order():
    # the module's header reads ENA IN1 IN2 IN3 IN4 ENB along its edge
    order = ["ENA", "IN1", "IN2", "IN3", "IN4", "ENB"]
    ys = [wiring.PINS[f"L298N.{p}"][1] for p in order]
    xs = {wiring.PINS[f"L298N.{p}"][0] for p in order}
    assert len(xs) == 1 and ys == sorted(ys, reverse=True)
    assert set(wiring.UNUSED) == {"L298N.IN3", "L298N.IN4", "L298N.ENB"}


def test_the_lead_colours_come_from_the_profiles():
    from jerklab.rig import load_profile

    colours = wiring.lead_colours()
    assert colours["Motor.M+"][0] == load_profile("pololu-37d-30").wires["motor +"]
    assert colours["Motor.M-"][-1] == load_profile("jgb37-520-30").wires["motor -"]
    assert set(colours) == {
        "Motor.M+",
        "Motor.M-",
        "Encoder.A",
        "Encoder.B",
        "Encoder.VCC",
        "Encoder.GND",
    }


def test_the_mechanics_drawing_is_made(tmp_path):
    out, mech = tmp_path / "w.png", tmp_path / "m.png"
    assert wiring.main([str(out), str(mech)]) == 0
    assert mech.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(TypeError, match="load"):
        wiring.mechanics_drawing(load=0.2)


def test_drawing_matches_its_table(drawn):
    assert drawn == {frozenset((w.a, w.b)) for w in wiring.CONNECTIONS}


def test_bad_axes_rejected():
    with pytest.raises(TypeError, match="ax"):
        wiring.wiring_diagram(ax="not an axes")


def test_main_writes_png(tmp_path):
    out = tmp_path / "w.png"
    assert wiring.main([str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
