"""Faults around the tuning panel and the class page: unstable designs, bad student IDs,
a rig or broker that is not there."""

from __future__ import annotations

import re
import socket

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from jerklab import tuning
from jerklab import widgets as W


class RecordingRig:
    """Stands in for a rig: records calls, never moves anything."""

    def __init__(self):
        self.calls = []

    def run_move(self, *args, **kwargs):
        self.calls.append((args, kwargs))
        raise AssertionError("an unstable design reached the rig")


def test_panel_refuses_an_unstable_design_and_says_why():
    """ωn 35, Ts 11 ms, z-domain design: 'max |error| = 142199.34 mrad' without a word."""
    rig = RecordingRig()
    p = W.pole_placement_panel(rig=rig, design="z-domain", wn=35.0, Ts=0.011)
    assert p.result.level == "unstable"
    assert p.rig_button.disabled
    msg = p.rig_status.value
    assert re.search(r"\|z\| = 1\.17\d ≥ 1", msg) and "direct z-domain design" in msg
    # the advice offers what helps for this design, never the design itself as the fix
    assert "What would help (checked)" in msg and "z-domain design with derivative filter" in msg
    assert "the direct z-domain design (" not in msg
    with pytest.raises(tuning.UnstableDesignError, match="direct z-domain"):
        p.run_on_rig()
    assert rig.calls == []
    # a stable setting enables the button again
    p.controls["design"].value = "z-domain-filter"
    assert p.result.stable and not p.rig_button.disabled and p.rig_status.value == ""


def test_forced_unstable_run_is_stopped_by_the_rig_and_shown():
    """force=True passes the panel's refusal; the rig's own safety stop then ends the run."""
    from jerklab.rig import RigRunError, connect

    p = W.pole_placement_panel(rig=connect(progress=False), design="z-domain", wn=35.0, Ts=0.011)
    with pytest.raises(RigRunError, match="tracking error"):
        p.run_on_rig(force=True)
    status = p.rig_status.value
    assert "rig error" in status and "tracking error" in status, status
    assert p.rig_button.disabled  # still refused for the button


def test_unstable_banner_never_recommends_the_selected_design():
    for design in tuning.DESIGN_NAMES:
        for wn, Ts in ((60.0, 0.005), (35.0, 0.011), (25.0, 0.020)):
            p = W.pole_placement_panel(design=design, wn=wn, Ts=Ts)
            if p.result.level == "ok":
                continue
            assert f"the {tuning.DESIGN_NAMES[design]} (" not in p.status.value
            # no emoji, no debug timing line
            assert not re.search("[\u2600-\u27bf\U0001f300-\U0001faff]", p.status.value)
            assert "redraw" not in p.status.value
            assert not any("timing" in " ".join(c._dom_classes) for c in p.children)


def test_panel_designs_for_a_given_motor_and_exposes_gains():
    """pole_placement_panel(K=..., tau=...) and panel.gains for the rig cell."""
    from jerklab.controller import DiscreteGains
    from jerklab.plant import DCMotor
    from jerklab.rig import connect

    K, tau = 27.5, 0.034
    p = W.pole_placement_panel(K=K, tau=tau, wn=25.0)
    # Stojčić eq. 11 then eq. 13, written out here
    wn, z, s, Ts = 25.0, 1.0, 175.0, 0.005
    kp, ki, kd = (
        wn * tau * (2 * z * s + wn) / K,
        tau * s * wn**2 / K,
        (tau * (2 * z * wn + s) - 1) / K,
    )
    g = p.gains
    assert isinstance(g, DiscreteGains) and g.Ts == Ts
    assert (g.kpd, g.kid, g.kdd) == pytest.approx((kp - ki * Ts / 2, ki * Ts, kd / Ts), rel=1e-12)
    # the gains go straight to a rig with that motor, and track the move
    rig = connect(progress=False, device=DCMotor(K=K, tau=tau))
    rig.set_model(K, tau)
    rec = rig.run_move(tuning.move_profile(), p.gains, Ts=p.gains.Ts, path=False)
    assert rec.metadata["status"] == "complete"
    assert abs(rec.position[-1] - tuning.DEFAULT_MOVE["distance"]) < 3 * 2 * 3.14159 / 448


WINDOWS_BAD = re.compile(r'[<>:"/\\|?*\x00-\x1f]')


@given(st.text(min_size=1, max_size=80))
@example("CON")
@example("nul.txt")
@example("..")
@example("  Ana Stojčić  ")
@example("a/b")
def test_student_id_is_a_valid_windows_folder_name(raw):
    try:
        name = W.sanitize_student_id(raw)
    except ValueError:
        assert not raw.strip()
        return
    assert name and not WINDOWS_BAD.search(name) and re.fullmatch(r"[A-Za-z0-9._-]+", name)
    assert not name.endswith((".", " ")) and name not in (".", "..")
    assert name.split(".")[0].upper() not in W._WINDOWS_RESERVED
    assert len(name) <= 64


def test_student_ids_do_not_collide():
    ids = ["a/b", "a_b", "a b", "a:b", "Stojčić", "Stojcic", "CON", "_CON"]
    names = [W.sanitize_student_id(i) for i in ids]
    assert len(set(names)) == len(ids), names
    assert W.sanitize_student_id("s1234") == "s1234"  # a plain ID is kept as is
    with pytest.raises(ValueError, match="student_id"):
        W.sanitize_student_id("   ")
    with pytest.raises(TypeError, match="student_id"):
        W.sanitize_student_id(1234)


def test_page_with_unreachable_broker_says_why():
    from jerklab.app import panel_for_page

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    box = panel_for_page(rig_port=f"broker://127.0.0.1:{port}")
    notice = box.children[0]
    assert "No rig behind this page" in notice.value and "broker" in notice.value
    assert isinstance(box.children[1], W.PolePlacementPanel)


def test_run_without_student_id_is_refused(tmp_path):
    rig = RecordingRig()
    p = W.pole_placement_panel(rig=rig, student=True, recordings=tmp_path)
    assert p.rig_button.disabled and "student ID" in p.rig_status.value
    with pytest.raises(ValueError, match="student_id"):
        p.run_on_rig()
    assert rig.calls == [] and not any(tmp_path.iterdir())
