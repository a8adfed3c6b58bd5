"""Labs a student does: five two-hour worksheets on the rig, a hidden motor per student,
checks that answer at once, a hand-in zip and autograding (otter-grader).

>>> from jerklab import lab
>>> S = lab.start(1, student="s1234567")          # doctest: +SKIP  (virtual rig, your hidden motor)
>>> rec = S.step(6.0, 0.4)                          # doctest: +SKIP
>>> S.check("tau", 0.031)                           # doctest: +SKIP
✘ tau: τ is too high beyond the tolerance (8 %): ...

The worksheets are ``notebooks/labs/lab1_identify.ipynb``, ``lab2_poles.ipynb``,
``lab3_move.ipynb``, ``lab4_ringing.ipynb`` (the flexible load) and ``lab5_ownlaw.ipynb``
(your own law through the host loop) (generated from
``jerklab/lab/masters/`` by ``python -m jerklab.lab assign``);
``python -m jerklab.lab grade SUBMISSIONS_DIR --out grades.csv`` grades a class.

A session is ``"graded"`` when it runs on the class rig service (``python -m jerklab.lab
service``, :mod:`~jerklab.lab.service`; the kernel reaches it with :mod:`~jerklab.lab.classrig`,
the motor and its truth stay in the service), ``"practice"`` without one (a practice motor from a
public class code, checked against the student's own recordings), or ``"instructor"`` where the
instructor key is in the process (trusted code only).

The parts: :mod:`~jerklab.lab.motors` (hidden motors, the student's device and rig),
:mod:`~jerklab.lab.session` (what a worksheet calls), the checks as pure functions
(:mod:`~jerklab.lab.checks` for labs 1-3, :mod:`~jerklab.lab.ringing` for lab 4,
:mod:`~jerklab.lab.ownlaw` for lab 5, on
:mod:`~jerklab.lab.checkbase`), their table (:mod:`~jerklab.lab.registry`), the plain data they
see (:mod:`~jerklab.lab.plain`), the hand-in (:mod:`~jerklab.lab.handin`) and the grader
(:mod:`~jerklab.lab.grade`).
"""

from jerklab.lab.checkbase import CheckResult
from jerklab.lab.checks import (
    DESIGN_TS,
    MOVE,
    PANEL_START,
    PRBS,
    SPEC,
    STEP_SECONDS,
    SWEEP_VOLTS,
    spec_failures,
    spec_metrics,
    steady_speed,
    sweep_fit,
)
from jerklab.lab.handin import HandinError, read_handin, write_handin
from jerklab.lab.motors import (
    CLASSROOM_DEFAULT_KEY,
    RANGES,
    DefaultKeyWarning,
    StudentFlexibleMotor,
    StudentMotor,
    connect_student,
    coupled_mode,
    instructor_key,
    practice_key,
    practice_motor,
    student_device,
    student_motor,
)
from jerklab.lab.plain import Evidence, Run
from jerklab.lab.registry import LABS, run_check
from jerklab.lab.ringing import (
    MODE_DRIFT,
    MOVE4,
    PRBS_MODE,
    SOFT_KPD,
    load_deflection,
    residual_amplitude,
    soft_gains,
)
from jerklab.lab.session import LabSession, panel_gains, start
from jerklab.metrics import move_metrics

__all__ = [
    "start",
    "LabSession",
    "CheckResult",
    "panel_gains",
    "LABS",
    "MOVE",
    "SPEC",
    "PANEL_START",
    "SWEEP_VOLTS",
    "STEP_SECONDS",
    "DESIGN_TS",
    "PRBS",
    "steady_speed",
    "sweep_fit",
    "move_metrics",
    "spec_metrics",
    "spec_failures",
    "run_check",
    "Evidence",
    "Run",
    "student_motor",
    "practice_motor",
    "practice_key",
    "student_device",
    "StudentMotor",
    "connect_student",
    "instructor_key",
    "CLASSROOM_DEFAULT_KEY",
    "RANGES",
    "DefaultKeyWarning",
    "write_handin",
    "read_handin",
    "HandinError",
    "PRBS_MODE",
    "MOVE4",
    "SOFT_KPD",
    "MODE_DRIFT",
    "soft_gains",
    "load_deflection",
    "residual_amplitude",
    "coupled_mode",
    "StudentFlexibleMotor",
]
