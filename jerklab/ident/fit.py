"""The motor fit :func:`fit_dc_motor` (Stojčić eq. 1, §4A; ASCII: Stojcic), one function per step.

:func:`fit_dc_motor` checks its options (:class:`FitOptions`), the sample period and the record,
then runs one estimator: the velocity ARX fit (:func:`jerklab.ident.arx.velocity_arx`), the
inverse dynamics (:mod:`jerklab.ident.idim`) or the multiple-shooting output error
(:mod:`jerklab.ident.oe`) started from it, and returns a :class:`~jerklab.ident.MotorFit` whose
diagnostics (:mod:`jerklab.ident.diagnostics`) are also issued as warnings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jerklab._lazy import lazy_module
from jerklab._validate import as_int, as_positive
from jerklab.ident._common import _check_excitation, _pair, fit_percent
from jerklab.ident.arx import velocity_arx
from jerklab.ident.diagnostics import _diagnose, _issue
from jerklab.ident.idim import _idim, _params_from_idim, _shooting_sim
from jerklab.ident.model import _best_theta0, _unit_response
from jerklab.ident.motorfit import MotorFit, _motor_tf
from jerklab.ident.oe import (
    TERMS,
    ShootingProblem,
    fit_output_error,
    projection_start,
    tau_grid_start,
)

control = lazy_module("control")  # python-control imports matplotlib: import it on first use

METHODS = ("pem", "arx", "idim", "idim-iv")

#: the sample periods :func:`fit_dc_motor` accepts (s): 1 ns … 1000 s. The fit scales with Ts, and far
#: outside this range its covariance under/overflows to NaN/inf (Ts = 1e-300 gives K_std = NaN)
FIT_TS_RANGE = (1e-9, 1e3)


@dataclass(frozen=True)
class FitOptions:
    """What :func:`fit_dc_motor` estimates and how: its keyword arguments, grouped and checked.

    ``fit_dc_motor(u, theta, Ts, options=FitOptions(friction=True, delay=True))`` is
    ``fit_dc_motor(u, theta, Ts, friction=True, delay=True)``; the fields, their defaults and
    their meaning are those of :func:`fit_dc_motor`. A bad value raises ``ValueError`` naming
    the field when the options are made.
    """

    method: str = "pem"
    fit_theta0: bool = True
    friction: bool = False
    offset: bool = False
    delay: int | bool = 0
    dead_zone: bool = False
    segment: float | None = None
    max_delay: int = 10
    cutoff: float | None = None
    coast: bool | str = False

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        if self.method not in METHODS:
            raise ValueError(
                f"method must be 'pem', 'arx', 'idim' or 'idim-iv', got {self.method!r}"
            )
        for nm in ("friction", "offset", "dead_zone", "fit_theta0"):
            val = getattr(self, nm)
            if not isinstance(val, (bool, np.bool_)):
                raise ValueError(f"{nm} must be True or False, got {val!r}")
            put(nm, bool(val))
        coast = self.coast
        if not (isinstance(coast, (bool, np.bool_)) or coast == "coulomb"):
            raise ValueError(f"coast must be True, False or 'coulomb', got {coast!r}")
        put("coast", coast if coast == "coulomb" else bool(coast))
        if self.coast == "coulomb" and not self.friction:
            raise ValueError(
                "coast='coulomb' (the open motor runs down on Coulomb friction alone) needs "
                "friction=True; without friction it would never stop"
            )
        if self.delay is not True:
            put("delay", 0 if self.delay is False else as_int("delay", self.delay, minimum=0))
        put("max_delay", as_int("max_delay", self.max_delay, minimum=0))
        if self.cutoff is not None:
            put("cutoff", as_positive("cutoff", self.cutoff))
        if self.segment is not None:
            put("segment", as_positive("segment", self.segment))
        if self.method == "arx" and (self.terms or self.delay is True or self.delay):
            raise ValueError(
                "friction, offset, dead_zone, delay and merged experiments need method='pem' "
                "or 'idim' (ARX has no such terms)"
            )
        if self.coast and self.method != "pem":
            raise ValueError(
                f"coast={self.coast!r} needs method='pem' (the output-error fit), "
                f"got method={self.method!r}"
            )

    @property
    def terms(self) -> tuple:
        """The estimated terms of the input map, among ``("friction", "offset", "dead_zone")``."""
        return tuple(nm for nm in TERMS if getattr(self, nm))

    @property
    def flags(self) -> dict:
        """``{"friction": bool, "offset": bool, "dead_zone": bool}`` (the inverse-dynamics columns)."""
        return {nm: getattr(self, nm) for nm in TERMS}

    @property
    def linear(self) -> bool:
        """True for Stojčić eq. 1 alone (a delay aside): no friction, offset, dead zone or coasting."""
        return not (self.terms or self.coast)

    @property
    def names(self) -> list:
        """The estimated parameters, in the order of the covariance."""
        return ["K", "tau", *self.terms] + (["tau_coast"] if self.coast is True else [])


def fit_dc_motor(
    u,
    theta,
    Ts,
    method: str = "pem",
    fit_theta0: bool = True,
    friction: bool = False,
    offset: bool = False,
    delay=0,
    dead_zone: bool = False,
    segment=None,
    max_delay: int = 10,
    cutoff=None,
    coast=False,
    *,
    options: FitOptions | None = None,
) -> MotorFit:
    """Identify K and tau of P(s) = K/(s(tau s + 1)) (Stojčić eq. 1, §4A) from a voltage/angle record.

    The paper ran MATLAB's ``pem(iddata(y, u, Ts), 'P2')``; 'P2' has no integrator, so this fits
    the structure Stojčić eq. 1 actually has, a pole plus an integrator ('P1I'). Options add what real
    records carry: Coulomb friction by the sign of the velocity (with sticking), an input offset,
    an input dead zone and a pure delay (see :func:`simulate_motor` for the model).

    Parameters
    ----------
    u : array_like, or list of array_like
        Motor voltage samples (V), held over each sample period: the *logged* input, open loop or
        closed loop. A list of records (with ``theta`` a list of the same length) merges several
        experiments for one estimate (MATLAB's ``merge``); see also :func:`merge`.
    theta : array_like, or list of array_like
        Measured angle (rad), same length as ``u``; sample k read at k Ts, before ``u[k]`` acts.
    Ts : float
        Sample period (s).
    method : {"pem", "arx", "idim", "idim-iv"}
        "pem": output error with **multiple shooting**: K, tau (and the options) minimise
        sum (theta - theta_sim)^2 over the exact ZOH simulation of the model, the record cut into
        segments, each started from its own estimated angle and velocity; so neither a
        closed-loop record nor an integrating plant can drift over a long record (Ljung §4.2
        output error). A record of at most 1000 samples is one segment: the plain output-error
        fit from an estimated initial state. Started from the inverse-dynamics estimate below
        (and, for Stojčić eq. 1 alone, from a grid over tau: whichever starts lower). The
        standard errors hold for coloured residuals: a Newey-West sandwich (Newey & West 1987),
        and, when the angle is in whole encoder counts, the encoder's quantization simulated
        about the fitted angle; each standard error is the largest of these and s^2 (J^T J)^-1
        (:meth:`ShootingProblem.covariance <jerklab.ident.oe.ShootingProblem.covariance>`).
        They cover noise and quantization, not a part of the plant the model leaves out
        (friction not fitted biases K by about f_c over the input voltage).
        "arx": least squares on the differenced angle v(k) = a v(k-1) + b1 u(k-1) + b2 u(k-2)
        (exact for the ZOH model), K = (b1 + b2)/(1 - a), tau = -Ts/ln a; biased (tau short)
        under noise (:func:`arx_asymptotic_bias`). No options.
        "idim": the inverse-dynamics least squares of motion-control practice (Gautier & Janot):
        u = (tau/K) omega' + omega/K + f_c sign(omega) - offset + dead_zone sign(u) on the
        low-passed angle's derivatives, every column and u filtered by the same zero-phase
        Butterworth filter (parallel filtering). Fast, linear, any record; errors-in-variables
        bias under noise. "idim-iv": the same with instrumental variables built from the model's
        own simulated angle (re-started on each segment), iterated (Janot, Vandanjon & Gautier
        2014; Ljung §7.6), which removes most of that bias.
    fit_theta0 : bool
        Estimate the initial angle (default). False holds it at the first, noisy, sample: the
        first segment of each record for "pem", the simulation of "arx" ("idim" starts every
        simulation at the measured angle anyway).
    friction : bool
        Also estimate a Coulomb friction voltage f_c >= 0 acting against the *velocity*, with
        sticking at rest (:func:`simulate_motor`). K and f_c are separable only if the record has
        at least two speed levels; friction and offset only if the motor turns both ways.
    offset : bool
        Also estimate an input offset (V): the motor sees u + offset.
    delay : int or True
        Pure input delay in whole samples: an int is taken as known; ``True`` estimates it over
        0 .. ``max_delay`` (inverse-dynamics residual, then the output-error cost around it).
    dead_zone : bool
        Also estimate an input dead zone (V) >= 0: the motor sees sign(x) max(|x| - dz, 0) of
        x = u + offset. Separable from friction only where the motor brakes or reverses.
    segment : float, optional
        Multiple-shooting segment length (s). Default: one segment per record of at most
        1000 samples, else segments of 500 samples. Not used by "arx".
    max_delay : int
        Largest delay tried with ``delay=True``.
    cutoff : float, optional
        Cut-off (Hz) of the low-pass filter of the inverse-dynamics regression (and of the
        velocities that start the segments); default 1/(10 Ts) (a fifth of the Nyquist frequency).
    coast : bool or "coulomb"
        True: also estimate ``tau_coast``, the time constant while the drive is *open* at u = 0
        (a switch or bridge that floats the motor: no back-EMF braking, the motor runs down on
        its mechanical friction; :func:`simulate_motor`). It is estimated as the rate
        1/tau_coast >= 0; with ``friction=True`` the coasting motor also decelerates by the same
        Coulomb torque, K friction / tau. "coulomb" (needs ``friction=True``): the open motor
        has no viscous drag (tau_coast = inf) and runs down on Coulomb friction alone, the model
        to choose when ``coast=True`` reports its rate at the bound 0. ``method="pem"`` only; u = 0
        must occur in the record, and an offset or dead zone is then seen only at the non-zero
        levels.
    options : FitOptions, optional
        All of the above as one :class:`FitOptions` (then leave the keywords at their defaults).

    Returns
    -------
    MotorFit
        K, tau, friction, offset, dead_zone (V) and their standard errors, delay, fit %, ...
        Physically impossible or poorly determined results issue an
        :class:`IdentificationWarning` naming the likely cause (also kept in ``fit.warnings``):
        K or tau <= 0 (encoder or motor leads reversed), friction above the input range, a
        parameter stuck at its bound, an ill-conditioned fit (input not exciting enough).

    Raises
    ------
    ValueError
        NaN/inf in ``u`` or ``theta``, mismatched lengths, fewer than 10 samples, constant ``u``
        or ``theta``, a ``Ts`` outside ``FIT_TS_RANGE``, an unknown ``method`` or option, or data
        from which the ARX pole falls outside (0, 1). Also an input with too few distinct levels
        for the input map asked for: the motor sees K dz(u + offset) only at the levels u takes,
        so K, ``offset`` and ``dead_zone`` need at least 1 + offset + dead_zone distinct (driven)
        levels (without an offset, distinct non-zero magnitudes |u|); a two-level input (a PRBS,
        a step) cannot separate all three, nor K and a dead zone alone.

    References
    ----------
    Stojčić (2015) §4A and Stojčić eq. 1; L. Ljung, *System Identification* (2nd ed.), §4.2 (output
    error), §7.3 and §9.3 (least squares, asymptotic covariance), §7.6 (instrumental variables),
    §16 (model validation); M. Gautier, "Dynamic identification of robots with power model",
    ICRA 1997, and A. Janot, P.-O. Vandanjon, M. Gautier, "A generic instrumental variable
    approach for industrial robot identification", IEEE TCST 22(1), 2014 (IDIM-LS, IDIM-IV).
    """
    keywords = dict(
        method=method,
        fit_theta0=fit_theta0,
        friction=friction,
        offset=offset,
        delay=delay,
        dead_zone=dead_zone,
        segment=segment,
        max_delay=max_delay,
        cutoff=cutoff,
        coast=coast,
    )
    opts = _options(options, keywords)
    Ts = _sample_period(Ts)
    exps = _experiments(u, theta)
    _check_record(opts, exps)
    if opts.method == "arx":
        fit = _fit_arx(*exps[0], Ts, opts)
    else:
        cutoff = 0.1 / Ts if opts.cutoff is None else opts.cutoff
        segment_n = _segment_samples(opts.segment, exps, Ts)
        delay, p_ls = _inverse_dynamics_delay(exps, Ts, opts, cutoff)
        if opts.method == "pem":
            fit = _fit_output_error(exps, Ts, opts, delay, p_ls, cutoff, segment_n)
        else:
            fit = _fit_inverse_dynamics(exps, Ts, opts, delay, cutoff, segment_n)
    _issue(fit.warnings)
    return fit


# ----------------------------------------------------------------------------------------------
# the steps of fit_dc_motor
# ----------------------------------------------------------------------------------------------
def _options(options, keywords) -> FitOptions:
    """The checked options: ``options`` itself, or the keywords made into a FitOptions."""
    given = FitOptions(**keywords)
    if options is None:
        return given
    if not isinstance(options, FitOptions):
        raise ValueError(f"options must be a FitOptions, got {type(options).__name__}")
    if given != FitOptions():
        raise ValueError(
            "options: give the fit options either as keywords or as options=FitOptions(...), "
            "not both"
        )
    return options


def _sample_period(Ts) -> float:
    Ts = as_positive("Ts", Ts)
    if not FIT_TS_RANGE[0] <= Ts <= FIT_TS_RANGE[1]:
        # the fit scales with Ts (tau ~ Ts); far outside this range its covariance under/overflows
        raise ValueError(
            f"Ts must lie within {FIT_TS_RANGE[0]:g} … {FIT_TS_RANGE[1]:g} s (FIT_TS_RANGE: the "
            f"sample period of a motor record), got {Ts:g}"
        )
    return Ts


def _experiments(u, theta) -> list:
    """One record (two 1-D arrays) or several (two sequences of 1-D arrays) -> list of (u, theta),
    each checked for finite values, equal lengths and an input and output that move."""

    def is_multi(x):
        return (
            isinstance(x, (list, tuple))
            and len(x) > 0
            and np.ndim(x[0]) == 1
            and not np.isscalar(x[0])
        )

    if is_multi(u) or is_multi(theta):
        if not (is_multi(u) and is_multi(theta)) or len(u) != len(theta):
            raise ValueError(
                "u and theta must both be one record (1-D arrays) or both lists of "
                "records of the same length"
            )
        exps = [_pair(uu, tt, f"u[{i}]", f"theta[{i}]") for i, (uu, tt) in enumerate(zip(u, theta))]
    else:
        exps = [_pair(u, theta, "u", "theta")]
    for i, (uu, tt) in enumerate(exps):
        suffix = "" if len(exps) == 1 else f"[{i}]"
        _check_excitation(uu, tt, "u" + suffix, "theta" + suffix)
    return exps


def _check_record(opts: FitOptions, exps) -> None:
    """What the options ask of the record: one record for ARX, an open drive for ``coast``,
    enough input levels for the offset and dead zone."""
    if opts.method == "arx" and len(exps) > 1:
        raise ValueError(
            "friction, offset, dead_zone, delay and merged experiments need method='pem' "
            "or 'idim' (ARX has no such terms)"
        )
    u_all = np.concatenate([uu for uu, _ in exps])
    if opts.coast and not np.any(u_all == 0.0):
        raise ValueError(
            "coast: u is never exactly 0, so the drive is never open; fit without coast"
        )
    if opts.offset or opts.dead_zone:
        _check_input_levels(opts, u_all)


def _check_input_levels(opts: FitOptions, u_all) -> None:
    """The static map u -> K dz(u + offset) is only seen at the levels u takes (without an
    offset, dz(0) = 0 and dz is odd: u = 0 tells nothing, and -l says what l says)."""
    offset, dead_zone = opts.offset, opts.dead_zone
    levels = np.unique(u_all if offset else np.abs(u_all))
    if opts.coast or not offset:
        levels = levels[levels != 0.0]
    need = 1 + int(offset) + int(dead_zone)
    if levels.size >= need:
        return
    shown = ", ".join(f"{lv:.4g}" for lv in levels[:4]) + (" ..." if levels.size > 4 else "")
    which = [nm for nm, on in (("K", True), ("offset", offset), ("dead_zone", dead_zone)) if on]
    which = ", ".join(which[:-1]) + " and " + which[-1]
    name = "dead_zone" if dead_zone else "offset"
    plural = "s" if levels.size > 1 else ""
    raise ValueError(
        f"{name}: the {'driven ' if opts.coast else ''}input takes only {levels.size} distinct "
        f"level{plural} ({shown} V), and the motor sees K dz(u + offset) only at those levels, "
        f"so {which} ({need} parameters) cannot be separated: the fit would trade them off "
        f"without bound. Drop {name}, or record an input with at least {need} levels"
    )


def _segment_samples(segment, exps, Ts):
    """Shooting segment length (samples): None (one segment per record) up to 1000 samples."""
    if segment is None:
        return None if max(uu.size for uu, _ in exps) <= 1000 else 500
    segment_n = int(round(segment / Ts))
    if segment_n < 10:
        raise ValueError(f"segment must be at least 10 samples ({10 * Ts:g} s), got {segment:g} s")
    return segment_n


def _u_abs_max(exps) -> float:
    return max(float(np.max(np.abs(uu))) for uu, _ in exps)


def _fit_arx(u, theta, Ts, opts: FitOptions) -> MotorFit:
    """The velocity ARX fit and the simulation of its model on the record."""
    K, tau, cov, res = velocity_arx(u, theta, Ts)
    g = K * _unit_response(tau, Ts, u)
    th0 = _best_theta0(theta, g) if opts.fit_theta0 else float(theta[0])
    par = {"K": K, "tau": tau, "friction": 0.0, "offset": 0.0, "dead_zone": 0.0}
    return _motor_fit(
        "arx",
        Ts,
        par,
        cov,
        ["K", "tau"],
        g + th0,
        theta,
        _diagnose(par, cov, ["K", "tau"], _u_abs_max([(u, theta)])),
        theta0=float(th0),
        noise_std=math.sqrt(res.noise_variance) * Ts,
        arx_result=res,
    )


def _inverse_dynamics_delay(exps, Ts, opts: FitOptions, cutoff):
    """The given delay, or the one in 0 .. max_delay with the least inverse-dynamics residual,
    and the IDIM-LS parameters (tau/K, 1/K, [f_c], [offset], [dead_zone]) at that delay."""
    best = None
    for d in range(opts.max_delay + 1) if opts.delay is True else [opts.delay]:
        try:
            p, _, sse, _ = _idim(exps, Ts, d, opts.flags, cutoff)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if best is None or sse < best[2]:
            best = (d, p, sse)
    if best is None:
        raise ValueError("theta: the inverse-dynamics regression failed (too few moving samples)")
    return best[0], best[1]


def _fit_inverse_dynamics(exps, Ts, opts: FitOptions, delay, cutoff, segment_n) -> MotorFit:
    """IDIM-LS or IDIM-IV, its covariance carried to (K, tau, ...), simulated segment by segment."""
    iv = 4 if opts.method == "idim-iv" else 0
    p, cov_p, _, _ = _idim(
        exps, Ts, delay, opts.flags, cutoff, iv_iterations=iv, segment_n=segment_n
    )
    par = _params_from_idim(p, opts.flags)
    names = opts.names
    # (tau/K, 1/K, ...) -> (K, tau, ...)
    Jt = np.zeros((len(names), p.size))
    a_, b_ = p[0], p[1]
    Jt[0, 1] = -1.0 / b_**2
    Jt[1, 0], Jt[1, 1] = 1.0 / b_, -a_ / b_**2
    for i in range(2, len(names)):
        Jt[i, i] = 1.0
    cov = Jt @ cov_p @ Jt.T
    ys = []
    for uu, tt in exps:
        if par["K"] > 0 and par["tau"] > 0:
            ys.append(_shooting_sim(uu, tt, Ts, par, delay, cutoff, segment_n))
        else:
            ys.append(np.full(tt.size, np.nan))
    y_sim = np.concatenate(ys)
    theta = np.concatenate([tt for _, tt in exps])
    resid = theta - y_sim
    s = float(np.sqrt(np.mean(resid**2))) if np.all(np.isfinite(resid)) else float("nan")
    return _motor_fit(
        opts.method,
        Ts,
        par,
        cov,
        names,
        y_sim,
        theta,
        _diagnose(par, cov, names, _u_abs_max(exps)),
        theta0=float(theta[0]),
        noise_std=s,
        delay=delay,
        n_experiments=len(exps),
    )


def _output_error_starts(exps, Ts, opts: FitOptions, delay, p_ls, segment_n) -> list:
    """Starts of the output-error fit: the inverse-dynamics estimate when it is a motor; the tau
    grid on the longest record when it is not (a reversed encoder, K < 0, or an unusable
    regression), and for Stojčić eq. 1 alone on records of one segment, where the grid is the
    start that cannot be far off (any sign of K, any tau/Ts), and the exact optimum over tau with
    every segment state (``oe.projection_start``), which a record much shorter than tau needs."""
    idim = _params_from_idim(p_ls, opts.flags)
    starts = []
    if idim["K"] > 0 and idim["tau"] > 0 and math.isfinite(idim["K"]):
        starts.append(idim)
    if not starts or (segment_n is None and opts.linear):
        uu, tt = max(exps, key=lambda e: e[0].size)
        K0, tau0, _ = tau_grid_start(uu, tt, Ts)
        starts.append({"K": K0, "tau": tau0, "friction": 0.0, "offset": 0.0, "dead_zone": 0.0})
    if segment_n is None and opts.linear:
        starts.append(projection_start(exps, Ts, delay, segment_n))
    # friction and dead zone start well inside (0, max |u|): the inverse-dynamics value can be
    # far off, and a start near max |u| lets the fit trade a huge K against a dead zone that
    # swallows the whole input
    u_max = _u_abs_max(exps)
    for par in starts:
        for nm in ("friction", "dead_zone"):
            if getattr(opts, nm):
                par[nm] = min(max(par[nm], 0.01 * u_max), 0.5 * u_max)
    return starts


def _fit_output_error(exps, Ts, opts: FitOptions, delay, p_ls, cutoff, segment_n) -> MotorFit:
    """Multiple-shooting output error from the better start; with ``delay=True`` the
    inverse-dynamics delay first, then its neighbours, started from that optimum."""
    kw = dict(
        terms=opts.terms,
        coast=opts.coast,
        segment_n=segment_n,
        cutoff=cutoff,
        fix_theta0=not opts.fit_theta0,
    )
    starts = _output_error_starts(exps, Ts, opts, delay, p_ls, segment_n)
    # Stojčić eq. 1 on short records: cheap evaluations, and a flat valley when tau is much longer
    # than the record (noise-free, 30 samples of tau = 67 records need 311 evaluations)
    budget = 2000 if segment_n is None and opts.linear else 200
    problem = ShootingProblem(exps, Ts, delay, offset_hint=starts[0].get("offset", 0.0), **kw)
    x0s = [problem.start(s) for s in starts]
    res = problem.solve(min(x0s, key=problem.cost), max_nfev=budget)
    if opts.delay is True:
        neighbours = sorted({max(delay - 1, 0), min(delay + 1, opts.max_delay)} - {delay})
        for d in neighbours:
            # a neighbour only has to show a higher cost: a few iterations, a full fit if it wins
            trial = fit_output_error(exps, Ts, d, res.par, max_nfev=15, **kw)
            if trial.cost < res.cost:
                res, delay = fit_output_error(exps, Ts, d, trial.par, max_nfev=budget, **kw), d
    names = opts.names
    msgs = _diagnose(res.par, res.cov, names, _u_abs_max(exps), res.at_bound)
    return _motor_fit(
        "pem",
        Ts,
        res.par,
        res.cov,
        names,
        res.y_sim,
        res.theta,
        msgs,
        theta0=float(res.seg_theta0[0]),
        omega0=float(res.seg_omega0[0]),
        noise_std=res.s,
        nfev=res.nfev,
        delay=delay,
        n_segments=res.nseg,
        n_experiments=len(exps),
    )


def _motor_fit(method, Ts, par, cov, names, y_sim, theta, msgs, **extra) -> MotorFit:
    """The MotorFit of estimated ``par`` (``names`` in the order of ``cov``) on the record."""
    std = dict(zip(names, np.sqrt(np.clip(np.diag(cov), 0.0, None))))
    K, tau = float(par["K"]), float(par["tau"])
    fp = fit_percent(theta, y_sim) if np.all(np.isfinite(y_sim)) else float("nan")
    return MotorFit(
        K=K,
        tau=tau,
        K_std=float(std["K"]),
        tau_std=float(std["tau"]),
        fit_percent=fp,
        model=_motor_tf(K, tau) if tau > 0 else control.tf([K], [1.0, 0.0]),
        method=method,
        Ts=Ts,
        cov=cov[:2, :2].copy(),
        y_sim=y_sim,
        residuals=theta - y_sim,
        friction=float(par["friction"]),
        friction_std=float(std.get("friction", 0.0)),
        offset=float(par["offset"]),
        offset_std=float(std.get("offset", 0.0)),
        dead_zone=float(par["dead_zone"]),
        dead_zone_std=float(std.get("dead_zone", 0.0)),
        estimated=tuple(names),
        covariance=cov,
        warnings=msgs,
        tau_coast=float(par.get("tau_coast", 0.0)),
        tau_coast_std=float(std.get("tau_coast", 0.0)),
        **extra,
    )
