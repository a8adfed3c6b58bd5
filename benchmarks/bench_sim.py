"""Closed-loop simulation speed against python-control, in the same process.

Peer: ``control.forced_response`` on the same *linear* sampled loop (ZOH plant, eq. 12
PID, feedforward as a second input) — it cannot do the nonlinearities at all. jerklab's
``simulate`` runs with every nonlinearity on (10-bit PWM, supply clamp, 448-pulse
encoder, Coulomb friction with sticking, step load disturbance, output clamp and
anti-windup). Also: the batch mode (controller steps per second over many perturbed
plants) and the tuning-widget redraw computation.

Run: ``python -m benchmarks sim``.
"""

from __future__ import annotations

import time

import control as ct
import numpy as np

from benchmarks._record import table
from jerklab.controller import (
    DigitalController,
    Feedforward,
    PositionLoop,
    discrete_pole_placement_pid,
    pole_placement_pid,
)
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.sim import HAVE_NUMBA, SampledProfile, perturbed_plants, simulate, simulate_batch

K, TAU, TS = 32.4, 0.025, 0.005


def _best(f, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t0)
    return best


def _linear_loop(d):
    Pz = ct.c2d(ct.ss(ct.tf([K], [TAU, 1, 0])), TS, "zoh")
    num, den = d._polys()
    Cz = ct.ss(ct.tf(num, den, TS))
    P = ct.ss(Pz.A, Pz.B, Pz.C, Pz.D, TS, inputs="u", outputs="y")
    C = ct.ss(Cz.A, Cz.B, Cz.C, Cz.D, TS, inputs="e", outputs="uc")
    return ct.interconnect(
        [
            P,
            C,
            ct.summing_junction(inputs=["uc", "uff"], output="u"),
            ct.summing_junction(inputs=["r", "-y"], output="e"),
        ],
        inputs=["r", "uff"],
        outputs=["y"],
    )


def main():
    d = discrete_pole_placement_pid(K, TAU, 30.0, Ts=TS)
    ctrl = DigitalController(d, Feedforward(K, TAU), output_limit=12.0)
    motor = DCMotor(coulomb_friction=0.3, load_disturbance=(1.0, -0.5))
    prof = plan_sine_jerk(10.0, 2e4, 300.0, 100.0)
    loop = _linear_loop(d)
    simulate(prof, motor, ctrl)  # compile (or load the cache)
    print(f"numba kernel: {HAVE_NUMBA}")
    rows = []
    for t_end in (2.0, 20.0, 200.0):
        r = simulate(prof, motor, ctrl, t_end=t_end)
        U = np.vstack([r.reference, (TAU * r.ref_accel + r.ref_velocity) / K])
        t_fr = _best(
            lambda: ct.forced_response(loop, T=r.time, U=U), repeat=2 if t_end > 20 else 10
        )
        t_sim = _best(
            lambda: simulate(prof, motor, ctrl, t_end=t_end), repeat=3 if t_end > 20 else 30
        )
        sp = SampledProfile.from_profile(prof, TS, t_end)
        t_pre = _best(
            lambda: simulate(sp, motor, ctrl, t_end=t_end), repeat=3 if t_end > 20 else 30
        )
        # a new move on every call: the profile is sampled each time (no reuse of its samples)
        fresh = iter([plan_sine_jerk(10.0 + 1e-3 * i, 2e4, 300.0, 100.0) for i in range(40)])
        t_new = _best(
            lambda: simulate(next(fresh), motor, ctrl, t_end=t_end), repeat=3 if t_end > 20 else 30
        )
        rows.append(
            (
                len(r.time),
                t_fr * 1e3,
                t_sim * 1e3,
                t_fr / t_sim,
                t_pre * 1e3,
                t_fr / t_pre,
                t_new * 1e3,
                t_fr / t_new,
            )
        )
    table(
        "single run: simulate (all nonlinearities on) vs control.forced_response (linear loop)",
        [
            "samples",
            "forced_response ms",
            "simulate ms",
            "x forced_response",
            "simulate pre-sampled ms",
            "x forced_response (pre-sampled)",
            "simulate new move ms",
            "x forced_response (new move)",
        ],
        rows,
        note="simulate: the same move again (its samples are reused); new move: a different planner "
        "profile on every call, sampled in closed form each time",
    )

    pp = perturbed_plants(4000, friction=(0.0, 0.5), seed=1)
    simulate_batch(prof, motor, ctrl, keep_traces=False, **perturbed_plants(8, seed=0))
    rows = []
    for engine, m in (("compiled", 4000), ("compiled", 20000), ("numpy", 4000)):
        p = pp if m == 4000 else perturbed_plants(m, friction=(0.0, 0.5), seed=2)
        b = simulate_batch(prof, motor, ctrl, engine=engine, keep_traces=False, **p)
        t = _best(
            lambda: simulate_batch(prof, motor, ctrl, engine=engine, keep_traces=False, **p),
            repeat=2,
        )
        rows.append((f"{engine} {m}", m, len(b.time), t, m * len(b.time) / t))
    table(
        "batch over perturbed plants (K, tau +-20 %, friction 0-0.5 V), all nonlinearities on",
        ["engine plants", "plants", "samples", "s", "controller steps/s"],
        rows,
    )

    def redraw(wn=30.0):
        out = []
        for gains in (
            pole_placement_pid(K, TAU, wn).discretize(TS),
            discrete_pole_placement_pid(K, TAU, wn, Ts=TS),
        ):
            L = PositionLoop(K, TAU, gains)
            out.append(
                (
                    L.poles_z(),
                    L.max_pole_radius(),
                    L.step_response(0.5),
                    L.disturbance_response(0.5),
                    L.tracking_error(prof),
                )
            )
        return out

    redraw()
    table(
        "tuning-widget redraw computation (eq.-13 and z-domain loops: poles, step, disturbance, "
        "sine-jerk error)",
        ["case", "ms", "target ms"],
        [("one redraw", _best(redraw, repeat=10) * 1e3, 20.0)],
    )


if __name__ == "__main__":
    main()
