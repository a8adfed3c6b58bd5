"""Output error with multiple shooting (the prediction-error method with an output-error noise model).

The parameters of the full motor model (:func:`jerklab.ident.simulate_motor`, Stojčić eq. 1
with friction, offset, dead zone, delay and coasting; ASCII: Stojcic) minimise
sum (theta - theta_sim)^2 over the record (Ljung, *System Identification*, §4.2). The record is
cut into segments, each started from its own estimated state (theta0, omega0), the model
parameters shared: Bock's multiple shooting without continuity constraints, so neither a
closed-loop record nor an integrating plant can drift over a long record. One segment is the
plain (single-shooting) output-error fit from an estimated initial state.

:class:`ShootingProblem` holds one such problem (the data, the segments, the delay), its start
and its solution; :func:`tau_grid_start` is the start that needs no other estimate (variable
projection over tau for Stojčić eq. 1 alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from jerklab.ident.covariance import grid_step, newey_west, quantization_covariance
from jerklab.ident.idim import _filtered_states
from jerklab.ident.model import _shift, _simulate_segments, _unit_response

#: the static terms of the input map the fit may estimate, in the order of its parameters
TERMS = ("friction", "offset", "dead_zone")


def tau_grid_start(u, theta, Ts):
    """Start (K, tau, theta0) of Stojčić eq. 1 by variable projection over tau on a log grid.

    For fixed tau the simulated angle from rest, K g_tau(u) + theta0, is linear in K and theta0,
    so each of 40 grid points from Ts/20 to the record length is one small least-squares
    problem; the best grid point is the start. It needs no other estimate, takes either sign of
    K, and works for any tau/Ts.
    """
    N = u.size
    taus = np.geomspace(Ts / 20.0, max(N * Ts, 2 * Ts), 40)
    best = None
    ones = np.ones(N)
    for tau in taus:
        M = np.column_stack([_unit_response(tau, Ts, u), ones])
        coef, *_ = np.linalg.lstsq(M, theta, rcond=None)
        r = theta - M @ coef
        sse = float(r @ r)
        if best is None or sse < best[0]:
            best = (sse, float(coef[0]), float(tau), float(coef[1]))
    return best[1:]


def _projection(exps, Ts, delay, segment_n, tau, states=False):
    """Stojčić eq. 1 with the delayed input, for a fixed tau, is linear in K and in each segment's
    initial angle and velocity: theta = K g(tau) + theta0_j + omega0_j tau (1 - a^k) on segment j
    (g the ZOH response from rest to the input, restarted at the segment start). Returns the
    least-squares K and sum of squared residuals, with ``states`` also each segment's
    (theta0, omega0). The two state columns are made orthonormal (Gram-Schmidt) and projected out
    segment by segment, so an evaluation costs O(samples)."""
    segs = []
    for u, th in exps:
        v = _shift(u, delay)
        st = _segment_starts(u.size, segment_n)
        for s0, s1 in zip(st, np.append(st[1:], u.size)):
            h = -tau * np.expm1(-np.arange(s1 - s0) * Ts / tau)
            hc = h - h.mean()
            q = hc / np.linalg.norm(hc) if np.any(hc) else hc
            g, y = _unit_response(tau, Ts, v[s0:s1]), th[s0:s1]
            gc, yc = g - g.mean(), y - y.mean()
            segs.append((h, g, y, gc - q * (q @ gc), yc - q * (q @ yc)))
    gg = sum(float(pg @ pg) for *_, pg, _ in segs)
    K = sum(float(pg @ py) for *_, pg, py in segs) / gg if gg > 0 else 0.0
    sse = sum(float((py - K * pg) @ (py - K * pg)) for *_, pg, py in segs)
    if not states:
        return K, sse
    coefs = [
        np.linalg.lstsq(np.column_stack([np.ones(h.size), h]), y - K * g, rcond=None)[0]
        for h, g, y, _, _ in segs
    ]
    return K, sse, np.array([c[0] for c in coefs]), np.array([c[1] for c in coefs])


def projection_start(exps, Ts, delay, segment_n) -> dict:
    """Start of Stojčić eq. 1 alone: the exact optimum over tau, K and every segment state.

    Variable projection (:func:`_projection`) leaves a one-dimensional search over ln tau, done on
    a log grid over the fit's whole range of tau (1e-3 Ts to 1e3 times the record) and refined by
    Brent's method. Where tau is much longer than the record, K and tau trade off along a narrow
    valley in which Levenberg-Marquardt on all parameters stops short; the projection does not.
    Returns K, tau, the terms at 0 and ``seg_theta0``, ``seg_omega0`` (:meth:`ShootingProblem.start`).
    """
    n = sum(u.size for u, _ in exps)

    def cost(x):
        return _projection(exps, Ts, delay, segment_n, math.exp(x))[1]

    grid = np.linspace(math.log(Ts * 1e-3), math.log(Ts * n * 1e3), 25)
    costs = [cost(x) for x in grid]
    i = int(np.argmin(costs))
    bounds = (grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)])
    sol = optimize.minimize_scalar(cost, bounds=bounds, method="bounded", options={"xatol": 1e-12})
    x = sol.x if sol.fun <= costs[i] else grid[i]
    K, _, theta0, omega0 = _projection(exps, Ts, delay, segment_n, math.exp(x), states=True)
    return {
        "K": float(K),
        "tau": math.exp(x),
        "friction": 0.0,
        "offset": 0.0,
        "dead_zone": 0.0,
        "seg_theta0": theta0,
        "seg_omega0": omega0,
    }


def _segment_starts(n, segment_n):
    if segment_n is None or segment_n >= n:
        return np.array([0])
    starts = np.arange(0, n, segment_n)
    if n - starts[-1] < max(segment_n // 2, 10) and starts.size > 1:
        starts = starts[:-1]  # fold a short tail into the previous segment
    return starts


@dataclass
class ShootingFit:
    """The solution of a :class:`ShootingProblem`."""

    par: dict  #: K, tau, friction, offset, dead_zone, coast_rate (and tau_coast with coasting)
    cov: np.ndarray  #: covariance of the problem's ``names``, in physical units
    y_sim: np.ndarray = field(repr=False)  #: the segment-restarted simulation
    theta: np.ndarray = field(repr=False)  #: the measured angle, experiments concatenated
    nfev: int
    s: float  #: residual standard deviation (rad)
    nseg: int
    seg_theta0: np.ndarray = field(repr=False)
    seg_omega0: np.ndarray = field(repr=False)
    at_bound: list  #: names of parameters at (or within two standard errors of) a bound
    cost: float  #: sum of squared residuals


class ShootingProblem:
    """Multiple-shooting output error of the full motor model on merged experiments.

    Parameters are the globals (K, ln tau, the estimated ``terms``, the coasting rate
    1/tau_coast with ``coast=True``) and a state (theta0, omega0) per segment.

    Parameters
    ----------
    exps : list of (u, theta)
        The experiments (V, rad).
    Ts : float
        Sample period (s).
    delay : int
        Input delay (samples), known.
    terms : sequence of str
        Which of :data:`TERMS` are estimated.
    coast : bool or "coulomb"
        The open-drive model (:func:`jerklab.ident.simulate_motor`): True estimates its rate,
        "coulomb" has none (tau_coast = inf).
    segment_n : int or None
        Segment length (samples); None: one segment per experiment.
    cutoff : float
        Cut-off (Hz) of the low-pass filter that gives the segments' starting velocities.
    offset_hint : float
        The offset the fit is started from; it widens the dead zone's upper bound.
    fix_theta0 : bool
        Hold the first angle of each experiment at its first sample instead of estimating it.
    """

    hac_lags = None

    def __init__(
        self,
        exps,
        Ts,
        delay,
        terms=(),
        coast=False,
        segment_n=None,
        cutoff=None,
        offset_hint=0.0,
        fix_theta0=False,
    ):
        self.Ts = Ts
        self.coast = coast
        self.names = ["K", "tau"] + [nm for nm in TERMS if nm in terms]
        if coast is True:
            self.names.append("tau_coast")
        self.ng = len(self.names)
        starts_all, pos = [], 0
        for u, _ in exps:
            starts_all.append(_segment_starts(u.size, segment_n) + pos)
            pos += u.size
        self.starts = np.concatenate(starts_all)
        #: the experiment of each sample: the covariance's lags stay within one
        self.exp_of = np.repeat(np.arange(len(exps)), [u.size for u, _ in exps])
        self.ucat = np.concatenate([_shift(u, delay) for u, _ in exps])
        self.theta = np.concatenate([th for _, th in exps])
        self.cmask = self.ucat == 0.0 if coast else None
        self.nseg = self.starts.size
        self.seg_of = np.repeat(np.arange(self.nseg), np.diff(np.append(self.starts, pos)))
        # the dead zone stays below the largest input it acts on (a larger one would stop the
        # motor for good, and lets K run to infinity against it); reaching this bound is reported
        self.dz_max = float(np.max(np.abs(self.ucat))) + 2.0 * abs(offset_hint)
        self.tau_lo, self.tau_hi = math.log(Ts * 1e-3), math.log(Ts * pos * 1e3)
        # the segments' starting states from the filtered record
        th0, om0 = [], []
        for (_, th), st in zip(exps, starts_all):
            _, w, _ = _filtered_states(th, Ts, cutoff)
            for s_ in st - st[0]:
                th0.append(th[s_])
                om0.append(w[min(max(s_ - 1, 0), w.size - 1)])
        self.seg_th0, self.seg_om0 = np.array(th0), np.array(om0)
        # every parameter, the globals to be set by start(): the fixed ones keep these values
        self._x_all = np.concatenate(
            [np.zeros(self.ng), np.ravel(np.column_stack([self.seg_th0, self.seg_om0]))]
        )
        self.free = np.ones(self._x_all.size, bool)
        if fix_theta0:
            firsts = np.cumsum([0] + [st.size for st in starts_all[:-1]])
            self.free[self.ng + 2 * firsts] = False

    # -- parameters --------------------------------------------------------------------------
    def _full(self, x):
        if self.free.all():
            return x
        xf = self._x_all.copy()
        xf[self.free] = x
        return xf

    def start(self, init) -> np.ndarray:
        """The free parameters at the start ``init`` (a dict of K, tau and the terms; with
        ``seg_theta0``, ``seg_omega0`` also the segments' states, else those of the filtered
        record)."""
        init = dict(init)
        if self.coast is True and "coast_rate" not in init:
            init["coast_rate"] = self._coast_rate_start(init)
        # the coasting enters as its rate 1/tau_coast >= 0 (|p|, like friction): 0 is a motor
        # with no viscous drag, whose open-drive run-down is Coulomb friction alone
        gl = [init["K"], math.log(init["tau"])] + [
            init["coast_rate"] if nm == "tau_coast" else init[nm] for nm in self.names[2:]
        ]
        x0 = self._x_all.copy()
        x0[: self.ng] = gl
        th0, om0 = init.get("seg_theta0"), init.get("seg_omega0")
        if th0 is not None and om0 is not None and len(th0) == len(om0) == self.nseg:
            states = np.ravel(np.column_stack([th0, om0]))
            keep = ~self.free[self.ng :]  # a fixed first angle stays at its sample
            x0[self.ng :] = np.where(keep, self._x_all[self.ng :], states)
        # friction and dead zone enter as |p| (>= 0 without bounds, so MINPACK's
        # Levenberg-Marquardt can be used: it is much faster than a bounded trust region on
        # hundreds of segment states); ln tau is clamped to a range no motor leaves, so a hopeless
        # record cannot overflow
        x0[1] = min(max(x0[1], self.tau_lo + 1e-6), self.tau_hi - 1e-6)
        for i, nm in enumerate(self.names[2:], start=2):
            if nm in ("friction", "dead_zone"):
                x0[i] = max(abs(x0[i]), 1e-6)
            if nm == "dead_zone":
                x0[i] = min(x0[i], 0.5 * self.dz_max)
            if nm == "tau_coast":
                x0[i] = abs(x0[i])
        return x0[self.free]

    def _coast_rate_start(self, init):
        """The best of 0 and a few fractions of 1/tau (one simulation each)."""
        best = None
        for m in (0.0, 1.0 / 64, 1.0 / 16, 1.0 / 4, 1.0):
            v = self.ucat + init["offset"]
            if init["dead_zone"] > 0:
                v = np.sign(v) * np.maximum(np.abs(v) - init["dead_zone"], 0.0)
            ys = _simulate_segments(
                v,
                max(init["friction"], 0.0),
                init["K"],
                init["tau"],
                self.Ts,
                self.starts,
                self.seg_th0,
                self.seg_om0,
                self.cmask,
                m / init["tau"],
            )
            c = float(np.sum((ys - self.theta) ** 2))
            if best is None or c < best[0]:
                best = (c, m / init["tau"])
        return max(best[1], 1e-3 / init["tau"])

    def unpack(self, x):
        """(globals in physical units, segment angles, segment velocities) of free parameters x."""
        xf = self._full(x)
        ng = self.ng
        g = dict(zip(self.names, xf[:ng]))
        g["tau"] = math.exp(min(max(g["tau"], self.tau_lo), self.tau_hi))
        g["coast_rate"] = abs(g.pop("tau_coast")) if self.coast is True else 0.0
        for nm in ("friction", "dead_zone"):
            g[nm] = abs(g.get(nm, 0.0))
        g["dead_zone"] = min(g["dead_zone"], self.dz_max)
        g.setdefault("offset", 0.0)
        return g, xf[ng::2], xf[ng + 1 :: 2]

    # -- the model and its derivatives -------------------------------------------------------
    def model(self, x) -> np.ndarray:
        """The segment-restarted simulated angle at free parameters x."""
        g, t0, w0 = self.unpack(x)
        v = self.ucat + g["offset"]
        if g["dead_zone"]:
            v = np.sign(v) * np.maximum(np.abs(v) - g["dead_zone"], 0.0)
        return _simulate_segments(
            v,
            g["friction"],
            g["K"],
            g["tau"],
            self.Ts,
            self.starts,
            t0,
            w0,
            self.cmask,
            g["coast_rate"],
        )

    def residuals(self, x) -> np.ndarray:
        return self.model(x) - self.theta

    def cost(self, x) -> float:
        r = self.residuals(x)
        return float(r @ r)

    def jacobian(self, x) -> np.ndarray:
        """Globals by central differences; the segment angles exactly (the model is invariant to a
        shift of the angle); the segment velocities by one grouped difference (segments are
        independent, so one perturbed simulation gives every segment's column)."""
        xf = self._full(x)
        n, ng, rows = self.theta.size, self.ng, np.arange(self.theta.size)
        J = np.zeros((n, xf.size))
        full = self.free.all()

        def model_full(xx):
            return self.model(xx if full else xx[self.free])

        for i in range(ng):
            h = 1e-6 * max(abs(xf[i]), 1e-2)
            xp, xm = xf.copy(), xf.copy()
            xp[i] += h
            xm[i] -= h
            J[:, i] = (model_full(xp) - model_full(xm)) / (2 * h)
        J[rows, ng + 2 * self.seg_of] = 1.0
        w0 = xf[ng + 1 :: 2]
        h = 1e-6 * max(float(np.max(np.abs(w0))), 1e-2)
        xp, xm = xf.copy(), xf.copy()
        xp[ng + 1 :: 2] += h
        xm[ng + 1 :: 2] -= h
        J[rows, ng + 2 * self.seg_of + 1] = (model_full(xp) - model_full(xm)) / (2 * h)
        return J if full else J[:, self.free]

    # -- the solution ------------------------------------------------------------------------
    def solve(self, x0, max_nfev=200) -> ShootingFit:
        """Levenberg-Marquardt from x0; the covariance of :meth:`covariance` at the optimum."""
        sol = optimize.least_squares(
            self.residuals,
            x0,
            jac=self.jacobian,
            method="lm",
            x_scale="jac",
            xtol=1e-8,
            ftol=1e-9,
            gtol=1e-9,
            max_nfev=max_nfev,
        )
        x = sol.x
        J = self.jacobian(x)
        r = self.residuals(x)
        dof = max(self.theta.size - x.size, 1)
        s2 = float(r @ r) / dof
        cov_x = self.covariance(J, r, s2)
        g, t0, w0 = self.unpack(x)
        cov, rate_sd = self._physical_covariance(g, cov_x)
        if self.coast:
            g["tau_coast"] = 1.0 / g["coast_rate"] if g["coast_rate"] > 0 else math.inf
        return ShootingFit(
            par=g,
            cov=cov,
            y_sim=self.theta + r,  # r = model - theta
            theta=self.theta,
            nfev=sol.nfev,
            s=math.sqrt(s2),
            nseg=self.nseg,
            seg_theta0=t0,
            seg_omega0=w0,
            at_bound=self._at_bound(g, cov, rate_sd, self._full(x)[1]),
            cost=float(r @ r),
        )

    def covariance(self, J, r, s2) -> np.ndarray:
        """Covariance of the free parameters at the optimum (Jacobian ``J``, residuals ``r``,
        residual variance ``s2``): honest for coloured residuals.

        Each parameter's standard error is the largest of three estimates; the correlations are
        those of the least-squares problem itself, (J^T J)^-1 (so the diagnostics of an
        ill-conditioned fit see its shape, not the noise of a sandwich):

        * the textbook s2 (J^T J)^-1, right for white residuals;
        * the Newey-West (HAC) sandwich of :func:`jerklab.ident.covariance.newey_west` (Newey &
          West 1987), lags within each experiment, for residuals of short memory of any origin;
        * when the angle lies on an encoder's grid (:func:`~jerklab.ident.covariance.grid_step`),
          the encoder's own quantization error simulated about the fitted angle, a random phase
          per experiment and a jitter of the variance that s2 leaves above step^2/12
          (:func:`~jerklab.ident.covariance.quantization_covariance`): its slow beats outlast any
          short lag window.

        They cover the spread of the estimate over records of the same motor (noise,
        quantization, where the shaft stood). Not a bias of a model that misses part of the
        plant (friction or a delay not fitted, a flexible load): no covariance covers that.
        """
        white = s2 * np.linalg.pinv(J.T @ J)
        hac, self.lags = newey_west(J, r, self.exp_of, self.hac_lags)
        sd = [np.diag(white), np.diag(hac)]
        self.encoder_step = grid_step(self.theta, self.exp_of)
        if self.encoder_step is not None:
            q = self.encoder_step
            jitter = math.sqrt(max(s2 - q * q / 12.0, 0.0))
            sd.append(np.diag(quantization_covariance(J, self.theta + r, self.exp_of, q, jitter)))
        sd_white = np.sqrt(np.clip(sd[0], 0.0, None))
        sd_max = np.sqrt(np.clip(np.max(sd, axis=0), 0.0, None))
        # scale the textbook covariance, parameter by parameter, up to the largest error
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(sd_white > 0, sd_max / sd_white, 1.0)
        return white * np.outer(scale, scale)

    def _physical_covariance(self, g, cov_x):
        """(K, ln tau, ..., rate) -> (K, tau, ..., tau_coast) by the delta method."""
        ng = self.ng
        T = np.eye(ng)
        T[1, 1] = g["tau"]
        rate_sd = 0.0
        if self.coast is True:
            # tau_coast = 1/rate: d tau_coast / d rate = -1/rate^2 (infinite at rate 0)
            rate_sd = math.sqrt(max(cov_x[ng - 1, ng - 1], 0.0))
            T[ng - 1, ng - 1] = -1.0 / g["coast_rate"] ** 2 if g["coast_rate"] > 0 else 0.0
        cov = T @ cov_x[:ng, :ng] @ T
        if self.coast is True and not g["coast_rate"] > 0:
            cov[ng - 1, ng - 1] = math.inf
        return cov, rate_sd

    def _at_bound(self, g, cov, rate_sd, ln_tau):
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        u_max = float(np.max(np.abs(self.ucat)))
        out = [
            nm
            for i, nm in enumerate(self.names)
            if nm in ("friction", "dead_zone") and (g[nm] <= 1e-4 * u_max or g[nm] < 2.0 * sd[i])
        ]
        if not (self.tau_lo + 1e-3 < ln_tau < self.tau_hi - 1e-3):
            out.append("tau")
        if self.coast is True and g["coast_rate"] <= 2.0 * rate_sd:
            out.append("tau_coast")
        if "dead_zone" in self.names and g["dead_zone"] >= 0.98 * self.dz_max:
            out.append("dead_zone_max")
        return out


def fit_output_error(exps, Ts, delay, init, *, max_nfev=200, **problem) -> ShootingFit:
    """Build the :class:`ShootingProblem` (``problem`` keywords), start it at ``init``, solve it."""
    p = ShootingProblem(exps, Ts, delay, offset_hint=init.get("offset", 0.0), **problem)
    return p.solve(p.start(init), max_nfev=max_nfev)
