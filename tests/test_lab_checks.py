"""The worksheets' check cells run without otter-grader (a student's ``jerklab[lab]`` has none).

The student versions carry the checks in otter's format in their metadata; ``jerklab.lab.notebook``
runs them with the standard library's doctest. Independent reference: each check's verdict is
compared with ``S.verify`` called directly, and the run happens with ``otter`` blocked from import.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
LABS = sorted((ROOT / "notebooks" / "labs").glob("lab*_*.ipynb"))


def test_student_versions_use_the_otter_free_runner():
    assert LABS
    for path in LABS:
        nb = json.loads(path.read_text(encoding="utf-8"))
        code = "\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code")
        assert "import otter" not in code, path.name
        assert f'grader = Notebook("{path.name}")' in code, path.name
        assert nb["metadata"]["otter"]["tests"], path.name


def test_checks_run_with_otter_blocked(tmp_path):
    script = textwrap.dedent(f"""
        import sys
        for m in ("otter", "nbconvert", "playwright"):
            sys.modules[m] = None                      # importing any of them now fails
        from jerklab import lab
        from jerklab.lab.motors import hidden_truth, student_motor
        from jerklab.lab.notebook import Notebook
        grader = Notebook({str(LABS[0])!r})
        S = lab.start(1, student="s42", port=None)
        K = hidden_truth(student_motor("s42"))["K"]
        right = grader.check("K", {{"S": S, "K": K}})
        wrong = grader.check("K", {{"S": S, "K": K * 6.283185307179586}})
        missing = grader.check("K", {{"S": S, "K": ...}})
        direct = S.verify("K", K * 6.283185307179586)
        print(repr(right)); print(repr(wrong)); print(repr(missing))
        assert right.passed and not wrong.passed and not missing.passed
        assert direct.message in wrong.message
        """)
    env = dict(
        os.environ,
        JERKLAB_INSTRUCTOR_KEY="k",
        JERKLAB_LAB_WORK=str(tmp_path / "w"),
        JERKLAB_RECORDINGS=str(tmp_path / "r"),
        PYTHONPATH=str(ROOT),
    )
    r = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    lines = r.stdout.strip().splitlines()[-3:]
    assert lines[0].startswith("✔ K") and lines[1].startswith("✘ K") and "factor 6.28" in lines[1]
    assert "replace the `...`" in lines[2]


def test_unknown_check_and_missing_worksheet_are_named(tmp_path):
    from jerklab.lab.notebook import Notebook

    g = Notebook(LABS[0])
    with pytest.raises(KeyError, match="no check 'nope'"):
        g.check("nope", {})
    with pytest.raises(FileNotFoundError, match="notebook: no worksheet"):
        Notebook(tmp_path / "lab9_nothing.ipynb")
    bare = tmp_path / "bare.ipynb"
    bare.write_text(json.dumps({"cells": [], "metadata": {}}), encoding="utf-8")
    with pytest.raises(ValueError, match="holds no checks"):
        Notebook(bare)


def test_a_renamed_copy_still_finds_its_checks(tmp_path, monkeypatch):
    from jerklab.lab.notebook import Notebook

    monkeypatch.chdir(tmp_path)  # not the worksheet's folder: the shipped copy is used
    assert Notebook(LABS[0].name).tests == Notebook(LABS[0]).tests
