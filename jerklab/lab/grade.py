"""Grading that student code cannot touch: answers out of a sandbox, scores in the grader.

``otter assign`` turns each master notebook (``jerklab/lab/masters/``, solutions and tests
marked in otter's format) into the student worksheet (solutions stripped) and an autograder
(:func:`assign`, :func:`autograder_zip`), cached in an instructor-only folder (0700, owned by
the grading user, never under the shared temporary folder) and verified by hash before every
use (:func:`verified_autograder`): a file changed or planted there is found and the folder is
made again.

:func:`grade_folder` grades a folder of hand-ins:

1. it reads every submission first (a later one cannot be changed by an earlier one), refuses
   zips over the limits of :mod:`jerklab.lab.handin` and validates every student ID before
   any use;
2. each worksheet runs in its own bubblewrap sandbox (:mod:`jerklab.lab.sandbox`: no network,
   a read-only system, no instructor key, no view of the other submissions, ``grades.csv``,
   ``feedback/`` or the autograder; CPU, memory and process limits; every process ends with
   it). Its rig is the student's hidden motor, simulated *by the grader* and served to the
   sandbox on a pseudo-terminal, so the worksheet measures the motor but cannot read it;
3. the worksheet exports plain answers (JSON numbers, strings, lists) and its recordings
   (:mod:`jerklab.lab.sheetrun`); the grader decodes them (:func:`decode_answer`) and scores
   each question with the same check functions as the worksheet
   (:func:`jerklab.lab.registry.run_check`) against the truth it holds. A replaced
   ``S.verify``, a lying ``__float__`` or ``__eq__`` or an answer read from a private attribute
   gains nothing: the checks run outside, on JSON data;
4. one bad submission gives an error row and never stops the run; ``grades.csv`` quotes cells
   that start with ``= + - @`` and flags duplicate IDs and byte-identical notebooks; feedback
   files land in ``feedback/`` only and hold the checks' messages (no key, argv, cwd or path).

``jobs`` sandboxes run in parallel. Without bubblewrap, grading refuses unless
``unsafe_no_sandbox=True`` (the same answers-out path, but the worksheet then runs as the
grading user, with no isolation).
"""

from __future__ import annotations

import concurrent.futures as _futures
import csv
import hashlib
import hmac
import json
import math
import os
import re
import secrets
import select
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

try:  # the cache's lock (grading runs on Linux; elsewhere one grader at a time)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

import jerklab
from jerklab.controller import DiscreteGains
from jerklab.lab.checkbase import Missing
from jerklab.lab.handin import MAX_ZIP_BYTES, HandinError, read_handin
from jerklab.lab.motors import (
    hidden_truth,
    instructor_key,
    normalize_student,
    practice_key,
    student_device,
    student_motor,
)
from jerklab.lab.plain import Evidence, Run
from jerklab.lab.registry import FLEXIBLE_LABS, HOST_LOOP_LABS, LABS, run_check
from jerklab.lab.sandbox import SAFE_ENV, SandboxUnavailable, bwrap_path, sandbox_command
from jerklab.lab.service import attempt_counts
from jerklab.lab.signing import claims_graded, verify_run
from jerklab.rig import Recording, load_profile
from jerklab.rig.server import DeviceServer
from jerklab.rig.virtual import VirtualDevice

__all__ = [
    "MASTERS",
    "MAX_EXPORT_BYTES",
    "master_path",
    "assign",
    "autograder_zip",
    "verified_autograder",
    "questions",
    "decode_answer",
    "grade_folder",
    "grade_one",
    "prepared_caches",
    "compile_package",
    "solved_master",
    "student_version_name",
    "csv_cell",
]

MASTERS = Path(__file__).parent / "masters"
#: The largest JSON export a sandboxed worksheet may write (answers and recordings).
MAX_EXPORT_BYTES = 64 * 2**20
_RIG_IN_SANDBOX = "/dev/ttyJERKLAB0"


def student_version_name(lab: int) -> str:
    return f"lab{lab}_{LABS[lab]}.ipynb"


def master_path(lab: int) -> Path:
    return MASTERS / student_version_name(lab)


def _otter(*args, cwd=None, timeout=600):
    cmd = [sys.executable, "-m", "otter", *map(str, args)]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def _assign_into(lab: int, dest: Path) -> Path:
    src = master_path(lab)
    work = dest / "master"
    work.mkdir(parents=True, exist_ok=True)
    shutil.copy(src, work / src.name)
    out = dest / "dist"
    r = _otter("assign", work / src.name, out, "-v", cwd=work)
    if r.returncode != 0 or not (out / "student" / src.name).is_file():
        raise RuntimeError(
            f"otter assign failed for lab {lab}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
        )
    return out


# ------------------------------------------------------------------ the instructor-only cache
def _cache_root() -> Path:
    """``$JERKLAB_CACHE``, else ``$XDG_CACHE_HOME/jerklab/autograder``, else
    ``~/.cache/jerklab/autograder``: created 0700; refused unless the grading user owns it and
    nobody else may enter it."""
    env = os.environ.get("JERKLAB_CACHE")
    if env:
        root = Path(env)
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        root = (Path(xdg) if xdg else Path.home() / ".cache") / "jerklab" / "autograder"
    root.mkdir(parents=True, exist_ok=True, mode=0o700)
    st = os.lstat(root)
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise RuntimeError(f"the autograder cache {root} is not a folder (a link?)")
    if st.st_uid != os.getuid():
        raise RuntimeError(
            f"the autograder cache {root} belongs to another user (uid {st.st_uid}): "
            "set JERKLAB_CACHE to a folder of your own"
        )
    if st.st_mode & 0o077:
        os.chmod(root, 0o700)
    return root


def _cache_secret(root: Path) -> bytes:
    """The cache's own random key (``.index-key``, 0600): it signs each folder's index."""
    p = root / ".index-key"
    try:
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    except FileExistsError:
        st = os.lstat(p)
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
            raise RuntimeError(f"{p} is not a private file of the grading user") from None
        return p.read_bytes()
    with os.fdopen(fd, "wb") as f:
        key = secrets.token_bytes(32)
        f.write(key)
    return key


def _otter_version() -> str:
    """otter-grader's version, without importing it (its import takes seconds)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("otter-grader")
    except PackageNotFoundError:
        import otter  # a source checkout without metadata

        return otter.__version__


def _cache_dir(lab: int) -> Path:
    h = hashlib.sha256(master_path(lab).read_bytes() + _otter_version().encode()).hexdigest()[:16]
    return _cache_root() / f"lab{lab}-{h}"


def _tree_index(dist: Path) -> dict:
    """``{relative path: sha256}`` of every file under ``dist``; RuntimeError for a link, a
    file of another user or one others may write."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(dist, followlinks=False):
        for name in sorted(dirnames + filenames):
            p = Path(dirpath) / name
            st = os.lstat(p)
            if stat.S_ISLNK(st.st_mode):
                raise RuntimeError(f"a link in the autograder: {p.relative_to(dist)}")
            if st.st_uid != os.getuid() or st.st_mode & 0o022:
                raise RuntimeError(f"not the grading user's own file: {p.relative_to(dist)}")
            if stat.S_ISREG(st.st_mode):
                out[str(p.relative_to(dist))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _index_mac(secret: bytes, index: dict) -> str:
    return hmac.new(secret, json.dumps(index, sort_keys=True).encode(), "sha256").hexdigest()


def _verify(d: Path) -> bool:
    """True if ``d/dist`` is exactly what this cache made (every file's hash as its signed
    index holds)."""
    dist, idx = d / "dist", d / "index.json"
    if not dist.is_dir() or not idx.is_file():
        return False
    try:
        stored = json.loads(idx.read_text())
        index = _tree_index(dist)
    except (ValueError, OSError, RuntimeError):
        return False
    mac = _index_mac(_cache_secret(_cache_root()), index)
    return stored.get("files") == index and hmac.compare_digest(str(stored.get("mac", "")), mac)


def verified_autograder(lab: int) -> Path:
    """The ``dist/`` folder of ``otter assign`` for ``lab`` in the instructor-only cache,
    verified by hash; made (again) when it is missing or differs from its signed index.

    One grader at a time checks or makes a lab's folder (an exclusive lock on
    ``.lab<N>.lock`` in the cache): two graders started together, or the parallel test
    workers, never remove the folder the other is making."""
    d = _cache_dir(lab)
    fd = os.open(d.parent / f".lab{lab}.lock", os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o600)
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        return _verified_or_made(lab, d)
    finally:
        os.close(fd)


def _verified_or_made(lab: int, d: Path) -> Path:
    if _verify(d):
        return d / "dist"
    if d.exists():
        warnings.warn(
            f"the cached autograder of lab {lab} ({d}) differs from its signed index: made again",
            RuntimeWarning,
            stacklevel=2,
        )
        shutil.rmtree(d, ignore_errors=True)
    d.mkdir(mode=0o700)
    tmp = Path(tempfile.mkdtemp(prefix="assign-", dir=d))
    try:
        _assign_into(lab, tmp)
        os.rename(tmp / "dist", d / "dist")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    index = _tree_index(d / "dist")
    doc = {"files": index, "mac": _index_mac(_cache_secret(_cache_root()), index)}
    (d / "index.json").write_text(json.dumps(doc, indent=1, sort_keys=True))
    return d / "dist"


_assigned = verified_autograder  # the name the tests of the student versions use


def autograder_zip(lab: int) -> Path:
    """The autograder zip of ``lab`` (made by ``otter assign`` from the master, cached by its
    hash in the instructor-only cache, verified before use)."""
    zips = sorted((verified_autograder(lab) / "autograder").glob("*.zip"))
    if not zips:
        raise RuntimeError(f"otter assign made no autograder zip for lab {lab}")
    return zips[-1]


# otter's initialisation cell becomes jerklab's check runner, so that a student's machine needs no
# otter-grader (jerklab.lab.notebook runs the same checks from the notebook's metadata)
_OTTER_INIT = re.compile(r"# Initialize Otter\nimport otter\ngrader = otter\.Notebook\(")
_CHECKS_INIT = (
    "# The checks (otter-grader's format, run by jerklab without otter)\n"
    "from jerklab.lab.notebook import Notebook\ngrader = Notebook("
)


def assign(out_dir, labs=tuple(LABS)) -> list[Path]:
    """Write the student versions (solutions stripped) of ``labs`` into ``out_dir``."""
    import nbformat

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for lab in labs:
        src = verified_autograder(lab) / "student" / student_version_name(lab)
        nb = nbformat.read(src, as_version=4)
        for c in nb.cells:  # otter stamps ids; keep the committed files stable
            c.pop("id", None)
            if c.cell_type == "code" and _OTTER_INIT.search(c.source):
                c.source = _OTTER_INIT.sub(_CHECKS_INIT, c.source)
            if c.cell_type == "code":
                c.outputs, c.execution_count = [], None
        nb.nbformat_minor = 4
        dst = out_dir / src.name
        nbformat.write(nb, dst)
        written.append(dst)
    return written


# ------------------------------------------------------------------ the questions
_VERIFY = re.compile(r"""S\.verify\(\s*["']([A-Za-z_]\w*)["']\s*,\s*([A-Za-z_]\w*)\s*\)""")


_QUESTIONS: dict = {}  # lab -> questions(lab), verified once per grading run


def questions(lab: int) -> dict:
    """``{question: (points, variable)}`` of ``lab``, in the worksheet's order: read from the
    verified autograder's tests (otter's ``metadata.otter.tests`` of the student version), each
    test's ``S.verify("name", variable)`` naming the variable that holds the answer."""
    if lab in _QUESTIONS:
        return dict(_QUESTIONS[lab])
    nb = json.loads(
        (verified_autograder(lab) / "student" / student_version_name(lab)).read_text("utf-8")
    )
    tests = nb.get("metadata", {}).get("otter", {}).get("tests", {})
    master = _master_points(lab)
    out = {}
    order = [n for n in master if n in tests] + sorted(set(tests) - set(master))
    for name in order:
        test = tests[name]
        code = "\n".join(
            case.get("code", "") for suite in test.get("suites", []) for case in suite["cases"]
        )
        m = _VERIFY.search(code)
        if m is None or m.group(1) != name:
            raise RuntimeError(f"lab {lab}: the test of {name!r} has no S.verify({name!r}, ...)")
        points = test.get("points", master.get(name))
        out[name] = (float(points if points is not None else 1.0), m.group(2))
    if not out:
        raise RuntimeError(f"lab {lab}: the autograder holds no tests")
    _QUESTIONS[lab] = out
    return dict(out)


def _master_points(lab: int) -> dict:
    nb = json.loads(master_path(lab).read_text("utf-8"))
    out = {}
    for c in nb["cells"]:
        src = "".join(c["source"]) if isinstance(c["source"], list) else c["source"]
        if c["cell_type"] == "raw" and src.startswith("# BEGIN QUESTION"):
            name = re.search(r"^name:\s*(\S+)", src, re.M)
            pts = re.search(r"^points:\s*([0-9.]+)", src, re.M)
            if name:
                out[name.group(1)] = float(pts.group(1)) if pts else 1.0
    return out


# ------------------------------------------------------------------ reading submissions
_STUDENT_RE = re.compile(r"""^\s*STUDENT\s*=\s*["']([^"'\n]*)["']""", re.M)


def _notebook_info(data: bytes, name: str):
    """(student as written or None, lab) of a notebook; ValueError if unreadable."""
    import nbformat

    if not data.strip():
        raise ValueError("empty notebook file")
    try:
        nb = nbformat.reads(data.decode("utf-8"), as_version=4)
    except Exception as exc:  # nbformat raises several kinds on junk
        raise ValueError(f"not a readable notebook ({type(exc).__name__})") from None
    lab = nb.metadata.get("jerklab", {}).get("lab")
    if lab is None:
        m = re.search(r"lab(\d)", name)
        lab = int(m.group(1)) if m else None
    student = None
    for c in nb.cells:
        if c.cell_type == "code":
            m = _STUDENT_RE.search(c.source)
            if m:
                student = m.group(1)
                break
    return student, lab


def _valid_id(student, where) -> str:
    try:
        return normalize_student(student)
    except (TypeError, ValueError):
        shown = repr(student)
        shown = shown if len(shown) <= 40 else shown[:37] + "..."
        raise ValueError(
            f"{where} student ID {shown} is not 1-64 letters, digits and ._@+- "
            "(refused before any use)"
        ) from None


def _handin_recordings(files: dict, key: bytes, student: str, lab: int) -> tuple[list, list]:
    """(verified, rejected): the names of a hand-in's recordings (``recordings/<name>.csv`` +
    ``.json``) that claim to come from the class rig service (:func:`jerklab.lab.signing.
    claims_graded`) and whose signature verifies, or does not (or that cannot be read)."""
    verified, rejected = [], []
    names = sorted(
        n[len("recordings/") : -len(".json")]
        for n in files
        if n.startswith("recordings/") and n.endswith(".json") and n.count("/") == 1
    )
    for name in names[:500]:
        meta_bytes = files[f"recordings/{name}.json"]
        try:
            meta = json.loads(meta_bytes)
        except ValueError:
            continue  # not a sidecar: nothing claimed
        if not claims_graded(meta):
            continue
        shown = _plain_text(name, 40)
        csv_bytes = files.get(f"recordings/{name}.csv")
        if csv_bytes is None:
            rejected.append(shown)
            continue
        with tempfile.TemporaryDirectory(prefix="jerklab-grade-rec-") as tmp:
            (Path(tmp) / "r.csv").write_bytes(csv_bytes)
            (Path(tmp) / "r.json").write_bytes(meta_bytes)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    run = Run.from_recording(Recording.load(Path(tmp) / "r.csv"))
            except Exception:  # an edited file the loader refuses: not what was served
                rejected.append(shown)
                continue
        why = verify_run(key, run, meta.get("signature"), student, lab)
        (verified if why is None else rejected).append(shown)
    return verified, rejected


def _read_submission(p: Path) -> dict:
    """One submission, read and validated: ``{"student", "lab", "notebook", "notes", "mode"}``
    (``mode``: "practice" when the hand-in's manifest says so, else "graded")."""
    st = os.lstat(p)
    if not stat.S_ISREG(st.st_mode):
        raise ValueError("not a regular file (a link?)")
    if st.st_size > MAX_ZIP_BYTES:
        raise ValueError(f"larger than {MAX_ZIP_BYTES // 2**20} MiB")
    with open(p, "rb", opener=lambda f, fl: os.open(f, fl | os.O_NOFOLLOW)) as f:
        data = f.read(MAX_ZIP_BYTES + 1)
    notes = []
    mode = "graded"
    signed = {"verified": [], "rejected": []}
    if p.suffix.lower() == ".zip":
        h = read_handin(p, data=data)
        student, lab, nb = h["student"], h["lab"], h["notebook"]
        mode = "practice" if h.get("mode") == "practice" else "graded"
        if nb is None:
            raise HandinError(f"{p.name}: no notebook in the hand-in")
        s2, _ = _notebook_info(nb, h["notebook_name"] or "")
        if s2 is not None and s2.strip().lower() != student:
            notes.append(
                "the notebook names another student than the manifest: graded as the manifest's"
            )
            nb = _STUDENT_RE.sub(f'STUDENT = "{student}"', nb.decode("utf-8"), count=1).encode()
        notes.append(f"manifest verified ({len(h['files'])} files)")
        if lab in LABS:
            signer, _ = instructor_key(warn=False)
            ok, bad = _handin_recordings(h["files"], signer, student, int(lab))
            if ok:
                notes.append(f"{len(ok)} recording(s) signed by the class rig, verified")
            for name in bad:
                notes.append(
                    f"recording {name!r} claims the class rig, but its signature does not "
                    "match (edited, or made elsewhere)"
                )
            signed = {"verified": ok, "rejected": bad}
    else:
        nb = data
        student, lab = _notebook_info(nb, p.name)
        if student is None:
            raise ValueError('no `STUDENT = "..."` line in the notebook')
        student = _valid_id(student, "the notebook's")
    if lab not in LABS:
        raise ValueError(f"cannot tell which lab this is (lab = {str(lab)[:20]!r})")
    return {
        "student": student,
        "lab": int(lab),
        "notebook": nb,
        "notes": notes,
        "mode": mode,
        "recordings": signed,
    }


# ------------------------------------------------------------------ decoding and scoring
def decode_answer(x, depth=0):
    """An exported answer (JSON data) as the checks take it: numbers, strings, booleans, None
    and lists as they are, ``{"__jerklab__": "complex", "re", "im"}`` as a complex,
    ``{"__jerklab__": "DiscreteGains", ...}`` as a validated
    :class:`jerklab.controller.DiscreteGains`; ``"nan"``/``"inf"`` as floats. Raises
    ValueError for anything else (the question then scores 0: "could not read your answer")."""
    if depth > 8:
        raise ValueError("answer: nested too deep")
    if x is None or isinstance(x, (bool, int, str)):
        if isinstance(x, int) and not isinstance(x, bool) and abs(x) > 2**63:
            raise ValueError("answer: an integer out of range")
        if isinstance(x, str) and len(x) > 10_000:
            raise ValueError("answer: a text longer than 10000 characters")
        if x in ("nan", "inf", "-inf"):
            return float(x)
        return x
    if isinstance(x, float):
        return x
    if isinstance(x, list):
        if len(x) > 100_000:
            raise ValueError("answer: a list longer than 100000")
        return [decode_answer(v, depth + 1) for v in x]
    if isinstance(x, dict):
        kind = x.get("__jerklab__")
        if kind == "complex":
            re_, im = x.get("re"), x.get("im")
            if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in (re_, im)):
                raise ValueError("answer: a complex number's parts are not numbers")
            return complex(re_, im)
        if kind == "DiscreteGains":
            fields = {}
            for k in ("kpd", "kid", "kdd", "Ts", "gamma"):
                v = x.get(k)
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ValueError(f"answer: gains field {k} is not a number")
                fields[k] = float(v)
            loop = x.get("loop", "position")
            design = decode_answer(x.get("design") or {}, depth + 1)
            if not isinstance(design, dict):
                raise ValueError("answer: gains design is not a mapping")
            return DiscreteGains(loop=str(loop), design=design, **fields)
        if kind is not None:
            raise ValueError(f"answer: a {str(x.get('type', kind))[:40]} cannot be graded")
        return {str(k): decode_answer(v, depth + 1) for k, v in x.items()}
    raise ValueError(f"answer: unexpected {type(x).__name__}")


def _evidence_of(doc, answers, signed=None, rejected=None, profile=None) -> tuple[Evidence, list]:
    """The export's recordings as the checks' evidence. With ``signed = (key, student, lab)``
    a recording that claims to come from the class rig service (a signature, or mode
    "graded") is kept only if its signature verifies (:func:`jerklab.lab.signing.verify_run`);
    the names of those left out are appended to ``rejected``."""
    notes = []
    ev = doc.get("evidence") or {}
    runs = ev.get("runs") if isinstance(ev, dict) else None
    claims = ev.get("claims") if isinstance(ev, dict) else None
    claims = claims if isinstance(claims, dict) else {}
    sigs = ev.get("signatures") if isinstance(ev, dict) else None
    sigs = sigs if isinstance(sigs, dict) else {}
    good = {}
    if isinstance(runs, dict):
        for name, run in list(runs.items())[:200]:
            try:
                r = Evidence.from_dict({"runs": {name: run}}).runs[name]
            except Exception:  # a malformed recording: left out, the check says it is missing
                notes.append(f"recording {str(name)[:40]!r} unreadable: left out")
                continue
            if signed is not None and (claims.get(name) or sigs.get(name) is not None):
                why = verify_run(signed[0], r, sigs.get(name), signed[1], signed[2])
                if why is not None:
                    notes.append(
                        f"recording {_plain_text(name, 40)!r} claims the class rig but {why}: "
                        "left out of the checks"
                    )
                    if rejected is not None:
                        rejected.append(_plain_text(name, 40))
                    continue
            good[str(name)[:80]] = r
    cpr = ev.get("counts_per_rev") if isinstance(ev, dict) else None
    if isinstance(cpr, bool) or not isinstance(cpr, int) or not 1 <= cpr <= 10**7:
        cpr = None
    plain = {k: v for k, v in answers.items() if not isinstance(v, DiscreteGains)}
    # the profile is the grader's (--profile), never what the export says
    return Evidence(runs=good, answers=plain, counts_per_rev=cpr, profile=profile), notes


def _score(lab, qs, doc, truth, signed=None, rejected=None, profile=None) -> tuple[dict, list]:
    """``{question: (score, max, message)}`` of an export ``doc`` against ``truth`` (``signed``,
    ``rejected``: :func:`_evidence_of`; ``profile``: the class's motor profile, a name or a
    file, None for the paper's class motors)."""
    raw = doc.get("answers") if isinstance(doc.get("answers"), dict) else {}
    answers, unread = {}, {}
    for name in qs:
        try:
            answers[name] = decode_answer(raw.get(name))
        except ValueError as exc:
            unread[name] = str(exc)
    evidence, notes = _evidence_of(doc, answers, signed, rejected, profile)
    out = {}
    for name, (points, _) in qs.items():
        if name in unread:
            out[name] = (0.0, points, f"could not read your answer ({unread[name]})")
            continue
        try:
            res = run_check(lab, name, answers[name], evidence, truth)
            ok, msg = bool(res.ok), str(res.message)
        except Missing as exc:
            ok, msg = False, str(exc)
        except Exception as exc:  # a check on junk data: that question only
            ok, msg = (
                False,
                f"could not read your answer ({type(exc).__name__}). Give a value of the type "
                "the task asks for.",
            )
        out[name] = (points if ok else 0.0, points, msg)
    return out, notes


# ------------------------------------------------------------------ one submission
def _served_rig(student, lab, key, profile=None):
    """The hidden motor of ``student`` for ``lab`` (drawn around ``profile``'s ranges, the
    paper's class motors without one), simulated here and served on a pty (in real time for a
    host-in-the-loop lab, :data:`jerklab.lab.registry.HOST_LOOP_LABS`)."""
    motor = student_motor(
        student,
        key,
        plant="flexible" if lab in FLEXIBLE_LABS else "rigid",
        profile=None if profile is None else load_profile(profile),
    )
    dev = student_device(motor)
    # unpaced, except where the worksheet's own law answers each tick (host-in-the-loop): an
    # unpaced device would find every answer late
    server = DeviceServer(
        VirtualDevice(motor, count_noise=dev.count_noise, noise_seed=dev.noise_seed),
        speed=1.0 if lab in HOST_LOOP_LABS else None,
    )
    server.start_pty()
    return server, motor


def _end(proc, deadline) -> bool:
    """Wait until ``proc`` exits or ``deadline``, then kill its whole process group (the
    sandbox; without one, what the worksheet started in its session) and reap it. The pid is
    reaped only after the group is killed, so it cannot have been reused. True if it ended by
    itself."""
    ended = False
    while True:
        try:
            info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            info, ended = None, True
            break
        if info is not None:
            ended = True
            break
        if time.monotonic() >= deadline:
            break
        time.sleep(0.02)
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()
    return ended


def _read_export(proc, fd, timeout) -> tuple[bytes | None, str | None]:
    """Read the export from ``fd`` until the sandbox ends; (data, error)."""
    deadline = time.monotonic() + timeout
    late = f"timed out after {timeout:g} s (an endless loop or a very slow cell?)"
    chunks, size = [], 0
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                _end(proc, 0)
                return None, late
            ready, _, _ = select.select([fd], [], [], min(left, 1.0))
            if not ready:
                continue
            block = os.read(fd, 1 << 20)
            if not block:
                break
            size += len(block)
            if size > MAX_EXPORT_BYTES:
                _end(proc, 0)
                return None, f"the worksheet exported more than {MAX_EXPORT_BYTES // 2**20} MiB"
            chunks.append(block)
    finally:
        os.close(fd)
    if not _end(proc, deadline):
        return None, late
    return b"".join(chunks), None


def grade_one(
    lab,
    notebook: bytes,
    student,
    timeout=300.0,
    sandbox=True,
    key=None,
    numba_cache=None,
    profile=None,
) -> dict:
    """Run one worksheet (its bytes) in a sandbox on the student's served hidden motor, decode
    its export and score it.

    ``numba_cache`` (a folder the grader made, :func:`prepared_caches`) is copied into the
    submission's working copy as its numba cache (``NUMBA_CACHE_DIR``): the worksheet loads the
    compiled kernels instead of compiling them, and what it compiles or changes stays in its
    own copy.

    ``profile`` (a built-in name or a profile file, as given to the class rig service's
    ``--profile``): the hidden motor is drawn around its ranges, the worksheet runs with it
    (``$JERKLAB_LAB_PROFILE_JSON``: the session adopts it, whatever its ``PROFILE`` line says)
    and the checks score on its numbers.

    Returns
    -------
    dict
        ``{"scores": {question: (score, max, message)}, "error": str or None,
        "notes": [str]}``; ``error`` says why nothing was scored (a time-out, no export).
    """
    qs = questions(lab)
    student = normalize_student(student)
    server, motor = _served_rig(student, lab, key, profile)
    work = Path(tempfile.mkdtemp(prefix="jerklab-grade-"))
    try:
        res = _run_and_score(
            lab, qs, notebook, student, timeout, sandbox, server, motor, work, numba_cache, profile
        )
        return res
    finally:
        server.close()
        shutil.rmtree(work, ignore_errors=True)


def _run_sheet(
    lab, qs, notebook, timeout, sandbox, server, motor, work, numba_cache=None, profile=None
):
    """Run ``notebook`` in ``work`` (sandboxed unless ``sandbox`` is False) on ``server``'s rig;
    (export bytes or None, error or None, exit code)."""
    sheet = work / student_version_name(lab)
    sheet.write_bytes(notebook)
    (work / "work").mkdir()
    nb_cache = work / ".numba"
    if numba_cache is not None and Path(numba_cache).is_dir():
        shutil.copytree(numba_cache, nb_cache, symlinks=False)
    else:
        nb_cache.mkdir()
    r, w = os.pipe()
    argv = [
        sys.executable,
        "-I",
        "-m",
        "jerklab.lab.sheetrun",
        str(sheet),
        str(w),
        *(f"{q}={var}" for q, (_, var) in qs.items()),
    ]
    env = {
        "JERKLAB_LAB_RIG": _RIG_IN_SANDBOX if sandbox else server.port,
        "JERKLAB_LAB_RIG_CPR": str(motor.encoder_ppr * motor.decoding),
        "JERKLAB_LAB_WORK": str(work / "work"),
        "JERKLAB_RECORDINGS": str(work / "rec"),
        "JERKLAB_LOCK_DIR": str(work / "locks"),
        "NUMBA_CACHE_DIR": str(nb_cache),
    }
    if profile is not None:  # the profile itself: a file of the instructor's is not in the sandbox
        env["JERKLAB_LAB_PROFILE_JSON"] = json.dumps(load_profile(profile).to_dict())
    if sandbox:
        cmd = sandbox_command(argv, work, env=env, devices=[(server.port, _RIG_IN_SANDBOX)])
    else:
        cmd = argv
        env = {**SAFE_ENV, "HOME": str(work), "MPLCONFIGDIR": str(work / ".mpl"), **env}
    try:
        proc = subprocess.Popen(
            cmd,
            cwd=work,
            env={"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"} if sandbox else env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            pass_fds=(w,),
            start_new_session=True,
        )
    finally:
        os.close(w)
    data, err = _read_export(proc, r, timeout)
    return data, err, proc.returncode


def _run_and_score(
    lab, qs, notebook, student, timeout, sandbox, server, motor, work, numba_cache, profile=None
):
    data, err, code = _run_sheet(
        lab, qs, notebook, timeout, sandbox, server, motor, work, numba_cache, profile
    )
    if err:
        return {"scores": {}, "error": err, "notes": []}
    if not data:
        return {
            "scores": {},
            "error": f"the worksheet ended without exporting its answers (exit code {code})",
            "notes": [],
        }
    try:
        doc = json.loads(data)
        if not isinstance(doc, dict):
            raise ValueError("not an object")
    except (ValueError, RecursionError):
        return {"scores": {}, "error": "the worksheet's export is not readable", "notes": []}
    truth = hidden_truth(motor)
    rejected = []
    signer, _ = instructor_key(warn=False)
    scores, notes = _score(lab, qs, doc, truth, (signer, student, lab), rejected, profile)
    errs = doc.get("errors") if isinstance(doc.get("errors"), list) else []
    if errs:  # the cell and the kind of error only: no text of the sandbox comes back
        first = errs[0] if isinstance(errs[0], dict) else {}
        cell = first.get("cell")
        kind = re.match(r"[A-Za-z_]\w{0,40}", str(first.get("error", "")))
        notes.append(
            f"{len(errs)} cell(s) raised an error; the first: code cell "
            f"{cell if isinstance(cell, int) and not isinstance(cell, bool) else '?'} "
            f"({kind.group(0) if kind else 'an error'})"
        )
    return {"scores": scores, "error": None, "notes": notes, "rejected": rejected}


# ------------------------------------------------------------------ compiled caches
_WARM_STUDENT = "grader-warm-up"
#: hand-ins of a lab from which grade_folder warms its compiled cache up (a warm-up runs the
#: master once; each full hand-in then saves the compile time)
_WARM_UP_FROM = 4


def solved_master(lab: int, student: str) -> bytes:
    """The worksheet of ``lab`` with the master's solutions (the verified autograder's copy,
    with jerklab's check runner as a student's worksheet has it), for ``student``."""
    import nbformat

    nb = nbformat.read(
        verified_autograder(lab) / "autograder" / student_version_name(lab), as_version=4
    )
    for c in nb.cells:
        if c.cell_type == "code":
            c.source = _OTTER_INIT.sub(_CHECKS_INIT, c.source)
            c.source = re.sub(r'^STUDENT = "[^"]*"', f'STUDENT = "{student}"', c.source, flags=re.M)
    return nbformat.writes(nb).encode()


def compile_package() -> bool:
    """Byte-compile the ``jerklab`` package into its own ``__pycache__`` folders (as ``pip
    install`` does), so that each sandbox, where the package is read-only, loads the compiled
    modules instead of compiling about 80 of them again. False when the package is not
    writable by the grading user (then nothing is written)."""
    import compileall

    pkg = Path(jerklab.__file__).resolve().parent
    if not os.access(pkg, os.W_OK):
        return False
    return bool(compileall.compile_dir(str(pkg), quiet=1, workers=1))


def _sources_stamp() -> str:
    """What compiled kernels depend on: jerklab's sources and the Python and numba versions."""
    from importlib.metadata import PackageNotFoundError, version

    h = hashlib.sha256(sys.version.encode())
    try:
        h.update(version("numba").encode())
    except PackageNotFoundError:
        h.update(b"no numba")
    pkg = Path(jerklab.__file__).resolve().parent
    for p in sorted(pkg.rglob("*.py")):
        h.update(str(p.relative_to(pkg)).encode() + b"\0" + p.read_bytes())
    return h.hexdigest()


def _copy_plain_tree(src: Path, dst: Path):
    """Copy the folders and regular files under ``src`` to ``dst`` (links and anything else
    left out)."""
    dst.mkdir(mode=0o700)
    for entry in os.scandir(src):
        if entry.is_symlink():
            continue
        if entry.is_dir(follow_symlinks=False):
            _copy_plain_tree(Path(entry.path), dst / entry.name)
        elif entry.is_file(follow_symlinks=False):
            shutil.copyfile(entry.path, dst / entry.name, follow_symlinks=False)


def prepared_caches(labs, sandbox=True, timeout=600.0) -> Path | None:
    """Make the compiled caches the sandboxes start from (those of ``labs`` that are not made
    yet); return the numba cache folder (or None when there is none).

    1. :func:`compile_package` (the ``.pyc`` files of jerklab, next to its sources);
    2. the numba cache of each lab in the instructor-only cache (``numba-<hash>/cache``, the
       hash of jerklab's sources and the Python and numba versions): made once by
       running the lab's own master (:func:`solved_master`, the instructor's code, never a
       student's) in a sandbox on a practice motor. Each submission gets its own copy
       (:func:`grade_one`), so nothing a submission compiles or writes reaches another.

    A warm-up that fails only costs time: the sandboxes then compile as before.
    """
    compile_package()
    sources = _sources_stamp()
    root = _cache_root() / f"numba-{sources[:16]}"
    root.mkdir(mode=0o700, exist_ok=True)
    cache, index = root / "cache", root / "labs.json"
    fd = os.open(root / ".lock", os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o600)
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            done = json.loads(index.read_text())
        except (OSError, ValueError):
            done = {}
        if not isinstance(done, dict) or done.get("sources") != sources or not cache.is_dir():
            shutil.rmtree(cache, ignore_errors=True)
            done = {"sources": sources, "labs": []}
        for lab in sorted(set(labs)):
            if lab in done["labs"]:
                continue
            made = _warm_up(lab, cache if cache.is_dir() else None, root, sandbox, timeout)
            if made is None:
                continue
            old = root / f".old-{os.getpid()}"
            if cache.is_dir():
                os.rename(cache, old)
            os.rename(made, cache)
            shutil.rmtree(old, ignore_errors=True)
            done["labs"].append(lab)
            index.write_text(json.dumps(done))
        return cache if cache.is_dir() else None
    finally:
        os.close(fd)


def _warm_up(lab, seed, root, sandbox, timeout) -> Path | None:
    """Run lab ``lab``'s master in a sandbox from the numba cache ``seed``; the folder of its
    numba cache afterwards (under ``root``), or None if the run failed."""
    try:
        nb = solved_master(lab, _WARM_STUDENT)
        qs = questions(lab)
    except Exception as exc:  # no autograder: nothing to warm up with
        warnings.warn(f"no compiled cache for lab {lab}: {exc}", RuntimeWarning, stacklevel=3)
        return None
    server, motor = _served_rig(_WARM_STUDENT, lab, practice_key())
    work = Path(tempfile.mkdtemp(prefix="jerklab-warm-"))
    try:
        _, err, _ = _run_sheet(lab, qs, nb, timeout, sandbox, server, motor, work, seed)
        if err:
            warnings.warn(
                f"no compiled cache for lab {lab}: its master {err}", RuntimeWarning, stacklevel=3
            )
            return None
        out = Path(tempfile.mkdtemp(prefix=".new-", dir=root))
        _copy_plain_tree(work / ".numba", out / "cache")
        return out / "cache"
    finally:
        server.close()
        shutil.rmtree(work, ignore_errors=True)


_FILE_ID = re.compile(r"^(?:lab(\d)_(.+)|(.+?)_lab(\d))$")


def _id_from_file_name(stem: str):
    """(student, lab) in a hand-in's file name (``lab1_alice``, ``bob_lab1``), else (None, None)."""
    m = _FILE_ID.match(stem)
    if not m:
        return None, None
    lab, student = (m.group(1), m.group(2)) if m.group(1) else (m.group(4), m.group(3))
    try:
        return normalize_student(student), int(lab)
    except (TypeError, ValueError):
        return None, None


def _plain_text(x, n) -> str:
    """A student-given text for feedback: printable, one line, at most ``n`` characters."""
    s = "".join(ch if ch.isprintable() else " " for ch in str(x))
    return s if len(s) <= n else s[: n - 3] + "..."


def _grade_job(args):
    lab, nb, student, timeout, sandbox, key, profile, numba_cache = args
    try:
        return grade_one(
            lab, nb, student, timeout, sandbox, key=key, numba_cache=numba_cache, profile=profile
        )
    except Exception as exc:  # the grader's own failure on this submission: its row says so
        return {"scores": {}, "error": f"grading failed ({type(exc).__name__})", "notes": []}


# ------------------------------------------------------------------ the CSV and feedback
_FORMULA = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value):
    """A CSV cell a spreadsheet shows as text: a string starting with ``= + - @`` (or a tab,
    a carriage return) gets a leading ``'``; numbers stay numbers."""
    if isinstance(value, str) and value.startswith(_FORMULA):
        return "'" + value
    return value


def _feedback_name(row, taken) -> str:
    """``<ID>_lab<N>_<file stem>.txt`` of plain characters (``_2``, ``_3``... when taken)."""
    stem = Path(row["file"]).stem
    stem = re.sub(r"[^A-Za-z0-9._@+-]", "_", stem)[:60].lstrip(".") or "submission"
    who = row["student"] or "unknown"
    base = f"{who}_lab{row['lab'] or 'X'}_{stem}"
    name, n = f"{base}.txt", 1
    while name in taken:
        n += 1
        name = f"{base}_{n}.txt"
    taken.add(name)
    return name


def _write_feedback(feedback_dir: Path, name: str, text: str):
    """Write ``text`` as ``feedback_dir/name``: a plain name, no link followed, nothing
    outside the folder."""
    if "/" in name or "\0" in name or name in (".", "..") or len(name) > 200:
        raise ValueError("a feedback file name that is not a plain name")
    fd = os.open(feedback_dir / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)


def grade_folder(
    folder,
    out_csv,
    feedback_dir=None,
    timeout=300.0,
    labs=None,
    jobs=1,
    unsafe_no_sandbox=False,
    check_log=None,
    profile=None,
) -> list[dict]:
    """Grade every ``*.zip`` hand-in and bare ``*.ipynb`` in ``folder``.

    Writes ``out_csv`` (one row per submission: student, lab, file, status, flags,
    recordings, one column per question, total, max) and a feedback text file per submission
    into ``feedback_dir`` (default: ``feedback/`` beside the CSV). A corrupt, empty, oversized or unverifiable
    submission, a bad student ID, a time-out or a worksheet that exports nothing gets a row
    with its status and zero points; it never stops the run.

    Every recording that claims to come from the class rig service, in the hand-in or in the
    worksheet's export, must carry the service's signature (:mod:`jerklab.lab.signing`, the
    instructor key): one that does not (edited, or made by the student) is named in the
    ``recordings`` column (``rejected: <names>``) and in ``flags``, and an exported one is left
    out of the checks. ``recordings`` says ``signed: N verified`` for a hand-in whose graded
    recordings all verify.

    Parameters
    ----------
    timeout : float
        Seconds per submission (wall clock).
    labs : iterable of int, optional
        Grade only these labs (others get a row "skipped").
    jobs : int
        Submissions graded at once (one sandbox each).
    unsafe_no_sandbox : bool
        Run worksheets without bubblewrap (no isolation): only when bwrap is missing and the
        submissions are trusted.
    check_log : path, optional
        The class rig service's check log (:func:`jerklab.lab.service.attempt_counts`): each
        row also gets ``attempts_<check>``, how often the student tried each check.
    profile : str or MotorProfile, optional
        The class's motor profile, as given to the class rig service's ``--profile``: every
        hidden motor is drawn around its ranges and every check scores on its numbers
        (default: the paper's class motors).

    Raises
    ------
    SandboxUnavailable
        bubblewrap is missing and ``unsafe_no_sandbox`` is False.
    """
    folder, out_csv = Path(folder), Path(out_csv)
    if not folder.is_dir():
        raise ValueError(f"SUBMISSIONS_DIR {str(folder)!r} is not a folder")
    jobs = int(jobs)
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    timeout = float(timeout)
    if not (math.isfinite(timeout) and timeout > 0):
        raise ValueError(f"timeout must be a positive number of seconds, got {timeout!r}")
    sandbox = not unsafe_no_sandbox
    if profile is not None:
        try:
            load_profile(profile)
        except (TypeError, OSError) as exc:
            raise ValueError(f"profile: {exc}") from None
    if sandbox and (bwrap_path() is None or shutil.which("prlimit") is None):
        raise SandboxUnavailable(
            "grading runs every worksheet in a bubblewrap sandbox, and bwrap (or prlimit) is "
            "not installed: without it a submission runs as you, can read your instructor key "
            "and change other submissions, grades.csv and the autograder. Install it (Debian/"
            "Ubuntu: apt-get install bubblewrap), or pass --unsafe-no-sandbox for trusted "
            "submissions only."
        )
    feedback_dir = Path(feedback_dir) if feedback_dir else out_csv.parent / "feedback"
    feedback_dir.mkdir(parents=True, exist_ok=True)
    wanted = set(LABS) if labs is None else {int(n) for n in labs}
    subs = sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() in (".zip", ".ipynb") and (p.is_file() or p.is_symlink())
    )
    rows, parsed = [], []
    for p in subs:  # every submission read before any runs
        row = {
            "file": p.name,
            "student": "",
            "lab": "",
            "status": "",
            "flags": "",
            "recordings": "",
            "total": 0.0,
            "max": 0.0,
        }
        try:
            sub = _read_submission(p)
            row.update(student=sub["student"], lab=sub["lab"])
        except (HandinError, ValueError, OSError, UnicodeDecodeError) as exc:
            sub = None
            row["status"] = f"error: {_plain_text(exc, 300)}"
            sid, lab_n = _id_from_file_name(p.stem)
            if sid is not None:
                row.update(student=sid, lab=lab_n if lab_n in LABS else "")
        rows.append(row)
        parsed.append(sub)
    _flag(rows, parsed)
    todo = []
    for i, (row, sub) in enumerate(zip(rows, parsed)):
        if sub is None:
            continue
        if sub["lab"] not in wanted:
            row["status"] = "skipped (lab not asked for)"
            continue
        # practice work is re-run on the practice motor the student had (public: the row is
        # flagged, it is not graded work); everything else on the student's graded motor
        key = practice_key() if sub["mode"] == "practice" else None
        if sub["mode"] == "practice":
            row["mode"] = "practice"
            row["flags"] = "; ".join(
                f for f in (row["flags"], "practice: a public motor, not graded work") if f
            )
        todo.append(
            (i, [sub["lab"], sub["notebook"], sub["student"], timeout, sandbox, key, profile])
        )
    _QUESTIONS.clear()
    labs_todo = sorted({a[0] for _, a in todo})
    for lab in labs_todo:
        questions(lab)  # the autograder made and verified once, before the workers start
    # a warm-up costs about one hand-in: worth it from a few hand-ins of a lab on
    per_lab = {lab: sum(1 for _, a in todo if a[0] == lab) for lab in labs_todo}
    warm = [lab for lab, n in per_lab.items() if n >= _WARM_UP_FROM]
    numba_cache = prepared_caches(warm, sandbox, timeout) if todo else None
    todo = [(i, (*a, numba_cache)) for i, a in todo]
    if jobs > 1 and len(todo) > 1:
        with _futures.ProcessPoolExecutor(max_workers=jobs) as pool:
            results = list(pool.map(_grade_job, [a for _, a in todo]))
    else:
        results = [_grade_job(a) for _, a in todo]
    exported_rejected = {}
    for (i, _), res in zip(todo, results):
        row, sub = rows[i], parsed[i]
        sub["notes"].extend(res["notes"])
        exported_rejected[i] = res.get("rejected", [])
        if res["error"]:
            row["status"] = f"error: {res['error']}"
            continue
        for q, (sc, mx, msg) in res["scores"].items():
            row[q] = sc
            row["total"] += sc
            row["max"] += mx
            verdict = "right" if sc >= mx else "not yet"
            sub["notes"].append(
                f"{q}: {sc:g}/{mx:g} ({verdict})" + (f"\n    {msg}" if sc < mx else "")
            )
        row["status"] = "graded"
    for i, (row, sub) in enumerate(zip(rows, parsed)):
        if sub is not None:  # also for a row not graded: the hand-in's recordings are checked
            _recordings_column(row, sub["recordings"], exported_rejected.get(i, []))
    taken = set()
    for row, sub in zip(rows, parsed):
        notes = list(sub["notes"]) if sub else []
        if row["status"].startswith("error"):
            notes.append(f"not graded: {row['status'][7:]}")
        if row["flags"]:
            notes.append(f"flagged: {row['flags']}")
        who = row["student"] or "?"
        text = (
            f"Feedback for {who}, lab {row['lab'] or '?'}, file {_plain_text(row['file'], 80)}\n"
            f"Score: {row['total']:g} / {row['max']:g}  ({row['status'][:300]})\n\n"
            + "\n".join(notes)
            + "\n"
        )
        try:
            _write_feedback(feedback_dir, _feedback_name(row, taken), text)
        except (OSError, ValueError) as exc:
            row["status"] += f" (feedback not written: {type(exc).__name__})"
    if check_log is not None:  # the class rig service's log: attempts per check
        counts = attempt_counts(check_log)
        for r in rows:
            for q, n in counts.get((r["student"], r["lab"]), {}).items():
                r[f"attempts_{q}"] = n
    qcols = [
        q for lab in sorted({r["lab"] for r in rows if r["lab"] in LABS}) for q in _qnames(lab)
    ]
    extra = sorted({k for r in rows for k in r} - set(qcols) - set(_FIXED))
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_csv.with_name(f".{out_csv.name}.{os.getpid()}.tmp")
    with tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(
            f,
            [
                "student",
                "lab",
                "file",
                "status",
                "flags",
                "recordings",
                *qcols,
                *extra,
                "total",
                "max",
            ],
            restval="",
        )
        w.writeheader()
        for r in rows:
            w.writerow({k: csv_cell(v) for k, v in r.items()})
    os.replace(tmp, out_csv)
    return rows


_FIXED = ("student", "lab", "file", "status", "flags", "recordings", "total", "max")

#: ``grades.csv``'s ``recordings`` column when a recording that claims the class rig service
#: fails its signature (and is left out of the checks): ``rejected: <names>``
REJECTED = "rejected"


def _recordings_column(row, handin, exported):
    """Fill the ``recordings`` column (and a flag) from the hand-in's recordings
    (``{"verified", "rejected"}``) and those the worksheet's export left out (``exported``)."""
    bad = list(dict.fromkeys([*handin.get("rejected", []), *exported]))
    if bad:
        row["recordings"] = f"{REJECTED}: " + ", ".join(bad)
        flag = "recordings that claim the class rig fail their signature: " + ", ".join(bad)
        row["flags"] = f"{row['flags']}; {flag}" if row["flags"] else flag
    elif handin.get("verified"):
        row["recordings"] = f"signed: {len(handin['verified'])} verified"


def _qnames(lab):
    try:
        return list(questions(lab))
    except Exception:
        return []


def _flag(rows, parsed):
    """Flag duplicate (student, lab) pairs and byte-identical notebooks in the rows."""
    by_id, by_hash = {}, {}
    for i, sub in enumerate(parsed):
        if sub is None:
            continue
        by_id.setdefault((sub["student"], sub["lab"]), []).append(i)
        by_hash.setdefault(hashlib.sha256(sub["notebook"]).hexdigest(), []).append(i)
    for group, what in (
        (by_id, "duplicate ID (same student and lab as {})"),
        (by_hash, "identical notebook to {}"),
    ):
        for idx in group.values():
            if len(idx) < 2:
                continue
            for i in idx:
                others = ", ".join(rows[j]["file"] for j in idx if j != i)
                flag = what.format(_plain_text(others, 200))
                rows[i]["flags"] = f"{rows[i]['flags']}; {flag}" if rows[i]["flags"] else flag
