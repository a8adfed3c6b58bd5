"""``jerklab rig check PORT``: the bring-up check of a rig, before the loop is closed.

Open-loop only (no gains are sent). Against the rig's motor profile (``--profile``, a built-in
name or a profile file; :mod:`jerklab.rig.profiles`):

1. **firmware**: its version, the protocol version of this jerklab, and the open-loop STEP;
2. **encoder**: counts while driving a short pulse each way (none: a dead or unplugged encoder,
   or a motor that did not turn);
3. **turn**: the counts of one revolution of the output shaft turned by hand, the way the arrow
   marked on the hub points (interactive: the check asks for it; ``--turn-counts N`` gives
   the count of a turn made before, for scripts and tests; the virtual rig turns itself);
4. **cpr** / **gear**: that count against the configured counts per revolution — a factor 2 or
   4 is the decoding (X1/X2/X4), a factor of the gear ratio is a count per *motor* revolution
   (or a gearbox other than the profile's), anything else another encoder;
5. **direction**: a hand turn that counts down is the encoder's A and B swapped; a positive
   voltage that turns the shaft against the arrow is the motor's leads reversed;
6. **supply** / **gear**: the steady speed per volt (the slope between two voltages, so friction
   drops out; Stojčić eq. 1, ASCII Stojcic eq. 1: ω = K (u − f_c) at rest of the transient)
   against the profile's K range: a factor of the gear ratio points to the gear ratio, any other
   low (high) K to the supply;
7. **friction**: the dead band f_c = u − ω/K against the profile's friction range.

Each finding prints what is wrong and how to fix it. Exit status 0 when every check passes.
``--save FILE`` writes the report as the rig's profile file (the profile with the measured
counts, K and friction), which ``jerklab.rig.connect(port, profile=FILE)``, the labs and
``jerklab app --profile FILE`` read.

    jerklab rig check /dev/ttyACM0 --profile pololu-37d-30 --save rig.json
    jerklab rig check COM3 --profile jgb37-520-30 --turn-counts 331
    jerklab rig check virtual                     # the paper's motor on the virtual rig
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
from dataclasses import dataclass

import numpy as np

from jerklab import __version__, paper
from jerklab import protocol as P
from jerklab.rig import Device, RigError, connect
from jerklab.rig.profiles import builtin_profiles, load_profile

__all__ = [
    "Finding",
    "CheckReport",
    "check_rig",
    "hand_turn",
    "format_report",
    "report_profile",
    "main",
]

#: measured over configured counts that are a decoding mistake (X1/X2/X4)
_CPR_FACTORS = (4.0, 2.0, 0.5, 0.25)
#: a hand turn is good to about ±10° of 360°
_TURN_TOLERANCE = 0.05
#: seconds the interactive hand turn records
TURN_SECONDS = 10.0


@dataclass
class Finding:
    """One check: ``name``, ``ok``, what was measured (``message``) and, if not ok, ``fix``."""

    name: str
    ok: bool
    message: str
    fix: str = ""

    def __str__(self):
        head = f"{'OK  ' if self.ok else 'FAIL'} {self.name:9s} {self.message}"
        return head + (f"\n               fix: {self.fix}" if self.fix else "")


class CheckReport(list):
    """The findings (a list of :class:`Finding`) and what was measured: ``turn_counts``,
    ``K``, ``friction`` (dead band, V), ``counts_per_rev`` (measured, or None)."""

    def __init__(self, findings=(), **measured):
        super().__init__(findings)
        self.measured = dict(measured)


def _speed(rec, tail=0.4):
    """Mean speed (counts/s) over the last ``tail`` of a step record, and the net counts."""
    c = np.asarray(rec.counts, float)
    t = np.asarray(rec.time, float)
    if c.size < 4:
        return 0.0, 0
    i0 = int(c.size * (1.0 - tail))
    span = t[-1] - t[i0]
    return (c[-1] - c[i0]) / span if span > 0 else 0.0, int(c[-1] - c[0])


def hand_turn(rig, seconds=TURN_SECONDS, ask=input, say=print) -> int:
    """Counts of one revolution turned by hand: asks the user to turn the marked output shaft
    once the way its arrow points, while a 0 V STEP records the encoder for ``seconds``; on the
    virtual rig a simulated hand turns it. Returns the net counts."""
    dev = getattr(rig.link, "device", None) if rig.is_virtual else None  # the in-process rig
    if dev is None:
        say(
            "Mark the output shaft (a piece of tape on the hub, an arrow for 'positive'). Press "
            f"Enter, then within {seconds:g} s turn the shaft by hand exactly one revolution the "
            "way the arrow points, and let go."
        )
        ask("Enter when ready ... ")
        say("turn now")
    else:
        dev.hand = 1.0
    try:
        rec = rig.step(0.0, seconds, Ts=0.01, rest=0.0, path=False, progress=False)
    finally:
        if dev is not None:
            dev.hand = None
    return _speed(rec)[1]


def _ratio_near(r, target, tol):
    return target > 0 and abs(r / target - 1.0) <= tol


def _profiles_with(counts):
    """Built-in profiles whose encoder gives ``counts`` a turn, at their decoding or at X1/X2/X4."""
    out = []
    for p in builtin_profiles().values():
        options = {p.counts_per_rev: ""}
        if p.counts_per_motor_rev and p.gear_ratio:
            for d, label in ((1, "x1"), (2, "x2"), (4, "x4")):
                options.setdefault(
                    round(p.counts_per_motor_rev / 4 * p.gear_ratio * d), f" at {label}"
                )
        out += [f"{p.name!r}{lab}" for c, lab in options.items() if abs(c / counts - 1) < 0.02]
    return out


class _GearFinding(Finding):
    """A gear-ratio finding that knows the gearbox measured (for the K expected after it)."""

    def __init__(self, gear_ratio, *args):
        super().__init__(*args)
        self.gear_ratio = gear_ratio


def _counts_finding(n, configured, prof):
    """The hand turn's count ``n`` (> 0) against the configured counts per revolution."""
    r = n / configured
    G = prof.gear_ratio if prof is not None else None
    if abs(r - 1.0) <= _TURN_TOLERANCE:
        return Finding(
            "cpr", True, f"one turn by hand gave {n} counts: {configured} counts/rev as configured"
        )
    if G and (_ratio_near(r, G, 0.1) or _ratio_near(r, 1.0 / G, 0.1)):
        if r > 1:
            why = (
                f"the configured {configured} is a count per *motor* revolution: times the "
                f"{G:g}:1 gear ratio it is about {n}"
            )
        else:
            why = f"the configured {configured} counts the {G:g}:1 gear ratio once too often"
        return Finding(
            "gear",
            False,
            f"one output revolution gave {n} counts, {r:.3g} x the configured {configured}: {why}",
            f"use counts_per_rev={n} (the profile {prof.name!r} says {prof.counts_per_rev}); in the "
            f"firmware JL_ENCODER_PPR is the pulses of one channel per *output* revolution",
        )
    for f in _CPR_FACTORS:
        if _ratio_near(r, f, 0.08):
            return Finding(
                "cpr",
                False,
                f"one turn by hand gave {n} counts, not the configured {configured} ({f:g} x): the "
                "encoder's decoding (X1/X2/X4 edges) and the configured count disagree",
                f"connect with counts_per_rev={n} (--cpr {n}), or the profile's decoding "
                "(the firmware decodes X1 when counts_per_rev equals JL_ENCODER_PPR, X2 at twice, "
                "X4 at four times)",
            )
    if G and prof.counts_per_motor_rev:
        # the encoder on the motor shaft: the count gives the gearbox (X1: a quarter of the CPR)
        per_motor_x1 = prof.counts_per_motor_rev / 4.0
        dec = prof.counts_per_rev / (per_motor_x1 * G)
        G_meas = n / (per_motor_x1 * dec)
        return _GearFinding(
            G_meas,
            "gear",
            False,
            f"one output revolution gave {n} counts, the profile {prof.name!r} expects "
            f"{prof.counts_per_rev}: with its encoder's {prof.counts_per_motor_rev} CPR on the motor "
            f"that is a {G_meas:.3g}:1 gearbox, not {G:g}:1",
            f"check the gear ratio printed on the motor (and its encoder); then use counts_per_rev={n} "
            "or the profile of the motor you have",
        )
    names = _profiles_with(n)
    return Finding(
        "cpr",
        False,
        f"one turn by hand gave {n} counts, the configured encoder {configured} counts/rev",
        f"use counts_per_rev={n} (--cpr {n})"
        + (f": the count of the profile {', '.join(names)}" if names else "")
        + "; in the firmware JL_ENCODER_PPR (pulses of channel A per output revolution)",
    )


def check_rig(
    rig,
    *,
    profile=None,
    K=None,
    tolerance=None,
    voltage=None,
    seconds=0.6,
    min_counts=4,
    turn_counts=None,
    turn=None,
) -> CheckReport:
    """Run the bring-up checks on an open :class:`~jerklab.rig.Rig`; return the findings.

    Parameters
    ----------
    rig : jerklab.rig.Rig
        Connected with the rig's ``supply_voltage`` and ``counts_per_rev`` (the configured encoder).
    profile : str, path or MotorProfile, optional
        The motor the rig should have (default ``rig.profile``); its K range, gear ratio,
        encoder and friction range are what the measurements are held against.
    K : float, optional
        The expected gain, rad/(V s) (Stojčić eq. 1): K within x/÷ ``tolerance`` passes. Default:
        the profile's K range, else the rig's model K.
    tolerance : float, optional
        Factor > 1 for ``K`` (default 1.5).
    voltage : float, optional
        The lower test voltage (V), default a quarter of the supply; the second is twice it.
    seconds : float
        Length of each steady turn (s); the speed is read over its last 40 %.
    min_counts : int
        Fewer counts than this during a pulse means no encoder signal.
    turn_counts : int, optional
        The counts of one output revolution turned by hand the way the marked arrow points.
    turn : callable, optional
        ``turn(rig) -> counts`` measures it (:func:`hand_turn`); used when ``turn_counts`` is
        None. None and no ``turn_counts``: the turn is not measured (a failed ``turn`` finding),
        except on the virtual rig, whose simulated hand turns it.

    Returns
    -------
    CheckReport
        The findings, with what was measured in ``.measured``.
    """
    prof = getattr(rig, "profile", None) if profile is None else load_profile(profile)
    if K is not None or prof is None:
        K = float(rig.model[0] if K is None else K)
        if not (math.isfinite(K) and K > 0):
            raise ValueError(f"K must be a positive number (rad/(V s)), got {K!r}")
        tol = 1.5 if tolerance is None else float(tolerance)
        if not (math.isfinite(tol) and tol > 1):
            raise ValueError(f"tolerance must be a factor > 1, got {tolerance!r}")
        K_nom, K_lo, K_hi = K, K / tol, K * tol
    else:
        if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 1):
            raise ValueError(f"tolerance must be a factor > 1, got {tolerance!r}")
        widen = 1.0 if tolerance is None else float(tolerance)
        K_nom, K_lo, K_hi = prof.K, prof.K_range[0] / widen, prof.K_range[1] * widen
    V1 = rig.supply_voltage / 4 if voltage is None else float(voltage)
    if not (0 < 2 * V1 <= rig.supply_voltage):
        raise ValueError(
            f"voltage must be in (0, supply/2 = {rig.supply_voltage / 2} V], got {voltage!r}"
        )
    if turn_counts is not None:
        if isinstance(turn_counts, bool) or int(turn_counts) != turn_counts:
            raise ValueError(f"turn_counts must be an integer count, got {turn_counts!r}")
        turn_counts = int(turn_counts)
    found = CheckReport(turn_counts=None, K=None, friction=None, counts_per_rev=None)

    # 1. firmware: the protocol is the contract (connect() refuses another version), STEP is needed
    fw = rig.firmware_version
    proto_ok = rig.info.protocol_version == P.PROTOCOL_VERSION
    has_step = bool(rig.capabilities & P.Capability.OPEN_LOOP_STEP)
    fix = ""
    if not proto_ok:
        fix = (
            f"the firmware speaks protocol {rig.info.protocol_version}, jerklab {__version__} speaks "
            f"{P.PROTOCOL_VERSION}: flash this jerklab's firmware "
            "(Arduino IDE: open firmware/jerklab_rig/jerklab_rig.ino, Upload; or make -C firmware "
            "upload PORT=...)"
        )
    elif not has_step:
        fix = (
            "this firmware has no open-loop STEP: flash the rig's firmware (Arduino IDE: open "
            "firmware/jerklab_rig/jerklab_rig.ino, Upload; or make -C firmware upload PORT=...)"
        )
    found.append(
        Finding(
            "firmware",
            proto_ok and has_step,
            f"{rig.name} firmware {fw}, protocol {rig.info.protocol_version}",
            fix,
        )
    )
    if not (proto_ok and has_step):
        return found

    def step(v, secs):
        return _speed(rig.step(v, secs, Ts=paper.TS, rest=0.0, path=False, progress=False))

    # 2. a short pulse each way: is there an encoder signal at all?
    _, up = step(+V1, 0.2)
    _, down = step(-V1, 0.2)
    if max(abs(up), abs(down)) < min_counts:
        found.append(
            Finding(
                "encoder",
                False,
                f"dead encoder: no counts while driving at ±{V1:g} V ({up:+d}, {down:+d} counts)",
                "encoder disconnected or unpowered: 5 V and GND to the encoder, A to D2, B to D3. If the "
                f"shaft did not turn either: check the {rig.supply_voltage:g} V supply, its fuse and "
                "switch, and the L298 (ENA on D9 with its jumper removed, IN1 D7, IN2 D8, common ground)",
            )
        )
        return found
    if abs(up) < min_counts or abs(down) < min_counts or (up > 0) == (down > 0):
        found.append(
            Finding(
                "direction",
                False,
                f"+{V1:g} V gave {up:+d} counts, -{V1:g} V gave {down:+d}: the motor "
                "does not turn both ways",
                "check the L298 direction inputs: IN1 on D7, IN2 on D8",
            )
        )
        return found
    found.append(
        Finding(
            "encoder", True, f"counts while driving ({up:+d} at +{V1:g} V, {down:+d} at -{V1:g} V)"
        )
    )

    # 3./4. one revolution by hand: the counts per output revolution, and the encoder's sign
    if (
        turn_counts is None
        and turn is None
        and rig.is_virtual
        and getattr(rig.link, "device", None) is not None
    ):
        turn = hand_turn  # the in-process virtual rig: its simulated hand
    if turn_counts is None and turn is not None:
        turn_counts = int(turn(rig))
    enc_sign = None
    counts_per_rad = rig.counts_per_rad
    if turn_counts is None:
        found.append(
            Finding(
                "turn",
                False,
                "the counts per output revolution were not measured by hand",
                "run the check in a terminal (it asks you to turn the marked shaft once), or give "
                "--turn-counts N, the counts of one revolution by hand",
            )
        )
    elif abs(turn_counts) < min_counts:
        found.append(
            Finding(
                "turn",
                False,
                f"one turn by hand gave {turn_counts:+d} counts",
                "turn the output shaft one full revolution within the time given; if the counts "
                "still stay at zero, the encoder's A/B wires are loose",
            )
        )
    else:
        n = abs(turn_counts)
        enc_sign = 1 if turn_counts > 0 else -1
        found.measured.update(turn_counts=turn_counts, counts_per_rev=n)
        counts_per_rad = n / (2.0 * math.pi)
        finding = _counts_finding(n, rig.counts_per_rev, prof)
        found.append(finding)
        if isinstance(finding, _GearFinding):  # another gearbox: K scales with 1/ratio
            found.measured["gear_ratio"] = finding.gear_ratio
            scale = prof.gear_ratio / finding.gear_ratio
            K_nom, K_lo, K_hi = K_nom * scale, K_lo * scale, K_hi * scale

    # 5. direction: the encoder's sign from the hand turn, the leads' from the drive
    drive = 1 if up > 0 else -1
    if enc_sign is None:
        if drive > 0:
            found.append(Finding("direction", True, "a positive voltage counts up"))
        else:
            found.append(
                Finding(
                    "direction",
                    False,
                    f"counts run against the drive ({up:+d} counts for +{V1:g} V)",
                    "if the shaft turned the way you call positive, swap the encoder's A and B (D2 <-> D3); "
                    "if it turned the other way, the motor leads are reversed: swap OUT1 and OUT2 at "
                    "the L298 (a hand turn tells which: --turn-counts)",
                )
            )
    else:
        shaft = drive * enc_sign  # +1: a positive voltage turns the shaft the arrow's way
        if enc_sign < 0:
            found.append(
                Finding(
                    "direction",
                    False,
                    "encoder A/B swapped: turning the shaft the arrow's way counts down "
                    f"({turn_counts:+d} counts)",
                    "swap the encoder's A and B (the wires on D2 and D3)",
                )
            )
        if shaft < 0:
            found.append(
                Finding(
                    "direction",
                    False,
                    f"motor leads reversed: +{V1:g} V turns the shaft against the arrow",
                    "swap the motor's two leads on OUT1 and OUT2 of the L298 (power off first)",
                )
            )
        if enc_sign > 0 and shaft > 0:
            found.append(
                Finding(
                    "direction",
                    True,
                    "the arrow's way counts up and a positive voltage turns it so",
                )
            )
    sign = drive

    # 6./7. speed per volt at V1 and 2 V1 (the slope: Coulomb friction drops out), the dead band
    w1, _ = step(+V1, seconds)
    w2, _ = step(+2 * V1, seconds)
    w1, w2 = sign * w1 / counts_per_rad, sign * w2 / counts_per_rad  # rad/s
    K_meas = (w2 - w1) / V1
    dead = V1 - w1 / K_meas if K_meas > 0 else float("nan")
    found.measured.update(K=K_meas, friction=dead if math.isfinite(dead) else None)
    cpr_note = (
        f"{found.measured['counts_per_rev']} counts/rev as measured by hand"
        if found.measured["counts_per_rev"]
        else f"{rig.counts_per_rev} counts/rev as configured"
    )
    measured = (
        f"{w1:.2f} rad/s at {V1:g} V, {w2:.2f} rad/s at {2 * V1:g} V: K = {K_meas:.3g} rad/(V s) "
        f"with {cpr_note}; expected {K_lo:.3g}-{K_hi:.3g}"
        + (f" ({prof.name})" if prof is not None and K is None else "")
    )
    ratio = K_meas / K_nom
    G = prof.gear_ratio if prof is not None else None
    if K_lo <= K_meas <= K_hi:
        if found.measured["counts_per_rev"] is None:
            found.append(
                Finding("cpr", True, f"{rig.counts_per_rev} counts/rev agrees with K ({measured})")
            )
        found.append(
            Finding(
                "supply",
                True,
                f"speed per volt as expected on {rig.supply_voltage:g} V ({measured})",
            )
        )
    elif G and (_ratio_near(ratio, G, 0.15) or _ratio_near(ratio, 1.0 / G, 0.15)):
        found.append(
            Finding(
                "gear",
                False,
                f"K is {ratio:.3g} x the profile's, about the {G:g}:1 gear ratio ({measured})",
                "the speed is counted at the motor, not at the output (or the other way): counts_per_rev "
                f"is per output revolution, {prof.counts_per_rev} for {prof.name!r}",
            )
        )
    elif found.measured["counts_per_rev"] is None and [
        f for f in _CPR_FACTORS if _ratio_near(ratio, f, 0.12)
    ]:
        f = [f for f in _CPR_FACTORS if _ratio_near(ratio, f, 0.12)][0]
        actual = int(round(rig.counts_per_rev * f))
        found.append(
            Finding(
                "cpr",
                False,
                f"the encoder gives about {actual} counts/rev, not the configured "
                f"{rig.counts_per_rev} ({measured})",
                f"connect with counts_per_rev={actual} (and --cpr {actual} here), or check the encoder's "
                "decoding (X1/X2/X4 edges) and the motor's data sheet",
            )
        )
    elif K_meas < K_lo:
        gear_hint = (
            f"; or a gearbox of about {G / ratio:.3g}:1 instead of {G:g}:1 (the hand turn tells)"
            if G and found.measured["counts_per_rev"] is None
            else ""
        )
        found.append(
            Finding(
                "supply",
                False,
                f"the motor turns too slowly for the voltage: about {100 * ratio:.0f} % of the "
                f"profile's speed per volt ({measured})",
                f"check the {rig.supply_voltage:g} V supply: its voltage under load (the L298 drops "
                "2 V more), a rating of at least 2 A, the fuse; or give the supply you use "
                f"(supply_voltage=, --supply) and the motor's profile (--profile){gear_hint}",
            )
        )
    else:
        found.append(
            Finding(
                "supply",
                False,
                f"the motor turns too fast for the voltage: {ratio:.2f} x the profile's speed per "
                f"volt ({measured})",
                f"is the supply above the configured {rig.supply_voltage:g} V? give the one you use "
                "(supply_voltage=, --supply); or the motor's profile (--profile) and counts/rev (--cpr)",
            )
        )
    if math.isfinite(dead):
        f_hi = prof.friction_range[1] if prof is not None else None
        if f_hi is not None and dead > 1.5 * f_hi + 0.1:
            found.append(
                Finding(
                    "friction",
                    False,
                    f"the motor needs about {dead:.2f} V before it turns (dead band; the profile "
                    f"{prof.name!r} has up to {f_hi:.2f} V)",
                    "something drags: the bracket's screws bend the motor's face, the hub rubs on the "
                    "bracket or the guard, the load touches something; loosen, align and try again",
                )
            )
        else:
            found.append(Finding("friction", True, f"dead band about {max(dead, 0.0):.2f} V"))
    return found


def report_profile(found: CheckReport, rig, profile=None, port=None):
    """The rig's profile file content from a check: the profile with what was measured
    (counts per revolution by hand, K and friction) and the check's findings."""
    prof = getattr(rig, "profile", None) if profile is None else load_profile(profile)
    if prof is None:
        prof = load_profile("paper")
    m = found.measured
    changes = {"supply_voltage": float(rig.supply_voltage)}
    if m.get("counts_per_rev"):
        changes["counts_per_rev"] = int(m["counts_per_rev"])
        changes["counts_options"] = (int(m["counts_per_rev"]),)
    measured = {
        "source": f"jerklab rig check {__version__} on {port or rig.port}",
        "date": datetime.datetime.now(datetime.timezone.utc).date().isoformat(),
        "turn_counts": m.get("turn_counts"),
        "K": m.get("K"),
        "coulomb_friction": m.get("friction"),
        "findings": [{"name": f.name, "ok": f.ok, "message": f.message} for f in found],
    }
    changes["measured"] = measured
    K = m.get("K")
    if K and K > 0 and all(f.ok for f in found):
        lo, hi = prof.K_range
        s = max(hi / prof.K - 1, 1 - lo / prof.K)
        changes.update(K=K, K_range=(min(lo, K * (1 - s)), max(hi, K * (1 + s))))
    fc = m.get("friction")
    if fc is not None and fc >= 0 and all(f.ok for f in found):
        lo, hi = prof.friction_range
        changes.update(coulomb_friction=fc, friction_range=(min(lo, fc), max(hi, fc)))
    return prof.replace(name=f"{prof.name}-checked", **changes)


def format_report(findings) -> str:
    """The findings as printed by ``jerklab rig check``."""
    bad = [f for f in findings if not f.ok]
    tail = (
        "all checks passed: the rig is ready for a closed loop"
        if not bad
        else f"{len(bad)} check(s) failed: fix them before closing the loop"
    )
    return "\n".join([str(f) for f in findings] + [tail])


def main(argv=None, prog="python -m jerklab.rig check", ask=input) -> int:
    """Command line of the check; returns the exit status."""
    ap = argparse.ArgumentParser(
        prog=prog,
        description=__doc__.split("\n")[0].split(": ", 1)[1],
        epilog="\n".join(__doc__.split("\n")[2:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("port", help="COM3, /dev/ttyACM0, socket://host:port, 'simavr' or 'virtual'")
    ap.add_argument(
        "--profile",
        default=None,
        help=f"the motor: {', '.join(builtin_profiles())}, or a profile file (default: the paper's motor)",
    )
    ap.add_argument(
        "--cpr",
        type=int,
        default=None,
        help="encoder counts per revolution (default the profile's)",
    )
    ap.add_argument(
        "--supply", type=float, default=None, help="H-bridge supply, V (default the profile's)"
    )
    ap.add_argument(
        "--K",
        type=float,
        default=None,
        help="expected motor gain, rad/(V s) (default the profile's range)",
    )
    ap.add_argument(
        "--tau", type=float, default=None, help="motor time constant, s (default the profile's)"
    )
    ap.add_argument(
        "--tolerance", type=float, default=None, help="K may be off by this factor (with --K: 1.5)"
    )
    ap.add_argument(
        "--voltage", type=float, default=None, help="test voltage, V (default supply/4)"
    )
    ap.add_argument(
        "--turn-counts",
        type=int,
        default=None,
        help="counts of one output revolution turned by hand (default: the check asks you to turn it)",
    )
    ap.add_argument(
        "--save", default=None, help="write the report as the rig's profile file (JSON)"
    )
    args = ap.parse_args(argv)
    port = None if args.port == "virtual" else args.port
    try:
        prof = load_profile(args.profile or "paper")
        rig = connect(
            port,
            device=Device(supply_voltage=args.supply, counts_per_rev=args.cpr),
            model=(args.K or prof.K, args.tau or prof.tau),
            profile=prof,
            progress=False,
        )
    except (RigError, ValueError, TypeError) as exc:
        print(f"FAIL connect   {exc}", file=sys.stderr)
        return 2
    interactive = args.turn_counts is None and port is not None and sys.stdin.isatty()
    try:
        found = check_rig(
            rig,
            profile=prof,
            K=args.K,
            tolerance=args.tolerance,
            voltage=args.voltage,
            turn_counts=args.turn_counts,
            turn=(lambda r: hand_turn(r, ask=ask)) if interactive else None,
        )
        saved = report_profile(found, rig, prof, args.port).save(args.save) if args.save else None
    except RigError as exc:
        print(f"FAIL link      {exc}", file=sys.stderr)
        return 2
    finally:
        rig.close()
    print(f"jerklab rig check on {args.port} (profile {prof.name}: {prof.title})")
    print(format_report(found))
    if saved is not None:
        print(
            f"the rig's profile written to {saved} (connect(port, profile={str(saved)!r}), --profile {saved})"
        )
    return 0 if all(f.ok for f in found) else 1


if __name__ == "__main__":
    sys.exit(main())
