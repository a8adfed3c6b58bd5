"""The crafted submissions of issue 32 ("Grading") and one run of the real grade command on them.

:func:`grade_class` writes a class folder (an honest hand-in and every attack: a replaced
``S.verify``, lying ``__float__``/``__eq__``, answers from private attributes, reading the
instructor key, writing others' files and ``grades.csv``, a detached child, path/NUL/long IDs,
a zip bomb, duplicates, spreadsheet formulas, an autograder planted in the shared temporary
folder), grades it with ``python -m jerklab.lab grade`` in a subprocess (instructor key in its
environment and in key files) and returns what came out. :data:`JUDGES` says, for each attack,
whether it was blocked. ``tests/security/test_grading.py`` asserts on the same run;
``python -m benchmarks security`` prints the verdicts (:mod:`benchmarks.bench_security`).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import nbformat

from benchmarks.bench_security import area
from jerklab.lab.handin import pack

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
    from jerklab.lab import grade
    from jerklab.lab.grade import student_version_name

    verified_autograder = getattr(grade, "verified_autograder", None) or grade._assigned

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


def grade_class(tmp, jobs=2, poison=True, only=None, check=True) -> dict:
    """Build the class folder in ``tmp`` and grade it once with the real command.

    ``jobs`` None leaves ``--jobs`` out (a grader without it); ``only`` keeps just the named
    submission files; ``check`` False returns a failed run (no ``grades.csv``) instead of
    raising."""
    tmp = Path(tmp)
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
    saved = os.environ.get("JERKLAB_CACHE")
    os.environ["JERKLAB_CACHE"] = str(cache)  # the builders below use the same cache
    try:
        made = _attacks(tmp, subs, keyfile, home, grades)
        if only is not None:
            for p in subs.iterdir():
                if p.name not in only:
                    p.unlink()
        if poison:
            _plant_poisoned_autograder(tmpdir, cache)
    finally:
        if saved is None:
            del os.environ["JERKLAB_CACHE"]
        else:
            os.environ["JERKLAB_CACHE"] = saved
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in subs.iterdir()}
    t0 = time.monotonic()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "jerklab.lab",
            "grade",
            str(subs),
            "--out",
            str(grades),
            *(["--jobs", str(jobs)] if jobs else []),
            "--timeout",
            "240",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    seconds = time.monotonic() - t0
    if r.returncode != 0 and check:
        raise RuntimeError(f"the grade command failed ({r.returncode}):\n{r.stderr[-3000:]}")
    grades_text = grades.read_text() if grades.is_file() else ""
    rows = (
        {row["file"].lstrip("'"): row for row in csv.DictReader(grades.open())}
        if grades.is_file()
        else {}
    )
    time.sleep(8)  # the detached child would have written by now
    return {
        "tmp": tmp,
        "subs": subs,
        "rows": rows,
        "grades": grades,
        "grades_text": grades_text,
        "feedback": {
            p.name: p.read_text(errors="replace")
            for p in (grades.parent / "feedback").glob("*")
            if p.is_file()
        },
        "returncode": r.returncode,
        "stderr": r.stderr[-2000:],
        "before": before,
        "stdout": r.stdout,
        "seconds": seconds,
        "made": made,
        "cache": cache,
    }


def _row(res, f):
    return res["rows"].get(f, {})


def _pts(res, f, *qs):
    row = _row(res, f)
    return sum(float(row.get(q) or 0) for q in qs)


def _alive():
    found = []
    for e in os.listdir("/proc"):
        try:
            if PROBE.encode() in Path("/proc", e, "cmdline").read_bytes():
                found.append(e)
        except OSError:
            pass
    return found


def _judge_writes(res):
    subs = res["subs"]
    after = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in subs.iterdir()}
    changed = [n for n in after if after[n] != res["before"].get(n)]
    hit = changed or (res["tmp"] / "pwned-by-writes").exists() or "pwned" in res["grades_text"]
    return not hit, f"changed: {changed}" if changed else (
        "wrote outside" if hit else "nothing written"
    )


def _judge_ids(res):
    rows = [_row(res, f) for f in ("lab1_pathid.zip", "lab1_nulid.zip", "lab1_longid.zip")]
    ok = all(r.get("status", "").startswith("error") for r in rows) and not list(
        res["tmp"].rglob("*evil-by-id*")
    )
    return ok, "; ".join(r.get("status", "no row")[:60] for r in rows)


#: (attack, judge(result) -> (blocked, outcome)) in the order of the issue
JUDGES = [
    (
        "honest hand-in scores full marks",
        lambda r: (
            float(_row(r, "lab1_honest.zip").get("total") or 0) == FULL,
            f"{_row(r, 'lab1_honest.zip').get('total')} / {FULL:g}",
        ),
    ),
    (
        "replaced S.verify",
        lambda r: (
            float(_row(r, "lab1_override.zip").get("total") or 0) == 0.0,
            f"{_row(r, 'lab1_override.zip').get('total')} / {FULL:g}",
        ),
    ),
    (
        "lying __float__ / __eq__",
        lambda r: (
            _pts(r, "lab1_liar.zip", "K", "tau", "f_c") == 0.0,
            f"K+tau+f_c {_pts(r, 'lab1_liar.zip', 'K', 'tau', 'f_c'):g} / 8",
        ),
    ),
    (
        "answers from S._truth() and private attributes",
        lambda r: (
            _pts(r, "lab1_private.zip", "K", "tau", "f_c") == 0.0,
            f"K+tau+f_c {_pts(r, 'lab1_private.zip', 'K', 'tau', 'f_c'):g} / 8",
        ),
    ),
    (
        "instructor key read (env, key files, /proc)",
        lambda r: (
            _pts(r, "lab1_keyread.zip", "trust", "pre_speed") == 0.0
            and all(KEY not in t for t in [r["grades_text"], *r["feedback"].values()]),
            "found" if _pts(r, "lab1_keyread.zip", "trust", "pre_speed") else "not found",
        ),
    ),
    ("writes to others' files, grades.csv, feedback, cache", _judge_writes),
    (
        "detached child (setsid) outlives the grader",
        lambda r: (
            not (r["tmp"] / "pwned-by-child").exists() and not _alive(),
            "survived" if _alive() or (r["tmp"] / "pwned-by-child").exists() else "gone",
        ),
    ),
    ("path / NUL / 300-character IDs", _judge_ids),
    (
        "zip bomb (1 MiB holding 1 GiB)",
        lambda r: (
            "uncompressed" in _row(r, "lab1_bomb.zip").get("status", ""),
            _row(r, "lab1_bomb.zip").get("status", "no row")[:70],
        ),
    ),
    (
        "same notebook under two IDs, one ID twice",
        lambda r: (
            "identical" in _row(r, "lab1_copyA.zip").get("flags", "")
            and "duplicate" in _row(r, "lab1_twiceA.zip").get("flags", ""),
            "flagged" if _row(r, "lab1_copyA.zip").get("flags") else "not flagged",
        ),
    ),
    (
        "CSV formulas (=1+2*3, +1-2, @sum)",
        lambda r: (
            "\n=1+2*3" not in r["grades_text"]
            and ",=1+2*3" not in r["grades_text"]
            and ",+1-2" not in r["grades_text"]
            and "\n+1-2" not in r["grades_text"],
            "quoted" if "'=1+2*3" in r["grades_text"] else "raw",
        ),
    ),
    (
        "autograder planted in the shared /tmp",
        lambda r: (
            float(_row(r, "lab1_empty.ipynb").get("total") or 0) == 0.0,
            f"empty worksheet {_row(r, 'lab1_empty.ipynb').get('total')} / {FULL:g}",
        ),
    ),
]


ID_ATTACKS = ("lab1_pathid.zip", "lab1_nulid.zip", "lab1_longid.zip")


def _grader_has_jobs() -> bool:
    """Whether the ``grade`` command on the path has ``--jobs`` (a grader from before it does not)."""
    r = subprocess.run(
        [sys.executable, "-m", "jerklab.lab", "grade", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    return "--jobs" in r.stdout


@area("grading")
def run(tmp):
    """The crafted class folder graded once (``--jobs 2``); one row per attack.

    Against a grader from before the fixes (``PYTHONPATH`` naming an older checkout) the
    command runs without ``--jobs`` where it has none; when one bad submission stops the whole
    run (no ``grades.csv``), the ID row says so and the class is graded again without the three
    bad-ID submissions, so that every other attack still gets its verdict."""
    jobs = 2 if _grader_has_jobs() else None
    res = grade_class(tmp / "class", jobs=jobs, check=False)
    if res["rows"]:
        return [(name, *judge(res)) for name, judge in JUDGES]
    crash = res["stderr"].strip().splitlines()[-1:] or ["no message"]
    keep = [n for n in res["before"] if n not in ID_ATTACKS]
    res = grade_class(tmp / "without-ids", jobs=jobs, only=keep)
    rows = []
    for name, judge in JUDGES:
        if judge is _judge_ids:
            rows.append((name, False, f"the whole run stopped, no grades.csv: {crash[0][:70]}"))
        else:
            rows.append((name, *judge(res)))
    return rows
