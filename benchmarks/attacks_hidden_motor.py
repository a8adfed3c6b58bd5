"""The hidden-motor attacks of issue 32 ("Hidden motors"), for ``python -m benchmarks security``.

A student's process, set up as the jerklab under attack tells an instructor to run a graded
class, tries every way the issue found to learn a graded motor's true K instead of measuring
it:

- with a class rig service (``python -m jerklab.lab service``, its own Unix user when run as
  root): the student's process holds only the service's address and a hub token;
- without one (a jerklab from before the service): the instructor key on the machine that runs
  the students' kernels, as that version's docs/INSTRUCTOR.md said ("Set the key on the machine
  that runs the students' kernels and the grader").

The attacks run in one student process (one session for ``alice``) and print what each found;
this benchmark, holding the key, compares every value with the true K of alice and of her
classmate bob. An attack *held* when nothing it found is the truth: 1e-3 relative for a value an
attack names, 1e-6 for the scan of every number in the process (as
tests/security/test_hidden_motor.py, which asserts the same on the service). Written against
the session's public surface, so that it also runs on a checkout from before the fix.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

from benchmarks.bench_security import area

KEY = "hidden-motor-bench-key-5c2e91"
TOKENS = {"tok-alice-4b7d1e09a3": "alice", "tok-bob-8e2c6f1d57": "bob"}

#: what the student's process tries; prints one JSON line {attack: value or "refused: ..."}
STUDENT = r'''
import gc, json, re, sys, warnings
import numpy as np
warnings.simplefilter("ignore")
from jerklab import lab
out = {}

def attempt(name, fn):
    try:
        v = fn()
        out[name] = float(v) if v is not None else None
    except Exception as exc:  # the attack failed: say how
        out[name] = f"refused: {type(exc).__name__}: {str(exc)[:90]}"

S = lab.start(1, student="alice")
S.step(6.0, 1.0)
attempt("truth", lambda: S._truth()["K"])
def motor_object():
    for path in ("_motor", "rig._hidden_motor", "rig.device.motor", "rig._device.motor"):
        obj = S
        try:
            for part in path.split("."):
                obj = getattr(obj, part)
            return obj.K
        except AttributeError:
            continue
    raise AttributeError("none of S._motor, S.rig._hidden_motor, S.rig.device.motor")

attempt("rig_motor", motor_object)

def from_percent():
    msg = S.verify("K", 1000.0).message
    m = re.search(r"([-+]?\d+(?:\.\d+)?)\s*%", msg)
    if m is None:
        raise LookupError(f"no percent in the feedback: {msg[:80]!r}")
    return 1000.0 / (1.0 + float(m.group(1)) / 100.0)

attempt("percent", from_percent)

def classmate():
    B = lab.start(1, student="bob")
    try:
        return B._truth()["K"]
    except AttributeError:
        return B.rig._hidden_motor.K

attempt("classmate", classmate)

def regenerate():
    from jerklab.lab.motors import hidden_truth, student_motor
    return hidden_truth(student_motor("bob"))["K"]

attempt("regenerate", regenerate)
# every number reachable in the process: objects gc knows and what they hold, module globals
found, arrays, seen = [], [], set()
def take(x):
    if isinstance(x, bool):
        return
    if isinstance(x, (float, int, np.floating, np.integer)):
        try:
            found.append(float(x))
        except OverflowError:
            pass
    elif isinstance(x, np.ndarray) and x.dtype.kind in "fiu" and id(x) not in seen:
        seen.add(id(x))
        arrays.append(np.asarray(x, dtype=float).ravel())
gc.collect()
for o in gc.get_objects():
    take(o)
    for r in gc.get_referents(o):
        take(r)
for mod in list(sys.modules.values()):
    for v in list(getattr(mod, "__dict__", {}).values()):
        take(v)
vals = np.concatenate([np.asarray(found, dtype=float), *arrays])
np.save("values.npy", vals[np.isfinite(vals)])
print(json.dumps(out))
'''

ATTACKS = [
    ("truth", "the session's own truth: S._truth()"),
    ("rig_motor", "the motor object behind the session (S._motor, S.rig...motor)"),
    ("percent", "a wrong guess (K = 1000) and the percent in the feedback"),
    ("classmate", "a classmate's session opened by typing their ID"),
    ("regenerate", "a classmate's motor regenerated from their ID"),
    ("scan", "every number in the student's process scanned for K"),
]


def _truth(student):
    from jerklab.lab.motors import hidden_truth, student_motor

    return hidden_truth(student_motor(student, KEY.encode()))["K"]


def _service(tmp: Path, env: dict):
    """Start the class rig service as the instructor would; return (process, address)."""
    os.chmod(tmp, 0o755)
    keyfile = tmp / "instructor.key"
    keyfile.write_text(KEY + "\n")
    os.chmod(keyfile, 0o600)
    tokens = tmp / "tokens.json"
    tokens.write_text(json.dumps(TOKENS))
    cmd = [sys.executable, "-m", "jerklab.lab", "service", "--listen", "127.0.0.1:0"]
    cmd += ["--tokens", str(tokens), "--log", str(tmp / "checks.jsonl")]
    if os.geteuid() == 0:
        cmd += ["--user", "nobody"]
    proc = subprocess.Popen(
        cmd,
        env=dict(env, JERKLAB_INSTRUCTOR_KEY_FILE=str(keyfile)),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()
    m = re.search(r"(classrig://\S+)", line)
    if m is None:
        proc.kill()
        raise RuntimeError(f"the service did not start: {line!r} {proc.stderr.read()[-500:]}")
    return proc, m.group(1)


@area("hidden motor")
def run(tmp):
    """One student process runs every attack against the class as its version sets it up."""
    return attack_class(tmp)


def attack_class(tmp, service=None):
    """Every attack from one student process; ``[(attack, held, outcome)]``.

    ``service`` None sets the class up as this jerklab does (a class rig service where
    ``jerklab.lab.service`` exists); False puts the key in the student's environment instead,
    as before the service (the control: there every attack finds the truth)."""
    import jerklab

    root = str(Path(jerklab.__file__).resolve().parent.parent)
    base = {k: v for k, v in os.environ.items() if not k.startswith("JERKLAB_")}
    base.pop("JUPYTERHUB_API_TOKEN", None)
    base.update(PYTHONPATH=root, MPLBACKEND="Agg")
    student_dir = Path(tempfile.mkdtemp(prefix="student-", dir=tmp))
    home = student_dir / "home"
    home.mkdir()
    proc = None
    if service is None:
        service = importlib.util.find_spec("jerklab.lab.service") is not None
    if service:
        service_dir = Path(tmp) / "service"
        service_dir.mkdir()
        proc, url = _service(service_dir, base)
        env = dict(base, HOME=str(home), JERKLAB_CLASS_RIG=url)
        env["JERKLAB_CLASS_TOKEN"] = "tok-alice-4b7d1e09a3"
        setup = "a class rig service; the student holds its address and a hub token"
    else:
        env = dict(base, HOME=str(home), JERKLAB_INSTRUCTOR_KEY=KEY)
        setup = "no service: the key on the machine that runs the students' kernels"
    try:
        r = subprocess.run(
            [sys.executable, "-c", textwrap.dedent(STUDENT)],
            env=env,
            cwd=student_dir,
            capture_output=True,
            text=True,
            timeout=600,
        )
    finally:
        if proc is not None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    if r.returncode != 0:
        err = (r.stderr.strip().splitlines() or ["no message"])[-1]
        return [(name, None, f"the student's process failed: {err[:80]}") for _, name in ATTACKS]
    found = json.loads(r.stdout.strip().splitlines()[-1])
    alice, bob = _truth("alice"), _truth("bob")
    values = np.load(student_dir / "values.npy")
    rows = []
    for key, name in ATTACKS:
        if key == "scan":
            hits = int(np.sum(np.abs(values - alice) <= 1e-6 * alice))
            outcome = f"{hits} copies of alice's K among {values.size} numbers"
            rows.append((name, hits == 0, outcome))
            continue
        v = found.get(key)
        truth = bob if key in ("classmate", "regenerate") else alice
        if isinstance(v, float):
            hit = abs(v / truth - 1) <= 1e-3
            outcome = f"found K = {v:.4g}; the truth is {truth:.4g}"
            rows.append((name, not hit, outcome))
        else:
            rows.append((name, True, str(v)))
    print(f"hidden motor: the class as this jerklab sets it up: {setup}")
    return rows
