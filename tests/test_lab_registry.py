"""The lab's checks as pure functions: one table (jerklab.lab.registry), plain evidence in, a
verdict out, the same whether the evidence comes from the session or from JSON.

Independent references: the check names each worksheet master actually calls (read from the
notebooks), and the session's own verdict for the same answer.
"""

from __future__ import annotations

import inspect
import json
import re

import nbformat
import numpy as np
import pytest
from _labnb import lab_env  # noqa: F401  (autouse: instructor key, work folders)

from jerklab import lab
from jerklab.lab import checks, registry, ringing
from jerklab.lab.checkbase import Missing
from jerklab.lab.grade import master_path
from jerklab.lab.motors import hidden_truth, motor_from_truth, student_motor
from jerklab.lab.plain import Evidence, Run


@pytest.mark.parametrize("n", sorted(registry.LABS))
def test_the_table_lists_exactly_what_each_worksheet_checks(n):
    nb = nbformat.read(master_path(n), as_version=4)
    code = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
    asked = list(dict.fromkeys(re.findall(r'S\.verify\("([A-Za-z_0-9]+)"', code)))
    assert asked and sorted(asked) == sorted(registry.checks_of(n))


def test_every_check_is_a_function_of_answer_evidence_and_truth():
    for (n, name), fn in registry.CHECKS.items():
        assert list(inspect.signature(fn).parameters) == ["answer", "evidence", "truth"], name
        home = {4: "jerklab.lab.ringing", 5: "jerklab.lab.ownlaw"}.get(n, "jerklab.lab.checks")
        assert fn.__module__ == home, name
    assert not hasattr(checks, "CHECKS") and not hasattr(ringing, "_check")
    with pytest.raises(KeyError, match="lab 3 has no check named 'tau'.*lost_time"):
        registry.check_function(3, "tau")


def test_a_check_gives_the_same_verdict_on_evidence_that_crossed_json(tmp_path):
    S = lab.start(1, student="plain1", folder=tmp_path)
    try:
        for V in (6.0, 3.0):
            S.step(V, lab.STEP_SECONDS)
        assert S.mode == "instructor"  # the test's key is in this process
        truth = hidden_truth(student_motor("plain1"))
        ev = S.evidence()
        back = Evidence.from_dict(json.loads(json.dumps(ev.to_dict())))
        assert (
            set(back.runs) == {"step_p6V", "step_p3V"} and back.counts_per_rev == ev.counts_per_rev
        )
        for k in ("time", "reference", "position", "voltage", "flags"):
            np.testing.assert_array_equal(
                getattr(back.runs["step_p6V"], k), getattr(ev.runs["step_p6V"], k)
            )
        for answer in (truth["tau"] * 1.02, truth["tau"] * 1.5, truth["tau"] * 1000):
            direct = registry.run_check(1, "tau", answer, ev, truth)
            crossed = registry.run_check(1, "tau", answer, back, json.loads(json.dumps(truth)))
            session = S.verify("tau", answer)
            assert direct.ok == crossed.ok == session.ok
            assert direct.message == crossed.message == session.message
        fit = registry.run_check(1, "fit_valid", 80.0, back, None)  # a real rig: no truth
        assert not fit.ok and "beyond the tolerance (1.5 points)" in fit.message
    finally:
        S.close()


def test_a_missing_recording_is_named():
    truth = {"K": 30.0, "tau": 0.03, "coulomb_friction": 0.3, "offset": 0.0}
    with pytest.raises(Missing, match="'step_p6V' is missing"):
        registry.run_check(1, "fit_valid", 90.0, Evidence(), truth)
    with pytest.raises(Missing, match="gap needs your model.*check `model` first"):
        registry.run_check(2, "gap", (0.9, 0.5), Evidence(), truth)


def test_the_truth_rebuilds_the_hidden_motor():
    for plant in ("rigid", "flexible"):
        m = student_motor("rebuild", plant=plant)
        again = motor_from_truth(json.loads(json.dumps(hidden_truth(m))))
        assert type(again) is type(m) and hidden_truth(again) == hidden_truth(m)
        x = np.zeros(m.n_states if hasattr(m, "n_states") else 2)
        np.testing.assert_array_equal(m.step_state(x, 6.0, 0.01), again.step_state(x, 6.0, 0.01))


def test_run_refuses_ragged_arrays():
    with pytest.raises(ValueError, match="position has 2 samples"):
        Run([0.0, 0.005, 0.01], [0, 0, 0], [0, 0], [0, 0, 0], [0, 0, 0], 0.005)
    with pytest.raises(ValueError, match="Ts"):
        Run([0.0], [0], [0], [0], [0], 0.0)
