"""The class rig service: graded hidden motors that students measure and never read.

One trusted process holds the instructor's key, derives each student's hidden motor, runs
that student's virtual rig and scores the checks that need the truth. A student's kernel
reaches it like a rig over a socket (:mod:`jerklab.lab.classrig` is the client,
``lab.start(N)`` uses it when ``$JERKLAB_CLASS_RIG`` names the service); the student is the
one an authentication token names, never a typed ID. The kernel gets recordings and verdicts;
no message carries a true K or τ, and no code of the student's runs in this process.

    python -m jerklab.lab service --listen 127.0.0.1:7341 --hub-api http://127.0.0.1:8081/hub/api
    python -m jerklab.lab service --unix /run/jerklab/classrig.sock --tokens tokens.json

Run it as a Unix user of its own (``--user jerklab-rig`` when started as root: the key is read,
the socket and the log are opened, then the process drops to that user), so that no student's
process can read its memory, its environment or its key file.

The link is one JSON object per line. The first request of a connection is ``{"op": "hello",
"token": ..., "lab": N}``; the service asks the authority (:class:`HubAuth`, the hub's
``/hub/api/user``, or :class:`TokenFile`, a JSON ``{token: user}`` for a class without a hub
and for the tests) whose token it is. Then ``step``, ``record_prbs``, ``run_move``,
``set_model``, ``set_shaper`` (the rig) and ``check`` (``{"name", "answer"}``: the service
scores the answer with the check of :mod:`jerklab.lab.registry`, on the recordings *it* made
for that student and the truth of the student's motor, and answers ``{"ok", "message"}``).
Every answer is ``{"ok": true, ...}`` or ``{"error": "...", "type": "..."}``.

``host_loop`` (lab 5, the host-in-the-loop labs of the registry) is a conversation: the
request ``{"name", "Ts", "duration", "reference": [r_0, ...] or null, "options"}`` starts the
run on the hidden motor in real time; for every tick the service sends ``{"tick", "t",
"position", "reference", "voltage", "missed"}`` and the student's kernel answers ``{"voltage":
v}`` (null: hold, a miss) or ``{"abort": "why"}``; the signed recording ends it. An answer that
does not come within ``LIMITS["host_answer_seconds"]`` stops the motor; the device's own misses,
tracking stop (the lab's, never raised) and watchdog stay on.

Every recording served is signed (:mod:`jerklab.lab.signing`: HMAC-SHA256 with a key derived
from the instructor key, over its samples, the student, the lab and the time; in its JSON
sidecar under ``"signature"``), so that the grader can tell it from one a student made or
edited.

Every check is appended to the log (JSON lines: time, student, lab, check, answer, ok,
attempt); :func:`attempt_counts` reads it for ``grades.csv``, :func:`check_log` returns its
entries.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import hmac
import json
import math
import os
import re
import socketserver
import stat
import sys
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

from jerklab import paper, planner
from jerklab.controller import DiscreteGains, discrete_pole_placement_pid
from jerklab.lab.checkbase import CheckResult, Missing
from jerklab.lab.motors import (
    CLASSROOM_DEFAULT_KEY,
    hidden_truth,
    instructor_key,
    normalize_student,
    student_device,
    student_motor,
)
from jerklab.lab.plain import Evidence, Run, jsonable
from jerklab.lab.registry import CHECKS, FLEXIBLE_LABS, HOST_LOOP_LABS, LABS, check_function
from jerklab.lab.signing import sign_run
from jerklab.lab.specs import lab_spec
from jerklab.rig import Recording, RigError, connect, load_profile
from jerklab.rig.hostloop import MAX_TS as HOST_MAX_TS
from jerklab.rig.hostloop import MIN_TS as HOST_MIN_TS
from jerklab.rig.hostloop import ControlLawError

__all__ = [
    "ClassRigService",
    "TokenFile",
    "HubAuth",
    "AuthError",
    "LIMITS",
    "attempt_counts",
    "check_log",
    "last_verdicts",
    "score_answers",
    "decode_answer",
    "main",
]

#: What one request may ask of a student's rig (a refusal names the limit).
LIMITS = {
    "request_bytes": 1 << 16,  # one request line
    "step_seconds": 5.0,  # s, one open-loop step
    "rest_seconds": 1.0,  # s of rest before a step or a PRBS
    "prbs_order": 12,  # maximal-length sequence order
    "prbs_hold": 16,  # samples per bit
    "move_distance": 100.0,  # rad
    "settle": 2.0,  # s after a move
    "move_seconds": 30.0,  # s, one move's planned duration (the labs' longest: 16 s)
    "runs_kept": 200,  # recordings kept per student and lab (the oldest go first)
    "connections": 256,  # open at a time, in all
    "connections_per_student": 4,  # open at a time by one student
    "hello_seconds": 10.0,  # s a new connection has to say who it is
    "host_loop_seconds": 30.0,  # s, one host-in-the-loop run (lab 5)
    "host_answer_seconds": 2.0,  # s the service waits for one tick's answer before it stops
}
_NAME_RE = re.compile(r"^[A-Za-z0-9_.+-]{1,60}$")
_IDLE_TIMEOUT = 3600.0  # s a connection may sit without a request


class AuthError(Exception):
    """A token that the authority does not know (or cannot be asked about)."""


# ------------------------------------------------------------------ who is asking
class TokenFile:
    """Tokens of a class without a hub (and of the tests): a JSON file ``{token: user}``.

    The file is read at start (before the service drops to its own user) and again at every
    look-up while it stays readable, so the instructor can add a student while the service
    runs. Tokens are compared in constant time.
    """

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"tokens: {str(self.path)!r} is not a file")
        self._table = self._read()

    def _read(self) -> dict:
        try:
            table = json.loads(self.path.read_text(encoding="utf-8"))
        except ValueError:
            raise ValueError(f"tokens: {str(self.path)!r} is not JSON {{token: user}}") from None
        if not isinstance(table, dict):
            raise ValueError(f"tokens: {str(self.path)!r} is not a JSON object {{token: user}}")
        return {str(k): str(v) for k, v in table.items()}

    def __call__(self, token: str) -> str:
        try:
            self._table = self._read()
        except (OSError, ValueError):
            pass  # keep the table read last (the file may be the instructor's only)
        found = None
        given = token.encode()
        for known, user in self._table.items():
            if hmac.compare_digest(known.encode(), given):
                found = user
        if found is None:
            raise AuthError("unknown token")
        return found


class HubAuth:
    """Ask JupyterHub whose token it is: ``GET {api_url}/user`` with ``Authorization: token``.

    A single-user server's ``$JUPYTERHUB_API_TOKEN`` identifies its user to the hub; the hub
    answers the user's model, whose ``name`` is the student. Answers are cached for
    ``cache_seconds``.

    Parameters
    ----------
    api_url : str
        The hub's API, e.g. ``http://127.0.0.1:8081/hub/api`` (``$JUPYTERHUB_API_URL``).
    """

    def __init__(self, api_url, timeout=5.0, cache_seconds=60.0):
        u = urllib.parse.urlparse(str(api_url))
        if u.scheme not in ("http", "https") or not u.netloc:
            raise ValueError(f"api_url must be an http(s) URL of the hub's API, got {api_url!r}")
        self.api_url = str(api_url).rstrip("/")
        self.timeout = float(timeout)
        self.cache_seconds = float(cache_seconds)
        self._cache = {}
        self._lock = threading.Lock()

    def __call__(self, token: str) -> str:
        now = time.monotonic()
        with self._lock:
            hit = self._cache.get(token)
            if hit and hit[1] > now:
                return hit[0]
        req = urllib.request.Request(
            self.api_url + "/user", headers={"Authorization": f"token {token}"}
        )
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as r:
                model = json.loads(r.read(1 << 16))
        except urllib.error.HTTPError as exc:
            raise AuthError(f"the hub does not know this token (HTTP {exc.code})") from None
        except (urllib.error.URLError, OSError, ValueError) as exc:
            raise AuthError(f"the hub cannot be asked ({type(exc).__name__})") from None
        name = model.get("name") if isinstance(model, dict) else None
        if not isinstance(name, str) or not name:
            raise AuthError("the hub's answer names no user")
        if model.get("kind", "user") != "user":
            raise AuthError(f"the token belongs to a {model.get('kind')}, not to a student")
        with self._lock:
            self._cache[token] = (name, now + self.cache_seconds)
        return name


# ------------------------------------------------------------------ answers as plain data
_GAINS_KEYS = {"kpd", "kid", "kdd", "Ts", "gamma", "loop", "design"}


def decode_answer(data):
    """An answer as the checks take it from its JSON form (:func:`jerklab.lab.plain.jsonable`,
    or :func:`jerklab.lab.classrig.encode_answer`): gains (a dict with ``kpd``, ``kid``,
    ``kdd``, ``Ts`` and at most ``gamma``, ``loop``, ``design``) become
    :class:`jerklab.controller.DiscreteGains`; anything else stays (a dict with more keys,
    such as lab 5's law with its gains, model and clamp, is a dict)."""
    if isinstance(data, dict) and {"kpd", "kid", "kdd", "Ts"} <= set(data) <= _GAINS_KEYS:
        design = data.get("design") if isinstance(data.get("design"), dict) else {}
        return DiscreteGains(
            data["kpd"],
            data["kid"],
            data["kdd"],
            data["Ts"],
            gamma=data.get("gamma", 0.0),
            loop=data.get("loop", "position"),
            design=design,
        )
    return data


def _run_check(lab, name, answer, evidence, truth) -> CheckResult:
    """Check ``answer``, turning "not there yet" and unreadable answers into a failed result."""
    check = check_function(lab, name)
    try:
        return check(decode_answer(answer), evidence, truth)
    except Missing as exc:
        return CheckResult(name, False, str(exc))
    except (TypeError, ValueError, KeyError, AttributeError, IndexError) as exc:
        return CheckResult(
            name,
            False,
            f"could not read your answer ({type(exc).__name__}). "
            "Replace the `...` with a value of the type the task asks for.",
        )


def score_answers(lab, student, answers, evidence, *, key=None, practice=False) -> dict:
    """Score a hand-in's plain answers as the trusted grader (never in a student's process).

    Parameters
    ----------
    lab : int
        The lab (1 to 4).
    student : str
        The student ID the hand-in names.
    answers : dict
        Check name -> the answer's JSON data, in the worksheet's order (later checks see the
        earlier answers, as in the worksheet).
    evidence : jerklab.lab.plain.Evidence
        The hand-in's recordings (its ``answers`` are replaced by ``answers``).
    key : bytes, optional
        The instructor key (default :func:`jerklab.lab.motors.instructor_key`).
    practice : bool
        True for a practice hand-in (no class rig service): scored against what the checks find
        in the student's own recordings, never against a motor the student never had.

    Returns
    -------
    dict
        Check name -> :class:`jerklab.lab.checkbase.CheckResult`.
    """
    sid = normalize_student(student)
    if lab not in LABS:
        raise ValueError(f"lab must be one of {sorted(LABS)}, got {lab!r}")
    truth = None
    if not practice:
        if key is None:
            key, _ = instructor_key()
        plant = "flexible" if lab in FLEXIBLE_LABS else "rigid"
        truth = hidden_truth(student_motor(sid, key, plant=plant))
    given, out = {}, {}
    for name, answer in answers.items():
        ev = Evidence(
            runs=evidence.runs, answers=dict(given), counts_per_rev=evidence.counts_per_rev
        )
        out[name] = _run_check(lab, name, answer, ev, truth)
        given[name] = answer
    return out


# ------------------------------------------------------------------ the log
def check_log(log_path) -> list[dict]:
    """Every check the service scored, in order: dicts with ``time``, ``student``, ``lab``,
    ``check``, ``answer``, ``ok``, ``attempt`` (unreadable lines are skipped)."""
    out = []
    path = Path(log_path)
    if not path.is_file():
        return out
    with path.open(encoding="utf-8") as f:
        for line in f:
            try:
                e = json.loads(line)
            except ValueError:
                continue
            if isinstance(e, dict) and {"student", "lab", "check", "ok"} <= set(e):
                out.append(e)
    return out


def attempt_counts(log_path) -> dict:
    """How often each student tried each check: ``{(student, lab): {check: attempts}}``.

    ``student`` is the service's (hub) identity, ``lab`` an int; the grade helper puts the counts
    into ``grades.csv``. A missing log gives an empty dict.
    """
    counts: dict = {}
    for e in check_log(log_path):
        try:
            k = (str(e["student"]), int(e["lab"]))
        except (TypeError, ValueError):
            continue
        per = counts.setdefault(k, {})
        per[str(e["check"])] = per.get(str(e["check"]), 0) + 1
    return counts


def last_verdicts(log_path) -> dict:
    """The service's verdict on each check: ``{(student, lab): {check: {"ok", "answer",
    "attempts"}}}`` of the last attempt. For graded work this is the trustworthy score: the
    service checked the answer on the recordings it made itself, against the truth."""
    out: dict = {}
    for e in check_log(log_path):
        try:
            k = (str(e["student"]), int(e["lab"]))
        except (TypeError, ValueError):
            continue
        per = out.setdefault(k, {})
        n = per.get(str(e["check"]), {}).get("attempts", 0) + 1
        per[str(e["check"])] = {"ok": bool(e["ok"]), "answer": e.get("answer"), "attempts": n}
    return out


class _Log:
    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o640)
        self._f = os.fdopen(fd, "a", encoding="utf-8")
        self._lock = threading.Lock()
        self._attempts = attempt_counts(self.path)

    def write(self, student, lab, check, answer, ok) -> int:
        with self._lock:
            per = self._attempts.setdefault((student, lab), {})
            per[check] = n = per.get(check, 0) + 1
            entry = {
                "time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                "student": student,
                "lab": lab,
                "check": check,
                "answer": answer,
                "ok": bool(ok),
                "attempt": n,
            }
            self._f.write(json.dumps(entry) + "\n")
            self._f.flush()
            return n

    def close(self):
        self._f.close()


# ------------------------------------------------------------------ a student's rig
def _number(name, x, lo=None, hi=None):
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise ValueError(f"{name} must be a finite number, got {x!r}")
    if lo is not None and x < lo:
        raise ValueError(f"{name} must be >= {lo}, got {x}")
    if hi is not None and x > hi:
        raise ValueError(f"{name} must be <= {hi} (the service's limit), got {x}")
    return float(x)


def _profile(p):
    if not isinstance(p, dict):
        raise ValueError("profile must be a dict with kind, distance and the limits")
    kind = p.get("kind")
    d = _number(
        "profile.distance", p.get("distance"), -LIMITS["move_distance"], LIMITS["move_distance"]
    )
    a = _number("profile.max_accel", p.get("max_accel"), 0.0)
    v = _number("profile.max_velocity", p.get("max_velocity"), 0.0)
    if kind == "trapezoid":
        return _bounded(planner.plan_trapezoid(d, a, v))
    plan = {
        "sine_jerk": planner.plan_sine_jerk,
        "sine_jerk_optimal": planner.plan_sine_jerk_optimal,
        "scurve": planner.plan_scurve,
    }.get(kind)
    if plan is None:
        raise ValueError(f"profile.kind must be a jerklab planner kind, got {kind!r}")
    return _bounded(plan(d, _number("profile.max_jerk", p.get("max_jerk"), 0.0), a, v))


def _bounded(profile):
    """``profile`` if its move lasts at most LIMITS["move_seconds"] (a slow move's samples would
    hold the service's CPU and memory for minutes)."""
    if not profile.duration <= LIMITS["move_seconds"]:
        raise ValueError(
            f"profile.duration must be <= {LIMITS['move_seconds']:g} s (the service's limit), "
            f"got {profile.duration:.6g} s: raise max_velocity or max_accel, or move less"
        )
    return profile


class _Student:
    """One student's lab on the service: the hidden motor's rig, its recordings, the answers."""

    def __init__(self, service, student, lab):
        self.student, self.lab = student, lab
        self._key = service.key  # signs the recordings served (jerklab.lab.signing)
        self.profile = service.profile
        plant = "flexible" if lab in FLEXIBLE_LABS else "rigid"
        motor = student_motor(student, service.key, plant=plant, profile=self.profile)
        self.truth = hidden_truth(motor)
        # a lab whose law runs in the student's kernel (host-in-the-loop) runs in real time:
        # the law answers each tick over the link, as it would a real board's
        speed = 1.0 if lab in HOST_LOOP_LABS and service.speed is None else service.speed
        self.rig = connect(
            None,
            device=student_device(motor, speed),
            progress=False,
            recordings=service.recordings,
            metadata={"student": student, "lab": lab, "mode": "graded"},
            profile=self.profile,
        )
        del motor
        self.runs = {}
        self.answers = {}
        self.lock = threading.Lock()
        self.archive = None
        if service.recordings is not None:
            self.archive = Path(service.recordings) / student / f"lab{lab}"
            self.archive.mkdir(parents=True, exist_ok=True)

    def _path(self, name):
        if self.archive is None:
            return False
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S-%f")
        return self.archive / f"{name}-{stamp}"

    def _keep(self, name, rec):
        self.runs.pop(name, None)
        self.runs[name] = Run.from_recording(rec)
        while len(self.runs) > LIMITS["runs_kept"]:
            self.runs.pop(next(iter(self.runs)))
        import tempfile

        with tempfile.TemporaryDirectory(prefix="jerklab-classrig-") as tmp:
            csv_path = Path(rec.save(Path(tmp) / "run"))
            # signed as the student's kernel reads it back (the CSV's numbers), so that the
            # grader finds the same bytes in the hand-in
            served = Run.from_recording(Recording.load(csv_path))
            meta = json.loads(csv_path.with_suffix(".json").read_text(encoding="utf-8"))
            meta["signature"] = sign_run(self._key, served, self.student, self.lab)
            return {
                "ok": True,
                "csv": csv_path.read_text(encoding="ascii"),
                "json": json.dumps(meta, indent=2) + "\n",
            }

    def info(self):
        r = self.rig
        return {
            "ok": True,
            "student": self.student,
            "lab": self.lab,
            "mode": "graded",
            "counts_per_rev": r.counts_per_rev,
            "supply_voltage": r.supply_voltage,
            "name": r.name,
            "firmware_version": r.firmware_version,
            # the rig's motor profile (None: the paper's class motors) and the lab's numbers
            # on it (jerklab.lab.specs.lab_spec), which the session adopts
            "profile": None if self.profile is None else self.profile.to_dict(),
            "spec": jsonable(lab_spec(self.lab, self.profile or "paper")),
        }

    def handle(self, req):
        op = req.get("op")
        if op == "info":
            return self.info()
        if op == "check":
            return None  # the service scores (it logs)
        name = req.get("name")
        if op in ("step", "record_prbs", "run_move") and not (
            isinstance(name, str) and _NAME_RE.match(name)
        ):
            raise ValueError(f"name must be 1-60 letters, digits or _.+-, got {name!r}")
        ts_given = req.get("Ts")
        Ts = paper.TS if ts_given is None else _number("Ts", ts_given, 1e-4, 0.1)
        if op == "step":
            rec = self.rig.step(
                _number("voltage", req.get("voltage")),
                _number("seconds", req.get("seconds"), 0.0, LIMITS["step_seconds"]),
                Ts=Ts,
                rest=_number("rest", req.get("rest", 0.05), 0.0, LIMITS["rest_seconds"]),
                path=self._path(name),
                progress=False,
            )
            return self._keep(name, rec)
        if op == "record_prbs":
            kw = {
                "order": int(_number("order", req.get("order", 8), 2, LIMITS["prbs_order"])),
                "hold": int(_number("hold", req.get("hold", 1), 1, LIMITS["prbs_hold"])),
                "seed": int(_number("seed", req.get("seed", 1), 1, 2**16)),
                "offset": _number("offset", req.get("offset", 0.0)),
                "rest": _number("rest", req.get("rest", 0.05), 0.0, LIMITS["rest_seconds"]),
            }
            if req.get("seconds") is not None:
                kw["seconds"] = _number("seconds", req["seconds"], 0.0, LIMITS["step_seconds"])
            rec = self.rig.record_prbs(
                _number("amplitude", req.get("amplitude")),
                Ts=Ts,
                path=self._path(name),
                progress=False,
                **kw,
            )
            return self._keep(name, rec)
        if op == "run_move":
            g = decode_answer(req.get("gains"))
            if not isinstance(g, DiscreteGains):
                raise ValueError("gains must be a dict with kpd, kid, kdd and Ts")
            run = req.get("run") or {}
            allowed = {"settle", "force", "feedforward"}
            if self.lab in HOST_LOOP_LABS:
                # lab 5 runs the board's law with the student's clamp (a saturating law is
                # the point), its safety stops for saturation and runaway off
                allowed |= {"max_voltage", "max_error", "runaway_time", "saturation_time"}
            if not isinstance(run, dict) or set(run) - allowed:
                raise ValueError(f"run may hold only {', '.join(sorted(allowed))}")
            spec = {"force": bool(run.get("force", False))}
            if "settle" in run:
                spec["settle"] = _number("settle", run["settle"], 0.0, LIMITS["settle"])
            if "feedforward" in run:
                spec["feedforward"] = bool(run["feedforward"])
            if "max_voltage" in run:
                spec["max_voltage"] = _number(
                    "max_voltage", run["max_voltage"], 1e-6, self.rig.supply_voltage
                )
            for k in ("runaway_time", "saturation_time"):
                if k in run:
                    spec[k] = _number(k, run[k], 0.0, 10.0)
            # the tracking-error stop of the lab on the class's profile (labs 2-3; lab 5's
            # spec["max_error"]), not the student's to raise
            sp = lab_spec(self.lab, self.profile or "paper")
            stop = sp.get("stop_error", sp.get("max_error") if self.lab in HOST_LOOP_LABS else None)
            if stop is not None:
                spec["max_error"] = stop
                if run.get("max_error") is not None:
                    spec["max_error"] = _number("max_error", run["max_error"], 0.0, stop)
            rec = self.rig.run_move(
                _profile(req.get("profile")),
                g,
                None if ts_given is None else Ts,
                path=self._path(name),
                progress=False,
                **spec,
            )
            return self._keep(name, rec)
        if op == "set_model":
            self.rig.set_model(
                _number("K", req.get("K"), 1e-6, 1e6), _number("tau", req.get("tau"), 1e-6, 100.0)
            )
            return {"ok": True}
        if op == "set_shaper":
            taps = req.get("taps")
            if taps is not None:
                if not isinstance(taps, list) or not 0 < len(taps) <= 64:
                    raise ValueError("taps must be a list of at most 64 numbers, or null")
                taps = [_number("taps[i]", t) for t in taps]
            self.rig.set_shaper(taps, Ts)
            return {"ok": True}
        raise ValueError(
            f"op must be one of info, step, record_prbs, run_move, host_loop, set_model, "
            f"set_shaper, check; got {op!r}"
        )

    def host_loop(self, req, send, readline):
        """A host-in-the-loop run whose law runs in the student's kernel (lab 5): for every
        tick the service sends ``{"tick", "t", "position", "reference", "voltage", "missed"}``
        and reads back ``{"voltage": v}`` (null: hold, a miss) or ``{"abort": why}``; the run's
        signed recording is the final answer, as for a move. The tracking-error stop is the
        lab's (``spec["max_error"]``), never above it; an answer that does not come within
        ``LIMITS["host_answer_seconds"]`` stops the motor."""
        if self.lab not in HOST_LOOP_LABS:
            raise ValueError(
                f"op host_loop is for the host-in-the-loop labs {list(HOST_LOOP_LABS)}, "
                f"not lab {self.lab}"
            )
        name = req.get("name")
        if not (isinstance(name, str) and _NAME_RE.match(name)):
            raise ValueError(f"name must be 1-60 letters, digits or _.+-, got {name!r}")
        Ts = _number("Ts", req.get("Ts"), HOST_MIN_TS - 1e-12, HOST_MAX_TS + 1e-12)
        duration = _number("duration", req.get("duration"), 0.0, LIMITS["host_loop_seconds"])
        opts = req.get("options") or {}
        if not isinstance(opts, dict) or set(opts) - {"max_misses", "max_voltage", "max_error"}:
            raise ValueError("options may hold only max_misses, max_voltage and max_error")
        kw = {}
        if opts.get("max_misses") is not None:
            kw["max_misses"] = int(_number("max_misses", opts["max_misses"], 1, 255))
        if opts.get("max_voltage") is not None:
            kw["max_voltage"] = _number(
                "max_voltage", opts["max_voltage"], 1e-6, self.rig.supply_voltage
            )
        table = req.get("reference")
        stop = lab_spec(self.lab, self.profile or "paper").get("max_error")
        if table is not None:
            n = int(math.ceil(duration / Ts - 1e-9)) + 1
            if not isinstance(table, list) or not 0 < len(table) <= n + 2:
                raise ValueError(f"reference must be a list of at most {n + 2} numbers or null")
            table = [
                _number("reference[k]", x, -LIMITS["move_distance"], LIMITS["move_distance"])
                for x in table
            ]
            last = len(table) - 1
            kw["reference"] = lambda t: table[min(int(round(t / Ts)), last)]
            if stop is not None:  # the lab's stop; a student may ask for a tighter one
                kw["max_error"] = stop
                if opts.get("max_error") is not None:
                    kw["max_error"] = _number("max_error", opts["max_error"], 0.0, stop)
        loop = self.rig.realtime(Ts, duration, path=self._path(name), **kw)
        steps = iter(loop)
        try:
            for step in steps:
                ref = step.reference
                send(
                    {
                        "tick": step.index,
                        "t": step.t,
                        "position": step.position,
                        "reference": None if not math.isfinite(ref) else ref,
                        "voltage": step.voltage,
                        "missed": step.missed,
                    }
                )
                try:
                    line = readline()
                except OSError:
                    line = b""
                if not line:
                    loop.abort(
                        f"fault: no answer from the student's kernel within "
                        f"{LIMITS['host_answer_seconds']:g} s at tick {step.index}"
                    )
                    break
                msg = json.loads(line.decode("utf-8"))
                if not isinstance(msg, dict):
                    raise ValueError("an answer is a JSON object")
                if "abort" in msg:
                    loop.abort(str(msg["abort"])[:300])
                    break
                v = msg.get("voltage")
                if v is None:
                    continue  # not applied: the device holds the last voltage (a miss)
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    loop.abort(f"error: the voltage at tick {step.index} is not a number")
                    break
                try:
                    step.apply(float(v))
                except ControlLawError:
                    break  # refused (non-finite): the motor is stopped, the status says why
        finally:
            steps.close()
        return self._keep(name, loop.recording)

    def score(self, name, answer):
        ev = Evidence(
            runs=dict(self.runs),
            answers=dict(self.answers),
            counts_per_rev=self.rig.counts_per_rev,
            profile=self.profile,
        )
        res = _run_check(self.lab, name, answer, ev, self.truth)
        self.answers[name] = answer
        return res

    def close(self):
        self.rig.close()


# ------------------------------------------------------------------ the service
class ClassRigService:
    """The class rig service (see the module's text).

    Parameters
    ----------
    auth : callable
        ``auth(token) -> user name``, raising :class:`AuthError` (:class:`HubAuth`,
        :class:`TokenFile`).
    log : path
        The check log (JSON lines), appended to.
    key : bytes, optional
        The instructor key (default :func:`jerklab.lab.motors.instructor_key`); the public
        classroom default is refused, since this service grades.
    listen : str
        ``"HOST:PORT"`` (TCP; port 0 picks a free one) or a Unix socket path (``unix:PATH``).
    recordings : path, optional
        Folder where the service keeps its own copy of every recording (by student and lab).
    speed : float or None
        The virtual rigs' pace (None: as fast as possible).
    profile : str, path or jerklab.rig.MotorProfile, optional
        The class's rig motor (:mod:`jerklab.rig.profiles`, a built-in name or a profile file):
        the hidden motors are drawn around its ranges (:func:`jerklab.lab.specs.hidden_ranges`)
        and every session gets the lab's numbers on it (``S.spec``); None: the paper's class
        motors.
    """

    def __init__(
        self,
        auth,
        log,
        key=None,
        listen="127.0.0.1:0",
        recordings=None,
        speed=None,
        profile=None,
    ):
        if key is None:
            key, source = instructor_key(warn=False)
            if source == "default":
                raise ValueError(
                    "key: the class rig service grades, so it needs the instructor key "
                    "(JERKLAB_INSTRUCTOR_KEY_FILE or ~/.config/jerklab/instructor.key); "
                    "without one, students work on practice motors and need no service"
                )
        key = bytes(key)
        if not key or hmac.compare_digest(key, CLASSROOM_DEFAULT_KEY):
            raise ValueError("key: the public classroom default key cannot grade")
        self.key = key
        self.profile = None if profile is None else load_profile(profile)
        self.auth = auth
        self.speed = speed
        self.recordings = None if recordings is None else Path(recordings)
        self.log = _Log(log)
        self._students = {}
        self._lock = threading.Lock()
        self.refused = 0
        self._connections = 0
        self._per_student = {}
        service = self

        class Handler(socketserver.StreamRequestHandler):
            def handle(self):
                service._serve(self.connection, self.rfile, self.wfile)

        if listen.startswith("unix:"):
            path = listen[len("unix:") :]
            if os.path.exists(path):
                if not stat.S_ISSOCK(os.stat(path).st_mode):
                    raise ValueError(f"listen: {path!r} exists and is not a socket")
                os.unlink(path)  # a socket left by an earlier run
            self._server = socketserver.ThreadingUnixStreamServer(path, Handler)
            os.chmod(path, 0o666)  # anyone may connect: the token says who they are
            self.address = f"unix:{path}"
        else:
            host, _, port = listen.rpartition(":")
            if not host or not port.isdigit():
                raise ValueError(f"listen must be 'HOST:PORT' or 'unix:PATH', got {listen!r}")
            self._server = socketserver.ThreadingTCPServer((host, int(port)), Handler)
            h, p = self._server.server_address[:2]
            self.address = f"{h}:{p}"
        self._server.daemon_threads = True
        self._thread = None

    @property
    def url(self) -> str:
        """The address a kernel connects to: ``classrig://HOST:PORT`` or ``classrig+unix://PATH``."""
        if self.address.startswith("unix:"):
            return "classrig+unix://" + self.address[len("unix:") :]
        return "classrig://" + self.address

    def start(self):
        """Serve from a background thread; returns self."""
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="jerklab-classrig", daemon=True
        )
        self._thread.start()
        return self

    def serve_forever(self):
        self._server.serve_forever()

    def close(self):
        self._server.shutdown()
        self._server.server_close()
        if self.address.startswith("unix:"):
            try:
                os.unlink(self.address[len("unix:") :])
            except OSError:
                pass
        with self._lock:
            for st in self._students.values():
                st.close()
            self._students.clear()
        self.log.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    def _student(self, student, lab) -> _Student:
        with self._lock:
            st = self._students.get((student, lab))
            if st is None:
                st = self._students[student, lab] = _Student(self, student, lab)
            return st

    def _hello(self, req):
        token = req.get("token")
        if not isinstance(token, str) or not 8 <= len(token) <= 512:
            raise AuthError("no token (the hub's JUPYTERHUB_API_TOKEN or the class token)")
        user = normalize_student(self.auth(token))
        typed = req.get("student")
        if typed is not None and (not isinstance(typed, str) or typed.strip().lower() != user):
            raise PermissionError(
                f"student: this connection is authenticated as {user!r} and cannot act as "
                f"{typed!r}; leave student out (your login names you)"
            )
        lab = req.get("lab")
        if lab not in LABS:
            raise ValueError(f"lab must be one of {sorted(LABS)}, got {lab!r}")
        return self._student(user, lab)

    def _serve(self, conn, rfile, wfile):
        with self._lock:
            full = self._connections >= LIMITS["connections"]
            if not full:
                self._connections += 1
        try:
            if full:
                msg = f"connections: the service serves at most {LIMITS['connections']} at a time"
                wfile.write((json.dumps({"error": msg, "type": "RigError"}) + "\n").encode())
                wfile.flush()
                return
            user = []
            try:
                self._serve_link(conn, rfile, wfile, user)
            finally:
                if user:
                    with self._lock:
                        self._per_student[user[0]] -= 1
        except OSError:
            return  # the client went away
        finally:
            if not full:
                with self._lock:
                    self._connections -= 1

    def _admit(self, st, user):
        """Count the connection of ``st``'s student (PermissionError beyond the limit)."""
        with self._lock:
            n = self._per_student.get(st.student, 0)
            if n >= LIMITS["connections_per_student"]:
                raise PermissionError(
                    f"connections: at most {LIMITS['connections_per_student']} at a time per "
                    "student; close another session (S.close()) first"
                )
            self._per_student[st.student] = n + 1
        user.append(st.student)

    def _serve_link(self, conn, rfile, wfile, user):
        conn.settimeout(LIMITS["hello_seconds"])
        st = None

        def send(obj):
            wfile.write((json.dumps(obj) + "\n").encode("utf-8"))
            wfile.flush()

        while True:
            try:
                line = rfile.readline(LIMITS["request_bytes"] + 1)
            except OSError:
                return
            if not line:
                return
            if len(line) > LIMITS["request_bytes"]:
                send(
                    {
                        "error": f"request longer than {LIMITS['request_bytes']} bytes",
                        "type": "ValueError",
                    }
                )
                return
            try:
                req = json.loads(line.decode("utf-8"))
                if not isinstance(req, dict):
                    raise ValueError("a request is a JSON object")
            except (ValueError, UnicodeDecodeError) as exc:
                send({"error": f"unreadable request ({exc})", "type": "ValueError"})
                return
            try:
                if st is None:
                    if req.get("op") != "hello":
                        raise AuthError("say hello with your token first")
                    st = self._hello(req)
                    self._admit(st, user)
                    conn.settimeout(_IDLE_TIMEOUT)
                    send(st.info())
                    continue
                with st.lock:
                    if req.get("op") == "check":
                        name = req.get("name")
                        check_function(st.lab, name)  # KeyError naming the lab's checks
                        answer = req.get("answer")
                        res = st.score(name, answer)
                        n = self.log.write(st.student, st.lab, name, answer, res.ok)
                        send(
                            {
                                "ok": True,
                                "name": name,
                                "passed": res.ok,
                                "message": res.message,
                                "attempt": n,
                            }
                        )
                    elif req.get("op") == "host_loop":

                        def answer_line():
                            conn.settimeout(LIMITS["host_answer_seconds"])
                            try:
                                return rfile.readline(LIMITS["request_bytes"] + 1)
                            finally:
                                conn.settimeout(_IDLE_TIMEOUT)

                        send(st.host_loop(req, send, answer_line))
                    else:
                        send(st.handle(req))
            except AuthError as exc:
                self.refused += 1
                send({"error": f"authentication failed: {exc}", "type": "AuthError"})
                return
            except PermissionError as exc:
                self.refused += 1
                send({"error": str(exc), "type": "PermissionError"})
                return
            except (ValueError, KeyError, TypeError) as exc:
                msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
                send({"error": str(msg), "type": type(exc).__name__})
            except RigError as exc:
                send({"error": str(exc), "type": "RigError"})
            except Exception as exc:  # the service keeps serving the class
                send({"error": f"the class rig failed ({type(exc).__name__})", "type": "RigError"})


# ------------------------------------------------------------------ command line
def _warm_up(svc):
    """Run every kind of request once on a throwaway student of each lab, so that everything the
    service imports lazily is loaded while it can still read it (before it drops to its user,
    who may not read the interpreter's files), and a broken install shows at start."""
    for lab in sorted(LABS):
        st = _Student(svc, "warm-up.self-test", lab)
        try:
            for v in (6.0, 3.0):
                st.handle({"op": "step", "name": f"step_p{v:g}V", "voltage": v, "seconds": 0.2})
            st.handle({"op": "record_prbs", "name": "prbs", "amplitude": 2.0, "offset": 6.0})
            p = planner.plan_sine_jerk(1.0, 2.0e4, 600.0, 80.0)
            g = jsonable(discrete_pole_placement_pid(30.0, 0.03, 30.0, 1.0, Ts=0.005))
            prof = {"kind": p.kind, "distance": 1.0, "max_jerk": 2.0e4, "max_accel": 600.0}
            prof["max_velocity"] = 80.0
            st.handle({"op": "set_shaper", "taps": [0.5, 0.5]})
            st.handle({"op": "set_shaper", "taps": None})
            move = {"op": "run_move", "name": "m", "profile": prof, "gains": g}
            try:
                st.handle({**move, "run": {"settle": 0.05, "force": True}})
            except RigError:
                pass  # a safety stop: the code ran
            for n, name in CHECKS:
                if n == lab:
                    st.score(name, 1.0)
        finally:
            st.close()


def _drop_to(user):
    import grp
    import pwd

    pw = pwd.getpwnam(user)
    os.setgroups([g.gr_gid for g in grp.getgrall() if user in g.gr_mem])
    os.setgid(pw.pw_gid)
    os.setuid(pw.pw_uid)
    os.environ["HOME"] = pw.pw_dir


def main(argv=None):
    """``python -m jerklab.lab service``: run the class rig service until interrupted."""
    ap = argparse.ArgumentParser(
        prog="python -m jerklab.lab service", description=__doc__.split("\n\n")[0]
    )
    where = ap.add_mutually_exclusive_group()
    where.add_argument(
        "--listen", default="127.0.0.1:7341", help="HOST:PORT (default 127.0.0.1:7341)"
    )
    where.add_argument("--unix", help="a Unix socket path instead of TCP")
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--hub-api", help="the hub's API URL (e.g. http://127.0.0.1:8081/hub/api)")
    who.add_argument("--tokens", help="a JSON file {token: student} (a class without a hub)")
    ap.add_argument("--log", default="classrig-checks.jsonl", help="the check log (JSON lines)")
    ap.add_argument("--recordings", help="keep a copy of every recording here")
    ap.add_argument("--user", help="when started as root: drop to this Unix user after start-up")
    ap.add_argument(
        "--profile",
        help="the rig's motor profile (a built-in name or a profile file, jerklab.rig.profiles): "
        "hidden motors around its ranges, the labs' specs on it (default: the paper's motors)",
    )
    args = ap.parse_args(argv)
    profile = None
    if args.profile is not None:
        try:
            profile = load_profile(args.profile)
        except (ValueError, TypeError) as exc:
            ap.error(f"--profile: {exc}")
    root = hasattr(os, "geteuid") and os.geteuid() == 0
    if root and not args.user:
        ap.error(
            "--user: do not run the class rig service as root; give its own user "
            "(e.g. --user jerklab-rig), to which it drops after reading the key"
        )
    if args.user and not root:
        ap.error("--user: only a service started as root can switch to its own user")
    key, source = instructor_key(warn=False)
    if source == "default":
        ap.error(
            "no instructor key (JERKLAB_INSTRUCTOR_KEY_FILE or ~/.config/jerklab/instructor.key): "
            "the class rig service grades and needs one"
        )
    os.environ.pop("JERKLAB_INSTRUCTOR_KEY", None)
    auth = HubAuth(args.hub_api) if args.hub_api else TokenFile(args.tokens)
    listen = f"unix:{args.unix}" if args.unix else args.listen
    svc = ClassRigService(
        auth, args.log, key=key, listen=listen, recordings=args.recordings, profile=profile
    )
    _warm_up(svc)
    if args.user:
        if args.recordings:
            import pwd

            pw = pwd.getpwnam(args.user)
            Path(args.recordings).mkdir(parents=True, exist_ok=True)
            os.chown(args.recordings, pw.pw_uid, pw.pw_gid)
        _drop_to(args.user)
    shown = "the paper's motors" if profile is None else f"motor profile {profile.name}"
    print(f"class rig service at {svc.url} ({shown}; log {args.log})", flush=True)
    try:
        svc.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        svc.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
