"""``fit_dc_motor``: K and tau of Stojčić eq. 1 (ASCII: Stojcic) and the terms of real records.

One estimate in small steps, each a function of its own:

1. :class:`FitOptions` checks the options (friction, offset, dead zone, delay, segments, coasting);
2. :func:`_experiments` checks the record(s) and :func:`_check_records` what the options ask of
   them (an estimator that has the terms, the input levels that separate them);
3. ``method="arx"``: ``jerklab.ident.equation_error.fit_velocity_arx``, done;
4. :func:`_inverse_dynamics`: the inverse-dynamics least squares over the delays tried
   (``jerklab.ident.inverse_dynamics``), the estimate of ``"idim"``/``"idim-iv"``
   (:func:`_idim_result`) and the delay (and, with friction, offset, dead zone or coasting,
   the start) of the output-error fit;
5. :func:`_start`, :func:`_output_error`: multiple-shooting output error
   (``jerklab.ident.output_error``), the delay refined among its neighbours;
6. ``jerklab.ident.diagnostics`` turns implausible or poorly determined results into
   :class:`IdentificationWarning` messages, and :func:`_motor_fit` assembles the
   :class:`~jerklab.ident.model.MotorFit`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from jerklab._lazy import lazy_module
from jerklab._validate import as_int, as_positive
from jerklab.ident._checks import _check_excitation, _pair
from jerklab.ident.diagnostics import _diagnose, _issue
from jerklab.ident.equation_error import fit_velocity_arx
from jerklab.ident.inverse_dynamics import _idim, _params_from_idim, _shooting_sim
from jerklab.ident.model import MotorFit, _motor_tf
from jerklab.ident.output_error import _fit_oe_ms, _grid_start, _linear_start
from jerklab.ident.validation import fit_percent

control = lazy_module("control")  # python-control imports matplotlib: import it on first use

__all__ = ["FIT_TS_RANGE", "METHODS", "FitOptions", "fit_dc_motor"]

#: the sample periods :func:`fit_dc_motor` accepts (s): 1 ns … 1000 s. The fit scales with Ts, and far
#: outside this range its covariance under/overflows to NaN/inf (Ts = 1e-300 gives K_std = NaN)
FIT_TS_RANGE = (1e-9, 1e3)

#: the estimators of :func:`fit_dc_motor`
METHODS = ("pem", "arx", "idim", "idim-iv")

#: the optional input-map terms, in the order of the estimated parameters after K and tau
TERMS = ("friction", "offset", "dead_zone")

#: the output-error fit's budget and tolerances (max_nfev, (xtol, ftol, gtol)). The linear model
#: (K, tau and the segment states) converges tightly: a record much shorter than tau, where K and
#: tau trade off along a narrow valley, needs a few hundred evaluations to pin them to 1e-6. A model
#: with friction, offset, dead zone or coasting stops sooner, where an ill-conditioned fit would
#: otherwise wander along its valley (the diagnostics then say so).
OE_LINEAR = (2000, (1e-12, 1e-12, 1e-12))
OE_EXTENDED = (200, (1e-8, 1e-9, 1e-9))

#: iterations of the instrumental variables of ``method="idim-iv"``
IV_ITERATIONS = 4


# ----------------------------------------------------------------------------------------------
# step 1: the options
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FitOptions:
    """The options of :func:`fit_dc_motor`, checked once (``fit_dc_motor(..., options=...)``).

    ``fit_dc_motor(u, theta, Ts, friction=True)`` and
    ``fit_dc_motor(u, theta, Ts, options=FitOptions(friction=True))`` are the same fit. Every
    field is checked when the options are made: a wrong type or value raises ``ValueError``
    naming the field.

    Attributes
    ----------
    fit_theta0 : bool
        ``method="arx"``: estimate the initial angle of the simulated model (default) instead of
        taking the first, noisy, sample. The other estimators always estimate every segment's
        initial angle and velocity; ``False`` is refused there.
    friction : bool
        Also estimate a Coulomb friction voltage f_c >= 0 acting against the *velocity*, with
        sticking at rest (``simulate_motor``). K and f_c are separable only if the record has
        at least two speed levels; friction and offset only if the motor turns both ways.
    offset : bool
        Also estimate an input offset (V): the motor sees u + offset.
    delay : int or True
        Pure input delay in whole samples: an int (>= 0) is taken as known; ``True`` estimates
        it over 0 .. ``max_delay`` (inverse-dynamics residual, then the output-error cost around
        it). ``False`` is 0.
    dead_zone : bool
        Also estimate an input dead zone (V) >= 0: the motor sees sign(x) max(|x| - dz, 0) of
        x = u + offset. Separable from friction only where the motor brakes or reverses.
    segment : float, optional
        Multiple-shooting segment length (s), at least 10 samples. Default: one segment per
        record of at most 1000 samples, else segments of 500 samples.
    max_delay : int
        Largest delay tried with ``delay=True``.
    cutoff : float, optional
        Cut-off (Hz) of the low-pass filter of the inverse-dynamics regression; default
        1/(10 Ts) (a fifth of the Nyquist frequency).
    coast : bool or "coulomb"
        True: also estimate ``tau_coast``, the time constant while the drive is *open* at u = 0
        (a switch or bridge that floats the motor: no back-EMF braking, the motor runs down on
        its mechanical friction; ``simulate_motor``). It is estimated as the rate
        1/tau_coast >= 0; with ``friction=True`` the coasting motor also decelerates by the same
        Coulomb torque, K friction / tau. "coulomb" (needs ``friction=True``): the open motor
        has no viscous drag (tau_coast = inf) and runs down on Coulomb friction alone, the model
        to choose when ``coast=True`` reports its rate at the bound 0. ``method="pem"`` only;
        u = 0 must occur in the record, and an offset or dead zone is then seen only at the
        non-zero levels.
    """

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
        for name in ("friction", "offset", "dead_zone", "fit_theta0"):
            value = getattr(self, name)
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {value!r}")
            object.__setattr__(self, name, bool(value))
        coast = self.coast
        if not (isinstance(coast, (bool, np.bool_)) or coast == "coulomb"):
            raise ValueError(f"coast must be True, False or 'coulomb', got {coast!r}")
        object.__setattr__(self, "coast", coast if coast == "coulomb" else bool(coast))
        if self.coast == "coulomb" and not self.friction:
            raise ValueError(
                "coast='coulomb' (the open motor runs down on Coulomb friction alone) needs "
                "friction=True; without friction it would never stop"
            )
        if self.delay is not True:
            delay = 0 if self.delay is False else as_int("delay", self.delay, minimum=0)
            object.__setattr__(self, "delay", delay)
        object.__setattr__(self, "max_delay", as_int("max_delay", self.max_delay, minimum=0))
        if self.segment is not None:
            object.__setattr__(self, "segment", as_positive("segment", self.segment))
        if self.cutoff is not None:
            object.__setattr__(self, "cutoff", as_positive("cutoff", self.cutoff))

    @classmethod
    def of(cls, options=None, keywords=None) -> FitOptions:
        """``options`` (a FitOptions or None) with the ``keywords`` of a call applied on top."""
        keywords = dict(keywords or {})
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(keywords) - fields)
        if unknown:
            raise TypeError(
                f"fit_dc_motor() got an unexpected keyword argument {unknown[0]!r}; "
                f"the options are {', '.join(sorted(fields))}"
            )
        if options is None:
            return cls(**keywords)
        if not isinstance(options, cls):
            raise ValueError(f"options must be a FitOptions, got {type(options).__name__}")
        return dataclasses.replace(options, **keywords) if keywords else options

    @property
    def estimate_delay(self) -> bool:
        """True when the delay is estimated (``delay=True``)."""
        return self.delay is True

    @property
    def terms(self) -> dict:
        """``{"friction": bool, "offset": bool, "dead_zone": bool}``: the input-map terms."""
        return {name: getattr(self, name) for name in TERMS}

    @property
    def names(self) -> list:
        """The estimated physical parameters, in the order of ``MotorFit.covariance``."""
        names = ["K", "tau"] + [name for name in TERMS if getattr(self, name)]
        return names + ["tau_coast"] if self.coast is True else names

    @property
    def is_linear(self) -> bool:
        """True when the model is Stojčić eq. 1 alone (apart from a known or estimated delay)."""
        return not (any(self.terms.values()) or self.coast)


# ----------------------------------------------------------------------------------------------
# step 2: the records, and what the options ask of them
# ----------------------------------------------------------------------------------------------
def _check_sample_period(Ts) -> float:
    Ts = as_positive("Ts", Ts)
    if not FIT_TS_RANGE[0] <= Ts <= FIT_TS_RANGE[1]:
        # the fit scales with Ts (tau ~ Ts); far outside this range its covariance under/overflows
        raise ValueError(
            f"Ts must lie within {FIT_TS_RANGE[0]:g} … {FIT_TS_RANGE[1]:g} s (FIT_TS_RANGE: the "
            f"sample period of a motor record), got {Ts:g}"
        )
    return Ts


def _experiments(u, theta) -> list:
    """One record (two 1-D arrays) or several (two sequences of 1-D arrays) -> [(u, theta), ...],
    each checked: finite, the same length, at least ``MIN_SAMPLES``, u and theta not constant."""

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


def _check_records(method: str, opts: FitOptions, exps: list) -> None:
    """Refuse what the estimator cannot do with these records before fitting anything."""
    if method == "arx" and (
        any(opts.terms.values()) or opts.estimate_delay or opts.delay or len(exps) > 1
    ):
        raise ValueError(
            "friction, offset, dead_zone, delay and merged experiments need method='pem' "
            "or 'idim' (ARX has no such terms)"
        )
    if opts.coast and method != "pem":
        raise ValueError(
            f"coast={opts.coast!r} needs method='pem' (the output-error fit), got method={method!r}"
        )
    if not opts.fit_theta0 and method != "arx":
        raise ValueError(
            f"fit_theta0=False (the first sample as the initial angle) applies to method='arx' "
            f"only: method={method!r} estimates every segment's initial angle and velocity"
        )
    u_all = np.concatenate([uu for uu, _ in exps])
    if opts.coast and not np.any(u_all == 0.0):
        raise ValueError(
            "coast: u is never exactly 0, so the drive is never open; fit without coast"
        )
    if opts.offset or opts.dead_zone:
        _check_input_levels(opts, u_all)


def _check_input_levels(opts: FitOptions, u_all: np.ndarray) -> None:
    """The static map u -> K dz(u + offset) is only seen at the levels u takes: K, offset and dead
    zone need 1 + offset + dead_zone distinct (driven) levels. Without an offset, dz(0) = 0 and dz
    is odd, so u = 0 tells nothing and -l says what l says: count distinct non-zero |u|."""
    levels = np.unique(u_all if opts.offset else np.abs(u_all))
    if opts.coast or not opts.offset:
        levels = levels[levels != 0.0]
    need = 1 + int(opts.offset) + int(opts.dead_zone)
    if levels.size >= need:
        return
    shown = ", ".join(f"{lv:.4g}" for lv in levels[:4]) + (" ..." if levels.size > 4 else "")
    which = [
        nm for nm, on in (("K", True), ("offset", opts.offset), ("dead_zone", opts.dead_zone)) if on
    ]
    which = ", ".join(which[:-1]) + " and " + which[-1]
    name = "dead_zone" if opts.dead_zone else "offset"
    raise ValueError(
        f"{name}: the {'driven ' if opts.coast else ''}input takes only "
        f"{levels.size} distinct level{'s' if levels.size > 1 else ''} ({shown} V), and the motor "
        f"sees K dz(u + offset) only at those levels, so {which} ({need} parameters) cannot be "
        f"separated: the fit would trade them off without bound. Drop {name}, or record an "
        f"input with at least {need} levels"
    )


def _segment_samples(opts: FitOptions, Ts: float, exps: list):
    """Samples per shooting segment, or None for one segment per record."""
    if opts.segment is None:
        return None if max(uu.size for uu, _ in exps) <= 1000 else 500
    segment_n = int(round(opts.segment / Ts))
    if segment_n < 10:
        raise ValueError(
            f"segment must be at least 10 samples ({10 * Ts:g} s), got {opts.segment:g} s"
        )
    return segment_n


# ----------------------------------------------------------------------------------------------
# step 4: inverse dynamics, the estimate of "idim" and the start of "pem"
# ----------------------------------------------------------------------------------------------
def _inverse_dynamics(exps, Ts, opts, cutoff, segment_n, iv_iterations):
    """The inverse-dynamics least squares at the delay (or, with ``delay=True``, the delay of
    0 .. ``max_delay`` with the least residual): ``(delay, p, cov_p)``, or None when the
    regression fails at every delay (too few moving samples)."""
    delays = range(0, opts.max_delay + 1) if opts.estimate_delay else [opts.delay]
    best = None
    for d in delays:
        try:
            p, cov_p, sse, _ = _idim(exps, Ts, d, opts.terms, cutoff)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if best is None or sse < best[3]:
            best = (d, p, cov_p, sse)
    if best is None:
        return None
    delay, p, cov_p, _ = best
    if iv_iterations:
        p, cov_p, _, _ = _idim(
            exps, Ts, delay, opts.terms, cutoff, iv_iterations=iv_iterations, segment_n=segment_n
        )
    return delay, p, cov_p


def _idim_result(exps, Ts, opts, cutoff, segment_n, delay, p, cov_p, u_abs_max) -> dict:
    """The inverse-dynamics estimate as the physical parameters, their covariance (delta method
    from (tau/K, 1/K, ...)) and the model simulated on the records (re-started per segment from
    the filtered measured state, as the instruments are)."""
    par = _params_from_idim(p, opts.terms)
    names = opts.names
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
    return dict(
        par=par,
        cov=cov,
        y_sim=y_sim,
        theta=theta,
        delay=delay,
        nfev=0,
        s=s,
        nseg=1,
        theta0=float(theta[0]),
        omega0=0.0,
        warnings=_diagnose(par, cov, names, u_abs_max),
    )


# ----------------------------------------------------------------------------------------------
# step 5: output error by multiple shooting
# ----------------------------------------------------------------------------------------------
def _start(exps, Ts, opts, idim_par, delay, segment_n, u_abs_max) -> dict:
    """The start of the output-error fit. The linear model: its exact optimum over tau by variable
    projection (``jerklab.ident.output_error._linear_start``), with every segment's state. With
    friction, offset, dead zone or coasting: the inverse-dynamics parameters when they describe a
    motor, else (a reversed encoder, K < 0, or a failed regression) the linear grid on the longest
    record; friction and dead zone moved well inside (0, max |u|)."""
    if opts.is_linear:
        return _linear_start(exps, Ts, delay, segment_n)
    par = idim_par
    if par is None or not (par["K"] > 0 and par["tau"] > 0 and math.isfinite(par["K"])):
        u_long, theta_long = max(exps, key=lambda e: e[0].size)
        K0, tau0, _ = _grid_start(u_long, theta_long, Ts)
        par = {"K": K0, "tau": tau0, "friction": 0.0, "offset": 0.0, "dead_zone": 0.0}
    par = dict(par)
    # the inverse-dynamics value can be far off, and a start near max |u| lets the fit trade a
    # huge K against a dead zone that swallows the whole input
    for nm in ("friction", "dead_zone"):
        if getattr(opts, nm):
            par[nm] = min(max(par[nm], 0.01 * u_abs_max), 0.5 * u_abs_max)
    return par


def _output_error(exps, Ts, opts, cutoff, segment_n, delay, start, u_abs_max) -> dict:
    """Multiple-shooting output error at ``delay``; with ``delay=True`` also at its neighbours
    (a few iterations from that optimum: a neighbour only has to show a higher cost; a full fit
    if it wins)."""
    model = dict(opts.terms, coast=opts.coast)
    budget, tol = OE_LINEAR if opts.is_linear else OE_EXTENDED
    candidates = [delay]
    if opts.estimate_delay:
        candidates += sorted({max(delay - 1, 0), min(delay + 1, opts.max_delay)} - {delay})

    def fit(d, init, max_nfev):
        return _fit_oe_ms(exps, Ts, d, model, init, segment_n, cutoff, max_nfev, tol)

    res = fit(delay, start, budget)
    for d in candidates[1:]:
        r_ = fit(d, res["par"], 15)
        if r_["cost"] < res["cost"]:
            res, delay = fit(d, r_["par"], budget), d
    return dict(
        par=res["par"],
        cov=res["cov"],
        y_sim=res["y_sim"],
        theta=res["theta"],
        delay=delay,
        nfev=res["nfev"],
        s=res["s"],
        nseg=res["nseg"],
        theta0=float(res["seg_theta0"][0]),
        omega0=float(res["seg_omega0"][0]),
        warnings=_diagnose(res["par"], res["cov"], opts.names, u_abs_max, res["at_bound"]),
    )


# ----------------------------------------------------------------------------------------------
# step 6: the result
# ----------------------------------------------------------------------------------------------
def _motor_fit(method, Ts, opts, n_experiments, r) -> MotorFit:
    """The :class:`MotorFit` of an inverse-dynamics or output-error result ``r``."""
    par, cov, names = dict(r["par"]), r["cov"], opts.names
    par.setdefault("tau_coast", 0.0)
    std = dict(zip(names, np.sqrt(np.clip(np.diag(cov), 0.0, None))))
    K, tau = float(par["K"]), float(par["tau"])
    y_sim, theta = r["y_sim"], r["theta"]
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
        theta0=r["theta0"],
        cov=cov[:2, :2].copy(),
        y_sim=y_sim,
        residuals=theta - y_sim,
        noise_std=float(r["s"]),
        nfev=int(r["nfev"]),
        friction=float(par["friction"]),
        friction_std=float(std.get("friction", 0.0)),
        offset=float(par["offset"]),
        offset_std=float(std.get("offset", 0.0)),
        dead_zone=float(par["dead_zone"]),
        dead_zone_std=float(std.get("dead_zone", 0.0)),
        delay=int(r["delay"]),
        estimated=tuple(names),
        covariance=cov,
        warnings=r["warnings"],
        n_segments=int(r["nseg"]),
        n_experiments=n_experiments,
        omega0=r["omega0"],
        tau_coast=float(par["tau_coast"]),
        tau_coast_std=float(std.get("tau_coast", 0.0)),
    )


def fit_dc_motor(u, theta, Ts, method: str = "pem", *, options=None, **keywords) -> MotorFit:
    """Identify K and tau of P(s) = K/(s(tau s + 1)) (Stojčić eq. 1, §4A) from a voltage/angle record.

    The paper ran MATLAB's ``pem(iddata(y, u, Ts), 'P2')``; 'P2' has no integrator, so this fits
    the structure Stojčić eq. 1 actually has, a pole plus an integrator ('P1I'). Options add what
    real records carry: Coulomb friction by the sign of the velocity (with sticking), an input
    offset, an input dead zone, a pure delay and an open drive (see
    ``jerklab.ident.simulate_motor`` for the model).

    Parameters
    ----------
    u : array_like, or list of array_like
        Motor voltage samples (V), held over each sample period: the *logged* input, open loop or
        closed loop. A list of records (with ``theta`` a list of the same length) merges several
        experiments for one estimate (MATLAB's ``merge``); see also ``jerklab.ident.merge``.
    theta : array_like, or list of array_like
        Measured angle (rad), same length as ``u``; sample k read at k Ts, before ``u[k]`` acts.
    Ts : float
        Sample period (s), within ``FIT_TS_RANGE``.
    method : {"pem", "arx", "idim", "idim-iv"}
        "pem": output error, by **multiple shooting**: the record is cut into segments (one for a
        record of at most 1000 samples), each with its own estimated initial angle and
        velocity, and K, tau (and the options) are shared; so neither a closed-loop record nor
        an integrating plant can drift over a long record (Ljung §4.2 output error; started by
        the inverse-dynamics estimate below). The standard errors come from s^2 (J^T J)^-1 at
        the optimum.
        "arx": least squares on the differenced angle v(k) = a v(k-1) + b1 u(k-1) + b2 u(k-2)
        (exact for the ZOH model), K = (b1 + b2)/(1 - a), tau = -Ts/ln a; biased (tau short)
        under noise (``arx_asymptotic_bias``). No options.
        "idim": the inverse-dynamics least squares of motion-control practice (Gautier & Janot):
        u = (tau/K) omega' + omega/K + f_c sign(omega) - offset + dead_zone sign(u) on the
        low-passed angle's derivatives, every column and u filtered by the same zero-phase
        Butterworth filter (parallel filtering). Fast, linear, any record; errors-in-variables
        bias under noise. "idim-iv": the same with instrumental variables built from the model's
        own simulated angle (re-started on each segment), iterated (Janot, Vandanjon & Gautier
        2014; Ljung §7.6), which removes most of that bias.
    options : FitOptions, optional
        The options as one object; keywords given as well replace its fields.
    **keywords
        The fields of :class:`FitOptions`, by name: ``fit_theta0``, ``friction``, ``offset``,
        ``delay``, ``dead_zone``, ``segment``, ``max_delay``, ``cutoff``, ``coast``.

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
        or ``theta``, a ``Ts`` outside ``FIT_TS_RANGE``, an unknown ``method`` or a bad option, or
        data from which the ARX pole falls outside (0, 1). Also an input with too few distinct
        levels for the input map asked for: the motor sees K dz(u + offset) only at the levels u
        takes, so K, ``offset`` and ``dead_zone`` need at least 1 + offset + dead_zone distinct
        (driven) levels (without an offset, distinct non-zero magnitudes |u|); a two-level input
        (a PRBS, a step) cannot separate all three, nor K and a dead zone alone.
    TypeError
        A keyword that is not an option.

    References
    ----------
    Stojčić (2015) §4A and Stojčić eq. 1; L. Ljung, *System Identification* (2nd ed.), §4.2 (output
    error), §7.3 and §9.3 (least squares, asymptotic covariance), §7.6 (instrumental variables),
    §16 (model validation); M. Gautier, "Dynamic identification of robots with power model",
    ICRA 1997, and A. Janot, P.-O. Vandanjon, M. Gautier, "A generic instrumental variable
    approach for industrial robot identification", IEEE TCST 22(1), 2014 (IDIM-LS, IDIM-IV).
    """
    if method not in METHODS:
        raise ValueError(f"method must be 'pem', 'arx', 'idim' or 'idim-iv', got {method!r}")
    opts = FitOptions.of(options, keywords)
    Ts = _check_sample_period(Ts)
    exps = _experiments(u, theta)
    cutoff = 0.1 / Ts if opts.cutoff is None else opts.cutoff
    segment_n = _segment_samples(opts, Ts, exps)
    _check_records(method, opts, exps)
    u_abs_max = max(float(np.max(np.abs(uu))) for uu, _ in exps)
    if method == "arx":
        fit = fit_velocity_arx(exps[0][0], exps[0][1], Ts, opts.fit_theta0)
        par = {"K": fit.K, "tau": fit.tau, "friction": 0.0, "offset": 0.0, "dead_zone": 0.0}
        fit.warnings = _diagnose(par, fit.cov, ["K", "tau"], u_abs_max)
        _issue(fit.warnings)
        return fit
    iv = IV_ITERATIONS if method == "idim-iv" else 0
    # the output-error fit of the linear model needs the inverse dynamics only to find the delay
    needed = method != "pem" or not opts.is_linear or opts.estimate_delay
    found = _inverse_dynamics(exps, Ts, opts, cutoff, segment_n, iv) if needed else None
    if method == "pem":
        delay = found[0] if found else (0 if opts.estimate_delay else opts.delay)
        idim_par = _params_from_idim(found[1], opts.terms) if found else None
        start = _start(exps, Ts, opts, idim_par, delay, segment_n, u_abs_max)
        r = _output_error(exps, Ts, opts, cutoff, segment_n, delay, start, u_abs_max)
    elif found is None:
        raise ValueError("theta: the inverse-dynamics regression failed (too few moving samples)")
    else:
        r = _idim_result(exps, Ts, opts, cutoff, segment_n, *found, u_abs_max)
    _issue(r["warnings"])
    return _motor_fit(method, Ts, opts, len(exps), r)
