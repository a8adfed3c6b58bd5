"""Fault injection for the control law, the controller and the simulation .

* a non-finite measurement is held by DigitalController, counted and reported, never fed to
  the law (before: one NaN poisoned it forever while it reported saturated=False);
* a diverged simulation says so (before: settling_time = 23.45 for a run that went to NaN);
* bad input to controller and sim public functions gets ValueError/TypeError naming the
  parameter (never AttributeError, IndexError, MemoryError, LinAlgError without a name, or a
  numba typing error).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from jerklab import controller as C
from jerklab import sim as S
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor, FlexibleDCMotor

K, TAU, TS = 32.4, 0.025, 0.005


def _ctrl(loop="position", **kw):
    if loop == "position":
        d = C.discrete_pole_placement_pid(K, TAU, 30.0, Ts=TS)
    else:
        d = C.discrete_pole_placement_pid(K, TAU, 20.0, Ts=TS, loop="velocity", extra_pole=0.0)
    return C.DigitalController(d, C.Feedforward(K, TAU), **kw)


# --------------------------------------------------------------------------- non-finite measurement


@pytest.mark.parametrize("loop", ["position", "velocity"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_measurement_is_held_and_reported(loop, bad):
    c, ref = _ctrl(loop), _ctrl(loop)
    ys = [0.0, 0.01, 0.03, 0.06]
    for y in ys[:3]:
        u_c = c.step(1.0, 2.0, 0.0, y)
        ref.step(1.0, 2.0, 0.0, y)
    with pytest.warns(RuntimeWarning, match="non-finite measurement"):
        held = c.step(1.0, 2.0, 0.0, bad)
    assert held == u_c  # the last output, held
    assert c.fault == "non-finite measurement" and c.nonfinite_count == 1
    assert c.last_parts["held"] and math.isfinite(c.last_parts["i"])
    # a second bad sample: counted, no second warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert c.step(1.0, 2.0, 0.0, bad) == u_c
    assert c.nonfinite_count == 2
    # the next finite sample resumes the law as if the bad samples had not been there
    u_after = c.step(1.0, 2.0, 0.0, ys[3])
    assert u_after == ref.step(1.0, 2.0, 0.0, ys[3])
    assert math.isfinite(u_after) and not c.last_parts["held"]
    c.reset()
    assert c.fault is None and c.nonfinite_count == 0


def test_nonfinite_measurement_before_any_output_holds_zero():
    c = _ctrl()
    with pytest.warns(RuntimeWarning):
        assert c.step(0.5, 0.0, 0.0, math.nan) == 0.0
    assert c.step(0.5, 0.0, 0.0, 0.0) != 0.0


@pytest.mark.parametrize(
    "name, args",
    [
        ("ref_position", (math.nan, 0.0, 0.0, 0.0)),
        ("ref_velocity", (0.0, math.inf, 0.0, 0.0)),
        ("ref_accel", (0.0, 0.0, -math.inf, 0.0)),
    ],
)
def test_nonfinite_reference_is_an_error(name, args):
    c = _ctrl()
    with pytest.raises(ValueError, match=name):
        c.step(*args)
    assert c.nonfinite_count == 0


@pytest.mark.parametrize(
    "name, args",
    [
        ("ref_position", ("a",)),
        ("ref_velocity", (0.0, None)),
        ("measured_position", (0.0, 0.0, 0.0, [1, 2])),
    ],
)
def test_non_numeric_step_arguments_name_the_parameter(name, args):
    with pytest.raises(TypeError, match=name):
        _ctrl().step(*args)


# --------------------------------------------------------------------------- divergence


def _unstable():
    g = C.pole_placement_pid(K, TAU, 60.0).discretize(TS)  # |z| > 1 at Ts = 5 ms
    return DCMotor(supply_voltage=None, pwm_bits=None, encoder_ppr=None), C.DigitalController(
        g, None, None
    )


def test_simulation_diverging_to_nan_says_diverged():
    motor, c = _unstable()
    with pytest.warns(RuntimeWarning, match="diverged"):
        r = S.simulate(S.StepProfile(1.0), motor, c, t_end=20.0)
    assert r.diverged and r.metrics["diverged"]
    assert math.isnan(r.metrics["settling_time"])  # never a number
    assert math.isinf(r.metrics["max_abs_error"])
    assert 0.0 < r.metrics["diverged_at"] < 1.0
    assert np.isnan(r.position[-1])  # the run stopped: NaN after it
    assert np.all(np.isfinite(r.position[:10]))


def test_simulation_diverging_beyond_the_bound_says_diverged():
    motor, c = _unstable()
    with pytest.warns(RuntimeWarning, match="diverged"):
        r = S.simulate(S.StepProfile(1.0), motor, c, t_end=1.0)
    assert np.all(np.isfinite(r.position))  # still finite, but far beyond any move
    assert r.diverged and math.isnan(r.metrics["settling_time"])
    assert r.metrics["max_abs_error"] > S.DIVERGENCE_FACTOR


def test_stable_simulation_does_not_say_diverged():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = S.simulate(plan_sine_jerk(2.0, 2e4, 300.0, 100.0), DCMotor(), _ctrl())
    assert (
        not r.diverged and not r.metrics["diverged"] and math.isfinite(r.metrics["settling_time"])
    )


def test_batch_diverged_plants_have_no_settling_time():
    motor, c = _unstable()
    b = S.simulate_batch(
        plan_sine_jerk(1.0, 2e4, 300.0, 100.0), motor, c, K=[32.4, 3.0], t_end=30.0
    )
    assert list(b.metrics["diverged"]) == [True, False]
    assert math.isnan(b.metrics["settling_time"][0]) and math.isfinite(
        b.metrics["settling_time"][1]
    )


# --------------------------------------------------------------------------- bad input

PROF = plan_sine_jerk(1.0, 2e4, 300.0, 100.0)
MOTOR = DCMotor()
D = C.discrete_pole_placement_pid(K, TAU, 30.0, Ts=TS)
CTRL = C.DigitalController(D, C.Feedforward(K, TAU))


class _Prof:
    def __init__(self, duration=0.2, kind="ok"):
        self.duration, self.kind = duration, kind

    def sample(self, t):
        t = np.asarray(t, dtype=float)
        pos = {"nan": np.full_like(t, np.nan), "shape": np.zeros(3)}.get(self.kind, 0 * t)
        if self.kind == "attr":
            return 5
        return type("S", (), dict(position=pos, velocity=0 * t, accel=0 * t))


BAD = [
    ("profile", lambda: S.simulate(None, MOTOR, CTRL)),
    ("motor", lambda: S.simulate(PROF, "motor", CTRL)),
    ("controller", lambda: S.simulate(PROF, MOTOR, None)),
    ("Gains", lambda: S.simulate(PROF, MOTOR, C.pole_placement_pid(K, TAU, 20.0))),
    ("Ts", lambda: S.simulate(PROF, MOTOR, CTRL, Ts="a")),
    ("Ts", lambda: S.simulate(PROF, MOTOR, CTRL, Ts=0.001)),
    ("t_end", lambda: S.simulate(PROF, MOTOR, CTRL, t_end=-1.0)),
    ("t_end", lambda: S.simulate(PROF, MOTOR, CTRL, t_end=math.inf)),
    ("MAX_SAMPLES", lambda: S.simulate(PROF, MOTOR, CTRL, t_end=1e12)),
    ("loop", lambda: S.simulate(PROF, MOTOR, CTRL, loop="speed")),
    ("x0", lambda: S.simulate(PROF, MOTOR, CTRL, x0=[1.0, 2.0, 3.0])),
    ("x0", lambda: S.simulate(PROF, MOTOR, CTRL, x0=[math.nan, 0.0])),
    ("x0", lambda: S.simulate(PROF, FlexibleDCMotor(), CTRL, x0=[0.0, 0.0])),
    ("settle_band", lambda: S.simulate(PROF, MOTOR, CTRL, settle_band=-1.0)),
    ("settle_band", lambda: S.simulate(PROF, MOTOR, CTRL, settle_band="x")),
    ("non-finite", lambda: S.simulate(_Prof(kind="nan"), MOTOR, CTRL)),
    ("shape", lambda: S.simulate(_Prof(kind="shape"), MOTOR, CTRL)),
    ("position", lambda: S.simulate(_Prof(kind="attr"), MOTOR, CTRL)),
    ("duration", lambda: S.simulate(_Prof(duration=math.nan), MOTOR, CTRL)),
    ("duration", lambda: S.simulate(_Prof(duration=None), MOTOR, CTRL)),
    ("duration", lambda: S.simulate(_Prof(duration=-1.0), MOTOR, CTRL)),
    ("K", lambda: S.simulate_batch(PROF, MOTOR, CTRL, K=[])),
    ("K", lambda: S.simulate_batch(PROF, MOTOR, CTRL, K=[-1.0])),
    ("K", lambda: S.simulate_batch(PROF, MOTOR, CTRL, K=[math.nan])),
    ("broadcast", lambda: S.simulate_batch(PROF, MOTOR, CTRL, K=[1.0, 2.0], tau=[0.1, 0.2, 0.3])),
    ("engine", lambda: S.simulate_batch(PROF, MOTOR, CTRL, engine="gpu")),
    ("offset", lambda: S.simulate_batch(PROF, DCMotor(offset=0.1), CTRL)),
    ("seed", lambda: S.simulate_batch(PROF, MOTOR, CTRL, seed="x")),
    (
        "keep_traces",
        lambda: S.simulate_batch(PROF, MOTOR, CTRL, K=np.full(100000, 30.0), t_end=1000.0),
    ),
    ("n", lambda: S.perturbed_plants(-1)),
    ("n", lambda: S.perturbed_plants("x")),
    ("n", lambda: S.perturbed_plants(2.5)),
    ("n", lambda: S.perturbed_plants(10**12)),
    ("friction", lambda: S.perturbed_plants(3, friction=(1.0,))),
    ("friction", lambda: S.perturbed_plants(3, friction=5.0)),
    ("friction", lambda: S.perturbed_plants(3, friction=(2.0, 1.0))),
    ("seed", lambda: S.perturbed_plants(3, seed="x")),
    ("position", lambda: S.SampledProfile(TS, [])),
    ("profile", lambda: S.SampledProfile.from_profile(None, TS)),
    ("gains", lambda: C.DigitalController("x")),
    ("feedforward", lambda: C.DigitalController(D, feedforward=3)),
    ("output_limit", lambda: C.DigitalController(D, output_limit=-1.0)),
    ("loop", lambda: C.DigitalController(D, loop="x")),
    ("error_scale", lambda: C.DigitalController(D, error_scale=0.0)),
    ("last_output", lambda: C.DigitalController(D).reset(last_output="x")),
    ("wn", lambda: C.discrete_pole_placement_pid(K, TAU, 1e300, Ts=TS)),
    ("wn", lambda: C.pole_placement_pid(K, TAU, 1e300)),
    ("encoder_ppr", lambda: C.paper_error_scale(TS, encoder_ppr="x")),
    ("encoder_ppr", lambda: C.paper_error_scale(TS, encoder_ppr=0)),
    ("decoding", lambda: C.paper_error_scale(TS, decoding=3)),
    ("profile", lambda: C.PositionLoop(K, TAU, D).tracking_error(None)),
    ("t_end", lambda: C.PositionLoop(K, TAU, D).step_response(1e12)),
]


@pytest.mark.parametrize("name, call", BAD, ids=[f"{i}-{n}" for i, (n, _) in enumerate(BAD)])
def test_bad_input_names_the_parameter(name, call):
    with pytest.raises((ValueError, TypeError), match=name) as exc:
        call()
    assert type(exc.value) in (ValueError, TypeError)  # not a subclass like LinAlgError
