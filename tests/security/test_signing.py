"""Recordings that claim the class rig service, against the grader (signed recordings).

The same attacks as ``python -m benchmarks security recordings``
(:mod:`benchmarks.attacks_recordings`): served recordings from a real class rig service, handed
in unchanged, with one count edited (consistently, signature kept), and forged (a step of the
student's own virtual rig labelled graded, carrying a served signature); and a forged one in a
worksheet's export. Each fails on the grader before signed recordings (no signature, no
``recordings`` column, every exported run kept).
"""

from __future__ import annotations

import json

import pytest

from benchmarks.attacks_recordings import (
    KEY,
    STUDENT,
    export_doc,
    forged,
    recordings_class,
    served_recordings,
)


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    return recordings_class(tmp_path_factory.mktemp("recordings"))


def test_honest_served_recordings_verify(rows):
    row = rows["lab1_honest.zip"]
    assert row["recordings"] == "signed: 2 verified"
    assert "signature" not in row["flags"]


def test_one_value_edited_in_a_served_recording_is_flagged(rows):
    row = rows["lab1_edited.zip"]
    assert row["recordings"] == "rejected: step_p6V"  # the unedited step_p3V verifies
    assert "fail their signature: step_p6V" in row["flags"]


def test_forged_recording_claiming_graded_is_flagged(rows):
    row = rows["lab1_forged.zip"]
    assert row["recordings"] == "rejected: step_p6V"
    assert "fail their signature: step_p6V" in row["flags"]


def test_forged_recording_in_the_export_does_not_reach_the_checks(tmp_path):
    from jerklab.lab.grade import _evidence_of

    served = served_recordings(tmp_path / "served")
    meta = json.loads(served["step_p6V"].with_suffix(".json").read_text())
    assert meta["signature"]["student"] == STUDENT and meta["signature"]["lab"] == 1
    doc = export_doc(served, forged(meta["signature"], tmp_path / "forge" / "step_p6V"))
    rejected = []
    ev, notes = _evidence_of(doc, {}, (KEY.encode(), STUDENT, 1), rejected)
    assert sorted(ev.runs) == ["step_p3V"] and rejected == ["step_p6V"]
    assert any("step_p6V" in n and "left out" in n for n in notes)
    # another student's key check: the same export graded as bob keeps neither
    rejected = []
    ev, _ = _evidence_of(doc, {}, (KEY.encode(), "bob", 1), rejected)
    assert ev.runs == {} and sorted(rejected) == ["step_p3V", "step_p6V"]
