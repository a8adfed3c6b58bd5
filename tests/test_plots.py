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
    assert np.allclose(np.hypot(x, y), 1.0) and np.ptp(np.arctan2(y, x)) > 6.2   # the whole circle
    poles, zeros = _markers(ax)
    assert np.allclose(poles.get_xdata() + 1j * poles.get_ydata(), p) and poles.get_marker() == "x"
    assert np.allclose(zeros.get_xdata() + 1j * zeros.get_ydata(), [-0.8]) and zeros.get_marker() == "o"
    assert zeros.get_markerfacecolor() == "none" and zeros.get_color() == poles.get_color()
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_title()) == ("Re z", "Im z", "closed loop")
    assert ax.get_aspect() == 1.0
    lo, hi = ax.get_xlim()
    assert lo <= -1.0 and hi >= 1.0
    labels = ax.get_legend_handles_labels()[1]
    assert labels == ["loop", "loop zeros"]                      # the circle stays out of the legend


def test_two_designs_on_one_axes_share_one_circle():
    fig, ax = plt.subplots()
    assert zplane([1.16, 0.3], ax=ax, label="eq. 13", color="r") is ax
    zplane([0.8], ax=ax, label="z-domain", marker="o", color="b")
    assert sum(ln.get_gid() == "jerklab-unit-circle" for ln in ax.get_lines()) == 1
    a, b = _markers(ax)
    assert a.get_color() == "r" and b.get_color() == "b" and b.get_markerfacecolor() == "none"
    assert ax.get_xlim()[1] >= 1.16                               # an unstable pole stays in view


def test_systems_are_accepted():
    from jerklab.controller import PositionLoop, discrete_pole_placement_pid

    loop = PositionLoop(32.4, 0.025, discrete_pole_placement_pid(32.4, 0.025, 30.0, Ts=0.005))
    ax = zplane(loop)
    pts = _markers(ax)[0]
    assert np.allclose(np.sort_complex(pts.get_xdata() + 1j * pts.get_ydata()), np.sort_complex(loop.poles_z()))
    sysd = control.c2d(control.tf([1.0], [1.0, 3.0, 2.0]), 0.1)
    ax = zplane(sysd)
    got = _markers(ax)[0]
    assert np.allclose(np.sort(got.get_xdata()), np.sort(np.exp(np.array([-2.0, -1.0]) * 0.1)))
    assert len(_markers(ax)) == 2                                 # the ZOH zero too


@pytest.mark.parametrize("bad, exc", [([np.nan], ValueError), ([1.0, np.inf], ValueError),
                                       ("abc", TypeError), (object(), TypeError)])
def test_bad_input(bad, exc):
    with pytest.raises(exc, match="poles"):
        zplane(bad)


def test_continuous_system_is_refused():
    with pytest.raises(ValueError, match="continuous"):
        zplane(control.tf([1.0], [1.0, 1.0]))
