"""The test suite itself: files named by what they test, and markers that say what a test needs.

``make check`` (the fast tier) deselects the markers of tests/conftest.py's ``FILE_MARKS``; a test
that needs simavr, a firmware build, a browser, a hub, the Arduino IDE or a notebook kernel must
carry its marker, or the fast tier would start it. The markers are read from the test's own
decorators and from ``FILE_MARKS``; what a test needs is read from its source (the tools it asks
``require_tool`` for, a notebook it executes).
"""

from __future__ import annotations

import ast
import fnmatch
import pathlib
import re

import conftest
import pytest
from hypothesis import settings

TESTS = pathlib.Path(__file__).resolve().parent

#: a name that tells history, not the module tested: an issue number or a version
HISTORY = re.compile(r"issue|(^|_)v\d+($|_)|version\d", re.IGNORECASE)

#: a tool asked for by require_tool -> the marker a test that asks for it carries
TOOL_MARKS = {
    "simavr": "simavr",
    "/usr/include/simavr/sim_avr.h": "simavr",
    "g++": "firmware",
    "arduino-builder": "arduino",
    "configurable-http-proxy": "hub",
    "/usr/bin/chromium": "browser",
    "iverilog": "verilog",
}

#: conftest's fixtures that need a tool -> the marker of a test that takes them
FIXTURE_MARKS = {"host_driver": "firmware"}

#: calls that execute a notebook in a kernel
NOTEBOOK_CALLS = {"NotebookClient", "_execute"}


def collected_files(config_files=None):
    """Every file pytest collects under tests/ (the python_files patterns of pyproject)."""
    patterns = config_files or ["test_*.py"]
    return sorted(
        p for p in TESTS.rglob("*.py") if any(fnmatch.fnmatch(p.name, pat) for pat in patterns)
    )


def test_no_test_file_or_test_is_named_after_history(pytestconfig):
    files = collected_files(pytestconfig.getini("python_files"))
    assert len(files) > 50
    bad = [str(f.relative_to(TESTS)) for f in files if HISTORY.search(f.stem)]
    for f in files:
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test"):
                if HISTORY.search(node.name):
                    bad.append(f"{f.relative_to(TESTS)}::{node.name}")
    assert bad == []


def test_the_history_check_sees_history():
    """The pattern above against names that tell history and names that do not."""
    for name in ("test_rig_v3", "test_issue21", "test_v2_frames", "test_moves_issue_7"):
        assert HISTORY.search(name), name
    for name in ("test_ident_p2", "test_rig_sequence_shaper", "test_vcd_timescale", "test_lab4"):
        assert not HISTORY.search(name), name


def _marks(decorators) -> set[str]:
    out = set()
    for d in decorators:
        d = d.func if isinstance(d, ast.Call) else d
        if isinstance(d, ast.Attribute) and ast.unparse(d).startswith("pytest.mark."):
            out.add(d.attr)
    return out


def _constants(tree) -> dict[str, list[str]]:
    """Module-level NAME = "..." and NAME = ("...", ...) assignments (the tools' names)."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            t = node.targets[0]
            if isinstance(t, ast.Name):
                vals = [
                    n.value
                    for n in ast.walk(node.value)
                    if isinstance(n, ast.Constant) and isinstance(n.value, str)
                ]
                out[t.id] = vals
    return out


def _needs(func, consts) -> set[str]:
    """The markers the body of ``func`` asks for."""
    need = {FIXTURE_MARKS[a.arg] for a in func.args.args if a.arg in FIXTURE_MARKS}
    for node in ast.walk(func):
        if not isinstance(node, ast.Call):
            continue
        name = ast.unparse(node.func).rsplit(".", 1)[-1]
        if name == "require_tool":
            tools = []
            for a in node.args:
                a = a.value if isinstance(a, ast.Starred) else a
                if isinstance(a, ast.Constant):
                    tools.append(a.value)
                elif isinstance(a, ast.Name):
                    tools += consts.get(a.id, [])
            need |= {TOOL_MARKS[t] for t in tools if t in TOOL_MARKS}
        elif name == "require_simavr":
            need.add("simavr")
        elif name in NOTEBOOK_CALLS:
            need.add("notebook")
    return need


def _reached_through_marked_params(tree) -> dict[str, set[str]]:
    """Fixtures that the tests reach only through a parametrized fixture's marked param:
    ``{name: marks}`` for each fixture ``name`` that no test or fixture takes as an argument
    and that is fetched (``request.getfixturevalue("name")``) only inside fixtures whose
    ``params`` mark *every* param that is not the plain one, e.g. ``params=["virtual",
    pytest.param("simavr", marks=pytest.mark.simavr)]``: its needs are then the marked
    params' marks (the unmarked path never fetches it; the test only checks that it is
    fetched in such fixtures, the fetch's own branch is for the reader)."""
    funcs = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
    as_arg = {a.arg for f in funcs for a in f.args.args}
    fetched: dict[str, list[set[str]]] = {}
    for f in funcs:
        param_marks = set()
        for d in f.decorator_list:
            if not (isinstance(d, ast.Call) and ast.unparse(d.func) == "pytest.fixture"):
                continue
            for kw in d.keywords:
                if kw.arg != "params" or not isinstance(kw.value, (ast.List, ast.Tuple)):
                    continue
                for p in kw.value.elts:
                    if isinstance(p, ast.Call) and ast.unparse(p.func) == "pytest.param":
                        for k in p.keywords:
                            if k.arg == "marks":
                                vals = (
                                    k.value.elts
                                    if isinstance(k.value, (ast.List, ast.Tuple))
                                    else [k.value]
                                )
                                param_marks |= {ast.unparse(v).rsplit(".", 1)[-1] for v in vals}
        for node in ast.walk(f):
            if (
                isinstance(node, ast.Call)
                and ast.unparse(node.func).endswith("getfixturevalue")
                and node.args
                and isinstance(node.args[0], ast.Constant)
            ):
                fetched.setdefault(node.args[0].value, []).append(param_marks)
    return {
        name: set.intersection(*marks)
        for name, marks in fetched.items()
        if name not in as_arg and all(marks)
    }


def unmarked_needs(path: pathlib.Path) -> list[str]:
    """``file::function needs marker`` for every test or fixture without the marker it needs
    (a fixture's needs must be marked on the whole file, in ``FILE_MARKS``)."""
    rel = path.relative_to(TESTS).as_posix()
    tree = ast.parse(path.read_text(encoding="utf-8"))
    consts = _constants(tree)
    file_marks = set(conftest.FILE_MARKS.get(rel, ()))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets
        ):
            vals = (
                node.value.elts if isinstance(node.value, (ast.List, ast.Tuple)) else [node.value]
            )
            file_marks |= _marks(vals)
    reached = _reached_through_marked_params(tree)
    out = []
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            funcs = [n for n in node.body if isinstance(n, ast.FunctionDef)]
            cls_marks = _marks(node.decorator_list)
        else:
            funcs, cls_marks = [node], set()
        for f in funcs:
            if not isinstance(f, ast.FunctionDef):
                continue
            missing = _needs(f, consts) - file_marks - cls_marks - _marks(f.decorator_list)
            missing -= reached.get(f.name, set())
            out += [f"{rel}::{f.name} needs {m}" for m in sorted(missing)]
    return out


def test_every_test_that_needs_a_tool_or_a_kernel_carries_its_marker(pytestconfig):
    bad = [
        m for f in collected_files(pytestconfig.getini("python_files")) for m in unmarked_needs(f)
    ]
    assert bad == []


def test_the_marker_check_finds_a_missing_marker(tmp_path, monkeypatch):
    """A test asking for simavr without its marker, a fixture asking for g++ in an unmarked file,
    a test taking the host driver and an unmarked notebook run are found; the marked ones are
    not."""
    monkeypatch.setattr("test_suite_layout.TESTS", tmp_path)
    f = tmp_path / "test_x.py"
    f.write_text(
        "import pytest\n"
        "TOOLS = ('make', 'simavr')\n"
        "def test_a():\n    require_tool(*TOOLS)\n"
        "@pytest.mark.simavr\ndef test_b():\n    require_tool('simavr')\n"
        "@pytest.fixture\ndef host():\n    require_tool('g++', 'make')\n"
        "def test_c():\n    NotebookClient(nb).execute()\n"
        "@pytest.mark.notebook\ndef test_d():\n    NotebookClient(nb).execute()\n"
        "def test_e():\n    require_tool('make')\n"
        "def test_f(host_driver):\n    pass\n"
        "def test_g():\n    require_simavr()\n",
        encoding="utf-8",
    )
    assert unmarked_needs(f) == [
        "test_x.py::test_a needs simavr",
        "test_x.py::host needs firmware",
        "test_x.py::test_c needs notebook",
        "test_x.py::test_f needs firmware",
        "test_x.py::test_g needs simavr",
    ]


def test_file_marks_name_existing_files_and_registered_markers(pytestconfig):
    registered = {m.split(":")[0].strip() for m in pytestconfig.getini("markers")}
    for rel, marks in conftest.FILE_MARKS.items():
        assert (TESTS / rel).is_file(), rel
        assert set(marks) <= registered, (rel, marks)
    for rel in conftest.ONE_WORKER:
        assert (TESTS / rel).is_file(), rel


def test_case_counts_come_from_the_profiles_only(pytestconfig):
    """No test sets ``max_examples``: tests/conftest.py's profiles (and their cost classes,
    ``cases``) decide every hypothesis case count."""
    bad = []
    for f in collected_files(pytestconfig.getini("python_files")):
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.keyword) and node.arg == "max_examples":
                bad.append(f"{f.relative_to(TESTS)}:{node.value.lineno}")
    assert bad == []


#: the hypothesis cases of the whole suite under the ci profile when each test set its own count
#: (56 tests, per-test max_examples from 25 to 2000); the profiles must give at least as many
CI_CASES_BEFORE = 28650

_COUNT_PLUGIN = """
import json, os
def pytest_collection_finish(session):
    rows = []
    for it in session.items:
        f = getattr(it, "obj", None)
        if getattr(f, "hypothesis", None) is not None:
            rows.append([it.nodeid, f._hypothesis_internal_use_settings.max_examples])
    with open(os.environ["CASES_OUT"], "w") as fh:
        json.dump(rows, fh)
"""


def _ci_cases(items) -> dict[str, int]:
    """nodeid -> the test's case count under the ci profile, from the count under the loaded one
    (``cases`` divides both profiles' counts by the same share)."""
    now = settings.default.max_examples
    ci = settings.get_profile("ci").max_examples
    out = {}
    for nodeid, n in items:
        share = now // n
        assert max(1, now // share) == n, (nodeid, n)  # a share of the profile, nothing else
        out[nodeid] = max(1, ci // share)
    return out


@pytest.mark.slow  # (collects every property test file when the session has not)
def test_the_ci_profile_keeps_the_total_case_count(request, tmp_path, pytestconfig):
    files = [
        f
        for f in collected_files(pytestconfig.getini("python_files"))
        if "@given(" in f.read_text(encoding="utf-8")
    ]
    got = {str(getattr(it, "path", "")) for it in request.session.items}
    if all(str(f) in got for f in files):  # the whole suite is in this session
        items = [
            (it.nodeid, it.obj._hypothesis_internal_use_settings.max_examples)
            for it in request.session.items
            if getattr(getattr(it, "obj", None), "hypothesis", None) is not None
        ]
    else:  # collect the files with property tests in a subprocess
        import json
        import os
        import subprocess
        import sys

        (tmp_path / "count_cases.py").write_text(_COUNT_PLUGIN, encoding="utf-8")
        env = {**os.environ, "CASES_OUT": str(tmp_path / "cases.json")}
        env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), env.get("PYTHONPATH", "")])
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "pytest",
                "--co",
                "-q",
                "-p",
                "count_cases",
                "-p",
                "no:cacheprovider",
            ]
            + [str(f) for f in files],
            cwd=TESTS.parent,
            env=env,
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
        items = json.loads((tmp_path / "cases.json").read_text())
    ci = _ci_cases(items)
    assert len(ci) >= 56
    assert sum(ci.values()) >= CI_CASES_BEFORE, sum(ci.values())


def test_cases_takes_the_share_of_the_loaded_profile():
    n = settings.default.max_examples
    assert conftest.cases("cheap").max_examples == n
    assert conftest.cases("costly", deadline=None).max_examples == max(1, n // 10)
    assert conftest.cases("batch").max_examples == max(1, n // 25)
    with pytest.raises(ValueError, match="cost"):
        conftest.cases("expensive")
    with pytest.raises(TypeError, match="max_examples"):
        conftest.cases("costly", **{"max_examples": 5})  # (a keyword the check above finds)


def test_a_fixture_reached_only_through_a_marked_param_needs_no_file_mark(tmp_path, monkeypatch):
    """``uno`` needs simavr and is fetched only in the simavr param of ``any_rig`` (marked):
    it passes; ``bare`` is fetched by an unmarked param and ``taken`` is a test's argument:
    both are found."""
    monkeypatch.setattr("test_suite_layout.TESTS", tmp_path)
    f = tmp_path / "test_y.py"
    f.write_text(
        "import pytest\n"
        "@pytest.fixture\ndef uno():\n    require_simavr()\n"
        "@pytest.fixture\ndef bare():\n    require_simavr()\n"
        "@pytest.fixture\ndef taken():\n    require_simavr()\n"
        "@pytest.fixture(params=['virtual', pytest.param('simavr', marks=pytest.mark.simavr)])\n"
        "def any_rig(request):\n    return request.getfixturevalue('uno')\n"
        "@pytest.fixture(params=['virtual', 'simavr'])\n"
        "def loose(request):\n    return request.getfixturevalue('bare')\n"
        "def test_h(any_rig, loose, taken):\n    pass\n",
        encoding="utf-8",
    )
    assert unmarked_needs(f) == ["test_y.py::bare needs simavr", "test_y.py::taken needs simavr"]


def test_the_groups_reach_xdist(request):
    """Under ``make test`` (``--dist loadgroup``) every test of a grouped file carries its group in
    its id, which is what pytest-xdist schedules by: a group marker added after xdist read them
    (tests/conftest.py's hook without ``tryfirst``) left every id bare, and each worker started
    its own hub with the same Unix users, graded the class folder again, ran its own browser."""
    if not request.config.getvalue("loadgroup"):
        pytest.skip("not run by pytest-xdist with --dist loadgroup (make test)")
    bare = [
        it.nodeid
        for it in request.session.items
        if conftest._group(it) is not None and not it.nodeid.endswith(f"@{conftest._group(it)}")
    ]
    assert bare == [], bare[:5]
    hubs = {conftest._group(it) for it in request.session.items if "test_hub.py" in it.nodeid}
    assert hubs <= {"test_hub.py"}, hubs  # both hub files: one worker, one hub at a time
