"""Running a lab worksheet headless in the tests (tests/test_labs.py, tests/test_lab4.py)."""

from __future__ import annotations

import re

import pytest

KEY = "test-instructor-key"


@pytest.fixture(autouse=True)
def lab_env(monkeypatch, tmp_path):
    """The instructor key and per-test work and recording folders (imported by the lab tests)."""
    monkeypatch.setenv("JERKLAB_INSTRUCTOR_KEY", KEY)
    monkeypatch.setenv("JERKLAB_LAB_WORK", str(tmp_path / "work"))
    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path / "rec"))
    monkeypatch.delenv("JERKLAB_LAB_GRADING", raising=False)


def execute(nb, cwd, timeout=240):
    """Execute ``nb`` in place (errors kept as outputs) with ``cwd`` as its folder."""
    from nbclient import NotebookClient

    NotebookClient(
        nb,
        timeout=timeout,
        kernel_name="python3",
        allow_errors=True,
        resources={"metadata": {"path": str(cwd)}},
    ).execute()
    return nb


def outputs(nb):
    """Every text a code cell showed, errors as ``ERROR name: value``."""
    out = []
    for c in nb.cells:
        if c.cell_type != "code":
            continue
        for o in c.get("outputs", []):
            if o.output_type == "error":
                out.append(f"ERROR {o.ename}: {o.evalue}")
            out.append(o.get("text", ""))
            for v in o.get("data", {}).values():
                if isinstance(v, str):
                    out.append(v)
    return out


def set_student(nb, sid):
    """Put student ID ``sid`` in the worksheet's STUDENT line."""
    for c in nb.cells:
        if c.cell_type == "code" and 'STUDENT = "' in c.source:
            c.source = re.sub(r'STUDENT = "[^"]*"', f'STUDENT = "{sid}"', c.source)
            return
    raise AssertionError("no STUDENT cell")


def answered(n):
    """The committed student version of lab ``n`` with every answer cell typed in: each
    ``...`` cell replaced by the master's solution for it (otter's autograder copy), so that it
    runs as a student who got everything right would run it."""
    from pathlib import Path

    import nbformat

    from jerklab.lab.grade import _assigned, student_version_name

    name = student_version_name(n)
    root = Path(__file__).parent.parent
    nb = nbformat.read(root / "notebooks" / "labs" / name, as_version=4)
    auto = nbformat.read(_assigned(n) / "autograder" / name, as_version=4)

    def tagged(book, tag):
        return [
            c for c in book.cells if c.cell_type == "code" and tag in c.metadata.get("tags", [])
        ]

    answers, solutions = tagged(nb, "otter_answer_cell"), tagged(auto, "otter_assign_solution_cell")
    assert len(answers) == len(solutions) > 0, (len(answers), len(solutions))
    for a, s in zip(answers, solutions):
        a.source = s.source
    return nb


def verdicts(nb):
    """``(check name, passed, text)`` of every ``grader.check("...")`` cell's shown outcome (in
    order), or of its error."""
    out = []
    for c in nb.cells:
        m = (
            re.fullmatch(r'\s*grader\.check\("(\w+)"\)\s*', c.source)
            if c.cell_type == "code"
            else None
        )
        if not m:
            continue
        texts = [o.get("data", {}).get("text/plain", "") for o in c.get("outputs", [])]
        errors = [
            f"ERROR {o.ename}: {o.evalue}" for o in c.get("outputs", []) if o.output_type == "error"
        ]
        text = "\n".join(t for t in texts if t) or "\n".join(errors)
        out.append((m.group(1), text.startswith("✔"), text))
    return out


#: how long run_master's virtual rigs wait for data (s; the rig's default is 2 s)
LINK_TIMEOUT = 30.0


def run_master(n, motor, profile=None, student="corner", ns=None):
    """Run the master of lab ``n`` (solutions in) in this process, in a plain namespace, as a
    student who got everything right: its code cells in order with ``PROFILE`` set to
    ``profile`` and the session's hidden motor replaced by ``motor`` (the instructor key is in
    the environment: the checks see its truth); the hand-in cell is left out. The virtual
    rigs wait up to ``LINK_TIMEOUT`` for the device (a loaded test machine is slower than a
    student's). Returns ``(session, failures)``: the :class:`jerklab.lab.LabSession` and
    ``(cell, message)`` of every check cell whose assert failed (any other error propagates).
    ``ns``: the dict the cells run in (the caller then reads the worksheet's names)."""
    from unittest import mock

    import matplotlib.pyplot as plt
    import nbformat

    from jerklab.lab.grade import master_path
    from jerklab.rig import Link, connect

    def patient(*args, **kwargs):
        kwargs.setdefault("link", Link(timeout=LINK_TIMEOUT))
        return connect(*args, **kwargs)

    nb = nbformat.read(master_path(n), as_version=4)
    ns = {} if ns is None else ns
    ns["__name__"] = f"lab{n}_master"
    failures = []
    with (
        mock.patch("jerklab.lab.session.student_motor", lambda *a, **k: motor),
        mock.patch("jerklab.lab.session.connect", patient),
        mock.patch("jerklab.lab.checks.connect", patient),
    ):
        for i, c in enumerate(nb.cells):
            if c.cell_type != "code" or "S.submit(" in c.source:
                continue
            src = c.source
            if 'STUDENT = "' in src:
                src = re.sub(r'STUDENT = "[^"]*"', f'STUDENT = "{student}"', src)
                src, k = re.subn(r"PROFILE = None", f"PROFILE = {profile!r}", src)
                assert k == 1, "no PROFILE line in the set-up cell"
            try:
                exec(compile(src, f"lab{n} master cell {i}", "exec"), ns)
            except AssertionError as exc:
                if "S.verify(" not in src:
                    raise
                failures.append((i, str(exc)))
            finally:
                plt.close("all")
    return ns["S"], failures
