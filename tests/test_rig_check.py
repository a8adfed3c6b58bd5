"""``jerklab rig check`` against a motor profile: each usual mistake injected on the virtual rig
is reported by name, and the report becomes the rig's profile file."""

from __future__ import annotations

import json

import pytest

from jerklab import cli
from jerklab.rig import Device, connect, load_profile
from jerklab.rig.check import check_rig, format_report, hand_turn, report_profile


def _rig(profile, motor=None, cpr=None, **faults):
    prof = load_profile(profile)
    dev = Device(prof.motor() if motor is None else motor, counts_per_rev=cpr)
    rig = connect(device=dev, profile=prof, progress=False)
    for k, v in faults.items():
        setattr(rig.link.device, k, v)
    return rig


def _check(rig, **kw):
    try:
        found = check_rig(rig, **kw)
    finally:
        rig.close()
    by = {}
    for f in found:
        by.setdefault(f.name, []).append(f)
    return by, format_report(found), found


def _failed(by):
    return sorted(n for n, fs in by.items() if any(not f.ok for f in fs))


@pytest.mark.parametrize(
    "name", ["paper", "pololu-37d-30", "jgb37-520-30", "pololu-25d-47-hp", "pololu-micro-30-hpcb"]
)
def test_a_healthy_rig_of_every_profile_passes(name):
    by, report, found = _check(_rig(name))
    assert _failed(by) == [], report
    prof = load_profile(name)
    assert found.measured["counts_per_rev"] == pytest.approx(prof.counts_per_rev, abs=1)
    assert prof.K_range[0] <= found.measured["K"] <= prof.K_range[1]
    assert found.measured["friction"] == pytest.approx(prof.coulomb_friction, abs=0.1)


def test_330_counts_against_448_is_a_counts_per_revolution_mistake():
    # the JGB37-520's encoder (330 counts a turn) on a rig configured for the paper's 448
    jgb = load_profile("jgb37-520-30")
    by, report, _ = _check(_rig("paper", motor=jgb.motor(K=30.0, encoder_ppr=330), cpr=448))
    assert _failed(by) == ["cpr"], report
    msg = by["cpr"][0].message + by["cpr"][0].fix
    assert "330 counts" in msg and "448" in msg and "counts_per_rev=330" in msg
    assert "jgb37-520-30" in msg  # the profile with that count is named


def test_330_against_448_on_the_batch_count_alone():
    # a real board's case: the count of a turn made by hand given as the batch argument
    jgb = load_profile("jgb37-520-30")
    by, report, _ = _check(
        _rig("paper", motor=jgb.motor(K=30.0, encoder_ppr=330), cpr=448), turn_counts=331
    )
    assert _failed(by) == ["cpr"], report


def test_a_count_per_motor_revolution_is_a_gear_ratio_mistake():
    # counts_per_rev given as the encoder's 44 counts (x4) per motor revolution, the x30 forgotten
    by, report, _ = _check(_rig("jgb37-520-30", cpr=44))
    assert "gear" in _failed(by), report
    f = by["gear"][0]
    assert (
        "motor* revolution" in f.message and "30:1" in f.message and "counts_per_rev=1320" in f.fix
    )


def test_another_gearbox_is_named_with_its_ratio():
    # a 50:1 JGB37 bought for the 30:1 of the profile: 2200 counts (x4) a turn, a third slower
    jgb = load_profile("jgb37-520-30")
    motor = jgb.motor(encoder_ppr=2200, K=jgb.K * 30 / 50)
    by, report, _ = _check(_rig("jgb37-520-30", motor=motor, cpr=1320))
    assert "gear" in _failed(by), report
    assert "50:1 gearbox, not 30:1" in by["gear"][0].message
    assert _failed(by) == ["gear"], report  # the K of a 50:1 gearbox is expected then


def test_swapped_a_and_b_is_named():
    by, report, _ = _check(_rig("pololu-37d-30", encoder_sign=-1))
    assert _failed(by) == ["direction"], report
    (f,) = [f for f in by["direction"] if not f.ok]
    assert f.message.startswith("encoder A/B swapped") and "D2 and D3" in f.fix
    assert all(x.ok for x in by["supply"])  # K is measured all the same


def test_reversed_motor_leads_are_named():
    by, report, _ = _check(_rig("pololu-37d-30", lead_sign=-1))
    assert _failed(by) == ["direction"], report
    (f,) = [f for f in by["direction"] if not f.ok]
    assert f.message.startswith("motor leads reversed") and "OUT1 and OUT2" in f.fix


def test_swapped_a_b_and_reversed_leads_together():
    by, report, _ = _check(_rig("pololu-37d-30", lead_sign=-1, encoder_sign=-1))
    msgs = [f.message for f in by["direction"] if not f.ok]
    assert len(msgs) == 2 and "A/B swapped" in msgs[0] and "leads reversed" in msgs[1], report


def test_a_dead_encoder_is_named():
    by, report, _ = _check(_rig("pololu-37d-30", encoder_sign=0))
    assert _failed(by) == ["encoder"], report
    assert by["encoder"][0].message.startswith("dead encoder") and "D2" in by["encoder"][0].fix


def test_a_low_supply_is_named():
    # a 6 V adapter on a 12 V rig: half the speed per volt; the hand turn rules out the gear
    by, report, _ = _check(_rig("pololu-37d-30", supply_fraction=0.5))
    assert _failed(by) == ["supply"], report
    f = by["supply"][0]
    assert "too slowly" in f.message and "50 %" in f.message and "check the 12 V supply" in f.fix


def test_high_friction_is_named():
    prof = load_profile("pololu-37d-30")
    by, report, _ = _check(_rig("pololu-37d-30", motor=prof.motor(coulomb_friction=2.2)))
    assert _failed(by) == ["friction"], report
    assert "2.2" in by["friction"][0].message or "2.1" in by["friction"][0].message


def test_without_a_hand_turn_a_real_board_is_told_to_turn(monkeypatch):
    rig = _rig("pololu-37d-30")
    monkeypatch.setattr(type(rig), "is_virtual", property(lambda self: False))
    by, report, _ = _check(rig)
    assert _failed(by) == ["turn"] and "--turn-counts" in by["turn"][0].fix, report


def test_the_interactive_turn_asks_and_counts(monkeypatch):
    rig = _rig("jgb37-520-30")
    dev = rig.link.device
    monkeypatch.setattr(type(rig), "is_virtual", property(lambda self: False))
    said, asked = [], []

    def ask(prompt):  # the user presses Enter and turns the shaft once (the device's "hand")
        asked.append(prompt)
        dev.hand = 1.0
        return ""

    try:
        n = hand_turn(rig, seconds=2.0, ask=ask, say=said.append)
    finally:
        rig.close()
    assert asked and "one revolution" in said[0] and n == 1320


def test_the_report_becomes_the_rigs_profile_file(tmp_path, capsys):
    out = tmp_path / "rig.json"
    assert (
        cli.main(["rig", "check", "virtual", "--profile", "jgb37-520-30", "--save", str(out)]) == 0
    )
    text = capsys.readouterr().out
    assert "all checks passed" in text and str(out) in text
    data = json.loads(out.read_text())
    assert data["format"] == "jerklab-motor-profile"
    prof = load_profile(out)
    base = load_profile("jgb37-520-30")
    assert prof.name == "jgb37-520-30-checked" and prof.counts_per_rev == 1320
    assert prof.K == pytest.approx(base.K, rel=0.05) and prof.measured["turn_counts"] == 1320
    # the labs and the class page read it: connect with the file
    rig = connect(profile=out, progress=False)
    try:
        assert rig.counts_per_rev == 1320 and rig.profile.name == "jgb37-520-30-checked"
    finally:
        rig.close()


def test_the_cli_reports_a_mistake_by_name(capsys):
    assert cli.main(["rig", "check", "virtual", "--profile", "jgb37-520-30", "--cpr", "44"]) == 1
    out = capsys.readouterr().out
    assert "FAIL gear" in out


def test_report_profile_keeps_the_profile_when_a_check_failed():
    rig = _rig("pololu-37d-30", supply_fraction=0.5)
    try:
        found = check_rig(rig)
        prof = report_profile(found, rig)
    finally:
        rig.close()
    base = load_profile("pololu-37d-30")
    assert prof.K == base.K  # a failed check does not overwrite the model
    assert prof.measured["K"] == pytest.approx(base.K / 2, rel=0.1)
