"""Execute every notebook in notebooks/ headless, as a student's kernel would.

Each must run top to bottom without error in under a minute, with the virtual rig. "A minute" is
a student's own machine: the kernel's CPU time (its processes', reaped) stays under
``CPU_LIMIT_S``, which leaves the rest of the minute to the rig's real-time runs; the wall time,
on the suite's shared cores (three workers on two here, the first notebook with cold caches),
is bounded by ``TIME_LIMIT_S`` per cell and ``WALL_LIMIT_S`` in all.
"""

from __future__ import annotations

import os
import pathlib
import time

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((pathlib.Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))
TIME_LIMIT_S = 60.0
CPU_LIMIT_S = 45.0
WALL_LIMIT_S = 2 * TIME_LIMIT_S
EXECUTED = pathlib.Path(__file__).parent.parent / "build" / "executed"


def test_notebooks_exist():
    assert NOTEBOOKS, "notebooks/ has no notebook"


def test_paper_notebooks_tell_the_story_and_tests_check_the_numbers():
    """The paper notebooks carry no ``assert``: the numbers they show are checked by the tests of
    the modules that compute them (tests/test_figures_*.py)."""
    import ast

    found = {}
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        for i, cell in enumerate(nb.cells):
            if cell.cell_type != "code":
                continue
            code = "\n".join(
                "pass" if line.lstrip().startswith(("%", "!")) else line
                for line in cell.source.splitlines()
            )
            n = sum(isinstance(node, ast.Assert) for node in ast.walk(ast.parse(code)))
            if n:
                found[f"{path.name} cell {i}"] = n
    assert found == {}


@pytest.mark.notebook
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path, monkeypatch):
    nb = nbformat.read(path, as_version=4)
    assert not any(c.get("outputs") for c in nb.cells if c.cell_type == "code"), (
        f"{path.name} is committed with outputs; clear them"
    )
    # the kernel's inline backend, as in JupyterLab: headless, and every figure becomes a PNG output,
    # which the book (tests/test_book.py, make book) shows from the executed copy kept below
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path))
    client = NotebookClient(
        nb,
        timeout=TIME_LIMIT_S,
        kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
    )
    t0 = time.perf_counter()
    cpu0 = _children_cpu()
    client.execute()  # starts the kernel, runs every cell, shuts the kernel down and reaps it
    elapsed = time.perf_counter() - t0
    cpu = _children_cpu() - cpu0
    # keep the executed copy: the book (tools/build_book.py, tests/test_book.py) shows it without
    # executing the notebook a second time
    # (written whole, then renamed: under xdist the book may read the folder meanwhile)
    EXECUTED.mkdir(parents=True, exist_ok=True)
    part = EXECUTED / f".{path.name}.{os.getpid()}.part"
    nbformat.write(nb, part)
    os.replace(part, EXECUTED / path.name)
    print(f"{path.name}: {cpu:.1f} s CPU, {elapsed:.1f} s wall")
    assert cpu > 0.5, cpu  # the kernel was reaped by this process, so its time is counted
    assert cpu < CPU_LIMIT_S, f"{path.name} took {cpu:.1f} s of CPU (limit {CPU_LIMIT_S} s)"
    assert elapsed < WALL_LIMIT_S, f"{path.name} took {elapsed:.1f} s (limit {WALL_LIMIT_S} s)"


def _children_cpu() -> float:
    """CPU seconds (user + system) of this process's reaped children, their children included."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime
