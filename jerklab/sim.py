"""Closed-loop simulation of the digital positioning system (Stojčić §3, §4B).

The controller runs at ``Ts`` on quantized measurements; between samples the plant is
integrated exactly (closed-form ZOH, with Coulomb-friction events, see
:mod:`jerklab.plant`), so the only approximations are the ones the rig makes: supply
saturation, PWM and encoder quantization, noise.

At sample ``k`` (``t = k Ts``):

1. the encoder gives ``y(k)`` = floor(θ(kTs)·counts/rad)/(counts/rad) (+ noise)
   (:func:`jerklab.law.encoder`);
2. the profile is sampled in closed form at ``kTs`` (position, velocity, acceleration);
3. the control law of :mod:`jerklab.law` (Stojčić eqs. 16–18, output clamp,
   anti-windup; the law :class:`~jerklab.controller.DigitalController` runs) gives ``u(k)``;
   position loop ``e = r − y``, or the paper's velocity loop ``e = ω_r − (y(k) − y(k−1))/Ts``
   (pulses per sample, §4B);
4. the amplifier applies the supply clamp and PWM rounding (:func:`jerklab.law.amplifier`)
   during ``[kTs, (k+1)Ts)``.

The loop is one compiled kernel (numba, if installed; else the same code in Python) that
also accumulates the metrics; all per-call work outside it is a few small arrays (the
reference of a planner profile is sampled once per grid and reused). It is cross-checked
in the tests against stepping ``DigitalController`` and ``DCMotor.step_state`` in Python and
against python-control on the linear loop. A run that diverges (NaN/inf, or an error beyond
``DIVERGENCE_FACTOR`` × the move) says so. :func:`simulate_batch` runs many perturbed
plants (K, τ, friction) at once, compiled or with the law's numpy form.

ASCII spelling of the paper's author: Stojcic.
"""

from __future__ import annotations

import math
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from jerklab import law, paper
from jerklab._validate import as_finite_array, as_int, as_nonnegative, as_positive, as_real
from jerklab._vocab import aliases
from jerklab.controller import DigitalController, DiscreteGains, Gains
from jerklab.law import HAVE_NUMBA, _jit  # one switch for every compiled kernel
from jerklab.metrics import MoveMetrics, series_metrics
from jerklab.planner import Profile
from jerklab.plant import DCMotor, FlexibleDCMotor, _advance, advance_em

__all__ = [
    "simulate",
    "simulate_batch",
    "SimResult",
    "BatchResult",
    "perturbed_plants",
    "SampledProfile",
    "StepProfile",
    "HAVE_NUMBA",
]

# packed plant and run parameters of :func:`_kernel` (see :func:`_plant_pack`)
(
    P_RIGID,
    P_K,
    P_TAU,
    P_FC,
    P_DIST_ON,
    P_DIST_AMP,
    P_DIST_TIME,
    P_SUPPLY,
    P_LEVELS,
    P_CPR,
    P_DISTANCE,
    P_DURATION,
    P_BOUND,
    P_OFFSET,
    P_DEAD_ZONE,
) = range(15)
_NP = 15
# rows of the kernel's output array after the ns state rows
(O_MEAS, O_UCMD, O_UAPP, O_P, O_I, O_D, O_FF, O_E) = range(8)
_NO = 8
# what the kernel accumulates beyond the traces: where the run stopped (a non-finite state) or
# left the divergence bound, and the flexible load's residual vibration after the move
(M_NONFINITE, M_BEYOND, M_RESID, M_NAFTER) = range(4)
_NM = 4
#: a run whose |error| exceeds this many times max(|distance|, 1) has diverged
DIVERGENCE_FACTOR = 1e3


# ---------------------------------------------------------------------------
# the compiled kernels (the law itself is jerklab.law)
# ---------------------------------------------------------------------------
@_jit
def _rigid_step(th, om, v, k, Ts, fc, K, tau, em_full, dist_on, dist_amp, dist_time):
    """Exact rigid-plant step over [k Ts, (k+1) Ts) with the disturbance split."""
    t0 = k * Ts
    if dist_on and t0 < dist_time and dist_time < t0 + Ts:
        a = dist_time - t0
        th, om = advance_em(th, om, v, fc, K, tau, a, -math.expm1(-a / tau))
        b = t0 + Ts - dist_time
        return advance_em(th, om, v + dist_amp, fc, K, tau, b, -math.expm1(-b / tau))
    w = dist_amp if (dist_on and t0 >= dist_time) else 0.0
    return advance_em(th, om, v + w, fc, K, tau, Ts, em_full)


@_jit
def _driver(v, offset, dead_zone):
    """The voltage the motor sees after the driver: ``dz(v + offset)`` (``DCMotor.drive_voltage``)."""
    x = v + offset
    if dead_zone > 0.0:
        a = abs(x) - dead_zone
        if a <= 0.0:
            return 0.0
        return a if x > 0.0 else -a
    return x


@_jit
def _kernel(ref, noise, x0, pp, M, ctl, OUT, sat, met):
    """One run, every signal stored, divergence and the load's vibration noted (:func:`simulate`).

    ``ref`` (3, n): position, velocity, acceleration; ``noise`` (n,) or empty; ``pp`` the
    packed plant (``P_*``); ``M`` (3, ns, ns + 1): ``[Φ | Γ]`` of the full period and of the
    two parts a disturbance step splits it in (flexible plant); ``ctl`` the packed
    controller (:data:`jerklab.law.CTL_FIELDS`). ``OUT`` (ns + 8, n): the states, then the
    ``O_*`` rows. A non-finite state stops the run (the rest of ``OUT`` is NaN).
    """
    n = ref.shape[1]
    ns = x0.shape[0]
    x = x0.copy()
    xn = np.empty(ns)
    rigid = pp[P_RIGID] != 0.0
    K = pp[P_K]
    tau = pp[P_TAU]
    fc = pp[P_FC]
    dist_on = pp[P_DIST_ON] != 0.0
    dist_amp = pp[P_DIST_AMP]
    dist_time = pp[P_DIST_TIME]
    supply = pp[P_SUPPLY]
    levels = pp[P_LEVELS]
    cpr = pp[P_CPR]
    distance = pp[P_DISTANCE]
    duration = pp[P_DURATION]
    bound = pp[P_BOUND]
    offset = pp[P_OFFSET]
    dead_zone = pp[P_DEAD_ZONE]
    drive = offset != 0.0 or dead_zone > 0.0
    kpd = ctl[law.C_KPD]
    kid = ctl[law.C_KID]
    kdd = ctl[law.C_KDD]
    gamma = ctl[law.C_GAMMA]
    limit = ctl[law.C_LIMIT]
    aw = ctl[law.C_AW] != 0.0
    ff_on = ctl[law.C_FF_ON] != 0.0
    ffK = ctl[law.C_FF_K]
    fftau = ctl[law.C_FF_TAU]
    velocity = ctl[law.C_VELOCITY] != 0.0
    scale = ctl[law.C_SCALE]
    bumpless = ctl[law.C_BUMPLESS] != 0.0
    Ts = ctl[law.C_TS]
    em_full = -math.expm1(-Ts / tau)
    has_noise = noise.shape[0] > 0
    i_prev = 0.0
    e_prev = 0.0
    d_prev = 0.0
    y_prev = 0.0
    beyond = -1.0
    resid = 0.0
    nafter = 0.0
    k_end = n
    for k in range(n):
        th = x[0]
        if not math.isfinite(th):
            k_end = k
            break
        for j in range(ns):
            OUT[j, k] = x[j]
        a = abs(ref[0, k] - th)
        if beyond < 0.0 and a > bound:
            beyond = k
        if ns == 4 and k * Ts >= duration:
            nafter += 1.0
            r = abs(x[2] - distance)
            if r > resid:
                resid = r
        y = law.encoder(th, cpr)
        if has_noise:
            y += noise[k]
        OUT[ns + O_MEAS, k] = y
        if velocity:
            if k == 0:
                y_prev = y
            e = scale * (ref[1, k] - (y - y_prev) / Ts)
        else:
            e = scale * (ref[0, k] - y)
        y_prev = y
        ff = (fftau * ref[2, k] + ref[1, k]) / ffK if ff_on else 0.0
        if k == 0 and bumpless:
            e_prev = e
        u, p, i_prev, d_prev, s = law.pid_step(
            e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, limit, aw
        )
        e_prev = e
        v, s2 = law.amplifier(u, supply, levels)
        OUT[ns + O_UCMD, k] = u
        OUT[ns + O_UAPP, k] = v
        OUT[ns + O_P, k] = p
        OUT[ns + O_I, k] = i_prev
        OUT[ns + O_D, k] = d_prev
        OUT[ns + O_FF, k] = ff
        OUT[ns + O_E, k] = e
        sat[k] = s or s2
        if rigid:
            vm = _driver(v, offset, dead_zone) if drive else v
            th1, om1 = _rigid_step(
                x[0], x[1], vm, k, Ts, fc, K, tau, em_full, dist_on, dist_amp, dist_time
            )
            x[0] = th1
            x[1] = om1
        else:
            t0 = k * Ts
            split = dist_on and t0 < dist_time and dist_time < t0 + Ts
            w = dist_amp if (dist_on and t0 >= dist_time) else 0.0
            m0 = 1 if split else 0
            for r_ in range(ns):
                acc = M[m0, r_, ns] * (v + w)
                for c in range(ns):
                    acc += M[m0, r_, c] * x[c]
                xn[r_] = acc
            if split:
                for r_ in range(ns):
                    acc = M[2, r_, ns] * (v + dist_amp)
                    for c in range(ns):
                        acc += M[2, r_, c] * xn[c]
                    x[r_] = acc
            else:
                for r_ in range(ns):
                    x[r_] = xn[r_]
    for k in range(k_end, n):
        for j in range(OUT.shape[0]):
            OUT[j, k] = np.nan
        sat[k] = False
    met[M_NONFINITE] = k_end if k_end < n else -1.0
    met[M_BEYOND] = beyond
    met[M_RESID] = resid
    met[M_NAFTER] = nafter


@_jit
def _batch_chunk(
    j0,
    j1,
    rpos,
    rvel,
    racc,
    Ks,
    taus,
    fcs,
    noise,
    noise_on,
    dist_on,
    dist_amp,
    dist_time,
    supply,
    levels,
    cpr,
    ctl,
    duration,
    distance,
    band,
    keep,
    POS,
    U,
    MET,
):
    """Plants ``j0 … j1-1``, same law as :func:`_kernel`; metrics accumulated on the fly.

    Time is the outer loop and the plants the inner one, so the independent plants
    overlap in the CPU pipeline (one plant alone is a chain of dependent operations).
    MET[j] = max|e| over the run, sum e^2 during the move, final e, last index outside the
    band, max|u applied|, number of samples in the move, max|e| during the move, max
    (θ − distance)·sign(distance) after the move (:func:`jerklab.metrics.series_metrics`).
    """
    kpd = ctl[law.C_KPD]
    kid = ctl[law.C_KID]
    kdd = ctl[law.C_KDD]
    gamma = ctl[law.C_GAMMA]
    limit = ctl[law.C_LIMIT]
    aw = ctl[law.C_AW] != 0.0
    ff_on = ctl[law.C_FF_ON] != 0.0
    ffK = ctl[law.C_FF_K]
    fftau = ctl[law.C_FF_TAU]
    velocity = ctl[law.C_VELOCITY] != 0.0
    scale = ctl[law.C_SCALE]
    bumpless = ctl[law.C_BUMPLESS] != 0.0
    Ts = ctl[law.C_TS]
    m = j1 - j0
    n = rpos.shape[0]
    th = np.zeros(m)
    om = np.zeros(m)
    ip = np.zeros(m)
    ep = np.zeros(m)
    dp = np.zeros(m)
    yp = np.zeros(m)
    em = np.empty(m)
    for q in range(m):
        j = j0 + q
        em[q] = -math.expm1(-Ts / taus[j])
    nmove = 0.0
    emax = np.zeros(m)
    esq = np.zeros(m)
    last = np.full(m, -1.0)
    umax = np.zeros(m)
    fin = np.zeros(m)
    emove = np.zeros(m)
    over = np.full(m, -np.inf)
    sgn = 1.0 if distance > 0 else -1.0
    for k in range(n):
        in_move = k * Ts <= duration + 1e-9
        if in_move:
            nmove += 1.0
        rp = rpos[k]
        rv = rvel[k]
        ff = (fftau * racc[k] + rv) / ffK if ff_on else 0.0
        t0 = k * Ts
        split = dist_on and t0 < dist_time and dist_time < t0 + Ts
        w = dist_amp if (dist_on and t0 >= dist_time) else 0.0
        for q in range(m):
            j = j0 + q
            x = th[q]
            err = rp - x
            a = abs(err)
            if a > emax[q]:
                emax[q] = a
            if in_move:
                esq[q] += err * err
                if a > emove[q]:
                    emove[q] = a
            elif (x - distance) * sgn > over[q]:
                over[q] = (x - distance) * sgn
            if abs(distance - x) > band:
                last[q] = k
            fin[q] = err
            y = law.encoder(x, cpr)
            if noise_on:
                y += noise[j, k]
            if velocity:
                if k == 0:
                    yp[q] = y
                e = scale * (rv - (y - yp[q]) / Ts)
            else:
                e = scale * (rp - y)
            yp[q] = y
            if k == 0 and bumpless:
                ep[q] = e
            u, p, i_new, d, s = law.pid_step(
                e, ep[q], ip[q], dp[q], ff, kpd, kid, kdd, gamma, limit, aw
            )
            ip[q] = i_new
            dp[q] = d
            ep[q] = e
            v, s2 = law.amplifier(u, supply, levels)
            if abs(v) > umax[q]:
                umax[q] = abs(v)
            if keep:
                POS[j, k] = x
                U[j, k] = v
            if split:
                th[q], om[q] = _rigid_step(
                    x, om[q], v, k, Ts, fcs[j], Ks[j], taus[j], em[q], dist_on, dist_amp, dist_time
                )
            else:
                th[q], om[q] = advance_em(x, om[q], v + w, fcs[j], Ks[j], taus[j], Ts, em[q])
    for q in range(m):
        j = j0 + q
        MET[j, 0] = emax[q]
        MET[j, 1] = esq[q]
        MET[j, 2] = fin[q]
        MET[j, 3] = last[q]
        MET[j, 4] = umax[q]
        MET[j, 5] = nmove
        MET[j, 6] = emove[q]
        MET[j, 7] = over[q]


def _batch_kernel(rpos, rvel, racc, Ks, taus, fcs, noise, noise_on, *args):
    """All plants in one compiled call (see :func:`_batch_chunk`)."""
    _batch_chunk(0, Ks.shape[0], rpos, rvel, racc, Ks, taus, fcs, noise, noise_on, *args)


# ---------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------
@aliases(t="time", u="command", u_applied="voltage")
@dataclass
class SimResult:
    """Time series and metrics of one closed-loop run (all SI; names of :mod:`jerklab._vocab`).

    Attributes
    ----------
    time : sample times k·Ts (s)
    reference, ref_velocity, ref_accel : the profile sampled at ``time``
    measured : encoder reading (rad)
    position, velocity : true motor angle (rad) and speed (rad/s) at ``time``
    load_position : load angle for a :class:`FlexibleDCMotor` (else None)
    error : tracking error ``reference − position`` (true, rad)
    loop_error : the error the PID saw (after ``error_scale``)
    command : the controller's output after its own clamp (V): what it asks for
    voltage : the voltage the motor got (V): ``command`` after the supply clamp and the PWM
        rounding of the amplifier (:func:`jerklab.law.amplifier`)
    parts : dict of arrays ``p``, ``i``, ``d``, ``ff``
    saturated : bool array, controller clamp or supply limit active
    metrics : :class:`jerklab.metrics.MoveMetrics` of the true angle (see :func:`simulate`)
    diverged : bool
        The run left every sensible range: a state became NaN/inf (the run stops there and
        the remaining samples are NaN) or ``|error|`` exceeded ``DIVERGENCE_FACTOR`` ×
        max(``|distance|``, 1). Its ``settling_time`` is then NaN, never a number.

    The older names ``t``, ``u`` and ``u_applied`` read ``time``, ``command`` and ``voltage``.
    """

    time: np.ndarray
    reference: np.ndarray
    ref_velocity: np.ndarray
    ref_accel: np.ndarray
    measured: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    error: np.ndarray
    loop_error: np.ndarray
    command: np.ndarray
    voltage: np.ndarray
    parts: dict
    saturated: np.ndarray
    metrics: dict
    loop: str = "position"
    load_position: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    diverged: bool = False

    def plot(self, fig=None, title=None):
        """Reference and output, tracking error, control parts: :func:`jerklab.plots.plot_simulation`."""
        from jerklab.plots import plot_simulation

        return plot_simulation(self, fig, title)


@aliases(t="time", u="voltage")
@dataclass
class BatchResult:
    """Runs over many plants: ``position`` and ``voltage`` (applied, V) are
    (n_plants, n_samples), or None without ``keep_traces``; ``metrics`` holds one array per
    key over the plants. The older names ``t`` and ``u`` read ``time`` and ``voltage``."""

    time: np.ndarray
    reference: np.ndarray
    K: np.ndarray
    tau: np.ndarray
    coulomb_friction: np.ndarray
    position: np.ndarray
    voltage: np.ndarray
    metrics: dict


def _batch_divergence(metrics, distance):
    """Mark the diverged plants of a batch (non-finite, or |error| beyond the bound): their
    settling time becomes NaN."""
    peak = np.asarray(metrics["peak_error"])
    diverged = ~np.isfinite(peak) | (peak > DIVERGENCE_FACTOR * max(abs(distance), 1.0))
    metrics["settling_time"] = np.where(diverged, np.nan, metrics["settling_time"])
    metrics["diverged"] = diverged
    return metrics


def _accumulated_metrics(MET, t, duration, distance, band):
    """The metrics of the compiled batch kernel's accumulators: the definitions of
    :func:`jerklab.metrics.series_metrics`, summed on the fly instead of from traces (the
    tests check both give the same numbers)."""
    n = len(t)
    Ts = float(t[1] - t[0]) if n > 1 else 0.0
    last = MET[:, 3].astype(int)
    with np.errstate(invalid="ignore", over="ignore"):
        settle = np.where(
            last < 0,
            0.0,
            np.where(
                last >= n - 1, np.inf, np.maximum(0.0, t[np.maximum(last, 0)] + Ts - duration)
            ),
        )
        return MoveMetrics(
            max_error=MET[:, 6],
            peak_error=MET[:, 0],
            rms_error=np.sqrt(MET[:, 1] / np.maximum(MET[:, 5], 1.0)),
            final_error=MET[:, 2],
            overshoot_pct=np.maximum(0.0, MET[:, 7]) / abs(distance) * 100.0
            if distance
            else np.full(len(MET), np.nan),
            settling_time=settle,
            settle_band=band,
            peak_voltage=MET[:, 4],
        )


# ---------------------------------------------------------------------------
# simple references (anything with duration and sample(t) works)
# ---------------------------------------------------------------------------
class _Sample:
    __slots__ = ("t", "jerk", "accel", "velocity", "position")

    def __init__(self, t, jerk, accel, velocity, position):
        self.t, self.jerk, self.accel, self.velocity, self.position = (
            t,
            jerk,
            accel,
            velocity,
            position,
        )


class StepProfile:
    """A position step of ``distance`` at t = 0 (no velocity or acceleration reference).

    The classic test signal of Stojčić's loop analysis; with feedforward it has none.
    """

    def __init__(self, distance=1.0):
        self.distance = as_real("distance", distance)
        self.duration = 0.0

    def sample(self, t):
        t = np.asarray(t, dtype=float)
        z = np.zeros_like(t)
        return _Sample(t, z, z, z, np.where(t >= 0.0, self.distance, 0.0))


class SampledProfile:
    """A reference given as samples at ``k Ts`` (a recording, or a pre-sampled profile).

    ``sample(t)`` returns the sample at the nearest grid point (held after the end).
    """

    def __init__(self, Ts, position, velocity=None, accel=None, duration=None):
        self.Ts = as_positive("Ts", Ts)
        self.position = as_finite_array("position", position, ndim=1)
        n = len(self.position)
        if n == 0:
            raise ValueError("position must have at least one sample")
        self.velocity = (
            np.zeros(n) if velocity is None else as_finite_array("velocity", velocity, ndim=1)
        )
        self.accel = np.zeros(n) if accel is None else as_finite_array("accel", accel, ndim=1)
        if not len(self.velocity) == len(self.accel) == n:
            raise ValueError("position, velocity and accel must have the same length")
        self.duration = (
            (n - 1) * self.Ts if duration is None else as_nonnegative("duration", duration)
        )

    @classmethod
    def from_profile(cls, profile, Ts, t_end=None):
        """Sample ``profile`` once on the grid (to re-run many simulations cheaply)."""
        _check_profile(profile)
        Ts = as_positive("Ts", Ts)
        t = np.arange(_n_samples(_duration(profile), Ts, t_end)) * Ts
        s = profile.sample(t)
        return cls(Ts, s.position, s.velocity, s.accel, duration=float(profile.duration))

    def sample(self, t):
        t = np.asarray(t, dtype=float)
        k = np.clip(np.rint(t / self.Ts).astype(int), 0, len(self.position) - 1)
        return _Sample(t, np.zeros_like(t), self.accel[k], self.velocity[k], self.position[k])


# ---------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------
def _check_profile(profile):
    if not (hasattr(profile, "duration") and callable(getattr(profile, "sample", None))):
        raise ValueError(
            "profile must have .duration and .sample(t) (a jerklab.planner Profile), "
            f"got {type(profile).__name__}"
        )


def _check_inputs(profile, motor):
    _check_profile(profile)
    if not isinstance(motor, (DCMotor, FlexibleDCMotor)):
        raise ValueError(f"motor must be a DCMotor or FlexibleDCMotor, got {type(motor).__name__}")


def _law_for(controller, motor, loop, Ts):
    """The packed law parameters (:func:`jerklab.law.pack`), the loop and Ts of a run.

    DiscreteGains get Stojčić eq. 16 feedforward from the motor's K, τ and an output limit at the
    supply voltage; the controller object is only read, never stepped.
    """
    if isinstance(controller, DigitalController):
        p = controller.params()
        cloop = controller.loop
    elif isinstance(controller, DiscreteGains):
        limit = math.inf if motor.supply_voltage is None else motor.supply_voltage
        g = controller
        p = dict(
            kpd=g.kpd,
            kid=g.kid,
            kdd=g.kdd,
            gamma=g.gamma,
            Ts=g.Ts,
            ff_on=True,
            ff_K=motor.K,
            ff_tau=motor.tau,
            limit=limit,
            anti_windup=True,
            error_scale=1.0,
            bumpless=False,
        )
        cloop = g.loop
    elif isinstance(controller, Gains):
        raise ValueError(
            "controller must be a DigitalController or DiscreteGains; "
            "discretize continuous Gains first (Gains.discretize(Ts), Stojčić eq. 13)"
        )
    else:
        raise TypeError(
            f"controller must be a DigitalController or DiscreteGains, got "
            f"{type(controller).__name__}"
        )
    if loop is not None:
        if loop not in ("position", "velocity"):
            raise ValueError(f"loop must be 'position' or 'velocity', got {loop!r}")
        cloop = loop
    p["velocity"] = cloop == "velocity"
    if Ts is None:
        Ts = p["Ts"]
    else:
        Ts = as_positive("Ts", Ts)
        if not math.isclose(p["Ts"], Ts, rel_tol=1e-12):
            raise ValueError(f"Ts={Ts} differs from the controller's gains.Ts={p['Ts']}")
    p["Ts"] = Ts
    return law.pack(**p), cloop, Ts


#: the largest run :func:`simulate` accepts (samples); beyond it the request is refused up front
MAX_SAMPLES = 20_000_000
_EMPTY = np.empty(0)
_RIGID_M = np.zeros((3, 2, 3))
# sampled references of planner profiles, by their defining parameters and the grid (LRU)
_REF_CACHE: OrderedDict = OrderedDict()
_REF_CACHE_SIZE = 16
_REF_CACHE_MAX_N = 200_000


def _duration(profile):
    try:
        d = float(profile.duration)
    except (TypeError, ValueError):
        raise ValueError(
            f"profile.duration must be a real number, got {profile.duration!r}"
        ) from None
    if not (math.isfinite(d) and d >= 0.0):
        raise ValueError(f"profile.duration must be finite and >= 0, got {d!r}")
    return d


def _n_samples(duration, Ts, t_end):
    t_end = duration + 0.5 if t_end is None else as_nonnegative("t_end", t_end)
    n = math.floor(t_end / Ts + 1e-9) + 1
    if n > MAX_SAMPLES:
        raise ValueError(
            f"t_end={t_end} at Ts={Ts} is {n} samples, more than MAX_SAMPLES={MAX_SAMPLES}; "
            "simulate a shorter time or a longer Ts"
        )
    return int(n)


def _profile_key(profile):
    """A key of a jerklab.planner profile (closed form, fixed by its public parameters), else None."""
    if not isinstance(profile, Profile) or type(profile).sample is not Profile.sample:
        return None
    return (
        type(profile),
        profile.kind,
        float(profile.distance),
        tuple(profile.phase_times),
        float(profile.peak_jerk),
    )


def _reference(profile, Ts, n, duration):
    """The profile sampled at ``k Ts``, k < n, as a (3, n) array (position, velocity, acceleration).

    Planner profiles are sampled once per grid and kept (a small LRU cache): the tuning panel
    and the labs simulate the same move many times with other gains.
    """
    key = _profile_key(profile)
    if key is not None:
        key = key + (Ts, n)
        hit = _REF_CACHE.get(key)
        if hit is not None:
            _REF_CACHE.move_to_end(key)
            return hit.copy()
    ref = np.empty((3, n))
    if isinstance(profile, SampledProfile) and profile.Ts == Ts:
        m = min(n, len(profile.position))
        for row, src in enumerate((profile.position, profile.velocity, profile.accel)):
            ref[row, :m] = src[:m]
            ref[row, m:] = src[-1]
    else:
        try:
            s = profile.sample(np.arange(n) * Ts)
            ref[0] = s.position
            ref[1] = s.velocity
            ref[2] = s.accel
        except AttributeError:
            raise ValueError(
                "profile.sample(t) must return .position, .velocity and .accel "
                "(a jerklab.planner Profile does)"
            ) from None
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"profile.sample(t) must return arrays of the shape of t ({n},): {exc}"
            ) from None
    if not np.isfinite(ref).all():
        raise ValueError("profile.sample(t) returned non-finite values (NaN or inf)")
    if key is not None and n <= _REF_CACHE_MAX_N:
        _REF_CACHE[key] = ref.copy()
        if len(_REF_CACHE) > _REF_CACHE_SIZE:
            _REF_CACHE.popitem(last=False)
    return ref


def _common(motor):
    d = motor.load_disturbance
    return dict(
        dist_on=d is not None,
        dist_amp=0.0 if d is None else d.amplitude,
        dist_time=0.0 if d is None else d.time,
        supply=0.0 if motor.supply_voltage is None else motor.supply_voltage,
        levels=0.0 if motor.pwm_bits is None else float(2**motor.pwm_bits - 1),
        cpr=0.0 if motor.counts_per_rad is None else motor.counts_per_rad,
    )


def _plant_pack(motor, Ts):
    """Packed plant parameters (``P_*``), the ZOH matrices ``M`` and the number of states."""
    c = _common(motor)
    pp = np.zeros(_NP)
    pp[P_K] = motor.K
    pp[P_TAU] = motor.tau
    pp[P_DIST_ON] = c["dist_on"]
    pp[P_DIST_AMP] = c["dist_amp"]
    pp[P_DIST_TIME] = c["dist_time"]
    pp[P_SUPPLY] = c["supply"]
    pp[P_LEVELS] = c["levels"]
    pp[P_CPR] = c["cpr"]
    if isinstance(motor, DCMotor):
        pp[P_RIGID] = 1.0
        pp[P_FC] = motor.coulomb_friction
        pp[P_OFFSET] = getattr(motor, "offset", 0.0)
        pp[P_DEAD_ZONE] = getattr(motor, "dead_zone", 0.0)
        return pp, _RIGID_M, 2
    Phi, Gam = motor.zoh(Ts)
    parts = [(Phi, Gam), (Phi, Gam), (Phi, Gam)]
    d = motor.load_disturbance
    if d is not None:
        frac = d.time / Ts - math.floor(d.time / Ts)
        if 0.0 < frac < 1.0:
            parts[1] = motor.zoh(frac * Ts)
            parts[2] = motor.zoh((1.0 - frac) * Ts)
    M = np.empty((3, 4, 5))
    for i, (F, G) in enumerate(parts):
        M[i, :, :4] = F
        M[i, :, 4] = G[:, 0]
    return pp, M, 4


def _band(motor, settle_band):
    if settle_band is not None:
        return as_positive("settle_band", settle_band)
    cpr = motor.counts_per_rad
    return 2.0 / cpr if cpr else 1e-3


def simulate(profile, motor, controller, Ts=None, t_end=None, loop=None, x0=None, settle_band=None):
    """Simulate the sampled closed loop on a move.

    Parameters
    ----------
    profile : Profile
        Anything with ``duration`` and ``sample(t)`` → ``.position .velocity .accel``
        (:mod:`jerklab.planner`); sampled in closed form at ``k Ts`` (a planner profile
        once per grid: repeated runs reuse the samples).
    motor : DCMotor or FlexibleDCMotor
        The plant with its imperfections (saturation, PWM, encoder, friction,
        disturbance, noise).
    controller : DigitalController or DiscreteGains
        DiscreteGains are wrapped with Stojčić eq. 16 feedforward from the motor's K, τ and an
        output limit at the supply voltage. The controller object itself is not stepped
        (its state is untouched); the compiled kernel runs the same law
        (:func:`jerklab.law.pid_step`).
    Ts : float, optional
        Sampling time; defaults to the gains' Ts (must agree with it).
    t_end : float, optional
        Simulated time, default ``profile.duration + 0.5`` s (at most ``MAX_SAMPLES``
        samples).
    loop : {"position", "velocity"}, optional
        Override the controller's loop (§4B velocity loop: reference in pulses per Ts
        when the controller's ``error_scale`` is :func:`~jerklab.controller.paper_error_scale`).
    x0 : array, optional
        Initial plant state (default rest at 0).
    settle_band : float, optional
        Band for the settling time (rad, > 0); default 2 encoder counts (1 mrad without an
        encoder).

    Returns
    -------
    SimResult
        ``metrics``: :func:`jerklab.metrics.move_metrics` of the true angle (``max_error``
        during the move, ``peak_error`` over the run, ``rms_error``, ``final_error``,
        ``overshoot_pct``, ``settling_time`` after the end of the profile into ``settle_band``
        (inf if never, NaN if the run diverged), ``peak_voltage``, ``saturated``,
        ``saturated_fraction``), with ``diverged`` (and ``diverged_at``, s) and, for a
        flexible load, ``residual_vibration`` (max ``|load − distance|`` after the move).

    Warns
    -----
    RuntimeWarning
        When the run diverged (``result.diverged``): a state went NaN/inf, or the error
        grew beyond ``DIVERGENCE_FACTOR`` × max(``|distance|``, 1).
    """
    _check_inputs(profile, motor)
    ctl, cloop, Ts = _law_for(controller, motor, loop, Ts)
    duration = _duration(profile)
    n = _n_samples(duration, Ts, t_end)
    ref = _reference(profile, Ts, n, duration)
    t = np.arange(n) * Ts
    band = _band(motor, settle_band)
    distance = float(ref[0, -1]) if t[-1] >= duration else float(profile.sample(duration).position)
    x = motor.initial_state(x0)
    noise = motor.rng.normal(0.0, motor.noise_std, n) if motor.noise_std > 0 else _EMPTY
    pp, M, ns = _plant_pack(motor, Ts)
    pp[P_DISTANCE] = distance
    pp[P_DURATION] = duration
    pp[P_BOUND] = DIVERGENCE_FACTOR * max(abs(distance), 1.0)
    OUT = np.empty((ns + _NO, n))
    sat = np.empty(n, dtype=np.bool_)
    met = np.empty(_NM)
    _kernel(ref, noise, x, pp, M, ctl, OUT, sat, met)
    position = OUT[0]
    metrics = series_metrics(
        t, ref[0], position, OUT[ns + O_UAPP], duration, distance, settle_band=band, saturated=sat
    )
    diverged = _divergence(met, t, ns, metrics)
    return SimResult(
        time=t,
        reference=ref[0],
        ref_velocity=ref[1],
        ref_accel=ref[2],
        measured=OUT[ns + O_MEAS],
        position=position,
        velocity=OUT[1],
        error=ref[0] - position,
        loop_error=OUT[ns + O_E],
        command=OUT[ns + O_UCMD],
        voltage=OUT[ns + O_UAPP],
        parts={"p": OUT[ns + O_P], "i": OUT[ns + O_I], "d": OUT[ns + O_D], "ff": OUT[ns + O_FF]},
        saturated=sat,
        metrics=metrics,
        loop=cloop,
        load_position=OUT[2] if ns == 4 else None,
        info=dict(Ts=Ts, duration=duration, distance=distance, compiled=HAVE_NUMBA),
        diverged=diverged,
    )


def _divergence(met, t, ns, metrics) -> bool:
    """Add the run's divergence (and a flexible load's residual vibration) to ``metrics``
    (:func:`jerklab.metrics.move_metrics` of the traces) from the kernel's notes; True if the
    run diverged (its settling time is then NaN)."""
    k_bad = int(met[M_NONFINITE])
    k_far = int(met[M_BEYOND])
    nonfinite = k_bad >= 0
    diverged = nonfinite or k_far >= 0
    if diverged:
        metrics["settling_time"] = math.nan
    metrics["diverged"] = diverged
    if ns == 4:
        metrics["residual_vibration"] = (
            float(met[M_RESID]) if met[M_NAFTER] > 0 and not nonfinite else math.nan
        )
    if diverged:
        k = min(k for k in (k_bad, k_far) if k >= 0)
        metrics["diverged_at"] = float(t[k])
        what = (
            "a state became NaN/inf"
            if nonfinite and k == k_bad
            else f"|error| exceeded {DIVERGENCE_FACTOR:g} x max(|distance|, 1)"
        )
        warnings.warn(
            f"simulate: the loop diverged at t = {t[k]:.6g} s ({what}); settling_time is NaN"
            + ("; the samples after it are NaN" if nonfinite else ""),
            RuntimeWarning,
            stacklevel=3,
        )
    return diverged


def _rng(seed):
    try:
        return np.random.default_rng(seed)
    except (TypeError, ValueError) as exc:
        raise TypeError(
            f"seed must be None, an int or a numpy Generator/SeedSequence, got {seed!r}: {exc}"
        ) from None


def perturbed_plants(
    n,
    K=paper.MOTOR_K,
    tau=paper.MOTOR_TAU,
    K_spread=0.2,
    tau_spread=0.2,
    friction=(0.0, 0.0),
    seed=None,
):
    """Random plants for robustness studies: K and τ uniform within ±spread (relative),
    Coulomb friction uniform in ``friction = (low, high)`` V. Returns a dict of arrays."""
    n = as_int("n", n, minimum=1)
    if n > MAX_SAMPLES:
        raise ValueError(f"n must be <= {MAX_SAMPLES} plants, got {n}")
    K = as_positive("K", K)
    tau = as_positive("tau", tau)
    ks = as_nonnegative("K_spread", K_spread)
    ts = as_nonnegative("tau_spread", tau_spread)
    if ks >= 1 or ts >= 1:
        raise ValueError("K_spread and tau_spread must be < 1 (relative spreads)")
    if isinstance(friction, (str, bytes)) or not hasattr(friction, "__len__") or len(friction) != 2:
        raise ValueError(f"friction must be a (low, high) pair in V, got {friction!r}")
    lo, hi = (
        as_nonnegative("friction low", friction[0]),
        as_nonnegative("friction high", friction[1]),
    )
    if hi < lo:
        raise ValueError(f"friction must be (low, high) with low <= high, got {friction!r}")
    rng = _rng(seed)
    return dict(
        K=K * (1 + rng.uniform(-ks, ks, n)),
        tau=tau * (1 + rng.uniform(-ts, ts, n)),
        coulomb_friction=rng.uniform(lo, hi, n),
    )


def _plant_values(name, value) -> np.ndarray:
    """One parameter of :func:`simulate_batch`'s plants: a number or a 1-D array, as 1-D."""
    a = as_finite_array(name, value)
    if a.ndim > 1:
        raise ValueError(
            f"{name} must be a number or a 1-D array (one value per plant), got shape {a.shape}"
        )
    return np.atleast_1d(a)


def simulate_batch(
    profile,
    motor,
    controller,
    K=None,
    tau=None,
    coulomb_friction=None,
    Ts=None,
    t_end=None,
    loop=None,
    engine="auto",
    settle_band=None,
    seed=None,
    keep_traces=True,
):
    """The closed loop of :func:`simulate` over many rigid plants at once.

    ``K``, ``tau``, ``coulomb_friction`` are 1-D arrays (or scalars, broadcast) overriding
    the template ``motor``'s values; every other imperfection (saturation, PWM,
    encoder, disturbance, noise level) comes from ``motor``. The controller (gains and
    feedforward) is the same for all plants — the robustness question.

    ``engine="numpy"`` vectorizes over the plants (a loop over time, numpy arrays over
    plants, :func:`jerklab.plant.advance`); ``"compiled"`` runs the numba kernel with
    the metrics accumulated on the fly; ``"auto"`` picks compiled when numba is
    present. Both give the same numbers (tested).

    Returns
    -------
    BatchResult
        ``position`` and applied ``voltage`` (n_plants × n_samples, None unless
        ``keep_traces``) and per-plant ``metrics`` arrays: the keys of
        :func:`jerklab.metrics.move_metrics` (no saturation count) and ``diverged``, defined
        as in :func:`simulate`.
    """
    _check_inputs(profile, motor)
    if not isinstance(motor, DCMotor):
        raise ValueError("simulate_batch needs a rigid DCMotor template")
    if getattr(motor, "offset", 0.0) or getattr(motor, "dead_zone", 0.0):
        raise ValueError(
            "simulate_batch does not model the motor's offset and dead_zone yet; "
            "use simulate() per plant, or a motor with offset=0 and dead_zone=0"
        )
    if engine not in ("auto", "numpy", "compiled"):
        raise ValueError(f"engine must be 'auto', 'numpy' or 'compiled', got {engine!r}")
    ctl, cloop, Ts = _law_for(controller, motor, loop, Ts)
    Kv, tv, fv = (
        _plant_values(name, default if value is None else value)
        for name, value, default in (
            ("K", K, motor.K),
            ("tau", tau, motor.tau),
            ("coulomb_friction", coulomb_friction, motor.coulomb_friction),
        )
    )
    try:
        Kv, tv, fv = (
            np.ascontiguousarray(a, dtype=float).ravel() for a in np.broadcast_arrays(Kv, tv, fv)
        )
    except ValueError:
        raise ValueError(
            f"K, tau and coulomb_friction must broadcast to one length, got shapes "
            f"{Kv.shape}, {tv.shape}, {fv.shape}"
        ) from None
    if Kv.size == 0:
        raise ValueError("K, tau and coulomb_friction give no plant (empty arrays)")
    for name, v, bad in (
        ("K", Kv, Kv <= 0),
        ("tau", tv, tv <= 0),
        ("coulomb_friction", fv, fv < 0),
    ):
        if np.any(bad):
            i = int(np.argmax(bad))
            rule = ">= 0" if name == "coulomb_friction" else "> 0"
            raise ValueError(
                f"{name} must be {rule} for every plant, got {float(v[i])!r} at plant {i}"
            )
    m = len(Kv)
    duration = _duration(profile)
    n = _n_samples(duration, Ts, t_end)
    if keep_traces and m * n > MAX_SAMPLES * 10:
        raise ValueError(
            f"keep_traces with {m} plants x {n} samples is more than {MAX_SAMPLES * 10} values; "
            "use keep_traces=False (metrics only) or fewer plants"
        )
    t = np.arange(n) * Ts
    ref = _reference(profile, Ts, n, duration)
    rpos, rvel, racc = ref[0], ref[1], ref[2]
    common = _common(motor)
    rng = _rng(seed)
    noise_on = motor.noise_std > 0
    noise = rng.normal(0.0, motor.noise_std, (m, n)) if noise_on else np.zeros((1, 1))
    band = _band(motor, settle_band)
    distance = float(profile.sample(duration).position)
    if engine == "auto":
        engine = "compiled" if HAVE_NUMBA else "numpy"
    if engine == "compiled":
        shape = (m, n) if keep_traces else (1, 1)
        POS = np.empty(shape)
        U = np.empty(shape)
        MET = np.empty((m, 8))
        _batch_kernel(
            rpos,
            rvel,
            racc,
            Kv,
            tv,
            fv,
            noise,
            noise_on,
            common["dist_on"],
            common["dist_amp"],
            common["dist_time"],
            common["supply"],
            common["levels"],
            common["cpr"],
            ctl,
            duration,
            distance,
            band,
            keep_traces,
            POS,
            U,
            MET,
        )
        metrics = _accumulated_metrics(MET, t, duration, distance, band)
        if not keep_traces:
            POS = U = None
    elif engine == "numpy":
        if not noise_on:
            noise = np.zeros((m, n))
        POS, U = _batch_numpy(rpos, rvel, racc, Kv, tv, fv, noise, common, ctl)
        metrics = series_metrics(t, rpos, POS, U, duration, distance, settle_band=band)
        if not keep_traces:
            POS = U = None
    return BatchResult(
        time=t,
        reference=rpos,
        K=Kv,
        tau=tv,
        coulomb_friction=fv,
        position=POS,
        voltage=U,
        metrics=_batch_divergence(metrics, distance),
    )


def _batch_numpy(rpos, rvel, racc, Kv, tv, fv, noise, common, ctl):
    """Time loop, numpy over plants: the law's vector form (:func:`jerklab.law.pid_step_vec`).

    Returns (θ, u applied).
    """
    m, n = noise.shape
    kpd, kid, kdd, gamma, lim = (
        ctl[law.C_KPD],
        ctl[law.C_KID],
        ctl[law.C_KDD],
        ctl[law.C_GAMMA],
        ctl[law.C_LIMIT],
    )
    aw, ff_on, velocity, bumpless = (
        bool(ctl[law.C_AW]),
        bool(ctl[law.C_FF_ON]),
        bool(ctl[law.C_VELOCITY]),
        bool(ctl[law.C_BUMPLESS]),
    )
    ffK, fftau, scale, Ts = ctl[law.C_FF_K], ctl[law.C_FF_TAU], ctl[law.C_SCALE], ctl[law.C_TS]
    th = np.zeros(m)
    om = np.zeros(m)
    i_prev = np.zeros(m)
    e_prev = np.zeros(m)
    d_prev = np.zeros(m)
    y_prev = np.zeros(m)
    POS = np.empty((m, n))
    U = np.empty((m, n))
    cpr, supply, levels = common["cpr"], common["supply"], common["levels"]
    for k in range(n):
        POS[:, k] = th
        y = law.encoder_vec(th, cpr)
        y += noise[:, k]
        if velocity:
            if k == 0:
                y_prev = y
            e = scale * (rvel[k] - (y - y_prev) / Ts)
        else:
            e = scale * (rpos[k] - y)
        y_prev = y
        ff = (fftau * racc[k] + rvel[k]) / ffK if ff_on else 0.0
        if k == 0 and bumpless:
            e_prev = e
        u, _, i_prev, d_prev, _ = law.pid_step_vec(
            e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, lim, aw, want_saturated=False
        )
        e_prev = e
        v = law.voltage_vec(u, supply, levels)
        U[:, k] = v
        t0 = k * Ts
        if common["dist_on"] and t0 < common["dist_time"] < t0 + Ts:
            first = common["dist_time"] - t0
            th, om = _advance(th, om, v, fv, Kv, tv, first)
            th, om = _advance(th, om, v + common["dist_amp"], fv, Kv, tv, Ts - first)
        else:
            w = common["dist_amp"] if (common["dist_on"] and t0 >= common["dist_time"]) else 0.0
            th, om = _advance(th, om, v + w, fv, Kv, tv, Ts)
    return POS, U


def pd_rest_band(
    kpd, load, coulomb_friction, counts_per_rad=None, supply_voltage=None, pwm_bits=None
):
    """Where a PD loop (no integrator) can come to rest under a constant load and Coulomb friction.

    At rest the derivative and the feedforward are zero, so the motor sees ``u = k_pd e_m`` (PWM
    rounded) plus the load ``w`` (input referred, W = P as in Stojčić eq. 9) and sticks while
    ``|u + w| <= f_c``. Without friction and quantization this is the rest error of
    Stojčić eq. 9, ``e = -w / k_pd``.
    The controller sees the *measured* error ``e_m = r - floor(θ c)/c`` (encoder count ``c`` per
    rad), which exceeds the true error ``e = r - θ`` by less than one count ``q = 1/c``; the PWM
    rounds ``u`` to half a duty step ``Δ/2``. The true error at rest therefore lies in

        ``((-w - f_c - Δ/2)/k_pd - q,  (-w + f_c + Δ/2)/k_pd]``   (for ``k_pd > 0``).

    Parameters
    ----------
    kpd : float
        Proportional gain k_pd (V/rad, > 0).
    load : float
        Constant input-referred load w (V).
    coulomb_friction : float
        Friction f_c (V, >= 0).
    counts_per_rad : float, optional
        Encoder counts per rad (None: ideal sensor, q = 0).
    supply_voltage, pwm_bits : optional
        PWM full scale (V) and resolution; both None: no PWM rounding.

    Returns
    -------
    tuple of float
        ``(lo, hi)`` bounds of the true error ``r - θ`` at rest, rad.
    """
    kpd = as_positive("kpd", kpd)
    w = as_real("load", load)
    fc = as_nonnegative("coulomb_friction", coulomb_friction)
    q = 0.0 if counts_per_rad is None else 1.0 / as_positive("counts_per_rad", counts_per_rad)
    half_step = 0.0
    if supply_voltage is not None and pwm_bits is not None:
        half_step = 0.5 * as_positive("supply_voltage", supply_voltage) / (2 ** int(pwm_bits) - 1)
    return ((-w - fc - half_step) / kpd - q, (-w + fc + half_step) / kpd)


__all__ += ["pd_rest_band"]
