"""Firmware laws the mutation audit of issue 31 found unpinned, on the firmware core's host build
(firmware/host/jl_host.cpp, the same C++ as on the Uno): the PRBS of every order, the S-curve
planner where its "A reached" threshold decides, the negative side of the tracking-error stop,
the no-motion threshold at an odd ``pwm_top``.
Each is checked against jerklab (the same law in Python, itself checked against Ruckig and
against a maximal-length period), and each fails with its firmware mutant applied (the
firmware source is changed only to show that, and restored)."""

from __future__ import annotations

import math
import subprocess

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


def _board_plan_agrees(host_driver, path, distance, planner, J, A, V, p):
    """The firmware core's planner ``planner`` (built into the board with
    JL_WITH_BOARD_PLANNERS=1; by default the host plans it) gives the phase times of jerklab's
    profile ``p``: a golden-vector P record (firmware/host/jl_host.cpp) checks its acceleration
    time, cruise and duration to 1.6e-5 of the duration."""
    pt = p.phase_times
    rec = f"P {planner} {distance!r} {J!r} {A!r} {V!r} {sum(pt[:3])!r} {pt[3]!r} {p.duration!r}"
    path.write_text(rec + "\n")
    proc = subprocess.run(
        [str(host_driver), "vectors", str(path)], capture_output=True, text=True, timeout=60
    )
    return proc.returncode == 0 and "plan records=3 failures=0" in proc.stdout, proc.stdout


def _send_segments(dev, profile):
    """The host-planned segments of ``profile`` (PLAN_SEGMENT ..., PLAN_COMMIT; protocol 5)."""
    segs, commit = P.profile_segments(profile)
    for m in (*segs, commit):
        dev.send(m)
    return dev


@pytest.mark.parametrize("planner", [2, 1])
@pytest.mark.parametrize("frac", [1.0, 1.3, 1.7, 1.99, 2.01, 2.5])
def test_the_board_scurve_where_the_acceleration_limit_decides(
    host_driver, tmp_path, planner, frac
):
    """Mutant killed: the firmware S-curve's "A reached" threshold ``d >= 2 A^3 / J^2`` moved
    (to ``A^3 / J^2``, its other natural reading): no golden case fell in
    ``A^3/J^2 <= d < 2 A^3/J^2``, where A is not reached although ``d >= A^3/J^2``.

    ``frac`` places the distance at ``frac A^3/J^2`` (V out of reach); the board's PLAN_INFO must
    give jerklab's phase times (sine: at the linear jerk 2J/pi)."""
    J, A, V = f32(2e4), f32(300.0), f32(1e4)
    Jl = J * (2 / math.pi if planner == 1 else 1.0)
    d = f32(frac * A**3 / Jl**2)
    p = (plan_scurve if planner == 2 else plan_sine_jerk_optimal)(d, J, A, V)
    ta = p.phase_times[1]
    assert (ta > 0.0) == (frac > 2.0)  # the law: A is reached from 2 A^3/J^2 on
    ok, out = _board_plan_agrees(host_driver, tmp_path / "plan.txt", d, planner, J, A, V, p)
    assert ok, out


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
    p = plan_scurve(distance, J, A, V)
    dev.send(P.SetLimits(J, A, V, 12.0, 200, max_error, 0, 0))
    _send_segments(dev, p).send(P.Run(20, 1))
    dev.wait(int((p.duration + 0.2) * 1000) + 50, heartbeat_every=40)
    msgs, _ = dev.run()
    end = [m for _, _, m in msgs if isinstance(m, P.EndOfRun)]
    assert len(end) == 1 and end[0].reason == P.EndReason.TRACKING_ERROR, end
    r = p.sample(np.arange(int(p.duration / Ts) + 2) * Ts).position
    k = int(np.argmax(np.abs(r) > max_error))
    assert end[0].detail < -max_error
    assert end[0].detail == pytest.approx(r[k], rel=1e-3)


class _DeadEncoderDevice(HostDevice):
    """The host build with its encoder unplugged (``jl_host device K tau supply 0``): the count
    stays 0 whatever the drive, as with a disconnected encoder or a stalled motor."""

    def run(self):
        import subprocess

        proc = subprocess.run(
            [str(self.driver), "device", "32.4", "0.025", "12", "0"],
            input="\n".join(self.script) + "\nquit\n",
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert proc.returncode == 0, proc.stderr
        dec = P.Decoder()
        msgs = []
        for line in proc.stdout.splitlines():
            kind, ms, val = line.split()
            if kind == "tx":
                msgs.extend((int(ms), f.seq, P.parse(f)) for f in dec.feed(bytes.fromhex(val)))
        assert dec.stats.dropped == 0
        return msgs


@pytest.mark.parametrize("held, stops", [(100, False), (101, True)])
def test_the_board_no_motion_threshold_at_an_odd_pwm_top(host_driver, held, stops):
    """Mutant killed: the board's "large drive" threshold ``P = (pwm_top + 1) / 2`` ->
    ``pwm_top / 2`` (jl_device.cpp, PROTOCOL.md "Safety stops" 2), which differs only at an
    odd ``pwm_top``; the virtual device's twin is pinned in test_mutants.py.

    ``max_voltage`` = 201 · 12 V / 1023 makes ``pwm_top`` = 201, so ``P`` = 101. A P-only
    position loop (no feedforward, no tracking-error stop) on a dead encoder holds, after the
    move, the drive ``kpd · d``, chosen to round to ``held`` PWM ticks for the whole settle.
    A held 100 is not a large drive: the run completes. A held 101 is, the count does not
    move, and the run ends NO_MOTION one runaway window (200 ms = 40 samples) after the drive
    first reaches 101, with 0 counts moved as its detail. The telemetry's own PWM column
    shows what was held, so the threshold is read against the board's output, not assumed."""
    supply, pwm_max, top = 12.0, 1023, 201
    max_voltage = f32(top * supply / pwm_max)
    d, Ts_us, settle = f32(1.0), 5000, 100
    kpd = f32((held + 0.2) * supply / pwm_max / d)
    J, A, V = 2e4, 300.0, 60.0
    dev = _DeadEncoderDevice(host_driver)
    dev.send(P.SetPlant(32.4, 0.025, supply, 448)).send(P.SetGains(kpd, 0.0, 0.0, Ts_us, 0, 0, 0.0))
    p = plan_scurve(float(d), J, A, V)
    dev.send(P.SetLimits(J, A, V, max_voltage, 200, 0.0, 200, 0))
    _send_segments(dev, p).send(P.Run(settle, 1))
    dev.wait(int(p.duration * 1000) + settle * 5 + 100, heartbeat_every=40)
    msgs = dev.run()
    tel = [m for _, _, m in msgs if isinstance(m, P.Telemetry)]
    end = [m for _, _, m in msgs if isinstance(m, P.EndOfRun)]
    assert len(end) == 1, end
    assert all(t.counts == 0 for t in tel)
    pwm = np.array([t.pwm for t in tel])
    # the drive grows with the reference and is held at `held` after the move
    assert pwm.max() == held, (pwm.max(), pwm[-20:])
    if not stops:
        assert pwm[-1] == held, pwm[-20:]
        assert end[0].reason == P.EndReason.DONE, end
        n = int(math.ceil(p.duration / (Ts_us * 1e-6))) + settle
        assert abs(len(tel) - n) <= 2, (len(tel), n)
    else:
        assert end[0].reason == P.EndReason.NO_MOTION and end[0].detail == 0, end
        first = int(np.argmax(pwm >= held))
        # held from its first sample to the stop, which comes one runaway window later
        last = (
            first + int(np.argmax(pwm[first:] < held)) if (pwm[first:] < held).any() else len(pwm)
        )
        assert (pwm[first:last] == held).all()
        assert 40 - 1 <= last - first <= 40 + 1, (first, last, len(tel), pwm[last - 2 :])
