"""Output-error (prediction-error) fits of the motor: multiple shooting, and the paper's 'P2' call.

The output-error fit of Stojčić eq. 1 (ASCII: Stojcic) with the terms of real records
(``jerklab.ident.model.simulate_motor``: Coulomb friction by the velocity, offset, dead zone,
delay, coasting) minimises sum (theta_measured - theta_simulated)^2 over the exact ZOH
simulation; with white measurement noise that is the maximum-likelihood estimate (Ljung,
*System Identification*, §4.2). :func:`_fit_oe_ms` does it by **multiple shooting**: the record
is cut into segments, each starting from its own estimated angle and velocity, the physical
parameters shared, so neither a closed-loop record nor an integrating plant can drift over a
long record (Bock's multiple shooting without continuity constraints). A record of at most
1000 samples is one segment: single shooting from an estimated initial state.
``fit_dc_motor(method="pem")`` calls it, started by the inverse-dynamics estimate or by
:func:`_grid_start`.

:func:`fit_p2` reproduces Stojčić §4A's literal ``pem(data, 'P2')``, a model without an
integrator, to show where it goes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize, signal

from jerklab._lazy import lazy_module
from jerklab._validate import as_positive
from jerklab.ident._checks import _check_excitation, _pair
from jerklab.ident.inverse_dynamics import _filtered_states
from jerklab.ident.model import _drive, _simulate_segments, _unit_response
from jerklab.ident.validation import fit_percent

control = lazy_module("control")  # python-control imports matplotlib: import it on first use

__all__ = ["P2Fit", "fit_p2"]


def _grid_start(u, theta, Ts):
    """(K, tau, theta0) of the linear model from rest, by variable projection over tau on a log
    grid: for fixed tau the angle is linear in K and theta0, so each grid point is one small
    least-squares problem (the start of an output-error fit the inverse dynamics cannot give)."""
    N = u.size
    taus = np.geomspace(Ts / 20.0, max(N * Ts, 2 * Ts), 40)
    best = None
    for tau in taus:
        M = np.column_stack([_unit_response(tau, Ts, u), np.ones(N)])
        coef, *_ = np.linalg.lstsq(M, theta, rcond=None)
        r = theta - M @ coef
        sse = float(r @ r)
        if best is None or sse < best[0]:
            best = (sse, coef[0], tau, coef[1])
    return best[1:]


def _linear_projection(exps, Ts, delay, segment_n, tau, states=False):
    """For a fixed tau the linear model's angle is linear in K and in each segment's initial angle
    and velocity: theta = K g(tau) + theta0_j + omega0_j tau (1 - a^k) on segment j (g the ZOH
    response from rest to the delayed input, restarted at the segment start). Returns the
    least-squares K and sum of squared residuals, and with ``states`` each segment's
    (theta0, omega0). The segment states are projected out segment by segment (the two columns
    made orthonormal by Gram-Schmidt), so one evaluation costs O(samples)."""
    segs = []
    for u, th in exps:
        v = _shift(u, delay)
        st = _segment_starts(u.size, segment_n)
        for s0, s1 in zip(st, np.append(st[1:], u.size)):
            h = -tau * np.expm1(-np.arange(s1 - s0) * Ts / tau)
            g, y = _unit_response(tau, Ts, v[s0:s1]), th[s0:s1]
            hc = h - h.mean()
            q = hc / np.linalg.norm(hc) if np.any(hc) else hc

            def project(x, q=q):
                xc = x - x.mean()
                return xc - q * (q @ xc)

            segs.append((h, g, y, project(g), project(y)))
    gg = sum(float(pg @ pg) for *_, pg, _ in segs)
    K = sum(float(pg @ py) for *_, pg, py in segs) / gg if gg > 0 else 0.0
    sse = sum(float((py - K * pg) @ (py - K * pg)) for *_, pg, py in segs)
    if not states:
        return K, sse
    theta0, omega0 = [], []
    for h, g, y, _, _ in segs:
        c, *_ = np.linalg.lstsq(np.column_stack([np.ones(h.size), h]), y - K * g, rcond=None)
        theta0.append(c[0])
        omega0.append(c[1])
    return K, sse, np.array(theta0), np.array(omega0)


def _linear_start(exps, Ts, delay, segment_n) -> dict:
    """The start of the output-error fit of the linear model (Stojčić eq. 1 with a delay): the
    exact optimum over tau of :func:`_linear_projection` (variable projection), found on a log grid
    over the fit's whole range of tau and refined by Brent's method. K and tau trade off along a
    narrow valley on a record shorter than tau; projecting out K and the segment states leaves a
    one-dimensional search that does not stall there."""
    n = sum(u.size for u, _ in exps)

    def cost(x):
        return _linear_projection(exps, Ts, delay, segment_n, math.exp(x))[1]

    grid = np.linspace(math.log(Ts * 1e-3), math.log(Ts * n * 1e3), 25)
    costs = [cost(x) for x in grid]
    i = int(np.argmin(costs))
    bounds = (grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)])
    sol = optimize.minimize_scalar(cost, bounds=bounds, method="bounded", options={"xatol": 1e-12})
    x = sol.x if sol.fun <= costs[i] else grid[i]
    K, _, theta0, omega0 = _linear_projection(exps, Ts, delay, segment_n, math.exp(x), True)
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


def _fit_oe_ms(
    exps, Ts, delay, opts, init, segment_n, cutoff, max_nfev=200, tol=(1e-8, 1e-9, 1e-9)
):
    """Output error with multiple shooting: global (K, ln tau, [f_c], [offset], [dead_zone]) and an
    initial state (theta0, omega0) per segment, minimising sum (theta - theta_sim)^2 over all
    segments of all experiments (Ljung §4.2 output error; Bock's multiple shooting without
    continuity constraints, i.e. each segment a short output-error problem with its own initial
    state, so an integrating plant cannot drift over a long record)."""
    names = ["K", "tau"] + [nm for nm in ("friction", "offset", "dead_zone") if opts[nm]]
    coast = opts.get("coast", False)
    if coast is True:
        names.append("tau_coast")
    ng = len(names)
    vs_u, ths, starts_all, offsets = [], [], [], []
    pos = 0
    for u, th in exps:
        st = _segment_starts(u.size, segment_n)
        starts_all.append(st + pos)
        vs_u.append(_shift(u, delay))
        ths.append(th)
        offsets.append(pos)
        pos += u.size
    starts = np.concatenate(starts_all)
    ucat = np.concatenate(vs_u)
    theta = np.concatenate(ths)
    cmask = ucat == 0.0 if coast else None
    nseg = starts.size
    # the dead zone stays below the largest input it acts on (a larger one would stop the motor for
    # good, and lets K run to infinity against it); reaching this bound is reported
    dz_max = float(np.max(np.abs(ucat))) + 2.0 * abs(init.get("offset", 0.0))
    # initial segment states: the start's (the linear model's projection), else from the
    # filtered record
    th0, om0 = list(init.get("seg_theta0", ())), list(init.get("seg_omega0", ()))
    if len(th0) != nseg or len(om0) != nseg:
        th0, om0 = [], []
        for (u, th), st in zip(exps, starts_all):
            _, w, _ = _filtered_states(th, Ts, cutoff)
            base = st[0]
            for s_ in st - base:
                th0.append(th[s_])
                om0.append(w[min(max(s_ - 1, 0), w.size - 1)])
    tau_lo, tau_hi = math.log(Ts * 1e-3), math.log(Ts * theta.size * 1e3)
    if coast is True and "coast_rate" not in init:
        # start the coasting rate 1/tau_coast from the best of 0 and a few fractions of 1/tau (one
        # simulation each, segment states from the filtered record)
        best = None
        for m in (0.0, 1.0 / 64, 1.0 / 16, 1.0 / 4, 1.0):
            v = ucat + init["offset"]
            if init["dead_zone"] > 0:
                v = np.sign(v) * np.maximum(np.abs(v) - init["dead_zone"], 0.0)
            ys = _simulate_segments(
                v,
                max(init["friction"], 0.0),
                init["K"],
                init["tau"],
                Ts,
                starts,
                th0,
                om0,
                cmask,
                m / init["tau"],
            )
            c = float(np.sum((ys - theta) ** 2))
            if best is None or c < best[0]:
                best = (c, m / init["tau"])
        init = dict(init, coast_rate=max(best[1], 1e-3 / init["tau"]))
    # the coasting enters as its rate 1/tau_coast >= 0 (|p|, like friction): 0 is a motor with no
    # viscous drag, whose open-drive run-down is Coulomb friction alone
    gl = [init["K"], math.log(init["tau"])] + [
        init["coast_rate"] if nm == "tau_coast" else init[nm] for nm in names[2:]
    ]
    x0 = np.concatenate([gl, np.ravel(np.column_stack([th0, om0]))])
    # friction and dead zone enter as |p| (>= 0 without bounds, so MINPACK's Levenberg-Marquardt
    # can be used: it is much faster than a bounded trust region on hundreds of segment states);
    # ln tau is clamped to a range no motor leaves, so a hopeless record cannot overflow
    x0[1] = min(max(x0[1], tau_lo + 1e-6), tau_hi - 1e-6)
    for i, nm in enumerate(names[2:], start=2):
        if nm in ("friction", "dead_zone"):
            x0[i] = max(abs(x0[i]), 1e-6)
        if nm == "dead_zone":
            x0[i] = min(x0[i], 0.5 * dz_max)
        if nm == "tau_coast":
            x0[i] = abs(x0[i])

    def unpack(x):
        g = dict(zip(names, x[:ng]))
        g["tau"] = math.exp(min(max(g["tau"], tau_lo), tau_hi))
        if coast is True:
            g["coast_rate"] = abs(g.pop("tau_coast"))
        else:
            g["coast_rate"] = 0.0
        for nm in ("friction", "dead_zone"):
            g[nm] = abs(g.get(nm, 0.0))
        g["dead_zone"] = min(g["dead_zone"], dz_max)
        g.setdefault("offset", 0.0)
        return g, x[ng::2], x[ng + 1 :: 2]

    def model(x):
        g, t0, w0 = unpack(x)
        v = ucat + g["offset"]
        if g["dead_zone"]:
            v = np.sign(v) * np.maximum(np.abs(v) - g["dead_zone"], 0.0)
        return _simulate_segments(
            v, g["friction"], g["K"], g["tau"], Ts, starts, t0, w0, cmask, g["coast_rate"]
        )

    def resid(x):
        return model(x) - theta

    seg_of = np.repeat(np.arange(nseg), np.diff(np.append(starts, theta.size)))

    def jac(x):
        # globals by central differences; the segment angles exactly (the model is invariant to a
        # shift of the angle); the segment velocities by one grouped difference (segments are
        # independent, so one perturbed simulation gives every segment's column)
        J = np.zeros((theta.size, x.size))
        for i in range(ng):
            h = 1e-6 * max(abs(x[i]), 1e-2)
            xp, xm = x.copy(), x.copy()
            xp[i] += h
            xm[i] -= h
            J[:, i] = (model(xp) - model(xm)) / (2 * h)
        J[np.arange(theta.size), ng + 2 * seg_of] = 1.0
        w0 = x[ng + 1 :: 2]
        h = 1e-6 * max(float(np.max(np.abs(w0))), 1e-2)
        xp, xm = x.copy(), x.copy()
        xp[ng + 1 :: 2] += h
        xm[ng + 1 :: 2] -= h
        J[np.arange(theta.size), ng + 2 * seg_of + 1] = (model(xp) - model(xm)) / (2 * h)
        return J

    sol = optimize.least_squares(
        resid,
        x0,
        jac=jac,
        method="lm",
        x_scale="jac",
        xtol=tol[0],
        ftol=tol[1],
        gtol=tol[2],
        max_nfev=max_nfev,
    )
    x = sol.x
    J = jac(x)
    r = resid(x)
    dof = max(theta.size - x.size, 1)
    s2 = float(r @ r) / dof
    cov_x = s2 * np.linalg.pinv(J.T @ J)
    g, t0, w0 = unpack(x)
    # (K, ln tau, ...) -> (K, tau, ...)
    T = np.eye(ng)
    T[1, 1] = g["tau"]
    rate_sd = 0.0
    if coast is True:
        # tau_coast = 1/rate: d tau_coast / d rate = -1/rate^2 (infinite at rate 0)
        rate_sd = math.sqrt(max(cov_x[ng - 1, ng - 1], 0.0))
        T[ng - 1, ng - 1] = -1.0 / g["coast_rate"] ** 2 if g["coast_rate"] > 0 else 0.0
    cov = T @ cov_x[:ng, :ng] @ T
    if coast is True and not g["coast_rate"] > 0:
        cov[ng - 1, ng - 1] = math.inf
    if coast:
        g["tau_coast"] = 1.0 / g["coast_rate"] if g["coast_rate"] > 0 else math.inf
    Jg = None
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    at_bound = [
        nm
        for i, nm in enumerate(names)
        if nm in ("friction", "dead_zone")
        and (g[nm] <= 1e-4 * float(np.max(np.abs(ucat))) or g[nm] < 2.0 * sd[i])
    ]
    if not (tau_lo + 1e-3 < x[1] < tau_hi - 1e-3):
        at_bound.append("tau")
    if coast is True and g["coast_rate"] <= 2.0 * rate_sd:
        at_bound.append("tau_coast")
    if "dead_zone" in names and g["dead_zone"] >= 0.98 * dz_max:
        at_bound.append("dead_zone_max")
    y_sim = theta + r  # r = model - theta
    return dict(
        par=g,
        names=names,
        cov=cov,
        y_sim=y_sim,
        theta=theta,
        nfev=sol.nfev,
        s=math.sqrt(s2),
        nseg=nseg,
        starts=starts,
        seg_theta0=t0,
        seg_omega0=w0,
        at_bound=at_bound,
        cost=float(r @ r),
        Jg=Jg,
        exp_offsets=offsets,
    )


def _shift(u, delay):
    return _drive(u, 0.0, 0.0, delay)


@dataclass
class P2Fit:
    """The paper's literal structure, MATLAB ``pem(data, 'P2')``: K / ((T1 s + 1)(T2 s + 1)).

    ``K`` is in rad/V (a DC gain: the model has no integrator), ``T1 >= T2`` in s. ``at_bound`` is
    True when 1/T1 ran to (nearly) 0 — T1 over 100 times the record — i.e. the data asked for an
    integrator (then T1 = K = inf and ``model`` is the integrator model g/(s(T2 s + 1)) the bound
    reached).
    """

    K: float
    T1: float
    T2: float
    fit_percent: float
    model: control.TransferFunction
    Ts: float
    theta0: float
    y_sim: np.ndarray = field(repr=False)
    at_bound: bool = False
    integrator_gain: float = float("nan")  #: K/T1 (rad/(V s)), comparable to the K of Stojčić eq. 1


def _p2_response(g, lam, T2, Ts, u):
    """Exact ZOH response of g / ((s + lam)(T2 s + 1)) to u (zero initial state).

    States theta' = -lam theta + v, T2 v' = -v + g u; with b = 1/T2 the one-sample transition is
    a1 = exp(-lam Ts), a2 = exp(-b Ts), phi12 = (a1 - a2)/(b - lam),
    gamma2 = g (1 - a2), gamma1 = g b (E(lam) - E(b))/(b - lam), E(c) = (1 - exp(-c Ts))/c.
    """
    b = 1.0 / T2
    if abs(b - lam) * Ts < 1e-5:  # (nearly) a double pole: the matrix exponential
        A = np.array([[-lam, 1.0, 0.0], [0.0, -b, g * b], [0.0, 0.0, 0.0]])
        E = linalg.expm(A * Ts)
        a1, phi12, g1 = E[0, 0], E[0, 1], E[0, 2]
        a2, g2 = E[1, 1], E[1, 2]
    else:

        def integral(c):
            return Ts if c == 0.0 else -math.expm1(-c * Ts) / c

        a1, a2 = math.exp(-lam * Ts), math.exp(-b * Ts)
        phi12 = (a1 - a2) / (b - lam)
        g2 = -g * math.expm1(-b * Ts)
        g1 = g * b * (integral(lam) - integral(b)) / (b - lam)
    num = [0.0, g1, phi12 * g2 - g1 * a2]
    den = [1.0, -(a1 + a2), a1 * a2]
    return signal.lfilter(num, den, u)


def fit_p2(u, theta, Ts) -> P2Fit:
    """Fit the two-pole process model Stojčić §4A names, ``pem(data, 'P2')``, for comparison.

    Output-error least squares of K / ((T1 s + 1)(T2 s + 1)) (exact ZOH simulation) on the angle,
    parametrised as g / ((s + lambda)(T2 s + 1)) with g = K/T1, lambda = 1/T1 >= 0, so that the
    integrator (lambda = 0, T1 = inf) is inside the search space instead of at infinity.
    This is kept to reproduce the paper's call, not to be used: the motor has an integrator, so on
    a step the fit drives lambda to (or next to) 0 — T1 and K run away together with K/T1 -> the K
    of Stojčić eq. 1 — and ``at_bound`` is set. Over the record the two models are
    indistinguishable; beyond it
    the P2 model settles at K u while the motor keeps turning. Use :func:`fit_dc_motor`
    (a pole plus an integrator, MATLAB's 'P1I').

    Parameters
    ----------
    u, theta, Ts
        As :func:`fit_dc_motor`.
    """
    Ts = as_positive("Ts", Ts)
    u, theta = _pair(u, theta, "u", "theta")
    _check_excitation(u, theta, "u", "theta")
    span = u.size * Ts
    _, tau0, _ = _grid_start(u, theta, Ts)
    ones = np.ones(u.size)

    def linear_part(q):
        # variable projection: for fixed (lambda, T2) the angle is linear in g and theta0
        h = _p2_response(1.0, q[0], math.exp(q[1]), Ts, u)
        M = np.column_stack([h, ones])
        coef, *_ = np.linalg.lstsq(M, theta, rcond=None)
        return coef, M @ coef

    best = None
    for lam0 in (0.0, 1.0 / span, 10.0 / span):  # integrator, slow, and faster starts
        q0 = np.array([lam0, math.log(tau0)])
        sol = optimize.least_squares(
            lambda q: linear_part(q)[1] - theta,
            q0,
            method="trf",
            bounds=([0.0, math.log(Ts / 50)], [20.0 / Ts, math.log(1e3 * span)]),
            x_scale=[1.0 / span, 1.0],
            xtol=1e-10,
            ftol=1e-12,
            max_nfev=200,
        )
        if best is None or sol.cost < best.cost:
            best = sol
    (g, th0), y_sim = linear_part(best.x)
    lam, T2 = best.x[0], math.exp(best.x[1])
    at_bound = lam * span < 1e-2
    if lam > 0.0:
        T1, K = 1.0 / lam, g / lam
        if T2 > T1:
            T1, T2 = T2, T1
        model = control.tf([K], np.convolve([T1, 1.0], [T2, 1.0]))
    else:
        T1, K = math.inf, math.inf * np.sign(g)
        model = control.tf([g], [T2, 1.0, 0.0])
    return P2Fit(
        float(K),
        float(T1),
        float(T2),
        fit_percent(theta, y_sim),
        model,
        Ts,
        float(th0),
        y_sim,
        bool(at_bound),
        float(g),
    )
