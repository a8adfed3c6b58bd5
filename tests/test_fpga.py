"""Yang et al. S-curve: integer model vs eqs. 7-8, vs the exact S-curve, vs Verilog (Icarus)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jerklab.fpga import (
    PAPER,
    HardwareLimitError,
    YangSCurve,
    divider_edges,
    paper_speed,
    published_divider,
    published_divider_lockup,
    simulate_divider_verilog,
    simulate_verilog,
)


# ---------------------------------------------------------------- eqs. 7, 8
@pytest.mark.parametrize(
    "n, v",
    [
        (300, 144),
        (1000, 1600),
        (2499, 9992),
        (2500, 10000),
        (2501, 10008),
        (3750, 17500),
        (4999, 20000),
        (4990, 20000),
        (4900, 19984),
        (5000, 20000),
    ],
)
def test_paper_eq7_eq8_values(n, v):
    # eq. 7: 16 n^2 / 10000; eq. 8: 20000 - (10000 - 2n)^2 / 2500 (integer division)
    assert paper_speed(n) == v
    assert YangSCurve(**PAPER).speed(n) == v


def test_general_integer_form_is_bit_identical_to_eq7_eq8():
    Y = YangSCurve(**PAPER)
    n = np.arange(300, 5001)
    assert (Y.coef_num, Y.coef_den) == (1, 625)
    assert np.array_equal(Y.speed(n), paper_speed(n))
    assert np.all(Y.speed(np.arange(300)) == 0)  # below PWM_INITAL_COUNT


@given(V=st.integers(1000, 25000), half=st.integers(20, 400), tc_us=st.sampled_from([50, 100, 200]))
def test_integer_speed_within_one_of_exact_scurve(V, half, tc_us):
    """floor-divided eqs. 5, 6 stay within 1 µm/s of v = J t^2/2, v = V - J (T-t)^2/2."""
    tc = tc_us * 1e-6
    T = 2 * half * tc
    start = math.ceil(half * math.sqrt(2.0 / V)) + 1  # first count with v >= 1 µm/s
    Y = YangSCurve(V, T, T, tc, clock_hz=50_000_000, step_um=1, start_count=start)
    assert Y.coef_num * half**2 < 2**32  # V N^2 < 2^32 here: no overflow
    n = np.arange(start, 2 * half + 1)
    t = n * tc
    J = 4 * V / T**2
    exact = np.where(t <= T / 2, J * t**2 / 2, V - J * (T - t) ** 2 / 2)
    v = Y.speed(n)
    assert np.all(np.abs(v - exact) < 1 + 1e-6)
    assert np.all(np.diff(v) >= 0) and v[-1] == V  # monotone speed-up to V
    assert np.all(Y.speed(np.arange(start)) == 0)


def test_speed_table_matches_planner_scurve():
    Y = YangSCurve(**PAPER)
    p = Y.exact_profile()
    assert p.duration == pytest.approx(3.0)
    assert p.phase_times[1] == pytest.approx(0.0, abs=1e-12)  # no constant-accel segment
    tab = Y.speed_table()
    ve = p.sample(Y.tick_times()).velocity
    on = tab.n >= Y.start_count
    assert np.max(np.abs(tab.speed[on] - ve[on])) < 1.0
    assert np.all(tab.speed[~on] == 0)
    # frequency floor: v = k f loses up to k - 1 µm/s
    assert np.all((tab.frequency * 20 <= tab.speed) & (tab.speed - tab.frequency * 20 < 20))
    assert tab.cycle.max() == 50_000_000 // 7 and tab.cycle[tab.cycle > 0].min() == 50_000


def test_commanded_position_of_paper_move():
    Y = YangSCurve(**PAPER)
    pt = Y.pulses()
    p = Y.exact_profile()
    t = np.linspace(0, 3.3, 3301)
    err = pt.position(t) - p.sample(t).position
    # the pulse train lags (floors, start count, latched periods) but never leads
    assert err.max() <= 0 and err.min() > -200.0
    assert 39800 <= pt.position(10.0) <= 40000
    assert np.all(np.diff(pt.rise) > 0) and np.all(pt.fall > pt.rise[: len(pt.fall)])


# ---------------------------------------------------------------- divider semantics
def brute_divider(starts, values, p_end):
    """Clock-by-clock simulation of pulse_divider.v, independent of divider_edges."""
    creg = count = out = 0
    rise, fall = [], []
    vi = 0
    for p in range(1, p_end + 1):
        while vi + 1 < len(starts) and starts[vi + 1] <= p:
            vi += 1
        w = values[vi]
        duty = creg >> 1
        if creg == 0:
            new_out, count, creg = 0, 0, w
        elif count == duty:
            new_out, count = 1, count + 1
        elif count >= creg:
            new_out, count, creg = 0, 1, w
        else:
            new_out, count = out, count + 1
        if new_out != out:
            (rise if new_out else fall).append(p)
        out = new_out
    return np.array(rise), np.array(fall)


stimulus = st.lists(
    st.tuples(st.integers(1, 40), st.sampled_from([0, 2, 3, 4, 5, 7, 10, 16, 31])),
    min_size=1,
    max_size=25,
)


@given(stimulus)
def test_divider_model_matches_clock_by_clock_semantics(stim):
    starts = np.cumsum([1] + [d for d, _ in stim[1:]])
    values = [v for _, v in stim]
    p_end = int(starts[-1]) + 60
    r1, f1 = divider_edges(starts, values, p_end)
    r2, f2 = brute_divider(starts, values, p_end)
    assert np.array_equal(r1, r2) and np.array_equal(f1, f2)


def brute_published(starts, values, p_end, bits):
    """Clock-by-clock simulation of the paper's listing with a ``bits``-wide counter."""
    mask = (1 << bits) - 1
    count = out = 0
    rise, fall = [], []
    vi = 0
    for p in range(1, p_end + 1):
        while vi + 1 < len(starts) and starts[vi + 1] <= p:
            vi += 1
        c = values[vi]
        if c != 0:
            if count == c // 2:
                new_out, count = 1, (count + 1) & mask
            elif count == c:
                new_out, count = 0, 1
            else:
                new_out, count = out, (count + 1) & mask
        else:
            new_out, count = 0, 0
        if new_out != out:
            (rise if new_out else fall).append(p)
        out = new_out
    return np.array(rise), np.array(fall)


@given(stimulus)
def test_published_divider_model_matches_clock_by_clock_semantics(stim):
    """Including the lock-up and the wrap-around of the counter (6 bits here, so it shows)."""
    starts = np.cumsum([1] + [d for d, _ in stim[1:]])
    values = [v for _, v in stim]
    p_end = int(starts[-1]) + 200
    r1, f1, _ = published_divider(starts, values, p_end, bits=6)
    r2, f2 = brute_published(starts, values, p_end, bits=6)
    assert np.array_equal(r1, r2) and np.array_equal(f1, f2)


def test_published_divider_locks_up_in_paper_move():
    hit = published_divider_lockup(YangSCurve(**PAPER))
    assert hit is not None
    assert hit["count"] > hit["compare_reg"]
    assert 0.06 < hit["t"] < 1.0  # during the first acceleration stage
    assert hit["lockup_s"] == pytest.approx(2**32 / 50e6)


# ---------------------------------------------------------------- hardware limits
def test_limits_raise_clear_errors():
    with pytest.raises(HardwareLimitError, match="minimum frequency"):
        YangSCurve(**{**PAPER, "start_count": 100})  # 16 µm/s < 20 µm/s = 1 Hz
    with pytest.raises(HardwareLimitError, match="32 bits"):
        YangSCurve(
            max_velocity=3_000_001, accel_time=1.0, refresh_period=1e-5, step_um=1, start_count=1000
        )
    with pytest.raises(HardwareLimitError, match="32 bits"):
        YangSCurve(**{**PAPER, "clock_hz": 5_000_000_000})
    with pytest.raises(HardwareLimitError, match="f_clk / 2"):
        YangSCurve(**{**PAPER, "clock_hz": 1_000, "refresh_period": 1e-3})
    with pytest.raises(HardwareLimitError, match="register"):
        divider_edges([1], [2**32], 10)
    with pytest.raises(ValueError, match="whole number"):
        YangSCurve(**{**PAPER, "refresh_period": 300e-6})
    with pytest.raises(ValueError, match="max_velocity"):
        YangSCurve(**{**PAPER, "max_velocity": 20000.5})
    with pytest.raises(ValueError, match="accel_time"):
        YangSCurve(**{**PAPER, "accel_time": math.nan})
    with pytest.raises(ValueError, match="n must be"):
        YangSCurve(**PAPER).speed(5001)
    with pytest.raises(ValueError, match="n must be"):
        paper_speed(1.5)


# ---------------------------------------------------------------- Verilog, bit for bit
def test_verilog_divider_matches_model(tmp_path):
    from conftest import require_tool

    require_tool("iverilog", "vvp")
    rng = np.random.default_rng(7)
    starts = np.r_[1, 1 + np.cumsum(rng.integers(1, 60, 80))]
    values = rng.choice([0, 2, 3, 5, 8, 13, 40, 101], size=starts.size)
    p_end = int(starts[-1]) + 300
    run = simulate_divider_verilog(starts, values, p_end, workdir=str(tmp_path))
    rise, fall = divider_edges(starts, values, p_end)
    assert len(rise) > 50
    assert np.array_equal(run.rise, rise) and np.array_equal(run.fall, fall)


@pytest.mark.slow
def test_verilog_whole_paper_move_bit_for_bit(tmp_path):
    """The paper's speed generator (V = 20 mm/s, T = 1 s, tc = 200 µs, start 300) over the
    whole accel-cruise-decel move; the divider clock scaled from 50 MHz to 200 kHz so that
    Icarus runs the 3 s move (6e5 clocks) in seconds.  Every tick's n, v, f, cycle and
    every pulse edge must equal the Python model."""
    from conftest import require_tool

    require_tool("iverilog", "vvp")
    Y = YangSCurve(**{**PAPER, "clock_hz": 200_000})
    run = simulate_verilog(Y, workdir=str(tmp_path))
    tab = Y.speed_table()
    for f in ("m", "n", "speed", "frequency", "cycle"):
        assert np.array_equal(getattr(run.table, f), getattr(tab, f)), f
    pt = Y.pulses()
    assert len(pt.rise) > 1900
    assert np.array_equal(run.rise, pt.rise) and np.array_equal(run.fall, pt.fall)


def test_verilog_published_divider_locks_up_like_the_model(tmp_path):
    """The paper's divider as printed, driven by the paper's speed generator (200 kHz clock):
    Verilog and model give the same two pulses, then silence from the lock-up on."""
    from conftest import require_tool

    require_tool("iverilog", "vvp")
    Y = YangSCurve(**{**PAPER, "clock_hz": 200_000})
    p_end = 120_000
    run = simulate_verilog(Y, p_end=p_end, workdir=str(tmp_path), published=True)
    starts, values = Y.cycle_input()
    rise, fall, hit = published_divider(starts, values, p_end)
    assert np.array_equal(run.rise, rise) and np.array_equal(run.fall, fall)
    assert hit is not None and run.rise.max() < hit["p"] < p_end
    assert len(Y.pulses(p_end=p_end).rise) > 100  # the latched divider keeps going


def test_verilog_general_parameters_bit_for_bit(tmp_path):
    from conftest import require_tool

    require_tool("iverilog", "vvp")
    Y = YangSCurve(
        max_velocity=15000,
        accel_time=0.06,
        cruise_time=0.02,
        refresh_period=100e-6,
        clock_hz=1_000_000,
        step_um=7,
        start_count=40,
    )
    assert (Y.coef_num, Y.coef_den) != (1, 625)
    run = simulate_verilog(Y, workdir=str(tmp_path))
    tab = Y.speed_table()
    for f in ("m", "n", "speed", "frequency", "cycle"):
        assert np.array_equal(getattr(run.table, f), getattr(tab, f)), f
    pt = Y.pulses()
    assert len(pt.rise) > 100
    assert np.array_equal(run.rise, pt.rise) and np.array_equal(run.fall, pt.fall)
