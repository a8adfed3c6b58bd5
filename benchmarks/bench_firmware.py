"""Firmware cycle budget on a simulated ATmega328P (simavr), against the 5 ms control period.

Runs sine-jerk moves and a 12 V open-loop step on the real firmware ELF in the simavr harness
(as fast as the host allows: the budget is counted in CPU cycles, not wall time) and prints
the control step's cycles (min/mean/max while the motor moves, measured between the rises and
falls of the firmware's PB5 probe, interrupts included) as ratios of the 80 000-cycle period and
of the issue's 8000-cycle (10 %) ceiling; the INT0 latency against a quarter encoder period at
top speed; and flash/RAM against the Uno's. The peer is the budget itself, plus the naive
step measured in RIG-NOTES (three sinf/cosf per step, ~12 000 cycles), and for the input
shaper (SET_SHAPER, protocol version 3) the same moves without it: a ZV shaper on the Ts grid
(3 taps) and the longest the device takes (10 taps).

    python -m benchmarks firmware
"""
from __future__ import annotations

import math
import re
import time


def _session(port, commands, timeout=60.0):
    import serial

    from jerklab import protocol as pr

    msgs, dec = [], pr.Decoder()
    with serial.Serial(port, 115200, timeout=0.02) as ser:
        # handshake first: the session starts once the firmware has answered HELLO
        ser.write(pr.encode(pr.Hello(1), 0xA5))
        t0, info = time.monotonic(), None
        while info is None:
            if time.monotonic() - t0 > 10.0:
                raise RuntimeError(f"the simulated Uno on {port} did not answer HELLO within 10 s")
            info = next((f for f in dec.feed(ser.read(256)) if f.type == pr.MsgType.HELLO_REPLY), None)
        for i, m in enumerate(commands):
            ser.write(pr.encode(m, i + 1))
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            msgs += [pr.parse(f) for f in dec.feed(ser.read(4096))]
            if any(isinstance(m, pr.EndOfRun) for m in msgs):
                return msgs
    raise RuntimeError(f"no END_OF_RUN from the simulated Uno within {timeout} s "
                       f"(last messages: {msgs[-3:]})")


def main():
    from jerklab import protocol as pr
    from jerklab.controller import pole_placement_pid
    from jerklab.rig import simavr

    missing = simavr.tools_missing()
    if missing:
        print(f"skipped: needs {', '.join(missing)}")
        return
    out = simavr.build_firmware("avr", "size", "simavr")
    m = re.search(r"flash (\d+) / (\d+) bytes .*RAM (\d+) / (\d+) bytes", out["output"])
    period = 16e6 * 0.005
    K, tau, Vs = 32.4, 0.025, 12.0
    g = pole_placement_pid(K, tau, 20).discretize(0.005)
    # ZV for an 8 Hz mode (zeta 0.02) split on the 5 ms grid, and a 10-tap shaper spread over
    # the ring buffer (the worst case the device accepts)
    zv = pr.SetShaper(3, (0.26, 0.51, 0.23), (0, 12, 13))
    ten = pr.SetShaper(10, (0.1,) * 10, tuple(range(0, 127, 14))[:10])
    rows = []
    for label, cmds in [
        ("move 4*pi rad (J 2e4, E 300, W 100)",
         [pr.Plan(4 * math.pi, 0), pr.Run(50, 1)]),
        ("move 600 rad near top speed (J 380, E 300, W 370)",
         [pr.SetLimits(380.0, 300.0, 370.0, Vs, 0), pr.Plan(600.0, 0), pr.Run(50, 1)]),
        ("open-loop step 12 V, 0.5 s", [pr.Step(Vs, 5000, 100)]),
        ("move 4*pi rad, ZV shaper on (3 taps)",
         [zv, pr.Plan(4 * math.pi, 0), pr.Run(50, 1)]),
        ("move 4*pi rad, 10-tap shaper on",
         [ten, pr.Plan(4 * math.pi, 0), pr.Run(50, 1)]),
        ("move 600 rad near top speed, 10-tap shaper on",
         [ten, pr.SetLimits(380.0, 300.0, 370.0, Vs, 0), pr.Plan(600.0, 0), pr.Run(50, 1)]),
        ("open-loop PRBS 12 V (SEQUENCE), 0.5 s", [pr.Sequence(Vs, 0.0, 5000, 100, 1, 8, 1)]),
    ]:
        with simavr.launch(realtime=False, build=False) as uno:
            setup = [pr.SetPlant(K, tau, Vs, 448), pr.SetGains(g.kpd, g.kid, g.kdd, 5000, 0, 1, 0.0),
                     pr.SetLimits(2e4, 300.0, 100.0, Vs, 0)]
            t0 = time.perf_counter()
            _session(uno.port, setup + cmds)
            wall = time.perf_counter() - t0
            s = uno.stats()
        b = s["control_step_cycles_moving"]
        rows.append((label, b["n"], b["min"], b["mean"], b["max"], b["max"] / period, b["max"] / 8000,
                     s["int0_latency_cycles"]["max"], s["sim_seconds"] / wall))
    print("control step on the simulated Uno (cycles at 16 MHz, while moving, interrupts included)")
    print(f"{'case':52s} {'steps':>6s} {'min':>6s} {'mean':>7s} {'max':>6s} {'max/Ts':>7s} "
          f"{'max/8000':>8s} {'INT0 lat':>8s} {'sim/wall':>8s}")
    for r in rows:
        print(f"{r[0]:52s} {r[1]:6d} {r[2]:6d} {r[3]:7.0f} {r[4]:6d} {r[5]:7.3f} {r[6]:8.3f} "
              f"{r[7]:8d} {r[8]:8.1f}")
    quarter = 16e6 / (4 * 448 * K * Vs / (2 * math.pi))
    print(f"INT0 latency budget at top speed (quarter encoder period): {quarter:.0f} cycles")
    worst = max(r[4] for r in rows)
    print(f"worst step / naive step with three trig calls (RIG-NOTES, ~12000 cycles): {worst / 12000:.2f}")
    if m:
        f, ft, r_, rt = (int(x) for x in m.groups())
        print(f"flash {f} / {ft} B = {f / ft:.3f} of the Uno, RAM {r_} / {rt} B = {r_ / rt:.3f} "
              f"(budget <= 0.75 each since protocol 3; was 0.5)")


if __name__ == "__main__":
    main()
