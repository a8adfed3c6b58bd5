"""Make the recorded rig runs of data/rig/: the virtual rig and the real firmware on simavr.

Run from the repository root:

    .venv/bin/python data/rig/make_recordings.py                  # (re)write all three recordings
    .venv/bin/python data/rig/make_recordings.py --only virtual   # the two virtual-rig recordings
    .venv/bin/python data/rig/make_recordings.py --only simavr    # the firmware-on-simavr move
    .venv/bin/python data/rig/make_recordings.py --check          # re-make the virtual ones in
                                                                  # memory, compare with the files
                                                                  # (exit 1 if not equal)

The simavr recording needs the Debian packages gcc-avr avr-libc arduino-core-avr simavr
libsimavr-dev and the firmware build (``make -C firmware``; ``connect("simavr")`` runs it
incrementally). Every number that defines a recording is in the constants below and is copied into
its JSON sidecar (``"made_by"``), so a file says how it was made.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import tempfile

import numpy as np

from jerklab.controller import pole_placement_pid
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.rig import Link, Recording, connect

HERE = pathlib.Path(__file__).resolve().parent
TS = 0.005

#: the motor: the paper's K and tau (Stojčić §4A), 12 V H-bridge, 10-bit PWM, 448-pulse encoder
#: (channel A, 448 counts/rev), and Coulomb friction 0.2 V (our choice, as data/ident: the paper
#: neglects friction). No angle noise: the encoder count is an integer. Nothing here is random;
#: the seed is fixed anyway so that the record says so.
PLANT = dict(
    K=32.4,
    tau=0.025,
    supply_voltage=12.0,
    pwm_bits=10,
    encoder_ppr=448,
    decoding=1,
    coulomb_friction=0.2,
    noise_std=0.0,
    seed=0,
)

#: the move: Stojčić's published sine-jerk planner (eq. 2-4), two turns
MOVE = dict(distance=4 * math.pi, max_jerk=2000.0, max_accel=300.0, max_velocity=60.0)

#: the gains: Stojčić eq. 11 pole placement (wn, zeta, sigma = 7 wn), eq. 13 discretization at TS;
#: the feedforward (eq. 8, 16) uses the true K, tau (the rig's model set to PLANT's)
GAINS = dict(wn=20.0, zeta=1.0)

#: run options passed to rig.run_move / rig.step
RUN = dict(Ts=TS, settle=0.25, host_timeout=1.0, feedforward=True)
STEP = dict(voltage=6.0, seconds=0.5, Ts=TS, rest=0.05)

NAMES = {
    "virtual_sine_jerk_move": "virtual",
    "virtual_step_6V": "virtual",
    "simavr_sine_jerk_move": "simavr",
}

#: sidecar keys that change from one making to the next (not part of the data)
VOLATILE = ("created", "csv")


def motor() -> DCMotor:
    return DCMotor(**PLANT)


def profile():
    return plan_sine_jerk(**MOVE)


def gains():
    return pole_placement_pid(PLANT["K"], PLANT["tau"], **GAINS).discretize(TS)


def _made_by(name: str, port, call: str) -> dict:
    return {
        "script": "data/rig/make_recordings.py",
        "command": f".venv/bin/python data/rig/make_recordings.py --only {NAMES[name]}",
        "connect": (
            f"jerklab.rig.connect({port!r}, device=DCMotor(**plant), model=(K, tau), "
            + ("link=Link(timeout=10.0), " if port == "simavr" else "")
            + "progress=False)"
        ),
        "call": call,
        "plant": PLANT,
        "move": MOVE,
        "gains": dict(
            GAINS,
            design="jerklab.controller.pole_placement_pid(K, tau, **gains)"
            ".discretize(Ts)  (Stojčić eq. 11, 13)",
        ),
        "run": RUN if "move" in name else STEP,
        "seed": PLANT["seed"],
    }


def _move(port, name: str) -> Recording:
    with tempfile.TemporaryDirectory() as tmp:
        with connect(
            port,
            device=motor(),
            link=Link(timeout=10.0) if port == "simavr" else None,
            model=(PLANT["K"], PLANT["tau"]),
            progress=False,
            recordings=tmp,
        ) as rig:
            rec = rig.run_move(profile(), gains(), path=False, **RUN)
    rec.metadata["made_by"] = _made_by(
        name, port, "rig.run_move(plan_sine_jerk(**move), gains, path=False, **run)"
    )
    if port == "simavr":
        rec.metadata["device"]["port"] = "simavr"  # was the harness's pty, /dev/pts/N
    return rec


def make_virtual_move() -> Recording:
    """The sine-jerk move on the virtual rig (``connect()``)."""
    return _move(None, "virtual_sine_jerk_move")


def make_simavr_move() -> Recording:
    """The same move on the real firmware inside simavr (``connect("simavr")``)."""
    return _move("simavr", "simavr_sine_jerk_move")


def make_virtual_step() -> Recording:
    """An open-loop step from rest on the virtual rig: ``rig.step(6.0, 0.5, Ts=0.005, rest=0.05)``."""
    with tempfile.TemporaryDirectory() as tmp:
        with connect(
            model=(PLANT["K"], PLANT["tau"]), progress=False, recordings=tmp, device=motor()
        ) as rig:
            rec = rig.step(
                STEP["voltage"], STEP["seconds"], Ts=STEP["Ts"], rest=STEP["rest"], path=False
            )
    rec.metadata["made_by"] = _made_by(
        "virtual_step_6V", None, "rig.step(voltage, seconds, Ts=Ts, rest=rest, path=False)"
    )
    return rec


MAKERS = {
    "virtual_sine_jerk_move": make_virtual_move,
    "virtual_step_6V": make_virtual_step,
    "simavr_sine_jerk_move": make_simavr_move,
}


def differences(a: Recording, b: Recording, reference_tol: float = 1e-9) -> list[str]:
    """What differs between two recordings: the integer telemetry (index, counts, pwm, flags)
    exactly, the reference within ``reference_tol`` rad, and the sidecar except :data:`VOLATILE`."""
    out = []
    if len(a) != len(b):
        return [f"{len(a)} samples vs {len(b)}"]
    for col in ("index", "counts", "pwm", "flags"):
        x, y = getattr(a, col), getattr(b, col)
        if not np.array_equal(x, y):
            out.append(
                f"{col} differs at {int(np.sum(x != y))} samples (max {int(np.max(np.abs(x - y)))})"
            )
    d = np.max(np.abs(a.reference - b.reference)) if len(a) else 0.0
    if d > reference_tol:
        out.append(f"reference differs by {d:.3g} rad")
    ma = {k: v for k, v in a.metadata.items() if k not in VOLATILE}
    mb = {k: v for k, v in b.metadata.items() if k not in VOLATILE}
    if _normal(ma) != _normal(mb):
        keys = sorted(k for k in set(ma) | set(mb) if _normal(ma.get(k)) != _normal(mb.get(k)))
        out.append(f"metadata differs in {keys}")
    return out


def _normal(o):
    """The sidecar as JSON reads it back (tuples -> lists, inf -> 'inf')."""
    import json

    from jerklab.rig.recording import _clean, _json_default

    return json.loads(json.dumps(_clean(o), default=_json_default))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["virtual", "simavr"], default=None)
    ap.add_argument(
        "--check",
        action="store_true",
        help="re-make the virtual-rig recordings in memory and compare with the files",
    )
    ap.add_argument("--out", type=pathlib.Path, default=HERE, help="output folder (default: here)")
    args = ap.parse_args(argv)
    only = "virtual" if args.check and args.only is None else args.only
    bad = 0
    for name, maker in MAKERS.items():
        if only is not None and NAMES[name] != only:
            continue
        rec = maker()
        if args.check:
            diff = differences(rec, Recording.load(args.out / name))
            bad += bool(diff)
            print(f"{name}: {'; '.join(diff) if diff else 'identical'}")
        else:
            path = rec.save(args.out / name)
            print(
                f"{path}: {len(rec)} samples, {rec.metadata['status']}, "
                f"final {rec.position[-1]:.5f} rad"
            )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
