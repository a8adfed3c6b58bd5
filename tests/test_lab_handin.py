"""A hand-in that cannot be silently empty (issue 33): ``S.submit`` refuses, saying what to do,
while STUDENT is the placeholder, when the saved notebook is older than the last cell run,
or when there are no answers; it hands in this session's recordings and those the student
names, not what earlier sessions left in the folder."""

from __future__ import annotations

import json
import os
import time
import zipfile

import nbformat
import pytest
from _labnb import execute, lab_env  # noqa: F401  (lab_env: autouse fixture)
from _labnb import outputs as _outputs

from jerklab import lab
from jerklab.lab.handin import PLACEHOLDER_STUDENT, HandinRefused, write_handin


def _notebook(path, student="s1", answered=True):
    """A saved worksheet: the STUDENT line and one answer cell (typed in, or still `...`)."""
    nb = nbformat.v4.new_notebook()
    nb.cells = [
        nbformat.v4.new_code_cell(f'STUDENT = "{student}"'),
        nbformat.v4.new_code_cell("pre_speed = 180" if answered else "pre_speed = ..."),
    ]
    nb.cells[1].metadata["tags"] = ["otter_answer_cell"]
    nbformat.write(nb, path)
    return path


def _names(zpath):
    with zipfile.ZipFile(zpath) as z:
        return set(z.namelist())


def test_placeholder_student_is_refused(tmp_path, capsys):
    S = lab.start(1, student=PLACEHOLDER_STUDENT, folder=tmp_path / "w")
    assert "Put your student ID in STUDENT" in capsys.readouterr().out
    S.verify("pre_speed", 180.0)
    nb = _notebook(tmp_path / "lab1_identify.ipynb", PLACEHOLDER_STUDENT)
    assert S.submit(nb, out=tmp_path / "out") is None
    msg = capsys.readouterr().out
    assert msg.startswith("✘ not handed in") and "placeholder" in msg and "student ID" in msg
    assert not (tmp_path / "out").exists()
    S.close()


def test_a_notebook_older_than_the_last_cell_is_refused(tmp_path):
    S = lab.start(1, student="s1", folder=tmp_path / "w")
    S.verify("pre_speed", 180.0)
    nb = _notebook(tmp_path / "lab1_identify.ipynb")
    old = time.time() - 60
    os.utime(nb, (old, old))  # saved a minute before the check ran
    with pytest.raises(HandinRefused, match="older file.*Save the notebook"):
        write_handin(S, nb, out=tmp_path / "out")
    os.utime(nb)  # saved now
    assert write_handin(S, nb, out=tmp_path / "out").is_file()
    S.close()


def test_no_answers_and_no_notebook_are_refused(tmp_path):
    S = lab.start(1, student="s1", folder=tmp_path / "w")
    nb = _notebook(tmp_path / "lab1_identify.ipynb")
    with pytest.raises(HandinRefused, match="no answer has been checked"):
        write_handin(S, nb, out=tmp_path / "out")
    S.verify("pre_speed", 180.0)
    with pytest.raises(HandinRefused, match="no notebook given"):
        write_handin(S, None, out=tmp_path / "out")
    with pytest.raises(HandinRefused, match="is not a file here"):
        write_handin(S, tmp_path / "nowhere.ipynb", out=tmp_path / "out")
    blank = _notebook(tmp_path / "blank.ipynb", answered=False)
    with pytest.raises(HandinRefused, match="has no answers"):
        write_handin(S, blank, out=tmp_path / "out")
    other = _notebook(tmp_path / "other.ipynb", student="s2")
    with pytest.raises(HandinRefused, match="names student 's2'"):
        write_handin(S, other, out=tmp_path / "out")
    S.close()


def test_only_this_sessions_recordings_or_those_named(tmp_path):
    work = tmp_path / "w"
    old = lab.start(1, student="s1", folder=work)
    old.step(-3.0, 0.1)
    old.step(3.0, 0.1)
    old.close()
    S = lab.start(1, student="s1", folder=work)
    S.step(6.0, 0.1)
    S.verify("pre_speed", 180.0)
    nb = _notebook(tmp_path / "lab1_identify.ipynb")
    rec = {n for n in _names(S.submit(nb, out=tmp_path / "a")) if n.startswith("recordings/")}
    assert rec == {"recordings/step_p6V.csv", "recordings/step_p6V.json"}
    z = S.submit(
        nb, out=tmp_path / "b", include=["step_m3V", work / "s1" / "lab1" / "step_p3V.csv"]
    )
    rec = {n for n in _names(z) if n.startswith("recordings/")}
    assert rec == {
        "recordings/step_p6V.csv",
        "recordings/step_p6V.json",
        "recordings/step_m3V.csv",
        "recordings/step_m3V.json",
        "recordings/step_p3V.csv",
    }
    with pytest.raises(ValueError, match="include: no recording 'step_p9V'"):
        S.submit(nb, out=tmp_path / "c", include=["step_p9V"])
    answers = json.loads(zipfile.ZipFile(z).read("answers.json"))
    assert answers == {"pre_speed": {"answer": 180.0, "ok": True}}
    S.close()


@pytest.mark.notebook
def test_in_a_kernel_a_cell_run_after_saving_is_noticed(tmp_path):
    """In Jupyter every finished cell counts: saving, then running one more cell, then
    submitting is refused; saving last is handed in."""
    save = (
        "import nbformat\n"
        "_nb = nbformat.v4.new_notebook()\n"
        "_nb.cells = [nbformat.v4.new_code_cell('STUDENT = \"s1\"')]\n"
        "nbformat.write(_nb, 'lab1_identify.ipynb')  # what Ctrl-S does\n"
        "import time; time.sleep(0.1)  # a person's pause before the next cell (> the 10 ms slack)"
    )
    cells = [
        "from jerklab import lab\nS = lab.start(1, student='s1')\nS.verify('pre_speed', 180.0)",
        save,
        "import time; time.sleep(0.7); x = 1",
        "print(S.submit('lab1_identify.ipynb'))",
        save,
        "print(S.submit('lab1_identify.ipynb'))",
    ]
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(c) for c in cells]
    execute(nb, tmp_path, timeout=120)
    outs = _outputs(nb)
    assert not [o for o in outs if o.startswith("ERROR")], outs
    first, second = nb.cells[3].outputs[0]["text"], nb.cells[5].outputs[0]["text"]
    assert "not handed in" in first and "before the cells you ran last" in first, first
    assert "hand-in written" in second and "lab1_s1.zip" in second, second


def test_practice_motor_notice_is_one_calm_line(tmp_path, monkeypatch, capsys):
    """Without an instructor key the set-up cell says so in one line: no warning (whose
    traceback a notebook shows) is raised."""
    import warnings

    monkeypatch.delenv("JERKLAB_INSTRUCTOR_KEY", raising=False)
    monkeypatch.delenv("JERKLAB_INSTRUCTOR_KEY_FILE", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        S = lab.start(1, student="s1", folder=tmp_path / "w")
    assert not [w for w in caught if issubclass(w.category, lab.DefaultKeyWarning)], caught
    out = capsys.readouterr().out.splitlines()
    lines = [x for x in out if "practice" in x.lower().replace(str(tmp_path).lower(), "")]
    assert len(lines) == 1 and lines[0].startswith("Practice motor:"), out
    assert S.practice
    S.close()
