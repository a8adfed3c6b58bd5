"""The motor fit: :func:`fit_dc_motor` and its result :class:`MotorFit` (Stojčić eq. 1, §4A; ASCII:
Stojcic)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from jerklab._lazy import lazy_module
from jerklab._validate import as_int, as_positive, as_real
from jerklab.ident._common import _check_excitation, _pair, _signal, fit_percent
from jerklab.ident.arx import ARXResult, _fit_arx
from jerklab.ident.diagnostics import _diagnose, _issue
from jerklab.ident.idim import _idim, _params_from_idim, _shooting_sim
from jerklab.ident.model import _best_theta0, _unit_response, simulate_dc_motor, simulate_motor
from jerklab.ident.oe import _fit_oe_ms, _fit_pem, _initial_guess
from jerklab.plant import DCMotor

control = lazy_module("control")  # python-control imports matplotlib: import it on first use


@dataclass
class MotorFit:
    """K and tau of P(s) = K/(s(tau s + 1)) (Stojčić eq. 1) with their uncertainty.

    Attributes
    ----------
    K, tau : float
        Gain rad/(V s) and time constant s.
    K_std, tau_std : float
        One-sigma standard errors (from the Jacobian for PEM, from the ARX covariance for ARX).
    fit_percent : float
        Simulation fit (NRMSE %, as MATLAB ``compare``) of the angle on the estimation data.
    model : control.TransferFunction
        K / (tau s^2 + s), volts -> rad.
    method : str
        "pem" or "arx".
    Ts : float
        Sample period of the data (s).
    theta0 : float
        Initial angle of the simulation (estimated).
    cov : ndarray
        2x2 covariance of (K, tau).
    y_sim, residuals : ndarray
        Simulated angle on the estimation data and measured - simulated.
    noise_std : float
        Residual standard deviation (rad for PEM; the equation-error scale for ARX).
    friction, friction_std : float
        Coulomb friction voltage f_c (V) by the sign of the velocity, with sticking, and its standard
        error (``friction=True``; 0.0 and 0.0 when not estimated).
    offset, offset_std : float
        Input offset (V): the motor sees ``u + offset`` (``offset=True``; else 0.0, 0.0).
    dead_zone, dead_zone_std : float
        Input dead zone (V) after the offset (``dead_zone=True``; else 0.0, 0.0).
    delay : int
        Pure input delay in whole samples (given or estimated with ``delay=True``).
    tau_coast, tau_coast_std : float
        Time constant (s) while the drive is open at u = 0 (``coast=True``; :func:`simulate_motor`),
        and its standard error; 0.0 and 0.0 when the drive always holds u.
    estimated : tuple of str
        The estimated parameters, in the order of ``covariance``.
    warnings : list of str
        The diagnostics the fit raised (also issued as :class:`IdentificationWarning`).

    The full model (:func:`simulate_motor`) is
    ``tau omega' = K (dz(u(t - delay Ts) + offset) - friction sign(omega)) - omega``, sticking at
    omega = 0 while ``|dz(u + offset)| <= friction``; ``dz(x) = sign(x) max(|x| - dead_zone, 0)``.
    """

    K: float
    tau: float
    K_std: float
    tau_std: float
    fit_percent: float
    model: control.TransferFunction
    method: str
    Ts: float
    theta0: float
    cov: np.ndarray
    y_sim: np.ndarray = field(repr=False)
    residuals: np.ndarray = field(repr=False)
    noise_std: float = float("nan")
    arx_result: ARXResult | None = field(default=None, repr=False)
    nfev: int = 0
    friction: float = 0.0  #: Coulomb friction voltage f_c (V); 0.0 when not estimated
    friction_std: float = 0.0  #: its standard error (V); 0.0 when fixed
    offset: float = 0.0  #: input offset (V): the motor sees u + offset
    offset_std: float = 0.0
    dead_zone: float = 0.0  #: input dead zone (V), after the offset
    dead_zone_std: float = 0.0
    delay: int = 0  #: pure input delay (whole samples)
    estimated: tuple = ("K", "tau")  #: names of the estimated parameters, in ``covariance`` order
    covariance: np.ndarray | None = field(default=None, repr=False)  #: covariance of ``estimated``
    warnings: list = field(default_factory=list, repr=False)  #: diagnostics raised by the fit
    n_segments: int = 1  #: shooting segments of the output-error fit
    n_experiments: int = 1  #: experiments merged in the estimation data
    omega0: float = 0.0  #: initial velocity of the first segment (rad/s)
    tau_coast: float = 0.0  #: time constant (s) with the drive open at u = 0; 0.0: no coasting
    tau_coast_std: float = 0.0

    def simulate(self, u, theta0=0.0, omega0=0.0) -> np.ndarray:
        """The fitted model's ZOH response to ``u`` (see :func:`simulate_dc_motor`).

        With friction, offset, dead zone or delay, the full model of :func:`simulate_motor`
        (friction by the sign of the velocity, with sticking).
        """
        u = _signal("u", u, min_len=1)
        if not self.is_linear:
            return simulate_motor(
                self.K,
                self.tau,
                self.Ts,
                u,
                theta0,
                omega0,
                self.friction,
                self.offset,
                self.dead_zone,
                self.delay,
                self.tau_coast or None,
            )
        return simulate_dc_motor(self.K, self.tau, self.Ts, u, theta0, omega0)

    @property
    def is_linear(self) -> bool:
        """True when the model is Stojčić eq. 1 alone (no friction, offset, dead zone or delay)."""
        return not (self.friction or self.offset or self.dead_zone or self.delay or self.tau_coast)

    @property
    def std(self) -> dict:
        """Standard errors by name: K, tau, friction, offset, dead_zone, tau_coast (0.0 when fixed)."""
        return {
            "K": self.K_std,
            "tau": self.tau_std,
            "friction": self.friction_std,
            "offset": self.offset_std,
            "dead_zone": self.dead_zone_std,
            "tau_coast": self.tau_coast_std,
        }

    def confidence_interval(self, level: float = 0.95):
        """Normal-approximation intervals ``{"K": (lo, hi), "tau": (lo, hi), ...}`` for every
        estimated parameter (friction, offset, dead_zone, tau_coast when estimated)."""
        level = as_real("level", level)
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must be in (0, 1), got {level}")
        z = stats.norm.ppf(0.5 + level / 2)
        out = {}
        for name in ("K", "tau", "friction", "offset", "dead_zone", "tau_coast"):
            if name in ("K", "tau") or name in self.estimated:
                v, sd = getattr(self, name), self.std[name]
                out[name] = (v - z * sd, v + z * sd)
        return out

    def to_motor(self, **kwargs):
        """A ``jerklab.plant.DCMotor`` with the fitted K and tau (other arguments passed on).

        The plant has no open-drive (coasting) mode: a fit with ``tau_coast`` raises ValueError
        (simulate it with :meth:`simulate` or :func:`simulate_motor`)."""
        if self.tau_coast:
            raise ValueError(
                "tau_coast: jerklab.plant.DCMotor has no open-drive (coasting) mode; "
                "use fit.simulate or ident.simulate_motor(..., tau_coast=fit.tau_coast)"
            )

        kw = dict(
            coulomb_friction=max(self.friction, 0.0),
            offset=self.offset,
            dead_zone=max(self.dead_zone, 0.0),
        )
        kw.update(kwargs)
        return DCMotor(K=self.K, tau=self.tau, **kw)

    def summary(self) -> str:
        """One line: K ± std, tau ± std, (friction ± std), fit %."""
        fr = ""
        if "friction" in self.estimated:
            fr += f", f_c = {self.friction:.3g} ± {self.friction_std:.2g} V"
        if "offset" in self.estimated:
            fr += f", offset = {self.offset:.3g} ± {self.offset_std:.2g} V"
        if "dead_zone" in self.estimated:
            fr += f", dead zone = {self.dead_zone:.3g} ± {self.dead_zone_std:.2g} V"
        if self.delay:
            fr += f", delay = {self.delay} sample{'s' if self.delay > 1 else ''}"
        if "tau_coast" in self.estimated:
            fr += f", tau_coast = {self.tau_coast * 1e3:.4g} ± {self.tau_coast_std * 1e3:.2g} ms"
        elif self.tau_coast == math.inf:
            fr += ", coasting on Coulomb friction (tau_coast = inf)"
        return (
            f"{self.method.upper():>3}: K = {self.K:.4g} ± {self.K_std:.2g} rad/(V s), "
            f"tau = {self.tau * 1e3:.4g} ± {self.tau_std * 1e3:.2g} ms{fr}, "
            f"fit = {self.fit_percent:.2f} %"
        )


def _motor_tf(K, tau):
    return control.tf([K], [tau, 1.0, 0.0])


#: the sample periods :func:`fit_dc_motor` accepts (s): 1 ns … 1000 s. The fit scales with Ts, and far
#: outside this range its covariance under/overflows to NaN/inf (Ts = 1e-300 gives K_std = NaN)
FIT_TS_RANGE = (1e-9, 1e3)


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
        "pem": output error. Without options, on one record of at most 1000 samples, the fit of
        earlier versions: minimise sum (theta - theta_sim(K, tau, theta0))^2 over the exact ZOH
        simulation from rest. Otherwise (friction, offset, dead zone, delay, several experiments,
        a long record or ``segment``) **multiple shooting**: the record is cut into segments,
        each with its own estimated initial angle and velocity, and K, tau (and the options) are
        shared; so neither a closed-loop record nor an integrating plant can drift over a long
        record (Ljung §4.2 output error; the segments are started by the inverse-dynamics estimate
        below). The standard errors come from s^2 (J^T J)^-1 at the optimum.
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
        Estimate the initial angle (default) instead of trusting the first, noisy, sample
        (legacy PEM path; the multiple-shooting fit always estimates every segment's state).
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
        1000 samples, else segments of 500 samples.
    max_delay : int
        Largest delay tried with ``delay=True``.
    cutoff : float, optional
        Cut-off (Hz) of the low-pass filter of the inverse-dynamics regression; default
        1/(10 Ts) (a fifth of the Nyquist frequency).
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
        or ``theta``, a ``Ts`` outside ``FIT_TS_RANGE``, an unknown ``method`` or option, or data from which
        the ARX pole falls outside (0, 1). Also an input with too few distinct levels for the
        input map asked for: the motor sees K dz(u + offset) only at the levels u takes, so K,
        ``offset`` and ``dead_zone`` need at least 1 + offset + dead_zone distinct (driven) levels
        (without an offset, distinct non-zero magnitudes |u|); a two-level input (a PRBS, a step)
        cannot separate all three, nor K and a dead zone alone.

    References
    ----------
    Stojčić (2015) §4A and Stojčić eq. 1; L. Ljung, *System Identification* (2nd ed.), §4.2 (output
    error), §7.3 and §9.3 (least squares, asymptotic covariance), §7.6 (instrumental variables),
    §16 (model validation); M. Gautier, "Dynamic identification of robots with power model",
    ICRA 1997, and A. Janot, P.-O. Vandanjon, M. Gautier, "A generic instrumental variable
    approach for industrial robot identification", IEEE TCST 22(1), 2014 (IDIM-LS, IDIM-IV).
    """
    if method not in ("pem", "arx", "idim", "idim-iv"):
        raise ValueError(f"method must be 'pem', 'arx', 'idim' or 'idim-iv', got {method!r}")
    for nm, val in (
        ("friction", friction),
        ("offset", offset),
        ("dead_zone", dead_zone),
        ("fit_theta0", fit_theta0),
    ):
        if not isinstance(val, (bool, np.bool_)):
            raise ValueError(f"{nm} must be True or False, got {val!r}")
    if not (isinstance(coast, (bool, np.bool_)) or coast == "coulomb"):
        raise ValueError(f"coast must be True, False or 'coulomb', got {coast!r}")
    coast = coast if coast == "coulomb" else bool(coast)
    if coast == "coulomb" and not friction:
        raise ValueError(
            "coast='coulomb' (the open motor runs down on Coulomb friction alone) needs "
            "friction=True; without friction it would never stop"
        )
    estimate_delay = delay is True
    if not estimate_delay:
        if delay is False:
            delay = 0
        delay = as_int("delay", delay, minimum=0)
    max_delay = as_int("max_delay", max_delay, minimum=0)
    Ts = as_positive("Ts", Ts)
    if not FIT_TS_RANGE[0] <= Ts <= FIT_TS_RANGE[1]:
        # the fit scales with Ts (tau ~ Ts); far outside this range its covariance under/overflows
        raise ValueError(
            f"Ts must lie within {FIT_TS_RANGE[0]:g} … {FIT_TS_RANGE[1]:g} s (FIT_TS_RANGE: the "
            f"sample period of a motor record), got {Ts:g}"
        )
    exps = _as_experiments(u, theta)
    for i, (uu, tt) in enumerate(exps):
        suffix = "" if len(exps) == 1 else f"[{i}]"
        _check_excitation(uu, tt, "u" + suffix, "theta" + suffix)
    n_total = sum(uu.size for uu, _ in exps)
    if cutoff is None:
        cutoff = 0.1 / Ts
    else:
        cutoff = as_positive("cutoff", cutoff)
    if segment is None:
        segment_n = None if max(uu.size for uu, _ in exps) <= 1000 else 500
    else:
        segment_n = int(round(as_positive("segment", segment) / Ts))
        if segment_n < 10:
            raise ValueError(
                f"segment must be at least 10 samples ({10 * Ts:g} s), got {segment:g} s"
            )
    opts = {"friction": bool(friction), "offset": bool(offset), "dead_zone": bool(dead_zone)}
    extended = (
        any(opts.values())
        or coast
        or estimate_delay
        or delay
        or len(exps) > 1
        or segment_n is not None
    )
    if method == "arx" and (
        extended and (any(opts.values()) or estimate_delay or delay or len(exps) > 1)
    ):
        raise ValueError(
            "friction, offset, dead_zone, delay and merged experiments need method='pem' "
            "or 'idim' (ARX has no such terms)"
        )
    if coast and method != "pem":
        raise ValueError(
            f"coast={coast!r} needs method='pem' (the output-error fit), got method={method!r}"
        )
    u_all = np.concatenate([uu for uu, _ in exps])
    if coast and not np.any(u_all == 0.0):
        raise ValueError(
            "coast: u is never exactly 0, so the drive is never open; fit without coast"
        )
    if offset or dead_zone:
        # the static map u -> K dz(u + offset) is only seen at the levels u takes
        # (without an offset, dz(0) = 0 and dz is odd: u = 0 tells nothing, and -l says what l says)
        levels = np.unique(u_all if offset else np.abs(u_all))
        if coast or not offset:
            levels = levels[levels != 0.0]
        need = 1 + int(bool(offset)) + int(bool(dead_zone))
        if levels.size < need:
            shown = ", ".join(f"{lv:.4g}" for lv in levels[:4]) + (
                " ..." if levels.size > 4 else ""
            )
            which = [
                nm for nm, on in (("K", True), ("offset", offset), ("dead_zone", dead_zone)) if on
            ]
            which = ", ".join(which[:-1]) + " and " + which[-1]
            raise ValueError(
                f"{'dead_zone' if dead_zone else 'offset'}: the {'driven ' if coast else ''}input takes only "
                f"{levels.size} distinct level{'s' if levels.size > 1 else ''} ({shown} V), and the motor sees "
                f"K dz(u + offset) only at those levels, so {which} ({need} parameters) cannot be "
                f"separated: the fit would trade them off without bound. Drop "
                f"{'dead_zone' if dead_zone else 'offset'}, or record an input with at least {need} levels"
            )
    u_abs_max = max(float(np.max(np.abs(uu))) for uu, _ in exps)
    if method in ("arx",) or (method == "pem" and not extended):
        fit = _fit_legacy(exps[0][0], exps[0][1], Ts, method, fit_theta0)
        names = ["K", "tau"]
        par = {"K": fit.K, "tau": fit.tau, "friction": 0.0, "offset": 0.0, "dead_zone": 0.0}
        fit.warnings = _diagnose(par, fit.cov, names, u_abs_max)
        _issue(fit.warnings)
        return fit

    # -- inverse dynamics: the estimate (idim) or the start (pem) ----------------------------
    delays = range(0, max_delay + 1) if estimate_delay else [delay]
    idim_iv = 4 if method == "idim-iv" else 0
    best = None
    for d in delays:
        try:
            p, cov_p, sse, _ = _idim(exps, Ts, d, opts, cutoff)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if best is None or sse < best[2]:
            best = (d, p, sse)
    if best is None:
        raise ValueError("theta: the inverse-dynamics regression failed (too few moving samples)")
    delay = best[0]
    p, cov_p, _, _ = _idim(
        exps, Ts, delay, opts, cutoff, iv_iterations=idim_iv, segment_n=segment_n
    )
    par = _params_from_idim(p, opts)
    names = ["K", "tau"] + [nm for nm in ("friction", "offset", "dead_zone") if opts[nm]]
    if coast is True:
        names.append("tau_coast")
    opts = dict(opts, coast=coast)
    if method in ("idim", "idim-iv"):
        Jt = np.zeros((len(names), p.size))
        a_, b_ = p[0], p[1]
        Jt[0, 1] = -1.0 / b_**2
        Jt[1, 0], Jt[1, 1] = 1.0 / b_, -a_ / b_**2
        for i in range(2, len(names)):
            Jt[i, i] = 1.0
        cov = Jt @ cov_p @ Jt.T
        ys, th_all = [], []
        for uu, tt in exps:
            if par["K"] > 0 and par["tau"] > 0:
                ys.append(_shooting_sim(uu, tt, Ts, par, delay, cutoff, segment_n))
            else:
                ys.append(np.full(tt.size, np.nan))
            th_all.append(tt)
        y_sim = np.concatenate(ys)
        theta_c = np.concatenate(th_all)
        resid = theta_c - y_sim
        msgs = _diagnose(par, cov, names, u_abs_max)
        s = float(np.sqrt(np.mean(resid**2))) if np.all(np.isfinite(resid)) else float("nan")
        nfev, nseg, th0 = 0, 1, float(theta_c[0])
        om0 = 0.0
        at_bound = []
    else:
        if not (par["K"] > 0 and par["tau"] > 0 and math.isfinite(par["K"])):
            # a reversed encoder (K < 0) or an unusable regression: start from the linear grid
            g_exp = max(exps, key=lambda e: e[0].size)
            K0, tau0, _, _ = _initial_guess(g_exp[0], g_exp[1], Ts, True, False)
            par = {"K": K0, "tau": tau0, "friction": 0.0, "offset": 0.0, "dead_zone": 0.0}
        # start friction and dead zone well inside (0, max |u|): the inverse-dynamics value can be
        # far off, and a start near max |u| lets the fit trade a huge K against a dead zone that
        # swallows the whole input
        for nm in ("friction", "dead_zone"):
            if opts[nm]:
                par[nm] = min(max(par[nm], 0.01 * u_abs_max), 0.5 * u_abs_max)
        # the inverse-dynamics delay first; then its neighbours, started from that optimum
        cands = (
            [delay]
            if not estimate_delay
            else [delay] + sorted({max(delay - 1, 0), min(delay + 1, max_delay)} - {delay})
        )
        # (a neighbour only has to show a higher cost: a few iterations, a full fit if it wins)
        res = None
        for d in cands:
            if res is None:
                res = _fit_oe_ms(exps, Ts, d, opts, par, segment_n, cutoff)
                continue
            r_ = _fit_oe_ms(exps, Ts, d, opts, res["par"], segment_n, cutoff, max_nfev=15)
            if r_["cost"] < res["cost"]:
                res, delay = _fit_oe_ms(exps, Ts, d, opts, r_["par"], segment_n, cutoff), d
        par, cov = res["par"], res["cov"]
        y_sim, theta_c = res["y_sim"], res["theta"]
        resid = theta_c - y_sim
        nfev, s, nseg, th0 = res["nfev"], res["s"], res["nseg"], float(res["seg_theta0"][0])
        om0 = float(res["seg_omega0"][0])
        msgs = _diagnose(par, cov, names, u_abs_max, res["at_bound"])
    _issue(msgs)
    par.setdefault("tau_coast", 0.0)
    std = dict(zip(names, np.sqrt(np.clip(np.diag(cov), 0.0, None))))
    K, tau = float(par["K"]), float(par["tau"])
    fp = fit_percent(theta_c, y_sim) if np.all(np.isfinite(y_sim)) else float("nan")
    return MotorFit(
        K=K,
        tau=tau,
        K_std=float(std["K"]),
        tau_std=float(std["tau"]),
        fit_percent=fp,
        model=_motor_tf(K, tau) if tau > 0 else control.tf([K], [1.0, 0.0]),
        method=method,
        Ts=Ts,
        theta0=th0,
        cov=cov[:2, :2].copy(),
        y_sim=y_sim,
        residuals=resid,
        noise_std=float(s),
        nfev=int(nfev),
        friction=float(par["friction"]),
        friction_std=float(std.get("friction", 0.0)),
        offset=float(par["offset"]),
        offset_std=float(std.get("offset", 0.0)),
        dead_zone=float(par["dead_zone"]),
        dead_zone_std=float(std.get("dead_zone", 0.0)),
        delay=int(delay),
        estimated=tuple(names),
        covariance=cov,
        warnings=msgs,
        n_segments=int(nseg),
        n_experiments=len(exps),
        omega0=om0,
        tau_coast=float(par["tau_coast"]),
        tau_coast_std=float(std.get("tau_coast", 0.0)),
    )


def _fit_legacy(u, theta, Ts, method, fit_theta0) -> MotorFit:
    """The linear single-record fits (ARX, and output error from rest) of earlier versions."""
    arx_res = None
    nfev = 0
    if method == "arx":
        K, tau, cov, arx_res = _fit_arx(u, theta, Ts)
        g = K * _unit_response(tau, Ts, u)
        th0 = _best_theta0(theta, g) if fit_theta0 else theta[0]
        noise_std = math.sqrt(arx_res.noise_variance) * Ts
        y_sim = g + th0
    else:
        K, tau, cov, th0, nfev, noise_std, _, _, y_sim = _fit_pem(u, theta, Ts, fit_theta0, False)
        if not (math.isfinite(K) and math.isfinite(tau)):
            raise ValueError("theta: the output-error fit did not converge")
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return MotorFit(
        K=float(K),
        tau=float(tau),
        K_std=float(std[0]),
        tau_std=float(std[1]),
        fit_percent=fit_percent(theta, y_sim),
        model=_motor_tf(K, tau),
        method=method,
        Ts=Ts,
        theta0=float(th0),
        cov=cov,
        y_sim=y_sim,
        residuals=theta - y_sim,
        noise_std=float(noise_std),
        arx_result=arx_res,
        nfev=int(nfev),
        covariance=cov.copy(),
    )


def _as_experiments(u, theta):
    """One record (two 1-D arrays) or several (two sequences of 1-D arrays) -> list of (u, theta)."""

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
        return [_pair(uu, tt, f"u[{i}]", f"theta[{i}]") for i, (uu, tt) in enumerate(zip(u, theta))]
    return [_pair(u, theta, "u", "theta")]
