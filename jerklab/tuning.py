"""The tuning panel's computations: design, stability, advice and simulation (no widgets).

Stojčić (ASCII: Stojcic) position loop: plant P(s) = K / (s (τ s + 1)) (Stojčić eq. 1), PID
placed by Stojčić eq. 11 and discretized by Stojčić eq. 13, or placed directly in z on the
ZOH plant. :mod:`jerklab.widgets` only builds the widgets and draws what these functions
return; a script or a lab worksheet can call them without ipywidgets or matplotlib.

Every result is cached on its parameters (:func:`functools.lru_cache`), so moving a slider
back to a value already seen costs nothing; the cached arrays are read-only.
:func:`clear_cache` empties the caches (the benchmarks do, to time the computation).

Main entry points
-----------------
* :func:`compute_pole_placement` — every curve the panel shows for one setting.
* :func:`closed_loop_max_radius` — the largest ``|z|`` of a sampled loop; the single place where
  "may this design run on a rig?" is decided (:func:`check_runnable` refuses ``|z|`` ≥ 1).
* :func:`advise` — which slider changes or other design would make an unstable or nearly
  unstable loop stable, each candidate checked by computing its loop.
* :func:`format_angle`, :func:`angle_unit`, :func:`gain_table` — numbers with units that scale.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from jerklab import controller as ctl
from jerklab import paper
from jerklab._validate import as_nonnegative, as_positive
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.sim import simulate

__all__ = [
    "DESIGNS",
    "DESIGN_NAMES",
    "DEFAULT_MOVE",
    "SLIDER_RANGES",
    "TuningResult",
    "Suggestion",
    "UnstableDesignError",
    "design_gains",
    "closed_loop_max_radius",
    "check_runnable",
    "stability_verdict",
    "advise",
    "compute_pole_placement",
    "move_profile",
    "continuous_equivalent",
    "gain_table",
    "angle_unit",
    "format_angle",
    "clear_cache",
]

#: The designs the panel offers: label -> key.
DESIGNS = {
    "continuous (Stojčić eq. 11) discretized by Stojčić eq. 13": "continuous",
    "direct z-domain (poles at z = exp(s Ts))": "z-domain",
    "z-domain, all 4 poles placed (derivative filter γ)": "z-domain-filter",
}

#: Short names of the designs for messages and titles.
DESIGN_NAMES = {
    "continuous": "Stojčić eq. 11 + Stojčić eq. 13 design",
    "z-domain": "direct z-domain design",
    "z-domain-filter": "z-domain design with derivative filter",
}

#: Default move for the tracking plot: Stojčić's sine-jerk planner, rad and s.
DEFAULT_MOVE = dict(distance=10.0, max_jerk=5000.0, max_accel=300.0, max_velocity=60.0)

#: Input-referred step load disturbance of the disturbance plot (V), Stojčić eq. 9 with W = P.
DISTURBANCE_VOLTS = 1.0

#: Diverging responses are clipped to this (mrad) in the plots (the verdict says why).
CLIP_MRAD = 2000.0

#: A loop whose largest |z| is above this is flagged as "near instability".
NEAR_UNSTABLE_RADIUS = 0.98

#: The panel's slider ranges (min, max, step); :func:`advise` only proposes reachable values.
SLIDER_RANGES = dict(
    zeta=(0.3, 2.0, 0.05),
    wn=(2.0, 100.0, 1.0),
    sigma_ratio=(1.0, 15.0, 0.5),
    Ts_ms=(1.0, 20.0, 1.0),
)


class UnstableDesignError(ValueError):
    """A design whose sampled loop has a closed-loop pole at ``|z|`` ≥ 1 was asked to run."""

    def __init__(self, message, max_radius=None, design=None):
        super().__init__(message)
        self.max_radius = max_radius
        self.design = design


# --------------------------------------------------------------------------------------
# design and stability
# --------------------------------------------------------------------------------------
def _check_design_key(design):
    if design not in DESIGN_NAMES:
        raise ValueError(f"design must be one of {sorted(DESIGN_NAMES)}, got {design!r}")
    return design


def design_gains(K, tau, zeta, wn, sigma_ratio, Ts, design="continuous"):
    """The discrete gains of one design (and the continuous ones when there are some).

    Parameters
    ----------
    K, tau : float
        Plant of Stojčić eq. 1, rad/(V·s) and s.
    zeta, wn, sigma_ratio : float
        Damping ratio, natural frequency (rad/s) and the real pole σ as a multiple of ωn.
    Ts : float
        Sampling period (s).
    design : {"continuous", "z-domain", "z-domain-filter"}
        ``"continuous"``: :func:`jerklab.controller.pole_placement_pid` (Stojčić eq. 11) then
        ``.discretize(Ts)`` (Stojčić eq. 13), as the paper. ``"z-domain"``:
        :func:`jerklab.controller.discrete_pole_placement_pid`, three poles placed at
        z = exp(s Ts), the fourth where the algebra puts it. ``"z-domain-filter"``: the same
        with a derivative filter pole γ, all four poles placed (the fourth at z = 0).

    Returns
    -------
    (DiscreteGains, Gains or None)
    """
    _check_design_key(design)
    sigma = sigma_ratio * wn
    if as_positive("sigma_ratio", sigma_ratio) < ctl.SIGMA_MIN_RATIO:  # named here, not as sigma
        raise ValueError(
            f"sigma_ratio must be >= controller.SIGMA_MIN_RATIO = {ctl.SIGMA_MIN_RATIO:g}, "
            f"got {sigma_ratio!r}"
        )
    if design == "continuous":
        g = ctl.pole_placement_pid(K, tau, wn, zeta=zeta, sigma=sigma)
        return g.discretize(Ts), g
    extra = 0.0 if design == "z-domain-filter" else None
    return ctl.discrete_pole_placement_pid(
        K, tau, wn, zeta=zeta, sigma=sigma, Ts=Ts, extra_pole=extra
    ), None


def closed_loop_max_radius(K, tau, gains, Ts=None):
    """Largest ``|z|`` of the closed-loop poles of the sampled position loop.

    The loop is the ZOH plant of Stojčić eq. 1 under the discrete PID of Stojčić eq. 12
    (with the derivative filter γ of ``gains``); it is stable iff the result is < 1. This is
    the one function that decides whether a design may run on a rig (:func:`check_runnable`).

    Parameters
    ----------
    K, tau : float
        The plant the gains are meant for.
    gains : jerklab.controller.DiscreteGains or Gains
        Continuous gains need ``Ts`` (they are discretized by Stojčić eq. 13).
    Ts : float, optional

    Returns
    -------
    float
    """
    K = as_positive("K", K)
    tau = as_positive("tau", tau)
    if isinstance(gains, ctl.Gains):
        if Ts is None:
            raise ValueError(
                "Ts is needed to check continuous gains (they run discretized by Stojčić eq. 13)"
            )
        gains = gains.discretize(Ts)
    elif not isinstance(gains, ctl.DiscreteGains):
        raise TypeError(f"gains must be DiscreteGains or Gains, got {type(gains).__name__}")
    if gains.loop != "position":
        raise ValueError(f"gains.loop must be 'position' for this check, got {gains.loop!r}")
    with np.errstate(all="ignore"):
        if hasattr(ctl, "max_pole_radius"):  # the controller's own check (rig.run_move's)
            r = ctl.max_pole_radius(K, tau, gains)
        else:
            r = ctl.PositionLoop(K, tau, gains).max_pole_radius()
    return float(r) if math.isfinite(r) else math.inf


def check_runnable(K, tau, gains, Ts=None, *, force=False, design=None):
    """Refuse a design whose sampled loop is unstable (largest ``|z|`` ≥ 1) unless ``force``.

    Returns the largest ``|z|``. Raises :class:`UnstableDesignError` (a ValueError) naming the
    radius and the design, so nothing is sent to a motor that would run away.
    """
    r = closed_loop_max_radius(K, tau, gains, Ts)
    if r >= 1.0 and not force:
        name = DESIGN_NAMES.get(design, "design")
        raise UnstableDesignError(
            f"refused: the sampled loop of the {name} has a closed-loop pole at |z| = {r:.3f} ≥ 1 "
            f"(unstable) for K = {K:g} rad/(V·s), tau = {1e3 * tau:g} ms; change the design "
            "(force=True runs it anyway)",
            max_radius=r,
            design=design,
        )
    return r


def stability_verdict(max_radius, desired_radius, Ts=None, sigma=None):
    """Classify a sampled loop from its largest closed-loop pole radius.

    Parameters
    ----------
    max_radius : float
        Largest ``|z|`` of the closed-loop poles actually obtained.
    desired_radius : float
        Largest ``|z|`` of the designed poles mapped by z = exp(s Ts).
    Ts, sigma : float, optional
        Used only to add the σ·Ts figure to the message.

    Returns
    -------
    level : {"ok", "near", "unstable"}
        ``"unstable"`` when ``|z|`` >= 1; ``"near"`` when ``|z|`` > ``NEAR_UNSTABLE_RADIUS`` and the
        sampled loop lost more than half of the stability margin (1 - ``|z|``) that the design
        asked for (a slow design is not flagged just because its poles are slow).
    message : str
        What the loop does; what would help is :func:`advise`'s job (it depends on the design).
    """
    r = as_nonnegative("max_radius", max_radius)  # |z| of a pole: never negative
    rd = as_nonnegative("desired_radius", desired_radius)
    extra = ""
    if Ts is not None and sigma is not None:
        extra = f" (σ·Ts = {sigma * Ts:.2f})"
    if r >= 1.0:
        return "unstable", f"UNSTABLE: the sampled loop has a pole at |z| = {r:.3f} ≥ 1{extra}."
    margin, margin_designed = 1.0 - r, 1.0 - rd
    if r > NEAR_UNSTABLE_RADIUS and margin < 0.5 * margin_designed:
        return "near", (
            f"Near instability: largest |z| = {r:.3f} (designed {rd:.3f}){extra}. "
            "A smooth reference with feedforward hides it; a step or a disturbance "
            "rings for a long time."
        )
    return "ok", f"Stable: largest |z| = {r:.3f} (designed {rd:.3f}){extra}."


def _desired(zeta, wn, sigma_ratio, Ts):
    sigma = sigma_ratio * wn
    poles = np.roots(np.polymul([1.0, sigma], [1.0, 2.0 * zeta * wn, wn * wn]))
    return poles, np.exp(poles * Ts)


@functools.lru_cache(maxsize=4096)
def _level(K, tau, zeta, wn, sigma_ratio, Ts, design):
    """(level, max ``|z|``) of one setting; inf when the design cannot be built."""
    try:
        d, _ = design_gains(K, tau, zeta, wn, sigma_ratio, Ts, design)
        r = closed_loop_max_radius(K, tau, d)
    except (ValueError, np.linalg.LinAlgError):
        return "unstable", math.inf
    _, zd = _desired(zeta, wn, sigma_ratio, Ts)
    level, _ = stability_verdict(min(r, 1e300), float(np.max(np.abs(zd))))
    return level, r


@dataclass(frozen=True)
class Suggestion:
    """One checked change that makes the loop stable and not near instability.

    ``change`` names the parameter (``"wn"``, ``"Ts"``, ``"sigma_ratio"``, ``"design"``),
    ``value`` its new value (SI, or the design key), ``max_radius`` the largest ``|z|`` there,
    ``text`` the sentence shown.
    """

    change: str
    value: object
    max_radius: float
    text: str


def _grid_below(value, lo, step, hi):
    """Slider values below ``value`` down to ``lo``, nearest first (none above the slider's ``hi``)."""
    value = min(
        value, hi + step
    )  # a value far above the slider (wn = 1e9) must not build 1e9 values
    n = int(math.floor((value - lo) / step + 1e-9))
    vals = [round(lo + k * step, 10) for k in range(n, -1, -1)]
    return [v for v in vals if v < value - 1e-9]


def _first_ok(values, ok):
    """The first value of ``values`` (nearest first) for which ``ok(v)`` holds.

    Scans every 4th value, then the skipped ones just before the hit, so the result is the
    nearest good value in ~n/4 evaluations when goodness does not flicker.
    """
    coarse = list(range(0, len(values), 4))
    for j, i in enumerate(coarse):
        if ok(values[i]):
            start = coarse[j - 1] + 1 if j else 0
            for k in range(start, i):
                if ok(values[k]):
                    return values[k]
            return values[i]
    return None


@functools.lru_cache(maxsize=512)
def _advise(K, tau, zeta, wn, sigma_ratio, Ts, design):
    out = []

    def ok(**change):
        p = dict(zeta=zeta, wn=wn, sigma_ratio=sigma_ratio, Ts=Ts, design=design)
        p.update(change)
        return _level(K, tau, p["zeta"], p["wn"], p["sigma_ratio"], p["Ts"], p["design"])

    lo, hi, step = SLIDER_RANGES["wn"]
    w = _first_ok(_grid_below(wn, lo, step, hi), lambda v: ok(wn=v)[0] == "ok")
    if w is not None:
        r = ok(wn=w)[1]
        out.append(Suggestion("wn", w, r, f"ωn ≤ {w:g} rad/s (|z| = {r:.3f})"))
    lo, hi, step = SLIDER_RANGES["Ts_ms"]
    t = _first_ok(_grid_below(1e3 * Ts, lo, step, hi), lambda v: ok(Ts=1e-3 * v)[0] == "ok")
    if t is not None:
        r = ok(Ts=1e-3 * t)[1]
        out.append(Suggestion("Ts", 1e-3 * t, r, f"Ts ≤ {t:g} ms (|z| = {r:.3f})"))
    lo, hi, step = SLIDER_RANGES["sigma_ratio"]
    s = _first_ok(_grid_below(sigma_ratio, lo, step, hi), lambda v: ok(sigma_ratio=v)[0] == "ok")
    if s is not None:
        r = ok(sigma_ratio=s)[1]
        out.append(Suggestion("sigma_ratio", s, r, f"σ/ωn ≤ {s:g} (|z| = {r:.3f})"))
    for other in DESIGN_NAMES:
        if other != design:
            level, r = ok(design=other)
            if level == "ok":
                out.append(
                    Suggestion("design", other, r, f"the {DESIGN_NAMES[other]} (|z| = {r:.3f})")
                )
    return tuple(out)


def advise(K, tau, zeta, wn, sigma_ratio, Ts, design="continuous"):
    """What would make this loop stable and well clear of instability, each candidate checked.

    Starting from the given setting, one change at a time within the panel's slider ranges
    (:data:`SLIDER_RANGES`): the largest ωn below the current one, the largest Ts below the
    current one, the largest σ/ωn below the current one, and every other design at the
    same setting. A candidate is kept only if its sampled loop, computed like the current one,
    is rated ``"ok"`` by :func:`stability_verdict`. So the advice never recommends the design
    that is failing, nor a change that does not help.

    Returns
    -------
    tuple of Suggestion
        Empty when no single change helps.
    """
    K, tau, zeta, wn, sigma_ratio, Ts = _validated(K, tau, zeta, wn, sigma_ratio, Ts)
    return _advise(K, tau, zeta, wn, sigma_ratio, Ts, _check_design_key(design))


def _advice_text(level, design, suggestions):
    if level == "ok":
        return ""
    if not suggestions:
        return (
            "No single change of ωn, Ts, σ/ωn or design within the sliders' ranges makes it "
            "stable and well damped; try another ζ."
        )
    return "What would help (checked): " + "; ".join(s.text for s in suggestions) + "."


# --------------------------------------------------------------------------------------
# the whole panel's numbers
# --------------------------------------------------------------------------------------
@dataclass
class TuningResult:
    """Everything the panel shows for one setting of the sliders.

    Attributes
    ----------
    params : dict
        ``K, tau, zeta, wn, sigma_ratio, sigma, Ts, design``.
    gains : jerklab.controller.DiscreteGains
        The discrete gains of the chosen design (what ``rig.run_move`` accepts).
    continuous_gains : object or None
        The Stojčić eq. 11 gains (``kp, ki, kd``) when the continuous design is chosen.
    poles_s_desired : ndarray
        Roots of (s + σ)(s² + 2ζωn s + ωn²), the designed closed-loop poles.
    poles_z : ndarray
        Closed-loop poles of the sampled loop (ZOH plant + discrete PID).
    poles_z_desired : ndarray
        ``exp(s Ts)`` of the designed poles.
    poles_s_equivalent : ndarray
        ``log(z) / Ts`` of the achieved poles (where the sampled loop really puts them).
    max_radius, desired_radius : float
        Largest ``|z|`` achieved and designed.
    stable : bool
    level, message : str
        ``"ok" | "near" | "unstable"`` and the verdict sentence.
    advice : tuple of Suggestion
        Checked changes that would help (empty when ``level == "ok"``).
    advice_text : str
        The advice as a sentence (empty when ``level == "ok"``).
    t_step, y_step : ndarray
        Unit step response reference -> position of the sampled loop (no feedforward).
    t_dist, y_dist : ndarray
        Position (rad) after a step load disturbance of ``DISTURBANCE_VOLTS`` at the plant input.
        Both responses run to 3 × ``t_view``. For a loop with ``level == "unstable"`` they grow
        without bound and may overflow to inf/NaN (the plots clip them).
    t_move, err_move, u_move : ndarray
        Tracking error reference − true angle (rad) and voltage (V) of the sine-jerk move
        simulated by :func:`jerklab.sim.simulate` (feedforward + PID, 10-bit PWM, 12 V,
        448-line encoder).
    err_move_measured : ndarray
        Reference − encoder reading (rad): the quantity a rig records, to compare with it.
    t_view : float
        Time span (s) that shows the step and disturbance responses (12 / (min(ζ, 1) ωn)).
    timings : dict
        Seconds spent in the design, the linear responses and the move simulation.
    """

    params: dict
    gains: object
    continuous_gains: object
    poles_s_desired: np.ndarray
    poles_z: np.ndarray
    poles_z_desired: np.ndarray
    poles_s_equivalent: np.ndarray
    max_radius: float
    desired_radius: float
    stable: bool
    level: str
    message: str
    t_step: np.ndarray
    y_step: np.ndarray
    t_dist: np.ndarray
    y_dist: np.ndarray
    t_move: np.ndarray
    err_move: np.ndarray
    u_move: np.ndarray
    err_move_measured: np.ndarray = field(default_factory=lambda: np.zeros(0))
    advice: tuple = ()
    advice_text: str = ""
    t_view: float = 1.0
    timings: dict = field(default_factory=dict)

    @property
    def design_name(self):
        return DESIGN_NAMES[self.params["design"]]


def _move_key(move):
    move = dict(DEFAULT_MOVE if move is None else move)
    unknown = set(move) - set(DEFAULT_MOVE)
    if unknown or set(DEFAULT_MOVE) - set(move):
        raise ValueError(f"move must have the keys {sorted(DEFAULT_MOVE)}, got {sorted(move)}")
    return tuple((k, as_positive(f"move[{k!r}]", move[k])) for k in sorted(move))


@functools.lru_cache(maxsize=32)
def _profile(key):
    m = dict(key)
    return plan_sine_jerk(m["distance"], m["max_jerk"], m["max_accel"], m["max_velocity"])


def move_profile(move=None):
    """The sine-jerk profile (Stojčić eq. 14) of ``move`` (a :data:`DEFAULT_MOVE`-like dict), cached."""
    return _profile(_move_key(move))


def _validated(K, tau, zeta, wn, sigma_ratio, Ts):
    return (
        as_positive("K", K),
        as_positive("tau", tau),
        as_positive("zeta", zeta),
        as_positive("wn", wn),
        as_positive("sigma_ratio", sigma_ratio),
        as_positive("Ts", Ts),
    )


def _frozen(a):
    a = np.asarray(a)
    a.flags.writeable = False
    return a


def compute_pole_placement(
    K=paper.MOTOR_K,
    tau=paper.MOTOR_TAU,
    zeta=paper.ZETA,
    wn=20.0,
    sigma_ratio=paper.SIGMA_RATIO,
    Ts=paper.TS,
    design="continuous",
    move=None,
    simulate_move=True,
):
    """Design the position-loop PID for one setting and compute every curve of the panel.

    Parameters
    ----------
    K, tau : float
        Plant P(s) = K / (s (τ s + 1)) (Stojčić eq. 1), rad/(V·s) and s.
    zeta, wn : float
        Damping ratio and natural frequency (rad/s) of the dominant pair.
    sigma_ratio : float
        The real pole σ as a multiple of ωn (the paper: σ ≥ 7 ωn).
    Ts : float
        Sampling period (s).
    design : {"continuous", "z-domain", "z-domain-filter"}
        See :func:`design_gains`.
    move : dict, optional
        ``distance, max_jerk, max_accel, max_velocity`` of the sine-jerk move (default
        :data:`DEFAULT_MOVE`).
    simulate_move : bool
        Skip the move simulation (empty arrays) when False.

    Returns
    -------
    TuningResult
        Cached on the parameters: the same object (read-only arrays) for the same call.
    """
    K, tau, zeta, wn, sigma_ratio, Ts = _validated(K, tau, zeta, wn, sigma_ratio, Ts)
    return _compute(
        K,
        tau,
        zeta,
        wn,
        sigma_ratio,
        Ts,
        _check_design_key(design),
        _move_key(move),
        bool(simulate_move),
    )


@functools.lru_cache(maxsize=64)
def _compute(K, tau, zeta, wn, sigma_ratio, Ts, design, move_key, simulate_move):
    t0 = time.perf_counter()
    sigma = sigma_ratio * wn
    d, g = design_gains(K, tau, zeta, wn, sigma_ratio, Ts, design)
    loop = ctl.PositionLoop(K, tau, d)
    poles_z = np.asarray(loop.poles_z(), dtype=complex)
    max_radius = closed_loop_max_radius(K, tau, d)
    stable = max_radius < 1.0

    poles_s_desired, poles_z_desired = _desired(zeta, wn, sigma_ratio, Ts)
    desired_radius = float(np.max(np.abs(poles_z_desired)))
    poles_s_equivalent = np.asarray(loop.poles_s(), dtype=complex)
    poles_s_equivalent = poles_s_equivalent[np.isfinite(poles_s_equivalent)]  # z = 0 has no s image
    level, message = stability_verdict(min(max_radius, 1e300), desired_radius, Ts, sigma)
    advice = _advise(K, tau, zeta, wn, sigma_ratio, Ts, design) if level != "ok" else ()
    t1 = time.perf_counter()

    # step and disturbance responses of the linear sampled loop (controller's own recursions)
    # t_view: the span worth looking at (~12 time constants of the dominant pair); the
    # responses run 3x longer so a figure can keep a wider axis without a gap
    t_view = float(np.clip(12.0 / (min(zeta, 1.0) * wn), 0.2, 4.0))
    t_end = min(3.0 * t_view, 10.0)
    with np.errstate(over="ignore", invalid="ignore"):
        t_lin, y_step = loop.step_response(t_end)
        _, y_dist = loop.disturbance_response(t_end, amplitude=DISTURBANCE_VOLTS)
    t2 = time.perf_counter()

    # sine-jerk move on the full nonlinear simulation (PWM, saturation, encoder)
    if simulate_move:
        profile = _profile(move_key)
        motor = DCMotor(K, tau)
        c = ctl.DigitalController(
            d, feedforward=ctl.Feedforward(K, tau), output_limit=motor.supply_voltage
        )
        with np.errstate(all="ignore"):
            r = simulate(profile, motor, c, Ts=Ts, t_end=profile.duration + 0.3)
        t_move = np.asarray(r.time, dtype=float)
        err_move = np.asarray(r.error, dtype=float)
        err_meas = np.asarray(r.reference, dtype=float) - np.asarray(r.measured, dtype=float)
        u_move = np.asarray(r.command, dtype=float)
    else:
        t_move = err_move = err_meas = u_move = np.zeros(0)
    t3 = time.perf_counter()

    return TuningResult(
        params=dict(
            K=K,
            tau=tau,
            zeta=zeta,
            wn=wn,
            sigma_ratio=sigma_ratio,
            sigma=sigma,
            Ts=Ts,
            design=design,
        ),
        gains=d,
        continuous_gains=g,
        poles_s_desired=_frozen(poles_s_desired),
        poles_z=_frozen(poles_z),
        poles_z_desired=_frozen(poles_z_desired),
        poles_s_equivalent=_frozen(poles_s_equivalent),
        max_radius=max_radius,
        desired_radius=desired_radius,
        stable=stable,
        level=level,
        message=message,
        t_step=_frozen(t_lin),
        y_step=_frozen(y_step),
        t_dist=_frozen(t_lin),
        y_dist=_frozen(y_dist),
        t_move=_frozen(t_move),
        err_move=_frozen(err_move),
        u_move=_frozen(u_move),
        err_move_measured=_frozen(err_meas),
        advice=advice,
        advice_text=_advice_text(level, design, advice),
        t_view=t_view,
        timings=dict(design=t1 - t0, responses=t2 - t1, move=t3 - t2),
    )


def clear_cache():
    """Empty every cache of this module (results, advice, profiles)."""
    for f in (_compute, _advise, _level, _profile):
        f.cache_clear()


# --------------------------------------------------------------------------------------
# numbers with units
# --------------------------------------------------------------------------------------
def continuous_equivalent(gains):
    """Continuous gains (kp, ki, kd) whose Stojčić eq. 13 discretization gives ``gains``.

    Inverts Stojčić eq. 13 (``kpd = kp − ki Ts/2``, ``kid = ki Ts``, ``kdd = kd/Ts``):
    ``ki = kid/Ts``, ``kp = kpd + kid/2``, ``kd = kdd Ts``. For a derivative filter γ ≠ 0 the
    derivative is ``kdd (1 − z⁻¹)/(1 − γ z⁻¹)``, whose low-frequency gain gives
    ``kd = kdd Ts / (1 − γ)``.
    """
    Ts, g = gains.Ts, getattr(gains, "gamma", 0.0)
    return gains.kpd + gains.kid / 2.0, gains.kid / Ts, gains.kdd * Ts / (1.0 - g)


def gain_table(gains, continuous=None):
    """Rows ``(name, value, unit)`` of the gains for display.

    The discrete gains of Stojčić eq. 12 act on the error in rad each sample (all V/rad);
    the continuous gains (Stojčić eq. 10: Kp V/rad, Ki V/(rad·s), Kd V·s/rad) are the
    design's own (Stojčić eq. 11) or, for a z-domain design, the Stojčić eq. 13 equivalent
    (:func:`continuous_equivalent`).
    """
    rows = [("kpd", gains.kpd, "V/rad"), ("kid", gains.kid, "V/rad"), ("kdd", gains.kdd, "V/rad")]
    if getattr(gains, "gamma", 0.0) != 0.0:
        rows.append(("γ", gains.gamma, ""))
    kp, ki, kd = (
        (continuous.kp, continuous.ki, continuous.kd)
        if continuous is not None
        else continuous_equivalent(gains)
    )
    rows += [("Kp", kp, "V/rad"), ("Ki", ki, "V/(rad·s)"), ("Kd", kd, "V·s/rad")]
    return rows


def angle_unit(max_abs_rad):
    """(factor, unit) to show angles of this size: mrad below 1 rad, rad from 1 rad up."""
    x = abs(float(max_abs_rad))
    if not math.isfinite(x) or x >= 1.0:
        return 1.0, "rad"
    return 1e3, "mrad"


def format_angle(x_rad, digits=3):
    """An angle with a unit that fits its size: ``"3.21 mrad"``, ``"142 rad"``, ``"inf rad"``."""
    x = float(x_rad)
    if not math.isfinite(x):
        return f"{x} rad"
    f, unit = angle_unit(x)
    v = x * f
    if v == 0.0:
        return f"0 {unit}"
    dec = max(0, digits - 1 - int(math.floor(math.log10(abs(v)))))
    return f"{v:.{dec}f} {unit}"
