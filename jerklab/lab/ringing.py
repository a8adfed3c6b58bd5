"""Lab 4, "Stop the ringing": the rig's flexible load, its hidden mode, input shapers.

The student's rig carries a load on a compliant shaft (``lab.start(4, ...)``: the student's
:class:`jerklab.lab.motors.StudentFlexibleMotor` on the virtual rig or simavr): a lightly damped
mode that the motor's encoder sees only faintly. The worksheet finds it from a PRBS through the encoder
(``jerklab.shaping.identify_mode``), designs input shapers for it
(``jerklab.shaping.input_shaper``; Singer & Seering's ZV/ZVD, Singhose's EI), runs the move with and
without them on the rig (``Rig.set_shaper``: the firmware's FIR on the reference), and estimates
the load's residual vibration through the identified model, since no sensor sees the load.

The checks (``check_<name>(answer, evidence, truth)``, pure functions like those of
:mod:`jerklab.lab.checks`, listed in :mod:`jerklab.lab.registry`) judge every answer against
the student's own hidden mode (``truth``, :func:`jerklab.lab.motors.hidden_truth`: ``mode_hz``,
``mode_zeta``, the coupled mode of the two-mass model) or, on a real rig, against the checker's
own analysis of the student's recordings. No message prints a true value.
"""

from __future__ import annotations

import math

import numpy as np

from jerklab import shaping
from jerklab.controller import DiscreteGains
from jerklab.lab.checkbase import (
    CheckResult,
    Missing,
    Mistake,
    beyond,
    number,
    rel,
    run_of,
    side,
)
from jerklab.lab.motors import coupled_mode, motor_from_truth
from jerklab.plant import FlexibleDCMotor
from jerklab.rig.flexload import RulerLoad, predict

__all__ = [
    "PRBS_MODE",
    "MOVE4",
    "SOFT_KPD",
    "MODE_DRIFT",
    "soft_gains",
    "load_deflection",
    "residual_amplitude",
    "predicted_mode",
    "KINDS4",
    "MISTAKES4",
]

#: Lab 4's PRBS (``S.record_prbs(**PRBS_MODE)``): 6 ± 3 V, order 9, one sample per bit —
#: 511 samples (2.6 s at 5 ms) whose flat spectrum reaches the 6-16 Hz modes of the class.
PRBS_MODE = {"amplitude": 3.0, "offset": 6.0, "order": 9, "hold": 1}
#: Lab 4's move: two revolutions with the paper's limits (rad, rad/s^3, rad/s^2, rad/s).
MOVE4 = {"distance": 4 * math.pi, "max_jerk": 2.0e4, "max_accel": 300.0, "max_velocity": 100.0}
#: The weak position gain of lab 4's runs (V/rad): the move is the feedforward of the identified
#: model plus this, so the loop barely touches the mode (one encoder count is under one PWM tick).
SOFT_KPD = 0.5
#: The load change of task B4: the mode drops by this fraction (a heavier load).
MODE_DRIFT = 0.15
#: The shapers of the lab.
KINDS4 = ("zv", "zvd", "ei")

#: The mistakes lab 4's checks recognise, with the words of their hint (as
#: :data:`jerklab.lab.checks.MISTAKES`; docs/INSTRUCTOR.md's table is generated from both).
MISTAKES4 = {
    "pre_zv_period": Mistake(
        4, "pre_zv_delay", "a whole period for ZV's delay", "2× too long", "that is a full period"
    ),
    "mode_rad": Mistake(
        4, "mode", "the mode in rad/s", "f 2π× too large", "f is 2π too large: that is ω in rad/s"
    ),
    "mode_zeta_percent": Mistake(
        4, "mode", "ζ in percent", "ζ 100× too large", "ζ is a ratio (0.05), not a percent (5)"
    ),
    "zv_period": Mistake(
        4,
        "zv_delay",
        "a whole period for ZV's second impulse",
        "2× too long",
        "that is a whole period",
    ),
    "residual_fraction": Mistake(
        4, "residual_pct", "fractions for percentages", "100× too small", "those are fractions"
    ),
}


def soft_gains(Ts=0.005):
    """The gains of lab 4's moves: the feedforward (set with ``S.set_model``) and a weak P term
    (``SOFT_KPD``), no integral or derivative. The rig's stability check counts the unused
    integrator's pole at z = 1, so the moves run with ``force=True``."""
    return DiscreteGains(SOFT_KPD, 0.0, 0.0, Ts)


def load_deflection(model, rec):
    """The shaft deflection θ_load − θ_motor (rad) of a two-mass ``model``
    (``jerklab.plant.FlexibleDCMotor``, e.g. ``ModeFit.model()``) driven from rest by the
    voltage a recording applied (``rec.voltage``, held over each sample), at each sample time.

    No sensor sees the load: this is the model's estimate of what it did (an open-loop
    observer), exact ZOH (``model.zoh(Ts)``)."""
    Ts = float(rec.Ts)
    Phi, Gam = model.zoh(Ts)
    u = np.asarray(rec.voltage, dtype=float)
    x = np.zeros(Phi.shape[0])
    out = np.empty(len(u))
    g = Gam[:, 0]
    for k, uk in enumerate(u):
        out[k] = x[2] - x[0]
        x = Phi @ x + g * uk
    return out


def residual_amplitude(rec, deflection, start=0.05):
    """Residual vibration of a move: half the peak-to-peak ``deflection`` (rad) from ``start`` s
    after the (shaped) move ended — the first sample with TELEMETRY's settling flag — to the end
    of the recording."""
    flags = np.asarray(rec.flags).astype(int)
    settling = np.flatnonzero(flags & 2)
    if settling.size == 0:
        raise ValueError("the recording has no settling samples: run the move with settle > 0")
    Ts = float(rec.Ts)
    i0 = int(settling[0]) + int(round(start / Ts))
    d = np.asarray(deflection, dtype=float)[i0:]
    if d.size < 2:
        raise ValueError("too few samples after the move: a longer settle")
    return float(np.ptp(d) / 2)


def _truth4(evidence, truth):
    """(f Hz, zeta, model, source) of the student's mode: the hidden motor's, else the checker's
    fit of the PRBS record (real rig)."""
    if truth is not None and "mode_frequency" in truth:
        m = motor_from_truth(truth)
        f, z = coupled_mode(m)
        return f, z, m, "your rig (its hidden mode)"
    r = run_of(evidence, "prbs")
    fit = shaping.identify_mode(r.voltage, r.position, r.Ts)
    return (
        fit.frequency_hz,
        fit.damping,
        fit.model(),
        "the checker's fit of your PRBS record (real rig)",
    )


def _own_fit(evidence):
    """The checker's fit of the student's own PRBS record (``shaping.identify_mode``, as the
    worksheet asks), or None when there is no record or no mode in it."""
    try:
        r = run_of(evidence, "prbs")
        return shaping.identify_mode(r.voltage, r.position, r.Ts)
    except (Missing, ValueError, RuntimeError):
        return None


def _zv_delay(f, z):
    return 1.0 / (2.0 * f * math.sqrt(1.0 - z * z))


# ------------------------------------------------------------------ pre-lab
def check_pre_zv_delay(answer, evidence, truth):
    v = number("pre_zv_delay", answer)
    ref = 0.05
    if rel(v, ref) < 0.01:
        return CheckResult(
            "pre_zv_delay",
            True,
            "half the period, 1/(2f) = 0.05 s: the second impulse "
            "starts a vibration in antiphase with the first, and they cancel.",
        )
    if rel(v, 0.1) < 0.01:
        return CheckResult(
            "pre_zv_delay",
            False,
            f"{MISTAKES4['pre_zv_period'].hint}: an impulse one period later rings "
            "in phase with the first and doubles the vibration. Half a period cancels it.",
        )
    if rel(v, 1 / (2 * 2 * math.pi * 10)) < 0.02 or rel(v, 1 / (2 * math.pi * 10)) < 0.02:
        return CheckResult(
            "pre_zv_delay",
            False,
            "10 Hz is a frequency in hertz, not rad/s: the period is 1/f, no 2π.",
        )
    if rel(v, 50.0) < 0.01:
        return CheckResult("pre_zv_delay", False, "1000× too large: seconds, not milliseconds.")
    return CheckResult(
        "pre_zv_delay",
        False,
        f"{side(v, ref)}: when does an impulse ring in antiphase with one at t = 0?",
    )


def check_pre_zvd_length(answer, evidence, truth):
    v = number("pre_zvd_length", answer)
    if rel(v, 0.1) < 0.01:
        return CheckResult(
            "pre_zvd_length",
            True,
            "ZVD's impulses sit at 0, T/2 and T (T = 1/f = 0.1 s): it "
            "delays every move by one period, twice ZV, and buys a much wider band.",
        )
    if rel(v, 0.05) < 0.01:
        return CheckResult(
            "pre_zvd_length",
            False,
            "that is ZV's length: ZVD adds a third impulse, another half period later.",
        )
    if rel(v, 0.15) < 0.01:
        return CheckResult(
            "pre_zvd_length",
            False,
            "three impulses half a period apart span two half periods, not three.",
        )
    return CheckResult("pre_zvd_length", False, f"{side(v, 0.1)}: ZVD = ZV convolved with ZV.")


# ------------------------------------------------------------------ on the rig
def check_mode(answer, evidence, truth):
    f_a, z_a = (number(f"mode[{i}]", a) for i, a in enumerate(answer))
    f, z, _, src = _truth4(evidence, truth)
    ok_f, ok_z = rel(f_a, f) <= 0.03, abs(z_a - z) <= max(0.3 * z, 0.01)
    if ok_f and ok_z:
        return CheckResult(
            "mode",
            True,
            f"f and ζ within the tolerances (3 %, and 30 % or 0.01) of {src}. The PRBS puts "
            "power at every frequency up to 1/(2Ts); the two-mass model's output-error fit "
            "reads the mode from the tiny wiggle it leaves in the motor's angle.",
        )
    own = _own_fit(evidence) if ok_f and truth is not None and "mode_frequency" in truth else None
    if own is not None and rel(f_a, own.frequency_hz) <= 0.01:
        if abs(z_a - own.damping) <= max(0.05 * own.damping, 0.002):
            # the method was right and the record's noise moved ζ: the student's number is the
            # fit of their own record, which is all a student can know on a real rig too
            return CheckResult(
                "mode",
                True,
                f"ζ = {z_a:.3f} is {100 * abs(z_a / z - 1):.0f} % from your rig's hidden "
                f"{z:.3f}, but it is the fit of your own PRBS record (the checker fitted it "
                f"again: f = {own.frequency_hz:.2f} Hz, ζ = {own.damping:.3f} ± "
                f"{own.damping_se:.3f}). The encoder's count noise moves a lightly damped "
                "mode's ζ that far on one record (more at few samples a period); a longer "
                "record (order=10) or a second one pins it down better. f within 3 % of "
                f"{src}.",
            )
    if rel(f_a, 2 * math.pi * f) < 0.04:
        return CheckResult("mode", False, f"{MISTAKES4['mode_rad'].hint}; the shapers take hertz.")
    if ok_f and rel(z_a, 100 * z) < 0.3:
        return CheckResult("mode", False, f"{MISTAKES4['mode_zeta_percent'].hint}.")
    if ok_f:
        return CheckResult(
            "mode",
            False,
            f"f is right, {beyond('ζ', z_a, z, '30 % or 0.01')}: take `fit.damping`, the "
            "damping ratio of the fitted pole pair.",
        )
    return CheckResult(
        "mode",
        False,
        f"{beyond('f', f_a, f, '3 %')}: fit the PRBS record with "
        "shaping.identify_mode(rp.voltage, rp.position, Ts) — the applied volts and the "
        "encoder angle of the same record.",
    )


def check_zv_delay(answer, evidence, truth):
    v = number("zv_delay", answer)
    f, z, _, src = _truth4(evidence, truth)
    ref = _zv_delay(f, z)
    if rel(v, ref) <= 0.04:
        return CheckResult(
            "zv_delay",
            True,
            f"within the tolerance (4 %) of half the damped period "
            f"of {src}: ZV's second impulse, which every shaped move waits for.",
        )
    if rel(v, 2 * ref) <= 0.05:
        return CheckResult(
            "zv_delay",
            False,
            f"{MISTAKES4['zv_period'].hint} (ZVD's length, or your own 1/f): ZV's "
            "second impulse comes half a period after the first.",
        )
    if rel(v, ref / math.pi) <= 0.05:
        return CheckResult(
            "zv_delay",
            False,
            "that is 1/(2·ω) with ω in rad/s: half the period is 1/(2 f_d), f in Hz.",
        )
    return CheckResult(
        "zv_delay",
        False,
        f"{side(v, ref)} beyond the tolerance (4 %): build the ZV shaper from *your* mode "
        "(shaping.input_shaper('zv', f, ζ)) and read its last impulse time, zv.times[-1].",
    )


def _runs(evidence):
    runs = {}
    for kind in ("none",) + KINDS4:
        runs[kind] = run_of(evidence, f"move_{kind}")
    return runs


def check_residual_pct(answer, evidence, truth):
    if not isinstance(answer, dict):
        raise Missing(
            'residual_pct: answer a dict {"zv": ..., "zvd": ..., "ei": ...} of percentages.'
        )
    got = {k: number(f"residual_pct[{k!r}]", answer.get(k)) for k in KINDS4}
    _, _, model, src = _truth4(evidence, truth)
    runs = _runs(evidence)
    amp = {k: residual_amplitude(r, load_deflection(model, r)) for k, r in runs.items()}
    ref = {k: 100.0 * amp[k] / amp["none"] for k in KINDS4}
    tol = {k: max(3.0, 0.25 * ref[k]) for k in KINDS4}
    bad = [k for k in KINDS4 if abs(got[k] - ref[k]) > tol[k]]
    if not bad:
        return CheckResult(
            "residual_pct",
            True,
            "each within the tolerance (3 percentage points, or a quarter of the value) of "
            f"the load of {src}, driven by the voltages your runs applied. "
            "Tuned to the mode, every shaper removes most of the ringing; what is left "
            "comes from the mode estimate and the sampled (5 ms) reference.",
        )
    if all(0 <= got[k] <= 1.0 for k in KINDS4) and all(
        abs(100 * got[k] - ref[k]) <= tol[k] for k in KINDS4
    ):
        return CheckResult(
            "residual_pct",
            False,
            f"{MISTAKES4['residual_fraction'].hint}: answer percentages of the unshaped "
            "move's residual (100 × shaped / unshaped).",
        )
    if all(got[k] > 100 for k in bad):
        return CheckResult(
            "residual_pct",
            False,
            "above 100 %: divide the shaped move's residual by the "
            "unshaped one's, not the other way round.",
        )
    return CheckResult(
        "residual_pct",
        False,
        f"{', '.join(f'{k} {side(got[k], ref[k])}' for k in bad)} beyond the tolerance (3 "
        "percentage points, or a quarter of the value): simulate your identified model "
        "(fit.model()) with each run's applied voltage (lab.load_deflection) and compare "
        "residual_amplitude with the unshaped run's.",
    )


def _drifted(f, z):
    return {
        k: float(shaping.input_shaper(k, f, z).residual_vibration((1 - MODE_DRIFT) * f, z))
        for k in KINDS4
    }


def check_robust(answer, evidence, truth):
    if not isinstance(answer, dict):
        raise Missing('robust: answer a dict {"zv": ..., "zvd": ..., "ei": ...} of percentages.')
    got = {k: number(f"robust[{k!r}]", answer.get(k)) for k in KINDS4}
    f, z, _, src = _truth4(evidence, truth)
    ref = _drifted(f, z)
    tol = {k: max(1.5, 0.15 * ref[k]) for k in KINDS4}
    if all(abs(got[k] - ref[k]) <= tol[k] for k in KINDS4):
        return CheckResult(
            "robust",
            True,
            "within the tolerance (1.5 points, or 15 % of the value) of "
            f"the shapers designed for {src}, on a mode {100 * MODE_DRIFT:.0f} % lower. ZV "
            "leaves a large part of the vibration; ZVD and EI, whose curves are flat around "
            "the design frequency, keep it small.",
        )
    up = {
        k: float(shaping.input_shaper(k, f, z).residual_vibration((1 + MODE_DRIFT) * f, z))
        for k in KINDS4
    }
    if all(abs(got[k] - up[k]) <= tol[k] for k in KINDS4):
        return CheckResult(
            "robust",
            False,
            "that is a mode 15 % *higher*: a heavier load lowers the frequency, f·(1 − 0.15).",
        )
    if all(abs(100 * got[k] - ref[k]) <= tol[k] for k in KINDS4):
        return CheckResult(
            "robust", False, "residual_vibration already returns percent: do not scale it."
        )
    at_design = {k: float(shaping.input_shaper(k, f, z).residual_vibration(f, z)) for k in KINDS4}
    if all(abs(got[k] - at_design[k]) <= tol[k] for k in KINDS4):
        return CheckResult(
            "robust",
            False,
            "that is the vibration at the design frequency, where each shaper "
            "was made to work: evaluate at the lower mode, (1 − 0.15)·f.",
        )
    return CheckResult(
        "robust",
        False,
        "evaluate each shaper you designed for your mode at the lower "
        "frequency: zv.residual_vibration(0.85 * f, ζ), the same for zvd and ei.",
    )


def check_choice(answer, evidence, truth):
    a = str(answer).strip().lower()
    if a not in KINDS4:
        raise Missing(f"choice: answer one of {', '.join(repr(k) for k in KINDS4)}.")
    f, z, _, _ = _truth4(evidence, truth)
    left = _drifted(f, z)
    best = min(KINDS4, key=lambda k: left[k])
    if a == best:
        return CheckResult(
            "choice",
            True,
            f"{a.upper()} leaves the least vibration on the heavier load: its "
            "sensitivity curve is flattest around the design frequency. It costs about one "
            "period of delay per move, twice ZV's.",
        )
    if a == "zv":
        return CheckResult(
            "choice",
            False,
            "ZV is the shortest, but on a mode 15 % off it leaves a fifth of "
            "the vibration: compare your `robust` numbers.",
        )
    return CheckResult(
        "choice",
        False,
        f"{a.upper()} is good, but another shaper of about the same length "
        "leaves less on the lower mode: compare your `robust` numbers.",
    )


def predicted_mode(load, profile, fit, ax=None):
    """Lab 4 B1b: the mode :func:`jerklab.rig.flexload.predict` gives for the load's build next
    to the one identified from the encoder, printed and drawn (like notebook 09, section 8).

    Parameters
    ----------
    load : dict or None
        ``RulerLoad`` keywords (``S.spec["load"]``); None on a profile without a stall current:
        then nothing is predicted and None is returned.
    profile : jerklab.rig.profiles.MotorProfile
        The rig's motor (``S.profile``).
    fit : jerklab.shaping.ModeFit
        The identified mode (``shaping.identify_mode``).
    ax : matplotlib Axes, optional
        Where to draw the two models' speed responses |ω/u|; a new figure by default.

    Returns
    -------
    dict or None
        :func:`jerklab.rig.flexload.predict`'s result, and ``ratio`` (identified / predicted
        coupled mode).
    """
    if load is None:
        print(
            "no predicted mode: this profile states no stall current (the motor's inertia is unknown)"
        )
        return None
    pred = predict(RulerLoad(**load), profile)
    built = FlexibleDCMotor(
        K=pred["K"],
        tau=pred["tau"],
        load_ratio=pred["load_ratio"],
        mode_frequency=pred["mode_frequency"],
        mode_damping=pred["damping"],
        supply_voltage=profile.supply_voltage,
    )
    f_p, f_i = pred["coupled_hz"], float(fit.frequency_hz)
    pred["ratio"] = f_i / f_p
    print(
        f"predicted from the build: {f_p:.2f} Hz at the encoder ({pred['mode_hz']:.2f} Hz with "
        f"the hub held, J_l/J_m = {pred['load_ratio']:.2f}); identified: {f_i:.2f} ± "
        f"{fit.frequency_se:.2f} Hz (identified / predicted = {pred['ratio']:.2f})"
    )
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3.5))
    fr = np.linspace(1.0, 40.0, 400)
    for label, m, style in (
        ("predicted model (flexload.predict)", built, "-"),
        ("identified model (encoder, identify_mode)", fit.model(), "--"),
    ):
        ax.semilogy(fr, np.abs(m.velocity_tf()(2j * np.pi * fr)), style, label=label)
    ax.axvline(f_p, color="C0", lw=0.8, ls=":")
    ax.axvline(f_i, color="C1", lw=0.8, ls="-.")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("|ω / u| (rad/(V s))")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    ax.set_title(f"Predicted mode {f_p:.1f} Hz vs identified from the encoder {f_i:.1f} Hz")
    return pred
