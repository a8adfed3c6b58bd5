"""The numbers notebook 06 (Yang et al.'s FPGA S-curve) shows, computed by jerklab.fpga against an
independent reference: the paper's printed integer formulas, the exact S-curve of
jerklab.planner, the Verilog of firmware/fpga run by Icarus, the paper's Table of the set-up.

The whole-move Verilog runs are tests/test_fpga.py's (at 200 kHz) and tests/test_multiaxis.py's
(both axes, 100 kHz); the notebook runs the same models at the clocks it draws.
"""

from __future__ import annotations

import math

import numpy as np

from jerklab import fpga
from jerklab.controller import discrete_pole_placement_pid
from jerklab.fpga import PAPER, YangSCurve, divider_edges, paper_speed, yang_axes
from jerklab.multiaxis import plan_multi_axis
from jerklab.planner import plan_scurve, plan_sine_jerk, plan_sine_jerk_optimal
from jerklab.plant import DCMotor
from jerklab.sim import simulate

Y = YangSCurve(**PAPER)


# ------------------------------------------------------------------ section 1
def test_general_form_is_the_printed_eq_7_8_on_every_tick():
    n = np.arange(Y.start_count, 5001)
    assert np.array_equal(Y.speed(n), paper_speed(n))


def test_integer_speed_within_1_um_s_of_the_exact_curve():
    """Notebook 06 §1: the speed register is within 1 µm/s of plan_scurve's curve from the start
    count on; the slowest pulse is 144 µm/s = 7 Hz at n = 300, a 143 ms period."""
    tab = Y.speed_table()
    on = tab.n >= Y.start_count
    exact = Y.exact_profile().sample(Y.tick_times()).velocity
    assert np.abs((tab.speed - exact)[on]).max() < 1.0
    assert Y.start_count == 300 and Y.speed(300) == 144
    assert Y.speed(300) // Y.step_um == 7 and round(1e3 / 7) == 143


# ------------------------------------------------------------------ section 2
def test_toy_divider_input_of_fig_6_verilog_and_model(tmp_path):
    """The toy input of the Fig. 6 timing (cycle 0 -> 10 -> 6 clocks): Verilog edges = model's."""
    from conftest import require_tool

    require_tool("iverilog", "vvp")
    starts, values, p_end = [1, 5, 40], [0, 10, 6], 70
    rise, fall = divider_edges(starts, values, p_end)
    run = fpga.simulate_divider_verilog(starts, values, p_end, workdir=str(tmp_path))
    assert np.array_equal(run.rise, rise) and np.array_equal(run.fall, fall)
    # rising edges every 10 clocks, one interval of 8 (the new cycle arrives at posedge 40, mid
    # period: the 5 clocks left of the 10-clock period, then half of the newly latched 6), then 6
    assert list(np.diff(rise)) == [10, 10, 10, 8, 6, 6, 6]


# ------------------------------------------------------------------ section 3
def test_pulse_train_lags_7_pulses_at_most_and_ends_4_short():
    """Notebook 06 §3 and its summary: the commanded position (20 µm per pulse) lags the exact
    S-curve by about 7 pulses at most and ends 4 pulses short of 40 mm."""
    pt = Y.pulses()
    tt = np.linspace(0, 3.2, 3201)
    err = pt.position(tt) - Y.exact_profile().sample(tt).position
    assert pt.position(10.0) == Y.distance_um - 4 * Y.step_um
    assert round(-err.min() / Y.step_um) == 7


# ------------------------------------------------------------------ section 4
def test_printed_divider_locks_up_after_two_pulses():
    """The printed divider emits two pulses, then locks up at t = 0.155 s for 2^32 clocks (86 s)."""
    hit = fpga.published_divider_lockup(Y)
    starts, values = Y.cycle_input()
    rise, _, _ = fpga.published_divider(starts, values, p_end=int(starts[-1]) + 10**6)
    assert len(rise) == 2
    assert round(hit["t"], 3) == 0.155
    assert round(hit["lockup_s"]) == 86 and hit["lockup_s"] == 2**32 / Y.clock_hz


# ------------------------------------------------------------------ section 5
def test_linear_jerk_is_the_fastest_then_the_optimal_sine_then_the_published():
    D, J, A, V = 20 * np.pi, 5000.0, 300.0, 100.0
    plans = [
        plan_scurve(D, J, A, V),
        plan_sine_jerk_optimal(D, J, A, V),
        plan_sine_jerk(D, J, A, V),
    ]
    d_sc, d_opt, d_pub = (p.duration for p in plans)
    assert d_sc < d_opt < 1.05 * d_sc and d_pub > 2 * d_sc
    # and all three track on Stojčić's motor within a few encoder-free mrad
    gains = discrete_pole_placement_pid(32.4, 0.025, wn=30.0, Ts=0.005)
    for p in plans:
        r = simulate(p, DCMotor(K=32.4, tau=0.025), gains)
        assert not r.diverged and r.metrics["max_abs_error"] < 0.05


# ------------------------------------------------------------------ section 6
XY = [40000.0, -15000.0]
LIM = (4 * 20000.0, 2 * 20000.0, 20000.0)


def test_phase_synced_x_axis_is_the_papers_generator():
    stands = {
        s: yang_axes(plan_multi_axis(XY, [LIM, LIM], sync=s), clock_hz=PAPER["clock_hz"])
        for s in ("phase", "time")
    }
    gx = stands["phase"].generators[0]
    assert gx.verilog_defines() == YangSCurve(**PAPER).verilog_defines()
    assert all(g.end_tick == stands[s].end_tick for s in stands for g in stands[s].generators)


def test_phase_sync_stays_on_the_line_time_sync_bends():
    """At the paper's 50 MHz: the pulse path of time sync leaves the straight line by more than
    five times as much as phase sync's."""
    tt = np.linspace(0, 3.2, 3201)
    u = np.array(XY) / math.hypot(*XY)
    off = {}
    for s in ("phase", "time"):
        stand = yang_axes(plan_multi_axis(XY, [LIM, LIM], sync=s), clock_hz=PAPER["clock_hz"])
        pos = stand.positions(tt, stand.pulses())
        off[s] = np.abs(u[0] * pos[1] - u[1] * pos[0]).max()
    assert off["time"] > 5 * off["phase"]
