"""jerklab.plots.zplane: unit circle, poles and zeros where they are, labelled axes."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import control
import matplotlib.pyplot as plt
import numpy as np
import pytest

from jerklab.plots import zplane


@pytest.fixture(autouse=True)
def _close():
    yield
    plt.close("all")


def _markers(ax):
    return [ln for ln in ax.get_lines() if ln.get_linestyle() == "None"]


def test_poles_zeros_circle_and_labels():
    p = np.array([0.9 + 0.2j, 0.9 - 0.2j, 0.5])
    ax = zplane(p, zeros=[-0.8], label="loop", title="closed loop")
    circle = [ln for ln in ax.get_lines() if ln.get_gid() == "jerklab-unit-circle"]
    assert len(circle) == 1
    x, y = circle[0].get_data()
    assert np.allclose(np.hypot(x, y), 1.0) and np.ptp(np.arctan2(y, x)) > 6.2  # the whole circle
    poles, zeros = _markers(ax)
    assert np.allclose(poles.get_xdata() + 1j * poles.get_ydata(), p) and poles.get_marker() == "x"
    assert (
        np.allclose(zeros.get_xdata() + 1j * zeros.get_ydata(), [-0.8])
        and zeros.get_marker() == "o"
    )
    assert zeros.get_markerfacecolor() == "none" and zeros.get_color() == poles.get_color()
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_title()) == ("Re z", "Im z", "closed loop")
    assert ax.get_aspect() == 1.0
    lo, hi = ax.get_xlim()
    assert lo <= -1.0 and hi >= 1.0
    labels = ax.get_legend_handles_labels()[1]
    assert labels == ["loop", "loop zeros"]  # the circle stays out of the legend


def test_two_designs_on_one_axes_share_one_circle():
    fig, ax = plt.subplots()
    assert zplane([1.16, 0.3], ax=ax, label="eq. 13", color="r") is ax
    zplane([0.8], ax=ax, label="z-domain", marker="o", color="b")
    assert sum(ln.get_gid() == "jerklab-unit-circle" for ln in ax.get_lines()) == 1
    a, b = _markers(ax)
    assert a.get_color() == "r" and b.get_color() == "b" and b.get_markerfacecolor() == "none"
    assert ax.get_xlim()[1] >= 1.16  # an unstable pole stays in view


def test_systems_are_accepted():
    from jerklab.controller import PositionLoop, discrete_pole_placement_pid

    loop = PositionLoop(32.4, 0.025, discrete_pole_placement_pid(32.4, 0.025, 30.0, Ts=0.005))
    ax = zplane(loop)
    pts = _markers(ax)[0]
    assert np.allclose(
        np.sort_complex(pts.get_xdata() + 1j * pts.get_ydata()), np.sort_complex(loop.poles_z())
    )
    sysd = control.c2d(control.tf([1.0], [1.0, 3.0, 2.0]), 0.1)
    ax = zplane(sysd)
    got = _markers(ax)[0]
    assert np.allclose(np.sort(got.get_xdata()), np.sort(np.exp(np.array([-2.0, -1.0]) * 0.1)))
    assert len(_markers(ax)) == 2  # the ZOH zero too


@pytest.mark.parametrize(
    "bad, exc",
    [
        ([np.nan], ValueError),
        ([1.0, np.inf], ValueError),
        ("abc", TypeError),
        (object(), TypeError),
    ],
)
def test_bad_input(bad, exc):
    with pytest.raises(exc, match="poles"):
        zplane(bad)


def test_continuous_system_is_refused():
    with pytest.raises(ValueError, match="continuous"):
        zplane(control.tf([1.0], [1.0, 1.0]))


# ----------------------------------------------------------------------------------------------
# the result figures: one home (jerklab.plots), the objects' .plot() call it, old names alias it
# ----------------------------------------------------------------------------------------------
def _data_of(ax, label):
    (ln,) = [ln for ln in ax.get_lines() if ln.get_label() == label]
    return ln.get_xdata(), ln.get_ydata()


def test_simulation_figure_draws_the_result():
    from jerklab import plots
    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.planner import plan_sine_jerk
    from jerklab.plant import DCMotor
    from jerklab.sim import simulate

    r = simulate(
        plan_sine_jerk(3.0, 2000.0, 100.0, 20.0),
        DCMotor(0.9 * 32.4, 0.03),
        discrete_pole_placement_pid(32.4, 0.025, 30.0, Ts=0.005),
    )
    fig = r.plot(title="run")
    assert [a.get_ylabel() for a in fig.axes] == [
        "angle (rad)",
        "tracking error (mrad)",
        "voltage (V)",
    ]
    assert fig.axes[2].get_xlabel() == "time (s)" and fig.axes[0].get_title() == "run"
    t, y = _data_of(fig.axes[0], "motor (true)")
    np.testing.assert_array_equal(t, r.t)
    np.testing.assert_array_equal(y, r.position)
    np.testing.assert_array_equal(
        fig.axes[1].get_lines()[0].get_ydata(), 1e3 * (r.reference - r.position)
    )
    np.testing.assert_array_equal(_data_of(fig.axes[2], "u applied")[1], r.u_applied)
    fig2 = plots.plot_simulation(r)  # the same figure from the function
    assert "mrad" in fig2.axes[0].get_title()
    assert [len(a.get_lines()) for a in fig2.axes] == [len(a.get_lines()) for a in fig.axes]


def test_ident_figures_draw_the_results():
    from jerklab import ident, plots

    Ts = 0.005
    u = ident.step_input(0.6, Ts, 4.0)
    theta = ident.simulate_dc_motor(32.4, 0.025, Ts, u)
    d = ident.IdentData(u, theta, Ts)
    axes = d.plot()
    assert axes[0].get_ylabel() == "input u (V)" and axes[1].get_ylabel() == "output y (rad)"
    np.testing.assert_array_equal(axes[1].get_lines()[0].get_ydata(), theta)
    fit = ident.fit_dc_motor(u, theta, Ts, method="arx")
    c = ident.compare(d, fit)
    ax = c.plot()
    np.testing.assert_allclose(ax.get_lines()[1].get_ydata(), c.y_hat)
    assert f"{c.fit_percent:.2f} %" in ax.get_lines()[1].get_label()
    assert ax.get_xlabel() == "time (s)" and ax.get_ylabel() == "angle (rad)"
    # the speed comparison carries its own unit
    s = ident.compare(d, fit, output="speed")
    assert s.plot().get_ylabel() == "speed (rad/s)"
    # ident.plot_compare computes the comparisons, plots.plot_compare only draws them
    pem = ident.fit_dc_motor(u, theta, Ts)
    ax2 = ident.plot_compare(d, fit, pem, horizon=5)
    ax3 = plots.plot_compare(ident.compare(d, fit, 5), ident.compare(d, pem, 5))
    assert len(ax2.get_lines()) == len(ax3.get_lines()) == 3
    for a, b in zip(ax2.get_lines(), ax3.get_lines()):
        np.testing.assert_array_equal(a.get_ydata(), b.get_ydata())
    assert "5-step prediction" in ax3.get_lines()[2].get_label()
    with pytest.raises(ValueError, match="results"):
        plots.plot_compare(d, fit)  # a record and a model: compute compare(d, fit) first
    with pytest.raises(ValueError, match="another record"):
        plots.plot_compare(c, ident.compare(d[:50], fit))
    with pytest.raises(ValueError, match="data"):
        ident.plot_compare((u, theta), fit)
    with pytest.raises(ValueError, match="analysis"):
        plots.plot_residuals(np.zeros(3))
    with pytest.raises(ValueError, match="analysis"):
        ident.plot_residuals(np.zeros(3))
    r = ident.resid(d, pem)
    axes = ident.plot_residuals(r, title="residuals")
    np.testing.assert_array_equal(axes[0].containers[0].markerline.get_ydata(), r.autocorr)
    assert axes[0].get_title() == "residuals"


def test_recording_figures_and_alias():
    from jerklab import plots, rig

    assert rig.plot_comparison is plots.plot_comparison
    rec = rig.Recording(
        {
            "kind": "step",
            "Ts": 0.005,
            "counts_per_rad": 448 / (2 * np.pi),
            "volts_per_pwm": 12 / 1023,
            "status": "ok",
        }
    )
    for k in range(5):
        rec.append(k, 0.0, 3 * k, 100 * k)
    fig = rec.plot()
    ax0, ax1 = fig.axes
    assert ax0.get_ylabel() == "position (rad)" and ax1.get_ylabel() == "control (V)"
    np.testing.assert_array_equal(ax0.get_lines()[0].get_ydata(), rec.position)
    assert ax0.get_title() == "rig recording: step (ok)"
