"""The rig's grouped options (jerklab.rig.options): Link, Device and RunSpec check their fields
when made, connect() and run_move() take them, and the short forms give the same run.

Independent references: the short form ``run_move(profile, gains, Ts, settle=...)`` against the
explicit ``spec=RunSpec(...)`` on a second, identical rig (sample for sample); what pyserial is
handed, read from a stand-in ``serial_for_url``; the virtual rig's encoder count noise against
the normal distribution's probabilities (scipy.stats) and against numpy's generator drawn by
hand with the same seed.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from jerklab import rig as R
from jerklab.controller import discrete_pole_placement_pid, pole_placement_pid
from jerklab.law import ENCODER_EPS
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor, FlexibleDCMotor
from jerklab.rig import Device, Link, RunSpec, connect
from jerklab.rig.virtual import VirtualDevice


# ----------------------------------------------------------------------------- each group checks
@pytest.mark.parametrize(
    "make, field",
    [
        (lambda: Link(timeout=float("nan")), "timeout"),
        (lambda: Link(timeout=1e-4), "timeout"),
        (lambda: Link(hello_timeout=0), "hello_timeout"),
        (lambda: Link(baudrate=0), "baudrate"),
        (lambda: Link(baudrate=9600.5), "baudrate"),
        (lambda: Link(serial={"port": "/dev/x"}), "serial"),
        (lambda: Link(serial=5), "serial"),
        (lambda: Device(speed=-1.0), "speed"),
        (lambda: Device(supply_voltage=float("inf")), "supply_voltage"),
        (lambda: Device(counts_per_rev=0), "counts_per_rev"),
        (lambda: Device(count_noise=-0.1), "count_noise"),
        (lambda: RunSpec(Ts=0.0), "Ts"),
        (lambda: RunSpec(Ts=0.1), "Ts"),
        (lambda: RunSpec(settle=-1.0), "settle"),
        (lambda: RunSpec(decimation=0), "decimation"),
        (lambda: RunSpec(decimation=256), "decimation"),
        (lambda: RunSpec(decimation=1.5), "decimation"),
        (lambda: RunSpec(decimation=True), "decimation"),
        (lambda: RunSpec(host_timeout=70.0), "host_timeout"),
        (lambda: RunSpec(max_error=1e39), "max_error"),
        (lambda: RunSpec(runaway_time=-1.0), "runaway_time"),
        (lambda: RunSpec(saturation_time=66.0), "saturation_time"),
        (lambda: RunSpec(max_voltage=0.0), "max_voltage"),
        (lambda: RunSpec(feedforward="yes"), "feedforward"),
        (lambda: RunSpec(force="no"), "force"),
    ],
)
def test_a_bad_field_is_named_when_the_group_is_made(make, field):
    with pytest.raises(ValueError, match=field):
        make()


def test_groups_are_frozen_hashable_and_replace_checks_again():
    link = Link(timeout=3.0, serial={"write_timeout": 1.0})
    assert link.serial == (("write_timeout", 1.0),) and link.serial_options == {
        "write_timeout": 1.0
    }
    assert hash(link) == hash(Link(timeout=3.0, serial={"write_timeout": 1.0}))
    with pytest.raises(dataclasses.FrozenInstanceError):
        link.timeout = 1.0
    spec = RunSpec(settle=0.4)
    assert spec.replace(force=True) == RunSpec(settle=0.4, force=True)
    with pytest.raises(ValueError, match="settle"):
        spec.replace(settle=-1.0)
    with pytest.raises(TypeError, match="'setle'.*settle"):
        spec.replace(setle=0.1)
    with pytest.raises(TypeError, match="motor must be"):
        Device("a motor")
    assert Device(DCMotor()).simulated_only == ["motor"]
    assert Device(supply_voltage=24.0, counts_per_rev=896).simulated_only == []


def test_runspec_period_is_the_gains_own_by_default():
    g = discrete_pole_placement_pid(32.4, 0.025, 30.0, Ts=0.004)
    assert RunSpec().period(g) == 0.004
    assert RunSpec(Ts=0.002).period(g) == 0.002
    assert RunSpec().period(pole_placement_pid(32.4, 0.025, 30.0)) == 0.005  # continuous gains


# ----------------------------------------------------------------------------- connect
@pytest.mark.parametrize(
    "kw, points_to",
    [
        ({"student": "s1"}, r"jerklab\.lab\.connect_student"),
        ({"plant": "flexible"}, r"device=FlexibleDCMotor\(\)"),
        ({"speed": 1.0}, r"device=Device\(motor, speed=\.\.\.\)"),
        ({"supply_voltage": 12.0}, r"device=Device\(supply_voltage="),
        ({"counts_per_rev": 448}, r"device=Device\(counts_per_rev="),
        ({"timeout": 2.0}, r"link=Link\(timeout="),
        ({"hello_timeout": 1.0}, r"link=Link\(hello_timeout="),
        ({"baudrate": 9600}, r"link=Link\(baudrate="),
        ({"rtscts": True}, r"unexpected keyword argument 'rtscts'"),
    ],
)
def test_old_keywords_say_where_they_went(kw, points_to):
    with pytest.raises(TypeError, match=points_to):
        connect(**kw)


def test_motor_is_the_older_name_of_device():
    m = DCMotor(K=27.5, tau=0.034)
    with connect(motor=m, progress=False) as rig:
        assert rig.link.device.motor is m
    with pytest.raises(TypeError, match="motor= is its older name"):
        connect(motor=m, device=DCMotor())


def test_a_simulated_device_field_is_refused_for_a_real_port_before_it_is_opened(monkeypatch):
    import serial

    def must_not_open(*a, **k):
        raise AssertionError("the port was opened")

    monkeypatch.setattr(serial, "serial_for_url", must_not_open)
    for device in (DCMotor(), FlexibleDCMotor(), Device(speed=1.0), Device(count_noise=0.3)):
        with pytest.raises(ValueError, match="applies to a simulated rig"):
            connect("loop://", device=device)
    with pytest.raises(ValueError, match="virtual rig only"):
        connect("simavr", device=Device(speed=2.0))


def test_the_link_reaches_pyserial(monkeypatch):
    """Baud rate and the Link's pyserial options are what serial_for_url is given."""
    import serial

    seen = {}

    def fake(port, **kw):
        seen.update(kw, port=port)
        raise serial.SerialException("no such device (stand-in)")

    monkeypatch.setattr(serial, "serial_for_url", fake)
    with pytest.raises(R.UnknownPortError, match="stand-in"):
        connect("loop://", link=Link(baudrate=57600, serial={"write_timeout": 0.5}))
    assert seen["port"] == "loop://" and seen["baudrate"] == 57600
    assert seen["write_timeout"] == 0.5


def test_device_sets_the_virtual_rigs_supply_and_encoder():
    with connect(
        device=Device(DCMotor(supply_voltage=24.0), counts_per_rev=896), progress=False
    ) as rig:
        assert rig.supply_voltage == 24.0 and rig.counts_per_rev == 896
    with connect(device=DCMotor(encoder_ppr=500, decoding=4), progress=False) as rig:
        assert rig.counts_per_rev == 2000 and rig.supply_voltage == 12.0


def test_metadata_must_be_json_data():
    with pytest.raises(ValueError, match="JSON"):
        connect(metadata={"who": float("nan")}, progress=False)
    with pytest.raises(TypeError, match="metadata must be a dict"):
        connect(metadata=["s1"], progress=False)


# ----------------------------------------------------------------------------- run_move
def _move_arrays(rec):
    return {k: getattr(rec, k) for k in ("time", "reference", "position", "voltage", "flags")}


def test_the_short_form_runs_the_same_move_as_the_spec():
    prof = plan_sine_jerk(6.0, 2e4, 300.0, 60.0)
    g = discrete_pole_placement_pid(32.4, 0.025, 30.0, Ts=0.005)
    runs = []
    for how in ("short", "spec"):
        with connect(device=DCMotor(seed=3, noise_std=0.0), progress=False) as rig:
            if how == "short":
                rec = rig.run_move(prof, g, 0.005, settle=0.1, decimation=2, path=False)
            else:
                spec = RunSpec(Ts=0.005, settle=0.1, decimation=2)
                rec = rig.run_move(prof, g, spec=spec, path=False)
        runs.append(rec)
    a, b = (_move_arrays(r) for r in runs)
    assert len(runs[0]) == len(runs[1]) > 100
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert runs[0].metadata["decimation"] == 2 and runs[0].metadata["settle_samples"] == 20


def test_run_move_names_a_bad_or_conflicting_option():
    prof = plan_sine_jerk(2.0, 2e4, 300.0, 60.0)
    g = discrete_pole_placement_pid(32.4, 0.025, 30.0, Ts=0.005)
    with connect(progress=False) as rig:
        with pytest.raises(TypeError, match="'setle'"):
            rig.run_move(prof, g, setle=0.1, path=False)
        with pytest.raises(ValueError, match="disagrees"):
            rig.run_move(prof, g, 0.005, spec=RunSpec(Ts=0.004), path=False)
        with pytest.raises(TypeError, match="spec must be"):
            rig.run_move(prof, g, spec={"settle": 0.1}, path=False)
        with pytest.raises(ValueError, match="decimation"):
            rig.run_move(prof, g, decimation=0, path=False)
        # the default period is the gains' own
        assert rig.run_move(prof, g, path=False).metadata["Ts"] == pytest.approx(0.005)


# ----------------------------------------------------------------------------- count noise
def test_count_noise_at_rest_follows_the_normal_distribution():
    """At θ = 0 the reading is floor(ε + n), n ~ N(0, σ²): P(k) = Φ((k + 1 − ε)/σ) − Φ((k − ε)/σ)."""
    sigma, n = 0.6, 6000
    dev = VirtualDevice(DCMotor(), count_noise=sigma, noise_seed=11)
    counts = np.array([dev._raw_counts() for _ in range(n)])
    ks = np.arange(-3, 3)
    p = stats.norm.cdf((ks + 1 - ENCODER_EPS) / sigma) - stats.norm.cdf((ks - ENCODER_EPS) / sigma)
    observed = np.array([np.count_nonzero(counts == k) for k in ks])
    assert observed.sum() >= n - 5  # beyond ±3 counts: < 1e-6 of the draws
    chi2 = np.sum((observed - n * p) ** 2 / (n * p))
    assert chi2 < stats.chi2.ppf(0.9999, len(ks) - 1), (observed, n * p)
    quiet = VirtualDevice(DCMotor())
    assert {quiet._raw_counts() for _ in range(50)} == {0}


def test_count_noise_is_numpys_generator_with_the_seed():
    """The noise of a device is numpy's default_rng(noise_seed).normal(0, σ), added before the
    floor: the same seed gives the same readings (the lab seeds it with the hidden motor's)."""
    motor = DCMotor()
    dev = VirtualDevice(motor, count_noise=0.4, noise_seed=(123, 1))
    rng = np.random.default_rng((123, 1))
    for theta in np.linspace(-0.3, 0.7, 40):
        dev.x[0] = theta
        expected = math.floor(theta * motor.counts_per_rad + ENCODER_EPS + rng.normal(0.0, 0.4))
        assert dev._raw_counts() == expected
    with pytest.raises(ValueError, match="count_noise"):
        VirtualDevice(motor, count_noise=float("nan"))
