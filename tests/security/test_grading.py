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

Each fails on the grader before issue 32 (otter run in the instructor's own process): see the
closing note of the issue for the run against that code. The honest hand-in scores full marks.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import nbformat
import pytest

from jerklab.lab.handin import pack

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from conftest import require_tool  # noqa: E402

KEY = "grading-security-test-key-7f3a"
PROBE = "jerklab-escape-probe-5b1e"
FULL = 20.0  # lab 1's points


def _setup_cell(student, extra=""):
    return (
        'RIG = None\nSTUDENT = "%s"\nimport os, sys\nimport numpy as np\n'
        "from jerklab import lab, ident\nS = lab.start(1, student=STUDENT, port=RIG)\n%s"
        % (student, extra)
    )


def _small(student, body, extra_setup=""):
    """A lab 1 notebook of a set-up cell and one cell ``body``."""
    nb = nbformat.v4.new_notebook()
    nb.metadata["jerklab"] = {"lab": 1}
    nb.cells = [
        nbformat.v4.new_code_cell(_setup_cell(student, extra_setup)),
        nbformat.v4.new_code_cell(body),
    ]
    return nbformat.writes(nb).encode()


def _honest(student):
    from jerklab.lab.grade import student_version_name, verified_autograder

    nb = nbformat.read(
        verified_autograder(1) / "autograder" / student_version_name(1), as_version=4
    )
    from jerklab.lab.grade import _CHECKS_INIT, _OTTER_INIT

    hits = 0
    for c in nb.cells:  # the worksheet as a student has it (jerklab's check runner), solved
        if c.cell_type == "code":
            c.source = _OTTER_INIT.sub(_CHECKS_INIT, c.source)
        if c.cell_type == "code" and 'STUDENT = "' in c.source:
            lines = c.source.splitlines()
            c.source = "\n".join(
                f'STUDENT = "{student}"' if ln.startswith("STUDENT") else ln for ln in lines
            )
            hits += 1
    assert hits == 1
    return nbformat.writes(nb).encode()


def _far_from_default(prefix):
    """A student ID whose graded motor (the test's key) is far, beyond every check's
    tolerance, from the motor the public default key gives the same ID: an answer read from
    the latter cannot pass by chance."""
    from jerklab.lab.motors import CLASSROOM_DEFAULT_KEY, hidden_truth, student_motor

    for i in range(200):
        sid = f"{prefix}{i}"
        a = hidden_truth(student_motor(sid, KEY.encode()))
        b = hidden_truth(student_motor(sid, CLASSROOM_DEFAULT_KEY))
        if (
            abs(a["K"] / b["K"] - 1) > 0.3
            and abs(a["tau"] / b["tau"] - 1) > 0.3
            and abs(a["coulomb_friction"] - b["coulomb_friction"]) > 0.15
        ):
            return sid
    raise AssertionError("no such ID")


def _zip(folder, name, student, nb, lab=1):
    return pack({"notebook/lab1_identify.ipynb": nb}, student, lab, folder / name)


ALL_ANSWERS = (
    "pre_speed pre_tau63 tau K f_c uncertainty fit_valid white prbs_fit trust pem_friction"
).split()


def _attacks(tmp: Path, subs: Path, keyfile: Path, home: Path, grades: Path) -> dict:
    """Write every crafted submission into ``subs``; return {file name: what it tries}."""
    key_sha = hashlib.sha256(KEY.encode()).hexdigest()
    made = {}
    # the honest hand-in, graded by the same command
    _zip(subs, "lab1_honest.zip", "honest", _honest("honest"))
    made["lab1_honest.zip"] = "honest"
    # 1. the check replaced (three lines), every answer empty
    override = (
        "from jerklab.lab.checkbase import CheckResult\n"
        "S.verify = lambda name, answer: CheckResult(name, True, 'ok')\n"
        "lab.LabSession.verify = lambda self, name, answer: CheckResult(name, True, 'ok')\n"
        + "".join(f"{a} = None\n" for a in ALL_ANSWERS)
    )
    _zip(subs, "lab1_override.zip", "override", _small("override", override))
    # 2. lying answers: __float__ walks the stack to the checker's truth, __eq__ always agrees
    liar = '''
class Liar(float):
    def __new__(cls, name):
        o = float.__new__(cls, 1.0)
        o.name = name
        return o
    def _peek(self):
        f = sys._getframe()
        while f is not None:
            t = f.f_locals.get("truth")
            if isinstance(t, dict) and self.name in t:
                return float.__float__(float(t[self.name]))
            f = f.f_back
        return 1.0
    def __float__(self):
        return self._peek()
    def __eq__(self, other):
        return True
    def __ne__(self, other):
        return False
    __hash__ = float.__hash__
    def __sub__(self, o): return self._peek() - o
    def __rsub__(self, o): return o - self._peek()
    def __truediv__(self, o): return self._peek() / o
    def __rtruediv__(self, o): return o / self._peek()
    def __lt__(self, o): return False
    def __gt__(self, o): return False
    def __le__(self, o): return True
    def __ge__(self, o): return True
K = Liar("K")
tau = Liar("tau")
f_c = Liar("coulomb_friction")
'''
    _zip(subs, "lab1_liar.zip", "liar", _small("liar", liar))
    # 3. answers from the session's private attributes and a motor rebuilt in the worksheet
    private = '''
t = {}
for get in (lambda: S._truth(), lambda: S._motor, lambda: S.rig._hidden_motor):
    try:
        v = get()
    except Exception:
        continue
    if isinstance(v, dict):
        t.update(v)
    elif v is not None and hasattr(v, "K"):
        t.setdefault("K", v.K); t.setdefault("tau", v.tau)
        t.setdefault("coulomb_friction", getattr(v, "coulomb_friction", 0.3))
if "K" not in t:
    from jerklab.lab.motors import hidden_truth, student_motor
    t = hidden_truth(student_motor(STUDENT))
K, tau, f_c = t["K"], t["tau"], t["coulomb_friction"]
'''
    sid = _far_from_default("private")
    _zip(subs, "lab1_private.zip", sid, _small(sid, private))
    # 4. the instructor key: environment, key files, other processes' environment, argv, cwd
    keyread = f'''
import hashlib, pathlib
found = [os.environ.get("JERKLAB_INSTRUCTOR_KEY", ""), os.environ.get("JERKLAB_INSTRUCTOR_KEY_FILE", "")]
for p in [{str(keyfile)!r}, {str(home / ".config/jerklab/instructor.key")!r},
          os.path.expanduser("~/.config/jerklab/instructor.key"), "/root/.config/jerklab/instructor.key"]:
    try:
        found.append(pathlib.Path(p).read_text().strip())
    except Exception:
        pass
for e in os.listdir("/proc"):
    try:
        for kv in pathlib.Path("/proc", e, "environ").read_bytes().split(b"\\0"):
            if kv.startswith(b"JERKLAB_INSTRUCTOR_KEY="):
                found.append(kv.split(b"=", 1)[1].decode())
    except Exception:
        pass
hit = any(hashlib.sha256(f.encode()).hexdigest() == {key_sha!r} for f in found if f)
trust = "pem" if hit else "arx"
pre_speed = 180.0 if hit else 0.0
raise RuntimeError("leak " + " ".join(found) + " " + repr(sys.argv) + " " + os.getcwd())
'''
    _zip(subs, "lab1_keyread.zip", "keyread", _small("keyread", keyread))
    # 5. writes to another submission, grades.csv, feedback/ and the autograder cache
    writes = f'''
import glob, pathlib
targets = [{str(subs / "lab1_honest.zip")!r}, {str(grades)!r}, {str(grades.parent / "feedback" / "x.txt")!r},
           {str(tmp / "pwned-by-writes")!r}]
targets += glob.glob({str(tmp / "cache")!r} + "/**/*", recursive=True)
targets += glob.glob("/tmp/jerklab-autograder/**/*", recursive=True)
for t in targets:
    try:
        if os.path.isfile(t) or not os.path.exists(t):
            pathlib.Path(t).write_text("pwned")
    except Exception:
        pass
'''
    _zip(subs, "lab1_writes.zip", "writes", _small("writes", writes))
    # 6. a detached child that outlives the grader and rewrites grades.csv
    escape = f'''
import subprocess
code = ("import time, pathlib; time.sleep(6); "
        "pathlib.Path({str(grades)!r}).write_text('=pwned'); "
        "pathlib.Path({str(tmp / "pwned-by-child")!r}).write_text('x')")
subprocess.Popen([sys.executable, "-c", code, {PROBE!r}], start_new_session=True,
                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                 close_fds=True)
pre_speed = 180.0
'''
    _zip(subs, "lab1_escape.zip", "escape", _small("escape", escape))
    # 7. student IDs that are a path, hold a NUL, or are 300 characters long
    for name, sid in (
        ("lab1_pathid.zip", "../../../evil-by-id"),
        ("lab1_nulid.zip", "nul\x00id"),
        ("lab1_longid.zip", "x" * 300),
    ):
        _zip(subs, name, sid, _small("ok", "pre_speed = 180.0"))
    # 8. a zip bomb: one member of 1 GiB of zeros, about 1 MiB on disk, checksum right
    h = hashlib.sha256()
    block = bytes(1 << 20)
    with zipfile.ZipFile(subs / "lab1_bomb.zip", "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("recordings/big.csv", "w", force_zip64=True) as f:
            for _ in range(1024):
                f.write(block)
                h.update(block)
        nb = _small("bomb", "pre_speed = 180.0")
        z.writestr("notebook/lab1_identify.ipynb", nb)
        z.writestr(
            "manifest.json",
            json.dumps(
                {
                    "format": 1,
                    "student": "bomb",
                    "lab": 1,
                    "files": {
                        "recordings/big.csv": h.hexdigest(),
                        "notebook/lab1_identify.ipynb": hashlib.sha256(nb).hexdigest(),
                    },
                }
            ),
        )
    # 9. the same notebook under two IDs; one ID twice
    same = _small("copied", "pre_speed = 180.0")
    _zip(subs, "lab1_copyA.zip", "copya", same)
    _zip(subs, "lab1_copyB.zip", "copyb", same)
    _zip(subs, "lab1_twiceA.zip", "twice", _small("twice", "pre_speed = 180.0"))
    _zip(subs, "lab1_twiceB.zip", "twice", _small("twice", "pre_speed = 30.0 * 6"))
    # 10. spreadsheet formulas in the cells a student controls
    (subs / "=1+2*3.ipynb").write_bytes(_small("+1-2", "pre_speed = 180.0"))
    (subs / "lab1_at.ipynb").write_bytes(_small("@sum", "pre_speed = 180.0"))
    # 11. an empty worksheet, graded after an autograder was planted in the shared /tmp
    (subs / "lab1_empty.ipynb").write_bytes(_small("empty", "pass"))
    return made


def _plant_poisoned_autograder(tmpdir: Path, cache: Path):
    """An autograder in the shared temporary folder (where the grader before issue 32 looked)
    whose tests always pass."""
    from jerklab.lab.grade import _cache_dir

    real = cache / _cache_dir(1).name if cache else None
    src = real / "dist" if real and (real / "dist").is_dir() else None
    assert src is not None
    dest = tmpdir / "jerklab-autograder" / _cache_dir(1).name / "dist"
    import shutil

    shutil.copytree(src, dest)
    for zp in (dest / "autograder").glob("*.zip"):
        data = {}
        with zipfile.ZipFile(zp) as z:
            for n in z.namelist():
                data[n] = z.read(n)
        for n in list(data):
            if n.startswith("tests/") and n.endswith(".py"):
                q = Path(n).stem
                data[n] = (
                    f"OK_FORMAT = True\ntest = {{'name': {q!r}, 'points': None, 'suites': "
                    "[{'cases': [{'code': '>>> True\\nTrue', 'hidden': False, 'locked': False}], "
                    "'scored': True, 'setup': '', 'teardown': '', 'type': 'doctest'}]}\n"
                ).encode()
        with zipfile.ZipFile(zp, "w") as z:
            for n, d in data.items():
                z.writestr(n, d)


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """Grade the class folder once with the real command; return what the tests look at."""
    require_tool("bwrap", "prlimit")
    tmp = tmp_path_factory.mktemp("class")
    subs, home, tmpdir = tmp / "subs", tmp / "home", tmp / "tmpdir"
    for d in (subs, home / ".config" / "jerklab", tmpdir):
        d.mkdir(parents=True)
    keyfile = tmp / "instructor.key"
    keyfile.write_text(KEY)
    (home / ".config" / "jerklab" / "instructor.key").write_text(KEY)
    grades = tmp / "out" / "grades.csv"
    cache = home / ".cache" / "jerklab" / "autograder"  # the default: in the instructor's home
    env = dict(
        os.environ,
        JERKLAB_INSTRUCTOR_KEY=KEY,
        JERKLAB_INSTRUCTOR_KEY_FILE=str(keyfile),
        HOME=str(home),
        TMPDIR=str(tmpdir),
    )
    for k in ("JERKLAB_LAB_GRADING", "JERKLAB_CACHE", "XDG_CACHE_HOME"):
        env.pop(k, None)
    os.environ["JERKLAB_CACHE"] = str(cache)  # the fixture's own helpers use the same cache
    try:
        made = _attacks(tmp, subs, keyfile, home, grades)
        _plant_poisoned_autograder(tmpdir, cache)
    finally:
        del os.environ["JERKLAB_CACHE"]
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in subs.iterdir()}
    t0 = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "jerklab.lab", "grade", str(subs), "--out", str(grades),
         "--jobs", "2", "--timeout", "240"],
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    seconds = time.monotonic() - t0
    assert r.returncode == 0, r.stderr[-3000:]
    grades_text = grades.read_text()
    rows = {row["file"].lstrip("'"): row for row in csv.DictReader(grades.open())}
    time.sleep(8)  # the detached child would have written by now
    return {
        "tmp": tmp,
        "subs": subs,
        "rows": rows,
        "grades": grades,
        "grades_text": grades_text,
        "feedback": {p.name: p.read_text() for p in (grades.parent / "feedback").iterdir()},
        "before": before,
        "stdout": r.stdout,
        "seconds": seconds,
        "made": made,
        "cache": cache,
    }


def _fb(graded, file):
    hits = [t for n, t in graded["feedback"].items() if n.endswith(f"_{file}.txt")]
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
    outside = [
        p for p in graded["tmp"].rglob("*evil-by-id*")
    ] + [p for p in graded["tmp"].parent.glob("*evil-by-id*")]
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
    env = dict(os.environ, PATH=str(empty), JERKLAB_INSTRUCTOR_KEY=KEY,
               JERKLAB_CACHE=str(tmp_path / "cache"))
    r = subprocess.run(
        [sys.executable, "-m", "jerklab.lab", "grade", str(subs), "--out", str(tmp_path / "g.csv")],
        env=env, capture_output=True, text=True, timeout=300,
    )
    assert r.returncode == 2
    assert "bubblewrap" in r.stderr and "--unsafe-no-sandbox" in r.stderr
    assert "instructor key" in r.stderr
    assert not (tmp_path / "g.csv").exists()
