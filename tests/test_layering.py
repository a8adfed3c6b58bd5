"""The modules below the face do not import matplotlib when they are imported.

Drawing lives in ``jerklab.plots`` and is imported when a figure is asked for, so a script,
a benchmark or the rig's command line that never draws does not pay for matplotlib (nor pick
a backend). Each module is imported in a fresh interpreter; python-control, which imports
matplotlib itself, must be imported lazily by the modules that use it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

BELOW_THE_FACE = [
    "jerklab",
    "jerklab.law",
    "jerklab.paper",
    "jerklab.planner",
    "jerklab.plant",
    "jerklab.controller",
    "jerklab.sim",
    "jerklab.metrics",
    "jerklab.ident",
    "jerklab.protocol",
    "jerklab.piezo",
    "jerklab.hysteresis",
    "jerklab.fpga",
    "jerklab.plots",
    "jerklab.rig",
    "jerklab.rig.virtual",
    "jerklab.rig.server",
    "jerklab.rig.recording",
    "jerklab.rig.client",
    "jerklab.rig.simavr",
    "jerklab.rig.progress",
    "jerklab.rig.ports",
    "jerklab.rig.check",
    "jerklab.rig.options",
    "jerklab.tuning",
    "jerklab.shaping",
    "jerklab.multiaxis",
]


def _imports(module):
    code = f"import sys, {module}; print(sorted(m for m in ('matplotlib', 'control') if m in sys.modules))"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@pytest.mark.parametrize("module", BELOW_THE_FACE)
def test_import_does_not_pull_matplotlib(module):
    assert _imports(module) == "[]"


def test_the_check_sees_matplotlib():
    """The probe itself: a module that does import matplotlib is seen."""
    assert "matplotlib" in _imports("matplotlib.figure")
