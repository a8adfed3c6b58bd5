"""One move_metrics (jerklab.metrics) for the simulation, the rig and the labs.

Independent references: a plain loop over the samples written from the definitions in the
module docstring (hypothesis draws the runs), a move whose numbers are known by construction,
and the compiled batch kernel, which accumulates the same definitions on the fly without traces.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jerklab import lab, sim
from jerklab.controller import discrete_pole_placement_pid
from jerklab.metrics import KEYS, OLD_KEYS, MoveMetrics, move_metrics, series_metrics
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.rig import connect


def _by_loop(t, r, y, u, T, D, band, sat=None):
    """The definitions, sample by sample."""
    n = len(t)
    Ts = t[1] - t[0] if n > 1 else 0.0
    during = [k for k in range(n) if t[k] <= T + 1e-9]
    after = [k for k in range(n) if t[k] > T + 1e-9]
    e = [r[k] - y[k] for k in range(n)]
    out = {
        "max_error": max(abs(e[k]) for k in during),
        "peak_error": max(abs(x) for x in e),
        "rms_error": math.sqrt(sum(e[k] ** 2 for k in during) / len(during)),
        "final_error": e[-1],
        "overshoot_pct": (
            max(0.0, max((y[k] - D) * math.copysign(1.0, D) for k in after)) / abs(D) * 100.0
            if after
            else 0.0
        ),
        "settle_band": band,
        "peak_voltage": max(abs(v) for v in u),
    }
    last = max((k for k in range(n) if abs(D - y[k]) > band), default=-1)
    if last < 0:
        out["settling_time"] = 0.0
    elif last == n - 1:
        out["settling_time"] = math.inf
    else:
        out["settling_time"] = max(0.0, t[last] + Ts - T)
    if sat is not None:
        out["saturated"] = int(sum(sat))
        out["saturated_fraction"] = sum(sat) / n
    return out


@given(
    n=st.integers(2, 60),
    T_frac=st.floats(0.0, 1.0),
    D=st.floats(-5.0, 5.0).filter(lambda d: abs(d) > 1e-3),
    band=st.floats(1e-3, 0.5),
    seed=st.integers(0, 2**32 - 1),
)
def test_the_metrics_follow_their_definitions(n, T_frac, D, band, seed):
    rng = np.random.default_rng(seed)
    Ts = 0.005
    t = np.arange(n) * Ts
    T = T_frac * t[-1]
    r = np.where(t <= T, D * t / max(T, Ts), D)
    y = r + rng.normal(0.0, 2 * band, n) * rng.integers(0, 2, n)
    u = rng.uniform(-12, 12, n)
    sat = rng.integers(0, 2, n).astype(bool)
    got = series_metrics(t, r, y, u, T, D, settle_band=band, saturated=sat)
    want = _by_loop(t, r, y, u, T, D, band, sat)
    assert set(got) == set(want) == set(KEYS)
    for k, v in want.items():
        assert got[k] == pytest.approx(v, rel=1e-12, abs=1e-12), k


def test_a_move_with_known_numbers():
    """Reference 0 -> 2 rad in 0.1 s; the position lags 0.05 rad during the move, overshoots to
    2.06 rad at 0.15 s and is back within 0.02 rad from 0.2 s on."""
    t = np.arange(0, 0.405, 0.01)
    r = np.minimum(20.0 * t, 2.0)
    y = r - np.where(t <= 0.1, 0.05 * (t > 0), 0.0)
    y = np.where(np.isclose(t, 0.15), 2.06, y)
    y = np.where(np.isclose(t, 0.16), 2.03, y)
    u = np.where(t <= 0.1, 6.0, -1.0)
    m = series_metrics(t, r, y, u, 0.1, 2.0, settle_band=0.02)
    assert m["max_error"] == pytest.approx(0.05)
    assert m["peak_error"] == pytest.approx(0.06)
    assert m["overshoot_pct"] == pytest.approx(3.0)
    assert m["settling_time"] == pytest.approx(0.16 + 0.01 - 0.1)
    assert m["peak_voltage"] == 6.0 and m["final_error"] == 0.0
    assert "saturated" not in m


def test_a_diverged_run_has_no_settling_time_and_infinite_errors():
    t = np.arange(5) * 0.01
    y = np.array([0.0, 0.5, np.nan, np.nan, np.nan])
    m = series_metrics(t, np.ones(5), y, np.zeros(5), 0.02, 1.0, settle_band=0.1)
    assert (
        math.isinf(m["peak_error"])
        and math.isinf(m["max_error"])
        and math.isnan(m["settling_time"])
    )


def test_old_keys_read_the_new_ones_and_stay_out_of_the_dict():
    m = MoveMetrics(peak_error=0.1, peak_voltage=5.0, settle_band=0.01, max_error=0.05)
    for old, new in OLD_KEYS.items():
        assert old in m and m[old] == m[new] == m.get(old)
    assert "max_abs_error" not in dict(m) and "max_abs_error" not in json.loads(json.dumps(m))
    with pytest.raises(KeyError):
        m["no_such_key"]
    assert m.get("no_such_key", 7) == 7


def test_simulation_rig_and_lab_measure_with_the_one_function():
    """The simulation's metrics are move_metrics of its own series; a rig recording measured
    with it agrees with the lab's spec_metrics (the same function, the lab's band)."""
    prof = plan_sine_jerk(**lab.MOVE)
    g = discrete_pole_placement_pid(30.0, 0.03, 30.0, Ts=0.005)
    r = sim.simulate(prof, DCMotor(30.0, 0.03), g, t_end=prof.duration + 0.4)
    again = move_metrics(r, prof.duration, prof.distance, settle_band=r.metrics["settle_band"])
    for k in KEYS:
        assert again[k] == r.metrics[k], k
    assert r.metrics["max_abs_error"] == r.metrics["peak_error"]  # the old name still reads
    with connect(device=DCMotor(30.0, 0.03), model=(30.0, 0.03), progress=False) as rig:
        rec = rig.run_move(prof, g, settle=0.4, path=False)
    assert lab.spec_metrics(rec, prof) == move_metrics(
        rec, prof.duration, prof.distance, settle_band=lab.SPEC["settle_band"]
    )
    assert lab.move_metrics is move_metrics


def test_the_batch_kernel_accumulates_the_same_definitions():
    prof = plan_sine_jerk(3.0, 2e4, 300.0, 60.0)
    g = discrete_pole_placement_pid(32.4, 0.025, 30.0, Ts=0.005)
    Ks = np.array([20.0, 32.4, 45.0])
    b = sim.simulate_batch(prof, DCMotor(), g, K=Ks, engine="compiled", keep_traces=True)
    traces = series_metrics(
        b.time,
        b.reference,
        b.position,
        b.voltage,
        prof.duration,
        prof.distance,
        settle_band=b.metrics["settle_band"],
    )
    for k in (
        "max_error",
        "peak_error",
        "rms_error",
        "final_error",
        "overshoot_pct",
        "settling_time",
        "peak_voltage",
    ):
        np.testing.assert_allclose(b.metrics[k], traces[k], rtol=1e-12, atol=1e-12, err_msg=k)
    assert b.metrics["overshoot_pct"].shape == (3,)
