"""``python -m jerklab.rig check PORT``: the bring-up check of a rig, before the loop is closed.

Open-loop only (no gains are sent): a short pulse each way, then two slow steady turns.

1. **firmware**: its version, the protocol version of this jerklab, and the open-loop STEP;
2. **encoder**: counts while driving (none: encoder unplugged or the motor did not turn);
3. **direction**: a positive voltage must count up (else "swap A and B" or "motor leads
   reversed"), and the two directions must differ (else the L298 IN1/IN2 wiring);
4. **counts per revolution**: the steady speed per volt (the slope between two voltages, so
   friction drops out) with the configured counts per revolution, against the motor's K
   (Stojčić eq. 1, ASCII Stojcic eq. 1: ω = K·u at rest of the transient); a factor of 2 or 4 is the encoder's
   decoding (X1/X2/X4) or a wrong ``counts_per_rev``;
5. **supply**: any other speed-per-volt outside the expected K range (a weak or wrong supply).

Each finding prints what is wrong and how to fix it. Exit status 0 when every check passes.

    python -m jerklab.rig check /dev/ttyACM0           # the paper's rig: 448 counts/rev, 12 V
    python -m jerklab.rig check COM3 --cpr 1200 --K 20  # another gearmotor
    python -m jerklab.rig check virtual                 # try it on the virtual rig
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np

from jerklab import __version__, paper
from jerklab import protocol as P
from jerklab.rig import Device, RigError, connect

__all__ = ["Finding", "check_rig", "format_report", "main"]

#: ratios of a wrong decoding / counts_per_rev that are recognised (measured K over expected)
_CPR_FACTORS = (4.0, 2.0, 0.5, 0.25)


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


def _speed(rec, tail=0.4):
    """Mean speed (counts/s) over the last ``tail`` of a step record, and the net counts."""
    c = np.asarray(rec.counts, float)
    t = np.asarray(rec.time, float)
    if c.size < 4:
        return 0.0, 0
    i0 = int(c.size * (1.0 - tail))
    span = t[-1] - t[i0]
    return (c[-1] - c[i0]) / span if span > 0 else 0.0, int(c[-1] - c[0])


def check_rig(rig, *, K=None, tolerance=1.5, voltage=None, seconds=0.6, min_counts=4):
    """Run the bring-up checks on an open :class:`~jerklab.rig.Rig`; return the findings.

    Parameters
    ----------
    rig : jerklab.rig.Rig
        Connected with the rig's ``supply_voltage`` and ``counts_per_rev`` (the configured encoder).
    K : float, optional
        The motor's expected gain, rad/(V s) (Stojčić eq. 1); default the rig's model K.
    tolerance : float
        The measured K may be this factor above or below ``K`` (default 1.5).
    voltage : float, optional
        The lower test voltage (V), default a quarter of the supply; the second is twice it.
    seconds : float
        Length of each steady turn (s); the speed is read over its last 40 %.
    min_counts : int
        Fewer counts than this during a pulse means no encoder signal.

    Returns
    -------
    list of Finding
    """
    K = float(rig.model[0] if K is None else K)
    if not (math.isfinite(K) and K > 0):
        raise ValueError(f"K must be a positive number (rad/(V s)), got {K!r}")
    if not (math.isfinite(tolerance) and tolerance > 1):
        raise ValueError(f"tolerance must be a factor > 1, got {tolerance!r}")
    V1 = rig.supply_voltage / 4 if voltage is None else float(voltage)
    if not (0 < 2 * V1 <= rig.supply_voltage):
        raise ValueError(
            f"voltage must be in (0, supply/2 = {rig.supply_voltage / 2} V], got {voltage!r}"
        )
    found = []

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

    # 2./3. a short pulse each way
    _, up = step(+V1, 0.2)
    _, down = step(-V1, 0.2)
    if max(abs(up), abs(down)) < min_counts:
        found.append(
            Finding(
                "encoder",
                False,
                f"no encoder counts while driving at ±{V1:g} V ({up:+d}, {down:+d} counts)",
                "encoder disconnected or unpowered: 5 V and GND to the encoder, A to D2, B to D3. If the "
                f"shaft did not turn either: check the {rig.supply_voltage:g} V supply and the L298 "
                "(ENA on D9 with its jumper removed, IN1 D7, IN2 D8, common ground)",
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
    sign = 1 if up > 0 else -1
    if sign > 0:
        found.append(Finding("direction", True, "a positive voltage counts up"))
    else:
        found.append(
            Finding(
                "direction",
                False,
                f"counts run against the drive ({up:+d} counts for +{V1:g} V)",
                "if the shaft turned the way you call positive, swap the encoder's A and B (D2 <-> D3); "
                "if it turned the other way, the motor leads are reversed: swap OUT1 and OUT2 at the L298",
            )
        )

    # 4./5. speed per volt at V1 and 2 V1 (the slope: Coulomb friction drops out)
    w1, _ = step(+V1, seconds)
    w2, _ = step(+2 * V1, seconds)
    w1, w2 = sign * w1 / rig.counts_per_rad, sign * w2 / rig.counts_per_rad  # rad/s
    K_meas = (w2 - w1) / V1
    dead = V1 - w1 / K_meas if K_meas > 0 else float("nan")
    ratio = K_meas / K
    measured = (
        f"{w1:.1f} rad/s at {V1:g} V, {w2:.1f} rad/s at {2 * V1:g} V: K = {K_meas:.1f} rad/(V s) "
        f"with {rig.counts_per_rev} counts/rev (expected {K:g}, x/÷{tolerance:g})"
    )
    if 1 / tolerance <= ratio <= tolerance:
        found.append(
            Finding("cpr", True, f"{rig.counts_per_rev} counts/rev agrees with K ({measured})")
        )
        found.append(
            Finding(
                "supply",
                True,
                f"speed per volt as expected on {rig.supply_voltage:g} V"
                + (
                    f"; dead band about {dead:.2f} V" if math.isfinite(dead) and dead > 0.05 else ""
                ),
            )
        )
        return found
    near = [f for f in _CPR_FACTORS if abs(ratio / f - 1) < 0.12]
    if near:
        actual = int(round(rig.counts_per_rev * near[0]))
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
        return found
    if ratio < 1:
        found.append(
            Finding(
                "supply",
                False,
                f"the motor turns too slowly for the voltage ({measured})",
                f"check the {rig.supply_voltage:g} V supply: its voltage under load and a rating of at least "
                "1 A; or give the supply you use (supply_voltage=, --supply) and the motor's K (--K)",
            )
        )
    else:
        found.append(
            Finding(
                "supply",
                False,
                f"the motor turns too fast for the voltage ({measured})",
                f"is the supply above the configured {rig.supply_voltage:g} V? give the one you use "
                "(supply_voltage=, --supply); or the motor's K (--K) and counts/rev (--cpr)",
            )
        )
    return found


def format_report(findings) -> str:
    """The findings as printed by ``python -m jerklab.rig check``."""
    bad = [f for f in findings if not f.ok]
    tail = (
        "all checks passed: the rig is ready for a closed loop"
        if not bad
        else f"{len(bad)} check(s) failed: fix them before closing the loop"
    )
    return "\n".join([str(f) for f in findings] + [tail])


def main(argv=None, prog="python -m jerklab.rig check") -> int:
    """Command line of the check; returns the exit status."""
    ap = argparse.ArgumentParser(
        prog=prog,
        description=__doc__.split("\n")[0].split(": ", 1)[1],
        epilog="\n".join(__doc__.split("\n")[2:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("port", help="COM3, /dev/ttyACM0, socket://host:port, 'simavr' or 'virtual'")
    cpr = paper.ENCODER_PPR * paper.ENCODER_DECODING
    ap.add_argument(
        "--cpr", type=int, default=cpr, help=f"encoder counts per revolution (default {cpr})"
    )
    ap.add_argument(
        "--supply",
        type=float,
        default=paper.SUPPLY_VOLTAGE,
        help=f"H-bridge supply, V (default {paper.SUPPLY_VOLTAGE:g})",
    )
    ap.add_argument(
        "--K",
        type=float,
        default=paper.MOTOR_K,
        help=f"expected motor gain, rad/(V s) (default {paper.MOTOR_K:g})",
    )
    ap.add_argument(
        "--tau",
        type=float,
        default=paper.MOTOR_TAU,
        help=f"motor time constant, s (default {paper.MOTOR_TAU:g})",
    )
    ap.add_argument(
        "--tolerance", type=float, default=1.5, help="K may be off by this factor (1.5)"
    )
    ap.add_argument(
        "--voltage", type=float, default=None, help="test voltage, V (default supply/4)"
    )
    args = ap.parse_args(argv)
    port = None if args.port == "virtual" else args.port
    try:
        rig = connect(
            port,
            device=Device(supply_voltage=args.supply, counts_per_rev=args.cpr),
            model=(args.K, args.tau),
            progress=False,
        )
    except (RigError, ValueError) as exc:
        print(f"FAIL connect   {exc}", file=sys.stderr)
        return 2
    try:
        findings = check_rig(rig, K=args.K, tolerance=args.tolerance, voltage=args.voltage)
    except RigError as exc:
        print(f"FAIL link      {exc}", file=sys.stderr)
        return 2
    finally:
        rig.close()
    print(f"jerklab rig check on {args.port}")
    print(format_report(findings))
    return 0 if all(f.ok for f in findings) else 1


if __name__ == "__main__":
    sys.exit(main())
