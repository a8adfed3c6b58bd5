"""The rig client against the real firmware on a simulated Uno (``connect("simavr")``),
and the virtual rig (the Python model of that firmware) against it, sample by sample."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import require_tool
from jerklab import protocol as P
from jerklab.controller import pole_placement_pid
from jerklab.planner import plan_scurve, plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.rig import RigCommandError, RigError, connect

MOTOR = dict(K=27.5, tau=0.034)


@pytest.fixture(scope="module")
def uno(tmp_path_factory):
    require_tool("make", "cc", "avr-g++", "avr-size", "/usr/share/arduino/hardware/arduino/avr/cores/arduino",
                 "/usr/include/simavr/sim_avr.h")
    rec_dir = tmp_path_factory.mktemp("simavr-recordings")
    rig = connect("simavr", motor=DCMotor(**MOTOR), recordings=rec_dir, progress=False, timeout=10.0)
    yield rig
    rig.close()


def test_hello_from_the_firmware(uno):
    assert uno.name == "jerklab-uno" and uno.info.protocol_version == P.PROTOCOL_VERSION
    # issue 12: the first HELLO right after launch is answered (it used to be lost and only the
    # retry 250 ms later got through); a retry may still be sent if the host is slow
    assert uno.hello_answered == 1
    assert uno.capabilities & P.Capability.PLANNER_SINE_JERK
    assert uno.info.pwm_max == 1023 and uno.info.tick_us == 1000


def test_identify_the_simulated_motor(uno):
    from jerklab.ident import fit_dc_motor

    rec = uno.step(6.0, 0.4)
    assert rec.metadata["status"] == "complete" and len(rec) == 90
    fit = fit_dc_motor(rec.control, rec.position, rec.Ts, method="pem")
    assert fit.K == pytest.approx(MOTOR["K"], rel=0.02)
    assert fit.tau == pytest.approx(MOTOR["tau"], rel=0.05)


def test_firmware_and_virtual_rig_agree(uno, tmp_path):
    """Same move, same gains, same motor: the firmware on simavr and its Python model."""
    prof = plan_sine_jerk(4 * math.pi, 2000.0, 300.0, 60.0)
    g = pole_placement_pid(MOTOR["K"], MOTOR["tau"], wn=20.0).discretize(0.005)
    uno.set_model(**MOTOR)
    fw = uno.run_move(prof, g, Ts=0.005, settle=0.2)
    with connect(motor=DCMotor(**MOTOR), model=(MOTOR["K"], MOTOR["tau"]), recordings=tmp_path,
                 progress=False) as virt:
        py = virt.run_move(prof, g, Ts=0.005, settle=0.2)
    assert fw.metadata["status"] == "complete" and len(fw) == len(py)
    assert fw.metadata["plan"]["n_samples"] == py.metadata["plan"]["n_samples"]
    assert fw.metadata["device_overruns"] == 0 and fw.metadata["lost_samples"] == 0
    # float32 planner on the AVR vs float64 in Python: the references agree to float32 precision
    assert np.max(np.abs(fw.reference - py.reference)) < 1e-5 * max(1.0, prof.distance)
    # The encoder counts differ by at most a count, when an edge falls next to the sampling
    # instant (interrupt latency on the AVR vs the exact edge time in Python). The control law
    # is the same: the PWM differs only at a sample whose count differs or the one after it
    # (the derivative term) — elsewhere by at most 2 ticks (integrator memory of such a count,
    # float32 round-off). With an integrator on a quantized angle both may hunt by a count at
    # rest (a limit cycle whose phase depends on round-off), so this is checked during the move.
    n = fw.metadata["plan"]["n_samples"]
    dc = fw.counts[:n] != py.counts[:n]
    assert np.max(np.abs(fw.counts - py.counts)) <= 1
    # How many samples may differ: the firmware writes each PWM value at the end of its control
    # step, the model at the sampling instant (its computation delay is not modelled, see
    # jerklab/rig/virtual.py), so the firmware's angle lags by about one control step, which the
    # firmware keeps under 10 % of Ts (tests/test_simavr.py). A count differs where the model's
    # angle is within that lag's travel of a count boundary, so the differing fraction is about
    # lag * (counts travelled) / (n Ts): bound the lag it implies. (The fraction itself is 0.261
    # from a fresh start and moves by a few samples with the sub-count angle the motor starts
    # at, so the former fixed bound of 0.25 failed at random; the implied lag is ~0.2 ms.)
    travelled = np.sum(np.abs(np.diff(py.counts[:n])))
    implied_lag = dc.sum() * 0.005 / travelled
    assert implied_lag < 0.1 * 0.005, (dc.mean(), implied_lag)
    explained = dc | np.r_[False, dc[:-1]]
    dp = np.abs(fw.pwm[:n] - py.pwm[:n])
    assert np.all(dp[~explained] <= 2), np.flatnonzero(dp > 2)
    # a count through kpd + kdd + kid, in PWM ticks; flips at two consecutive samples enter
    # the derivative twice, so two counts bound the explained differences
    one_count = (g.kpd + g.kdd + g.kid) / uno.counts_per_rad * uno.info.pwm_max / uno.supply_voltage
    assert np.max(dp) <= 2 * one_count + 2
    assert abs(fw.position[-1] - prof.distance) < 2 / uno.counts_per_rad
    assert np.max(np.abs(fw.error)) < 0.05


def test_firmware_refuses_bad_parameters(uno):
    with pytest.raises(RigCommandError, match="'Ts_us'"):
        uno._request(P.SetGains(1.0, 0.0, 0.0, 1500))
    with pytest.raises(RigCommandError, match="'max_voltage'"):
        uno._request(P.SetLimits(1e4, 100.0, 50.0, 30.0, 1000))
    if not uno.capabilities & P.Capability.PLANNER_SCURVE:
        with pytest.raises(RigError, match="no 'scurve' planner"):
            uno.run_move(plan_scurve(1.0, 1e3, 100.0, 10.0), pole_placement_pid(27.5, 0.034, wn=20.0))
