"""Fault probe: bad inputs across the public API and injected faults, with their outcomes.

``python -m benchmarks faults`` calls every public function / class / method of jerklab with a
valid set of arguments in which one parameter at a time is replaced by a bad value (NaN, ±inf,
0, a negative number, 1e-300, 1e300, 1e9, a wrong type, None, a list, an empty / ragged / 2-D /
non-finite array, an out-of-range integer, an unknown name) and classifies the outcome:

``clear``
    ``ValueError`` / ``TypeError`` (or a subclass) whose message names the parameter; for a
    file that is not there, a ``FileNotFoundError`` naming the parameter.
``obscure``
    any other exception (``AttributeError``, ``KeyError``, ``ZeroDivisionError``, a numba
    ``TypingError``, a raw ``MemoryError``, ``LinAlgError``, ``OverflowError``...), or a
    ``ValueError`` / ``TypeError`` whose message does not name the parameter.
``silent``
    returned a result with NaN / inf in it, or accepted a value outside the parameter's domain
    (NaN, a wrong type, a limit <= 0...), or (protocol) encoded a value that does not come back.
``hang``
    no answer within the time limit (the worker process is killed and restarted).
``ok``
    a value inside the parameter's domain (0, a tiny or a huge number where they are legal)
    accepted with a finite result.

Then faults are injected into the rig and its recordings (corrupt frames, a pulled cable, a
frozen board, a full disk, an I/O error, a client killed mid-run, a torn last row, a blank line,
bad metadata, Ctrl-C) and each outcome is checked against what the issue asks for.

The calls run in a worker subprocess (memory capped at 3 GB so that a huge request shows up as
a ``MemoryError`` instead of swapping); the parent watches each call with a time limit.

Run it as ``python -m benchmarks faults`` (add ``--verbose`` through ``JERKLAB_FAULTS_VERBOSE=1``
to list every case that is not ``clear`` / ``ok``; ``JERKLAB_FAULTS_ONLY=planner,protocol`` to
probe only some modules).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import errno
import io
import json
import math
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: seconds one call may take before it counts as a hang
TIME_LIMIT = float(os.environ.get("JERKLAB_FAULTS_TIME_LIMIT", "20"))
#: the first call of a target (warm-up, numba compilation) gets this much
WARMUP_LIMIT = 180.0
#: the worker's address-space cap (bytes)
MEMORY_LIMIT = 3 * 2**30

NAN, INF = float("nan"), float("inf")

# ----------------------------------------------------------------------------- bad values
# (label, value); value factories are used for arrays so that every case gets a fresh one

REAL = [
    ("nan", NAN),
    ("+inf", INF),
    ("-inf", -INF),
    ("0", 0.0),
    ("negative", -1.0),
    ("1e-300", 1e-300),
    ("1e300", 1e300),
    ("1e9", 1e9),
    ("str", "1.0"),
    ("None", None),
    ("list", [1.0, 2.0]),
]
INT = [
    ("nan", NAN),
    ("0", 0),
    ("negative", -1),
    ("2.5", 2.5),
    ("1e9", 10**9),
    ("2**64", 2**64),
    ("str", "3"),
    ("None", None),
]
ARRAY = [
    ("nan-in-array", lambda: [0.0, NAN, 1.0, 2.0]),
    ("inf-in-array", lambda: [0.0, INF, 1.0, 2.0]),
    ("empty", lambda: []),
    ("ragged", lambda: [[1.0], [1.0, 2.0]]),
    ("2-D", lambda: [[0.0, 1.0], [2.0, 3.0]]),
    ("strings", lambda: ["a", "b", "c"]),
    ("None", None),
    ("scalar-str", "x"),
]
STR = [("unknown", "nonsense"), ("empty", ""), ("None", None), ("int", 3)]
OBJ = [("None", None), ("str", "x"), ("int", 3), ("float", 1.5), ("dict", {})]

REJECT = {  # labels that must be refused, by domain
    "R": {"nan", "+inf", "-inf", "str", "None", "list"},
    "P": {"nan", "+inf", "-inf", "str", "None", "list", "0", "negative"},
    "N": {"nan", "+inf", "-inf", "str", "None", "list", "negative"},
    "I1": {"nan", "0", "negative", "2.5", "str", "None"},
    "I0": {"nan", "negative", "2.5", "str", "None"},
    "A": {"nan-in-array", "inf-in-array", "ragged", "strings", "None", "scalar-str"},
    "S": {"unknown", "empty", "None", "int"},
    "O": {"None", "str", "int", "float", "dict"},
}
VALUES = {"R": REAL, "P": REAL, "N": REAL, "I1": INT, "I0": INT, "A": ARRAY, "S": STR, "O": OBJ}


@dataclasses.dataclass
class Param:
    name: str  # keyword passed to the call
    domain: str  # key of REJECT / VALUES
    ok: tuple = ()  # labels that are legal for this parameter although the domain refuses them
    values: list | None = None  # replaces the domain's value list
    shown: str | None = None  # the name the error must use (default: name)


@dataclasses.dataclass
class Target:
    module: str
    name: str
    call: object  # callable(**kwargs)
    base: dict
    params: list
    check: object = None  # callable(result, kwargs) -> None or a description of a wrong result
    allow_nonfinite: bool = False


# ----------------------------------------------------------------------------- helpers


def _prof(kind="sine_jerk"):
    from jerklab import planner

    if kind == "trapezoid":
        return planner.plan_trapezoid(1.0, 300.0, 100.0)
    return getattr(planner, "plan_" + kind)(1.0, 2000.0, 300.0, 100.0)


def _motor(**kw):
    from jerklab.plant import DCMotor

    return DCMotor(**kw)


def _gains(Ts=None):
    from jerklab.controller import pole_placement_pid

    g = pole_placement_pid(32.4, 0.025, 20.0)
    return g if Ts is None else g.discretize(Ts)


def _rig(**kw):
    from jerklab.rig import connect

    return connect(None, progress=False, **kw)


def _with_rig(method):
    def call(**kw):
        rig = _rig()
        try:
            return getattr(rig, method)(**kw)
        finally:
            rig.close()

    return call


def _run_move_limits(max_accel=300.0, max_velocity=100.0, kpd_scale=1.0):
    from jerklab.controller import DiscreteGains
    from jerklab.planner import plan_trapezoid

    prof = plan_trapezoid(1.0, max_accel, max_velocity)
    d = _gains(0.005)
    d = DiscreteGains(d.kpd * kpd_scale, d.kid, d.kdd, d.Ts)
    rig = _rig()
    try:
        return rig.run_move(prof, d, 0.005, path=False, settle=0.0)
    finally:
        rig.close()


def _protocol_roundtrip(cls):
    def call(**kw):
        from jerklab import protocol as P

        return P.parse(P.Decoder().feed(P.encode(cls(**kw)))[0]), kw

    return call


def _check_roundtrip(result, kw):
    msg, sent = result
    for k, v in sent.items():
        got = getattr(msg, k)
        if isinstance(v, float) and isinstance(got, float):
            if math.isnan(v) and math.isnan(got):
                continue
            if got == v or (math.isfinite(v) and abs(got - v) <= 1e-6 * abs(v)):
                continue
        elif got == v:
            continue
        return f"{k}={v!r} came back as {got!r}"
    return None


_BASE = object()  # "the valid object" in a base case


def _preisach():
    from jerklab.hysteresis import Preisach

    return Preisach.uniform(-1.0, 1.0, n=10)


def _nonfinite(obj, depth=0, seen=None):
    """A description of the first NaN / inf found in ``obj`` (a result), or None."""
    if seen is None:
        seen = set()
    if id(obj) in seen or depth > 3:
        return None
    seen.add(id(obj))
    if isinstance(obj, bool) or obj is None or isinstance(obj, (str, bytes)):
        return None
    if isinstance(obj, (float, np.floating, complex, np.complexfloating)):
        return None if np.isfinite(obj) else repr(obj)
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind in "fc" and obj.size and not np.all(np.isfinite(obj)):
            return f"array with {int(np.count_nonzero(~np.isfinite(obj)))} non-finite"
        if obj.dtype == object:
            for v in obj.ravel()[:1000]:
                d = _nonfinite(v, depth + 1, seen)
                if d:
                    return d
        return None
    if isinstance(obj, dict):
        for k, v in list(obj.items())[:200]:
            d = _nonfinite(v, depth + 1, seen)
            if d:
                return f"{k}: {d}"
        return None
    if isinstance(obj, (list, tuple)):
        for v in list(obj)[:1000]:
            d = _nonfinite(v, depth + 1, seen)
            if d:
                return d
        return None
    names = []
    if dataclasses.is_dataclass(obj):
        names = [f.name for f in dataclasses.fields(obj)]
    elif hasattr(obj, "__dict__"):
        names = [n for n in vars(obj) if not n.startswith("__")]
    for n in ("duration", "phase_times", "peak_accel", "peak_velocity"):
        if hasattr(type(obj), n) and isinstance(getattr(type(obj), n), property):
            names.append(n)
    for n in names:
        try:
            v = getattr(obj, n)
        except Exception:
            continue
        if callable(v):
            continue
        d = _nonfinite(v, depth + 1, seen)
        if d:
            return f"{n}: {d}"
    return None


# ----------------------------------------------------------------------------- the targets

# the kinds of VALUES as names (O: any object, the key VALUES and OBJ use)
P, R, N, I1, I0, A, S, O = "P", "R", "N", "I1", "I0", "A", "S", "O"  # noqa: E741


def _targets() -> list[Target]:
    from jerklab import planner as PL
    from jerklab import protocol as PR

    T: list[Target] = []
    lim4 = [
        Param("distance", R),
        Param("max_jerk", P),
        Param("max_accel", P),
        Param("max_velocity", P),
    ]
    for kind in ("sine_jerk", "sine_jerk_optimal", "scurve"):
        T.append(
            Target(
                "planner",
                f"plan_{kind}",
                getattr(PL, f"plan_{kind}"),
                dict(distance=1.0, max_jerk=2000.0, max_accel=300.0, max_velocity=100.0),
                lim4,
            )
        )
    T.append(
        Target(
            "planner",
            "plan_trapezoid",
            PL.plan_trapezoid,
            dict(distance=1.0, max_accel=300.0, max_velocity=100.0),
            lim4[:1] + lim4[2:],
        )
    )
    # extreme but legal combinations: the plan must be finite or refused by name
    T.append(
        Target(
            "planner",
            "plan_sine_jerk(d=1e300)",
            PL.plan_sine_jerk,
            dict(distance=1e300, max_jerk=2000.0, max_accel=300.0, max_velocity=100.0),
            [Param("max_jerk", P), Param("max_accel", P), Param("max_velocity", P)],
        )
    )
    T.append(
        Target(
            "planner",
            "plan_scurve(d=1e-300)",
            PL.plan_scurve,
            dict(distance=1e-300, max_jerk=2000.0, max_accel=300.0, max_velocity=100.0),
            [Param("max_jerk", P), Param("max_accel", P), Param("max_velocity", P)],
        )
    )
    AP = [
        ("0", lambda: [1.0, 0.0, 2.0, 3.0]),
        ("negative", lambda: [1.0, -1.0, 2.0, 3.0]),
        ("1e-300", lambda: [1.0, 1e-300, 2.0, 3.0]),
        ("1e300", lambda: [1.0, 1e300, 2.0, 3.0]),
    ]
    arr_pos = ARRAY + AP
    for engine, n in (("numpy", 4), ("numba", 4)):
        base = dict(
            kind="scurve",
            distance=np.linspace(0.1, 2.0, n),
            max_jerk=2000.0,
            max_accel=300.0,
            max_velocity=100.0,
            engine=engine,
        )
        T.append(
            Target(
                "planner",
                f"plan_batch[{engine}]",
                PL.plan_batch,
                base,
                [
                    Param("kind", S),
                    Param(
                        "distance",
                        A,
                        ok=("empty",),
                        values=ARRAY + [("1e300", lambda: [1.0, 1e300, 2.0, 3.0])],
                    ),
                    Param("max_jerk", A, ok=("empty", "2-D"), values=arr_pos),
                    Param("max_accel", A, ok=("empty", "2-D"), values=arr_pos),
                    Param("max_velocity", A, ok=("empty", "2-D"), values=arr_pos),
                ],
            )
        )
    T.append(
        Target(
            "planner",
            "plan_batch(n huge)",
            lambda n: PL.plan_batch(
                "scurve", np.broadcast_to(np.float64(1.0), (n,)), 1.0, 1.0, 1.0, engine="numpy"
            ),
            dict(n=10),
            [Param("n", I1, values=[("1e9", 10**9), ("2**40", 2**40)])],
        )
    )
    T.append(
        Target(
            "planner",
            "Profile.sample",
            lambda t: _prof().sample(t),
            dict(t=[0.0, 0.01]),
            [Param("t", A, ok=("empty", "2-D"))],
        )
    )
    T.append(
        Target(
            "planner",
            "Profile.synchronized",
            lambda Ts: _prof().synchronized(Ts),
            dict(Ts=0.005),
            [Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "planner",
            "Profile.discretize",
            lambda Ts, t_end: _prof().discretize(Ts, t_end),
            dict(Ts=0.005, t_end=None),
            [Param("Ts", P), Param("t_end", N, ok=("None",))],
        )
    )
    T.append(
        Target(
            "planner",
            "Profile.discretize(trapezoid)",
            lambda Ts, t_end: _prof("trapezoid").discretize(Ts, t_end),
            dict(Ts=0.005, t_end=None),
            [Param("Ts", P), Param("t_end", N, ok=("None",))],
        )
    )
    T.append(
        Target(
            "planner",
            "BatchPlan.sample",
            lambda t: PL.plan_batch("scurve", [1.0, 2.0], 2000, 300, 100, engine="numpy").sample(t),
            dict(t=[0.0, 0.01]),
            [Param("t", A, ok=("empty", "2-D"))],
        )
    )
    T.append(
        Target(
            "planner",
            "BatchPlan.profile",
            lambda i: PL.plan_batch("scurve", [1.0, 2.0], 2000, 300, 100, engine="numpy").profile(
                i
            ),
            dict(i=1),
            [Param("i", I0, ok=("negative",), values=INT + [("2", 2), ("-3", -3)])],
        )
    )

    # -- protocol: every message, every field; the frame must carry the value back
    fmt_dom = {"f": R, "B": I0, "H": I0, "I": I0, "i": R, "h": R}
    fmt_ok = {
        "f": ("nan", "+inf", "-inf", "0", "negative", "1e-300", "1e9"),
        "B": ("0",),
        "H": ("0",),
        "I": ("0",),
        "i": ("0", "negative"),
        "h": ("0", "negative"),
    }
    base_vals = {"f": 1.5, "B": 1, "H": 100, "I": 1000, "i": -5, "h": -5}
    INTF = INT + [("256", 256), ("65536", 65536), ("2**32", 2**32), ("-2**31-1", -(2**31) - 1)]
    for cls in (
        PR.Hello,
        PR.SetPlant,
        PR.SetGains,
        PR.SetLimits,
        PR.Plan,
        PR.Run,
        PR.Step,
        PR.Ack,
        PR.Nack,
        PR.HelloReply,
        PR.PlanInfo,
        PR.Telemetry,
        PR.EndOfRun,
        PR.DeviceError,
    ):
        fmt = cls.FORMAT.lstrip("<")
        fields = dataclasses.fields(cls)
        codes = []
        for ch in fmt:
            if ch.isdigit():
                continue
            codes.append(ch)
        base, params = {}, []
        for f, ch in zip(fields, [c for c in codes]):
            if ch == "s":
                base[f.name] = "x"
                continue
            base[f.name] = base_vals[ch]
            vals = REAL if ch == "f" else INTF
            if ch in "ih":
                # signed ints: wrong types and out-of-range values must be refused
                dom = I0
                ok = ("0", "negative")
            else:
                dom, ok = fmt_dom[ch], fmt_ok[ch]
            params.append(Param(f.name, dom, ok=ok, values=vals))
        T.append(
            Target(
                "protocol",
                f"encode({cls.__name__})",
                _protocol_roundtrip(cls),
                base,
                params,
                check=_check_roundtrip,
                allow_nonfinite=True,
            )
        )
    T.append(
        Target(
            "protocol",
            "encode_frame",
            PR.encode_frame,
            dict(msg_type=1, seq=0, payload=b""),
            [
                Param("msg_type", I0, values=INTF),
                Param("seq", I0, values=INTF),
                Param(
                    "payload",
                    O,
                    values=[("None", None), ("int", 3), ("str", "x"), ("too long", b"x" * 70)],
                ),
            ],
        )
    )
    T.append(
        Target(
            "protocol",
            "encode(seq)",
            lambda seq: PR.encode(PR.Stop(), seq),
            dict(seq=0),
            [Param("seq", I0, values=INTF)],
        )
    )
    T.append(
        Target(
            "protocol",
            "Decoder.feed",
            lambda data: PR.Decoder().feed(data),
            dict(data=b"\xa5\x5a"),
            [
                Param(
                    "data",
                    O,
                    values=[
                        ("None", None),
                        ("int", 3),
                        ("str", "x"),
                        ("float", 1.5),
                        ("list-of-str", ["a"]),
                    ],
                )
            ],
        )
    )
    T.append(
        Target(
            "protocol",
            "crc16_ccitt_false",
            PR.crc16_ccitt_false,
            dict(data=b"123456789"),
            [Param("data", O, values=[("None", None), ("str", "x"), ("float", 1.5)])],
        )
    )
    T.append(
        Target(
            "protocol",
            "payload_field_name",
            PR.payload_field_name,
            dict(command=2, index=0),
            [Param("command", I0, values=INTF), Param("index", I0, values=INTF)],
        )
    )

    # -- plant
    from jerklab import plant as PLT

    T.append(
        Target(
            "plant",
            "DCMotor",
            PLT.DCMotor,
            dict(K=32.4, tau=0.025),
            [
                Param("K", P),
                Param("tau", P),
                Param("supply_voltage", P, ok=("None",)),
                Param("pwm_bits", I1, ok=("None",)),
                Param("encoder_ppr", I1, ok=("None",)),
                Param("decoding", I1),
                Param("coulomb_friction", N),
                Param("noise_std", N),
                Param("load_disturbance", R, ok=("None", "list")),
            ],
        )
    )
    T.append(
        Target(
            "plant",
            "FlexibleDCMotor",
            PLT.FlexibleDCMotor,
            dict(K=32.4, tau=0.025),
            [
                Param("K", P),
                Param("tau", P),
                Param("load_ratio", P),
                Param("mode_frequency", P),
                Param("mode_damping", N),
            ],
        )
    )
    T.append(
        Target(
            "plant", "DCMotor.zoh", lambda Ts: _motor().zoh(Ts), dict(Ts=0.005), [Param("Ts", P)]
        )
    )
    T.append(
        Target(
            "plant",
            "DCMotor.discrete_tf",
            lambda Ts: _motor().discrete_tf(Ts),
            dict(Ts=0.005),
            [Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "plant",
            "DCMotor.ss",
            lambda outputs: _motor().ss(outputs),
            dict(outputs="theta"),
            [Param("outputs", S)],
        )
    )
    T.append(
        Target(
            "plant",
            "DCMotor.step_state",
            lambda x, u, dt, t: _motor().step_state(x, u, dt, t),
            dict(x=[0.0, 0.0], u=1.0, dt=0.005, t=0.0),
            [Param("x", A), Param("u", R), Param("dt", N), Param("t", R)],
        )
    )
    T.append(
        Target(
            "plant",
            "DCMotor.open_loop",
            lambda u, Ts: _motor().open_loop(u, Ts),
            dict(u=[1.0, 1.0, 1.0], Ts=0.005),
            [Param("u", A, ok=("empty",)), Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "plant",
            "DCMotor.quantize_voltage",
            lambda u: _motor().quantize_voltage(u),
            dict(u=[1.0, 2.0]),
            [Param("u", A, ok=("empty", "2-D"))],
        )
    )
    T.append(
        Target(
            "plant",
            "DCMotor.measure",
            lambda theta: _motor().measure(theta),
            dict(theta=[1.0, 2.0]),
            [Param("theta", A, ok=("empty", "2-D"))],
        )
    )
    T.append(
        Target(
            "plant",
            "FlexibleDCMotor.open_loop",
            lambda u, Ts: PLT.FlexibleDCMotor().open_loop(u, Ts),
            dict(u=[1.0, 1.0, 1.0], Ts=0.005),
            [Param("u", A, ok=("empty",)), Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "plant",
            "advance_scalar",
            PLT.advance_scalar,
            dict(theta=0.0, omega=0.0, v=1.0, fc=0.0, K=32.4, tau=0.025, dt=0.005),
            [
                Param("theta", R),
                Param("omega", R),
                Param("v", R),
                Param("fc", N),
                Param("K", P),
                Param("tau", P),
                Param("dt", N),
            ],
        )
    )
    T.append(
        Target(
            "plant",
            "advance",
            PLT.advance,
            dict(theta=0.0, omega=0.0, v=1.0, fc=0.0, K=32.4, tau=0.025, dt=0.005),
            # vectorized: a list broadcasts (documented), so it is a legal value here
            [
                Param("v", R, ok=("list",)),
                Param("K", P, ok=("list",)),
                Param("tau", P, ok=("list",)),
                Param("dt", N, ok=("list",)),
            ],
        )
    )
    T.append(
        Target(
            "plant",
            "quantize_voltage",
            PLT.quantize_voltage,
            dict(u=[1.0], supply_voltage=12.0, pwm_bits=10),
            [
                Param("u", A, ok=("empty", "2-D")),
                Param("supply_voltage", P, ok=("None",)),
                Param("pwm_bits", I1, ok=("None",)),
            ],
        )
    )
    T.append(
        Target(
            "plant",
            "measure_angle",
            PLT.measure_angle,
            dict(theta=[1.0], counts_per_rad=71.3),
            [Param("theta", A, ok=("empty", "2-D")), Param("counts_per_rad", P, ok=("None",))],
        )
    )
    T.append(
        Target(
            "plant",
            "StepDisturbance",
            PLT.StepDisturbance,
            dict(amplitude=1.0, time=0.0),
            [Param("amplitude", R), Param("time", R)],
        )
    )

    # -- fpga
    from jerklab import fpga as FP

    T.append(
        Target(
            "fpga",
            "YangSCurve",
            FP.YangSCurve,
            dict(),
            [
                Param("max_velocity", I1),
                Param("accel_time", P),
                Param("cruise_time", N),
                Param("refresh_period", P),
                Param("clock_hz", I1),
                Param("step_um", I1),
                Param("start_count", I0),
                Param("bits", I1),
            ],
        )
    )
    T.append(
        Target(
            "fpga",
            "YangSCurve.pulses",
            lambda p_end: FP.YangSCurve(cruise_time=0.01, accel_time=0.01, start_count=10).pulses(
                p_end
            ),
            dict(p_end=None),
            [Param("p_end", I1, ok=("None",))],
        )
    )
    T.append(
        Target(
            "fpga",
            "YangSCurve.speed",
            lambda n: FP.YangSCurve().speed(n),
            dict(n=[0, 10]),
            [Param("n", A, ok=("empty", "2-D"))],
        )
    )
    T.append(
        Target(
            "fpga",
            "paper_speed",
            FP.paper_speed,
            dict(n=[0, 10]),
            [Param("n", A, ok=("empty", "2-D"))],
        )
    )
    T.append(
        Target(
            "fpga",
            "divider_edges",
            FP.divider_edges,
            dict(starts=[1, 100], values=[1000, 500], p_end=50, bits=32),
            [Param("starts", A), Param("values", A), Param("p_end", I1), Param("bits", I1)],
        )
    )
    T.append(
        Target(
            "fpga",
            "published_divider",
            FP.published_divider,
            dict(starts=[1, 100], values=[1000, 500], p_end=50, bits=32),
            [Param("starts", A), Param("values", A), Param("p_end", I1), Param("bits", I1)],
        )
    )
    T.append(
        Target(
            "fpga",
            "PulseTrain.position",
            lambda t: (
                FP.YangSCurve(cruise_time=0.01, accel_time=0.01, start_count=10)
                .pulses()
                .position(t)
            ),
            dict(t=[0.0, 0.001]),
            [Param("t", A, ok=("empty", "2-D"))],
        )
    )

    # -- piezo
    from jerklab import piezo as PZ

    T.append(
        Target(
            "piezo",
            "PZTModel",
            PZ.PZTModel,
            dict(),
            [
                Param("K", P),
                Param("zeta_z", N),
                Param("f_z", P),
                Param("zeta_1", N),
                Param("f_1", P),
                Param("zeta_2", N),
                Param("f_2", P),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "PZTModel.zoh",
            lambda Ts: PZ.PZTModel().zoh(Ts),
            dict(Ts=2e-4),
            [Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "piezo",
            "PZTModel.perturbed",
            lambda freq_scale: PZ.PZTModel().perturbed(freq_scale),
            dict(freq_scale=1.1),
            [Param("freq_scale", P)],
        )
    )
    T.append(
        Target(
            "piezo",
            "ScanSpec",
            PZ.ScanSpec,
            dict(),
            [
                Param("scan_length", P),
                Param("scan_velocity", P),
                Param("Ts", P),
                Param("F_max", P),
                Param("velocity_tolerance", P),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "simulate",
            lambda u, Ts: PZ.simulate(PZ.PZTModel(), u, Ts),
            dict(u=[0.0, 1.0, 1.0], Ts=2e-4),
            [Param("u", A, ok=("empty",)), Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "piezo",
            "simulate(model)",
            lambda model: PZ.simulate(model, [0.0, 1.0]),
            dict(model=PZ.PZTModel()),
            [Param("model", O)],
        )
    )
    T.append(
        Target(
            "piezo",
            "shape_rampup",
            lambda max_samples, scan_start: PZ.shape_rampup(
                max_samples=max_samples, scan_start=scan_start
            ),
            dict(max_samples=400, scan_start=None),
            [
                Param("max_samples", I1, values=INT[:4] + [("None", None), ("str", "3")]),
                Param(
                    "scan_start",
                    R,
                    ok=("None",),
                    values=[
                        ("nan", NAN),
                        ("+inf", INF),
                        ("negative", -1.0),
                        ("str", "1"),
                        ("1e300", 1e300),
                    ],
                ),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "shape_return",
            lambda b, max_samples: PZ.shape_return(b, max_samples=max_samples),
            dict(b=-6.0, max_samples=400),
            [
                Param(
                    "b",
                    R,
                    values=[
                        ("nan", NAN),
                        ("+inf", INF),
                        ("str", "1"),
                        ("None", None),
                        ("1e300", 1e300),
                        ("0", 0.0),
                    ],
                ),
                Param("max_samples", I1, values=INT[:4] + [("None", None)]),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "energy_optimal_return",
            lambda b, k_r: PZ.energy_optimal_return(b, k_r),
            dict(b=-6.0, k_r=40),
            [
                Param(
                    "b", R, values=[("nan", NAN), ("+inf", INF), ("None", None), ("1e300", 1e300)]
                ),
                Param("k_r", I1, values=INT),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "pole_placement_gains",
            PZ.pole_placement_gains,
            dict(),
            [
                Param("Ts", P),
                Param("mode1_damping", P),
                Param("integral_frequency", P),
                Param("observer_speedup", P),
                Param("observer_damping", P),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "rampup_time_vs_scan_start",
            lambda scan_starts: PZ.rampup_time_vs_scan_start(scan_starts, max_samples=200),
            dict(scan_starts=[0.0, 0.5]),
            [Param("scan_starts", A, values=ARRAY[:1] + ARRAY[2:4] + ARRAY[5:])],
        )
    )

    # -- hysteresis
    from jerklab import hysteresis as HY

    T.append(
        Target(
            "hysteresis",
            "Preisach",
            HY.Preisach,
            dict(u_min=-1.0, u_max=1.0, density=np.ones((4, 4))),
            [
                Param("u_min", R),
                Param("u_max", R),
                Param("density", A, values=ARRAY + [("(1e9,1e9) size", None)]),
                Param("offset", R),
                Param("initial", S),
            ],
        )
    )
    T.append(
        Target(
            "hysteresis",
            "Preisach.uniform",
            HY.Preisach.uniform,
            dict(u_min=-1.0, u_max=1.0, n=10),
            [Param("u_min", R), Param("u_max", R), Param("n", I1), Param("gain", P)],
        )
    )
    T.append(
        Target(
            "hysteresis",
            "Preisach.apply",
            lambda u: _preisach().apply(u),
            dict(u=[0.0, 0.5]),
            [Param("u", A, ok=("empty", "2-D"))],
        )
    )
    T.append(
        Target(
            "hysteresis",
            "Preisach.peek",
            lambda u: _preisach().peek(u),
            dict(u=0.5),
            [Param("u", R, ok=("list",))],
        )
    )
    T.append(
        Target(
            "hysteresis",
            "Preisach.invert",
            lambda f_d, eps, max_iter: _preisach().invert(f_d, eps=eps, max_iter=max_iter),
            dict(f_d=[0.0, 0.5], eps=None, max_iter=200),
            [
                Param("f_d", A, ok=("empty", "2-D")),
                Param("eps", P, ok=("None",)),
                Param("max_iter", I1),
            ],
        )
    )
    T.append(
        Target(
            "hysteresis",
            "Preisach.everett",
            lambda alpha, beta: _preisach().everett(alpha, beta),
            dict(alpha=0.5, beta=-0.5),
            [Param("alpha", R, ok=("list",)), Param("beta", R, ok=("list",))],
        )
    )
    T.append(
        Target(
            "hysteresis",
            "forc_experiment",
            lambda system, **kw: HY.forc_experiment(
                _preisach() if system is _BASE else system, **kw
            ),
            dict(system=_BASE, u_min=-1.0, u_max=1.0, n_curves=5, points_per_curve=5),
            [
                Param("system", O),
                Param("u_min", R),
                Param("u_max", R),
                Param("n_curves", I1),
                Param("points_per_curve", I1),
            ],
        )
    )
    T.append(
        Target(
            "hysteresis",
            "fit_preisach",
            lambda forc_data, n, regularization: HY.fit_preisach(
                forc_data
                if forc_data is not None
                else HY.forc_experiment(_preisach(), -1, 1, 5, 5),
                n,
                regularization,
            ),
            dict(forc_data=None, n=5, regularization=0.0),
            [Param("forc_data", O, values=OBJ[1:]), Param("n", I1), Param("regularization", N)],
        )
    )

    # -- controller (fixed elsewhere; probed here for the lead)
    from jerklab import controller as C

    T.append(
        Target(
            "controller",
            "pole_placement_pid",
            C.pole_placement_pid,
            dict(K=32.4, tau=0.025, wn=20.0),
            [
                Param("K", P),
                Param("tau", P),
                Param("wn", P),
                Param("zeta", P),
                Param("sigma", P, ok=("None",)),
            ],
        )
    )
    T.append(
        Target(
            "controller",
            "Gains.discretize",
            lambda Ts: _gains().discretize(Ts),
            dict(Ts=0.005),
            [Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "controller",
            "discrete_pole_placement_pid",
            C.discrete_pole_placement_pid,
            dict(K=32.4, tau=0.025, wn=20.0),
            [
                Param("K", P),
                Param("tau", P),
                Param("wn", P),
                Param("zeta", P),
                Param("Ts", P),
                Param("loop", S),
                Param("extra_pole", R, ok=("None", "0", "negative", "1e-300")),
            ],
        )
    )
    T.append(
        Target(
            "controller",
            "velocity_pole_placement_pid",
            C.velocity_pole_placement_pid,
            dict(K=32.4, tau=0.025, wn=20.0),
            [Param("K", P), Param("tau", P), Param("wn", P), Param("zeta", P), Param("kd", N)],
        )
    )
    # tau = 0 is the documented static inverse u = omega/K (domain tau >= 0), not a wrong value
    T.append(
        Target(
            "controller",
            "Feedforward",
            C.Feedforward,
            dict(K=32.4, tau=0.025),
            [Param("K", P), Param("tau", P, ok=("0",))],
        )
    )
    T.append(
        Target(
            "controller",
            "DigitalController",
            lambda gains, output_limit, error_scale: C.DigitalController(
                gains if gains is not None else _gains(0.005),
                output_limit=output_limit,
                error_scale=error_scale,
            ),
            dict(gains=None, output_limit=12.0, error_scale=1.0),
            # output_limit=None is documented: no clamp
            [
                Param("gains", O, values=OBJ[1:]),
                Param("output_limit", P, ok=("None",)),
                Param("error_scale", P),
            ],
        )
    )

    def _ctl_step(ref_position, ref_velocity, ref_accel, measured_position):
        c = C.DigitalController(_gains(0.005), feedforward=C.Feedforward(32.4, 0.025))
        return c.step(ref_position, ref_velocity, ref_accel, measured_position), c.fault

    def _ctl_check(result, kw):
        # a non-finite measurement is held (issue 12 item 8: "rejects or holds ... and says so"):
        # legal only if the controller reports it in .fault
        m = kw["measured_position"]
        if isinstance(m, float) and not math.isfinite(m) and result[1] is None:
            return f"measured_position={m!r} held without a fault"
        return None

    T.append(
        Target(
            "controller",
            "DigitalController.step",
            _ctl_step,
            dict(ref_position=0.1, ref_velocity=0.0, ref_accel=0.0, measured_position=0.0),
            [
                Param("ref_position", R),
                Param("ref_velocity", R),
                Param("ref_accel", R),
                Param("measured_position", R, ok=("nan", "+inf", "-inf")),
            ],
            check=_ctl_check,
        )
    )
    T.append(
        Target(
            "controller",
            "PositionLoop",
            lambda K, tau, Ts: C.PositionLoop(K, tau, _gains(), Ts=Ts),
            dict(K=32.4, tau=0.025, Ts=0.005),
            [Param("K", P), Param("tau", P), Param("Ts", P, ok=("None",))],
        )
    )
    T.append(
        Target(
            "controller",
            "desired_poles",
            C.desired_poles,
            dict(wn=20.0),
            [Param("wn", P), Param("zeta", P), Param("sigma", P, ok=("None",))],
        )
    )
    T.append(
        Target(
            "controller",
            "paper_error_scale",
            C.paper_error_scale,
            dict(),
            [Param("Ts", P), Param("encoder_ppr", I1), Param("decoding", I1)],
        )
    )

    # -- sim
    from jerklab import sim as SM

    def _sim_check(r, kw):
        # documented: settling_time is inf when the loop never settles within the run, which is
        # the case of every run that ends before the move does (t_end < duration); any other
        # non-finite number is wrong
        m = dict(r.metrics)
        if math.isinf(m.get("settling_time", 0.0)) and r.time[-1] < r.info["duration"]:
            del m["settling_time"]
        bad = _nonfinite(m) or _nonfinite(r.position) or _nonfinite(r.command)
        return f"result has {bad}" if bad else None

    # t_end >= 0 is the documented domain (t_end = 0: the one sample at t = 0)
    T.append(
        Target(
            "sim",
            "simulate",
            lambda profile, motor, controller, Ts, t_end: SM.simulate(
                profile if profile is not None else _prof(),
                motor if motor is not None else _motor(),
                controller if controller is not None else _gains(0.005),
                Ts=Ts,
                t_end=t_end,
            ),
            dict(profile=None, motor=None, controller=None, Ts=None, t_end=None),
            [
                Param("profile", O, values=OBJ[1:]),
                Param("motor", O, values=OBJ[1:]),
                Param("controller", O, values=OBJ[1:]),
                Param("Ts", P, ok=("None",)),
                Param("t_end", N, ok=("None",)),
            ],
            check=_sim_check,
            allow_nonfinite=True,
        )
    )
    # K=None / tau=None are documented: the template motor's value
    T.append(
        Target(
            "sim",
            "simulate_batch",
            lambda K, tau: SM.simulate_batch(
                _prof(), _motor(), _gains(0.005), K=K, tau=tau, engine="numpy"
            ),
            dict(K=[30.0, 32.4], tau=[0.025, 0.03]),
            [
                Param("K", A, values=ARRAY + AP, ok=("None",)),
                Param("tau", A, values=ARRAY + AP, ok=("None",)),
            ],
        )
    )
    T.append(
        Target(
            "sim",
            "perturbed_plants",
            SM.perturbed_plants,
            dict(n=3),
            [
                Param("n", I1),
                Param("K", P),
                Param("tau", P),
                Param("K_spread", N),
                Param("tau_spread", N),
            ],
        )
    )
    T.append(
        Target(
            "sim",
            "SampledProfile",
            SM.SampledProfile,
            dict(Ts=0.005, position=[0.0, 0.1, 0.2]),
            [Param("Ts", P), Param("position", A)],
        )
    )
    T.append(
        Target("sim", "StepProfile", SM.StepProfile, dict(distance=1.0), [Param("distance", R)])
    )

    # -- ident
    from jerklab import ident as ID

    u_id = np.r_[np.zeros(10), 6.0 * np.ones(200)]
    th_id = ID.simulate_dc_motor(32.4, 0.025, 0.005, u_id)[: len(u_id)]
    T.append(
        Target(
            "ident",
            "fit_dc_motor",
            ID.fit_dc_motor,
            dict(u=u_id, theta=th_id, Ts=0.005),
            [Param("u", A), Param("theta", A), Param("Ts", P), Param("method", S)],
        )
    )
    T.append(
        Target(
            "ident",
            "arx",
            ID.arx,
            dict(y=th_id, u=u_id, na=2, nb=2, nk=1),
            # documented: na >= 0, nb >= 0 (na + nb >= 1): na = 0 is an FIR model, nb = 0 an AR model
            [Param("y", A), Param("u", A), Param("na", I0), Param("nb", I0), Param("nk", I0)],
        )
    )
    # K <= 0 is what a fit on a reversed encoder returns (fit_dc_motor warns); simulating that
    # fitted model (validate, compare) must work, so K is any finite real here
    T.append(
        Target(
            "ident",
            "simulate_dc_motor",
            ID.simulate_dc_motor,
            dict(K=32.4, tau=0.025, Ts=0.005, u=u_id),
            [Param("K", R), Param("tau", P), Param("Ts", P), Param("u", A, ok=("empty",))],
        )
    )
    T.append(
        Target(
            "ident",
            "dc_motor_zoh_coefficients",
            ID.dc_motor_zoh_coefficients,
            dict(K=32.4, tau=0.025, Ts=0.005),
            [Param("K", R), Param("tau", P), Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "ident",
            "IdentData",
            ID.IdentData,
            dict(voltage=u_id, position=th_id, Ts=0.005),
            [Param("voltage", A), Param("position", A), Param("Ts", P)],
        )
    )
    T.append(
        Target(
            "ident",
            "step_input",
            ID.step_input,
            dict(duration=1.0, Ts=0.005, amplitude=6.0),
            [Param("duration", P), Param("Ts", P), Param("amplitude", R), Param("t_step", N)],
        )
    )
    T.append(
        Target(
            "ident",
            "prbs",
            ID.prbs,
            dict(duration=1.0, Ts=0.005, amplitude=6.0),
            [
                Param("duration", P),
                Param("Ts", P),
                Param("amplitude", R),
                Param("clock_period", P, ok=("None",)),
            ],
        )
    )
    T.append(
        Target(
            "ident",
            "fit_percent",
            ID.fit_percent,
            dict(y=[1.0, 2.0, 3.0], y_hat=[1.0, 2.1, 2.9]),
            [Param("y", A), Param("y_hat", A)],
        )
    )

    def _resid_check(r, kw):
        # documented: without u, cross_bound is NaN (no independence test, crosscorr None)
        fields = {f.name: getattr(r, f.name) for f in dataclasses.fields(r)}
        if r.crosscorr is None:
            fields.pop("cross_bound")
        bad = _nonfinite(fields)
        return f"result has {bad}" if bad else None

    T.append(
        Target(
            "ident",
            "residual_analysis",
            ID.residual_analysis,
            dict(residuals=np.sin(np.arange(100.0))),
            [Param("residuals", A), Param("max_lag", I1), Param("confidence", P)],
            check=_resid_check,
            allow_nonfinite=True,
        )
    )
    T.append(
        Target(
            "ident", "sample_time_range", ID.sample_time_range, dict(tau=0.025), [Param("tau", P)]
        )
    )

    # -- widgets
    from jerklab import widgets as W

    def _tuning_check(r, kw):
        # documented: the responses of a loop reported UNSTABLE grow without bound and may overflow
        # (level and message say so, the plots clip them); anything else must be finite
        fields = {f.name: getattr(r, f.name) for f in dataclasses.fields(r)}
        if r.level == "unstable" and not r.stable:
            for k in ("y_step", "y_dist", "err_move", "u_move"):
                fields.pop(k)
        bad = _nonfinite(fields)
        return f"result has {bad}" if bad else None

    T.append(
        Target(
            "widgets",
            "compute_pole_placement",
            lambda **kw: W.compute_pole_placement(simulate_move=False, **kw),
            dict(),
            [
                Param("K", P),
                Param("tau", P),
                Param("zeta", P),
                Param("wn", P),
                Param("sigma_ratio", P),
                Param("Ts", P),
                Param("design", S),
            ],
            check=_tuning_check,
            allow_nonfinite=True,
        )
    )
    T.append(
        Target(
            "widgets",
            "stability_verdict",
            W.stability_verdict,
            dict(max_radius=0.9, desired_radius=0.9),
            [Param("max_radius", N), Param("desired_radius", N)],
        )
    )

    # -- rig and recordings
    from jerklab import rig as RG

    meta = dict(Ts=0.005, counts_per_rad=71.3, volts_per_pwm=12 / 1023)

    def recording(**kw):
        return RG.Recording(dict(meta, **kw))

    T.append(
        Target(
            "recording",
            "Recording(metadata)",
            recording,
            dict(),
            [Param("Ts", P), Param("counts_per_rad", P), Param("volts_per_pwm", P)],
        )
    )
    T.append(
        Target(
            "recording",
            "Recording(metadata=...)",
            RG.Recording,
            dict(metadata=meta),
            [Param("metadata", O, values=OBJ[:4])],
        )
    )
    T.append(
        Target(
            "recording",
            "Recording.append",
            lambda **kw: RG.Recording(meta).append(**kw),
            dict(index=0, reference=0.0, counts=0, pwm=0, flags=0),
            [
                Param("index", I0),
                Param("reference", R),
                Param("counts", I0, ok=("negative",)),
                Param("pwm", I0, ok=("negative",)),
                Param("flags", I0),
            ],
        )
    )
    T.append(
        Target(
            "rig",
            "connect",
            lambda port, timeout, hello_timeout: RG.connect(
                port, progress=False, link=RG.Link(timeout=timeout, hello_timeout=hello_timeout)
            ).close(),
            dict(port=None, timeout=2.0, hello_timeout=None),
            [
                Param(
                    "port",
                    O,
                    ok=("None",),
                    values=[
                        ("int", 3),
                        ("float", 1.5),
                        ("dict", {}),
                        ("no such device", "/dev/jerklab-nonexistent"),
                        ("bad url", "nonsense://x"),
                    ],
                ),
                Param("timeout", P),
                Param("hello_timeout", P, ok=("None",)),
            ],
        )
    )
    T.append(
        Target(
            "rig",
            "Rig.run_move",
            lambda profile, gains, Ts, settle, decimation, host_timeout, max_voltage: _with_rig(
                "run_move"
            )(
                profile=profile if profile is not None else _prof(),
                gains=gains if gains is not None else _gains(),
                Ts=Ts,
                settle=settle,
                decimation=decimation,
                host_timeout=host_timeout,
                max_voltage=max_voltage,
                path=False,
            ),
            dict(
                profile=None,
                gains=None,
                Ts=0.005,
                settle=0.0,
                decimation=1,
                host_timeout=1.0,
                max_voltage=None,
            ),
            [
                Param("profile", O, values=OBJ[1:]),
                Param("gains", O, values=OBJ[1:]),
                Param("Ts", P, ok=("None",)),  # None: the gains' own period, else 5 ms
                Param("settle", N),
                Param("decimation", I1),
                Param("host_timeout", N),
                Param("max_voltage", P, ok=("None",)),
            ],
        )
    )
    T.append(
        Target(
            "rig",
            "Rig.run_move(limits)",
            _run_move_limits,
            dict(),
            [
                Param("max_accel", P, values=[("1e39", 1e39), ("1e300", 1e300)]),
                Param("max_velocity", P, values=[("1e39", 1e39), ("1e300", 1e300)]),
                Param("kpd_scale", P, shown="kpd", values=[("1e39", 1e39), ("1e300", 1e300)]),
            ],
        )
    )
    T.append(
        Target(
            "rig",
            "Rig.step",
            lambda voltage, seconds, Ts, rest: _with_rig("step")(
                voltage=voltage, seconds=seconds, Ts=Ts, rest=rest, path=False
            ),
            dict(voltage=1.0, seconds=0.05, Ts=0.005, rest=0.0),
            [Param("voltage", R), Param("seconds", P), Param("Ts", P), Param("rest", N)],
        )
    )
    T.append(
        Target(
            "rig",
            "Rig.set_model",
            lambda K, tau: _with_rig("set_model")(K=K, tau=tau),
            dict(K=32.4, tau=0.025),
            [Param("K", P), Param("tau", P)],
        )
    )
    T += _targets_issue31()
    T += _targets_hostloop_classrig()
    return T


def _targets_issue31() -> list[Target]:
    """Issue 31: wrong types and files at the public boundary, unbounded requests, and the APIs
    that landed since round 2 (shaping, multiaxis, rig/retarget, the lab's checks and hand-in,
    the broker)."""
    from jerklab import fpga as FP
    from jerklab import multiaxis as MA
    from jerklab import piezo as PZ
    from jerklab import rig as RG
    from jerklab import shaping as SH
    from jerklab.controller import pole_placement_pid
    from jerklab.ident import IdentData
    from jerklab.lab import checks as LC
    from jerklab.lab import handin as LH
    from jerklab.plant import DCMotor, FlexibleDCMotor
    from jerklab.rig import retarget as RT
    from jerklab.rig.recording import compare

    T: list[Target] = []
    wrong_obj = [("str", "x"), ("int", 3), ("float", 1.5), ("dict", {}), ("list", [1.0])]
    # -- a wrong type reaches deep code (round 3: AttributeError)
    cycle = []

    def _cycle():
        if not cycle:
            cycle.append(PZ.shape_cycle())
        return cycle[0]

    T.append(
        Target(
            "piezo",
            "evaluate_cycle",
            lambda cycle, perturbed: PZ.evaluate_cycle(
                _cycle() if cycle is _BASE else cycle, perturbed
            ),
            dict(cycle=_BASE, perturbed=None),
            [
                Param("cycle", O, values=wrong_obj + [("None", None)]),
                Param("perturbed", O, ok=("None",), values=wrong_obj),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "closed_loop(hysteresis)",
            lambda hysteresis, actuator: PZ.closed_loop(
                _cycle(), hysteresis=hysteresis, actuator=actuator, extra_time=0.0
            ),
            dict(hysteresis=None, actuator=None),
            [
                Param("hysteresis", O, ok=("None",), values=wrong_obj),
                Param("actuator", O, ok=("None",), values=wrong_obj),
            ],
        )
    )
    T.append(
        Target(
            "piezo",
            "shape_rampup(orders)",
            lambda orders: PZ.shape_rampup(orders=orders),
            dict(orders=1),
            [
                Param(
                    "orders",
                    O,
                    values=[
                        ("str", "x"),
                        ("float", 1.5),
                        ("50", 50),
                        ("-1", -1),
                        ("{1: 50}", {1: 50}),
                        ("{3: 1}", {3: 1}),
                        ("{1: 'a'}", {1: "a"}),
                        ("list", [1]),
                    ],
                )
            ],
        )
    )
    T.append(
        Target(
            "fpga",
            "published_divider_lockup",
            FP.published_divider_lockup,
            dict(model=FP.YangSCurve(clock_hz=500_000)),
            [Param("model", O, values=wrong_obj + [("None", None)])],
        )
    )
    T.append(
        Target(
            "fpga",
            "simulate_verilog(model)",
            FP.simulate_verilog,
            dict(model=FP.YangSCurve(clock_hz=500_000)),
            [Param("model", O, values=wrong_obj + [("None", None)])],
        )
    )
    T.append(
        Target(
            "fpga",
            "YangSCurve(work)",
            FP.YangSCurve,
            dict(accel_time=1.0, bits=32, clock_hz=50_000_000),
            [
                Param("accel_time", P, values=[("1e6", 1e6), ("1e4", 1e4)]),
                Param("bits", I1, values=[("64", 64), ("63", 63), ("4", 4)]),
                Param("clock_hz", I1, values=[("1e15 float", 1e15), ("2**70", 2**70)]),
            ],
        )
    )
    T.append(
        Target(
            "fpga",
            "read_vcd",
            lambda path, signals: FP.read_vcd(_files()["vcd"] if path is _BASE else path, signals),
            dict(path=_BASE, signals=["clk"]),
            [
                Param(
                    "path",
                    O,
                    values=[
                        ("missing file", "/nonexistent/x.vcd"),
                        ("int", 3),
                        ("None", None),
                        ("a folder", "/"),
                        ("empty", ""),
                    ],
                ),
                Param("signals", O, values=[("str", "clk"), ("int", 3), ("None", None)]),
            ],
        )
    )
    T.append(
        Target(
            "recording",
            "compare",
            lambda rec, sim: compare(
                RG.Recording({"Ts": 0.005, "counts_per_rad": 71.3, "volts_per_pwm": 0.0117})
                if rec is _BASE
                else rec,
                _small_sim() if sim is _BASE else sim,
            ),
            dict(rec=_BASE, sim=_BASE),
            [
                Param("rec", O, values=wrong_obj + [("None", None)]),
                Param("sim", O, values=wrong_obj + [("None", None)]),
            ],
            allow_nonfinite=True,  # an empty recording: no samples in common, NaN differences
        )
    )
    T.append(
        Target(
            "recording",
            "Recording.load(path)",
            lambda path: RG.Recording.load(_files()["recording"] if path is _BASE else path),
            dict(path=_BASE),
            [
                Param(
                    "path",
                    O,
                    values=[
                        ("int", 3),
                        ("float", 1.5),
                        ("empty", ""),
                        ("list", ["a"]),
                        ("bytes", b"x"),
                    ],
                )
            ],
        )
    )
    T.append(
        Target(
            "ident",
            "IdentData.load(path)",
            lambda path: IdentData.load(_files()["ident"] if path is _BASE else path),
            dict(path=_BASE),
            [Param("path", O, values=[("int", 3), ("float", 1.5), ("empty", ""), ("list", ["a"])])],
        )
    )
    T.append(
        Target(
            "rig",
            "Rig.wait_still",
            lambda window, tolerance, timeout: _with_rig("wait_still")(
                window=window, tolerance=tolerance, timeout=timeout
            ),
            dict(window=10, tolerance=0, timeout=0.5),
            [
                Param("window", I1, values=INT + [("1", 1), ("70000", 70000)]),
                Param("tolerance", I0),
                Param("timeout", P),
            ],
        )
    )
    # -- numbers
    T.append(
        Target(
            "controller",
            "pole_placement_pid(sigma)",
            lambda sigma: pole_placement_pid(32.4, 0.025, 20.0, sigma=sigma),
            dict(sigma=140.0),
            [Param("sigma", P, ok=("None",), values=REAL + [("1e-300 (slow pole)", 1e-300)])],
        )
    )
    T.append(
        Target(
            "plant",
            "DCMotor(seed)",
            DCMotor,
            dict(seed=None),
            [Param("seed", I0, ok=("None", "0"), values=INT)],
        )
    )
    T.append(
        Target(
            "plant",
            "FlexibleDCMotor(load_ratio).zoh",
            lambda load_ratio: FlexibleDCMotor(load_ratio=load_ratio).zoh(0.005),
            dict(load_ratio=0.05),
            [Param("load_ratio", P)],
        )
    )
    # -- shaping
    T.append(
        Target(
            "shaping",
            "input_shaper",
            SH.input_shaper,
            dict(kind="zvd", frequency_hz=8.0, damping=0.02),
            [
                Param("kind", S),
                Param("frequency_hz", P),
                Param("damping", N, values=REAL + [("1", 1.0), ("2", 2.0)]),
            ],
        )
    )
    T.append(
        Target(
            "shaping",
            "residual_vibration_of",
            SH.residual_vibration_of,
            dict(amplitudes=[0.5, 0.5], times=[0.0, 0.0625], frequency_hz=8.0, damping=0.0),
            [
                Param("amplitudes", A, values=ARRAY + [("length 3", lambda: [0.2, 0.3, 0.5])]),
                Param("times", A),
                Param("frequency_hz", P, ok=("list",)),  # an array of frequencies is legal
                Param("damping", N),
            ],
        )
    )
    T.append(
        Target(
            "shaping",
            "chirp_input",
            SH.chirp_input,
            dict(duration=1.0, Ts=0.005, amplitude=3.0, f0=1.0, f1=20.0, offset=0.0),
            [
                Param("duration", P),
                Param("Ts", P),
                Param("amplitude", P),
                Param("f0", P),
                Param("f1", P, values=REAL + [("above Nyquist", 150.0)]),
                Param("offset", R),
            ],
        )
    )
    T.append(
        Target(
            "shaping",
            "profile_residual_vibration",
            lambda profile, frequency_hz, damping: SH.profile_residual_vibration(
                _prof("sine_jerk_optimal") if profile is _BASE else profile, frequency_hz, damping
            ),
            dict(profile=_BASE, frequency_hz=8.0, damping=0.0),
            [
                Param("profile", O, values=wrong_obj + [("None", None)]),
                Param("frequency_hz", P, ok=("list",)),
                Param("damping", N),
            ],
        )
    )
    T.append(
        Target(
            "shaping",
            "tuned_profile",
            SH.tuned_profile,
            dict(
                kind="sine_jerk_optimal",
                distance=1.0,
                frequency_hz=8.0,
                max_accel=300.0,
                max_velocity=100.0,
                max_jerk=None,
                damping=0.0,
            ),
            [
                Param("kind", S),
                Param("distance", R),
                Param("frequency_hz", P),
                Param("max_accel", P),
                Param("max_velocity", P),
                Param("max_jerk", P, ok=("None",)),
                Param("damping", N),
            ],
        )
    )
    T.append(
        Target(
            "shaping",
            "residual_amplitude",
            SH.residual_amplitude,
            dict(
                y=np.sin(np.arange(200) * 0.3) * np.exp(-np.arange(200) * 0.01), Ts=0.005, start=50
            ),
            [
                Param("y", A),
                Param("Ts", P),
                Param("start", I0, values=INT + [("past the end", 500)]),
            ],
        )
    )
    # -- multiaxis
    lim = [(2000.0, 300.0, 100.0), (2000.0, 300.0, 100.0)]
    T.append(
        Target(
            "multiaxis",
            "plan_multi_axis",
            MA.plan_multi_axis,
            dict(distances=[1.0, 0.5], limits_per_axis=lim, sync="time", planner="scurve"),
            [
                Param("distances", A, values=ARRAY + [("3 for 2 axes", lambda: [1.0, 2.0, 3.0])]),
                Param(
                    "limits_per_axis",
                    O,
                    values=[
                        ("str", "x"),
                        ("None", None),
                        ("one axis", [(2000.0, 300.0, 100.0)]),
                        ("nan limit", [(2000.0, NAN, 100.0)] * 2),
                        ("negative limit", [(2000.0, -300.0, 100.0)] * 2),
                        ("2-tuple", [(2000.0, 300.0)] * 2),
                        ("dict without key", [{"max_jerk": 1.0}] * 2),
                    ],
                ),
                Param("sync", S),
                Param("planner", S),
            ],
        )
    )
    base_axis = []

    def _axis():
        if not base_axis:
            from jerklab.planner import plan_scurve

            base_axis.append(plan_scurve(1.0, 2000.0, 300.0, 100.0))
        return base_axis[0]

    T.append(
        Target(
            "multiaxis",
            "stretch_to_duration",
            lambda profile, duration: MA.stretch_to_duration(
                _axis() if profile is _BASE else profile, duration
            ),
            dict(profile=_BASE, duration=1.0),
            [
                Param("profile", O, values=wrong_obj + [("None", None)]),
                Param("duration", P, values=REAL + [("shorter than optimal", 0.01)]),
            ],
        )
    )
    T.append(
        Target(
            "multiaxis",
            "MultiAxisPlan.synchronized",
            lambda Ts: MA.plan_multi_axis([1.0, 0.5], lim).synchronized(Ts),
            dict(Ts=0.005),
            [Param("Ts", P, values=REAL + [("1e-300 (below MIN_SYNC_TS)", 1e-300)])],
        )
    )
    # -- rig/retarget (mirrors of the firmware's re-planning)
    T.append(
        Target(
            "retarget",
            "rest_plan",
            RT.rest_plan,
            dict(kind=2, distance=1.0, max_jerk=2000.0, max_accel=300.0, max_velocity=100.0),
            [
                Param("kind", I0, values=INT + [("4", 4)]),
                Param("distance", R),
                Param("max_jerk", P),
                Param("max_accel", P),
                Param("max_velocity", P),
            ],
        )
    )
    T.append(
        Target(
            "retarget",
            "moving_plan",
            RT.moving_plan,
            dict(
                kind=2, distance=1.0, v0=1.0, max_jerk=2000.0, max_accel=300.0, max_velocity=100.0
            ),
            [
                Param("kind", I0, values=INT + [("4", 4)]),
                Param("distance", R),
                Param("v0", N),
                Param("max_jerk", P),
                Param("max_accel", P),
                Param("max_velocity", P),
            ],
            allow_nonfinite=False,
        )
    )
    T.append(
        Target(
            "retarget",
            "stop_plan",
            RT.stop_plan,
            dict(kind=2, v=1.0, max_jerk=2000.0, max_accel=300.0),
            [
                Param("kind", I0, values=INT + [("4", 4)]),
                Param("v", R),
                Param("max_jerk", P),
                Param("max_accel", P),
            ],
        )
    )
    T.append(
        Target(
            "retarget",
            "lead_samples",
            RT.lead_samples,
            dict(Ts_us=5000),
            [Param("Ts_us", I1)],
        )
    )
    # -- the lab: checks and the hand-in
    T.append(
        Target(
            "lab",
            "sweep_fit",
            LC.sweep_fit,
            dict(speeds={-3.0: -84.5, -2.0: -52.2, -1.0: -20.1, 1.0: 20.0, 2.0: 52.0, 3.0: 84.0}),
            [
                Param(
                    "speeds",
                    O,
                    values=[
                        ("str", "x"),
                        ("None", None),
                        ("empty", {}),
                        ("one level", {1.0: 20.0}),
                        ("one side", {1.0: 20.0, 2.0: 52.0, 3.0: 84.0, 4.0: 116.0}),
                        ("nan speed", {-2.0: -52.0, -1.0: -20.0, 1.0: NAN, 2.0: 52.0}),
                        ("text voltage", {"a": 1.0, "b": 2.0}),
                        ("text speed", {-2.0: "x", -1.0: -20.0, 1.0: 20.0, 2.0: 52.0}),
                    ],
                )
            ],
        )
    )
    T.append(
        Target(
            "lab",
            "read_handin",
            lambda path: LH.read_handin(_files()["handin"] if path is _BASE else path),
            dict(path=_BASE),
            [
                Param(
                    "path",
                    O,
                    values=[
                        ("int", 3),
                        ("None", None),
                        ("empty", ""),
                        ("missing file", "/nonexistent/handin.zip"),
                    ],
                )
            ],
        )
    )
    # -- the broker
    from jerklab.broker import BrokerRig

    T.append(
        Target(
            "broker",
            "BrokerRig",
            lambda address, timeout: BrokerRig(
                _broker().address if address is _BASE else address, timeout=timeout
            ),
            dict(address=_BASE, timeout=1.0),
            [
                Param(
                    "address",
                    O,
                    values=[
                        ("int", 3),
                        ("None", None),
                        ("no scheme", "127.0.0.1:1"),
                        ("bad port", "broker://127.0.0.1:notaport"),
                        ("port 0", "broker://127.0.0.1:0"),
                        ("port 70000", "broker://127.0.0.1:70000"),
                    ],
                ),
                Param("timeout", P),
            ],
        )
    )
    return T


def _host_loop(control, **kw):
    """One short host-in-the-loop run on the virtual rig; a law's refused voltage comes back
    as the ValueError the probe counts (see :func:`_targets_hostloop_classrig`)."""
    from jerklab.rig.hostloop import ControlLawError

    rig = _rig()
    try:
        # a gentle P law (1 V/rad: no overshoot on the virtual motor) toward the reference, or
        # toward 0 without one (r is nan then)
        law = (lambda t, p, r: 1.0 * ((0.0 if r != r else r) - p)) if control is _BASE else control
        try:
            return rig.host_loop(law, **kw)
        except ControlLawError as exc:
            rec = exc.recording
            status = "" if rec is None else str(rec.metadata.get("status", ""))
            stopped = status.startswith("error") and "tick" in status
            if stopped and exc.tick is not None and "voltage" in str(exc):
                raise ValueError(f"voltage refused at tick {exc.tick}: {exc}") from None
            raise
    finally:
        rig.close()


def _run_completed(rec, kw):
    """A run the law did not refuse must have completed (a fault ends it with its status)."""
    status = str(rec.metadata.get("status"))
    return None if status == "complete" else f"the run ended {status!r}"


_SERVICE: dict = {}


def _class_service():
    """A class rig service on 127.0.0.1 with one token (started once per worker)."""
    if "svc" not in _SERVICE:
        from jerklab.lab.service import ClassRigService, TokenFile

        tmp = Path(tempfile.mkdtemp(prefix="jerklab-faults-svc-"))
        tokens = tmp / "tokens.json"
        tokens.write_text(json.dumps({"tok-probe-5f1c2a9e": "probe"}))
        svc = ClassRigService(
            TokenFile(tokens), tmp / "checks.log", b"faults-probe-instructor-key", "127.0.0.1:0"
        )
        svc.start()
        _SERVICE["svc"] = svc
    return _SERVICE["svc"]


def _class_rig(**kw):
    from jerklab.lab.classrig import ClassRig

    kw.setdefault("token", "tok-probe-5f1c2a9e")
    return ClassRig(
        _class_service().url if kw.get("address") is _BASE else kw.pop("address"),
        **{k: v for k, v in kw.items() if k != "address"},
    )


def _with_class_rig(method):
    def call(**kw):
        rig = _class_rig(address=_BASE, lab=1)
        try:
            return getattr(rig, method)(**kw)
        finally:
            rig.close()

    return call


def _targets_hostloop_classrig() -> list[Target]:
    """The host loop (``Rig.host_loop``, a law's voltage) and the class rig service's client.

    A law that returns a bad voltage ends the run with
    :class:`jerklab.rig.hostloop.ControlLawError`; :func:`_host_loop` counts that as a clear
    refusal only when the recording's status says the motor was stopped and names the tick."""
    T: list[Target] = []
    not_callable = [("str", "x"), ("int", 3), ("None", None), ("dict", {})]
    T.append(
        Target(
            "hostloop",
            "host_loop",
            lambda control, Ts, duration, reference, max_misses, max_voltage: _host_loop(
                _BASE if control is _BASE else control,
                Ts=Ts,
                duration=duration,
                reference=reference,
                max_misses=max_misses,
                max_voltage=max_voltage,
                path=False,
            ),
            dict(
                control=_BASE, Ts=0.01, duration=0.1, reference=0.5, max_misses=3, max_voltage=6.0
            ),
            [
                Param("control", O, values=not_callable),
                Param("Ts", P, values=REAL + [("1 ms", 0.001), ("1 s", 1.0)]),
                Param("duration", P, values=[v for v in REAL if v[0] != "1e300"]),
                Param(
                    "reference",
                    R,
                    ok=("None", "list"),
                    # a reference step past max_error (0.5 rad) is a tracking-error stop
                    values=[v for v in REAL if v[0] not in ("1e300", "1e9", "negative")]
                    + [("negative", -0.3), ("dict", {})],
                ),
                Param("max_misses", I1, values=[v for v in INT if v[0] not in ("1e9", "2**64")]),
                Param("max_voltage", P, ok=("None",), values=REAL),  # None: the supply
            ],
            check=_run_completed,
            allow_nonfinite=True,
        )
    )
    law_values = [
        ("nan", NAN),
        ("+inf", INF),
        ("-inf", -INF),
        ("str", "1.0"),
        ("None", None),
        ("list", [1.0, 2.0]),
        ("complex", 1j),
        ("bool", True),
    ]
    T.append(
        Target(
            "hostloop",
            "host_loop(law returns)",
            lambda voltage: _host_loop(
                lambda t, p, r: 1.0 if voltage is _BASE else voltage,
                Ts=0.01,
                duration=0.05,
                reference=None,
                path=False,
            ),
            dict(voltage=_BASE),
            [Param("voltage", R, values=law_values)],
            check=_run_completed,
            allow_nonfinite=True,
        )
    )
    # -- the class rig service's client (a running service on 127.0.0.1)
    T.append(
        Target(
            "classrig",
            "ClassRig",
            lambda address, lab, token, timeout: _class_rig(
                address=address, lab=lab, token=token, timeout=timeout
            ).close(),
            dict(address=_BASE, lab=1, token="tok-probe-5f1c2a9e", timeout=10.0),
            [
                Param(
                    "address",
                    O,
                    values=[
                        ("int", 3),
                        ("None", None),
                        ("no scheme", "127.0.0.1:1"),
                        ("bad port", "classrig://127.0.0.1:notaport"),
                        ("port 70000", "classrig://127.0.0.1:70000"),
                    ],
                ),
                Param("lab", I1, values=INT + [("lab 9", 9)]),
                Param(
                    "token",
                    O,
                    values=[("wrong", "tok-nobody-00000000"), ("int", 3), ("empty", "")],
                ),
                Param("timeout", P),
            ],
        )
    )
    T.append(
        Target(
            "classrig",
            "ClassRig.step",
            lambda voltage, seconds, Ts: _with_class_rig("step")(
                voltage=voltage, seconds=seconds, Ts=Ts, path=False
            ),
            dict(voltage=6.0, seconds=0.1, Ts=0.005),
            [
                Param(
                    "voltage", R, ok=("0", "negative"), values=[v for v in REAL if v[0] != "1e9"]
                ),
                Param("seconds", P, values=[v for v in REAL if v[0] not in ("1e300", "1e9")]),
                Param("Ts", P, values=[v for v in REAL if v[0] not in ("1e300", "1e9")]),
            ],
        )
    )
    T.append(
        Target(
            "classrig",
            "ClassRig.check",
            lambda name, answer: _with_class_rig("check")(name=name, answer=answer),
            dict(name="pre_speed", answer=180.0),
            [
                Param("name", S, values=[("unknown", "no_such_check"), ("None", None), ("int", 3)]),
                Param(
                    "answer",
                    O,
                    ok=("int", "float", "0", "negative", "1e300"),
                    values=[
                        ("object", object()),
                        ("nan", NAN),
                        ("inf", INF),
                        ("int", 3),
                        ("float", 1.5),
                    ],
                ),
            ],
        )
    )
    return T


_FILES: dict = {}


def _files() -> dict:
    """Valid files for the loaders' base cases (written once per worker, in a temporary folder)."""
    if not _FILES:
        from jerklab.lab.handin import pack

        tmp = Path(tempfile.mkdtemp(prefix="jerklab-faults-files-"))
        vcd = tmp / "a.vcd"
        vcd.write_text(
            "$timescale 1ns $end\n$var wire 1 ! clk $end\n$enddefinitions $end\n#0\n0!\n#10\n1!\n"
        )
        root = Path(__file__).resolve().parents[1] / "data"
        _FILES.update(
            vcd=vcd,
            recording=root / "rig" / "virtual_step_6V",
            ident=root / "ident" / "step_6V",
            handin=pack({"answers.json": b"{}"}, "s1", 1, tmp / "handin.zip"),
        )
    return _FILES


_BROKER: list = []


def _broker():
    """One broker on 127.0.0.1 (a virtual rig) for the worker's broker cases."""
    if not _BROKER:
        from jerklab.broker import RigBroker

        _BROKER.append(RigBroker(None, speed=1.0))
    return _BROKER[0]


def _small_sim():
    from jerklab.sim import simulate

    return simulate(_prof(), _motor(), _gains(0.005), t_end=0.05)


# ----------------------------------------------------------------------------- the cases


def _value(v):
    return v() if callable(v) else v


def _cases(targets):
    """(target index, param name or None, label, value) for every case, base case first."""
    only = os.environ.get("JERKLAB_FAULTS_ONLY")
    only = set(only.split(",")) if only else None
    out = []
    for ti, t in enumerate(targets):
        if only and t.module not in only:
            continue
        out.append((ti, None, "base", None))
        for p in t.params:
            for label, v in p.values if p.values is not None else VALUES[p.domain]:
                out.append((ti, p.name, label, v))
    return out


def _names_param(msg: str, name: str) -> bool:
    return name.lower() in msg.lower()


def classify(t: Target, pname, label, value) -> tuple[str, str]:
    """Run one case and classify it (see the module docstring)."""
    kw = dict(t.base)
    param = next((p for p in t.params if p.name == pname), None)
    if param is not None:
        if label == "(1e9,1e9) size":
            value = np.broadcast_to(np.float64(1.0), (10**5, 10**5))
        kw[pname] = _value(value)
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = t.call(**kw)
    # a missing file and a refused login (the class rig service's token): their own classes
    except (ValueError, TypeError, FileNotFoundError, PermissionError) as exc:
        if param is None:
            return "base-failed", f"{type(exc).__name__}: {exc}"
        shown = param.shown or pname
        if _names_param(str(exc), shown):
            return "clear", f"{type(exc).__name__}"
        return (
            "obscure",
            f"{type(exc).__module__}.{type(exc).__name__} not naming {shown}: {str(exc)[:120]}",
        )
    except BaseException as exc:  # noqa: BLE001 - classifying is the point
        if param is None:
            return "base-failed", f"{type(exc).__name__}: {exc}"
        return "obscure", f"{type(exc).__module__}.{type(exc).__name__}: {str(exc)[:120]}"
    if t.check is not None:
        wrong = t.check(res, kw)
        if wrong:
            return ("silent" if param is not None else "base-failed"), wrong
    if not t.allow_nonfinite:
        bad = _nonfinite(res)
        if bad:
            return ("silent" if param is not None else "base-failed"), f"result has {bad}"
    if param is None:
        return "ok", ""
    if label in REJECT.get(param.domain, ()) and label not in param.ok:
        return "silent", f"accepted {pname}={label}"
    return "ok", ""


# ----------------------------------------------------------------------------- injected faults


def _fault_rig(link_kw=None, **kw):
    from jerklab.plant import DCMotor
    from jerklab.rig import Rig, VirtualDevice, VirtualSerial

    link = VirtualSerial(VirtualDevice(DCMotor()), timeout=0.05, **(link_kw or {}))
    return Rig(link, "virtual", progress=False, timeout=0.5, hello_timeout=1.0, **kw)


def _move_args():
    from jerklab.planner import plan_sine_jerk

    return plan_sine_jerk(4 * math.pi, 2000.0, 300.0, 100.0), _gains()


def _sidecar(csv_path):
    p = Path(csv_path)
    return json.loads(p.with_suffix(".json").read_text())


class _CorruptingLink:
    """Flips one byte in every ``every`` bytes the device sends (a noisy cable)."""

    def __init__(self, link, every=97):
        self.link, self.every, self.n = link, every, 0

    def __getattr__(self, name):
        return getattr(self.link, name)

    @property
    def in_waiting(self):
        return self.link.in_waiting

    def read(self, size=1):
        data = bytearray(self.link.read(size))
        for i in range(len(data)):
            self.n += 1
            if self.n % self.every == 0:
                data[i] ^= 0x5A
        return bytes(data)


def fault_corrupt_frames(tmp):
    rig = _fault_rig()
    rig.link = _CorruptingLink(rig.link)
    prof, g = _move_args()
    try:
        rec = rig.run_move(prof, g, path=tmp / "corrupt")
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {exc}"
    finally:
        rig.close()
    m = rec.metadata
    if m.get("lost_samples", 0) + m.get("host_dropped_frames", 0) > 0:
        return (
            "clear",
            f"status {m['status']}, lost {m['lost_samples']}, dropped {m['host_dropped_frames']}",
        )
    return "silent", "corruption not counted"


def _broken_link_run(tmp, name, link_kw, expected_exc, expected_status, needs_count):
    """A move over a link that fails mid-run: the expected error, naming the file (and the
    samples saved when ``needs_count``), and the sidecar at the expected final status."""
    rig = _fault_rig(link_kw=link_kw)
    prof, g = _move_args()
    try:
        rig.run_move(prof, g, path=tmp / name)
    except expected_exc as exc:
        meta = _sidecar(tmp / f"{name}.csv")
        ok = (
            meta["status"] == expected_status
            and f"{name}.csv" in str(exc)
            and (not needs_count or "samples" in str(exc))
        )
        return ("clear" if ok else "obscure"), f"status {meta['status']}: {str(exc)[:90]}"
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {exc}"
    finally:
        rig.close()
    return "silent", "no error"


def fault_pulled_cable(tmp):
    from jerklab.rig import RigConnectionError

    return _broken_link_run(
        tmp,
        "pulled",
        dict(pull_cable_after=3000),
        RigConnectionError,
        "disconnected",
        needs_count=True,
    )


def fault_frozen_board(tmp):
    from jerklab.rig import RigTimeoutError

    return _broken_link_run(
        tmp, "frozen", dict(freeze_after=3000), RigTimeoutError, "timeout", needs_count=False
    )


class FailingFile:
    """A text file whose writes fail with ``OSError(code)`` once ``limit`` characters are written
    (a full disk: ENOSPC; a dying USB stick: EIO)."""

    def __init__(self, f, limit, code=errno.ENOSPC):
        self.f, self.limit, self.code, self.written = f, limit, code, 0

    def write(self, s):
        if self.written + len(s) > self.limit:
            raise OSError(self.code, os.strerror(self.code))
        self.written += len(s)
        return self.f.write(s)

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


@contextlib.contextmanager
def failing_csv_writes(limit, code=errno.ENOSPC):
    """Make the recordings' CSV files fail after ``limit`` characters (patches the ``open`` that
    ``jerklab.rig.recording`` uses: the real write path runs)."""
    import builtins

    import jerklab.rig.recording as recmod

    def fake_open(file, mode="r", *args, **kwargs):
        f = builtins.open(file, mode, *args, **kwargs)
        if str(file).endswith(".csv") and "w" in mode:
            return FailingFile(f, limit, code)
        return f

    recmod.open = fake_open
    try:
        yield
    finally:
        del recmod.open


def _fault_disk(tmp, code, name):
    rig = _fault_rig()
    prof, g = _move_args()
    try:
        with failing_csv_writes(4000, code):
            try:
                rig.run_move(prof, g, path=tmp / name)
            except Exception as exc:  # noqa: BLE001
                err = exc
            else:
                return "silent", "no error"
        meta = _sidecar(tmp / f"{name}.csv")
        msg = str(err)
        try:  # the device must not be left BUSY: PLAN is refused while busy
            rig._request(
                __import__("jerklab.protocol", fromlist=["Plan"]).Plan(1.0, 0),
                replies=(__import__("jerklab.protocol", fromlist=["MsgType"]).MsgType.PLAN_INFO,),
            )
            idle = True
        except Exception:  # noqa: BLE001
            idle = False
        ok = (
            f"{name}.csv" in msg
            and "samples" in msg
            and str(meta.get("status", "")).startswith("error")
            and idle
            and isinstance(err, OSError)
        )
        return ("clear" if ok else "obscure"), (
            f"{type(err).__name__}; sidecar {meta.get('status')!r}; "
            f"rig idle after: {idle}; {msg[:80]}"
        )
    finally:
        rig.close()


def fault_disk_full(tmp):
    return _fault_disk(tmp, errno.ENOSPC, "diskfull")


def fault_io_error(tmp):
    return _fault_disk(tmp, errno.EIO, "eio")


def fault_no_permission(tmp):
    folder = tmp / "readonly"
    folder.mkdir()
    os.chmod(folder, 0o500)
    rig = _fault_rig()
    prof, g = _move_args()
    try:
        if os.access(folder, os.W_OK):
            return "skipped", "running as root: permissions not enforced"
        rig.run_move(prof, g, path=folder / "rec")
    except PermissionError as exc:
        ok = "rec.csv" in str(exc) or "rec.json" in str(exc)
        return ("clear" if ok else "obscure"), str(exc)[:100]
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {exc}"
    finally:
        rig.close()
        os.chmod(folder, 0o700)
    return "silent", "no error"


def fault_interrupted(tmp):
    from jerklab.rig import Recording

    rig = _fault_rig()
    prof, g = _move_args()
    orig = Recording.append
    calls = [0]

    def append(self, *a, **k):
        calls[0] += 1
        if calls[0] == 100:
            raise KeyboardInterrupt
        return orig(self, *a, **k)

    Recording.append = append
    try:
        rig.run_move(prof, g, path=tmp / "ctrlc")
    except KeyboardInterrupt:
        meta = _sidecar(tmp / "ctrlc.csv")
        return (
            "clear" if meta["status"] == "interrupted" else "obscure"
        ), f"status {meta['status']}"
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {exc}"
    finally:
        Recording.append = orig
        rig.close()
    return "silent", "no interrupt"


KILL_SCRIPT = r"""
import sys
from jerklab.controller import pole_placement_pid
from jerklab.planner import plan_sine_jerk
from jerklab.rig import Device, connect
rig = connect(None, device=Device(speed=1.0), progress=False)
print("started", flush=True)
rig.run_move(plan_sine_jerk(4 * 3.141592653589793, 20.0, 30.0, 10.0), pole_placement_pid(32.4, 0.025, 20.0),
             path=sys.argv[1])
"""


def kill_client_mid_run(path, wait_rows=50, timeout=60.0):
    """Start a client in a subprocess recording a (real-time) move to ``path``, SIGKILL it once
    ``wait_rows`` rows are on disk; return the CSV path."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen(
        [sys.executable, "-c", KILL_SCRIPT, str(path)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    csv_path = Path(str(path) + ".csv")
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            if csv_path.exists() and csv_path.read_text().count("\n") > wait_rows:
                break
            if proc.poll() is not None:
                raise RuntimeError(f"client exited early: {proc.stderr.read().decode()[-500:]}")
            time.sleep(0.05)
        else:
            raise RuntimeError("client wrote no rows in time")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    return csv_path


def _load(path):
    import warnings

    from jerklab.rig import Recording

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        rec = Recording.load(path)
    return rec, [str(x.message) for x in w]


def fault_killed_client(tmp):
    csv_path = kill_client_mid_run(tmp / "killed")
    try:
        rec, warns = _load(csv_path)
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"load failed: {type(exc).__name__}: {exc}"
    st = rec.metadata.get("status")
    if st == "incomplete" and warns:
        return "clear", f"status {st!r}, {len(rec)} samples, warning: {warns[0][:60]}"
    return "silent", f"status {st!r}, {len(rec)} samples, warnings {warns}"


def _small_recording(tmp, name, n=20):
    from jerklab.rig import Recording

    rec = Recording(
        dict(kind="demo", Ts=0.005, counts_per_rad=71.3, volts_per_pwm=12 / 1023), tmp / name
    )
    for i in range(n):
        rec.append(i, 0.01 * i, i, 10 * i)
    rec.finish("complete")
    return rec.csv_path


def fault_torn_row(tmp):
    p = _small_recording(tmp, "torn")
    text = p.read_text()
    last = text.rstrip("\n").rsplit("\n", 1)[1]
    cut = len(text.rstrip("\n")) - len(last) + [i for i, c in enumerate(last) if c == ","][6] + 1
    p.write_text(text[:cut])
    try:
        rec, warns = _load(p)
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"load failed: {type(exc).__name__}: {str(exc)[:80]}"
    if len(rec) == 19 and warns:
        return "clear", f"19 rows kept, warning: {warns[0][:60]}"
    return "silent", f"{len(rec)} rows, warnings {warns}"


def fault_blank_line(tmp):
    p = _small_recording(tmp, "blank")
    lines = p.read_text().split("\n")
    lines.insert(10, "")
    p.write_text("\n".join(lines))
    try:
        rec, warns = _load(p)
    except ValueError as exc:
        return ("clear" if "line 11" in str(exc) else "obscure"), str(exc)[:90]
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {exc}"
    if any("line 11" in w for w in warns):
        return "clear", f"{len(rec)} rows, warning: {warns[0][:60]}"
    return "silent", f"{len(rec)} of 20 rows, no word"


def _bad_sidecar(tmp, name, change):
    p = _small_recording(tmp, name)
    j = p.with_suffix(".json")
    meta = json.loads(j.read_text())
    change(meta)
    j.write_text(json.dumps(meta))
    field = {"ts0": "Ts", "cpr0": "counts_per_rad", "nokey": "volts_per_pwm", "tsnan": "Ts"}[name]
    try:
        rec, _ = _load(p)
    except ValueError as exc:
        ok = field in str(exc) and j.name in str(exc)
        return ("clear" if ok else "obscure"), str(exc)[:90]
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {exc}"
    return "silent", f"loaded with {field} = {meta.get(field)!r}"


def fault_sidecar_ts0(tmp):
    return _bad_sidecar(tmp, "ts0", lambda m: m.update(Ts=0.0))


def fault_sidecar_ts_nan(tmp):
    return _bad_sidecar(tmp, "tsnan", lambda m: m.update(Ts="nan"))


def fault_sidecar_cpr0(tmp):
    return _bad_sidecar(tmp, "cpr0", lambda m: m.update(counts_per_rad=0))


def fault_sidecar_missing_key(tmp):
    return _bad_sidecar(tmp, "nokey", lambda m: m.pop("volts_per_pwm"))


def fault_garbage_decoder(tmp):
    from jerklab import protocol as PR

    rng = np.random.default_rng(1)
    d = PR.Decoder()
    good = PR.encode(PR.Stop(), 7)
    frames = d.feed(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes() + good)
    if any(f.seq == 7 and f.type == PR.MsgType.STOP for f in frames):
        return "clear", f"resynchronised; {d.stats.skipped_bytes} bytes skipped"
    return "silent", "frame after garbage lost"


def fault_garbage_cell(tmp):
    """Issue 31: one garbage cell mid-file loaded the other rows without a word."""
    from jerklab.rig import Recording

    p = _small_recording(tmp, "cell")
    lines = p.read_text().split("\n")
    cells = lines[10].split(",")
    cells[2] = "0.0x5"  # the reference of sample 9
    lines[10] = ",".join(cells)
    p.write_text("\n".join(lines))
    try:
        rec = Recording.load(p)
    except ValueError as exc:
        msg = str(exc)
        if "line 11" in msg and "'reference'" in msg:
            return "clear", msg[-80:]
        return "obscure", f"ValueError not naming line and column: {msg[:80]}"
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {str(exc)[:80]}"
    return "silent", f"{len(rec)} rows loaded"


def fault_handin_changed(tmp):
    """A hand-in whose notebook was changed after it was packed."""
    import zipfile

    from jerklab.lab.handin import HandinError, pack, read_handin

    p = pack({"lab1.ipynb": b"{}"}, "s1", 1, tmp / "h.zip")
    with zipfile.ZipFile(p) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["lab1.ipynb"] = b'{"cells": []}'
    with zipfile.ZipFile(p, "w") as z:
        for n, data in members.items():
            z.writestr(n, data)
    try:
        read_handin(p)
    except HandinError as exc:
        if "lab1.ipynb" in str(exc) and "checksum" in str(exc):
            return "clear", str(exc)[:80]
        return "obscure", str(exc)[:80]
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {str(exc)[:80]}"
    return "silent", "a changed hand-in was accepted"


def fault_broker_gone(tmp):
    """The class page's broker stops while a kernel still holds its address."""
    from jerklab.broker import BrokerError, BrokerRig, RigBroker

    b = RigBroker(None, speed=1.0)
    client = BrokerRig(b.address, timeout=2.0)
    b.close()
    try:
        client.run_move(_prof(), _gains(0.005), 0.005, path=False)
    except BrokerError as exc:
        if b.address in str(exc):
            return "clear", str(exc)[:80]
        return "obscure", str(exc)[:80]
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {str(exc)[:80]}"
    return "silent", "a run on a stopped broker returned"


def fault_synchronized_move(tmp):
    """Issue 31: run_move of a synchronized() profile reached the device and came back with the
    device's re-plan message; it must be refused before anything is sent, naming the profile."""
    rig = _fault_rig()
    try:
        rig.run_move(_prof().synchronized(0.005), _gains(), 0.005, path=False)
    except ValueError as exc:
        if "synchronized" in str(exc) and str(exc).startswith("profile"):
            return "clear", str(exc)[:80]
        return "obscure", str(exc)[:80]
    except Exception as exc:  # noqa: BLE001
        return "obscure", f"{type(exc).__name__}: {str(exc)[:80]}"
    finally:
        rig.close()
    return "silent", "a synchronized profile ran"


FAULTS = [
    ("corrupt frames (1 byte in 97 flipped)", fault_corrupt_frames),
    ("pulled cable mid-run", fault_pulled_cable),
    ("frozen board mid-run", fault_frozen_board),
    ("garbage bytes then a frame", fault_garbage_decoder),
    ("disk full (ENOSPC) mid-run", fault_disk_full),
    ("I/O error (EIO) mid-run", fault_io_error),
    ("recordings folder not writable", fault_no_permission),
    ("Ctrl-C mid-run", fault_interrupted),
    ("client SIGKILLed mid-run", fault_killed_client),
    ("file cut after the 7th comma of its last row", fault_torn_row),
    ("blank line in the middle of the CSV", fault_blank_line),
    ("sidecar Ts = 0", fault_sidecar_ts0),
    ("sidecar Ts = 'nan'", fault_sidecar_ts_nan),
    ("sidecar counts_per_rad = 0", fault_sidecar_cpr0),
    ("sidecar without volts_per_pwm", fault_sidecar_missing_key),
    ("one garbage cell mid-file", fault_garbage_cell),
    ("hand-in changed after packing", fault_handin_changed),
    ("broker stopped under a client", fault_broker_gone),
    ("run_move of a synchronized profile", fault_synchronized_move),
]


# ----------------------------------------------------------------------------- worker / parent


def _worker(start: int, faults: bool) -> None:
    import resource
    import warnings

    warnings.simplefilter("ignore")
    try:
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    except (ValueError, OSError):
        pass
    tmp = Path(tempfile.mkdtemp(prefix="jerklab-faults-"))
    os.environ["JERKLAB_RECORDINGS"] = str(tmp / "recordings")
    out = sys.stdout
    if faults:
        for i, (_, fn) in enumerate(FAULTS):
            if i < start:
                continue
            print(f"S {i}", file=out, flush=True)
            sub = tmp / f"fault{i}"
            sub.mkdir()
            try:
                outcome, detail = fn(sub)
            except BaseException as exc:  # noqa: BLE001
                outcome, detail = "obscure", f"probe failed: {type(exc).__name__}: {exc}"
            print("R " + json.dumps([i, outcome, detail]), file=out, flush=True)
        return
    targets = _targets()
    cases = _cases(targets)
    for i, (ti, pname, label, value) in enumerate(cases):
        if i < start:
            continue
        print(f"S {i}", file=out, flush=True)
        try:
            outcome, detail = classify(targets[ti], pname, label, value)
        except BaseException as exc:  # noqa: BLE001
            outcome, detail = "obscure", f"classifier: {type(exc).__name__}: {exc}"
        print("R " + json.dumps([i, outcome, str(detail)[:200]]), file=out, flush=True)


def _run_all(n_cases: int, faults: bool, is_base=lambda i: False) -> dict:
    """Run cases ``0..n_cases-1`` in worker processes; return {index: (outcome, detail)}."""
    results: dict = {}
    start = 0
    while start < n_cases:
        cmd = [sys.executable, "-m", "benchmarks.bench_faults", "--worker", str(start)]
        if faults:
            cmd.append("--faults")
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        fd = proc.stdout.fileno()
        current, t0, restart = None, time.monotonic(), None
        pending = b""
        eof = False
        while True:
            if b"\n" not in pending and not eof:
                limit = (
                    120.0
                    if faults
                    else (WARMUP_LIMIT if current is None or is_base(current) else TIME_LIMIT)
                )
                left = (t0 + limit) - time.monotonic() if current is not None else WARMUP_LIMIT
                r, _, _ = select.select([fd], [], [], max(0.0, left))
                if not r:
                    if current is None:
                        restart = n_cases  # the worker does not start at all
                        break
                    results[current] = ("hang", f"no answer within {limit:g} s")
                    restart = current + 1
                    break
                chunk = os.read(fd, 65536)
                if chunk:
                    pending += chunk
                    continue
                eof = True
            if b"\n" not in pending:
                if current is not None and current not in results:
                    results[current] = (
                        "obscure",
                        f"worker died (exit {proc.poll()}): crash or kill",
                    )
                    restart = current + 1
                else:
                    restart = n_cases
                break
            raw, pending = pending.split(b"\n", 1)
            line = raw.decode("utf-8", "replace")
            if line.startswith("S "):
                current, t0 = int(line.split()[1]), time.monotonic()
            elif line.startswith("R "):
                i, outcome, detail = json.loads(line[2:])
                results[i] = (outcome, detail)
                current = None
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        proc.wait()
        start = restart if restart is not None else n_cases
    return results


def main() -> None:
    verbose = os.environ.get("JERKLAB_FAULTS_VERBOSE") == "1"
    targets = _targets()
    cases = _cases(targets)
    base_idx = {i for i, c in enumerate(cases) if c[1] is None}
    t0 = time.monotonic()
    res = _run_all(len(cases), False, is_base=lambda i: i in base_idx)
    elapsed = time.monotonic() - t0
    kinds = ("clear", "ok", "obscure", "silent", "hang")
    by_mod = collections.OrderedDict()
    problems = []
    for i, (ti, pname, label, _) in enumerate(cases):
        outcome, detail = res.get(i, ("not run", ""))
        t = targets[ti]
        if pname is None:
            if outcome != "ok":
                problems.append(f"  BASE CASE {t.name}: {outcome} {detail}")
            continue
        row = by_mod.setdefault(t.module, collections.Counter())
        row[outcome] += 1
        if outcome not in ("clear", "ok"):
            problems.append(f"  {outcome:8s} {t.name}({pname}={label}): {detail}")
    print(
        f"bad inputs: {sum(sum(c.values()) for c in by_mod.values())} cases over {len(targets)} targets "
        f"(time limit {TIME_LIMIT:g} s per call, {elapsed:.0f} s in all)"
    )
    print(f"{'module':12s} " + " ".join(f"{k:>8s}" for k in kinds) + f" {'cases':>8s}")
    total = collections.Counter()
    for mod, c in by_mod.items():
        total.update(c)
        print(f"{mod:12s} " + " ".join(f"{c[k]:8d}" for k in kinds) + f" {sum(c.values()):8d}")
    print(
        f"{'total':12s} " + " ".join(f"{total[k]:8d}" for k in kinds) + f" {sum(total.values()):8d}"
    )
    other = set(total) - set(kinds)
    if other:
        print("other outcomes:", {k: total[k] for k in other})
    fres = _run_all(len(FAULTS), True)
    print(f"\ninjected faults: {len(FAULTS)}")
    print(f"{'fault':48s} {'outcome':8s} detail")
    fc = collections.Counter()
    for i, (name, _) in enumerate(FAULTS):
        outcome, detail = fres.get(i, ("not run", ""))
        fc[outcome] += 1
        print(f"{name:48s} {outcome:8s} {detail[:100]}")
    print("faults: " + ", ".join(f"{k} {fc[k]}" for k in sorted(fc)))
    if verbose or problems:
        shown = problems if verbose else problems[:60]
        print(f"\ncases not clear/ok ({len(problems)}){'' if verbose else ', first 60'}:")
        print("\n".join(shown))


if __name__ == "__main__":
    if len(sys.argv) >= 3 and sys.argv[1] == "--worker":
        _worker(int(sys.argv[2]), "--faults" in sys.argv)
    else:
        main()
