"""Lab 4, "Stop the ringing" (in the format of labs 1-3): the worksheet headless
with its solutions (every check passes, in under 2 minutes, no true value in the output) and with
wrong answers (each check fails with its hint); the student version is generated and current;
the flexible students' hidden modes; the helper that estimates the load's motion."""

from __future__ import annotations

import math
import time
from pathlib import Path

import nbformat
import numpy as np
import pytest
from _labnb import KEY, lab_env  # noqa: F401  (lab_env: autouse fixture)
from _labnb import answered as _answered
from _labnb import execute as _execute
from _labnb import outputs as _outputs
from _labnb import set_student as _set_student
from _labnb import verdicts as _verdicts

from jerklab import lab
from jerklab.lab.motors import coupled_mode, motor_from_truth, student_motor
from jerklab.lab.motors import hidden_truth as _truth
from jerklab.lab.ringing import MISTAKES4

ROOT = Path(__file__).parent.parent


def _leaks(motor):
    t = _truth(motor)
    pats = set()
    for v in (
        t["K"],
        t["tau"],
        t["mode_hz"],
        t["mode_zeta"],
        motor.mode_frequency,
        motor.mode_damping,
        motor.mode_frequency / (2 * math.pi),
    ):
        pats.add(repr(v))
        for d in (5, 6, 7):
            pats.add(f"{v:.{d}g}")
    return pats


def test_lab4_with_solutions_passes_every_check_quickly(tmp_path):
    """The student version with every answer typed in: one check cell per question, all ✔."""
    nb = _answered(4)
    _set_student(nb, "sol4")
    t0 = time.monotonic()
    _execute(nb, tmp_path)
    elapsed = time.monotonic() - t0
    outs = _outputs(nb)
    errors = [o for o in outs if o.startswith("ERROR")]
    assert not errors, errors
    shown = _verdicts(nb)
    names = [v[0] for v in shown]
    assert len(names) == len(set(names)) and sorted(names) == sorted(lab.registry.checks_of(4))
    assert all(ok for _, ok, _ in shown), [v for v in shown if not v[1]]
    blob = "\n".join(outs)
    for pat in _leaks(student_motor("sol4", plant="flexible")):
        assert pat not in blob, f"true value {pat} in the notebook's output"
    assert elapsed < 120, f"lab 4 took {elapsed:.0f} s headless (limit 2 min)"


#: (a line of the typed answer, the wrong answer a student computes instead, the check, its hint)
WRONG4 = [
    (
        "mode = (fit.frequency_hz, fit.damping)",
        "_wrong_mode = (2 * np.pi * fit.frequency_hz, fit.damping)",
        "mode",
        MISTAKES4["mode_rad"].hint,
    ),
    (
        "zv_delay = float(zv.times[-1])",
        "_wrong_zv_delay = float(zvd.times[-1])",
        "zv_delay",
        MISTAKES4["zv_period"].hint,
    ),
    (
        'residual_pct = {k: 100 * amp[k] / amp["none"] for k in ("zv", "zvd", "ei")}',
        '_wrong_residual_pct = {k: amp[k] / amp["none"] for k in ("zv", "zvd", "ei")}',
        "residual_pct",
        MISTAKES4["residual_fraction"].hint,
    ),
    (
        "float(sh.residual_vibration((1 - lab.MODE_DRIFT) * f, z))",
        "_wrong_robust = {k: float(sh.residual_vibration(f, z)) "
        'for k, sh in (("zv", zv), ("zvd", zvd), ("ei", ei))}',
        "robust",
        "at the design frequency",
    ),
    ('choice = "ei"', '_wrong_choice = "zv"', "choice", "a fifth of the vibration"),
]


def test_lab4_wrong_answers_get_their_hints(tmp_path):
    """Each wrong answer in turn, in one execution: just before its check cell the answer is
    swapped for the wrong one, and swapped back after it for the cells that follow."""
    nb = _answered(4)
    _set_student(nb, "wrong4")
    for old, wrong, name, hint in WRONG4:
        hits = [c for c in nb.cells if c.cell_type == "code" and old in c.source]
        assert len(hits) == 1, old
        hits[0].source = hits[0].source + "\n" + wrong
        i = next(
            i
            for i, c in enumerate(nb.cells)
            if c.cell_type == "code" and c.source.strip() == f'grader.check("{name}")'
        )
        nb.cells[i + 1 : i + 1] = [nbformat.v4.new_code_cell(f"{name} = _right_{name}")]
        nb.cells[i:i] = [
            nbformat.v4.new_code_cell(f"_right_{name}, {name} = {name}, _wrong_{name}")
        ]
    cut = max(
        i
        for i, c in enumerate(nb.cells)
        if c.cell_type == "code" and c.source.startswith("grader.check(")
    )
    nb.cells = nb.cells[: cut + 2]
    _execute(nb, tmp_path)
    outs = _outputs(nb)
    assert not [o for o in outs if o.startswith("ERROR")]
    shown = {k: (ok, text) for k, ok, text in _verdicts(nb)}
    for _, _, name, hint in WRONG4:
        ok, text = shown[name]
        assert not ok and hint in text, (name, text)


def test_lab4_mistakes_without_runs_get_their_hints():
    """The mistakes of lab 4 that need no recording, given to the checks with the truth."""
    from jerklab.lab.plain import Evidence
    from jerklab.lab.registry import run_check

    m = student_motor("hints4", plant="flexible")
    f, z = coupled_mode(m)
    t = _truth(m)
    cases = {
        "pre_zv_period": ("pre_zv_delay", 0.1),
        "mode_rad": ("mode", (2 * math.pi * f, z)),
        "mode_zeta_percent": ("mode", (f, 100 * z)),
        "zv_period": ("zv_delay", 1.0 / (f * math.sqrt(1 - z * z))),
    }
    for key, (name, answer) in cases.items():
        assert MISTAKES4[key].check == name
        res = run_check(4, name, answer, Evidence(), t)
        assert not res.ok and MISTAKES4[key].hint in res.message, (key, res)


def test_lab4_student_version_is_generated_and_current(tmp_path):
    from jerklab.lab.grade import assign

    (p,) = assign(tmp_path, labs=(4,))
    committed = nbformat.read(ROOT / "notebooks" / "labs" / p.name, as_version=4)
    fresh = nbformat.read(p, as_version=4)
    assert [c.source for c in committed.cells] == [c.source for c in fresh.cells]
    text = "\n".join(c.source for c in fresh.cells)
    assert "SOLUTION" not in text and "BEGIN TESTS" not in text
    assert "choice = ..." in text and "pre_zv_delay = ..." in text
    code = "\n".join(c.source for c in fresh.cells if c.cell_type == "code")
    for solution in (
        "fit = shaping.identify_mode",
        "zv = shaping.input_shaper",
        "residual_pct = {k:",
    ):
        assert solution not in code
    assert committed.metadata["jerklab"]["lab"] == 4
    assert all(not c.get("outputs") for c in committed.cells if c.cell_type == "code")


def test_flexible_modes_in_range_and_distinct():
    modes = [coupled_mode(student_motor(f"s{i}", plant="flexible")) for i in range(30)]
    f = np.array([m[0] for m in modes])
    z = np.array([m[1] for m in modes])
    assert len(set(np.round(f, 6))) == 30
    assert f.min() > 5.0 and f.max() < 17.0 and z.min() > 0.02 and z.max() < 0.2
    # same ID, same mode; the key enters the seed (the autouse fixture's key vs another)
    assert coupled_mode(student_motor("s1", plant="flexible")) == modes[1]
    assert coupled_mode(student_motor("s1", key=b"other", plant="flexible")) != modes[1]


def test_load_deflection_matches_the_virtual_rigs_load():
    """lab.load_deflection (the model driven by the recorded volts) against the virtual rig's
    own state: the same load motion when the model is the rig's motor."""
    import warnings

    from jerklab.planner import plan_sine_jerk

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rig = lab.connect_student("defl", plant="flexible", progress=False)
        hidden = student_motor("defl", plant="flexible")
    dev = rig.link.device
    dev.compute_delay = 0.0  # each PWM held over its whole sample, as load_deflection assumes
    log = []
    tick = dev.tick

    def logged():
        log.append(dev.x[2] - dev.x[0])  # the state at the sample, before the period
        tick()

    dev.tick = logged
    rec = rig.run_move(
        plan_sine_jerk(**lab.MOVE4), lab.soft_gains(), path=False, settle=0.3, force=True
    )
    rig.close()
    est = lab.load_deflection(hidden.ideal(), rec)
    true = np.array(log[: len(rec)])
    assert np.max(np.abs(est - true)) < 1e-9 + 1e-6 * np.max(np.abs(true))
    amp = lab.residual_amplitude(rec, est)
    assert 0 < amp < np.max(np.abs(est))
    with pytest.raises(ValueError, match="settling"):
        lab.residual_amplitude(_NoSettle(rec), est)


class _NoSettle:
    """A recording-like object without settling samples."""

    def __init__(self, rec):
        self.flags = np.zeros(len(rec), dtype=int)
        self.metadata = rec.metadata


def test_lab4_session_on_simavr_finds_the_students_mode(tmp_path):
    """The worksheet's calls on the firmware in a simulated Uno driving the student's two-mass
    load: the PRBS finds the hidden mode, the check says right, a ZV-shaped move completes."""
    from conftest import require_simavr

    require_simavr()
    from jerklab import shaping
    from jerklab.planner import plan_sine_jerk

    S = lab.start(4, student="sim4", port="simavr", folder=tmp_path)
    try:
        assert S.plant == "flexible" and S.rig.is_virtual
        rp = S.record_prbs(**lab.PRBS_MODE)
        assert rp.metadata["status"] == "complete" and rp.metadata["lost_samples"] == 0
        fit = shaping.identify_mode(rp.voltage, rp.position, rp.metadata["Ts"])
        assert S.verify("mode", (fit.frequency_hz, fit.damping)).ok
        S.set_model(fit.params["K"], fit.params["tau"])
        S.set_shaper(shaping.input_shaper("zv", fit.frequency_hz, fit.damping))
        rec = S.run_move(
            plan_sine_jerk(**lab.MOVE4), lab.soft_gains(), name="move_zv", settle=0.3, force=True
        )
        assert rec.metadata["status"] == "complete" and rec.metadata["shaper"]["delays"][0] == 0
    finally:
        S.close()


def test_grade_command_scores_lab4(tmp_path):
    """`python -m jerklab.lab grade` on two lab 4 submissions (the autograder's notebook with
    its solutions, and the same with a wrong choice): 13/13 and 12/13, each against its own
    student's hidden mode."""
    import csv

    from jerklab.lab.__main__ import main
    from jerklab.lab.grade import _assigned, student_version_name

    subs = tmp_path / "subs"
    subs.mkdir()
    for sid, wrong in (("gina", False), ("hal", True)):
        nb = nbformat.read(_assigned(4) / "autograder" / student_version_name(4), as_version=4)
        _set_student(nb, sid)
        if wrong:
            hits = [
                c for c in nb.cells if c.cell_type == "code" and c.source.startswith("choice = ")
            ]
            assert len(hits) == 1
            hits[0].source = 'choice = "zv"'
        nbformat.write(nb, subs / f"{sid}_lab4.ipynb")
    out = tmp_path / "grades.csv"
    assert main(["grade", str(subs), "--out", str(out), "--timeout", "300"]) == 0
    rows = {r["student"]: r for r in csv.DictReader(out.open())}
    assert (
        rows["gina"]["status"] == "graded"
        and float(rows["gina"]["total"]) == float(rows["gina"]["max"]) == 13.0
    )
    assert float(rows["hal"]["total"]) == 12.0 and float(rows["hal"]["choice"]) == 0.0


def test_the_mode_check_accepts_the_fit_of_the_students_own_record(tmp_path):
    """One PRBS record pins a lightly damped mode's ζ down only so far: when the answer is the
    fit of the student's own record (the checker fits it again) and f is right, ``mode`` passes
    however far that record's ζ lies from the hidden one, and says so; a ζ that is neither near
    the hidden one nor the record's fit still fails, and so does the record's fit when the
    record is not in the evidence. (The hidden mode is moved here so that the record's ζ is
    1.8 times off it; on the micro gearmotor's stiffest load one record in five was 30 % off.)"""
    from jerklab import shaping
    from jerklab.lab.plain import Evidence
    from jerklab.lab.registry import run_check

    S = lab.start(4, student="own4", folder=tmp_path)
    try:
        S.record_prbs(**lab.PRBS_MODE)
        ev = S.evidence()
    finally:
        S.close()
    r = ev.runs["prbs"]
    fit = shaping.identify_mode(r.voltage, r.position, r.Ts)
    t = _truth(student_motor("own4", plant="flexible"))  # the session's hidden motor
    far = dict(t)
    for _ in range(20):  # the shaft damping that puts the coupled ζ at the record's / 1.8
        f, z = coupled_mode(motor_from_truth(far))
        far["mode_damping"] *= fit.damping / 1.8 / z
    f, z = coupled_mode(motor_from_truth(far))
    assert abs(fit.frequency_hz / f - 1) < 0.03 and abs(fit.damping - z) > 0.3 * z
    own = run_check(4, "mode", (fit.frequency_hz, fit.damping), ev, far)
    assert own.ok and "fit of your own PRBS record" in own.message, own
    off = run_check(4, "mode", (fit.frequency_hz, 1.4 * fit.damping), ev, far)
    assert not off.ok and "ζ" in off.message, off
    bare = run_check(4, "mode", (fit.frequency_hz, fit.damping), Evidence(), far)
    assert not bare.ok, bare
    # the hidden mode itself stays right, with or without the record
    assert run_check(4, "mode", (f, z), Evidence(), far).ok
