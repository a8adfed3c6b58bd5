"""The result figures of jerklab.plots that the paper notebooks draw: each draws the data its
result holds (read back from the axes and compared with the result's own arrays), labels every
axis with its unit, and refuses what it cannot draw, naming it."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pytest

from jerklab import plots
from jerklab.controller import discrete_pole_placement_pid
from jerklab.planner import plan_scurve, plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.sim import simulate


@pytest.fixture(autouse=True)
def _close():
    yield
    plt.close("all")


def _lines(ax):
    return [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 2]


def _units(ax):
    return "(" in ax.get_ylabel() and ")" in ax.get_ylabel()


def test_plot_profile_draws_the_closed_form_and_the_boundaries():
    p = plan_sine_jerk(10.0, 1000.0, 100.0, 10.0)
    t = np.linspace(0, p.duration, 500)
    axes = plots.plot_profile(p, t, boundaries=True, label="move")
    assert [a.get_ylabel() for a in axes] == [
        "jerk (rad/s³)",
        "acceleration (rad/s²)",
        "velocity (rad/s)",
        "position (rad)",
    ]
    s = p.sample(t)
    for ax, q in zip(axes, ("jerk", "accel", "velocity", "position")):
        (line,) = _lines(ax)
        assert np.array_equal(line.get_xdata(), t)
        assert np.allclose(line.get_ydata(), getattr(s, q))
        marks = sorted(ln.get_xdata()[0] for ln in ax.get_lines() if len(ln.get_xdata()) == 2)
        assert np.allclose(marks, np.cumsum(p.phase_times))  # T, T + t_v, t_u
    assert axes[-1].get_xlabel() == "time (s)"
    # a sample (e.g. the eq. 15 recursion) is drawn as it is, in another unit with a scale
    rec = p.discretize(0.005)
    (ax,) = plots.plot_profile(rec, quantities=("velocity",), unit="mrad", scale=1e3)
    (line,) = _lines(ax)
    assert (
        np.allclose(line.get_ydata(), 1e3 * rec.velocity) and ax.get_ylabel() == "velocity (mrad/s)"
    )
    with pytest.raises(ValueError, match="quantities"):
        plots.plot_profile(p, quantities=("snap",))
    with pytest.raises(TypeError, match="profile"):
        plots.plot_profile([1, 2, 3])
    with pytest.raises(ValueError, match="axes"):
        plots.plot_profile(p, axes=[ax])


@pytest.fixture(scope="module")
def runs():
    motor = DCMotor(32.4, 0.025, coulomb_friction=0.2)
    gains = discrete_pole_placement_pid(32.4, 0.025, wn=30.0, Ts=0.005)
    return {
        "scurve": simulate(plan_scurve(2.0, 2000.0, 150.0, 40.0), motor, gains, t_end=0.8),
        "sine": simulate(plan_sine_jerk(2.0, 2000.0, 150.0, 40.0), motor, gains, t_end=0.8),
    }


def test_plot_runs_overlays_every_run_in_si_and_mrad(runs):
    axes = plots.plot_runs(runs, signals=("ref_velocity", "error", "u_applied"))
    assert all(_units(a) for a in axes) and axes[1].get_ylabel() == "tracking error (mrad)"
    for ax, attr, factor in zip(axes, ("ref_velocity", "error", "u_applied"), (1, 1e3, 1)):
        lines = _lines(ax)
        assert len(lines) == 2
        for line, r in zip(lines, runs.values()):
            assert np.allclose(line.get_xdata(), r.t)
            assert np.allclose(line.get_ydata(), factor * getattr(r, attr))
    assert [t.get_text() for t in axes[0].get_legend().get_texts()] == list(runs)
    with pytest.raises(ValueError, match="signals"):
        plots.plot_runs(runs, signals=("torque",))
    with pytest.raises(ValueError, match="labels"):
        plots.plot_runs(list(runs.values()), labels=["one"])
    with pytest.raises(ValueError, match="load_position"):
        plots.plot_runs(runs, signals=("load_position",))  # a rigid motor has no load


def test_plot_control_parts_draws_the_four_parts(runs):
    r = runs["sine"]
    ax = plots.plot_control_parts(r)
    lines = _lines(ax)
    assert [ln.get_label() for ln in lines] == ["ff", "p", "i", "d"]
    for line, name in zip(lines, ("ff", "p", "i", "d")):
        assert np.allclose(line.get_ydata(), r.parts[name])
    assert ax.get_ylabel() == "voltage (V)"


def test_piezo_cycle_closed_loop_and_table_ii():
    from jerklab import piezo as pz

    model, spec = pz.PZTModel(), pz.ScanSpec()
    cycle = pz.shape_cycle(1, 1, model, spec)
    ev = pz.evaluate_cycle(cycle)
    axes = plots.plot_scan_cycle(ev, cycle, title="test")
    assert all(_units(a) for a in axes)
    assert np.allclose(_lines(axes[2])[0].get_ydata(), ev.y_perturbed - ev.y_nominal)
    assert f"e_m = {ev.e_m:.3f}" in axes[0].get_title()
    cl = pz.closed_loop(cycle)
    axes = plots.plot_scan_closed_loop(cl, cycle)
    assert np.allclose(_lines(axes[0])[1].get_ydata(), cl.u_c)
    assert np.allclose(_lines(axes[2])[0].get_ydata(), cl.y - cl.y_desired)
    assert all(_units(a) for a in axes)
    rows = {
        "a robust": {"cycle_time": 0.01, "e_m": 0.1, "e_r": 0.2, "paper": (0.011, 0.12, 0.25)},
        "b": {"cycle_time": 0.02, "e_m": 0.3, "e_r": 0.4, "paper": (0.019, 0.2, 0.5)},
    }
    axes = plots.plot_table_ii(rows, title=None)
    heights = [p.get_height() for p in axes[0].patches]
    assert np.allclose(heights, [10, 20, 11, 19])  # ms: ours, then the paper's
    assert axes[1].get_yscale() == "log" and all(_units(a) for a in axes)


def test_preisach_weight_memory_and_forcs():
    from jerklab.hysteresis import Preisach, forc_experiment

    H = Preisach.piezo_like(0.0, 100.0, n=20, width=0.25)
    ax = plots.plot_preisach_weight(H)
    img = ax.get_images()[0].get_array()
    assert np.allclose(np.ma.filled(img, np.nan), H.masked_density(), equal_nan=True)
    H.apply([80, 20, 65])
    ax = plots.plot_preisach_memory(H)
    b, a = H.interface()
    (stair,) = [ln for ln in ax.get_lines() if ln.get_marker() == "."]
    assert np.allclose(stair.get_xdata(), b) and np.allclose(stair.get_ydata(), a)
    data = forc_experiment(H, 0.0, 100.0, n_curves=4, points_per_curve=6)
    ax = plots.plot_forc(data)
    drawn = np.concatenate([ln.get_ydata() for ln in ax.get_lines()])
    assert np.allclose(np.sort(drawn), np.sort(data.f))
    assert ax.get_xlabel() == "input u (V)"


def test_speed_register_and_pulse_speed():
    from jerklab.fpga import PAPER, YangSCurve

    Y = YangSCurve(**{**PAPER, "clock_hz": 100_000})
    ax = plots.plot_speed_register(Y)
    (line,) = ax.get_lines()
    assert np.allclose(line.get_ydata(), 1e-3 * Y.speed_table().speed)
    assert np.allclose(line.get_xdata(), Y.tick_times()) and ax.get_ylabel() == "speed (mm/s)"
    pt = Y.pulses()
    ax = plots.plot_pulse_speed(pt, scale=1.0, unit="µm/s")
    t, v = pt.speed()
    (line,) = ax.get_lines()
    assert np.allclose(line.get_xdata(), t) and np.allclose(line.get_ydata(), v)
    assert ax.get_ylabel() == "speed k/Δt (µm/s)"


def test_sensitivity_of_shapers():
    from jerklab import shaping

    shapers = {k: shaping.input_shaper(k, 8.0, 0.02) for k in ("zv", "zvd")}
    r = np.linspace(0.5, 1.5, 101)
    ax = plots.plot_sensitivity(shapers, r, frequency_hz=8.0)
    lines = _lines(ax)
    for line, s in zip(lines, shapers.values()):
        assert np.allclose(line.get_ydata(), s.sensitivity_curve(r))
    assert ax.get_ylabel() == "residual vibration (%)" and "8.00 Hz" in ax.get_xlabel()
    with pytest.raises(ValueError, match="ratios"):
        plots.plot_sensitivity(shapers, [np.nan, 1.0])
