"""Firmware laws the mutation audit of issue 31 found unpinned, on the firmware core's host build
(firmware/host/jl_host.cpp, the same C++ as on the Uno): the PRBS of every order, the S-curve
planner where its "A reached" threshold decides, the negative side of the tracking-error stop.
Each is checked against jerklab (the same law in Python, itself checked against Ruckig and
against a maximal-length period), and each fails with its firmware mutant applied (the
firmware source is changed only to show that, and restored)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import require_tool
from test_firmware import HostDevice, build_firmware

from jerklab import protocol as P
from jerklab.planner import plan_scurve, plan_sine_jerk_optimal


def f32(x):
    return float(np.float32(x))


@pytest.fixture(scope="module")
def host_driver():
    require_tool("g++", "make")
    return build_firmware("host")["host"]


@pytest.mark.parametrize("order", sorted(P.PRBS_TAPS))
def test_the_board_prbs_matches_python_for_every_order(host_driver, order):
    """Mutant killed: a wrong feedback mask for any order in the firmware's table
    (jl_excite.cpp); before, only orders 5, 8 and 10 were compared. Python's mask is the
    reference: its sequence has the maximal period 2**order - 1 (checked here for the short
    orders), and the board's SEQUENCE must apply it bit for bit."""
    n = min(400, (1 << order) - 1 + 7)
    seed = 1
    bits = P.prbs_bits(order, seed, n)
    if order <= 10:
        period = (1 << order) - 1
        long = P.prbs_bits(order, seed, 2 * period)
        assert long[:period] == long[period:] and sum(long[:period]) == 1 << (order - 1)
        # no shorter period: for each proper divisor p the sequence is not p-periodic
        assert all(
            long[:period] != long[:p] * (period // p) for p in range(1, period) if period % p == 0
        )
    msg = P.Sequence(2.0, 0.0, 5000, n, seed, order, 1)
    dev = HostDevice(host_driver)
    dev.send(msg).wait(50 * (-(-(5 * n + 30) // 50)), heartbeat_every=50)
    msgs, _ = dev.run()
    tel = [m for _, _, m in msgs if isinstance(m, P.Telemetry)]
    assert [t.index for t in tel] == list(range(n))
    assert [int(t.reference > 0.0) for t in tel] == bits


def _plan_info(host_driver, distance, planner, J, A, V):
    dev = HostDevice(host_driver)
    dev.send(P.SetPlant(32.4, 0.025, 12.0, 448)).send(P.SetGains(1.0, 0.0, 0.0, 5000, 0, 1, 0.0))
    dev.send(P.SetLimits(J, A, V, 12.0, 200)).send(P.Plan(distance, planner))
    msgs, _ = dev.run()
    return next(m for _, _, m in msgs if isinstance(m, P.PlanInfo))


@pytest.mark.parametrize("planner", [2, 1])
@pytest.mark.parametrize("frac", [1.0, 1.3, 1.7, 1.99, 2.01, 2.5])
def test_the_board_scurve_where_the_acceleration_limit_decides(host_driver, planner, frac):
    """Mutant killed: the firmware S-curve's "A reached" threshold ``d >= 2 A^3 / J^2`` moved
    (to ``A^3 / J^2``, its other natural reading): no golden case fell in
    ``A^3/J^2 <= d < 2 A^3/J^2``, where A is not reached although ``d >= A^3/J^2``.

    ``frac`` places the distance at ``frac A^3/J^2`` (V out of reach); the board's PLAN_INFO must
    give jerklab's phase times (sine: at the linear jerk 2J/pi)."""
    J, A, V = f32(2e4), f32(300.0), f32(1e4)
    Jl = J * (2 / math.pi if planner == 1 else 1.0)
    d = f32(frac * A**3 / Jl**2)
    p = (plan_scurve if planner == 2 else plan_sine_jerk_optimal)(d, J, A, V)
    tj, ta = p.phase_times[0], p.phase_times[1]
    assert (ta > 0.0) == (frac > 2.0)  # the law: A is reached from 2 A^3/J^2 on
    info = _plan_info(host_driver, d, planner, J, A, V)
    assert info.accel_time == pytest.approx(2 * tj + ta, rel=2e-5)
    assert info.duration == pytest.approx(p.duration, rel=2e-5)


def test_the_board_stops_a_negative_move_whose_error_runs_away(host_driver):
    """Mutant killed: the tracking-error check on the positive side only (``e > max_error``
    instead of ``|e| > max_error``, jl_device.cpp); every case was a positive move.

    A negative move with every gain and the feedforward off: the motor never moves, so the
    error is the reference itself. The run must end TRACKING_ERROR at the first sample where
    ``|r(k Ts)| > max_error``, with the (negative) error as its detail -- from the closed form."""
    distance, J, A, V = f32(-3.0), 2e4, 300.0, 60.0
    max_error, Ts = 0.5, 0.005
    dev = HostDevice(host_driver)
    dev.send(P.SetPlant(32.4, 0.025, 12.0, 448)).send(P.SetGains(0.0, 0.0, 0.0, 5000, 0, 0, 0.0))
    dev.send(P.SetLimits(J, A, V, 12.0, 200, max_error, 0, 0)).send(P.Plan(distance, 2))
    dev.send(P.Run(20, 1))
    p = plan_scurve(distance, J, A, V)
    dev.wait(int((p.duration + 0.2) * 1000) + 50, heartbeat_every=40)
    msgs, _ = dev.run()
    end = [m for _, _, m in msgs if isinstance(m, P.EndOfRun)]
    assert len(end) == 1 and end[0].reason == P.EndReason.TRACKING_ERROR, end
    r = p.sample(np.arange(int(p.duration / Ts) + 2) * Ts).position
    k = int(np.argmax(np.abs(r) > max_error))
    assert end[0].detail < -max_error
    assert end[0].detail == pytest.approx(r[k], rel=1e-3)
