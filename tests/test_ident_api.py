"""jerklab.ident is a package whose public names are those of the module it was, and whose
modules import drawing only where a result draws itself.

The names are today's ``__all__`` of the former ``jerklab/ident.py``, its public constants, and
every ``ident.<name>`` the notebooks, labs, benchmarks and tests use; ``plot_compare_result`` and
``plot_ident_data``, which the module only imported from ``jerklab.plots``, live there.
"""

from __future__ import annotations

import ast
import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
IDENT = ROOT / "jerklab" / "ident"

#: the public names of the module jerklab/ident.py was (its __all__ and constants)
NAMES = """
IdentData ARXResult arx MotorFit fit_dc_motor IdentificationWarning simulate_motor
simulate_dc_motor dc_motor_zoh_coefficients arx_asymptotic_bias P2Fit fit_p2 fit_percent
ResidualAnalysis residual_analysis Validation MergedData merge CompareResult compare resid
load_micromouse load_dc_generator micromouse_battery_voltage validate plot_compare plot_residuals
step_input prbs sample_time_range
MIN_SAMPLES FIT_TS_RANGE MAX_INPUT_SAMPLES MICROMOUSE_RECORDS DC_GENERATOR_FILE
DC_GENERATOR_ROW_STEP DC_GENERATOR_RAW_PER_CLOCK
""".split()
#: names the package adds
NEW = "FitOptions CompareResults ModeEstimate identify_mode coupled_mode".split()


@pytest.mark.parametrize("name", NAMES + NEW)
def test_public_name_is_importable(name):
    mod = importlib.import_module("jerklab.ident")
    assert getattr(mod, name) is not None
    assert name in mod.__all__
    exec(f"from jerklab.ident import {name}", {})


def test_all_lists_only_what_is_there():
    import jerklab.ident as ident

    assert sorted(ident.__all__) == sorted(set(ident.__all__))
    assert [n for n in ident.__all__ if not hasattr(ident, n)] == []
    assert sorted(ident.__all__) == sorted(NAMES + NEW)


def _used_names():
    """Every ``ident.<name>`` (or ``from jerklab.ident import <name>``) outside the package."""
    import json
    import re

    pat = re.compile(r"(?:jerklab\.|(?<![/\w.]))ident\.([A-Za-z_][A-Za-z0-9_]*)")
    imp = re.compile(r"from jerklab\.ident import ([A-Za-z_, ]+)")
    found = set()
    for folder in ("notebooks", "jerklab", "benchmarks", "tests", "data"):
        for f in (ROOT / folder).rglob("*"):
            if f.suffix not in (".py", ".ipynb") or IDENT in f.parents:
                continue
            text = f.read_text(encoding="utf-8")
            if f.suffix == ".ipynb":
                cells = json.loads(text)["cells"]
                text = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
            found |= set(pat.findall(text))
            for group in imp.findall(text):
                found |= {n.split(" as ")[0].strip() for n in group.split(",") if n.strip()}
    return found


def test_every_name_the_repository_uses_exists():
    import jerklab.ident as ident

    used = _used_names()
    assert {"fit_dc_motor", "IdentData", "compare", "plot_compare"} <= used  # the scan works
    public = {n for n in used if not n.startswith("_")}
    assert sorted(n for n in public if not hasattr(ident, n)) == []


def _imports(path):
    """(function name or None, imported module) for every import statement of a file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []

    def visit(node, func):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                visit(child, child.name)
            elif isinstance(child, ast.Import):
                out.extend((func, a.name) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                out.append((func, child.module or ""))
            else:
                visit(child, func)

    visit(tree, None)
    return out


def test_drawing_is_imported_only_by_plot_methods():
    """No jerklab import inside a function of jerklab/ident/, except the late import of
    jerklab.plots in a ``.plot()`` method; no module of it imports jerklab.plots at the top."""
    bad = []
    for f in sorted(IDENT.glob("*.py")):
        for func, mod in _imports(f):
            if func is None and mod.startswith("jerklab.plots"):
                bad.append(f"{f.name}: imports {mod} at the top")
            if func is not None and mod.startswith("jerklab"):
                if not (func == "plot" and mod == "jerklab.plots"):
                    bad.append(f"{f.name}: {func}() imports {mod}")
    assert bad == []


def test_plots_does_not_import_ident():
    """jerklab.plots draws results; it computes nothing and imports nothing of jerklab.ident."""
    mods = [mod for _, mod in _imports(ROOT / "jerklab" / "plots.py")]
    assert [m for m in mods if m.startswith("jerklab.ident")] == []
    assert "jerklab._validate" in mods  # the scan sees the module's imports


def test_import_does_not_load_plots():
    code = (
        "import sys, jerklab.ident; "
        "print(sorted(m for m in ('jerklab.plots', 'matplotlib', 'control') if m in sys.modules))"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
