"""Every name a worksheet's code reads is stated where it is first needed (issue 33).

Each student version (``notebooks/labs/lab*.ipynb``, what a student opens) is parsed cell by
cell. A name that a code cell reads must be a builtin, imported or assigned in an earlier cell
(or earlier in the same cell), or be one that the student is told to make: an answer cell (its
``...``) makes exactly the names that the markdown above it names in a code span (`` `K` `` or
`` `val = ident.validate(...)` ``, whose target is ``val``). The check cells
(``grader.check("K")``) read what their test code reads. A name mentioned only as an argument
in the markdown (`` `ident.validate(fit_pem, ...)` ``) does not count: the task that makes it must
name it.
"""

from __future__ import annotations

import ast
import builtins
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
SHEETS = sorted((ROOT / "notebooks" / "labs").glob("lab*.ipynb"))
_SPAN = re.compile(r"`([^`]+)`")
_IDENT = re.compile(r"[A-Za-z_]\w*")


def _source(cell):
    s = cell.get("source", "")
    return "".join(s) if isinstance(s, list) else s


def named_in_markdown(text):
    """The names a markdown text tells the student to make: code spans that are a name, or a
    ``name = ...`` / ``a, b = ...`` assignment (its targets)."""
    return _spans(text)[0]


def _spans(text):
    """(made, read): the names a markdown text's code spans make (a lone name, the targets of an
    assignment) and the names the code in them reads (what the student's code will read)."""
    made, read = set(), []
    for span in _SPAN.findall(text):
        span = span.strip()
        if _IDENT.fullmatch(span):
            made.add(span)
            continue
        try:
            tree = ast.parse(span)
        except SyntaxError:
            continue
        for stmt in tree.body:
            r, stores = _reads_and_stores(stmt)
            if isinstance(stmt, ast.Assign):
                made |= stores
            if isinstance(stmt, (ast.Assign, ast.Expr)) and not (
                isinstance(stmt, ast.Expr) and _is_reference(stmt.value)
            ):
                read += [x for x in r if x not in made]
    return made, read


def _is_reference(node):
    """A code span that is a constant or names a module of the package (`jerklab.controller`)."""
    while isinstance(node, ast.Attribute):
        node = node.value
    return isinstance(node, ast.Constant) or (isinstance(node, ast.Name) and node.id == "jerklab")


def _loop_targets(node):
    """The targets of ``node``'s ``for`` loops and ``with ... as``: bound before the body reads
    them, and still bound after."""
    out = set()
    for n in ast.walk(node):
        if isinstance(n, (ast.For, ast.AsyncFor)):
            out |= {x.id for x in ast.walk(n.target) if isinstance(x, ast.Name)}
        elif isinstance(n, ast.withitem) and n.optional_vars is not None:
            out |= {x.id for x in ast.walk(n.optional_vars) if isinstance(x, ast.Name)}
    return out


def _local_names(node):
    """Names bound inside comprehensions, lambdas and function definitions of ``node``."""
    out = set()
    for n in ast.walk(node):
        if isinstance(n, ast.comprehension):
            out |= {x.id for x in ast.walk(n.target) if isinstance(x, ast.Name)}
        elif isinstance(n, (ast.Lambda, ast.FunctionDef)):
            a = n.args
            out |= {x.arg for x in [*a.posonlyargs, *a.args, *a.kwonlyargs]}
            out |= {x.arg for x in (a.vararg, a.kwarg) if x is not None}
    return out


def _reads_and_stores(stmt):
    local = _local_names(stmt)
    targets = _loop_targets(stmt)
    reads, stores = [], set(targets)
    for n in ast.walk(stmt):
        if isinstance(n, ast.Name):
            if isinstance(n.ctx, ast.Load) and n.id not in local | targets:
                reads.append(n.id)
            elif isinstance(n.ctx, (ast.Store, ast.Del)) and n.id not in local:
                stores.add(n.id)
        elif isinstance(n, (ast.Import, ast.ImportFrom)):
            for a in n.names:
                stores.add((a.asname or a.name).split(".")[0])
        elif isinstance(n, (ast.FunctionDef, ast.ClassDef)):
            stores.add(n.name)
    if isinstance(stmt, ast.AugAssign) and isinstance(stmt.target, ast.Name):
        reads.append(stmt.target.id)
    return reads, stores


def unstated_names(nb) -> list[str]:
    """``"cell N: name"`` for every name read before it is stated (empty: all stated)."""
    tests = nb.get("metadata", {}).get("otter", {}).get("tests", {})
    known = set(dir(builtins)) | {"_r"}
    missing = []
    above = ""
    for i, cell in enumerate(nb["cells"]):
        src = _source(cell)
        if cell["cell_type"] == "markdown":
            above += "\n" + src
            continue
        if cell["cell_type"] != "code":
            continue
        tree = ast.parse(src)
        m = re.fullmatch(r'\s*grader\.check\(["\'](\w+)["\']\)\s*', src)
        if m:
            case_code = "\n".join(
                line[4:]
                for suite in tests[m.group(1)]["suites"]
                for case in suite["cases"]
                for line in case["code"].splitlines()
                if line.startswith((">>> ", "... "))
            )
            tree = ast.parse(case_code)
        for stmt in tree.body:
            if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant):
                if stmt.value.value is Ellipsis:  # the student's code, as the task above says
                    made, read = _spans(above)
                    for name in read:
                        if name not in known:
                            missing.append(f"cell {i} (its task's text): {name}")
                            known.add(name)
                    known |= made
                continue
            reads, stores = _reads_and_stores(stmt)
            for name in reads:
                if name not in known:
                    missing.append(f"cell {i}: {name}")
                    known.add(name)  # once per name
            known |= stores
        above = ""
    return missing


@pytest.mark.parametrize("path", SHEETS, ids=[p.stem for p in SHEETS])
def test_every_name_is_stated_where_first_needed(path):
    nb = json.loads(path.read_text(encoding="utf-8"))
    assert unstated_names(nb) == []


def test_the_name_test_finds_an_unstated_name():
    """A worksheet whose task does not name `fit_pem`, read by a later cell, is caught; naming it
    in the task's markdown (not only as an argument further down) makes it pass."""

    def nb(task_text):
        cells = [
            {"cell_type": "code", "source": "from jerklab import ident\nrecs = {}"},
            {"cell_type": "markdown", "source": task_text},
            {"cell_type": "code", "source": "...\nprint(fit_pem.summary())"},
            {"cell_type": "markdown", "source": "`val = ident.validate(fit_pem, u, y, Ts)`"},
            {"cell_type": "code", "source": "val = ident.validate(fit_pem, 1, 2, 3)\nval"},
        ]
        return {"cells": cells, "metadata": {}}

    assert unstated_names(nb("Fit the step by PEM.")) == ["cell 2: fit_pem"]
    assert unstated_names(nb("Fit the step by PEM into `fit_pem`.")) == []
    assert named_in_markdown("`a, b = f(x)` and `c` but not `g(d)`") == {"a", "b", "c"}
