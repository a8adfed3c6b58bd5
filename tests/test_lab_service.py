"""``python -m jerklab.lab service --profile NAME``: the class rig service on a rig's motor profile."""

from __future__ import annotations

import json

import pytest

from jerklab.lab import service
from jerklab.lab.service import ClassRigService, TokenFile, _Student
from jerklab.lab.session import LabSession
from jerklab.lab.specs import hidden_ranges, lab_spec

KEY = b"service-profile-test-key"
PROFILE = "pololu-37d-30"


@pytest.fixture
def svc(tmp_path):
    tokens = tmp_path / "tokens.json"
    tokens.write_text(json.dumps({"tok-ann-0123456789": "ann"}))
    s = ClassRigService(TokenFile(tokens), tmp_path / "log.jsonl", key=KEY, profile=PROFILE)
    with s:
        yield s


def test_hidden_motors_are_drawn_around_the_profiles_ranges(svc):
    ranges = hidden_ranges(PROFILE)
    paper = hidden_ranges("paper")
    for i in range(3):
        st = _Student(svc, f"s{i:03d}", 2)
        try:
            t = st.truth
            for name in ("K", "tau", "coulomb_friction"):
                lo, hi = ranges[name]
                assert lo <= t[name] <= hi, (name, t[name], ranges[name])
            assert not paper["K"][0] <= t["K"] <= paper["K"][1]  # the paper's class has none
            assert st.rig.counts_per_rev in ranges["encoder_ppr"]
        finally:
            st.close()


def test_sessions_get_the_profiles_spec(svc, tmp_path, monkeypatch):
    monkeypatch.delenv("JERKLAB_LAB_RIG", raising=False)
    S = LabSession(2, port=svc.url, token="tok-ann-0123456789", folder=tmp_path)
    try:
        assert S.mode == "graded" and S.student == "ann"
        assert S.profile.name == PROFILE and S.profile_name == PROFILE
        assert S.spec == lab_spec(2, PROFILE) != lab_spec(2, "paper")
        assert S.evidence().profile == PROFILE
    finally:
        S.close()
    with pytest.raises(ValueError, match="profile: the class rig service runs"):
        LabSession(2, port=svc.url, token="tok-ann-0123456789", folder=tmp_path, profile="paper")


def test_cli_refuses_an_unknown_profile_naming_the_option(tmp_path, capsys):
    tokens = tmp_path / "tokens.json"
    tokens.write_text("{}")
    with pytest.raises(SystemExit) as exc:
        service.main(["--tokens", str(tokens), "--profile", "no-such-motor"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--profile" in err and "pololu-37d-30" in err
