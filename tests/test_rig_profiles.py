"""Motor profiles (jerklab.rig.profiles): their numbers against the vendors' stated counts, the
measured micromouse records, and a simulated run at full supply; connect(profile=)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from jerklab import ident
from jerklab.rig import connect, load_profile, profile_names
from jerklab.rig.profiles import MotorProfile, builtin_profiles

#: counts per output revolution as the vendors state them (X4: both edges of both channels)
VENDOR_X4 = {
    "pololu-37d-30": 1920.0,  # 64 CPR x 30
    "pololu-25d-47-hp": 2248.86,  # Pololu item 4845's page
    "jgb37-520-30": 1320.0,  # 11 PPR x 4 x 30
    "pololu-micro-30-hpcb": 12 * 29.861,
}


def test_there_are_at_least_three_buyable_motors_and_the_paper():
    names = profile_names()
    assert names[0] == "paper"
    buyable = [n for n in names if builtin_profiles()[n].part.get("url") or n.startswith("jgb")]
    assert len(buyable) >= 3 and len(names) >= 4


@pytest.mark.parametrize("name", sorted(VENDOR_X4))
def test_counts_per_revolution_agree_with_the_vendor(name):
    p = load_profile(name)
    x4 = p.counts_per_motor_rev * p.gear_ratio
    assert x4 == pytest.approx(VENDOR_X4[name], rel=1e-4)
    # the firmware holds JL_ENCODER_PPR, an integer count of one channel a turn, and decodes X4
    # when counts_per_rev is exactly four times it
    ppr = round(x4 / 4)
    assert p.counts_per_rev == 4 * ppr and p.counts_per_rev == pytest.approx(x4, rel=0.005)


@pytest.mark.parametrize("name", profile_names())
def test_the_virtual_rig_of_a_profile_runs_at_the_datasheet_no_load_speed(name):
    p = load_profile(name)
    rig = connect(profile=name, progress=False)
    try:
        rec = rig.step(p.supply_voltage, 1.5, rest=0.0, path=False, progress=False)
    finally:
        rig.close()
    t, y = np.asarray(rec.time), np.asarray(rec.position)
    sel = t > t[-1] - 0.2
    w = np.polyfit(t[sel], y[sel], 1)[0]
    rpm = p.datasheet["no_load_rpm"]
    assert w * 60 / (2 * math.pi) == pytest.approx(rpm, rel=0.02)


def test_the_micromouse_profile_holds_the_measured_fit():
    p = load_profile("pololu-micro-30-hpcb")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = ident.load_micromouse(p.measured["record"]).fit("pem", friction=True, delay=True)
    assert p.measured["K_nominal_volts"] == pytest.approx(fit.K, rel=0.01)
    assert p.tau == pytest.approx(fit.tau, rel=0.01)
    assert p.coulomb_friction == pytest.approx(fit.friction, rel=0.01)
    assert p.tau_range[0] <= fit.tau <= p.tau_range[1]


def _line_residual(counts, n=9):
    """The rms of ``counts`` about a straight line fitted to each run of ``n`` samples."""
    t = np.arange(n)
    res = [
        counts[i : i + n] - np.polyval(np.polyfit(t, counts[i : i + n], 1), t)
        for i in range(0, len(counts) - n + 1, n)
    ]
    return float(np.std(np.concatenate(res)))


def test_the_micromouse_records_bound_the_count_noise():
    """The micro profile's measured ``count_noise`` (the hidden encoders' largest, jerklab.lab.
    specs.hidden_ranges) against its records: at steady speed the counts deviate from a line no
    more than the bare quantization of a simulated ramp at the same speed with that much noise
    (the virtual rig's model: Gaussian before the floor), while 0.05 counts more would show;
    at rest the reading never changes."""
    from pathlib import Path

    p = load_profile("pololu-micro-30-hpcb")
    sigma = p.measured["count_noise"]
    data = Path(__file__).parent.parent / "data" / "real" / "micromouse"
    rng = np.random.default_rng(5)
    for rec in ("encoders1", "encoders3", "encoders5"):
        d = np.genfromtxt(data / f"{rec}.csv", delimiter=",", names=True)
        on = np.nonzero(d["leftMode"] != 0)[0]
        steady = -d["leftEncoder"][on[0] : on[-1] + 1]
        steady = steady[len(steady) // 2 :]
        measured = _line_residual(steady)
        v = float(np.mean(np.diff(steady)))

        def simulated(s, steady=steady, v=v):
            x = rng.uniform() + v * np.arange(len(steady) * 40)
            return _line_residual(np.floor(x + rng.normal(0.0, s, x.size)))

        sims = (simulated(sigma), simulated(sigma + 0.05))
        assert measured <= sims[0] + 0.005 and measured < sims[1], (rec, measured, sims)
    for rec in ("encoders3", "encoders4", "encoders5", "encoders6"):
        d = np.genfromtxt(data / f"{rec}.csv", delimiter=",", names=True)
        rest = d["leftMode"][1:] == 0
        assert rest.sum() > 80 and not np.diff(d["leftEncoder"])[rest].any(), rec


@pytest.mark.parametrize("name", profile_names())
def test_every_profile_is_consistent(name):
    p = load_profile(name)
    assert p.K_range[0] <= p.K <= p.K_range[1]
    assert p.friction_range[0] <= p.coulomb_friction + 1e-12 or name == "paper"
    assert p.counts_per_rev in p.counts_options
    assert p.datasheet["source"]
    if p.wires:
        assert set(p.wires) == {
            "motor +",
            "motor -",
            "encoder GND",
            "encoder VCC",
            "encoder A",
            "encoder B",
        }
        assert len(set(p.wires.values())) == 6  # six colours on the 6-wire lead


def test_connect_takes_the_profile():
    rig = connect(profile="pololu-37d-30", progress=False)
    try:
        p = rig.profile
        assert rig.counts_per_rev == 1920 and rig.supply_voltage == 12.0
        assert rig.model == pytest.approx((p.K, p.tau))
        assert rig.link.device.motor.K == pytest.approx(p.K)
    finally:
        rig.close()
    rig = connect(progress=False)
    try:
        assert rig.profile is None and rig.counts_per_rev == 448
    finally:
        rig.close()


def test_load_profile_names_the_parameter():
    with pytest.raises(ValueError, match="pololu-37d-30"):
        load_profile("no-such-motor")
    with pytest.raises(TypeError, match="profile"):
        load_profile(3)
    with pytest.raises(ValueError, match="K_range"):
        MotorProfile(
            "x",
            "x",
            12.0,
            None,
            None,
            100,
            (100,),
            50.0,
            (1.0, 2.0),
            0.02,
            (0.01, 0.03),
            0.0,
            (0.0, 0.1),
        )


def test_a_file_that_is_not_a_profile_is_refused(tmp_path):
    f = tmp_path / "x.json"
    f.write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match="not a jerklab motor profile"):
        load_profile(f)
