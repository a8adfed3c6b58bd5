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
