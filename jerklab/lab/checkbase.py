"""What every lab check is built from: its result, its "not there yet", and reading answers.

A check is a pure function ``check(answer, evidence, truth) -> CheckResult``
(:mod:`jerklab.lab.registry` lists them): ``answer`` is what the student gave, ``evidence`` the
plain data of their work (:class:`jerklab.lab.plain.Evidence`: recordings' arrays, earlier
answers, the rig's encoder resolution) and ``truth`` the hidden motor's parameters
(:func:`jerklab.lab.motors.hidden_truth`), or None on a real rig, where the check analyses the
recordings itself. A check never reads a session, a rig or a file.
"""

from __future__ import annotations

import math

__all__ = ["CheckResult", "Missing", "number", "rel", "pct", "run_of", "step_name"]


class CheckResult:
    """Outcome of one check: ``ok``, the ``message`` shown (hint or explanation), ``name``."""

    def __init__(self, name, ok, message):
        self.name, self.ok, self.message = name, bool(ok), str(message)

    def __bool__(self):
        return self.ok

    def __repr__(self):
        return f"{'✔' if self.ok else '✘'} {self.name}: {self.message}"

    def _repr_markdown_(self):
        colour = "green" if self.ok else "#b00"
        mark = "✔ right" if self.ok else "✘ not yet"
        return f"<span style='color:{colour}'>**{mark} — {self.name}**</span>: {self.message}"


class Missing(Exception):
    """A check needs a recording or an earlier answer that is not there yet (the message says
    which); the session shows it as a failed check."""


def number(name, x) -> float:
    """``x`` as a finite float; :class:`Missing` for ``...``/None or a non-finite number."""
    if x is Ellipsis or x is None:
        raise Missing(f"{name}: no answer yet — replace the `...`.")
    v = float(x)
    if not math.isfinite(v):
        raise Missing(f"{name}: your answer is {v}, not a finite number.")
    return v


def rel(a, b) -> float:
    """Relative difference ``|a − b| / |b|``."""
    return abs(a - b) / abs(b)


def pct(a, b) -> float:
    """Signed difference in percent of ``|b|``."""
    return 100.0 * (a - b) / abs(b)


def step_name(volts) -> str:
    """The name a step of ``volts`` is recorded under (``step_p6V`` for +6 V)."""
    return f"step_{volts:+g}V".replace("+", "p").replace("-", "m").replace(".", "_")


def run_of(evidence, name):
    """The recording ``name`` of ``evidence``; :class:`Missing` if it was not recorded."""
    run = evidence.runs.get(name)
    if run is None:
        raise Missing(
            f"the recording {name!r} is missing: run the recording cell of this task first."
        )
    return run
