"""Lab 5, "Your own law": the student writes Stojčić eqs. 16–18 in Python and closes the loop.

The student's law (feedforward of Stojčić eq. 16, the discrete PID of Stojčić eqs. 17, 18, the
output clamp and conditional-integration anti-windup; ASCII: Stojcic eqs. 16–18) runs through the
rig's host-in-the-loop mode (``board.host_loop``) at Ts = 10 ms; the firmware runs its own law on
the same move (``board.run_move``). In the host loop the voltage the law computes from the sample
at t = k Ts is applied at tick k + 1 (a whole Ts later); the board's own law applies it about
0.13 ms after the sample. So the two recordings are not equal, only close: within
:data:`MATCH_COUNTS` encoder counts on the lab's move (``lab_spec(5)["match_counts"]``, the
bound's source in :data:`jerklab.lab.specs.MATCH_COUNTS_5`; on the gentler move of
tests/test_hostloop.py the two stay within 4 counts).

The lab's clamp is set low on purpose (f_c + max|u_F|, ``lab_spec(5)["limit_share"]``, no
headroom for the PID's corrections): the output saturates while the move is at its fastest, so
that the anti-windup acts and a law whose anti-windup is reversed or missing winds its
integrator up and overshoots.

The checks (``check_<name>(answer, evidence, truth)``, pure functions like those of
:mod:`jerklab.lab.ringing`) explain a mismatch from the recordings themselves: the checker replays
candidate laws on the positions the host run recorded (:func:`replay`) and names the one whose
voltages the run applied (:func:`diagnose`): the right law, the error's sign reversed, the
anti-windup freezing the integrator in the wrong direction (or not at all), or the continuous
gains used as discrete ones (the discretization of Stojčić eq. 13 left out).
"""

from __future__ import annotations

import math

import numpy as np

from jerklab.controller import DiscreteGains, pole_placement_pid
from jerklab.lab.checkbase import CheckResult, Missing, Mistake, number, rel, run_of, side
from jerklab.lab.specs import MATCH_COUNTS_5, lab_spec
from jerklab.rig.profiles import load_profile

__all__ = [
    "TS5",
    "MATCH_COUNTS",
    "LAWS5",
    "MISTAKES5",
    "replay",
    "diagnose",
    "feedforward_table",
]

#: Lab 5's control period (s)
TS5 = 0.01
#: |host-closed − firmware-closed| (counts) at every sample of the lab's move when the laws match
#: (:data:`jerklab.lab.specs.MATCH_COUNTS_5`, where it was measured)
MATCH_COUNTS = MATCH_COUNTS_5
#: the candidate laws :func:`diagnose` tells apart
LAWS5 = ("pid", "sign", "aw_reversed", "no_aw", "continuous", "p", "pd")

MISTAKES5 = {
    "pre_ff_no_accel": Mistake(
        5,
        "pre_ff",
        "the feedforward without τ·a",
        "the velocity term alone",
        "the τ·a term is missing",
    ),
    "pre_delay_board": Mistake(
        5, "pre_delay", "the host's voltage applied at once", "0 ms", "that is the board's own law"
    ),
    "match_sign": Mistake(
        5, "match", "the error's sign reversed", "e = y − r", "your error has the wrong sign"
    ),
    "match_aw_reversed": Mistake(
        5,
        "match",
        "anti-windup in the wrong direction",
        "the integrator frozen when the error pulls out of the clamp",
        "your anti-windup freezes the integrator in the wrong direction",
    ),
    "law_continuous": Mistake(
        5,
        "law",
        "the continuous gains in the law's parameters",
        "kid = ki, kdd = kd",
        "these are the continuous gains",
    ),
    "match_continuous": Mistake(
        5,
        "match",
        "continuous gains in the discrete law",
        "ki, kd for kid, kdd",
        "you used the continuous gains ki and kd",
    ),
}


def feedforward_table(profile, n, Ts, K, tau):
    """Stojčić eq. 16's ``u_F = (τ a_r + v_r)/K`` (V) at the ticks 0..n of ``profile``."""
    s = profile.sample(np.arange(n + 1) * Ts)
    return (tau * np.asarray(s.accel, float) + np.asarray(s.velocity, float)) / K


def replay(law, position, reference, ff, gains, limit):
    """The voltages (V) candidate ``law`` (one of :data:`LAWS5`) computes from the recorded
    ``position`` and ``reference`` (rad) at each tick, with feedforward ``ff`` (V) and the
    discrete ``gains`` (``kpd``, ``kid``, ``kdd``; ``Ts``): Stojčić eqs. 16–18, clamped to
    ``±limit``, varied as the name says."""
    kpd, kid, kdd = gains.kpd, gains.kid, gains.kdd
    if law == "continuous":  # ki = kid/Ts, kd = kdd·Ts used as the discrete gains
        kid, kdd = kid / gains.Ts, kdd * gains.Ts
    if law in ("p", "pd"):
        kid = 0.0
    if law == "p":
        kdd = 0.0
    out = np.empty(len(position))
    i = e_prev = 0.0
    for k, (y, r) in enumerate(zip(position, reference)):
        e = (y - r) if law == "sign" else (r - y)
        i_new = i + kid * e
        u = ff[k] + kpd * e + i_new + kdd * (e - e_prev)
        hi, lo = u > limit, u < -limit
        if law == "aw_reversed":
            freeze = (hi and e < 0) or (lo and e > 0)
        elif law == "no_aw":
            freeze = False
        else:
            freeze = (hi and e > 0) or (lo and e < 0)
        if freeze:
            u, i_new = u - kid * e, i
        out[k] = min(max(u, -limit), limit)
        i, e_prev = i_new, e
    return out


def diagnose(run, ff, gains, limit, laws=LAWS5):
    """Which candidate law a host-loop ``run`` (:class:`jerklab.lab.plain.Run`) applied:
    ``(name, rms)`` of the candidate whose replayed voltage at tick k is closest (RMS, V) to
    the voltage the run applied at tick k + 1 (the host loop's one tick), over the ticks whose
    answer came in time and applied (no ``HOST_SAMPLE_MISSED`` flag, bit 0, nor the fault's,
    bit 2, of ``jerklab.protocol``)."""
    v = np.asarray(run.voltage, float)
    timely = (np.asarray(run.flags)[1:] & 5) == 0
    best = None
    for law in laws:
        u = replay(law, run.position, run.reference, ff, gains, limit)[:-1]
        u = np.clip(u, -limit, limit)
        d = (v[1:] - u)[timely]
        rms = float(np.sqrt(np.mean(d * d))) if d.size else math.inf
        if best is None or rms < best[1]:
            best = (law, rms)
    return best


def _counts_apart(a, b, counts_per_rev):
    cpr = counts_per_rev / (2 * math.pi)
    m = min(len(a.position), len(b.position))
    return float(np.max(np.abs(np.asarray(a.position[:m]) - np.asarray(b.position[:m]))) * cpr)


# ------------------------------------------------------------------ pre-lab
#: the pre-lab's numbers: K (rad/(V s)), τ (s), v_r (rad/s), a_r (rad/s²)
PRE_FF = (32.4, 0.025, 10.0, 200.0)


def check_pre_ff(answer, evidence, truth):
    """Stojčić eq. 16 at :data:`PRE_FF`: ``(τ a + v)/K``."""
    x = number("pre_ff", answer)
    K, tau, v, a = PRE_FF
    ref = (tau * a + v) / K
    if rel(x, ref) < 0.01:
        return CheckResult(
            "pre_ff",
            True,
            "u_F = (τ·a + v)/K: the voltage the model needs for that speed and acceleration; "
            "the PID only corrects what the model misses.",
        )
    if rel(x, v / K) < 0.01:
        return CheckResult(
            "pre_ff", False, f"{MISTAKES5['pre_ff_no_accel'].hint}: the motor's inertia needs it."
        )
    if rel(x, (tau * a + v) * K) < 0.01:
        return CheckResult("pre_ff", False, "divide by K (rad/(V s)), do not multiply: volts.")
    return CheckResult("pre_ff", False, f"{side(x, ref)}: Stojčić eq. 16, u_F = (τ·a + v)/K.")


def check_pre_delay(answer, evidence, truth):
    """The host loop's delay (ms) at Ts = 10 ms: the answer to sample k applies at tick k + 1."""
    x = number("pre_delay", answer)
    ref = TS5 * 1e3
    if abs(x - ref) <= 0.5:
        return CheckResult(
            "pre_delay",
            True,
            "one whole tick: the device applies your answer to sample k at tick k + 1; the "
            "board's own law applies its voltage about 0.13 ms after the sample.",
        )
    if abs(x) <= 0.5:
        return CheckResult(
            "pre_delay",
            False,
            f"{MISTAKES5['pre_delay_board'].hint}: your answer travels over the link and waits "
            "for the next tick.",
        )
    if abs(x - 0.01) < 1e-3:
        return CheckResult("pre_delay", False, "milliseconds, not seconds.")
    return CheckResult("pre_delay", False, f"{side(x, ref)}: when does tick k + 1 start?")


# ------------------------------------------------------------------ on the rig
def _setup(evidence, answer_name="law"):
    """(gains, ff, limit) the runs used, from the earlier answer ``law`` (a dict of ``kpd``,
    ``kid``, ``kdd``, ``Ts``, ``K``, ``tau``, ``limit``), ff on the ``board`` run's ticks."""
    law = evidence.answers.get(answer_name)
    if not isinstance(law, dict):
        raise Missing("law: record the law's parameters first (S.verify('law', ...)).")
    try:
        g = DiscreteGains(float(law["kpd"]), float(law["kid"]), float(law["kdd"]), float(law["Ts"]))
        K, tau, limit = float(law["K"]), float(law["tau"]), float(law["limit"])
    except (KeyError, TypeError, ValueError) as exc:
        raise Missing(f"law: the parameters are incomplete ({exc}).") from None
    return g, K, tau, limit


def _ff_of(run, K, tau):
    """Stojčić eq. 16 from the run's own reference, by differences (the profile is not in the
    evidence): velocity and acceleration of the recorded reference."""
    r = np.asarray(run.reference, float)
    Ts = run.Ts
    v = np.gradient(r, Ts)
    a = np.gradient(v, Ts)
    return (tau * a + v) / K


def _spec(evidence):
    return lab_spec(5, evidence.profile or "paper")


def check_law(answer, evidence, truth):
    """``answer``: the law's parameters, ``{"kpd", "kid", "kdd", "Ts", "K", "tau", "limit"}``:
    right when ``Ts`` is the lab's, the gains are the lab's design (Stojčić eq. 11 at
    ``design_wn``, discretized by Stojčić eq. 13) for the ``K`` and ``τ`` given, and the clamp is a
    positive voltage within the supply. (The model itself is not judged here: both runs use the
    same one.)"""
    if not isinstance(answer, dict):
        raise Missing('law: answer a dict {"kpd", "kid", "kdd", "Ts", "K", "tau", "limit"}.')
    try:
        x = {k: float(answer[k]) for k in ("kpd", "kid", "kdd", "Ts", "K", "tau", "limit")}
    except KeyError as exc:
        raise Missing(f"law: the parameters have no {exc.args[0]!r}.") from None
    spec = _spec(evidence)
    Ts = spec["Ts"]
    if abs(x["Ts"] - Ts) > 1e-9:
        if abs(x["Ts"] - 1e3 * Ts) < 1e-6:
            return CheckResult("law", False, "Ts in seconds, not milliseconds.")
        return CheckResult("law", False, f"Ts is {x['Ts']!r} s: lab 5 runs at {Ts:g} s.")
    if not (x["K"] > 0 and x["tau"] > 0):
        return CheckResult("law", False, "K and τ are positive: your identified model.")
    g = pole_placement_pid(x["K"], x["tau"], spec["design_wn"], spec["zeta"])
    d = g.discretize(Ts)

    def near(a, b):
        return abs(a - b) <= 1e-3 * max(abs(b), 1e-3)

    if near(x["kpd"], d.kpd) and near(x["kid"], g.ki) and near(x["kdd"], g.kd):
        return CheckResult(
            "law",
            False,
            f"{MISTAKES5['law_continuous'].hint} ki, kd: the discrete law takes kid = ki·Ts and "
            "kdd = kd/Ts (Stojčić eq. 13), the gains' .discretize(Ts).",
        )
    if not (near(x["kpd"], d.kpd) and near(x["kid"], d.kid) and near(x["kdd"], d.kdd)):
        return CheckResult(
            "law",
            False,
            f"the gains are not the lab's design for your K and τ: "
            f"pole_placement_pid(K, tau, {spec['design_wn']:g}).discretize({Ts:g}) "
            "(Stojčić eqs. 11, 13).",
        )
    supply = load_profile(evidence.profile or "paper").supply_voltage
    if not 0 < x["limit"] <= supply:
        return CheckResult(
            "law", False, f"the clamp is a voltage between 0 and the supply ({supply:g} V)."
        )
    return CheckResult(
        "law",
        True,
        "the lab's gains for your model and a clamp: give the board the same K and τ "
        "(S.set_model) and the same clamp (max_voltage).",
    )


def check_match(answer, evidence, truth):
    """``answer``: the largest distance (counts) between the ``mine`` (host loop, the
    student's law) and ``board`` (run_move) recordings; right when it is the recordings' own,
    within the bound (``lab_spec(5)["match_counts"]``) and the voltages the host run applied are
    those of Stojčić eqs. 16–18 with the anti-windup (:func:`diagnose`); otherwise the mismatch
    is named from the ``mine`` run: the error's sign, the anti-windup reversed or missing, the
    continuous gains."""
    x = number("match", answer)
    board, mine = run_of(evidence, "board"), run_of(evidence, "mine")
    cpr = evidence.counts_per_rev or 448
    bound = _spec(evidence)["match_counts"]
    apart = _counts_apart(mine, board, cpr)
    if abs(x - apart) > 1.0 + 0.05 * apart:
        return CheckResult(
            "match",
            False,
            f"{side(x, apart)} for your recordings: the largest |mine.position − "
            "board.position| over the run, in counts (× counts per rev / 2π).",
        )
    g, K, tau, limit = _setup(evidence)
    law, _ = diagnose(
        mine, _ff_of(mine, K, tau), g, limit, ("pid", "sign", "aw_reversed", "continuous", "no_aw")
    )
    if apart <= bound and law == "pid":
        return CheckResult(
            "match",
            True,
            f"within {bound} counts of the board's own law: the same law. What is left "
            "is the host loop's extra tick of delay (your voltage applies at k + 1).",
        )
    aw = (
        f"{MISTAKES5['match_aw_reversed'].hint} (or not at all): keep i(k−1) only while the "
        "error pushes further into the clamp (u > limit and e > 0, or u < −limit and e < 0); "
        "otherwise the integrator winds up while the output is clamped."
    )
    why = {
        "sign": f"{MISTAKES5['match_sign'].hint}: e = r − y (reference minus position).",
        "aw_reversed": aw,
        "no_aw": aw,
        "continuous": f"{MISTAKES5['match_continuous'].hint}: the discrete law takes "
        "kid = ki·Ts and kdd = kd/Ts (Stojčić eq. 13).",
        "pid": "your voltages are those of Stojčić eqs. 16–18 tick by tick, yet the runs "
        "differ: run both on the same move, gains, clamp and feedforward model.",
    }[law]
    if law == "pid":
        return CheckResult("match", False, f"more than {bound} counts apart. {why}")
    where = f"more than {bound} counts apart" if apart > bound else f"{apart:.0f} counts apart"
    return CheckResult("match", False, f"{where}, and not the same law. {why}")


def check_variant(answer, evidence, truth):
    """``answer``: ``{"law": "p" | "pd" | "no_aw", "max_error": rad}`` of the ``variant`` run
    (the law changed); right when the run applied that law and ``max_error`` is its largest
    |r − y| (5 %)."""
    if not isinstance(answer, dict) or answer.get("law") not in ("p", "pd", "no_aw"):
        raise Missing('variant: answer {"law": "p", "pd" or "no_aw", "max_error": rad}.')
    x = number("variant['max_error']", answer.get("max_error"))
    run = run_of(evidence, "variant")
    g, K, tau, limit = _setup(evidence)
    law, _ = diagnose(run, _ff_of(run, K, tau), g, limit, ("pid", "p", "pd", "no_aw"))
    if law != answer["law"]:
        return CheckResult(
            "variant",
            False,
            f"the run's voltages are those of the {law!r} law, not {answer['law']!r}: run the "
            "law you name.",
        )
    err = float(np.max(np.abs(np.asarray(run.reference) - np.asarray(run.position))))
    if rel(x, err) > 0.05:
        return CheckResult(
            "variant",
            False,
            f"max_error is {side(x, err)} for your run: the largest |reference − position| (rad).",
        )
    return CheckResult(
        "variant",
        True,
        "the law you changed, and its tracking error read from the run: compare it with the "
        "full law's and say which term did the work.",
    )
