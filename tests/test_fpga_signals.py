"""jerklab.fpga's signal helpers that notebook 06 draws with: the speed of a pulse train and the
conversion of an Icarus VCD dump to clock edges (against the divider model's edges)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_tool

from jerklab import fpga


# ------------------------------------------------------------------------------ pulse speed
def test_pulse_speed_of_a_constant_divider():
    """A constant cycle c gives rising edges c clocks apart: v = k f_clk / c everywhere."""
    rise, _ = fpga.divider_edges([1], [250], p_end=10_000)
    t, v = fpga.pulse_speed(rise, 50_000_000, 20)
    assert len(v) == len(rise) - 1 > 30
    assert np.all(v == 20 * 50_000_000 / 250)
    assert np.allclose(t, rise[1:] / 50e6)


def test_pulse_speed_follows_the_scurve():
    """On Yang's move (scaled clock) the pulse speed tracks the exact S-curve velocity."""
    Y = fpga.YangSCurve(**{**fpga.PAPER, "clock_hz": 1_000_000})
    pt = Y.pulses()
    t, v = pt.speed()
    t2, v2 = fpga.pulse_speed(pt.rise, pt.clock_hz, pt.step_um)
    assert np.array_equal(t, t2) and np.array_equal(v, v2)
    cruise = (t > 1.1) & (t < 1.9)
    assert np.all(np.abs(v[cruise] - 20000) <= 20000 * 2e-3)  # cycle = 1e6 // 1000 exactly
    exact = Y.exact_profile().sample(t).velocity
    fast = exact > 5000
    assert np.max(np.abs(v[fast] - exact[fast])) < 0.06 * 20000


@pytest.mark.parametrize("rise", [[5, 5, 9], [9, 3]])
def test_pulse_speed_needs_increasing_edges(rise):
    with pytest.raises(ValueError, match="rise"):
        fpga.pulse_speed(rise, 1e6)


def test_pulse_speed_bad_clock():
    with pytest.raises(ValueError, match="clock_hz"):
        fpga.pulse_speed([1, 3], 0.0)


# ------------------------------------------------------------------------------ VCD clock
def test_vcd_to_posedge_formula():
    # 50 MHz testbench clock toggling every 10 ns from 0: posedge p at (p - 1/2) 20 ns
    ps = np.array([10_000, 30_000, 50_000, 20_000])
    assert np.array_equal(fpga.vcd_to_posedge(ps, 20e-9, 1e-12), [1.0, 2.0, 3.0, 1.5])
    with pytest.raises(ValueError, match="clock_period"):
        fpga.vcd_to_posedge(ps, -1.0)


def test_vcd_timescale(tmp_path):
    f = tmp_path / "a.vcd"
    f.write_text("$date x $end\n$timescale 1ps $end\n$enddefinitions $end\n#0\n")
    assert fpga.vcd_timescale(f) == 1e-12
    f.write_text("$timescale\n  10 ns\n$end\n$enddefinitions $end\n")
    assert fpga.vcd_timescale(f) == pytest.approx(1e-8)
    f.write_text("$enddefinitions $end\n")
    with pytest.raises(ValueError, match="timescale"):
        fpga.vcd_timescale(f)


def test_vcd_edges_equal_the_model(tmp_path):
    """Icarus' VCD of the divider, converted to posedges, shows clkout changing exactly at the
    model's edges (the overlay of notebook 06, Yang Fig. 6)."""
    require_tool("iverilog", "vvp")
    starts, values, p_end = [1, 5, 40], [0, 10, 6], 70
    vcd = tmp_path / "divider.vcd"
    fpga.simulate_divider_verilog(starts, values, p_end, vcd=str(vcd))
    w = fpga.read_vcd(vcd, ["clk", "clkout"])
    scale = fpga.vcd_timescale(vcd)
    t, val = w["clkout"]
    p = fpga.vcd_to_posedge(t, 20e-9, scale)
    rise, fall = fpga.divider_edges(starts, values, p_end)
    assert np.array_equal(p[val == 1], rise)
    assert np.array_equal(p[(val == 0) & (p >= 1)], fall)  # (the reset pulse is before posedge 1)
    tc, vc = w["clk"]
    assert np.all(
        fpga.vcd_to_posedge(tc[vc == 1], 20e-9, scale) == np.arange(1, (vc == 1).sum() + 1)
    )
