"""A lab session: the student's rig, the recordings of the lab, the answers and their checks.

A session runs in one of three modes (``S.mode``, written into every recording and hand-in):

``"graded"``
    The class rig service (:mod:`jerklab.lab.service`) runs the student's hidden motor; the
    session reaches it over a socket (``port="classrig://..."``, or ``$JERKLAB_CLASS_RIG``)
    and the service scores the checks. The student is whoever the login's token names. The
    student's process never holds the motor or its truth.
``"practice"``
    No service: the virtual rig (or simavr) runs a **practice** motor seeded by a public class
    code (:func:`jerklab.lab.motors.practice_motor`), or the port is a real board. The checks
    compare the answers with what the checker finds in the student's own recordings (as on a
    real rig), never with a motor's parameters.
``"instructor"``
    The instructor key is in this process (``key=`` or the instructor's key file): the hidden
    motor runs here and the checks see its truth. Only for the trusted grader and the
    instructor's own runs; a student's process never has the key.

The session keeps what the student records and answers and, for each check, gathers the plain
evidence (:class:`jerklab.lab.plain.Evidence`) and calls the check through
:mod:`jerklab.lab.registry` (or asks the service, which does the same with its own recordings).
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

from jerklab import paper
from jerklab.lab.checkbase import CheckResult, Missing
from jerklab.lab.checks import MOVE, SPEC
from jerklab.lab.classrig import SCHEMES, ClassRig, ClassRigError, service_address
from jerklab.lab.handin import PLACEHOLDER_STUDENT, HandinRefused, write_handin
from jerklab.lab.motors import (
    hidden_truth,
    instructor_key,
    normalize_student,
    practice_key,
    simulated_motor,
    student_device,
    student_motor,
)
from jerklab.lab.plain import Evidence, Run, jsonable
from jerklab.lab.registry import FLEXIBLE_LABS, LABS, check_function
from jerklab.lab.specs import lab_spec
from jerklab.rig import Device, MotorProfile, RigError, connect, load_profile
from jerklab.rig.profiles import builtin_profiles, profile_from_dict

__all__ = ["LabSession", "start", "panel_gains", "CheckResult", "LABS", "SPEC", "MOVE", "MODES"]

#: The modes of a session (see the module's text).
MODES = ("graded", "practice", "instructor")


def panel_gains(panel):
    """The gains chosen in a tuning panel: ``panel.gains`` where the panel has it, else
    ``panel.result.gains`` (``jerklab.widgets.pole_placement_panel``)."""
    g = getattr(panel, "gains", None)
    if g is None:
        g = panel.result.gains
    return g


def _port_from_env(port):
    """While graded, every worksheet runs on the rig the grader serves (``$JERKLAB_LAB_RIG``, a
    pseudo-terminal in the sandbox: the hidden motor stays in the grader's process); with
    ``JERKLAB_LAB_GRADING`` alone, on the virtual rig of its student."""
    served = os.environ.get("JERKLAB_LAB_RIG")
    if served:
        return served
    if os.environ.get("JERKLAB_LAB_GRADING"):
        return None
    return port


def _grader_served(port) -> bool:
    """True when ``port`` is the rig the grader serves (``$JERKLAB_LAB_RIG``): its virtual
    device, whose motor is at rest at once after every run."""
    served = os.environ.get("JERKLAB_LAB_RIG")
    return bool(served) and port == served


def _graders_profile(port):
    """The class's motor profile the grader serves its rig with (``$JERKLAB_LAB_PROFILE_JSON``,
    set by ``grade --profile``; a built-in profile by its name, another written to a file in
    the working folder), or None."""
    text = os.environ.get("JERKLAB_LAB_PROFILE_JSON")
    if not text or not _grader_served(port):
        return None
    import json

    prof = profile_from_dict(json.loads(text))
    if builtin_profiles().get(prof.name) == prof:
        return prof.name
    path = Path(os.environ.get("JERKLAB_LAB_WORK", ".")) / "class-profile.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    return str(prof.save(path))


def _served_device():
    """The encoder of the rig the grader serves (``$JERKLAB_LAB_RIG_CPR`` counts per revolution),
    or None: a real board's defaults."""
    cpr = os.environ.get("JERKLAB_LAB_RIG_CPR")
    return Device(counts_per_rev=int(cpr)) if cpr else None


def _service_of(port, key):
    """The class rig service's address for ``port``, or None for a local rig."""
    if isinstance(port, str) and port.startswith(SCHEMES):
        return port
    if port in (None, "virtual", "") and key is None:
        return service_address()
    return None


class LabSession:
    """What a worksheet works with: ``rig``, ``student``, ``mode``, ``folder``, ``recordings``,
    ``answers``, and the lab's numbers on the rig's motor profile (``profile``; ``spec``:
    :func:`jerklab.lab.specs.lab_spec`, e.g. ``S.spec["move"]``).

    Make one with :func:`start`. Runs go through :meth:`step` and :meth:`run_move` so that
    every recording lands in the lab's folder (handed in by :meth:`submit`).

    Parameters
    ----------
    lab : int
        1 to 5.
    student : str, optional
        The student ID. With the class rig service the login's token names the student: leave
        it out, or give the same ID (another one is refused).
    port : None, str
        None: the class rig service if ``$JERKLAB_CLASS_RIG`` names one, else the virtual rig;
        ``"classrig://HOST:PORT"`` or ``"classrig+unix:///PATH"``: the service; ``"simavr"``; a
        serial port of a real Uno.
    key : bytes, optional
        The instructor key (trusted processes only: mode ``"instructor"``).
    class_code : str, optional
        The public code of the practice motors (default ``$JERKLAB_CLASS_CODE``).
    token : str, optional
        The service's token (default ``$JUPYTERHUB_API_TOKEN``, else ``$JERKLAB_CLASS_TOKEN``).
    """

    def __init__(
        self,
        lab,
        student=None,
        port=None,
        folder=None,
        speed=None,
        key=None,
        progress=False,
        profile=None,
        class_code=None,
        token=None,
    ):
        if lab not in LABS:
            raise ValueError(f"lab must be one of {sorted(LABS)}, got {lab!r}")
        self.lab = lab
        self.port = _port_from_env(port)
        self.plant = "flexible" if lab in FLEXIBLE_LABS else "rigid"
        graders = _graders_profile(self.port)
        if graders is not None:
            # graded by `python -m jerklab.lab grade --profile`: the class's profile decides
            # the motor and the numbers, whatever the worksheet's PROFILE line says
            profile = graders
        # the rig's motor profile: the hidden motors' ranges, the moves and specs (lab_spec)
        self.profile = None if profile is None else load_profile(profile)
        # what the checks are told (a name, or a profile file's path)
        self.profile_name = (
            None
            if profile is None
            else self.profile.name
            if isinstance(profile, MotorProfile)
            else os.fspath(profile)
        )
        self.spec = lab_spec(lab, self.profile or "paper")
        service = _service_of(self.port, key)
        trusted = None
        if service is not None:
            if speed is not None:
                raise ValueError("speed applies to a local virtual rig only, not the class rig")
            self.rig = ClassRig(service, lab, token=token, student=student)
            self.student = normalize_student(self.rig.student)
            self.mode = "graded"
            self._simulated = True
            # the service's motor profile decides the motors and the lab's numbers
            served = self.rig.profile
            if self.profile is not None and (served is None or served.name != self.profile.name):
                self.rig.close()
                raise ValueError(
                    f"profile: the class rig service runs "
                    f"{'the paper' if served is None else served.name!r}'s motors, not "
                    f"{self.profile.name!r}; leave profile out on the class rig"
                )
            self.profile = served
            self.profile_name = None if served is None else served.name
            self.spec = lab_spec(lab, served or "paper")
        else:
            if student is None:
                raise ValueError("student: give your student ID (no class rig service is set)")
            self.student = normalize_student(student)
            if key is None:
                found, source = instructor_key(warn=False)
                key = found if source != "default" else None
            self.mode = "practice" if key is None else "instructor"
            seed_key = practice_key(class_code) if key is None else bytes(key)
            if self.plant == "flexible" and self.port not in (None, "virtual", "", "simavr"):
                print(
                    f"⚠ lab {lab} needs the flexible load: on a real Uno, mount the load on its "
                    "shaft coupling"
                )
            local = None if self.port == "" else self.port
            # the motor as this port simulates it; None on a real board, or the rig the grader
            # serves into its sandbox (the motor is behind the port)
            motor = simulated_motor(
                student_motor(self.student, seed_key, plant=self.plant, profile=self.profile),
                local,
            )
            if motor is None and speed is not None:
                raise ValueError("speed applies to the virtual rig only (port=None)")
            self._simulated = motor is not None
            if motor is not None and self.mode == "instructor":
                trusted = hidden_truth(motor)
            device = _served_device() if motor is None else student_device(motor, speed)
            del motor
        #: True for practice work (no class rig service, no instructor key)
        self.practice = self.mode == "practice"
        base = (
            Path(folder)
            if folder is not None
            else Path(os.environ.get("JERKLAB_LAB_WORK", "lab-work"))
        )
        self.folder = base / self.student / f"lab{lab}"
        self.folder.mkdir(parents=True, exist_ok=True)
        if service is None:
            self.rig = connect(
                local,
                device=device,
                progress=progress,
                recordings=self.folder,
                metadata={"student": self.student, "lab": lab, "mode": self.mode},
                profile=self.profile,
            )
            if _grader_served(self.port):
                # the grader's virtual device coasts to rest at the end of every run
                # (jerklab.rig.virtual): no wait_still after each step over the pty
                self.rig.instant_coast = True
        # the checks' truth: only in a trusted process (mode "instructor"), never returned
        self._check_truth = (lambda: trusted) if trusted is not None else (lambda: None)
        self.recordings = {}
        self.answers = {}
        self.results = {}
        self.gains = None
        #: when the student last did something (a cell ran, a recording, a check): the saved
        #: notebook must be newer for :meth:`submit`
        self.last_activity = time.time()
        self._ipython = None
        try:
            from IPython import get_ipython

            ip = get_ipython()
            if ip is not None:
                ip.events.register("pre_run_cell", self._cell_starts)
                ip.events.register("post_run_cell", self._cell_ran)
                self._ipython = ip
        except ImportError:
            pass

    def _cell_starts(self, info=None):
        self._cell_start = time.time()

    def _cell_ran(self, result=None):
        # a cell counts from when it started: a save during or after it is newer
        start = getattr(self, "_cell_start", None) or time.time()
        self.last_activity = max(self.last_activity, start)

    # ---------------------------------------------------------------- the rig
    @property
    def simulated(self) -> bool:
        """True when the plant is a simulated motor (the class rig, virtual rig or simavr)."""
        return self._simulated

    @property
    def graded(self) -> bool:
        """True when the class rig service runs the motor and scores the checks."""
        return self.mode == "graded"

    def _path(self, name):
        if not re.match(r"^[A-Za-z0-9_.+-]{1,60}$", name):
            raise ValueError(f"name must be 1-60 letters, digits or _.+-, got {name!r}")
        return self.folder / name

    def step(self, voltage, seconds, name=None, Ts=paper.TS, **kwargs):
        """``rig.step(voltage, seconds, Ts)`` saved as ``name`` (default ``step_<V>V``)."""
        name = name or f"step_{voltage:+g}V".replace("+", "p").replace("-", "m").replace(".", "_")
        rec = self.rig.step(voltage, seconds, Ts=Ts, path=self._path(name), **kwargs)
        self.recordings[name] = rec
        self.last_activity = time.time()
        return rec

    def record_prbs(self, amplitude, name="prbs", Ts=paper.TS, **kwargs):
        """``rig.record_prbs(amplitude, Ts=Ts, **kwargs)`` (the on-board PRBS) saved as ``name``."""
        rec = self.rig.record_prbs(amplitude, Ts=Ts, path=self._path(name), **kwargs)
        self.recordings[name] = rec
        self.last_activity = time.time()
        return rec

    def set_shaper(self, shaper, Ts=paper.TS):
        """``rig.set_shaper(shaper, Ts)``: the input shaper of the following moves (None: off)."""
        return self.rig.set_shaper(shaper, Ts)

    def run_move(self, profile, gains, Ts=None, name=None, **run):
        """``rig.run_move(profile, gains, Ts, **run)`` saved as ``name`` (default
        ``move_<kind>``); ``run`` are fields of :class:`jerklab.rig.RunSpec` (``settle=0.4``,
        ``force=True``, ...).

        A planner the device does not have (the firmware runs only the published sine-jerk)
        returns None with a message instead of stopping the worksheet. The tracking-error stop
        (``max_error``) defaults to the lab's ``spec["stop_error"]`` where the lab has one
        (labs 2-3: the device's 0.5 rad, or 1.25 times a larger spec limit); on the class rig
        service the service sets it.
        """
        name = name or f"move_{profile.kind}"
        if "stop_error" in (self.spec or {}) and not isinstance(self.rig, ClassRig):
            run.setdefault("max_error", self.spec["stop_error"])
        try:
            rec = self.rig.run_move(profile, gains, Ts, path=self._path(name), **run)
        except RigError as exc:
            if "planner" not in str(exc):
                raise
            print(
                f"⚠ {self.rig.port}: this device has no {profile.kind!r} planner (the firmware runs "
                f"only the published sine-jerk today); the {profile.kind} move is skipped here and "
                f"its cells use the simulation only."
            )
            return None
        self.recordings[name] = rec
        self.gains = gains
        self.last_activity = time.time()
        return rec

    def host_loop(self, control, Ts, duration, reference=None, name="host", **options):
        """``rig.host_loop(control, Ts, duration, reference, **options)`` saved as ``name``: your
        own law ``control(t, position, reference) -> volts`` closes the loop through the rig
        (host-in-the-loop, :meth:`jerklab.rig.Rig.host_loop`; lab 5). The voltage your law
        returns for the sample at tick k applies at tick k + 1."""
        rec = self.rig.host_loop(control, Ts, duration, reference, path=self._path(name), **options)
        self.recordings[name] = rec
        self.last_activity = time.time()
        return rec

    def realtime(self, Ts, duration, reference=None, name="host", **options):
        """``rig.realtime(Ts, duration, reference, **options)`` (iterate the ticks, ``step.apply(v)``
        each) whose recording is saved as ``name`` once the loop ends (the loop's ``recording``,
        :meth:`jerklab.rig.Rig.realtime`)."""
        loop = self.rig.realtime(Ts, duration, reference, path=self._path(name), **options)
        return _KeptLoop(self, name, loop)

    def set_model(self, K, tau):
        """The feedforward model of the rig (your identified K and τ)."""
        self.rig.set_model(K, tau)

    # ---------------------------------------------------------------- checks
    def evidence(self) -> Evidence:
        """The plain data the checks see: every recording's arrays, the answers whose check
        passed (a later check that builds on a failed one says it needs it), the rig's counts
        per revolution."""
        passed = {k: v for k, v in self.answers.items() if k in self.results and self.results[k].ok}
        return Evidence(
            runs={k: Run.from_recording(r) for k, r in self.recordings.items()},
            answers=passed,
            counts_per_rev=self.rig.counts_per_rev,
            profile=self.profile_name,
        )

    def verify(self, name, answer):
        """Run check ``name`` of this lab on ``answer`` silently; return a :class:`CheckResult`.

        Every answer is kept for the hand-in (``answers``), but a later check sees it only
        once its own check passed (:meth:`evidence`). In mode ``"graded"`` the class rig service
        scores it (and logs the attempt); in mode ``"practice"`` the check compares with the
        checker's analysis of your recordings. Raises KeyError for a name the lab has no check
        for."""
        check = check_function(self.lab, name)
        self.answers[name] = jsonable(answer)
        if self.mode == "graded":
            try:
                passed, message = self.rig.check(name, answer)
                res = CheckResult(name, passed, message)
            except ClassRigError as exc:
                res = CheckResult(name, False, f"not checked: {exc}")
            self.results[name] = res
            return res
        try:
            res = check(answer, self.evidence(), self._check_truth())
        except Missing as exc:
            res = CheckResult(name, False, str(exc))
        except (TypeError, ValueError, KeyError, AttributeError, IndexError) as exc:
            res = CheckResult(
                name,
                False,
                f"could not use your answer ({type(exc).__name__}: {exc}): give a value of "
                "the type and in the units the task asks for.",
            )
        self.results[name] = res
        self.last_activity = time.time()
        return res

    def check(self, name, answer):
        """Run check ``name`` and show right/wrong with a hint or the reason (the result is in
        ``self.results[name]``; :meth:`verify` returns it silently)."""
        res = self.verify(name, answer)
        try:
            from IPython import get_ipython
            from IPython.display import display

            if get_ipython() is not None:
                display(res)
                return
        except ImportError:
            pass
        print(repr(res))

    def summary(self):
        """One line per check run so far."""
        for r in self.results.values():
            print(repr(r))

    # ---------------------------------------------------------------- hand-in
    def submit(self, notebook=None, out=None, include=()):
        """Write the hand-in zip (the saved notebook, this session's recordings and those named
        in ``include``, gains, answers, student ID, manifest); return its path.

        When it would be empty or not the student's (:func:`jerklab.lab.handin.write_handin`:
        the placeholder ID, a notebook not saved since the last cell ran, no answers) nothing
        is written: one line says why and what to do, and None is returned."""
        try:
            return write_handin(self, notebook=notebook, out=out, include=include)
        except HandinRefused as exc:
            print(f"✘ not handed in: {exc}")
            return None

    def close(self):
        if self._ipython is not None:
            try:
                self._ipython.events.unregister("pre_run_cell", self._cell_starts)
                self._ipython.events.unregister("post_run_cell", self._cell_ran)
            except ValueError:
                pass
            self._ipython = None
        self.rig.close()

    def __repr__(self):
        return (
            f"LabSession(lab={self.lab}, student={self.student!r}, rig={self.rig.port!r}, "
            f"recordings={len(self.recordings)})"
        )


class _KeptLoop:
    """A :class:`jerklab.rig.hostloop.RealtimeLoop` whose recording the session keeps when the
    iteration ends (its end, ``break``, an error)."""

    def __init__(self, session, name, loop):
        self._session, self._name, self._loop = session, name, loop

    def __iter__(self):
        try:
            yield from self._loop
        finally:
            rec = self._loop.recording
            if rec is not None:
                self._session.recordings[self._name] = rec
                self._session.last_activity = time.time()

    def __getattr__(self, name):
        return getattr(self._loop, name)


def start(lab, student=None, port=None, **options):
    """Start lab ``lab`` (1 to 5; lab 4's rig has the flexible load, lab 5 closes the loop
    through the rig with your own law: ``S.host_loop``) for ``student`` on
    ``port`` (None: the class rig service when ``$JERKLAB_CLASS_RIG`` names one, else the
    virtual rig with a practice motor; ``"simavr"``; a serial port of a real Uno). ``profile=``
    names the rig's motor (``jerklab.rig.profiles``: a built-in name or the profile file of
    ``jerklab rig check --save``): the hidden motors, the moves and the specs follow it
    (``S.spec``)."""
    s = LabSession(lab, student, port, **options)
    if s.mode == "graded":
        where = f"class rig ({s.rig.port}; your graded motor, checked by the service)"
    elif s.port in (None, "virtual", ""):
        where = "virtual rig (your hidden motor)"
    elif s.port == "simavr":
        where = f"firmware on a simulated Uno (your hidden motor; {s.rig.port})"
    else:
        where = f"rig at {s.rig.port}"
    print(
        f"Lab {lab} ({LABS[lab]}) for student {s.student} on the {where}; "
        f"encoder {s.rig.counts_per_rev} counts/rev, supply {s.rig.supply_voltage:g} V"
        + (f", motor profile {s.profile.name}" if s.profile is not None else "")
        + "; "
        f"recordings in {s.folder}"
    )
    if s.student == PLACEHOLDER_STUDENT:
        print(
            f"Put your student ID in STUDENT (it is still {PLACEHOLDER_STUDENT!r}) and run this "
            "cell again: your motor is drawn from it, and a hand-in needs it."
        )
    if s.mode == "practice":
        print(
            "Practice motor: no class rig service here, so your motor comes from the public "
            "class code and the checks compare your answers with your own recordings; graded "
            "work runs on the class rig."
        )
    return s
