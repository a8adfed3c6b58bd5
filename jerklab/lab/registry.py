"""Which check answers which question of which lab: one table, no registration on import.

:data:`CHECKS` maps ``(lab, check name)`` to its function ``check(answer, evidence, truth) ->
CheckResult`` (:mod:`jerklab.lab.checkbase`): labs 1-3 in :mod:`jerklab.lab.checks`, lab 4 in
:mod:`jerklab.lab.ringing`, lab 5 in :mod:`jerklab.lab.ownlaw`. :func:`run_check` is the one way
in — the session calls it in the student's kernel today; a grader can call it with the same
plain data and the truth it holds.
"""

from __future__ import annotations

from jerklab.lab import checks as c
from jerklab.lab import ownlaw as o
from jerklab.lab import ringing as r
from jerklab.lab.checkbase import CheckResult, UnknownCheckError

__all__ = [
    "LABS",
    "FLEXIBLE_LABS",
    "HOST_LOOP_LABS",
    "CHECKS",
    "MISTAKES",
    "checks_of",
    "check_function",
    "run_check",
    "mistakes_table",
]

#: lab number -> short name (also the worksheet file stem: notebooks/labs/labN_<name>.ipynb)
LABS = {1: "identify", 2: "poles", 3: "move", 4: "ringing", 5: "ownlaw"}
#: labs whose rig carries the flexible load: the student's motor with a hidden load mode
FLEXIBLE_LABS = (4,)
#: labs whose law runs in the student's kernel (host-in-the-loop): their rig runs in real time
HOST_LOOP_LABS = (5,)

#: (lab, check name) -> check function, in the order the worksheets ask
CHECKS = {
    (1, "pre_speed"): c.check_pre_speed,
    (1, "pre_tau63"): c.check_pre_tau63,
    (1, "tau"): c.check_tau,
    (1, "K"): c.check_K,
    (1, "f_c"): c.check_f_c,
    (1, "uncertainty"): c.check_uncertainty,
    (1, "fit_valid"): c.check_fit_valid,
    (1, "white"): c.check_white,
    (1, "prbs_fit"): c.check_prbs_fit,
    (1, "trust"): c.check_trust,
    (1, "pem_friction"): c.check_pem_friction,
    (2, "pre_z"): c.check_pre_z,
    (2, "pre_integral"): c.check_pre_integral,
    (2, "model"): c.check_model,
    (2, "design"): c.check_design,
    (2, "measured"): c.check_measured,
    (2, "gap"): c.check_gap,
    (3, "pre_shortest"): c.check_pre_shortest,
    (3, "durations"): c.check_durations,
    (3, "lost_time"): c.check_lost_time,
    (3, "model3"): c.check_model3,
    (3, "predicted"): c.check_predicted,
    (3, "measured3"): c.check_measured3,
    (3, "rig_vs_sim"): c.check_rig_vs_sim,
    (4, "pre_zv_delay"): r.check_pre_zv_delay,
    (4, "pre_zvd_length"): r.check_pre_zvd_length,
    (4, "mode"): r.check_mode,
    (4, "zv_delay"): r.check_zv_delay,
    (4, "residual_pct"): r.check_residual_pct,
    (4, "robust"): r.check_robust,
    (4, "choice"): r.check_choice,
    (5, "pre_ff"): o.check_pre_ff,
    (5, "pre_delay"): o.check_pre_delay,
    (5, "law"): o.check_law,
    (5, "match"): o.check_match,
    (5, "variant"): o.check_variant,
}


#: Every mistake a check names, by key (:class:`jerklab.lab.checkbase.Mistake`): labs 1-3's
#: :data:`jerklab.lab.checks.MISTAKES`, lab 4's :data:`jerklab.lab.ringing.MISTAKES4` and lab 5's
#: :data:`jerklab.lab.ownlaw.MISTAKES5`
MISTAKES = {**c.MISTAKES, **r.MISTAKES4, **o.MISTAKES5}


def mistakes_table() -> str:
    """docs/INSTRUCTOR.md's table of common mistakes, as Markdown: one row per
    :data:`MISTAKES` entry (lab, check, the mistake, what it looks like, the words the check
    says). tests/test_lab_hints.py checks that the document holds exactly this table and
    that each check says its words when given its mistake."""
    rows = [
        "| lab | check | mistake | in the answer or the data | the check says |",
        "|---|---|---|---|---|",
    ]
    for m in MISTAKES.values():
        cells = (str(m.lab), f"`{m.check}`", m.mistake, m.data, f"\"{m.hint} …\"")
        rows.append("| " + " | ".join(x.replace("|", "\\|") for x in cells) + " |")
    return "\n".join(rows) + "\n"


def checks_of(lab) -> list[str]:
    """The check names of ``lab``, in the worksheet's order."""
    if lab not in LABS:
        raise ValueError(f"lab must be one of {sorted(LABS)}, got {lab!r}")
    return [name for (n, name) in CHECKS if n == lab]


def check_function(lab, name):
    """The function of check ``name`` of ``lab``; :class:`UnknownCheckError` (a KeyError)
    naming the lab's checks."""
    try:
        return CHECKS[lab, name]
    except (KeyError, TypeError):  # TypeError: an unhashable name
        raise UnknownCheckError(
            f"name: lab {lab} has no check named {name!r} (its checks: {', '.join(checks_of(lab))})"
        ) from None


def run_check(lab, name, answer, evidence, truth) -> CheckResult:
    """Check ``answer`` to question ``name`` of ``lab`` on ``evidence`` (plain data,
    :class:`jerklab.lab.plain.Evidence`) against ``truth`` (the hidden motor's parameters, or
    None on a real rig). May raise :class:`jerklab.lab.checkbase.Missing` (a recording or an
    earlier answer is not there yet) or the error of an unreadable answer."""
    return check_function(lab, name)(answer, evidence, truth)
