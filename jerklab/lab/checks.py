"""The checks of labs 1-3 (identify, place the poles, move smoothly), as pure functions.

Each check is ``check_<name>(answer, evidence, truth) -> CheckResult``
(:mod:`jerklab.lab.checkbase`; :mod:`jerklab.lab.registry` maps each lab's check names to them).
It compares the student's answer with the truth of *this* student's motor (``truth``: the
hidden motor of the virtual rig or of simavr, :func:`jerklab.lab.motors.hidden_truth`) or, on a
real Uno (``truth`` None), with the checker's own analysis of the student's recordings
(``evidence``, :class:`jerklab.lab.plain.Evidence`); tolerances follow what the measurement
allows (quantization, noise). A failing check names the most likely mistake; a passing one says
why the answer is right. No message ever prints a true parameter value. The physics is
Stojčić's (Stojcic 2015): the motor of Stojčić eq. 1, the load of Stojčić eq. 9, the PID of
Stojčić eq. 11.
"""

from __future__ import annotations

import math

import numpy as np

from jerklab import ident
from jerklab._validate import BadInput, as_finite_array, as_real
from jerklab.controller import (
    DiscreteGains,
    PositionLoop,
    discrete_pole_placement_pid,
    pole_placement_pid,
)
from jerklab.lab.checkbase import (
    CheckResult,
    Missing,
    Mistake,
    beyond,
    number,
    rel,
    run_of,
    side,
    step_name,
)
from jerklab.lab.motors import motor_from_truth, student_device
from jerklab.lab.specs import lab_spec
from jerklab.metrics import move_metrics
from jerklab.planner import plan_scurve, plan_sine_jerk, plan_sine_jerk_optimal, plan_trapezoid
from jerklab.plant import DCMotor
from jerklab.rig import RigError, connect
from jerklab.sim import simulate

__all__ = [
    "MOVE",
    "SPEC",
    "PANEL_START",
    "MISTAKES",
    "SWEEP_VOLTS",
    "STEP_SECONDS",
    "DESIGN_TS",
    "PRBS",
    "steady_speed",
    "sweep_fit",
    "spec_metrics",
    "spec_failures",
]

#: The labs' numbers on the paper's class motors (K 15-45 rad/(V s), tau 10-60 ms, 12 V); another
#: rig's: jerklab.lab.specs.lab_spec(lab, profile), the one place they are made.
_LAB1, _LAB2 = lab_spec(1), lab_spec(2)
#: The move of labs 2 and 3 (rad, rad/s^3, rad/s^2, rad/s): three revolutions and a bit.
MOVE = _LAB2["move"]

#: The spec of lab 2, feasible for every motor of jerklab.lab.motors.RANGES (tests/test_labs.py;
#: on every profile: tests/test_lab_profiles.py): max |r - y| during the move (rad), overshoot
#: after it (% of the distance), the settle band (rad) and the time to stay in it after the move
#: (s), the supply (V) with no saturated sample.
SPEC = _LAB2["spec"]

#: Lab 1's tolerances: K and τ relative, f_c in volts (what the measurement allows on every
#: motor of jerklab.lab.motors.RANGES, tests/test_labs.py)
TOL = {"K": 0.04, "tau": 0.08, "f_c": 0.06}

#: Lab 2's tuning panel starts here (``pole_placement_panel(K, tau, **PANEL_START)``): a first
#: guess that misses SPEC on at least 80 % of the class's motors (its 10 ms period lets friction
#: hold the motor outside the settling band), a slider away (Ts 5 ms, ωn 30 rad/s) from a design
#: that meets it on every motor. Another profile's: ``lab_spec(2, profile)["panel_start"]``, made
#: with its SPEC, misses it on at least 80 % of that profile's motors too
#: (tests/test_lab_profiles.py checks every profile).
PANEL_START = _LAB2["panel_start"]

#: Voltages of lab 1's sweep of steps (each from rest) and their length (s).
SWEEP_VOLTS = _LAB1["sweep_volts"]
STEP_SECONDS = _LAB1["step_seconds"]
#: Lab 1's PRBS record (``rig.record_prbs(**PRBS)``): 6 ± 2 V, so the motor never stops or turns
#: back (friction then acts as a constant input bias, which PEM's offset absorbs), a maximal-length
#: sequence of order 7 with each bit held 2 samples: 254 samples, 1.27 s at Ts = 5 ms.
PRBS = _LAB1["prbs"]
#: Control period of labs 2-3 (s)
DESIGN_TS = _LAB2["design_Ts"]

#: The mistakes the checks of labs 1-3 recognise, each with the words its check's message
#: gives (``hint``). docs/INSTRUCTOR.md's table of mistakes is generated from these
#: (:func:`jerklab.lab.registry.mistakes_table`), and tests/test_lab_hints.py makes each mistake
#: on a student's motor and finds its hint in the check's message. A message never holds a
#: percent error or another number that gives the true value back: it names the mistake, or
#: says "too high" / "too low" beyond the stated tolerance.
MISTAKES = {
    m_key: Mistake(*m_row)
    for m_key, m_row in {
        "pre_speed_rev": (
            1,
            "pre_speed",
            "speed in revolutions per second",
            "2π× too small",
            "that is in revolutions per second",
        ),
        "pre_speed_deg": (
            1,
            "pre_speed",
            "speed in degrees per second",
            "57.3× too large",
            "that is in degrees per second (× 57.3)",
        ),
        "pre_tau63_ms": (
            1,
            "pre_tau63",
            "τ in milliseconds",
            "1000× too large",
            "1000× too large: seconds, not milliseconds",
        ),
        "tau_ms": (
            1,
            "tau",
            "τ in milliseconds",
            "τ ≈ 20 instead of 0.02",
            "about 1000× too large: seconds, not milliseconds",
        ),
        "tau_arx": (
            1,
            "tau",
            "ARX τ reported",
            "τ short on noisy, coarse encoders",
            "that is the ARX estimate",
        ),
        "K_negative": (
            1,
            "K",
            "encoder or motor leads reversed",
            "K < 0: a positive voltage turns the angle down",
            "K is negative: the encoder is wired backwards (swap A and B) or the "
            "motor leads are reversed (swap OUT1 and OUT2)",
        ),
        "K_inverse": (
            1,
            "K",
            "voltage regressed on speed",
            "about 1/K, in V·s/rad",
            "that is 1/K: you regressed the voltage on the speed",
        ),
        "K_degrees": (
            1,
            "K",
            "K in degrees",
            "57.3× too large",
            "K is off by a factor 57.3: that is degrees, not radians",
        ),
        "K_rev": (
            1,
            "K",
            "K in revolutions",
            "2π× too small",
            "K is off by a factor 0.159: that is revolutions, not radians",
        ),
        "K_rpm": (
            1,
            "K",
            "K in rpm per volt",
            "9.55× too large",
            "K is off by a factor 9.55: that is rpm per volt",
        ),
        "K_2pi": (
            1,
            "K",
            "radians converted twice",
            "2π× too large",
            "K is off by a factor 6.28: did you convert revolutions twice?",
        ),
        "K_single_step": (
            1,
            "K",
            "K from the +6 V step alone (PEM, or ω/V)",
            "a few % low, by about (f_c − offset)/6 V; passes a 4 % band on a "
            "low-friction motor, so the check compares with the step's own gain",
            "that is the gain of the +6 V step alone",
        ),
        "f_c_negative": (
            1,
            "f_c",
            "friction with the wrong sign",
            "f_c < 0",
            "f_c is negative: friction opposes the motion",
        ),
        "f_c_rad": (
            1,
            "f_c",
            "friction left in rad/s",
            "f_c K× too large",
            "that is in rad/s: f_c is a voltage",
        ),
        "fit_valid_fraction": (
            1,
            "fit_valid",
            "fit as a fraction",
            "0.93 instead of 93",
            "fit is in percent (0–100), not a fraction",
        ),
        "prbs_no_offset": (
            1,
            "prbs_fit",
            "PRBS fitted by PEM without the offset",
            "K low by the friction's share of 6 V",
            "that is PEM without the offset",
        ),
        "prbs_degrees": (
            1,
            "prbs_fit",
            "K in degrees",
            "57.3× too large",
            "K is off by a factor 57.3: that is degrees, not radians",
        ),
        "model_ms": (
            2,
            "model",
            "τ in milliseconds",
            "τ ≈ 20 instead of 0.02",
            "τ in milliseconds: the design needs seconds",
        ),
        "design_unstable": (
            2,
            "design",
            "continuous design at a long Ts",
            "panel turns red",
            "your sampled loop has |z| =",
        ),
        "design_pd": (
            2,
            "design",
            "PD only",
            "error stays after a load step",
            "no integral action (kid = 0)",
        ),
        "design_slow": (
            2,
            "design",
            "slow loop",
            "large error at the start of the move (friction)",
            "a stiffer loop (larger ωn) rejects the friction sooner",
        ),
        "durations_ms": (
            3,
            "durations",
            "durations in milliseconds",
            "1000× too large",
            "milliseconds — give seconds",
        ),
        "lost_time_sign": (
            3,
            "lost_time",
            "optimal minus published",
            "negative",
            "the sign: published minus optimal",
        ),
        "rig_vs_sim_inverted": (
            3,
            "rig_vs_sim",
            "predicted / measured",
            "the inverse",
            "inverted: measured divided by predicted",
        ),
    }.items()
}


def _hint(key):
    return MISTAKES[key].hint


def _needs(name, earlier, what):
    """The message of a check that builds on an earlier answer which has not passed."""
    return (
        f"{name} needs {what}: check `{earlier}` first — its answer is used here only once "
        "its check says ✔ right."
    )


def _pct_text(fraction):
    return f"{100 * fraction:g} %"


# ------------------------------------------------------------------ analysis helpers (the checker's own)
def steady_speed(rec, window=0.1):
    """Steady speed (rad/s) of a step record: slope of the angle over its last ``window`` s."""
    t, y = np.asarray(rec.time), np.asarray(rec.position)
    sel = t >= t[-1] - window
    return float(np.polyfit(t[sel], y[sel], 1)[0])


def sweep_fit(speeds):
    """Least squares ω = K·V + K·offset − K·f_c·sign(V) over a sweep {V: ω}; returns
    (K, f_c, offset) and their standard errors."""
    if not isinstance(speeds, dict):
        raise BadInput(f"speeds must be a dict {{voltage: speed}}, got {speeds!r:.60}")
    V = as_finite_array("speeds (voltages)", [as_real("speeds voltage", v) for v in speeds])
    w = as_finite_array("speeds (speeds)", [as_real(f"speeds[{v!r}]", speeds[v]) for v in speeds])
    order = np.argsort(V)
    V, w = V[order], w[order]
    if len(V) < 4 or not (np.any(V > 0) and np.any(V < 0)):
        raise ValueError(
            f"speeds must hold at least 4 voltages on both sides of 0 (K, f_c and the offset "
            f"are separable only then), got {sorted(V.tolist())}"
        )
    A = np.column_stack([V, np.ones_like(V), -np.sign(V)])
    coef, res, *_ = np.linalg.lstsq(A, w, rcond=None)
    dof = max(1, len(V) - 3)
    s2 = float(np.sum((w - A @ coef) ** 2)) / dof
    cov = s2 * np.linalg.inv(A.T @ A)
    K, a, b = coef
    J = np.array(
        [[1, 0, 0], [-b / K**2, 0, 1 / K], [-a / K**2, 1 / K, 0]]
    )  # d(K, fc, off)/d(K, a, b)
    cv = J @ cov @ J.T
    std = np.sqrt(np.clip(np.diag(cv), 0, None))
    return (float(K), float(b / K), float(a / K)), tuple(float(s) for s in std)


def spec_metrics(run, profile, settle_band=None):
    """:func:`jerklab.metrics.move_metrics` of a move recording with the spec's settle band
    (``settle_band`` in rad, default ``SPEC["settle_band"]``; another rig's:
    ``jerklab.lab.specs.lab_spec(2, profile)["spec"]["settle_band"]``): max |e| during the move,
    overshoot (% of the distance) after it, settling time after the end, peak |u|, saturated
    samples."""
    band = SPEC["settle_band"] if settle_band is None else settle_band
    return move_metrics(run, profile.duration, profile.distance, settle_band=band)


# ------------------------------------------------------------------ lab 1: identify your motor
def check_pre_speed(answer, evidence, truth):
    v = number("pre_speed", answer)
    ref = 30.0 * 6.0
    if rel(v, ref) < 0.01:
        return CheckResult(
            "pre_speed",
            True,
            "ω_ss = K·V = 30 × 6 = 180 rad/s: at steady state "
            "τ·ω' = 0, so the velocity part K/(τs+1) of Stojčić eq. 1 gives K·V; τ only sets how fast.",
        )
    if rel(v, ref / (2 * math.pi)) < 0.02:
        return CheckResult("pre_speed", False, f"{_hint('pre_speed_rev')}: K is in rad/(V·s).")
    if rel(v, ref * 180 / math.pi) < 0.02:
        return CheckResult("pre_speed", False, f"{_hint('pre_speed_deg')}: answer in rad/s.")
    if rel(v, ref * 60 / (2 * math.pi)) < 0.02:
        return CheckResult("pre_speed", False, "that is in rpm: answer in rad/s.")
    if rel(v, 30 * 6 * 0.040) < 0.02 or rel(v, 6 / 0.040) < 0.02:
        return CheckResult(
            "pre_speed", False, "τ does not enter the steady speed: set ω' = 0 in τω' + ω = K·V."
        )
    return CheckResult(
        "pre_speed",
        False,
        f"{side(v, ref)}: at steady state τω' = 0 in τω' + ω = K·V.",
    )


def check_pre_tau63(answer, evidence, truth):
    v = number("pre_tau63", answer)
    if rel(v, 0.040) < 0.01:
        return CheckResult(
            "pre_tau63", True, "ω(t) = K·V(1 − e^(−t/τ)) reaches 1 − 1/e ≈ 63 % at t = τ = 0.040 s."
        )
    if rel(v, 40.0) < 0.01:
        return CheckResult("pre_tau63", False, f"{_hint('pre_tau63_ms')}.")
    if rel(v, 0.040 * math.log(2)) < 0.02 or rel(v, 0.040 * 3) < 0.02:
        return CheckResult(
            "pre_tau63", False, "that is the time to 50 % or 95 %: 63 % is exactly one τ."
        )
    return CheckResult("pre_tau63", False, f"{side(v, 0.040)}: solve 1 − e^(−t/τ) = 0.63 for t.")


def _sweep_volts(evidence):
    """Lab 1's sweep on the evidence's motor profile (``lab_spec``; paper: :data:`SWEEP_VOLTS`)."""
    name = getattr(evidence, "profile", None)
    return SWEEP_VOLTS if name is None else lab_spec(1, name)["sweep_volts"]


def _lab1_reference(evidence, truth):
    """(K, tau, f_c, offset) of the motor: the truth on a simulated plant, else the checker's fit."""
    if truth is not None:
        return truth["K"], truth["tau"], truth["coulomb_friction"], truth["offset"], "your motor"
    speeds = {v: steady_speed(run_of(evidence, step_name(v))) for v in _sweep_volts(evidence)}
    (K, fc, off), _ = sweep_fit(speeds)
    r = run_of(evidence, step_name(6.0))
    tau = ident.fit_dc_motor(r.voltage, r.position, r.Ts, "pem").tau
    return K, tau, fc, off, "the checker's analysis of your recordings (real rig)"


def check_tau(answer, evidence, truth):
    v = number("tau", answer)
    K, tau, fc, off, src = _lab1_reference(evidence, truth)
    tol = _pct_text(TOL["tau"])
    if v <= 0:
        return CheckResult(
            "tau", False, "τ must be positive: a time constant of the velocity's exponential."
        )
    if rel(v, tau * 1000) < 0.15:
        return CheckResult("tau", False, f"τ is {_hint('tau_ms')}.")
    if rel(v, tau) <= TOL["tau"]:
        return CheckResult(
            "tau",
            True,
            f"within the tolerance ({tol}) of {src}. From rest the "
            "motor sees a constant net voltage (V + offset − f_c), so friction changes the "
            "gain of a step but not its time constant, and PEM, which fits the simulated "
            "angle, is not biased by the encoder's quantization.",
        )
    try:
        r = run_of(evidence, step_name(6.0))
        t_arx = ident.fit_dc_motor(r.voltage, r.position, r.Ts, "arx").tau
    except (Missing, ValueError):
        t_arx = None
    if t_arx is not None and rel(v, t_arx) < 0.02:
        return CheckResult(
            "tau",
            False,
            f"{beyond('τ', v, tau, tol)} — {_hint('tau_arx')}: ARX "
            "regresses the differenced angle, whose quantization noise sits in the regressor "
            "and biases τ short. Report PEM's τ.",
        )
    return CheckResult(
        "tau",
        False,
        f"{beyond('τ', v, tau, tol)}: did you fit the angle (PEM) of the "
        "+6 V step from rest, with u = rec.voltage and y = rec.position?",
    )


def _single_step_gains(evidence):
    """The gains a student gets from the +6 V step alone: PEM's K and the steady speed / 6 V
    (empty without that recording), and the checker's sweep K from the recordings (or None)."""
    try:
        r = run_of(evidence, step_name(6.0))
    except Missing:
        return [], None
    gains = [steady_speed(r) / 6.0]
    try:
        gains.append(ident.fit_dc_motor(r.voltage, r.position, r.Ts, "pem").K)
    except ValueError:
        pass
    try:
        speeds = {v: steady_speed(run_of(evidence, step_name(v))) for v in _sweep_volts(evidence)}
        k_sweep = sweep_fit(speeds)[0][0]
    except Missing:
        k_sweep = None
    return gains, k_sweep


def check_K(answer, evidence, truth):
    v = number("K", answer)
    K, tau, fc, off, src = _lab1_reference(evidence, truth)
    tol = _pct_text(TOL["K"])
    if v < 0:
        return CheckResult(
            "K",
            False,
            f"{_hint('K_negative')}: with a positive voltage your angle runs down.",
        )
    if v > 0 and rel(v, 1 / K) < 0.06:
        return CheckResult(
            "K", False, f"{_hint('K_inverse')}: regress the speed ω on the voltage V."
        )
    # the single step's gain: friction takes (f_c - offset)/V of it, which on a low-friction
    # motor is inside the tolerance, so it is recognised by being that step's own number
    steps, k_sweep = _single_step_gains(evidence)
    k_ref = K if k_sweep is None else k_sweep
    for k_step in steps:
        if rel(v, k_step) < 1e-3 and rel(k_step, k_ref) > 5e-3 and abs(v - k_step) < abs(v - k_ref):
            return CheckResult(
                "K",
                False,
                f"{_hint('K_single_step')}: friction lowers a single step's gain by about "
                "f_c/V. Take the slope of the sweep's steady speeds.",
            )
    if rel(v, K) <= TOL["K"]:
        return CheckResult(
            "K",
            True,
            f"within the tolerance ({tol}) of {src}. The slope of the "
            "steady speed against the voltage is K whatever the friction: f_c and the offset "
            "only shift the lines, so the sweep separates them.",
        )
    for factor, key in (
        (180 / math.pi, "K_degrees"),
        (2 * math.pi, "K_2pi"),
        (1 / (2 * math.pi), "K_rev"),
        (60 / (2 * math.pi), "K_rpm"),
    ):
        if rel(v, K * factor) < 0.06:
            return CheckResult("K", False, f"{_hint(key)} — K is in rad/(V·s).")
    k_eff = K * (1 - (fc - off) / 6.0)
    if rel(v, k_eff) < 0.03 and rel(k_eff, K) > 0.02:
        return CheckResult(
            "K",
            False,
            f"{beyond('K', v, K, tol)} — {_hint('K_single_step')}: friction lowers a "
            "single step's gain by about f_c/V. Take the slope of the sweep's steady speeds.",
        )
    return CheckResult(
        "K",
        False,
        f"{beyond('K', v, K, tol)}: did you take the slope of steady speed "
        "(rad/s) against voltage (V) — the speed at the end of each step, not the angle?",
    )


def check_f_c(answer, evidence, truth):
    v = number("f_c", answer)
    K, tau, fc, off, src = _lab1_reference(evidence, truth)
    tol = TOL["f_c"]
    if abs(v - fc) <= tol:
        return CheckResult(
            "f_c",
            True,
            f"within the tolerance ({tol:g} V) of {src}. The two branches of the "
            "sweep cross zero speed at +f_c − offset and −f_c − offset: half their distance is "
            "the friction, their midpoint the offset.",
        )
    if v < 0:
        return CheckResult(
            "f_c",
            False,
            f"{_hint('f_c_negative')} — check the sign of the sign(V) column in your regression.",
        )
    if min(abs(v - (fc - off)), abs(v - (fc + off))) <= tol / 2 and abs(off) > tol / 2:
        return CheckResult(
            "f_c",
            False,
            "that is where one branch crosses zero speed: the offset shifts both "
            "branches the same way — average the + and − branch.",
        )
    if abs(v / K - fc) <= tol:
        return CheckResult("f_c", False, f"{_hint('f_c_rad')} — divide the speed intercept by K.")
    return CheckResult(
        "f_c",
        False,
        f"{beyond('f_c', v, fc, f'{tol:g} V')}: fit ω = K·V + K·offset − K·f_c·sign(V) "
        "over all six steps.",
    )


def check_uncertainty(answer, evidence, truth):
    ks, ts, fs = (number(f"uncertainty[{i}]", a) for i, a in enumerate(answer))
    K, tau, fc, off, src = _lab1_reference(evidence, truth)
    bad = [n for n, x in (("K_std", ks), ("tau_std", ts), ("f_c_std", fs)) if not x > 0]
    if bad:
        return CheckResult(
            "uncertainty", False, f"{', '.join(bad)} must be a positive standard error."
        )
    if ks > 0.2 * K or ts > 0.2 * tau or fs > 0.3:
        return CheckResult(
            "uncertainty",
            False,
            "an uncertainty larger than 20 % of the value: did you give "
            "a variance instead of a standard deviation, or use ms/rad-per-rev units?",
        )
    if ks < 1e-6 * K or ts < 1e-6 * tau:
        return CheckResult(
            "uncertainty",
            False,
            "the uncertainty is ~0: a fit of noisy, quantized data "
            "cannot be exact — take the square root of the covariance's diagonal.",
        )
    return CheckResult(
        "uncertainty",
        True,
        "positive and small against the values: one standard error from the covariance of "
        "each fit (s²(AᵀA)⁻¹ for the sweep; for PEM a sandwich that allows for the encoder's "
        "slowly changing error). They say how far a new record of the same motor would move "
        "the estimate, not how wrong a model is: the +6 V step's K is off by friction, not noise.",
    )


def _validation(evidence):
    r6, r3 = run_of(evidence, step_name(6.0)), run_of(evidence, step_name(3.0))
    Ts = r6.Ts
    fit = ident.fit_dc_motor(r6.voltage, r6.position, Ts, "pem")
    return ident.validate(fit, r3.voltage, r3.position, Ts)


def check_fit_valid(answer, evidence, truth):
    v = number("fit_valid", answer)
    val = _validation(evidence)
    if abs(v - val.fit_percent) <= 1.5:
        return CheckResult(
            "fit_valid",
            True,
            "agrees with the checker's within 1.5 points. Where the 6 V "
            "model misses the 3 V record, it is mostly because friction takes a bigger share of "
            "3 V than of 6 V — a gain error that a single step cannot see.",
        )
    if 0 < v <= 1 and abs(100 * v - val.fit_percent) <= 1.5:
        return CheckResult("fit_valid", False, f"{_hint('fit_valid_fraction')}.")
    return CheckResult(
        "fit_valid",
        False,
        f"{beyond('the fit', v, val.fit_percent, '1.5 points')}: simulate the PEM "
        "model of the +6 V step on the +3 V record (ident.validate), not on its own data.",
    )


def check_white(answer, evidence, truth):
    if not isinstance(answer, (bool, np.bool_)):
        raise Missing("white: answer True or False.")
    val = _validation(evidence)
    if bool(answer) == bool(val.analysis.white):
        why = (
            "the residuals are white: the model has explained all the structure"
            if val.analysis.white
            else "the residuals are not white: a slow drift remains that the linear model cannot "
            "explain (the friction's share differs between 3 V and 6 V)"
        )
        return CheckResult("white", True, f"{why}.")
    return CheckResult(
        "white",
        False,
        "read `analysis.white` of the validation (Ljung-Box test over 25 lags), "
        "not the autocorrelation at lag 0 (always 1).",
    )


def check_prbs_fit(answer, evidence, truth):
    K_a, tau_a = (number(f"prbs_fit[{i}]", a) for i, a in enumerate(answer))
    r = run_of(evidence, "prbs")
    u, y, Ts = r.voltage, r.position, r.Ts
    if truth is not None:
        K, tau, src = truth["K"], truth["tau"], "your motor"
    else:
        f = ident.fit_dc_motor(u, y, Ts, "pem", offset=True)
        K, tau, src = (
            f.K,
            f.tau,
            "the checker's PEM fit (with offset) of your PRBS record (real rig)",
        )
    tk, tt = _pct_text(TOL["K"]), _pct_text(TOL["tau"])
    # the two biased fits of this very record, recognised by being its own numbers (on a
    # low-friction motor they may fall inside the tolerance), then by the tolerance
    try:
        ref_fit = ident.fit_dc_motor(u, y, Ts, "pem", offset=True)
    except ValueError:
        ref_fit = None
    for method, hint in (
        (
            "pem",
            f"{_hint('prbs_no_offset')}: the PRBS runs at 6 ± 2 V, so friction takes a "
            "constant share of the input and shows up as a lower gain. Fit with offset=True.",
        ),
        (
            "arx",
            "that is the ARX estimate: its regressor holds the differenced, quantized angle "
            "(errors in the variables), and it has no offset term for the friction. Report PEM "
            "with offset=True.",
        ),
    ):
        try:
            f = ident.fit_dc_motor(u, y, Ts, method)
        except ValueError:
            continue
        own = rel(K_a, f.K) < 1e-3 and rel(tau_a, f.tau) < 1e-3
        distinct = ref_fit is not None and (
            rel(f.K, ref_fit.K) > 5e-3 or rel(f.tau, ref_fit.tau) > 5e-3
        )
        near = rel(K_a, f.K) < 0.01 and rel(tau_a, f.tau) < 0.03
        off = rel(f.K, K) > 0.02 or rel(f.tau, tau) > 0.04
        if (own and distinct) or (near and off):
            return CheckResult("prbs_fit", False, hint)
    if rel(K_a, K) <= TOL["K"] and rel(tau_a, tau) <= TOL["tau"]:
        return CheckResult(
            "prbs_fit",
            True,
            f"K and τ within the tolerances ({tk}, {tt}) of {src}. The PRBS keeps the motor "
            "turning one way, so friction acts as a constant input bias: PEM's offset absorbs "
            "it (offset − f_c), and K comes out unbiased from one record, where a single step "
            "could not tell K from friction.",
        )
    if rel(tau_a, tau * 1000) < 0.15:
        return CheckResult("prbs_fit", False, f"τ is {_hint('tau_ms')}.")
    for factor, hint in (
        (180 / math.pi, f"{_hint('prbs_degrees')} — K is in rad/(V·s)."),
        (2 * math.pi, "K is 2π too large: radians were converted twice?"),
        (1 / (2 * math.pi), "K is in revolutions: K is in rad/(V·s)."),
    ):
        if rel(K_a, K * factor) < 0.06:
            return CheckResult("prbs_fit", False, hint)
    parts = []
    if rel(K_a, K) > TOL["K"]:
        parts.append(beyond("K", K_a, K, tk))
    if rel(tau_a, tau) > TOL["tau"]:
        parts.append(beyond("τ", tau_a, tau, tt))
    return CheckResult(
        "prbs_fit",
        False,
        f"{' and '.join(parts)}: fit the PRBS record with u = rp.voltage (the applied volts) "
        "and y = rp.position, by PEM with offset=True.",
    )


def check_trust(answer, evidence, truth):
    a = str(answer).strip().lower()
    if a not in ("pem", "arx"):
        raise Missing('trust: answer "pem" or "arx".')
    if a == "pem":
        return CheckResult(
            "trust",
            True,
            "PEM minimizes the error of the simulated angle, so white "
            "measurement noise and quantization do not bias it; ARX puts the differenced, "
            "noisy angle into its regressor and comes out with τ too short.",
        )
    return CheckResult(
        "trust",
        False,
        "compare the two τ with the validation: ARX's regressor holds the "
        "differenced, quantized angle (errors in the variables) — which estimate is biased?",
    )


# ------------------------------------------------------------------ lab 2: place the poles
def check_pre_z(answer, evidence, truth):
    v = number("pre_z", answer)
    ref = math.exp(-140 * 0.005)
    if abs(v - ref) < 2e-3:
        return CheckResult(
            "pre_z",
            True,
            f"z = e^(sTs) = e^(−0.7) = {ref:.4f}: the exact map of the ZOH "
            "plant's poles, which the z-domain design uses.",
        )
    if abs(v - (1 - 0.7)) < 2e-3:
        return CheckResult(
            "pre_z",
            False,
            "1 − σTs is the forward-Euler approximation of e^(−σTs); at σTs = 0.7 it is far off.",
        )
    if abs(v - 1 / (1 + 0.7)) < 2e-3:
        return CheckResult(
            "pre_z", False, "1/(1 + σTs) is backward Euler; the sampled pole is exactly e^(−σTs)."
        )
    return CheckResult("pre_z", False, "use z = e^(sTs) with s = −σ = −140 /s and Ts = 0.005 s.")


def check_pre_integral(answer, evidence, truth):
    if not isinstance(answer, (bool, np.bool_)):
        raise Missing("pre_integral: answer True or False.")
    if answer is False or answer == False:  # noqa: E712
        return CheckResult(
            "pre_integral",
            True,
            "the load enters at the voltage, before the plant's "
            "integrator; at steady state a PD needs e·kp = −w to cancel it, so an error "
            "remains: only the controller's own integrator drives it to zero (Stojčić eq. 9).",
        )
    return CheckResult(
        "pre_integral",
        False,
        "the plant's integrator is after the disturbance (W = P, Stojčić eq. 9): "
        "write the steady state of K(u + w) = 0 with u = kp·e.",
    )


def check_model(answer, evidence, truth):
    K_hat, tau_hat = (number(f"model[{i}]", a) for i, a in enumerate(answer))
    if truth is None:
        return CheckResult(
            "model", True, "noted (real rig: your lab 1 values are the best model there is)."
        )
    eK, et = rel(K_hat, truth["K"]), rel(tau_hat, truth["tau"])
    if eK <= 0.08 and et <= 0.12:
        return CheckResult(
            "model",
            True,
            "your lab 1 values describe this motor: the design and the "
            "feedforward are built on them.",
        )
    if rel(tau_hat, truth["tau"] * 1000) < 0.2:
        return CheckResult("model", False, f"{_hint('model_ms')}.")
    parts = []
    if eK > 0.08:
        parts.append(beyond("K", K_hat, truth["K"], "8 %"))
    if et > 0.12:
        parts.append(beyond("τ", tau_hat, truth["tau"], "12 %"))
    return CheckResult(
        "model",
        False,
        f"{' and '.join(parts)} for this motor: use the K and τ you identified in lab 1 "
        "on this rig, in rad/(V·s) and seconds.",
    )


def _gains_of(answer):
    if answer is Ellipsis or answer is None:
        raise Missing("gains: no answer yet — take them from the panel (lab.panel_gains(panel)).")
    if not isinstance(answer, DiscreteGains):
        raise Missing(
            f"gains must be DiscreteGains (from the panel or discrete_pole_placement_pid, or "
            f"Gains.discretize(Ts)), got {type(answer).__name__}"
        )
    return answer


def _lab2(evidence):
    """Lab 2's move and spec on the evidence's motor profile (``lab_spec``; paper: MOVE, SPEC)."""
    name = getattr(evidence, "profile", None)
    return _LAB2 if name is None else lab_spec(2, name)


def _spec_move_on(truth, gains, model, move=None, settle_band=None, stop_error=None):
    """The spec move on the student's hidden motor rebuilt from ``truth`` (the same motor and
    encoder noise as their virtual rig), the feedforward from their ``model``, in memory, the
    rig's tracking-error stop at ``stop_error`` (rad; None: the device's default); its
    :func:`spec_metrics` with ``settle_band``."""
    stops = {} if stop_error is None else {"max_error": stop_error}
    prof = plan_sine_jerk(**(MOVE if move is None else move))
    rig = connect(device=student_device(motor_from_truth(truth)), progress=False, live=False)
    try:
        rig.set_model(*model)
        rec = rig.run_move(prof, gains, gains.Ts, settle=0.4, path=False, **stops)
    finally:
        rig.close()
    return spec_metrics(rec, prof, settle_band)


def spec_failures(m, spec=None):
    """What a move's :func:`spec_metrics` miss of ``spec`` (default :data:`SPEC`; another rig's:
    ``jerklab.lab.specs.lab_spec(2, profile)["spec"]``), each with its hint (empty: met)."""
    SPEC = _LAB2["spec"] if spec is None else spec
    out = []
    if m["saturated"] or m["peak_voltage"] > SPEC["max_voltage"] + 1e-9:
        out.append(
            f"the voltage hits the {SPEC['max_voltage']:g} V supply ({m['saturated']} saturated samples): "
            "lower ωn or σ/ωn — the derivative gain grows with σ"
        )
    if m["max_error"] > SPEC["max_error"]:
        out.append(
            f"the tracking error reaches {m['max_error']:.2f} rad > {SPEC['max_error']} rad: "
            + _hint("design_slow")
        )
    if m["overshoot_pct"] > SPEC["overshoot_pct"]:
        out.append(
            f"it overshoots the target by {m['overshoot_pct']:.2f} % > {SPEC['overshoot_pct']} %: "
            "raise ζ towards 1"
        )
    if m["settling_time"] > SPEC["settling_time"]:
        st = "never" if math.isinf(m["settling_time"]) else f"after {m['settling_time']:.2f} s"
        out.append(
            f"it settles into ±{SPEC['settle_band']} rad {st} (spec {SPEC['settling_time']} s): raise ωn"
        )
    return out


def check_design(answer, evidence, truth):
    g = _gains_of(answer)
    model = evidence.answers.get("model")
    if model is None:
        raise Missing(_needs("design", "model", "your model (K, τ), task 1"))
    if g.kid <= 0:
        return CheckResult(
            "design",
            False,
            f"{_hint('design_pd')}: a load step then leaves a "
            "steady-state error — the spec asks for zero.",
        )
    K, tau = (truth["K"], truth["tau"]) if truth else model
    r = PositionLoop(K, tau, g).max_pole_radius()
    sigma = (g.design or {}).get("sigma")
    if r >= 1.0:
        extra = (
            f"; σ·Ts = {sigma * g.Ts:.2f}: the discretized PID no longer has the poles you placed"
            if sigma and sigma * g.Ts > 1
            else ""
        )
        return CheckResult(
            "design",
            False,
            f"{_hint('design_unstable')} {r:.2f} ≥ 1 on this motor: unstable{extra}. "
            "Use the z-domain design or a shorter Ts.",
        )
    if truth is None:
        return CheckResult(
            "design",
            True,
            f"stable on your model (largest |z| = {r:.3f}) with integral "
            "action; the rig run below tells whether it meets the spec.",
        )
    lab2 = _lab2(evidence)
    try:
        m = _spec_move_on(
            truth, g, model, lab2["move"], lab2["spec"]["settle_band"], lab2.get("stop_error")
        )
    except RigError as exc:  # the rig's safety stops ended the spec move
        why = str(exc).split("(", 1)[-1].split(")", 1)[0] if "(" in str(exc) else str(exc)
        hint = (
            _hint("design_slow")
            if "tracking error" in why
            else "lower ωn or σ/ωn, or shorten Ts, until the sampled poles sit well inside |z| = 1"
        )
        return CheckResult(
            "design", False, f"on your motor the rig stopped the spec move ({why}): {hint}."
        )
    fails = spec_failures(m, lab2["spec"])
    if fails:
        return CheckResult("design", False, "on your motor " + "; ".join(fails) + ".")
    return CheckResult(
        "design",
        True,
        f"on your motor it meets every item (max error {m['max_error']:.3f} rad, "
        f"overshoot {m['overshoot_pct']:.2f} %, settled {m['settling_time']:.3f} s after the move, "
        f"peak {m['peak_voltage']:.1f} V), its sampled poles are inside |z| = {r:.3f}, and the "
        "integrator removes a load step's steady-state error.",
    )


def check_measured(answer, evidence, truth):
    rec = run_of(evidence, "move_sine_jerk")
    lab2 = _lab2(evidence)
    SPEC = lab2["spec"]
    prof = plan_sine_jerk(**lab2["move"])
    m = spec_metrics(rec, prof, SPEC["settle_band"])
    keys = ("max_error", "overshoot_pct", "settling_time", "peak_voltage")
    if not isinstance(answer, dict) or set(keys) - set(answer):
        raise Missing(f"measured: a dict with keys {keys}.")
    for k in keys:
        v = number(k, answer[k])
        ref = m[k]
        tol = {
            "max_error": 0.01 * ref + 1e-3,
            "overshoot_pct": 0.05,
            "settling_time": 0.011,
            "peak_voltage": 0.02 * ref + 0.02,
        }[k]
        if not (abs(v - ref) <= tol or (math.isinf(ref) and math.isinf(v))):
            hint = {
                "max_error": "the largest |reference − position| while the move lasts (t ≤ duration)",
                "overshoot_pct": "max(position − distance) after the move, in % of the distance, 0 if none",
                "settling_time": (
                    f"the last time |e| leaves ±{SPEC['settle_band']} rad, minus the move's duration"
                ),
                "peak_voltage": "max |rec.voltage| (the PWM-quantized voltage applied)",
            }[k]
            return CheckResult("measured", False, f"{k} disagrees with the recording: {hint}.")
    fails = spec_failures(m, SPEC)
    if fails:
        return CheckResult(
            "measured",
            False,
            "measured right, but the rig misses the spec: " + "; ".join(fails) + ".",
        )
    return CheckResult(
        "measured", True, "read right from the recording, and the rig meets the spec."
    )


def check_gap(answer, evidence, truth):
    model = evidence.answers.get("model")
    if model is None:
        raise Missing(_needs("gap", "model", "your model (K, τ), task 1"))
    K, tau = model
    rc, rz = (number(f"gap[{i}]", a) for i, a in enumerate(answer))
    # the question's numbers on the evidence's profile (paper: ωn 30 rad/s, σ 210 rad/s, 20 ms)
    G = _lab2(evidence)["gap"]
    Ts, wn, zeta, sigma = G["Ts"], G["wn"], G["zeta"], G["sigma"]
    ref_c = PositionLoop(
        K, tau, pole_placement_pid(K, tau, wn, zeta, sigma=sigma).discretize(Ts)
    ).max_pole_radius()
    ref_z = PositionLoop(
        K,
        tau,
        discrete_pole_placement_pid(K, tau, wn, zeta, sigma=sigma, Ts=Ts, extra_pole=0.0),
    ).max_pole_radius()
    if abs(rc - ref_c) <= 0.01 and abs(rz - ref_z) <= 0.01:
        return CheckResult(
            "gap",
            True,
            f"|z| = {ref_c:.2f} for Stojčić eq. 11 discretized by Stojčić eq. 13 against "
            f"{ref_z:.2f} for the z-domain design: at σ·Ts = {sigma * Ts:.1f} the "
            "approximation behind Stojčić eq. 13 breaks down and the loop leaves the unit circle, while the "
            "z-domain design solves for the poles on the exact ZOH plant: they sit at e^(sTs) "
            "(the dominant pair at e^(−ζωnTs)) and the fourth at z = 0.",
        )
    if abs(rc - ref_z) <= 0.01 and abs(rz - ref_c) <= 0.01:
        return CheckResult(
            "gap",
            False,
            "the two are swapped: the first is the continuous design "
            "(Stojčić eq. 11, discretized by Stojčić eq. 13).",
        )
    which = "the continuous design's" if abs(rc - ref_c) > 0.01 else "the z-domain design's"
    return CheckResult(
        "gap",
        False,
        f"{which} radius is off: use PositionLoop(K, τ, gains).max_pole_radius() "
        f"with YOUR K and τ, ωn = {wn:g} rad/s, ζ = {zeta:g}, σ = {sigma:g} rad/s, "
        f"Ts = {1e3 * Ts:g} ms (S.spec['gap']), extra_pole=0.0 for the z design.",
    )


# ------------------------------------------------------------------ lab 3: move smoothly
KINDS = ("trapezoid", "scurve", "sine_jerk")


def _plans(evidence=None):
    """Lab 3's three moves (and the optimal sine-jerk) with the lab's limits on the evidence's
    motor profile (:func:`_lab2`; paper: :data:`MOVE`)."""
    name = getattr(evidence, "profile", None)
    M = MOVE if name is None else lab_spec(3, name)["move"]
    return {
        "trapezoid": plan_trapezoid(M["distance"], M["max_accel"], M["max_velocity"]),
        "scurve": plan_scurve(**M),
        "sine_jerk": plan_sine_jerk(**M),
        "sine_jerk_optimal": plan_sine_jerk_optimal(**M),
    }


def check_pre_shortest(answer, evidence, truth):
    a = str(answer).strip().lower().replace("-", "_")
    if a not in KINDS:
        raise Missing(f"pre_shortest: one of {KINDS}.")
    if a == "trapezoid":
        return CheckResult(
            "pre_shortest",
            True,
            "with the same acceleration and velocity limits the "
            "trapezoid reaches them at once (infinite jerk); a jerk limit costs ramp time.",
        )
    return CheckResult(
        "pre_shortest", False, "which profile reaches its acceleration limit instantly?"
    )


def check_durations(answer, evidence, truth):
    p = _plans(evidence)
    if not isinstance(answer, dict):
        raise Missing(f"durations: a dict {{kind: seconds}} for {KINDS}.")
    for k in KINDS:
        v = number(f"durations[{k!r}]", answer.get(k))
        if rel(v, p[k].duration) > 1e-4:
            if rel(v, p[k].duration * 1000) < 1e-3:
                return CheckResult("durations", False, f"{k}: {_hint('durations_ms')}.")
            return CheckResult(
                "durations",
                False,
                f"{k}: {side(v, p[k].duration, 'too long', 'too short')}: plan it with "
                "the move's limits (S.spec['move']) and read profile.duration.",
            )
    return CheckResult(
        "durations",
        True,
        "trapezoid < S-curve < published sine-jerk: each smoother jerk "
        "costs time, and the published planner's phases cost more than they need to.",
    )


def check_lost_time(answer, evidence, truth):
    v = number("lost_time", answer)
    p = _plans(evidence)
    ref = p["sine_jerk"].duration - p["sine_jerk_optimal"].duration
    if abs(v - ref) <= 1e-4 + 1e-3 * abs(ref):
        return CheckResult(
            "lost_time",
            True,
            f"{ref * 1e3:.0f} ms: the published planner (Stojčić eq. 2) "
            "holds the jerk pulse for the whole acceleration phase instead of reaching the "
            "acceleration limit and holding it, so it loses time at the same limits.",
        )
    if abs(v + ref) <= 1e-4 + 1e-3 * abs(ref):
        return CheckResult("lost_time", False, f"{_hint('lost_time_sign')}.")
    return CheckResult(
        "lost_time",
        False,
        "plan_sine_jerk(...).duration − plan_sine_jerk_optimal(...).duration with the same limits.",
    )


def _prediction(evidence, model):
    """Lab 3's predicted max error and peak voltage of each move: the z-domain design at the
    lab's ωn (``design_wn`` on the evidence's motor profile; 30 rad/s on the paper's class),
    ζ = 1, on the student's model."""
    K, tau, fc = model
    name = getattr(evidence, "profile", None)
    s3 = _LAB2 if name is None else lab_spec(3, name)
    g = discrete_pole_placement_pid(K, tau, s3["design_wn"], 1.0, Ts=s3["design_Ts"])
    motor = DCMotor(K=K, tau=tau, coulomb_friction=fc, encoder_ppr=evidence.counts_per_rev)
    out = {}
    for k, p in _plans(evidence).items():
        if k in KINDS:
            met = simulate(p, motor, g).metrics
            out[k] = {
                "max_error": float(met["max_error"]),
                "peak_voltage": float(met["peak_voltage"]),
            }
    return out


def _pairs(name, answer, ref, tol_rel, hint):
    if not isinstance(answer, dict):
        raise Missing(f"{name}: a dict {{kind: {{'max_error': ..., 'peak_voltage': ...}}}}.")
    for k, r in ref.items():
        a = answer.get(k)
        if not isinstance(a, dict):
            raise Missing(f"{name}[{k!r}]: a dict with 'max_error' and 'peak_voltage'.")
        for q in ("max_error", "peak_voltage"):
            v = number(f"{name}[{k!r}][{q!r}]", a.get(q))
            if abs(v - r[q]) > tol_rel * abs(r[q]) + 1e-3:
                return CheckResult(
                    name, False, f"{k}: {beyond(q, v, r[q], _pct_text(tol_rel))}: {hint}"
                )
    return None


def check_predicted(answer, evidence, truth):
    model = evidence.answers.get("model3")
    if model is None:
        raise Missing(_needs("predicted", "model3", "your model (K, τ, f_c)"))
    ref = _prediction(evidence, model)
    bad = _pairs(
        "predicted",
        answer,
        ref,
        0.03,
        "simulate(profile, DCMotor(K, τ, coulomb_friction=f_c, "
        "encoder_ppr=rig.counts_per_rev), gains) and read metrics['max_error'], ['peak_voltage'].",
    )
    if bad:
        return bad
    return CheckResult(
        "predicted",
        True,
        "the simulation of your identified model with the lab's gains: with "
        "the same limits the profiles differ in how hard they ask the loop at each jerk step.",
    )


def check_measured3(answer, evidence, truth):
    ref = {}
    for k in KINDS:
        rec = evidence.runs.get(f"move_{k}")
        if rec is None:
            continue
        p = _plans(evidence)[k]
        m = spec_metrics(rec, p)
        ref[k] = {"max_error": m["max_error"], "peak_voltage": m["peak_voltage"]}
    if "sine_jerk" not in ref:
        raise Missing("the recording 'move_sine_jerk' is missing: run the rig cell first.")
    bad = _pairs(
        "measured3",
        answer,
        ref,
        0.01,
        "max |reference − position| for t ≤ duration, and max |rec.voltage|.",
    )
    if bad:
        return bad
    skipped = [k for k in KINDS if k not in ref]
    note = f" ({', '.join(skipped)} not run: this device lacks the planner)" if skipped else ""
    return CheckResult("measured3", True, "read right from your recordings" + note + ".")


def check_rig_vs_sim(answer, evidence, truth):
    v = number("rig_vs_sim", answer)
    model = evidence.answers.get("model3")
    if model is None:
        raise Missing(_needs("rig_vs_sim", "model3", "your model (K, τ, f_c)"))
    rec = run_of(evidence, "move_sine_jerk")
    p = _plans(evidence)["sine_jerk"]
    meas = spec_metrics(rec, p)["max_error"]
    pred = _prediction(evidence, model)["sine_jerk"]["max_error"]
    ref = meas / pred
    if rel(v, ref) <= 0.03:
        return CheckResult(
            "rig_vs_sim",
            True,
            f"measured / predicted = {ref:.2f}: what the model leaves out "
            "(the offset, count noise, errors in K, τ, f_c) shows up as the difference.",
        )
    if rel(v, 1 / ref) <= 0.03:
        return CheckResult("rig_vs_sim", False, f"{_hint('rig_vs_sim_inverted')}.")
    return CheckResult(
        "rig_vs_sim", False, "the sine-jerk move's measured max error divided by the simulated one."
    )


def check_model3(answer, evidence, truth):
    K_hat, tau_hat, fc_hat = (number(f"model3[{i}]", a) for i, a in enumerate(answer))
    res = check_model((K_hat, tau_hat), evidence, truth)
    if not res.ok or truth is None:
        return CheckResult("model3", res.ok, res.message)
    if abs(fc_hat - truth["coulomb_friction"]) > 0.1:
        return CheckResult(
            "model3",
            False,
            "f_c is not your motor's: take the friction voltage you found in "
            "lab 1's sweep (V, not rad/s).",
        )
    return CheckResult(
        "model3",
        True,
        "K, τ and f_c from lab 1 describe this motor: the predictions below use them.",
    )


def check_pem_friction(answer, evidence, truth):
    if not isinstance(answer, (tuple, list)) or len(answer) != 3:
        raise Missing(
            "pem_friction: a tuple (K, tau, f_c) from the PEM fit with friction and offset."
        )
    if answer[2] is None:
        return CheckResult(
            "pem_friction",
            False,
            "f_c is None: pass friction=True (and offset=True) to ident.fit_dc_motor.",
        )
    Kp, tp, fp = (number(f"pem_friction[{i}]", a) for i, a in enumerate(answer))
    K, tau, fc, off, src = _lab1_reference(evidence, truth)
    bad = []
    if rel(Kp, K) > TOL["K"]:
        bad.append(beyond("K", Kp, K, _pct_text(TOL["K"])))
    if rel(tp, tau) > TOL["tau"]:
        bad.append(beyond("τ", tp, tau, _pct_text(TOL["tau"])))
    if abs(fp - fc) > TOL["f_c"]:
        bad.append(beyond("f_c", fp, fc, f"{TOL['f_c']:g} V"))
    if bad:
        return CheckResult(
            "pem_friction",
            False,
            ", ".join(bad) + ": fit all six steps at once (lists of "
            "u and θ, one per record) with friction=True and offset=True — from one step "
            "friction and gain cannot be told apart.",
        )
    return CheckResult(
        "pem_friction",
        True,
        f"all three agree with {src}: with six records at different "
        "voltages and both directions, the output-error fit separates the gain, the friction "
        "(which flips with the direction) and the offset (which does not), and it agrees "
        "with the sweep — two methods, one motor.",
    )
