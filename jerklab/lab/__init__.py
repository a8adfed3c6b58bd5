"""Labs a student does: four two-hour worksheets on the rig, a hidden motor per student,
checks that answer at once, a hand-in zip and autograding (otter-grader).

>>> from jerklab import lab
>>> S = lab.start(1, student="s1234567")          # doctest: +SKIP  (virtual rig, your hidden motor)
>>> rec = S.step(6.0, 0.4)                          # doctest: +SKIP
>>> S.check("tau", 0.031)                           # doctest: +SKIP
✘ tau: τ is +12 % off: ...

The worksheets are ``notebooks/labs/lab1_identify.ipynb``, ``lab2_poles.ipynb``,
``lab3_move.ipynb`` and ``lab4_ringing.ipynb`` (the flexible load) (generated from ``jerklab/lab/masters/`` by ``python -m jerklab.lab
assign``); ``python -m jerklab.lab grade SUBMISSIONS_DIR --out grades.csv`` grades a class.
"""

from jerklab.lab.checks import (
    DESIGN_TS,
    PRBS,
    STEP_SECONDS,
    SWEEP_VOLTS,
    move_metrics,
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
    student_motor,
)
from jerklab.lab.ringing import (
    MODE_DRIFT,
    MOVE4,
    PRBS_MODE,
    SOFT_KPD,
    load_deflection,
    residual_amplitude,
    soft_gains,
)
from jerklab.lab.session import LABS, MOVE, SPEC, CheckResult, LabSession, panel_gains, start

__all__ = [
    "start",
    "LabSession",
    "CheckResult",
    "panel_gains",
    "LABS",
    "MOVE",
    "SPEC",
    "SWEEP_VOLTS",
    "STEP_SECONDS",
    "DESIGN_TS",
    "PRBS",
    "steady_speed",
    "sweep_fit",
    "move_metrics",
    "student_motor",
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
