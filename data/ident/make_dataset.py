"""Make the identification data set of the paper's motor (Stojčić §4A) from jerklab.plant.DCMotor.

Run from the repository root:

    .venv/bin/python data/ident/make_dataset.py            # (re)write data/ident/*.csv + *.json
    .venv/bin/python data/ident/make_dataset.py --check    # regenerate in memory, compare,
                                                           # exit 1 if different
    .venv/bin/python data/ident/make_dataset.py --only rig # just the virtual-rig record

Every number that defines a record is in ``RUNS`` and ``PLANT`` below and is copied into the
record's JSON sidecar, so a file says how it was made.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

from jerklab import ident
from jerklab.plant import DCMotor

HERE = pathlib.Path(__file__).resolve().parent
TS = 0.005

#: the motor: the paper's K and tau, the rig's imperfections (friction and noise are our choice:
#: the paper neglects friction and does not report noise)
PLANT = dict(
    K=32.4,
    tau=0.025,
    supply_voltage=12.0,
    pwm_bits=10,
    encoder_ppr=448,
    decoding=1,
    coulomb_friction=0.2,
    noise_std=0.001,
)

#: name -> (input generator, plant seed)
RUNS = {
    "step_6V": (dict(kind="step", duration=2.0, amplitude=6.0, t_step=0.05), 1),
    "prbs_6V_3V": (
        dict(kind="prbs", duration=4.0, amplitude=3.0, offset=6.0, clock_period=0.02, seed=4),
        2,
    ),
}


def make_input(spec: dict) -> np.ndarray:
    spec = dict(spec)
    kind = spec.pop("kind")
    if kind == "step":
        return ident.step_input(Ts=TS, **spec)
    if kind == "prbs":
        return ident.prbs(Ts=TS, **spec)
    raise ValueError(f"unknown input kind {kind!r}")


def make_run(name: str) -> ident.IdentData:
    spec, seed = RUNS[name]
    u = make_input(spec)
    motor = DCMotor(seed=seed, **PLANT)
    theta_true, theta_meas = motor.open_loop(u, TS)
    applied = motor.quantize_voltage(u)
    # open_loop returns len(u)+1 samples; sample k is read before u[k] is applied
    meta = {
        "description": f"simulated open-loop {spec['kind']} of the Stojčić motor for identification",
        "made_by": "data/ident/make_dataset.py (jerklab.plant.DCMotor.open_loop)",
        "plant": PLANT,
        "plant_seed": seed,
        "input": spec,
        "Ts": TS,
        "u_is": "commanded voltage (V); the motor sees it after 10-bit PWM quantization",
        "applied_voltage_levels_V": sorted({float(v) for v in np.unique(applied)}),
        "y_is": "encoder angle (rad): floor(theta * 448 / 2pi) * 2pi / 448 + N(0, noise_std)",
        "true_K": PLANT["K"],
        "true_tau": PLANT["tau"],
        "rms_quantization_plus_noise_rad": float(np.sqrt(np.mean((theta_meas - theta_true) ** 2))),
    }
    return ident.IdentData(u, theta_meas[:-1], TS, "V", "rad", meta)


#: a record from the virtual rig (jerklab.rig.connect()), the same open-loop step a student runs on the
#: board: ``rig.step(6.0, 2.0, Ts=0.005, rest=0.05)``; the rig logs the PWM-quantized voltage it applied
RIG_RUNS = {
    "rig_step_6V": dict(voltage=6.0, seconds=2.0, rest=0.05, plant_seed=5),
}
#: the rig's encoder counts are exact integers: its motor has friction but no added angle noise
RIG_PLANT = dict(PLANT, noise_std=0.0)


def make_rig_run(name: str) -> ident.IdentData:
    import tempfile

    from jerklab.rig import connect

    spec = dict(RIG_RUNS[name])
    seed = spec.pop("plant_seed")
    with tempfile.TemporaryDirectory() as tmp:
        rig = connect(progress=False, recordings=tmp, device=DCMotor(seed=seed, **RIG_PLANT))
        try:
            rec = rig.step(spec["voltage"], spec["seconds"], Ts=TS, rest=spec["rest"])
        finally:
            rig.close()
        d = ident.IdentData.from_recording(rec)
    meta = {k: v for k, v in d.metadata.items() if k not in ("created", "csv")}
    meta.update(
        {
            "description": "open-loop step recorded from the virtual rig (jerklab.rig.connect())",
            "made_by": "data/ident/make_dataset.py: connect(device=DCMotor(seed=plant_seed, **plant))"
            ".step(voltage, seconds, Ts=0.005, rest=rest)",
            "plant": RIG_PLANT,
            "plant_seed": seed,
            "input": RIG_RUNS[name],
            "u_is": "voltage the rig applied (PWM-quantized), as logged by the rig",
            "y_is": "encoder counts / counts_per_rad (rad), zeroed at the start",
            "true_K": PLANT["K"],
            "true_tau": PLANT["tau"],
        }
    )
    return ident.IdentData(d.u, d.y, d.Ts, d.input_unit, d.output_unit, meta)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--check",
        action="store_true",
        help="regenerate in memory and compare with the files on disk",
    )
    ap.add_argument("--out", type=pathlib.Path, default=HERE, help="output folder (default: here)")
    ap.add_argument(
        "--only",
        choices=["plant", "rig"],
        default=None,
        help="only the plant-model records or only the virtual-rig record",
    )
    args = ap.parse_args(argv)
    bad = 0
    makers = {}
    if args.only in (None, "plant"):
        makers.update({name: make_run for name in RUNS})
    if args.only in (None, "rig"):
        makers.update({name: make_rig_run for name in RIG_RUNS})
    for name, maker in makers.items():
        d = maker(name)
        if args.check:
            old = ident.IdentData.load(args.out / name)
            same = (
                old.n == d.n
                and np.array_equal(old.u, d.u)
                and np.array_equal(old.y, d.y)
                and old.Ts == d.Ts
            )
            print(f"{name}: {'identical' if same else 'DIFFERENT'}")
            bad += not same
        else:
            csv, js = d.save(args.out / name)
            print(f"wrote {csv} and {js.name} ({d.n} samples, {d.duration:g} s)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
