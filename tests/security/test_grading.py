"""Crafted submissions against the real ``python -m jerklab.lab grade`` (issue 32, "Grading").

One class folder holds an honest hand-in and every attack of the issue; it is graded once,
by the command a teacher types (a subprocess, instructor key in its environment and in a key
file, ``--jobs 2``), and each test reads its own row, feedback file or side effect:

* a replaced ``S.verify`` (manifest recomputed with the package's own ``pack()``);
* lying answers: a ``float`` subclass whose ``__float__`` walks the stack to the checker's
  truth and whose ``__eq__`` says yes to everything;
* answers read from ``S._truth()``, ``S._motor`` or a motor the worksheet rebuilds itself;
* reading the instructor key (environment, key file, ``~/.config``, other processes'
  ``/proc/*/environ``), its argv and cwd;
* writing another submission, ``grades.csv``, ``feedback/`` and the autograder cache;
* a detached child (``setsid``) that outlives the grader and rewrites ``grades.csv``;
* student IDs that are a path, hold a NUL or have 300 characters;
* a zip bomb (1 MiB holding 1 GiB);
* the same notebook under two IDs, one ID twice; ``=1+2*3`` and friends in the CSV;
* an autograder pre-planted in the shared temporary folder (cache poisoning).

The submissions are built by :mod:`benchmarks.attacks_grading` (``python -m benchmarks
security`` prints the same run's verdicts). Each test fails on the grader before issue 32
(otter run in the instructor's own process, checked once against that code); the honest
hand-in scores full marks.
"""

from __future__ import annotations

import csv
import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.attacks_grading import FULL, JUDGES, KEY, PROBE, _small, grade_class

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from conftest import require_tool  # noqa: E402


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """Grade the class folder once with the real command; return what the tests look at."""
    require_tool("bwrap", "prlimit")
    return grade_class(tmp_path_factory.mktemp("class"), jobs=2)


def _fb(graded, file):
    hits = [t for n, t in graded["feedback"].items() if n.endswith(f"_{Path(file).stem}.txt")]
    assert len(hits) == 1, (file, sorted(graded["feedback"]))
    return hits[0]


def test_honest_hand_in_scores_full_marks(graded):
    row = graded["rows"]["lab1_honest.zip"]
    assert row["status"] == "graded", row
    assert float(row["total"]) == float(row["max"]) == FULL


def test_replaced_check_gains_nothing(graded):
    row = graded["rows"]["lab1_override.zip"]
    assert row["status"] == "graded" and float(row["max"]) == FULL, row
    assert float(row["total"]) == 0.0, row


def test_lying_float_and_eq_gain_nothing(graded):
    row = graded["rows"]["lab1_liar.zip"]
    assert row["status"] == "graded", row
    assert float(row["tau"]) == float(row["K"]) == float(row["f_c"]) == 0.0, row


def test_answers_from_private_attributes_gain_nothing(graded):
    row = graded["rows"]["lab1_private.zip"]
    assert row["status"] == "graded", row
    assert float(row["tau"]) == float(row["K"]) == float(row["f_c"]) == 0.0, row


def test_worksheet_cannot_read_the_key(graded):
    """Neither the environment, a key file, ~/.config nor another process's environment: the
    worksheet scores a point for each only if it found the key."""
    row = graded["rows"]["lab1_keyread.zip"]
    assert row["status"] == "graded", row
    assert float(row["trust"]) == 0.0 and float(row["pre_speed"]) == 0.0, row


def test_no_key_argv_cwd_or_path_in_feedback_or_grades(graded):
    texts = [graded["grades_text"], *graded["feedback"].values()]
    assert KEY not in graded["stdout"]
    for t in texts:
        assert KEY not in t
        assert str(graded["tmp"]) not in t
        assert "jerklab-grade-" not in t and "sheetrun" not in t and "argv" not in t
    fb = _fb(graded, "lab1_keyread.zip")
    assert "RuntimeError" in fb and "leak" not in fb


def test_no_write_to_other_submissions_grades_feedback_or_cache(graded):
    subs, tmp = graded["subs"], graded["tmp"]
    after = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in subs.iterdir()}
    assert after == graded["before"]
    assert not (tmp / "pwned-by-writes").exists()
    assert "pwned" not in graded["grades_text"]
    assert not (graded["grades"].parent / "feedback" / "x.txt").exists()
    for p in graded["cache"].rglob("*"):
        if p.is_file():
            assert p.read_bytes() != b"pwned", p
    assert graded["rows"]["lab1_writes.zip"]["status"] == "graded"


def test_detached_child_is_gone_and_grades_unchanged(graded):
    assert not (graded["tmp"] / "pwned-by-child").exists()
    assert graded["grades"].read_text() == graded["grades_text"]
    alive = []
    for e in os.listdir("/proc"):
        try:
            if PROBE.encode() in Path("/proc", e, "cmdline").read_bytes():
                alive.append(e)
        except OSError:
            pass
    assert not alive, f"processes of the submission still running: {alive}"
    row = graded["rows"]["lab1_escape.zip"]
    assert row["status"] == "graded" and float(row["pre_speed"]) == 1.0, row


@pytest.mark.parametrize("file", ["lab1_pathid.zip", "lab1_nulid.zip", "lab1_longid.zip"])
def test_bad_ids_get_an_error_row_and_write_nothing_outside(graded, file):
    row = graded["rows"][file]
    assert row["status"].startswith("error") and "student ID" in row["status"], row
    assert float(row["total"]) == 0.0
    outside = [p for p in graded["tmp"].rglob("*evil-by-id*")] + [
        p for p in graded["tmp"].parent.glob("*evil-by-id*")
    ]
    assert not outside
    names = list(graded["feedback"])
    assert all("/" not in n and "\0" not in n and len(n) < 200 for n in names)
    assert len(names) == len(graded["rows"])  # one feedback file a row, all in feedback/


def test_zip_bomb_refused_unread(graded):
    row = graded["rows"]["lab1_bomb.zip"]
    assert row["status"].startswith("error") and "uncompressed" in row["status"], row
    assert float(row["total"]) == 0.0


def test_duplicates_flagged(graded):
    rows = graded["rows"]
    for f in ("lab1_copyA.zip", "lab1_copyB.zip"):
        assert "identical notebook" in rows[f]["flags"], rows[f]
    for f in ("lab1_twiceA.zip", "lab1_twiceB.zip"):
        assert "duplicate ID" in rows[f]["flags"], rows[f]
    assert rows["lab1_honest.zip"]["flags"] == ""


def test_csv_formulas_quoted(graded):
    rows = graded["rows"]
    assert "=1+2*3.ipynb" in rows
    raw = list(csv.reader(graded["grades"].open()))
    cells = [c for r in raw for c in r]
    assert "'=1+2*3.ipynb" in cells and "'+1-2" in cells and "'@sum" in cells
    header = raw[0]
    text_cols = {header.index(c) for c in ("student", "file", "status", "flags")}
    for r in raw[1:]:
        for i in text_cols:
            assert not r[i].startswith(("=", "+", "-", "@")), r[i]


def test_planted_autograder_in_shared_tmp_is_not_used(graded):
    row = graded["rows"]["lab1_empty.ipynb"]
    assert row["status"] == "graded" and float(row["total"]) == 0.0, row
    cache = graded["cache"]
    assert (os.stat(cache).st_mode & 0o777) == 0o700


def test_every_attack_judged_blocked(graded):
    """The verdicts ``python -m benchmarks security`` prints, on this run."""
    verdicts = [(name, *judge(graded)) for name, judge in JUDGES]
    assert all(ok for _, ok, _ in verdicts), [v for v in verdicts if not v[1]]


def test_grading_rate(graded):
    """Every submission of the class folder (about 20, one a full worksheet) in one run."""
    n = len(graded["rows"])
    assert n >= 18
    print(f"{n} submissions in {graded['seconds']:.0f} s")


def test_tampered_cache_is_found_and_made_again(tmp_path, monkeypatch):
    """A file of the instructor-only cache changed (by hand, or by an earlier unsandboxed run):
    verified by hash before use, so it is made again from the master."""
    from jerklab.lab import grade

    monkeypatch.setenv("JERKLAB_CACHE", str(tmp_path / "cache"))
    dist = grade.verified_autograder(1)
    target = next((dist / "student").glob("*.ipynb"))
    good = target.read_bytes()
    target.write_bytes(good.replace(b"S.verify", b"S.verifx"))
    with pytest.warns(RuntimeWarning, match="differs from its signed index"):
        dist2 = grade.verified_autograder(1)
    assert (dist2 / "student" / target.name).read_bytes() == good
    assert grade.questions(1)["K"] == (3.0, "K")


def test_cache_of_another_user_or_open_to_others_refused(tmp_path, monkeypatch):
    from jerklab.lab import grade

    root = tmp_path / "cache"
    root.mkdir(mode=0o777)
    os.chmod(root, 0o777)
    monkeypatch.setenv("JERKLAB_CACHE", str(root))
    grade._cache_root()
    assert (os.stat(root).st_mode & 0o777) == 0o700  # made instructor-only
    link = tmp_path / "link"
    link.symlink_to(root)
    monkeypatch.setenv("JERKLAB_CACHE", str(link))
    with pytest.raises(RuntimeError, match="not a folder"):
        grade._cache_root()


def test_refuses_without_bubblewrap_and_says_why(tmp_path):
    subs = tmp_path / "subs"
    subs.mkdir()
    (subs / "lab1_a.ipynb").write_bytes(_small("a", "pre_speed = 180.0"))
    empty = tmp_path / "bin"
    empty.mkdir()
    env = dict(
        os.environ,
        PATH=str(empty),
        JERKLAB_INSTRUCTOR_KEY=KEY,
        JERKLAB_CACHE=str(tmp_path / "cache"),
    )
    r = subprocess.run(
        [sys.executable, "-m", "jerklab.lab", "grade", str(subs), "--out", str(tmp_path / "g.csv")],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 2
    assert "bubblewrap" in r.stderr and "--unsafe-no-sandbox" in r.stderr
    assert "instructor key" in r.stderr
    assert not (tmp_path / "g.csv").exists()


def test_unsafe_no_sandbox_grades_and_warns(tmp_path):
    """The escape hatch for a machine without bubblewrap: the same answers-out path, with a
    warning that says what is lost."""
    subs = tmp_path / "subs"
    subs.mkdir()
    (subs / "lab1_a.ipynb").write_bytes(_small("unsafe", "pre_speed = 180.0\ntrust = 'pem'"))
    env = dict(os.environ, JERKLAB_INSTRUCTOR_KEY=KEY, JERKLAB_CACHE=str(tmp_path / "cache"))
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "jerklab.lab",
            "grade",
            str(subs),
            "--out",
            str(tmp_path / "g.csv"),
            "--unsafe-no-sandbox",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "no isolation" in r.stderr
    (row,) = list(csv.DictReader((tmp_path / "g.csv").open()))
    assert row["status"] == "graded" and float(row["total"]) == 2.0, row


def test_decode_answer_takes_plain_data_only():
    from jerklab.controller import DiscreteGains
    from jerklab.lab.grade import decode_answer

    assert decode_answer([1.5, "pem", True, None]) == [1.5, "pem", True, None]
    assert decode_answer("nan") != decode_answer("nan")  # a float NaN: the check says not finite
    g = decode_answer(
        {
            "__jerklab__": "DiscreteGains",
            "kpd": 1.0,
            "kid": 0.1,
            "kdd": 2.0,
            "Ts": 0.005,
            "gamma": 0.0,
            "loop": "position",
            "design": {"sigma": 3.0},
        }
    )
    assert isinstance(g, DiscreteGains) and g.design == {"sigma": 3.0}
    for bad in (
        {"__jerklab__": "unsupported", "type": "Liar"},
        {"__jerklab__": "DiscreteGains", "kpd": "1", "kid": 0, "kdd": 0, "Ts": 0.005, "gamma": 0},
        {"__jerklab__": "DiscreteGains", "kpd": 1, "kid": 0, "kdd": 0, "Ts": -1, "gamma": 0},
        "x" * 20_000,
        2**80,
    ):
        with pytest.raises(ValueError):
            decode_answer(bad)
    deep = []
    for _ in range(20):
        deep = [deep]
    with pytest.raises(ValueError, match="nested"):
        decode_answer(deep)


def test_csv_cell_quotes_formulas_only():
    from jerklab.lab.grade import csv_cell

    for s in ("=1+2*3", "+1-2", "-3", "@sum(A1)", "\t=x"):
        assert csv_cell(s) == "'" + s
    assert csv_cell("alice") == "alice" and csv_cell(-3.0) == -3.0 and csv_cell(2) == 2


def test_read_handin_refuses_declared_size_and_bad_ids(tmp_path, monkeypatch):
    from jerklab.lab import handin
    from jerklab.lab.handin import pack

    p = pack(
        {"notebook/x.ipynb": b"{}", "recordings/a.csv": bytes(5000)}, "ok", 1, tmp_path / "a.zip"
    )
    monkeypatch.setattr(handin, "MAX_UNCOMPRESSED_BYTES", 4000)
    with pytest.raises(handin.HandinError, match="uncompressed"):
        handin.read_handin(p)
    monkeypatch.undo()
    for sid in ("../x", "a/b", "nul\0", "x" * 65, "", 42):
        q = pack({"notebook/x.ipynb": b"{}"}, sid, 1, tmp_path / "b.zip")
        with pytest.raises(handin.HandinError, match="student ID"):
            handin.read_handin(q)
    assert (
        handin.read_handin(pack({"notebook/x.ipynb": b"{}"}, " Bob ", 1, tmp_path / "c.zip"))[
            "student"
        ]
        == "bob"
    )


@pytest.mark.parametrize("lab", [2, 3, 4])
def test_honest_worksheets_of_labs_2_to_4_score_full_marks(lab, tmp_path, monkeypatch):
    """Solved worksheets in the sandbox: every answer type (the gains, their design's complex
    z-poles, tuples, strings) crosses the export and scores against the served motor."""
    import re

    import nbformat

    from jerklab.lab import grade

    require_tool("bwrap", "prlimit")
    monkeypatch.setenv("JERKLAB_INSTRUCTOR_KEY", KEY)
    nb = nbformat.read(
        grade.verified_autograder(lab) / "autograder" / grade.student_version_name(lab),
        as_version=4,
    )
    for c in nb.cells:
        if c.cell_type == "code":
            c.source = grade._OTTER_INIT.sub(grade._CHECKS_INIT, c.source)
            c.source = re.sub(r'^STUDENT = "[^"]*"', f'STUDENT = "full{lab}"', c.source, flags=re.M)
    res = grade.grade_one(lab, nbformat.writes(nb).encode(), f"full{lab}", timeout=600)
    assert res["error"] is None, res
    missed = {q: m for q, (s, mx, m) in res["scores"].items() if s < mx}
    assert not missed and len(res["scores"]) >= 6, missed


def test_a_class_on_a_profile_is_graded_on_it(tmp_path, monkeypatch):
    """``grade --profile``: the served hidden motor is drawn around the profile's ranges (the
    37D gearmotor: K 2-3.5 rad/(V s), far below the paper's class, 15-45), the worksheet (its
    PROFILE line left at None) adopts the grader's profile, and the solved lab 1 scores full
    marks on it; a profile the grader does not know is refused naming the option."""
    from jerklab.lab import grade
    from jerklab.lab.__main__ import main as lab_main
    from jerklab.lab.motors import hidden_truth, student_motor
    from jerklab.rig import load_profile

    require_tool("bwrap", "prlimit")
    monkeypatch.setenv("JERKLAB_INSTRUCTOR_KEY", KEY)
    prof = load_profile("pololu-37d-30")
    truth = hidden_truth(student_motor("prof1", KEY.encode(), profile=prof))
    assert prof.K_range[0] <= truth["K"] <= prof.K_range[1] and truth["K"] < 15.0
    res = grade.grade_one(
        1, grade.solved_master(1, "prof1"), "prof1", timeout=600, profile=prof.name
    )
    assert res["error"] is None, res
    missed = {q: m for q, (s, mx, m) in res["scores"].items() if s < mx}
    assert not missed and len(res["scores"]) >= 6, missed
    with pytest.raises(SystemExit):
        lab_main(["grade", str(tmp_path), "--profile", "no-such-motor"])
