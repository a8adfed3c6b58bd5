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


@pytest.mark.parametrize("lab, profile", [(2, "pololu-micro-30-hpcb"), (3, PROFILE), (1, PROFILE)])
def test_a_move_stops_where_the_lab_on_the_profile_says(tmp_path, lab, profile):
    """The service runs each move with the tracking-error stop of the lab on its profile
    (``lab_spec(lab, profile)["stop_error"]``: 1.375 rad on the micro gearmotor, the device's
    0.5 rad elsewhere; none where the lab has no spec move), and a student cannot choose it."""
    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.lab.classrig import encode_answer

    tokens = tmp_path / "tokens.json"
    tokens.write_text("{}")
    svc = ClassRigService(TokenFile(tokens), tmp_path / "log.jsonl", key=KEY, profile=profile)
    st = _Student(svc, "s000", lab)
    seen = []
    real = st.rig.run_move

    def run_move(*args, **kw):
        seen.append(kw)
        return real(*args, **kw)

    st.rig.run_move = run_move
    g = discrete_pole_placement_pid(st.truth["K"], st.truth["tau"], 4.0, 1.0, Ts=0.005)
    move = {"kind": "sine_jerk", "distance": 0.5, "max_jerk": 500.0}
    move |= {"max_accel": 20.0, "max_velocity": 3.0}
    req = {"op": "run_move", "name": "m", "profile": move, "gains": encode_answer(g)}
    try:
        assert st.handle(req | {"run": {"settle": 0.1}})["ok"]
        stop = lab_spec(lab, profile).get("stop_error")
        assert seen[-1].get("max_error") == stop and (stop is None) == (lab == 1)
        if lab == 2:
            assert stop == 1.375
        with pytest.raises(ValueError, match="run may hold only"):
            st.handle(req | {"run": {"max_error": 100.0}})
    finally:
        st.close()
