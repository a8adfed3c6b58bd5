"""jerklab.peers: Ruckig's duration, checked against the closed-form planner, and its absence."""

from __future__ import annotations

import math
import sys

import pytest

from jerklab import peers
from jerklab.planner import plan_scurve


@pytest.mark.parametrize(
    "d, J, A, V",
    [
        (10 * math.pi, 2e4, 300.0, 100.0),
        (-1.0, 1e3, 100.0, 10.0),
        (0.01, 1e3, 10.0, 10.0),
        (1000.0, 2e4, 10.0, 100.0),
    ],
)
def test_duration_equals_the_time_optimal_scurve(d, J, A, V):
    pytest.importorskip("ruckig")
    assert peers.ruckig_duration(d, J, A, V) == pytest.approx(
        plan_scurve(d, J, A, V).duration, rel=1e-9
    )


def test_the_published_example():
    """The example of notebook 01: the published sine planner is slow when E binds."""
    pytest.importorskip("ruckig")
    from jerklab.planner import plan_sine_jerk

    best = peers.ruckig_duration(10 * math.pi, 2e4, 300.0, 100.0)
    pub = plan_sine_jerk(10 * math.pi, 2e4, 300.0, 100.0).duration
    assert pub == pytest.approx(4.4916, abs=1e-4) and best == pytest.approx(0.6624, abs=1e-4)
    assert pub / best == pytest.approx(6.78, abs=0.01)


def test_zero_distance_and_trajectory():
    pytest.importorskip("ruckig")
    assert peers.ruckig_duration(0.0, 1e3, 10.0, 10.0) == 0.0
    traj = peers.ruckig_trajectory(2.0, 1e3, 100.0, 10.0)
    x, v, a = (u[0] for u in traj.at_time(traj.duration))
    assert x == pytest.approx(2.0) and abs(v) < 1e-9


@pytest.mark.parametrize(
    "args, name",
    [
        ((1.0, -1.0, 1.0, 1.0), "max_jerk"),
        ((1.0, 1.0, 0.0, 1.0), "max_accel"),
        ((1.0, 1.0, 1.0, math.nan), "max_velocity"),
        ((math.inf, 1.0, 1.0, 1.0), "distance"),
    ],
)
def test_bad_input_names_the_parameter(args, name):
    with pytest.raises(ValueError, match=name):
        peers.ruckig_duration(*args)


def test_missing_ruckig_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "ruckig", None)  # import ruckig -> ImportError
    with pytest.raises(ImportError, match="pip install 'ruckig"):
        peers.ruckig_duration(1.0, 1e3, 100.0, 10.0)
