"""The checks of the three lab worksheets.

Each check compares a student's answer with the truth of *this* student's motor (the hidden
motor of the virtual rig or of simavr) or, on a real Uno, with the checker's own analysis of
the student's recordings; tolerances follow what the measurement allows (quantization,
noise). A failing check names the most likely mistake; a passing one says why the answer
is right. No message ever prints a true parameter value. The physics is Stojčić's (Stojcic
2015): the motor of Stojčić eq. 1, the load of Stojčić eq. 9, the PID of Stojčić eq. 11.
"""

from __future__ import annotations

import math

import numpy as np

from jerklab.lab.session import MOVE, SPEC, CheckResult, _Missing

__all__ = [
    "run_check",
    "CHECKS",
    "steady_speed",
    "sweep_fit",
    "move_metrics",
    "SWEEP_VOLTS",
    "STEP_SECONDS",
    "DESIGN_TS",
    "PRBS",
]

#: Voltages of lab 1's sweep of steps (each from rest) and their length (s).
SWEEP_VOLTS = (-9.0, -6.0, -3.0, 3.0, 6.0, 9.0)
STEP_SECONDS = 0.4
#: Lab 1's PRBS record (``rig.record_prbs(**PRBS)``): 6 ± 2 V, so the motor never stops or turns
#: back (friction then acts as a constant input bias, which PEM's offset absorbs), a maximal-length
#: sequence of order 7 with each bit held 2 samples: 254 samples, 1.27 s at Ts = 5 ms.
PRBS = {"amplitude": 2.0, "offset": 6.0, "order": 7, "hold": 2}
#: Control period of labs 2-3 (s)
DESIGN_TS = 0.005

CHECKS = {}


def _check(name):
    def deco(f):
        CHECKS[name] = f
        return f

    return deco


def run_check(session, name, answer, **context):
    if name not in CHECKS:
        raise KeyError(f"no check named {name!r} (known: {sorted(CHECKS)})")
    return CHECKS[name](session, answer, **context)


def _num(name, x):
    if x is Ellipsis or x is None:
        raise _Missing(f"{name}: no answer yet — replace the `...`.")
    v = float(x)
    if not math.isfinite(v):
        raise _Missing(f"{name}: your answer is {v}, not a finite number.")
    return v


def _rec_name(volts):
    return f"step_{volts:+g}V".replace("+", "p").replace("-", "m").replace(".", "_")


def _rec(session, name):
    rec = session.recordings.get(name)
    if rec is None:
        raise _Missing(
            f"the recording {name!r} is missing: run the recording cell of this task first."
        )
    return rec


# ------------------------------------------------------------------ analysis helpers (the checker's own)
def steady_speed(rec, window=0.1):
    """Steady speed (rad/s) of a step record: slope of the angle over its last ``window`` s."""
    t, y = np.asarray(rec.time), np.asarray(rec.position)
    sel = t >= t[-1] - window
    return float(np.polyfit(t[sel], y[sel], 1)[0])


def sweep_fit(speeds):
    """Least squares ω = K·V + K·offset − K·f_c·sign(V) over a sweep {V: ω}; returns
    (K, f_c, offset) and their standard errors."""
    V = np.array(sorted(speeds), dtype=float)
    w = np.array([speeds[v] for v in sorted(speeds)])
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


def move_metrics(rec, duration, distance):
    """Tracking metrics of a move recording: max |e| during the move, overshoot (% of the
    distance) after it, settling time into ``SPEC['settle_band']`` after the end, peak |u|,
    saturated samples."""
    t = np.asarray(rec.time)
    e = np.asarray(rec.reference) - np.asarray(rec.position)
    during = t <= duration + 1e-9
    over = (np.asarray(rec.position) - distance) * np.sign(distance)
    after = t > duration
    overshoot = max(0.0, float(np.max(over[after]))) / abs(distance) * 100 if after.any() else 0.0
    out = np.nonzero(np.abs(e) > SPEC["settle_band"])[0]
    Ts = float(np.median(np.diff(t)))
    settle = max(0.0, float(t[out[-1]] + Ts - duration)) if len(out) else 0.0
    if len(out) and out[-1] == len(t) - 1:
        settle = math.inf
    return {
        "max_error": float(np.max(np.abs(e[during]))),
        "overshoot_pct": overshoot,
        "settling_time": settle,
        "peak_voltage": float(np.max(np.abs(rec.control))),
        "saturated": int(np.count_nonzero(np.asarray(rec.saturated))),
    }


def _rel(a, b):
    return abs(a - b) / abs(b)


def _pct(a, b):
    return 100.0 * (a - b) / abs(b)


# ------------------------------------------------------------------ lab 1: identify your motor
@_check("pre_speed")
def _pre_speed(s, ans):
    v = _num("pre_speed", ans)
    ref = 30.0 * 6.0
    if _rel(v, ref) < 0.01:
        return CheckResult(
            "pre_speed",
            True,
            "ω_ss = K·V = 30 × 6 = 180 rad/s: at steady state "
            "τ·ω' = 0, so the velocity part K/(τs+1) of Stojčić eq. 1 gives K·V; τ only sets how fast.",
        )
    if _rel(v, ref / (2 * math.pi)) < 0.02:
        return CheckResult(
            "pre_speed", False, "that is in revolutions per second: K is in rad/(V·s)."
        )
    if _rel(v, ref * 60 / (2 * math.pi)) < 0.02:
        return CheckResult("pre_speed", False, "that is in rpm: answer in rad/s.")
    if _rel(v, 30 * 6 * 0.040) < 0.02 or _rel(v, 6 / 0.040) < 0.02:
        return CheckResult(
            "pre_speed", False, "τ does not enter the steady speed: set ω' = 0 in τω' + ω = K·V."
        )
    return CheckResult(
        "pre_speed", False, f"{_pct(v, ref):+.0f} % off: at steady state τω' = 0 in τω' + ω = K·V."
    )


@_check("pre_tau63")
def _pre_tau63(s, ans):
    v = _num("pre_tau63", ans)
    if _rel(v, 0.040) < 0.01:
        return CheckResult(
            "pre_tau63", True, "ω(t) = K·V(1 − e^(−t/τ)) reaches 1 − 1/e ≈ 63 % at t = τ = 0.040 s."
        )
    if _rel(v, 40.0) < 0.01:
        return CheckResult("pre_tau63", False, "1000× too large: seconds, not milliseconds.")
    if _rel(v, 0.040 * math.log(2)) < 0.02 or _rel(v, 0.040 * 3) < 0.02:
        return CheckResult(
            "pre_tau63", False, "that is the time to 50 % or 95 %: 63 % is exactly one τ."
        )
    return CheckResult(
        "pre_tau63", False, f"{_pct(v, 0.040):+.0f} % off: solve 1 − e^(−t/τ) = 0.63 for t."
    )


def _lab1_reference(s):
    """(K, tau, f_c, offset) of the motor: the truth on a simulated plant, else the checker's fit."""
    truth = s._truth()
    if truth is not None:
        return truth["K"], truth["tau"], truth["coulomb_friction"], truth["offset"], "your motor"
    from jerklab import ident

    speeds = {v: steady_speed(_rec(s, _rec_name(v))) for v in SWEEP_VOLTS}
    (K, fc, off), _ = sweep_fit(speeds)
    r = _rec(s, _rec_name(6.0))
    tau = ident.fit_dc_motor(r.control, r.position, r.metadata["Ts"], "pem").tau
    return K, tau, fc, off, "the checker's analysis of your recordings (real rig)"


@_check("tau")
def _tau(s, ans):
    from jerklab import ident

    v = _num("tau", ans)
    K, tau, fc, off, src = _lab1_reference(s)
    if v <= 0:
        return CheckResult(
            "tau", False, "τ must be positive: a time constant of the velocity's exponential."
        )
    if _rel(v, tau * 1000) < 0.15:
        return CheckResult("tau", False, "τ is about 1000× too large: seconds, not milliseconds.")
    if _rel(v, tau) <= 0.08:
        return CheckResult(
            "tau",
            True,
            f"within {100 * _rel(v, tau):.1f} % of {src}. From rest the "
            "motor sees a constant net voltage (V + offset − f_c), so friction changes the "
            "gain of a step but not its time constant, and PEM, which fits the simulated "
            "angle, is not biased by the encoder's quantization.",
        )
    try:
        r = _rec(s, _rec_name(6.0))
        t_arx = ident.fit_dc_motor(r.control, r.position, r.metadata["Ts"], "arx").tau
    except (_Missing, ValueError):
        t_arx = None
    if t_arx is not None and _rel(v, t_arx) < 0.02:
        return CheckResult(
            "tau",
            False,
            f"τ is {_pct(v, tau):+.0f} % off — that is the ARX estimate: ARX "
            "regresses the differenced angle, whose quantization noise sits in the regressor "
            "and biases τ short. Report PEM's τ.",
        )
    return CheckResult(
        "tau",
        False,
        f"τ is {_pct(v, tau):+.0f} % off: did you fit the angle (PEM) of the "
        "+6 V step from rest, with u = rec.control and y = rec.position?",
    )


@_check("K")
def _K(s, ans):
    v = _num("K", ans)
    K, tau, fc, off, src = _lab1_reference(s)
    if v < 0 and _rel(-v, K) < 0.1:
        return CheckResult(
            "K",
            False,
            "K is negative: is the encoder wired backwards (swap A and B), or "
            "the motor leads — or did you regress V on ω instead of ω on V?",
        )
    if _rel(v, K) <= 0.04:
        return CheckResult(
            "K",
            True,
            f"within {100 * _rel(v, K):.1f} % of {src}. The slope of the "
            "steady speed against the voltage is K whatever the friction: f_c and the offset "
            "only shift the lines, so the sweep separates them.",
        )
    for factor, hint in (
        (2 * math.pi, "that is in rad/(V·s) × 2π: did you convert revolutions twice?"),
        (1 / (2 * math.pi), "that is revolutions, not radians: K is in rad/(V·s)."),
        (60 / (2 * math.pi), "that is rpm per volt: K is in rad/(V·s)."),
    ):
        if _rel(v, K * factor) < 0.06:
            return CheckResult("K", False, f"K is off by a factor {factor:.3g}: {hint}")
    k_eff = K * (1 - (fc - off) / 6.0)
    if _rel(v, k_eff) < 0.03 and _rel(k_eff, K) > 0.02:
        return CheckResult(
            "K",
            False,
            f"K is {_pct(v, K):+.0f} % off — that is the gain of the 6 V step "
            "alone: friction lowers a single step's gain by about f_c/V. Take the slope of "
            "the sweep's steady speeds.",
        )
    return CheckResult(
        "K",
        False,
        f"K is {_pct(v, K):+.0f} % off: did you take the slope of steady speed "
        "(rad/s) against voltage (V) — the speed at the end of each step, not the angle?",
    )


@_check("f_c")
def _fc(s, ans):
    v = _num("f_c", ans)
    K, tau, fc, off, src = _lab1_reference(s)
    tol = 0.06
    if abs(v - fc) <= tol:
        return CheckResult(
            "f_c",
            True,
            f"within {abs(v - fc):.2f} V of {src}. The two branches of the "
            "sweep cross zero speed at +f_c − offset and −f_c − offset: half their distance is "
            "the friction, their midpoint the offset.",
        )
    if v < 0 and abs(-v - fc) <= tol:
        return CheckResult(
            "f_c",
            False,
            "f_c is negative: friction opposes the motion — check the sign of "
            "the sign(V) column in your regression.",
        )
    if min(abs(v - (fc - off)), abs(v - (fc + off))) <= tol / 2 and abs(off) > tol / 2:
        return CheckResult(
            "f_c",
            False,
            "that is where one branch crosses zero speed: the offset shifts both "
            "branches the same way — average the + and − branch.",
        )
    if abs(v / K - fc) <= tol:
        return CheckResult(
            "f_c", False, "that is in rad/s: f_c is a voltage — divide the speed intercept by K."
        )
    return CheckResult(
        "f_c",
        False,
        f"f_c is {v - fc:+.2f} V off: fit ω = K·V + K·offset − K·f_c·sign(V) over all six steps.",
    )


@_check("uncertainty")
def _unc(s, ans):
    ks, ts, fs = (_num(f"uncertainty[{i}]", a) for i, a in enumerate(ans))
    K, tau, fc, off, src = _lab1_reference(s)
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
        "positive and small against the values: one standard error from "
        "the covariance of each least-squares fit (s²(AᵀA)⁻¹ or the Jacobian for PEM).",
    )


def _validation(s):
    from jerklab import ident

    r6, r3 = _rec(s, _rec_name(6.0)), _rec(s, _rec_name(3.0))
    Ts = r6.metadata["Ts"]
    fit = ident.fit_dc_motor(r6.control, r6.position, Ts, "pem")
    return ident.validate(fit, r3.control, r3.position, Ts)


@_check("fit_valid")
def _fit_valid(s, ans):
    v = _num("fit_valid", ans)
    val = _validation(s)
    if abs(v - val.fit_percent) <= 1.5:
        return CheckResult(
            "fit_valid",
            True,
            f"{val.fit_percent:.1f} % agrees with the checker's. Where the 6 V "
            "model misses the 3 V record, it is mostly because friction takes a bigger share of "
            "3 V than of 6 V — a gain error that a single step cannot see.",
        )
    if 0 < v <= 1 and abs(100 * v - val.fit_percent) <= 1.5:
        return CheckResult("fit_valid", False, "fit is in percent (0–100), not a fraction.")
    return CheckResult(
        "fit_valid",
        False,
        f"the checker finds {val.fit_percent:.1f} %: simulate the PEM "
        "model of the +6 V step on the +3 V record (ident.validate), not on its own data.",
    )


@_check("white")
def _white(s, ans):
    if not isinstance(ans, (bool, np.bool_)):
        raise _Missing("white: answer True or False.")
    val = _validation(s)
    if bool(ans) == bool(val.analysis.white):
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


@_check("prbs_fit")
def _prbs_fit(s, ans):
    from jerklab import ident

    K_a, tau_a = (_num(f"prbs_fit[{i}]", a) for i, a in enumerate(ans))
    r = _rec(s, "prbs")
    u, y, Ts = r.control, r.position, r.metadata["Ts"]
    truth = s._truth()
    if truth is not None:
        K, tau, src = truth["K"], truth["tau"], "your motor"
    else:
        f = ident.fit_dc_motor(u, y, Ts, "pem", offset=True)
        K, tau, src = (
            f.K,
            f.tau,
            "the checker's PEM fit (with offset) of your PRBS record (real rig)",
        )
    if _rel(K_a, K) <= 0.04 and _rel(tau_a, tau) <= 0.08:
        return CheckResult(
            "prbs_fit",
            True,
            f"K within {100 * _rel(K_a, K):.1f} % and τ within "
            f"{100 * _rel(tau_a, tau):.1f} % of {src}. The PRBS keeps the motor turning one "
            "way, so friction acts as a constant input bias: PEM's offset absorbs it "
            "(offset − f_c), and K comes out unbiased from one record, where a single step "
            "could not tell K from friction.",
        )
    if _rel(tau_a, tau * 1000) < 0.15:
        return CheckResult(
            "prbs_fit", False, "τ is about 1000× too large: seconds, not milliseconds."
        )
    for factor, hint in (
        (2 * math.pi, "K is 2π too large: radians were converted twice?"),
        (1 / (2 * math.pi), "K is in revolutions: K is in rad/(V·s)."),
    ):
        if _rel(K_a, K * factor) < 0.06:
            return CheckResult("prbs_fit", False, hint)
    for method, kw, hint in (
        (
            "pem",
            {},
            "that is PEM without the offset: the PRBS runs at 6 ± 2 V, so friction takes a "
            "constant share of the input and shows up as a lower gain. Fit with offset=True.",
        ),
        (
            "arx",
            {},
            "that is the ARX estimate: its regressor holds the differenced, quantized angle "
            "(errors in the variables), and it has no offset term for the friction. Report PEM "
            "with offset=True.",
        ),
    ):
        try:
            f = ident.fit_dc_motor(u, y, Ts, method, **kw)
        except ValueError:
            continue
        if (
            _rel(K_a, f.K) < 0.01
            and _rel(tau_a, f.tau) < 0.03
            and (_rel(f.K, K) > 0.02 or _rel(f.tau, tau) > 0.04)
        ):
            return CheckResult(
                "prbs_fit",
                False,
                f"K is {_pct(K_a, K):+.0f} % and τ {_pct(tau_a, tau):+.0f} % off — {hint}",
            )
    return CheckResult(
        "prbs_fit",
        False,
        f"K is {_pct(K_a, K):+.0f} % and τ {_pct(tau_a, tau):+.0f} % off: fit "
        "the PRBS record with u = rp.control (the applied volts) and y = rp.position, by PEM "
        "with offset=True.",
    )


@_check("trust")
def _trust(s, ans):
    a = str(ans).strip().lower()
    if a not in ("pem", "arx"):
        raise _Missing('trust: answer "pem" or "arx".')
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
@_check("pre_z")
def _pre_z(s, ans):
    v = _num("pre_z", ans)
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


@_check("pre_integral")
def _pre_integral(s, ans):
    if not isinstance(ans, (bool, np.bool_)):
        raise _Missing("pre_integral: answer True or False.")
    if ans is False or ans == False:  # noqa: E712
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


@_check("model")
def _model(s, ans):
    K_hat, tau_hat = (_num(f"model[{i}]", a) for i, a in enumerate(ans))
    truth = s._truth()
    if truth is None:
        return CheckResult(
            "model", True, "noted (real rig: your lab 1 values are the best model there is)."
        )
    eK, et = _rel(K_hat, truth["K"]), _rel(tau_hat, truth["tau"])
    if eK <= 0.08 and et <= 0.12:
        return CheckResult(
            "model",
            True,
            "your lab 1 values describe this motor: the design and the "
            "feedforward are built on them.",
        )
    if _rel(tau_hat, truth["tau"] * 1000) < 0.2:
        return CheckResult("model", False, "τ in milliseconds: the design needs seconds.")
    return CheckResult(
        "model",
        False,
        f"K is {100 * eK:.0f} % and τ {100 * et:.0f} % away from your "
        "motor: use the values you identified in lab 1 on this rig (a neighbour's motor differs).",
    )


def _gains_of(ans):
    from jerklab.controller import DiscreteGains

    if ans is Ellipsis or ans is None:
        raise _Missing("gains: no answer yet — take them from the panel (lab.panel_gains(panel)).")
    if not isinstance(ans, DiscreteGains):
        raise _Missing(
            f"gains must be DiscreteGains (from the panel or discrete_pole_placement_pid, or "
            f"Gains.discretize(Ts)), got {type(ans).__name__}"
        )
    return ans


def _simulate_on_motor(s, gains, model):
    """The spec move on a fresh copy of the student's rig (same hidden motor), in memory."""
    from jerklab.lab.motors import connect_student
    from jerklab.planner import plan_sine_jerk

    prof = plan_sine_jerk(**MOVE)
    rig = connect_student(
        s.student, None, progress=False, recordings=s.folder, key=getattr(s, "_key", None)
    )
    try:
        rig.set_model(*model)
        rec = rig.run_move(prof, gains, gains.Ts, settle=0.4, path=False)
    finally:
        rig.close()
    return move_metrics(rec, prof.duration, prof.distance)


def _spec_failures(m):
    out = []
    if m["saturated"] or m["peak_voltage"] > SPEC["max_voltage"] + 1e-9:
        out.append(
            f"the voltage hits the {SPEC['max_voltage']:g} V supply ({m['saturated']} saturated samples): "
            "lower ωn or σ/ωn — the derivative gain grows with σ"
        )
    if m["max_error"] > SPEC["max_error"]:
        out.append(
            f"the tracking error reaches {m['max_error']:.2f} rad > {SPEC['max_error']} rad: a stiffer "
            "loop (larger ωn) rejects the friction sooner"
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


@_check("design")
def _design(s, ans, model=None):
    from jerklab.controller import PositionLoop

    g = _gains_of(ans)
    model = model or s.answers.get("model")
    if model is None:
        raise _Missing("design: check your model (K, τ) first (task 1).")
    truth = s._truth()
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
            f"your sampled loop has |z| = {r:.2f} ≥ 1 on this motor: unstable{extra}. "
            "Use the z-domain design or a shorter Ts.",
        )
    if g.kid <= 0:
        return CheckResult(
            "design",
            False,
            "no integral action (kid = 0): a load step then leaves a "
            "steady-state error — the spec asks for zero.",
        )
    if truth is None:
        return CheckResult(
            "design",
            True,
            f"stable on your model (largest |z| = {r:.3f}) with integral "
            "action; the rig run below tells whether it meets the spec.",
        )
    m = _simulate_on_motor(s, g, model)
    fails = _spec_failures(m)
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


@_check("measured")
def _measured(s, ans):
    from jerklab.planner import plan_sine_jerk

    rec = _rec(s, "move_sine_jerk")
    prof = plan_sine_jerk(**MOVE)
    m = move_metrics(rec, prof.duration, prof.distance)
    keys = ("max_error", "overshoot_pct", "settling_time", "peak_voltage")
    if not isinstance(ans, dict) or set(keys) - set(ans):
        raise _Missing(f"measured: a dict with keys {keys}.")
    for k in keys:
        v = _num(k, ans[k])
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
                "settling_time": f"the last time |e| leaves ±{SPEC['settle_band']} rad, minus the move's duration",
                "peak_voltage": "max |rec.control| (the PWM-quantized voltage applied)",
            }[k]
            return CheckResult("measured", False, f"{k} disagrees with the recording: {hint}.")
    fails = _spec_failures(m)
    if fails:
        return CheckResult(
            "measured",
            False,
            "measured right, but the rig misses the spec: " + "; ".join(fails) + ".",
        )
    return CheckResult(
        "measured", True, "read right from the recording, and the rig meets the spec."
    )


@_check("gap")
def _gap(s, ans):
    from jerklab.controller import PositionLoop, discrete_pole_placement_pid, pole_placement_pid

    model = s.answers.get("model")
    if model is None:
        raise _Missing("gap: check your model (K, τ) first (task 1).")
    K, tau = model
    rc, rz = (_num(f"gap[{i}]", a) for i, a in enumerate(ans))
    Ts, wn = 0.020, 30.0
    ref_c = PositionLoop(
        K, tau, pole_placement_pid(K, tau, wn, 1.0).discretize(Ts)
    ).max_pole_radius()
    ref_z = PositionLoop(
        K, tau, discrete_pole_placement_pid(K, tau, wn, 1.0, Ts=Ts, extra_pole=0.0)
    ).max_pole_radius()
    if abs(rc - ref_c) <= 0.01 and abs(rz - ref_z) <= 0.01:
        return CheckResult(
            "gap",
            True,
            f"|z| = {ref_c:.2f} for Stojčić eq. 11 discretized by Stojčić eq. 13 against "
            f"{ref_z:.2f} for the z-domain design: at σ·Ts = {7 * wn * Ts:.1f} the "
            "approximation behind Stojčić eq. 13 breaks down and the loop leaves the unit circle, while the "
            "z-domain design solves for the poles on the exact ZOH plant: they sit at e^(sTs) "
            "(the dominant pair at e^(−ζωnTs)) and the fourth at z = 0.",
        )
    if abs(rc - ref_z) <= 0.01 and abs(rz - ref_c) <= 0.01:
        return CheckResult(
            "gap",
            False,
            "the two are swapped: the first is the continuous design (Stojčić eq. 11, discretized by Stojčić eq. 13).",
        )
    which = "the continuous design's" if abs(rc - ref_c) > 0.01 else "the z-domain design's"
    return CheckResult(
        "gap",
        False,
        f"{which} radius is off: use PositionLoop(K, τ, gains).max_pole_radius() "
        "with YOUR K and τ, ωn = 30 rad/s, ζ = 1, σ = 7ωn, Ts = 20 ms, extra_pole=0.0 for the z design.",
    )


# ------------------------------------------------------------------ lab 3: move smoothly
KINDS = ("trapezoid", "scurve", "sine_jerk")


def _plans():
    from jerklab.planner import plan_scurve, plan_sine_jerk, plan_sine_jerk_optimal, plan_trapezoid

    return {
        "trapezoid": plan_trapezoid(MOVE["distance"], MOVE["max_accel"], MOVE["max_velocity"]),
        "scurve": plan_scurve(**MOVE),
        "sine_jerk": plan_sine_jerk(**MOVE),
        "sine_jerk_optimal": plan_sine_jerk_optimal(**MOVE),
    }


@_check("pre_shortest")
def _pre_shortest(s, ans):
    a = str(ans).strip().lower().replace("-", "_")
    if a not in KINDS:
        raise _Missing(f"pre_shortest: one of {KINDS}.")
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


@_check("durations")
def _durations(s, ans):
    p = _plans()
    if not isinstance(ans, dict):
        raise _Missing(f"durations: a dict {{kind: seconds}} for {KINDS}.")
    for k in KINDS:
        v = _num(f"durations[{k!r}]", ans.get(k))
        if _rel(v, p[k].duration) > 1e-4:
            if _rel(v, p[k].duration * 1000) < 1e-3:
                return CheckResult("durations", False, f"{k}: milliseconds — give seconds.")
            return CheckResult(
                "durations",
                False,
                f"{k}: {_pct(v, p[k].duration):+.1f} % off: plan it with "
                "the move's limits (lab.MOVE) and read profile.duration.",
            )
    return CheckResult(
        "durations",
        True,
        "trapezoid < S-curve < published sine-jerk: each smoother jerk "
        "costs time, and the published planner's phases cost more than they need to.",
    )


@_check("lost_time")
def _lost(s, ans):
    v = _num("lost_time", ans)
    p = _plans()
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
        return CheckResult("lost_time", False, "the sign: published minus optimal.")
    return CheckResult(
        "lost_time",
        False,
        "plan_sine_jerk(...).duration − plan_sine_jerk_optimal(...).duration with the same limits.",
    )


def _prediction(s, model):
    from jerklab.controller import discrete_pole_placement_pid
    from jerklab.plant import DCMotor
    from jerklab.sim import simulate

    K, tau, fc = model
    g = discrete_pole_placement_pid(K, tau, 30.0, 1.0, Ts=DESIGN_TS)
    motor = DCMotor(K=K, tau=tau, coulomb_friction=fc, encoder_ppr=s.rig.counts_per_rev)
    out = {}
    for k, p in _plans().items():
        if k in KINDS:
            met = simulate(p, motor, g).metrics
            out[k] = {
                "max_error": float(met["max_abs_error"]),
                "peak_voltage": float(met["max_abs_voltage"]),
            }
    return out


def _pairs(name, ans, ref, tol_rel, hint):
    if not isinstance(ans, dict):
        raise _Missing(f"{name}: a dict {{kind: {{'max_error': ..., 'peak_voltage': ...}}}}.")
    for k, r in ref.items():
        a = ans.get(k)
        if not isinstance(a, dict):
            raise _Missing(f"{name}[{k!r}]: a dict with 'max_error' and 'peak_voltage'.")
        for q in ("max_error", "peak_voltage"):
            v = _num(f"{name}[{k!r}][{q!r}]", a.get(q))
            if abs(v - r[q]) > tol_rel * abs(r[q]) + 1e-3:
                return CheckResult(name, False, f"{k}: {q} is {_pct(v, r[q]):+.0f} % off: {hint}")
    return None


@_check("predicted")
def _predicted(s, ans, model=None):
    model = model or s.answers.get("model3")
    if model is None:
        raise _Missing("predicted: check your model (K, τ, f_c) first.")
    ref = _prediction(s, model)
    bad = _pairs(
        "predicted",
        ans,
        ref,
        0.03,
        "simulate(profile, DCMotor(K, τ, coulomb_friction=f_c, "
        "encoder_ppr=rig.counts_per_rev), gains) and read metrics['max_abs_error'], ['max_abs_voltage'].",
    )
    if bad:
        return bad
    return CheckResult(
        "predicted",
        True,
        "the simulation of your identified model with the lab's gains: with "
        "the same limits the profiles differ in how hard they ask the loop at each jerk step.",
    )


@_check("measured3")
def _measured3(s, ans):
    ref = {}
    for k in KINDS:
        rec = s.recordings.get(f"move_{k}")
        if rec is None:
            continue
        p = _plans()[k]
        m = move_metrics(rec, p.duration, p.distance)
        ref[k] = {"max_error": m["max_error"], "peak_voltage": m["peak_voltage"]}
    if "sine_jerk" not in ref:
        raise _Missing("the recording 'move_sine_jerk' is missing: run the rig cell first.")
    bad = _pairs(
        "measured3",
        ans,
        ref,
        0.01,
        "max |reference − position| for t ≤ duration, and max |rec.control|.",
    )
    if bad:
        return bad
    skipped = [k for k in KINDS if k not in ref]
    note = f" ({', '.join(skipped)} not run: this device lacks the planner)" if skipped else ""
    return CheckResult("measured3", True, "read right from your recordings" + note + ".")


@_check("rig_vs_sim")
def _rig_vs_sim(s, ans):
    v = _num("rig_vs_sim", ans)
    model = s.answers.get("model3")
    if model is None:
        raise _Missing("rig_vs_sim: check your model first.")
    rec = _rec(s, "move_sine_jerk")
    p = _plans()["sine_jerk"]
    meas = move_metrics(rec, p.duration, p.distance)["max_error"]
    pred = _prediction(s, model)["sine_jerk"]["max_error"]
    ref = meas / pred
    if _rel(v, ref) <= 0.03:
        return CheckResult(
            "rig_vs_sim",
            True,
            f"measured / predicted = {ref:.2f}: what the model leaves out "
            "(the offset, count noise, errors in K, τ, f_c) shows up as the difference.",
        )
    if _rel(v, 1 / ref) <= 0.03:
        return CheckResult("rig_vs_sim", False, "inverted: measured divided by predicted.")
    return CheckResult(
        "rig_vs_sim", False, "the sine-jerk move's measured max error divided by the simulated one."
    )


@_check("model3")
def _model3(s, ans):
    K_hat, tau_hat, fc_hat = (_num(f"model3[{i}]", a) for i, a in enumerate(ans))
    res = _model(s, (K_hat, tau_hat))
    truth = s._truth()
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


@_check("pem_friction")
def _pem_friction(s, ans):
    if not isinstance(ans, (tuple, list)) or len(ans) != 3:
        raise _Missing(
            "pem_friction: a tuple (K, tau, f_c) from the PEM fit with friction and offset."
        )
    if ans[2] is None:
        return CheckResult(
            "pem_friction",
            False,
            "f_c is None: pass friction=True (and offset=True) to ident.fit_dc_motor.",
        )
    Kp, tp, fp = (_num(f"pem_friction[{i}]", a) for i, a in enumerate(ans))
    K, tau, fc, off, src = _lab1_reference(s)
    bad = []
    if _rel(Kp, K) > 0.04:
        bad.append(f"K is {_pct(Kp, K):+.0f} % off")
    if _rel(tp, tau) > 0.08:
        bad.append(f"τ is {_pct(tp, tau):+.0f} % off")
    if abs(fp - fc) > 0.06:
        bad.append(f"f_c is {fp - fc:+.2f} V off")
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


# ------------------------------------------------------------------ lab 4: stop the ringing
from jerklab.lab import ringing as _ringing  # noqa: E402,F401  (registers lab 4's checks)
