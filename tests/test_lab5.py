"""Lab 5, "Your own law" (in the format of labs 1-4): the worksheet headless with its solutions
(every check passes, no true value in the output), with a wrong answer per check (each fails with
its hint: a law whose anti-windup is reversed is named by check_match), the student version
unanswered (it runs, no check passes), and the committed student version is the generated one."""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import nbformat
import pytest
from _labnb import KEY, lab_env  # noqa: F401  (lab_env: autouse fixture)
from _labnb import answered as _answered
from _labnb import execute as _execute
from _labnb import outputs as _outputs
from _labnb import set_student as _set_student
from _labnb import verdicts as _verdicts

from jerklab import lab
from jerklab.lab.motors import hidden_truth as _truth
from jerklab.lab.motors import student_motor
from jerklab.lab.ownlaw import MISTAKES5

ROOT = Path(__file__).parent.parent

#: the anti-windup's test in the worksheet's law, and the same reversed (freeze while the error
#: pulls out of the clamp)
AW = "(u > self.limit and e > 0) or (u < -self.limit and e < 0)"
AW_REVERSED = "(u > self.limit and e < 0) or (u < -self.limit and e > 0)"


def _leaks(motor):
    t = _truth(motor)
    pats = set()
    for v in (t["K"], t["tau"], t["coulomb_friction"], 1e3 * t["tau"]):
        pats.add(repr(v))
        for d in (6, 7):
            pats.add(f"{v:.{d}g}")
    return pats


def _check_cell(nb, name):
    return next(
        i
        for i, c in enumerate(nb.cells)
        if c.cell_type == "code" and c.source.strip() == f'grader.check("{name}")'
    )


def test_lab5_with_solutions_passes_every_check(tmp_path):
    """The student version with every answer typed in: one check cell per question, all ✔;
    the master's law and the board's own stay within the bound; no true value printed."""
    nb = _answered(5)
    _set_student(nb, "sol5")
    t0 = time.monotonic()
    _execute(nb, tmp_path)
    elapsed = time.monotonic() - t0
    outs = _outputs(nb)
    assert not [o for o in outs if o.startswith("ERROR")]
    shown = _verdicts(nb)
    names = [v[0] for v in shown]
    assert len(names) == len(set(names)) and sorted(names) == sorted(lab.registry.checks_of(5))
    assert all(ok for _, ok, _ in shown), [v for v in shown if not v[1]]
    blob = "\n".join(outs)
    for pat in _leaks(student_motor("sol5")):
        assert pat not in blob, f"true value {pat} in the notebook's output"
    assert elapsed < 60, f"lab 5 took {elapsed:.0f} s headless (limit 1 min)"


@pytest.mark.simavr
def test_lab5_runs_unchanged_on_the_simulated_uno(tmp_path):
    """The same answered worksheet with ``RIG = "simavr"``: the firmware on a simulated Uno closes
    the loop through the host (HOST_LOOP) and runs the board's own law. Every cell runs and the
    checks whose answers do not depend on the host's timing pass (pre-lab, the law's gains, the
    variant); the host loop's runs are complete. ``match`` is reported, not asserted here: its
    distance grows with the answers that come late on a loaded machine (7 and 15 counts against
    the bound of 20 on two motors, 7 and 33 of 172 answers late, on the suite's shared cores)."""
    from conftest import require_simavr

    require_simavr()
    nb = _answered(5)
    _set_student(nb, "sim5")
    hits = 0
    for c in nb.cells:
        if c.cell_type == "code" and c.source.startswith("RIG = None"):
            c.source = c.source.replace("RIG = None", 'RIG = "simavr"', 1)
            hits += 1
    assert hits == 1
    _execute(nb, tmp_path)
    outs = _outputs(nb)
    assert not [o for o in outs if o.startswith("ERROR")], [o for o in outs if "ERROR" in o][:3]
    blob = "\n".join(outs)
    assert "firmware on a simulated Uno" in blob
    shown = {name: (ok, text) for name, ok, text in _verdicts(nb)}
    assert sorted(shown) == sorted(lab.registry.checks_of(5))
    for name in ("pre_ff", "pre_delay", "law", "variant"):
        assert shown[name][0], (name, shown[name][1], shown["match"])
    assert re.search(r"largest distance \d+ counts \(bound \d+\)", blob), shown["match"]


#: (a line of the typed answer, the wrong answer computed instead, the check, its hint)
WRONG5 = [
    (
        "pre_ff = (0.025 * 200 + 10) / 32.4",
        "_wrong_pre_ff = 10 / 32.4",
        "pre_ff",
        "pre_ff_no_accel",
    ),
    ("pre_delay = 10.0", "_wrong_pre_delay = 0.0", "pre_delay", "pre_delay_board"),
    (
        'law = {"kpd": gains.kpd',
        "_c = pole_placement_pid(K_hat, tau_hat, S.spec['design_wn'], S.spec['zeta'])\n"
        '_wrong_law = {**law, "kid": _c.ki, "kdd": _c.kd}',
        "law",
        "law_continuous",
    ),
    (
        "match = float(np.max(",
        # the same run with the anti-windup reversed, as the student's "mine"
        None,
        "match",
        "match_aw_reversed",
    ),
    (
        'variant = {"law": "pd"',
        '_wrong_variant = {**variant, "law": "p"}',
        "variant",
        None,
    ),
]


def test_lab5_wrong_answers_get_their_hints(tmp_path):
    """Each wrong answer in turn, in one execution: just before its check cell the answer is
    swapped for the wrong one (for ``match``: the student's law with its anti-windup reversed,
    run through the host loop as ``mine``), and swapped back after it."""
    nb = _answered(5)
    _set_student(nb, "wrong5")
    (law_cell,) = [c for c in nb.cells if c.cell_type == "code" and "class OwnLaw" in c.source]
    assert AW in law_cell.source
    reversed_law = (
        law_cell.source.replace("class OwnLaw", "class _Reversed").replace(AW, AW_REVERSED)
        + "\n_m = S.host_loop(_Reversed(gains, u_ff, limit), Ts=Ts, duration=(n - 1) * Ts, "
        'reference=move, name="mine", max_voltage=limit, max_error=S.spec["max_error"], '
        "max_misses=50)\n"
        "_k = min(len(_m), len(board))\n"
        "_wrong_match = float(np.max(np.abs(np.asarray(_m.counts[:_k]) - "
        "np.asarray(board.counts[:_k]))))"
    )
    for old, wrong, name, _ in WRONG5:
        hits = [c for c in nb.cells if c.cell_type == "code" and old in c.source]
        assert len(hits) == 1, old
        i = _check_cell(nb, name)
        # the right answer back, and its verdict: a later check uses an answer whose check passed
        restore = f"{name} = _right_{name}\n_ = S.verify({name!r}, {name})"
        nb.cells[i + 1 : i + 1] = [nbformat.v4.new_code_cell(restore)]
        nb.cells[i:i] = [
            nbformat.v4.new_code_cell(reversed_law if wrong is None else wrong),
            nbformat.v4.new_code_cell(f"_right_{name}, {name} = {name}, _wrong_{name}"),
        ]
    nb.cells = nb.cells[: _check_cell(nb, "variant") + 2]
    _execute(nb, tmp_path)
    outs = _outputs(nb)
    assert not [o for o in outs if o.startswith("ERROR")], [o for o in outs if "ERROR" in o]
    shown = {k: (ok, text) for k, ok, text in _verdicts(nb)}
    for _, _, name, key in WRONG5:
        ok, text = shown[name]
        words = MISTAKES5[key].hint if key else "the run's voltages are those of the 'pd' law"
        assert not ok and words in text, (name, text)


def test_lab5_unanswered_student_version_runs_headless(tmp_path):
    """The committed student version as handed out, no answer typed in: the set-up and the given
    cells run (the virtual rig, the model), and no check passes."""
    nb = nbformat.read(ROOT / "notebooks" / "labs" / "lab5_ownlaw.ipynb", as_version=4)
    _set_student(nb, "blank5")
    nb.cells = [c for c in nb.cells if not (c.cell_type == "code" and "S.submit(" in c.source)]
    _execute(nb, tmp_path)
    code = [c for c in nb.cells if c.cell_type == "code"]
    setup = next(c for c in code if "lab.start(5" in c.source)
    model = next(c for c in code if "sweep_fit" in c.source)
    for c in (setup, model):
        assert not [o for o in c.outputs if o.output_type == "error"], c.source[:60]
    assert "Lab 5 (ownlaw)" in "\n".join(o.get("text", "") for o in setup.outputs)
    shown = _verdicts(nb)
    assert sorted(k for k, _, _ in shown) == sorted(lab.registry.checks_of(5))
    assert not [k for k, ok, _ in shown if ok]


def test_lab5_student_version_is_generated_and_current(tmp_path):
    from jerklab.lab.grade import assign

    (p,) = assign(tmp_path, labs=(5,))
    committed = nbformat.read(ROOT / "notebooks" / "labs" / p.name, as_version=4)
    fresh = nbformat.read(p, as_version=4)
    assert [c.source for c in committed.cells] == [c.source for c in fresh.cells]
    text = "\n".join(c.source for c in fresh.cells)
    assert "SOLUTION" not in text and "BEGIN TESTS" not in text
    assert "pre_ff = ..." in text and "pre_delay = ..." in text
    code = "\n".join(c.source for c in fresh.cells if c.cell_type == "code")
    for solution in ("e = r - y", "law = {", "match = float(", "changed = S.host_loop("):
        assert solution not in code
    assert committed.metadata["jerklab"]["lab"] == 5
    assert all(not c.get("outputs") for c in committed.cells if c.cell_type == "code")


@pytest.mark.parametrize("profile", ["paper", "pololu-37d-30"])
def test_lab5_move_needs_less_than_the_supply_on_every_corner(profile):
    """Stojčić eq. 16 over lab 5's move on the corners of the profile's motors (the model the
    firmware runs, independent of the spec's fractions): the clamp f_c + max|u_F| it sets stays
    below the supply, so the host loop's voltages are never the supply's."""
    import numpy as np

    from jerklab.lab.specs import hidden_ranges, lab_spec
    from jerklab.planner import plan_sine_jerk
    from jerklab.rig import load_profile

    spec = lab_spec(5, profile)
    move = plan_sine_jerk(**spec["move"])
    s = move.sample(np.arange(0.0, move.duration, spec["Ts"]))
    R = hidden_ranges(profile)
    V = load_profile(profile).supply_voltage
    for K in R["K"]:
        for tau in R["tau"]:
            peak = np.max(np.abs(tau * np.asarray(s.accel) + np.asarray(s.velocity))) / K
            assert R["coulomb_friction"][1] + spec["limit_share"] * peak < V / 2, (K, tau)
    assert math.isclose(move.sample(move.duration).position, 2 * math.pi, rel_tol=1e-9)


@pytest.mark.parametrize("lab_n", [5, 3])
def test_the_graders_rig_paces_a_host_loop_in_real_time(lab_n):
    """The rig ``grade`` serves a worksheet (a pty): for lab 5, whose law answers each tick from
    the worksheet's kernel, it runs in real time (speed 1), so a 0.3 s host loop takes its 0.3 s
    and a law that answers at once is (nearly) never late; for lab 3 (the board's own law
    only) it is unpaced (speed None), and the same loop runs as fast as the device computes."""
    from jerklab.lab.grade import _served_rig
    from jerklab.rig import connect

    server, _ = _served_rig("pace5", lab_n, KEY.encode())
    try:
        assert server.speed == (1.0 if lab_n == 5 else None)
        rig = connect(server.port, progress=False)
        try:
            t0 = time.monotonic()
            rec = rig.host_loop(lambda t, y, r: 0.0, Ts=0.01, duration=0.3, max_misses=255)
            wall = time.monotonic() - t0
        finally:
            rig.close()
    finally:
        server.close()
    assert rec.metadata["status"] == "complete"
    if lab_n == 5:  # 31 ticks in real time: a loaded machine may be late once or twice
        assert wall >= 0.28 and rec.metadata["misses"] <= 3, (wall, rec.metadata["misses"])
