"""The student's path on any OS: no POSIX-only import, Windows-valid file names, spreadsheet CSVs."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jerklab import cli
from jerklab.ident import IdentData
from jerklab.rig import Recording, connect

ROOT = Path(__file__).resolve().parents[1]
POSIX_ONLY = {"pty", "tty", "termios", "fcntl"}
#: the Linux/macOS tools: the pty server (select on sockets, tty lazily), the simavr harness
POSIX_TOOLS = ("jerklab/rig/server.py", "jerklab/rig/simavr")


def test_student_path_with_posix_modules_blocked(tmp_path):
    """jerklab's code never imports pty/tty/termios/fcntl on the student's path; on "win32"
    serve and simavr say what to use instead (tests/_student_path.py)."""
    env = {k: v for k, v in os.environ.items() if k not in ("JERKLAB_RECORDINGS", "JERKLAB_HOME")}
    env["PYTHONPATH"] = str(ROOT)
    env["MPLBACKEND"] = "Agg"
    r = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "_student_path.py"), str(tmp_path), "--block-posix"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0 and "STUDENT PATH OK" in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]
    assert "step: Windows messages of serve and simavr" in r.stdout


def _unguarded_imports(tree):
    """Top-level module names imported outside a ``try: ... except ImportError`` block."""
    guarded = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and any(
            h.type is None
            or any(
                isinstance(n, ast.Name) and n.id in ("ImportError", "ModuleNotFoundError")
                for n in ast.walk(h.type)
            )
            for h in node.handlers
        ):
            guarded.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    for node in ast.walk(tree):
        if id(node) in guarded:
            continue
        if isinstance(node, ast.Import):
            yield from (a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module.split(".")[0]


def test_no_posix_only_import_outside_the_posix_tools():
    """pty/tty/termios/fcntl only in the Linux/macOS tools, or behind ``except ImportError``
    (``select`` is fine: on Windows it works on sockets, which is all jerklab selects on there)."""
    bad = []
    for path in sorted((ROOT / "jerklab").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(POSIX_TOOLS):
            continue
        names = set(_unguarded_imports(ast.parse(path.read_text(encoding="utf-8"))))
        bad += [(rel, n) for n in sorted(names & POSIX_ONLY)]
    assert not bad, bad
    # the pty server: tty only inside start_pty
    tree = ast.parse((ROOT / "jerklab/rig/server.py").read_text(encoding="utf-8"))
    top = {a.name for n in tree.body if isinstance(n, ast.Import) for a in n.names}
    assert not top & POSIX_ONLY, top & POSIX_ONLY
    # the rule sees an unguarded import and accepts a guarded one
    assert "fcntl" in set(_unguarded_imports(ast.parse("import fcntl")))
    assert "fcntl" not in set(
        _unguarded_imports(
            ast.parse("try:\n    import fcntl\nexcept ImportError:\n    fcntl = None")
        )
    )


# ----------------------------------------------------------------------------- file names
_RESERVED = {
    "CON",
    "PRN",
    "AUX",
    "NUL",
    *(f"COM{i}" for i in range(1, 10)),
    *(f"LPT{i}" for i in range(1, 10)),
}


def windows_name_problem(name: str):
    """Why ``name`` is not a valid Windows file name (None if it is)."""
    if re.search(r'[<>:"/\\|?*\x00-\x1f]', name):
        return "forbidden character"
    if name.endswith((".", " ")):
        return "trailing dot or space"
    if name.split(".")[0].upper().rstrip() in _RESERVED:
        return "reserved name"
    if len(name) > 200:
        return "too long"
    return None


@pytest.mark.parametrize(
    "name, ok",
    [
        ("20261127-183838_move.csv", True),
        ("12:30_move.csv", False),
        ("NUL.csv", False),
        ("com3.json", False),
        ("run.", False),
        ("console.csv", True),
    ],
)
def test_windows_name_rule(name, ok):
    assert (windows_name_problem(name) is None) == ok


def test_recording_names_are_valid_on_windows(tmp_path):
    from jerklab.controller import pole_placement_pid
    from jerklab.planner import plan_sine_jerk

    with connect(progress=False, recordings=tmp_path) as rig:
        rig.step(3.0, 0.05)
        rig.step(3.0, 0.05)  # the same second: a suffix, no clash
        rig.run_move(
            plan_sine_jerk(1.0, 2e4, 300.0, 100.0),
            pole_placement_pid(32.4, 0.025, 20.0),
            settle=0.05,
        )
    names = sorted(p.name for p in tmp_path.iterdir())
    assert len(names) == 6, names
    assert [n for n in names if windows_name_problem(n)] == []
    assert len({n.lower() for n in names}) == len(names)  # no two differ by case only


def test_shipped_files_have_windows_names():
    for folder in ("notebooks", "data", "app"):
        for p in (ROOT / folder).rglob("*"):
            rel = p.relative_to(ROOT)
            assert all(windows_name_problem(part) is None for part in rel.parts), rel
            assert len(str(rel)) < 120, rel  # room under MAX_PATH below C:\Users\...


def test_recordings_default_to_the_working_folder(tmp_path, monkeypatch):
    # set, then removed: monkeypatch then restores the variable after `jerklab app` sets it
    monkeypatch.setenv("JERKLAB_RECORDINGS", "")
    monkeypatch.delenv("JERKLAB_RECORDINGS")
    monkeypatch.chdir(tmp_path)
    with connect(progress=False) as rig:
        rec = rig.step(3.0, 0.05)
    assert rec.csv_path.resolve().parent == tmp_path / "recordings"
    # the class page started by `jerklab app` records to the working folder, not the package
    seen = {}
    import jerklab.app

    monkeypatch.setenv("JERKLAB_HOME", str(tmp_path / "w"))
    monkeypatch.setattr(
        jerklab.app, "main", lambda argv: seen.update(env=os.environ["JERKLAB_RECORDINGS"]) or 0
    )
    pytest.importorskip("voila")
    assert cli.main(["app", "--pool", "0"]) == 0
    assert seen["env"] == str(tmp_path / "w" / "recordings")


# ----------------------------------------------------------------------------- CSVs
_NUMBER = re.compile(r"^-?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?$|^-?(inf|nan)$")


def _spreadsheet_ok(path):
    raw = path.read_bytes()
    bom = raw.startswith(b"\xef\xbb\xbf")
    text = raw.decode("utf-8-sig")
    lines = text.splitlines()
    if not bom:
        assert raw.isascii(), f"{path}: non-ASCII without a BOM"
    cols = lines[0].split(",")
    for line in lines[1:]:
        fields = line.split(",")
        assert len(fields) == len(cols), f"{path}: {line!r}"
        assert all(_NUMBER.match(f) for f in fields), (
            f"{path}: {line!r} (one decimal separator: '.')"
        )
    return cols, bom


def test_recording_csv_opens_in_a_spreadsheet(tmp_path):
    with connect(progress=False, recordings=tmp_path) as rig:
        rec = rig.step(-3.0, 0.05)
    cols, bom = _spreadsheet_ok(rec.csv_path)
    assert not bom and cols[:3] == ["index", "time", "reference"]


def test_ident_csv_ascii_or_bom_and_loads_back(tmp_path):
    t = np.arange(50) * 0.01
    plain = IdentData(np.ones(50), np.sin(t), 0.01, "V", "rad")
    micro = IdentData(np.ones(50), 1e-6 * np.sin(t), 0.01, "V", "µm")
    for name, d in (("plain", plain), ("micro", micro)):
        csv_path, _ = d.save(tmp_path / name)
        cols, bom = _spreadsheet_ok(csv_path)
        assert bom == (name == "micro")
        assert cols[2] == f"y_{d.output_unit}"
        back = IdentData.load(tmp_path / name)
        np.testing.assert_array_equal(back.y, d.y)
        assert back.output_unit == d.output_unit


def test_shipped_data_still_loads():
    """The loaders read the files in data/ as before (backward compatible)."""
    for js in sorted((ROOT / "data" / "ident").glob("*.json")):
        d = IdentData.load(js.with_suffix(""))
        assert d.n > 10
        _spreadsheet_ok(js.with_suffix(".csv"))
    for js in sorted((ROOT / "data" / "rig").glob("*.json")):
        rec = Recording.load(js.with_suffix(".csv"))
        assert len(rec) > 10
        _spreadsheet_ok(js.with_suffix(".csv"))
