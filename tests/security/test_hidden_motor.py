"""Hidden motors that are measured, never read (issue 32, part 1), tried as a student would.

* A graded lab runs in a student's process through the class rig service (a process of its
  own, started as ``python -m jerklab.lab service``); afterwards every object reachable in the
  student's process (``gc.get_objects()`` and what they hold, every module's globals) is
  scanned for the true K and τ of the student's motor, to 1e-6 relative: neither is there.
  The same scan finds them in a process that holds the motor, as every session did before the
  service (the scan can fail).
* A typed ID that is not the login's is refused; a bad token is refused, by the token file and
  by a hub's API.
* Without a service, work is practice: marked in every recording and in the hand-in, checked
  against the student's own recordings, never against the graded motor.
"""

from __future__ import annotations

import gc
import http.server
import json
import math
import os
import pwd
import re
import socket
import subprocess
import sys
import textwrap
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from jerklab.lab import motors
from jerklab.lab.motors import hidden_truth, student_motor

KEY = "security-test-instructor-key-0123456789"
TOKENS = {"tok-alice-7f3a9c1e5b": "alice", "tok-bob-2d8e4f6a0c": "bob"}
ROOT = Path(__file__).resolve().parents[2]


def _clean_env(tmp, **extra):
    """A student's environment: no instructor key anywhere, a home of its own."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JERKLAB_")}
    env.pop("JUPYTERHUB_API_TOKEN", None)
    home = Path(tmp) / "home"
    home.mkdir(exist_ok=True)
    env.update(HOME=str(home), MPLBACKEND="Agg", PYTHONPATH=str(ROOT), **extra)
    return env


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    """The class rig service as its own process (as its own Unix user when the tests run as
    root); yields (url, log path, process)."""
    d = tmp_path_factory.mktemp("classrig")
    os.chmod(d, 0o755)
    keyfile = d / "instructor.key"
    keyfile.write_text(KEY + "\n")
    os.chmod(keyfile, 0o600)
    tokens = d / "tokens.json"
    tokens.write_text(json.dumps(TOKENS))
    log = d / "checks.jsonl"
    env = {k: v for k, v in os.environ.items() if not k.startswith("JERKLAB_")}
    env.update(JERKLAB_INSTRUCTOR_KEY_FILE=str(keyfile), PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "jerklab.lab", "service", "--listen", "127.0.0.1:0"]
    cmd += ["--tokens", str(tokens), "--log", str(log)]
    if os.geteuid() == 0:
        cmd += ["--user", "nobody"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    m = re.search(r"(classrig://\S+)", line)
    if m is None:
        proc.kill()
        raise AssertionError(f"the service did not start: {line!r} {proc.stderr.read()[-2000:]}")
    try:
        yield m.group(1), log, proc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _truth(student, lab=1):
    plant = "flexible" if lab == 4 else "rigid"
    return hidden_truth(student_motor(student, KEY.encode(), plant=plant))


# ------------------------------------------------------------------ the scan of a student's process
SCAN = r'''
def _scan(out):
    """Every number reachable in this process (objects gc knows and what they hold, module
    globals, numbers written in strings) into the .npy file ``out``; and the hidden motors."""
    import gc, re, sys
    import numpy as np
    from jerklab.lab.motors import StudentFlexibleMotor, StudentMotor
    found, arrays, seen = [], [], set()
    num = re.compile(r"[-+]?\d+\.\d+(?:[eE][-+]?\d+)?")

    def take(x):
        if isinstance(x, bool):
            return
        if isinstance(x, (float, int, np.floating, np.integer)):
            try:
                found.append(float(x))
            except OverflowError:
                pass
        elif isinstance(x, complex):
            found.extend((x.real, x.imag))
        elif isinstance(x, np.ndarray) and x.dtype.kind in "fiuc" and id(x) not in seen:
            seen.add(id(x))
            a = np.asarray(x).ravel()
            arrays.append(np.concatenate([a.real, a.imag]).astype(float) if a.dtype.kind == "c"
                          else a.astype(float))
        elif isinstance(x, str) and len(x) < 200000:
            found.extend(float(s) for s in num.findall(x))

    gc.collect()
    objs = gc.get_objects()
    motors = [o for o in objs if isinstance(o, (StudentMotor, StudentFlexibleMotor))]
    for o in objs:
        take(o)
        for r in gc.get_referents(o):
            take(r)
    for mod in list(sys.modules.values()):
        for v in list(getattr(mod, "__dict__", {}).values()):
            take(v)
    vals = np.concatenate([np.asarray(found, dtype=float), *arrays]) if arrays else np.asarray(found)
    np.save(out, vals[np.isfinite(vals)])
    return len(motors)
'''


def _run_student(script, tmp_path, env, timeout=300):
    path = tmp_path / "student.py"
    path.write_text(SCAN + textwrap.dedent(script))
    r = subprocess.run(
        [sys.executable, str(path)],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _hits(values, truth):
    """Which of the true K and τ (τ also in ms) appear among ``values`` to 1e-6 relative."""
    hits = {}
    for name, v in (("K", truth["K"]), ("tau", truth["tau"]), ("tau_ms", truth["tau"] * 1e3)):
        n = int(np.sum(np.abs(values - v) <= 1e-6 * abs(v)))
        if n:
            hits[name] = n
    return hits


GRADED_LAB = """
import json, math, os
from jerklab import lab, ident
S = lab.start(1, folder="work")  # no student ID: the login's token names the student
assert S.mode == "graded" and S.student == "alice"
assert not hasattr(S, "_truth") and not hasattr(S.rig, "_hidden_motor") and not hasattr(S, "_motor")
recs = {V: S.step(V, lab.STEP_SECONDS) for V in lab.SWEEP_VOLTS}
(K, f_c, off), _ = lab.sweep_fit({V: lab.steady_speed(r) for V, r in recs.items()})
r6 = recs[6.0]
tau = ident.fit_dc_motor(r6.voltage, r6.position, r6.Ts, "pem").tau
verdicts = {}
for name, answer in (("pre_speed", 180.0), ("K", K), ("K", K * 2 * math.pi), ("tau", tau),
                     ("tau", tau * 1000), ("f_c", f_c), ("trust", "pem")):
    verdicts.setdefault(name, []).append(S.verify(name, answer).ok)
rp = S.record_prbs(**lab.PRBS)
f = ident.fit_dc_motor(rp.voltage, rp.position, rp.Ts, "pem", offset=True)
verdicts["prbs_fit"] = [S.verify("prbs_fit", (f.K, f.tau)).ok]
mode = json.load(open(str(r6.json_path)))["caller"]["mode"]
# the one-line attacks of issue 32: the session's truth, the rig's motor, regenerating the motor
# (without the key this gives the public practice motor, not the graded one)
import warnings
from jerklab.lab.motors import hidden_truth, student_motor
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    regenerated = hidden_truth(student_motor("alice"))["K"]
S.close()
del S, recs, r6, rp, f, K, tau, f_c, off
n_motors = _scan("values.npy")
out = {"verdicts": verdicts, "motors": n_motors, "mode": mode, "regenerated": regenerated}
print(json.dumps(out))
"""


def test_a_graded_lab_leaves_no_truth_in_the_students_process(service, tmp_path):
    url, log, _ = service
    env = _clean_env(tmp_path, JERKLAB_CLASS_RIG=url, JERKLAB_CLASS_TOKEN="tok-alice-7f3a9c1e5b")
    out = _run_student(GRADED_LAB, tmp_path, env)
    # the lab worked: the service scored the answers against alice's motor
    assert out["verdicts"] == {
        "pre_speed": [True],
        "K": [True, False],
        "tau": [True, False],
        "f_c": [True],
        "trust": [True],
        "prbs_fit": [True],
    }
    assert out["mode"] == "graded" and out["motors"] == 0
    assert abs(out["regenerated"] / _truth("alice")["K"] - 1) > 1e-3
    values = np.load(tmp_path / "values.npy")
    assert values.size > 10000  # the recordings' arrays were scanned
    assert _hits(values, _truth("alice")) == {}
    # every check is logged with its answer; the attempts are counted per student and lab
    from jerklab.lab.service import attempt_counts, check_log, last_verdicts

    last = last_verdicts(log)[("alice", 1)]
    assert last["K"]["ok"] is False and last["K"]["attempts"] == 2 and last["f_c"]["ok"] is True
    counts = attempt_counts(log)[("alice", 1)]
    assert counts["K"] == 2 and counts["tau"] == 2 and counts["prbs_fit"] == 1
    entries = [e for e in check_log(log) if e["student"] == "alice" and e["check"] == "K"]
    assert [e["ok"] for e in entries][-2:] == [True, False]
    assert entries[-1]["answer"] == pytest.approx(entries[-2]["answer"] * 2 * math.pi)


PRACTICE_IN_PROCESS = """
import json
from jerklab import lab
from jerklab.lab.motors import hidden_truth
S = lab.start(1, student="alice", folder="work", key=KEY.encode())  # the motor in this process
S.step(6.0, lab.STEP_SECONDS)
n_motors = _scan("values.npy")
print(json.dumps({"mode": S.mode, "motors": n_motors}))
"""


def test_the_scan_finds_the_truth_in_a_process_that_holds_the_motor(tmp_path):
    """The control: a session that runs the hidden motor in its own process (every session
    before the class rig service did) holds K and τ, and the scan finds both."""
    env = _clean_env(tmp_path)
    out = _run_student(f"KEY = {KEY!r}\n" + PRACTICE_IN_PROCESS, tmp_path, env)
    assert out["mode"] == "instructor" and out["motors"] >= 1
    hits = _hits(np.load(tmp_path / "values.npy"), _truth("alice"))
    assert "K" in hits and "tau" in hits


# ------------------------------------------------------------------ who is asking
def _ask(url, *reqs, timeout=30.0):
    """Send ``reqs`` one by one on one connection; the answers (None once it is closed)."""
    host, _, port = url[len("classrig://") :].rpartition(":")
    out = []
    with socket.create_connection((host, int(port)), timeout=timeout) as s:
        f = s.makefile("rwb")
        for r in reqs:
            try:
                f.write((json.dumps(r) + "\n").encode())
                f.flush()
                line = f.readline()
            except OSError:
                line = b""
            out.append(json.loads(line) if line else None)
    return out


def test_a_typed_id_cannot_act_as_a_classmate(service, tmp_path, monkeypatch):
    url, log, _ = service
    from jerklab import lab

    for k in ("JERKLAB_INSTRUCTOR_KEY", "JERKLAB_INSTRUCTOR_KEY_FILE", "JUPYTERHUB_API_TOKEN"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("JERKLAB_CLASS_TOKEN", "tok-alice-7f3a9c1e5b")
    with pytest.raises(PermissionError, match=r"student: .*'alice'.*'bob'"):
        lab.start(1, student="bob", port=url, folder=tmp_path)
    # on the wire: alice's token with bob's name is refused, and the link is closed
    hello, step = _ask(
        url,
        {"op": "hello", "token": "tok-alice-7f3a9c1e5b", "lab": 1, "student": "bob"},
        {"op": "step", "name": "step_p6V", "voltage": 6.0, "seconds": 0.2},
    )
    assert "cannot act as 'bob'" in hello["error"] and step is None
    # the same ID as the login is fine; bob's own work is bob's: alice's recordings are not his
    S = lab.start(1, student="Alice", port=url, folder=tmp_path)
    assert S.student == "alice"
    rec = S.step(3.0, 0.2)
    assert rec.metadata["caller"]["student"] == "alice"
    S.close()
    hello, check = _ask(
        url,
        {"op": "hello", "token": "tok-bob-2d8e4f6a0c", "lab": 1},
        {"op": "check", "name": "fit_valid", "answer": 90.0},
    )
    assert hello["student"] == "bob"
    assert not check["passed"] and "missing" in check["message"]


def test_the_service_refuses_a_bad_token(service):
    url, _, _ = service
    for token in ("tok-alice-7f3a9c1e5X", "x" * 40, None):
        hello, step, check = _ask(
            url,
            {"op": "hello", "token": token, "lab": 1},
            {"op": "step", "name": "s", "voltage": 6.0, "seconds": 0.2},
            {"op": "check", "name": "K", "answer": 30.0},
        )
        assert "authentication failed" in hello["error"], hello
        assert step is None and check is None
    # nothing before hello
    (step,) = _ask(url, {"op": "step", "name": "s", "voltage": 6.0, "seconds": 0.2})
    assert "authentication failed" in step["error"]


class _FakeHub(http.server.BaseHTTPRequestHandler):
    """JupyterHub's ``GET /hub/api/user``: the model of the token's owner, 403 otherwise."""

    users = {
        "hub-token-carol-91b2c3": {"kind": "user", "name": "carol"},
        "hub-token-service-55aa": {"kind": "service", "name": "grader"},
    }

    def do_GET(self):
        auth = self.headers.get("Authorization", "")
        model = self.users.get(auth[len("token ") :]) if auth.startswith("token ") else None
        if self.path != "/hub/api/user" or model is None:
            self.send_response(403)
            self.end_headers()
            return
        body = json.dumps(model).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


def test_on_the_hub_the_token_is_checked_against_the_hubs_api(tmp_path):
    from jerklab.lab.service import ClassRigService, HubAuth

    hub = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _FakeHub)
    threading.Thread(target=hub.serve_forever, daemon=True).start()
    api = f"http://127.0.0.1:{hub.server_address[1]}/hub/api"
    try:
        with ClassRigService(HubAuth(api), tmp_path / "log.jsonl", key=KEY.encode()) as svc:
            (hello,) = _ask(svc.url, {"op": "hello", "token": "hub-token-carol-91b2c3", "lab": 2})
            assert hello["ok"] and hello["student"] == "carol" and hello["mode"] == "graded"
            for token in ("hub-token-carol-91b2c4", "hub-token-service-55aa"):
                (hello,) = _ask(svc.url, {"op": "hello", "token": token, "lab": 2})
                assert "authentication failed" in hello["error"]
            assert svc.refused == 2
    finally:
        hub.shutdown()
        hub.server_close()


def test_the_service_runs_only_with_the_instructor_key_and_not_as_root(tmp_path):
    from jerklab.lab.service import ClassRigService, TokenFile

    tokens = tmp_path / "t.json"
    tokens.write_text(json.dumps(TOKENS))
    with pytest.raises(ValueError, match="key: the public classroom default"):
        ClassRigService(TokenFile(tokens), tmp_path / "l", key=motors.CLASSROOM_DEFAULT_KEY)
    env = _clean_env(tmp_path)
    r = subprocess.run(
        [sys.executable, "-m", "jerklab.lab", "service", "--tokens", str(tokens)],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and ("instructor key" in r.stderr or "--user" in r.stderr)


def test_the_service_process_is_its_own_user(service):
    """Started as root, the service drops to its own user: a student's process (another user)
    can read neither its memory nor its environment (the kernel makes it non-dumpable)."""
    if os.geteuid() != 0:
        pytest.skip("the tests run as a normal user: the service runs as that user")
    _, _, proc = service
    status = Path(f"/proc/{proc.pid}/status").read_text()
    uid = int(re.search(r"^Uid:\s+(\d+)\s+(\d+)", status, re.M).group(2))
    assert uid == pwd.getpwnam("nobody").pw_uid


# ------------------------------------------------------------------ practice
def test_practice_is_marked_and_checked_on_the_students_own_recordings(tmp_path, monkeypatch):
    from jerklab import lab
    from jerklab.lab import checks

    for k in ("JERKLAB_INSTRUCTOR_KEY", "JERKLAB_INSTRUCTOR_KEY_FILE", "JERKLAB_CLASS_RIG"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("JERKLAB_CLASS_CODE", "me301-test")
    graded = _truth("pia")
    practice = hidden_truth(motors.practice_motor("pia", "me301-test"))
    assert abs(practice["K"] / graded["K"] - 1) > 0.1  # two different motors
    S = lab.start(1, student="pia", folder=tmp_path / "w")
    assert S.mode == "practice"
    recs = {V: S.step(V, lab.STEP_SECONDS) for V in lab.SWEEP_VOLTS}
    for r in recs.values():
        assert json.loads(Path(r.json_path).read_text())["caller"]["mode"] == "practice"
    (K, _, _), _ = lab.sweep_fit({V: lab.steady_speed(r) for V, r in recs.items()})
    res = S.verify("K", K)
    assert res.ok and "your recordings" in res.message  # the checker's own fit, not a truth
    assert not S.verify("K", graded["K"]).ok  # a motor the student never had is not the reference
    nb = tmp_path / "lab1_identify.ipynb"  # the saved worksheet (submit refuses without one)
    nb.write_text(json.dumps({"cells": [], "metadata": {}, "nbformat": 4, "nbformat_minor": 4}))
    z = S.submit(notebook=nb, out=tmp_path / "handin")
    assert z is not None, "the hand-in was refused"
    with zipfile.ZipFile(z) as f:
        assert json.loads(f.read("student.json"))["mode"] == "practice"
        assert json.loads(f.read("manifest.json"))["mode"] == "practice"
    assert lab.read_handin(z)["mode"] == "practice"
    S.close()
    assert "neighbour" not in Path(checks.__file__).read_text()


def test_graded_answers_can_be_scored_by_the_trusted_grader_only_with_the_key(tmp_path):
    """score_answers: a practice hand-in is scored on its recordings, a graded one against the
    motor the key gives; the student's process never needs either."""
    from jerklab import lab
    from jerklab.lab.service import score_answers

    S = lab.start(1, student="dana", folder=tmp_path, key=KEY.encode())
    recs = {V: S.step(V, lab.STEP_SECONDS) for V in lab.SWEEP_VOLTS}
    (K, f_c, _), _ = lab.sweep_fit({V: lab.steady_speed(r) for V, r in recs.items()})
    ev = S.evidence()
    S.close()
    t = _truth("dana")
    graded = score_answers(1, "dana", {"K": K, "f_c": f_c}, ev, key=KEY.encode())
    assert graded["K"].ok and graded["f_c"].ok and "your motor" in graded["K"].message
    wrong = score_answers(1, "dana", {"K": t["K"] * 1.3}, ev, key=KEY.encode())
    assert not wrong["K"].ok
    practice = score_answers(1, "dana", {"K": K}, ev, practice=True)
    assert practice["K"].ok and "your recordings" in practice["K"].message
    gc.collect()


# ------------------------------------------------------------------ an honest worksheet
def _run_master(n, student, tmp_path):
    """Execute master worksheet ``n`` (solutions in) as ``student`` in a Jupyter kernel that
    inherits this process's environment; its outputs, errors as ``ERROR name: value``."""
    import nbformat
    from nbclient import NotebookClient

    from jerklab.lab.grade import master_path

    nb = nbformat.read(master_path(n), as_version=4)
    for c in nb.cells:
        if c.cell_type == "code" and 'STUDENT = "' in c.source:
            c.source = re.sub(r'STUDENT = "[^"]*"', f'STUDENT = "{student}"', c.source)
    NotebookClient(
        nb,
        timeout=240,
        kernel_name="python3",
        allow_errors=True,
        resources={"metadata": {"path": str(tmp_path)}},
    ).execute()
    outs = []
    for c in nb.cells:
        for o in c.get("outputs", []) if c.cell_type == "code" else []:
            if o.output_type == "error":
                outs.append(f"ERROR {o.ename}: {o.evalue}")
            outs.append(o.get("text", ""))
            outs.extend(v for v in o.get("data", {}).values() if isinstance(v, str))
    assert not [o for o in outs if o.startswith("ERROR")], [o for o in outs if "ERROR" in o]
    # one check cell per question: ``assert (_r := S.verify("name", answer)).ok, _r.message``,
    # so a check that does not pass is an error output (refused above)
    n_checks = sum(
        1
        for c in nb.cells
        if c.cell_type == "code" and re.match(r"assert \(_r := S\.verify\(", c.source)
    )
    assert n_checks > 3
    return outs, n_checks


def _student_env(monkeypatch, tmp_path, **env):
    for k in [k for k in os.environ if k.startswith("JERKLAB_")] + ["JUPYTERHUB_API_TOKEN"]:
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("JERKLAB_LAB_WORK", str(tmp_path / "work"))
    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path / "rec"))
    monkeypatch.setenv("HOME", str(tmp_path))
    for k, v in env.items():
        monkeypatch.setenv(k, v)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_an_honest_worksheet_scores_full_marks_through_the_service(
    n, service, tmp_path, monkeypatch
):
    """The master worksheet (solutions in) in a Jupyter kernel that has no key, on the class rig
    of the login "bob": every check passes, scored by the service, and no output shows a true
    value; the hand-in says "graded"."""
    url, log, _ = service
    _student_env(
        monkeypatch, tmp_path, JERKLAB_CLASS_RIG=url, JERKLAB_CLASS_TOKEN="tok-bob-2d8e4f6a0c"
    )
    outs, n_checks = _run_master(n, "bob", tmp_path)
    assert any("class rig" in o for o in outs)
    truth = _truth("bob", n)
    blob = "\n".join(outs)
    for k in ("K", "tau"):  # 6-7 digits: a good estimate may agree to 4-5
        for d in (6, 7):
            assert f"{truth[k]:.{d}g}" not in blob and repr(truth[k]) not in blob
    from jerklab.lab.service import attempt_counts

    assert sum(attempt_counts(log)[("bob", n)].values()) >= n_checks
    for z in tmp_path.rglob(f"lab{n}_bob.zip"):
        with zipfile.ZipFile(z) as f:
            assert json.loads(f.read("manifest.json"))["mode"] == "graded"


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_an_honest_worksheet_passes_in_practice(n, tmp_path, monkeypatch):
    """Without a service and without a key: the practice motor, every check right against the
    student's own recordings, "practice" in every recording."""
    _student_env(monkeypatch, tmp_path, JERKLAB_CLASS_CODE="me301-test")
    outs, _ = _run_master(n, "pia", tmp_path)
    assert any("Practice motor:" in o for o in outs)
    sidecars = list((tmp_path / "work").rglob("*.json"))
    assert sidecars
    for p in sidecars:
        assert json.loads(p.read_text())["caller"]["mode"] == "practice"


def test_the_service_bounds_connections_and_requests(tmp_path, monkeypatch):
    """A student cannot hold the service: at most LIMITS["connections_per_student"] links, a
    silent link is closed, a 400 rad move and a long step are refused naming the limit."""
    from jerklab.lab import service as svc_mod
    from jerklab.lab.service import LIMITS, ClassRigService, TokenFile

    monkeypatch.setitem(LIMITS, "hello_seconds", 0.5)
    tokens = tmp_path / "t.json"
    tokens.write_text(json.dumps(TOKENS))
    with ClassRigService(TokenFile(tokens), tmp_path / "log", key=KEY.encode()) as svc:
        host, _, port = svc.address.rpartition(":")
        hello = (
            json.dumps({"op": "hello", "token": "tok-alice-7f3a9c1e5b", "lab": 1}) + "\n"
        ).encode()
        links = []
        for _ in range(LIMITS["connections_per_student"]):
            s = socket.create_connection((host, int(port)), timeout=10)
            s.sendall(hello)
            assert json.loads(s.makefile("rb").readline())["ok"]
            links.append(s)
        (extra,) = _ask(svc.url, {"op": "hello", "token": "tok-alice-7f3a9c1e5b", "lab": 1})
        assert "connections: at most" in extra["error"]
        (bob,) = _ask(svc.url, {"op": "hello", "token": "tok-bob-2d8e4f6a0c", "lab": 1})
        assert bob["ok"]  # alice's links do not lock bob out
        links.pop().close()
        time.sleep(0.2)
        hello_again, move, step = _ask(
            svc.url,
            {"op": "hello", "token": "tok-alice-7f3a9c1e5b", "lab": 1},
            {
                "op": "run_move",
                "name": "m",
                "profile": {
                    "kind": "sine_jerk",
                    "distance": 400.0,
                    "max_jerk": 2e4,
                    "max_accel": 600.0,
                    "max_velocity": 80.0,
                },
                "gains": {"kpd": 1.0, "kid": 0.0, "kdd": 0.1, "Ts": 0.005},
            },
            {"op": "step", "name": "s", "voltage": 6.0, "seconds": 60.0},
        )
        assert hello_again["ok"]
        assert "profile.distance must be <= 100" in move["error"]
        assert "seconds must be <= 5" in step["error"]
        silent = socket.create_connection((host, int(port)), timeout=10)
        t0 = time.monotonic()
        assert silent.recv(100) == b""  # closed by the service
        assert time.monotonic() - t0 < 5
        for s in links + [silent]:
            s.close()
    assert svc_mod.LIMITS["connections_per_student"] == 4


def test_the_service_on_a_unix_socket(tmp_path):
    """``--unix PATH``: the same service on a Unix socket (``classrig+unix://PATH``)."""
    from jerklab.lab.classrig import ClassRig
    from jerklab.lab.service import ClassRigService, TokenFile

    tokens = tmp_path / "t.json"
    tokens.write_text(json.dumps(TOKENS))
    sock = tmp_path / "classrig.sock"
    (tmp_path / "not-a-socket").write_text("keep me")
    with pytest.raises(ValueError, match="not a socket"):
        ClassRigService(
            TokenFile(tokens), tmp_path / "l", KEY.encode(), f"unix:{tmp_path / 'not-a-socket'}"
        )
    assert (tmp_path / "not-a-socket").read_text() == "keep me"
    with ClassRigService(TokenFile(tokens), tmp_path / "log", KEY.encode(), f"unix:{sock}") as svc:
        assert svc.url == f"classrig+unix://{sock}"
        rig = ClassRig(svc.url, 1, token="tok-bob-2d8e4f6a0c")
        try:
            assert rig.student == "bob"
            rec = rig.step(6.0, 0.2, path=tmp_path / "step_p6V")
            assert rec.csv_path.is_file() and len(rec) == 50
            assert rig.check("pre_speed", 180.0)[0]
        finally:
            rig.close()
    assert not sock.exists()


def test_the_benchmarks_attacks_hold_against_the_service_and_not_without_it(tmp_path):
    """``python -m benchmarks security``'s hidden-motor area, one student process each: against
    the class rig service every attack (the session's truth, the motor object, a percent in the
    feedback, a classmate's session and regenerated motor, the scan) comes back without the
    truth; with the key in the student's environment, as before the service, the scan finds
    alice's K and bob's motor regenerates from his ID (today's session has no ``_truth`` and
    no motor attribute either way: the key is what gives the truth away)."""
    from benchmarks.attacks_hidden_motor import attack_class

    (tmp_path / "with").mkdir()
    (tmp_path / "without").mkdir()
    held = attack_class(tmp_path / "with")
    assert len(held) == 6 and all(ok for _, ok, _ in held), held
    control = attack_class(tmp_path / "without", service=False)
    broken = {name for name, ok, _ in control if not ok}
    assert {
        "every number in the student's process scanned for K",
        "a classmate's motor regenerated from their ID",
    } <= broken, control


def test_the_service_refuses_a_move_too_slow_to_end(tmp_path):
    """A student's 100 rad move at 0.5 rad/s would last 200 s: the service simulates every sample
    of it (40,000 in 6.6 s of its CPU, the recording sent back whole; at 0.01 rad/s two million)
    while classmates wait for the same cores. It is refused naming the limit, before it runs;
    the labs' own moves (16 s at the longest, lab 4 on a geared motor) stay under it."""
    from jerklab.lab.service import LIMITS, ClassRigService, TokenFile
    from jerklab.lab.specs import lab_spec
    from jerklab.planner import plan_sine_jerk
    from jerklab.rig import profile_names

    tokens = tmp_path / "t.json"
    tokens.write_text(json.dumps(TOKENS))
    with ClassRigService(TokenFile(tokens), tmp_path / "log", key=KEY.encode()) as svc:
        t0 = time.monotonic()
        _, move = _ask(
            svc.url,
            {"op": "hello", "token": "tok-alice-7f3a9c1e5b", "lab": 2},
            {
                "op": "run_move",
                "name": "slow",
                "profile": {
                    "kind": "sine_jerk",
                    "distance": 100.0,
                    "max_jerk": 2e4,
                    "max_accel": 600.0,
                    "max_velocity": 0.5,
                },
                "gains": {"kpd": 4.522, "kid": 0.216, "kdd": 21.6, "Ts": 0.005},
            },
        )
        assert "profile.duration must be <= 30 s" in move["error"]
        assert time.monotonic() - t0 < 5
    longest = max(
        plan_sine_jerk(**lab_spec(n, p)["move"]).duration
        for p in profile_names()
        for n in (2, 3, 4, 5)
    )
    assert longest < LIMITS["move_seconds"]
