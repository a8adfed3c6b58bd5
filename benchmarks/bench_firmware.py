"""Firmware cycle budget on a simulated ATmega328P (simavr), at Ts = 5 ms and at Ts = 1 ms.

Runs moves of every planner, one near top speed, and a 12 V open-loop step on the real firmware
ELF in the simavr harness (as fast as the host allows: the budget is counted in CPU cycles, not
wall time) and prints the control step's cycles against the period and against the issue-21
ceiling of 4000 cycles (25 % of 1 ms). The control step is what the default build's PB5 probe
spans, interrupts included: encoder read, safety checks, PID + feedforward, PWM write, the
reference of the next sample (planner sample, feedforward, SET_SHAPER's FIR) and the TELEMETRY
frame (encode, CRC, into the UART ring) -- min/mean/max over the ticks while the motor moves. The
work done after it in the idle time before the next tick (the next chunk's coefficients,
re-targeting, the shaper's delayed taps) is measured separately (probe build 7) and the CPU load
per period reported with it. It also prints whether an encoder count was lost (the firmware's
count against the harness's ideal one, and INT0 latency against a quarter encoder period at top
speed), then where the cycles of a 1 ms tick go, from builds that raise the probe around one part
each (``-DJL_PROBE_PART=n``), and flash/RAM against the Uno's.

    python -m benchmarks firmware

It does so for each build of the control law (``BUILDS``: the default, the C++ law of
firmware/jerklab_rig/src/jl_law.h; ``JL_ASM=1``, its assembly twin), each with its flash, RAM
and stack margin (the lowest stack pointer the harness saw, interrupts included, above the end
of .bss, over PLAN of every planner, RUN with a RETARGET and a HEARTBEAT flood, SET_SHAPER,
SEQUENCE and STEP); the parts table for the default build only.

The runs use the sketch built for 115200 baud at 5 ms and for 1 Mbaud (``JL_BAUD``) at 1 ms, so
a TELEMETRY goes out at every sample (115200 baud carries ~11.8 bytes/ms, a 22-byte frame every
3rd sample at 1 ms).
"""

from __future__ import annotations

import math
import re
import time


def _session(port, commands, timeout=60.0, baud=115200):
    import serial

    from jerklab import protocol as pr

    msgs, dec = [], pr.Decoder()
    with serial.Serial(port, baud, timeout=0.02) as ser:
        # handshake first: the session starts once the firmware has answered HELLO
        ser.write(pr.encode(pr.Hello(pr.PROTOCOL_VERSION), 0xA5))
        t0, info = time.monotonic(), None
        while info is None:
            if time.monotonic() - t0 > 10.0:
                raise RuntimeError(f"the simulated Uno on {port} did not answer HELLO within 10 s")
            info = next(
                (f for f in dec.feed(ser.read(256)) if f.type == pr.MsgType.HELLO_REPLY), None
            )
        # one command at a time, each after the previous reply (at 1 Mbaud a burst of frames
        # would overrun the firmware's 64-byte receive ring while it handles the first)
        for i, m in enumerate(commands):
            ser.write(pr.encode(m, i + 1))
            if isinstance(m, (pr.Run, pr.Step, pr.Sequence)):
                break
            t0, seen = time.monotonic(), len(msgs)
            # this command's own reply: one that arrives after it was sent (a PLAN_SEGMENT's
            # ACK carries the same command byte as the previous segment's)
            while not any(
                getattr(x, "command", None) == int(m.TYPE) or isinstance(x, pr.PlanInfo)
                for x in msgs[seen:]
            ):
                if time.monotonic() - t0 > 10.0:
                    raise RuntimeError(
                        f"no reply to {m} from the simulated Uno (last: {msgs[-3:]})"
                    )
                msgs += [pr.parse(f) for f in dec.feed(ser.read(256))]
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            msgs += [pr.parse(f) for f in dec.feed(ser.read(4096))]
            if any(isinstance(m, pr.EndOfRun) for m in msgs):
                return msgs
    raise RuntimeError(
        f"no END_OF_RUN from the simulated Uno within {timeout} s (last messages: {msgs[-3:]})"
    )


K, TAU, VS = 32.4, 0.025, 12.0


#: the moves of every planner: distance (rad) and the limits SetLimits sends (J, E, W)
MOVE = (4 * math.pi, 2e4, 300.0, 100.0)


def _segments(profile):
    """The PLAN_SEGMENTs and PLAN_COMMIT of ``profile`` (the host's plan, as Rig.run_move sends)."""
    from jerklab import protocol as pr

    segs, commit = pr.profile_segments(profile)
    return [*segs, commit]


def _cases(Ts_us):
    from jerklab import protocol as pr
    from jerklab.planner import plan_scurve, plan_sine_jerk_optimal, plan_trapezoid

    top = 600.0 if Ts_us == 5000 else 150.0
    return [
        ("sine-jerk 4*pi rad (J 2e4, E 300, W 100)", [pr.Plan(4 * math.pi, 0)]),
        (
            f"sine-jerk {top:g} rad near top speed (J 380, W 370)",
            [pr.SetLimits(380.0, 300.0, 370.0, VS, 0), pr.Plan(top, 0)],
        ),
        # planners 1-3 are the host's (protocol 5): their segments, PLAN_SEGMENT and PLAN_COMMIT
        ("optimal sine 4*pi rad (host-planned)", _segments(plan_sine_jerk_optimal(*MOVE))),
        ("S-curve 4*pi rad (host-planned)", _segments(plan_scurve(*MOVE))),
        ("trapezoid 4*pi rad (host-planned)", _segments(plan_trapezoid(MOVE[0], *MOVE[2:]))),
        # protocol 3's input shaper (SET_SHAPER): a ZV shaper split on the grid (3 taps) and the
        # longest the default firmware takes (10 taps over its 31-sample history); the FIR runs
        # with the reference one tick ahead, after the PWM write
        (
            "sine-jerk 4*pi rad, ZV shaper (3 taps)",
            [pr.SetShaper(3, (0.26, 0.51, 0.23), (0, 12, 13)), pr.Plan(4 * math.pi, 0)],
        ),
        (
            f"sine-jerk {top:g} rad near top speed, 10-tap shaper",
            [
                pr.SetShaper(10, (0.1,) * 10, tuple(range(0, 30, 3))),
                pr.SetLimits(380.0, 300.0, 370.0, VS, 0),
                pr.Plan(top, 0),
            ],
        ),
    ]


def _run(elf, Ts_us, cmds, baud, run=True):
    from jerklab import protocol as pr
    from jerklab.controller import pole_placement_pid
    from jerklab.rig import simavr

    g = pole_placement_pid(K, TAU, 20).discretize(Ts_us * 1e-6)
    with simavr.launch(elf, realtime=False, build=False) as uno:
        setup = [
            pr.SetPlant(K, TAU, VS, 448),
            pr.SetGains(g.kpd, g.kid, g.kdd, Ts_us, 0, 1, 0.0),
            pr.SetLimits(2e4, 300.0, 100.0, VS, 0),
        ]
        t0 = time.perf_counter()
        msgs = _session(uno.port, setup + cmds + ([pr.Run(50, 1)] if run else []), baud=baud)
        wall = time.perf_counter() - t0
        s = uno.stats()
    end = next(m for m in msgs if isinstance(m, pr.EndOfRun))
    return s, end, wall


# The builds of the control law compared (firmware/README.md "Change the control law"): the
# default (the C++ law, its multiply-accumulate the assembly primitive) and JL_ASM=1 (the law's
# hand-written assembly twin)
BUILDS = [("default", ()), ("JL_ASM=1", ("-DJL_ASM=1",))]


def _stack_margin(elf, tmp):
    """Bytes between the lowest stack pointer the harness saw (interrupts included) and the end
    of .bss, over PLAN of every planner, RUN with a RETARGET, SET_SHAPER, SEQUENCE, STEP and a
    HEARTBEAT flood during a run."""
    import subprocess

    from jerklab import protocol as pr
    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.planner import plan_scurve, plan_sine_jerk, plan_sine_jerk_optimal, plan_trapezoid
    from jerklab.rig import Link, connect, simavr
    from jerklab.shaping import input_shaper

    nm = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    bss_end = (
        next(int(ln.split()[0], 16) for ln in nm.splitlines() if ln.endswith(" __bss_end"))
        - 0x800000
    )
    g = discrete_pole_placement_pid(K, TAU, 20.0, Ts=0.005, extra_pole=0.5)
    d, J, E, W = 4 * math.pi, 2000.0, 300.0, 60.0
    profiles = [
        plan_sine_jerk(d, J, E, W),
        plan_sine_jerk_optimal(d, J, E, W),
        plan_scurve(d, J, E, W),
        plan_trapezoid(d, E, W),
    ]
    with simavr.launch(elf, K=K, tau=TAU, build=False) as sim:
        with connect(sim.port, recordings=tmp, progress=False, link=Link(timeout=10.0)) as rig:
            rig.set_model(K, TAU)
            for prof in profiles:
                rig.run_move(prof, g, Ts=0.005, settle=0.05)

            def cb(k, r, y):
                if k == 10:
                    rig.retarget(25.0)
                if k % 3 == 0:  # a HEARTBEAT flood on top of the client's own
                    for _ in range(4):
                        rig._write(pr.Heartbeat())

            rig.run_move(profiles[1], g, Ts=0.005, settle=0.05, on_telemetry=cb)
            rig.set_shaper(input_shaper("zv", 8.0, 0.05), Ts=0.005)
            rig.run_move(profiles[0], g, Ts=0.005, settle=0.05)
            rig.set_shaper(None, Ts=0.005)
            rig.record_prbs(2.0, 0.2, Ts=0.005)
            rig.step(3.0, 0.1)
        st = sim.stats()
    return st["stack_min_sp"] + 1 - bss_end


def main():
    import tempfile

    from jerklab.rig import simavr

    missing = simavr.tools_missing()
    if missing:
        print(f"skipped: needs {', '.join(missing)}")
        return
    fw = simavr.firmware_dir()
    simavr.build_firmware("simavr")
    for i, (name, defines) in enumerate(BUILDS):
        print(f"\n=== build: {name} ===")
        bdir = fw / "build" / f"bench-{name.replace('=', '')}"
        out = simavr.build_firmware("avr", "size", build_dir=bdir, defines=defines)
        m = re.search(r"flash (\d+) / (\d+) bytes .*RAM (\d+) / (\d+) bytes", out["output"])
        f, ft, r_, rt = (int(x) for x in m.groups())
        print(f"flash {f} B ({f / ft:.1%} of {ft}), RAM {r_} B ({r_ / rt:.1%} of {rt})")
        with tempfile.TemporaryDirectory() as tmp:
            print(f"stack margin {_stack_margin(out['elf'], tmp)} B (lowest SP above .bss's end)")
        _cycles(fw, name, defines, parts=i == 0)


def _cycles(fw, name, defines, parts):
    from jerklab import protocol as pr
    from jerklab.rig import simavr

    # the control step: the default build's probe (encoder read -> PWM write, next reference,
    # TELEMETRY)
    tag = name.replace("=", "")
    whole = {
        baud: simavr.build_firmware(
            "avr", build_dir=fw / "build" / f"step{baud}-{tag}", baud=baud, defines=defines
        )["elf"]
        for baud in (115200, 1000000)
    }
    rows, groups = [], {}
    for Ts_us, baud in [(5000, 115200), (1000, 1000000)]:
        cases = _cases(Ts_us) + [
            (f"open-loop step 12 V, {100 * Ts_us / 1e6:g} s", [pr.Step(VS, Ts_us, 100)]),
            (
                f"open-loop PRBS 12 V (SEQUENCE), {100 * Ts_us / 1e6:g} s",
                [pr.Sequence(VS, 0.0, Ts_us, 100, 1, 8, 1)],
            ),
        ]
        for label, cmds in cases:
            s, end, wall = _run(
                whole[baud], Ts_us, cmds, baud, run=not label.startswith("open-loop")
            )
            b = s["control_step_cycles_moving"]
            lost = abs(
                s.get("firmware_counts", s["ideal_counts_x1"]) - s["ideal_counts_x1"]
            )  # counts
            rows.append(
                (
                    Ts_us,
                    label,
                    b["n"],
                    b["min"],
                    b["mean"],
                    b["max"],
                    b["max"] / (16 * Ts_us),
                    b["max"] / 4000,
                    s["int0_latency_cycles"]["max"],
                    lost,
                    end.overruns,
                    s["sim_seconds"] / wall,
                )
            )
            if not label.startswith("open-loop"):
                # the line over the unshaped closed-loop moves; SET_SHAPER's FIR and the
                # moves of polynomial segments only (no half-sine pulse) on lines of their own
                group = "shaped" if "shaper" in label else "unshaped"
                for g in (
                    (group, "polynomial")
                    if label.startswith(("S-curve", "trapezoid"))
                    else (group,)
                ):
                    wm, wx = groups.setdefault((Ts_us, g), (0.0, 0))
                    groups[(Ts_us, g)] = (max(wm, b["mean"]), max(wx, b["max"]))
    print(
        "control step on the simulated Uno = the default build's D13 probe (encoder read, PID + "
        "feedforward, PWM write, the next sample's reference, TELEMETRY; cycles at 16 MHz while "
        "moving, interrupts included; the idle-time work after it: see the parts table)"
    )
    print(
        f"{'Ts':>5s} {'case':46s} {'steps':>6s} {'min':>6s} {'mean':>7s} {'max':>6s} {'max/Ts':>7s} "
        f"{'max/4000':>8s} {'INT0 lat':>8s} {'lost':>5s} {'ovr':>4s} {'sim/wall':>8s}"
    )
    for r in rows:
        print(
            f"{r[0] / 1000:4g}ms {r[1]:46s} {r[2]:6d} {r[3]:6d} {r[4]:7.0f} {r[5]:6d} {r[6]:7.3f} "
            f"{r[7]:8.3f} {r[8]:8d} {r[9]:5d} {r[10]:4d} {r[11]:8.1f}"
        )
    for Ts_us in (5000, 1000):
        for g, what, head in [
            ("unshaped", "the closed-loop moves without SET_SHAPER", ""),
            ("shaped", "the moves with SET_SHAPER's FIR", " with SET_SHAPER"),
            ("polynomial", "S-curve and trapezoid, no half-sine pulse", " on polynomial segments"),
        ]:
            mean, mx = groups[(Ts_us, g)]
            print(
                f"control step at Ts={Ts_us // 1000} ms{head}: max {mx} cycles (mean {mean:.0f}; "
                f"worst tick over {what}; {mx / (16 * Ts_us):.3f} of the period, "
                f"{mx / 4000:.2f} x the 4000-cycle ceiling)"
            )
    quarter = 16e6 / (4 * 448 * K * VS / (2 * math.pi))
    print(f"INT0 latency budget at top speed (quarter encoder period): {quarter:.0f} cycles")
    if not parts:
        return

    # where a 1 ms tick's cycles go: one probe build per part (0 = the default build's probe)
    parts = [
        (0, "control step (the default build's probe)"),
        (3, "  encoder read -> PWM write (Device::control)"),
        (4, "    of which the PID"),
        (8, "  reference of the next sample (Device::reference)"),
        (6, "  TELEMETRY frame: encode, CRC, into the UART ring"),
        (7, "idle-time work after the step (Device::background)"),
    ]
    for ci in (1, 3):
        label0 = _cases(1000)[ci][0]
        print(
            f"\nparts of a 1 ms tick ({label0}; each part's own probe build; interrupts included)"
        )
        print(f"{'part':66s} {'n':>6s} {'mean':>7s} {'max':>6s} {'max/4000':>8s}")
        means = {}
        for n, label in parts:
            b_dir = fw / "build" / (f"probe{n}-{tag}" if n else f"step1000000-{tag}")
            simavr.build_firmware(
                "avr", build_dir=b_dir, baud=1000000, probe_part=n or None, defines=defines
            )
            s, end, wall = _run(b_dir / "jerklab_rig.elf", 1000, _cases(1000)[ci][1], 1000000)
            b = s["control_step_cycles_all"]
            means[n] = (b["mean"], b["max"])
            print(f"{label:66s} {b['n']:6d} {b['mean']:7.0f} {b['max']:6d} {b['max'] / 4000:8.3f}")
        print(
            f"CPU load per 1 ms period (step + idle-time work, means): "
            f"{(means[0][0] + means[7][0]) / 16000:.3f}; worst single period <= "
            f"{(means[0][1] + means[7][1]) / 16000:.3f}"
        )


if __name__ == "__main__":
    main()
