"""A lab session: the student's rig, the recordings of the lab, the answers and their checks.

The session connects the student's device (:func:`jerklab.lab.motors.student_device`) to the
rig, keeps what the student records and answers, and for each check gathers the plain
evidence (:class:`jerklab.lab.plain.Evidence`), fetches the truth of the hidden motor (today
from :mod:`jerklab.lab.motors`), calls the check through :mod:`jerklab.lab.registry` and stores
the result.
"""

from __future__ import annotations

import os
import re
import time
import warnings
from pathlib import Path

from jerklab import paper
from jerklab.lab.checkbase import CheckResult, Missing
from jerklab.lab.checks import MOVE, SPEC
from jerklab.lab.handin import PLACEHOLDER_STUDENT, HandinRefused, write_handin
from jerklab.lab.motors import (
    DefaultKeyWarning,
    hidden_truth,
    normalize_student,
    simulated_motor,
    student_device,
    student_motor,
)
from jerklab.lab.plain import Evidence, Run, jsonable
from jerklab.lab.registry import FLEXIBLE_LABS, LABS, check_function
from jerklab.rig import RigError, connect

__all__ = ["LabSession", "start", "panel_gains", "CheckResult", "LABS", "SPEC", "MOVE"]


def panel_gains(panel):
    """The gains chosen in a tuning panel: ``panel.gains`` where the panel has it, else
    ``panel.result.gains`` (``jerklab.widgets.pole_placement_panel``)."""
    g = getattr(panel, "gains", None)
    if g is None:
        g = panel.result.gains
    return g


def _port_from_env(port):
    """While grading, every notebook runs on the virtual rig of its student."""
    if os.environ.get("JERKLAB_LAB_GRADING"):
        return None
    return port


class LabSession:
    """What a worksheet works with: ``rig``, ``student``, ``folder``, ``recordings``, ``answers``.

    Make one with :func:`start`. Runs go through :meth:`step` and :meth:`run_move` so that
    every recording lands in the lab's folder (handed in by :meth:`submit`).
    """

    def __init__(self, lab, student, port=None, folder=None, speed=None, key=None, progress=False):
        if lab not in LABS:
            raise ValueError(f"lab must be one of {sorted(LABS)}, got {lab!r}")
        self.lab = lab
        self.student = normalize_student(student)
        self.port = _port_from_env(port)
        base = (
            Path(folder)
            if folder is not None
            else Path(os.environ.get("JERKLAB_LAB_WORK", "lab-work"))
        )
        self.folder = base / self.student / f"lab{lab}"
        self.folder.mkdir(parents=True, exist_ok=True)
        self.plant = "flexible" if lab in FLEXIBLE_LABS else "rigid"
        if self.plant == "flexible" and self.port not in (None, "virtual", "", "simavr"):
            print(
                f"⚠ lab {lab} needs the flexible load: on a real Uno, mount the load on its shaft coupling"
            )
        port = None if self.port == "" else self.port
        # the hidden motor as this port simulates it; None on a real board (its motor is real);
        # without an instructor key it is a practice motor, said in one line by start()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DefaultKeyWarning)
            drawn = student_motor(self.student, key, plant=self.plant)
        self.practice = any(issubclass(w.category, DefaultKeyWarning) for w in caught)
        for w in caught:
            if not issubclass(w.category, DefaultKeyWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        self._motor = simulated_motor(drawn, port)
        if self._motor is None and speed is not None:
            raise ValueError("speed applies to the virtual rig only (port=None)")
        self.rig = connect(
            port,
            device=None if self._motor is None else student_device(self._motor, speed),
            progress=progress,
            recordings=self.folder,
            metadata={"student": self.student, "lab": lab},
        )
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
        """True when the plant is the student's hidden motor (virtual rig or simavr)."""
        return self._motor is not None

    def _truth(self):
        """The hidden motor's parameters for the checks (None on a real rig)."""
        return None if self._motor is None else hidden_truth(self._motor)

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
        returns None with a message instead of stopping the worksheet.
        """
        name = name or f"move_{profile.kind}"
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
        )

    def verify(self, name, answer):
        """Run check ``name`` of this lab on ``answer`` silently; return a :class:`CheckResult`.

        Every answer is kept for the hand-in (``answers``), but a later check sees it only
        once its own check passed (:meth:`evidence`). Raises KeyError for a name the lab has
        no check for."""
        check = check_function(self.lab, name)
        self.answers[name] = jsonable(answer)
        try:
            res = check(answer, self.evidence(), self._truth())
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


def start(lab, student, port=None, **options):
    """Start lab ``lab`` (1 to 4; lab 4's rig has the flexible load) for ``student`` on
    ``port`` (None: the virtual rig with the student's hidden motor; ``"simavr"``; a serial port
    of a real Uno)."""
    s = LabSession(lab, student, port, **options)
    if s.port in (None, "virtual", ""):
        where = "virtual rig (your hidden motor)"
    elif s.port == "simavr":
        where = f"firmware on a simulated Uno (your hidden motor; {s.rig.port})"
    else:
        where = f"rig at {s.rig.port}"
    print(
        f"Lab {lab} ({LABS[lab]}) for student {s.student} on the {where}; "
        f"encoder {s.rig.counts_per_rev} counts/rev, supply {s.rig.supply_voltage:g} V; "
        f"recordings in {s.folder}"
    )
    if s.student == PLACEHOLDER_STUDENT:
        print(
            f"Put your student ID in STUDENT (it is still {PLACEHOLDER_STUDENT!r}) and run this "
            "cell again: your motor is drawn from it, and a hand-in needs it."
        )
    if s.practice and s.simulated:
        print(
            "Practice motor: no instructor key on this machine, so your motor comes from the "
            "public class default — fine for practice; graded work is run with the class key."
        )
    return s
