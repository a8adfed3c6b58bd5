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
from typing import NamedTuple

__all__ = [
    "CheckResult",
    "UnknownCheckError",
    "Missing",
    "Mistake",
    "number",
    "rel",
    "pct",
    "side",
    "beyond",
    "run_of",
    "step_name",
]


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


class UnknownCheckError(KeyError, ValueError):
    """A check name the lab does not have: a KeyError (a lookup by name, as before) and a
    ValueError (a bad argument ``name``), so either ``except`` catches it."""

    def __str__(self):
        return str(self.args[0]) if self.args else ""


class Missing(Exception):
    """A check needs a recording or an earlier answer that is not there yet (the message says
    which); the session shows it as a failed check."""


class Mistake(NamedTuple):
    """A mistake a check recognises and names: the rows of docs/INSTRUCTOR.md's table.

    Attributes
    ----------
    lab : int
        The lab whose check names it.
    check : str
        The check's name (:data:`jerklab.lab.registry.CHECKS`).
    mistake : str
        What the student did.
    data : str
        What it looks like in the answer or the data.
    hint : str
        The words of the check's message that name it (the message contains them verbatim).
    """

    lab: int
    check: str
    mistake: str
    data: str
    hint: str


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
    """Signed difference in percent of ``|b|`` (for the checker's own use: a message never
    shows it, since with the answer it gives the true value back)."""
    return 100.0 * (a - b) / abs(b)


def side(a, b, high="too high", low="too low") -> str:
    """``high`` when ``a > b``, else ``low``: the only direction a failing message gives."""
    return high if a > b else low


def beyond(name, a, b, tolerance, high="too high", low="too low") -> str:
    """``"<name> is too high beyond the tolerance (<tolerance>)"`` (or too low): what a check
    says of a wrong number without anything that inverts to the true value."""
    return f"{name} is {side(a, b, high, low)} beyond the tolerance ({tolerance})"


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
