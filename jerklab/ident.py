"""System identification of the DC motor: data container, ARX, output-error (PEM) fit, validation.

Stojčić §4A (ASCII: Stojcic) identified the plant of Stojčić eq. 1,

    P(s) = K / (s (tau s + 1))        (volts -> rad)

from a voltage step recorded every 5 ms, with MATLAB's ``pem(data, 'P2')``, and got
K = 32.4 rad/(V s), tau = 0.025 s. A ``'P2'`` process model has two poles and *no* integrator;
the structure of Stojčić eq. 1 is a pole plus an integrator (MATLAB's ``'P1I'``), and that is what this
module fits; :func:`fit_p2` reproduces the paper's literal call to show where it goes
(notebooks/02_identification.ipynb). Two estimators are offered:

* ``method="arx"``: linear least squares on the differenced angle. The ZOH discretization of
  Stojčić eq. 1 gives, for v(k) = (theta(k) - theta(k-1)) / Ts, the *exact* difference equation

      v(k) = a v(k-1) + b1 u(k-1) + b2 u(k-2),    a = exp(-Ts/tau),

  with K = (b1 + b2) / (1 - a) and tau = -Ts / ln a. It is exact on noise-free data, but the
  regressor v(k-1) carries the measurement noise, so under output noise or encoder quantization the
  estimate is biased (``arx_asymptotic_bias`` predicts by how much).
* ``method="pem"``: the output-error (simulation-error) fit: K, tau (and the initial angle) minimise
  sum (theta_measured - theta_simulated)^2, where theta_simulated is the exact ZOH simulation of
  Stojčić eq. 1.
  With white measurement noise this is the maximum-likelihood estimate and is unbiased; its
  covariance comes from the Jacobian at the optimum.

Real records (measured, closed loop, several experiments) need more than Stojčić eq. 1: ``fit_dc_motor``
also estimates Coulomb friction against the velocity (with sticking), an input offset, a dead zone
and a pure delay (:func:`simulate_motor`), by output error with **multiple shooting** (each segment
of the record starts from its own estimated state, so an integrating plant cannot drift), started
by the inverse-dynamics least squares of motion control (``method="idim"``, Gautier & Janot; and
``"idim-iv"`` with instrumental variables). Implausible results raise an
:class:`IdentificationWarning` naming the likely cause.

Also here: :class:`IdentData` (CSV + JSON records, built from a rig ``Recording``), :func:`merge`
of several experiments, :func:`load_micromouse` (measured gearmotor records, data/real), :func:`arx`
for any orders, validation with MATLAB's semantics (:func:`compare` for simulation and k-step
prediction, :func:`resid`, :func:`validate`, :func:`residual_analysis`, :func:`plot_compare`,
:func:`plot_residuals`), input design (:func:`step_input`, :func:`prbs`, :func:`sample_time_range`)
and :func:`arx_asymptotic_bias`. Everything is SI: volts in, radians out, seconds.
"""

from __future__ import annotations

import json
import math
import pathlib
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize, signal, stats

from jerklab._lazy import lazy_module
from jerklab._validate import as_finite_array, as_int, as_nonnegative, as_positive, as_real
from jerklab.law import zoh_coefficients
from jerklab.plant import _jit, advance_em
from jerklab.plots import plot_compare, plot_compare_result, plot_ident_data, plot_residuals

control = lazy_module("control")  # python-control imports matplotlib: import it on first use

__all__ = [
    "IdentData",
    "ARXResult",
    "arx",
    "MotorFit",
    "fit_dc_motor",
    "IdentificationWarning",
    "simulate_motor",
    "simulate_dc_motor",
    "dc_motor_zoh_coefficients",
    "arx_asymptotic_bias",
    "P2Fit",
    "fit_p2",
    "fit_percent",
    "ResidualAnalysis",
    "residual_analysis",
    "Validation",
    "MergedData",
    "merge",
    "CompareResult",
    "compare",
    "resid",
    "load_micromouse",
    "load_dc_generator",
    "micromouse_battery_voltage",
    "validate",
    "plot_compare",
    "plot_residuals",
    "step_input",
    "prbs",
    "sample_time_range",
]

#: fewest samples a record must hold to be fitted (a handful per parameter, plus transients)
MIN_SAMPLES = 10


# ----------------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------------
def _signal(name: str, value, min_len: int = MIN_SAMPLES) -> np.ndarray:
    a = as_finite_array(name, value)
    if a.ndim != 1:
        a = np.squeeze(a)
        if a.ndim != 1:
            raise ValueError(
                f"{name} must be a 1-D sequence of samples, got shape {np.shape(value)}"
            )
    if a.size < min_len:
        raise ValueError(f"{name} is too short: {a.size} samples, need at least {min_len}")
    return a


def _pair(u, y, u_name: str = "u", y_name: str = "y", min_len: int = MIN_SAMPLES):
    u = _signal(u_name, u, min_len)
    y = _signal(y_name, y, min_len)
    if u.size != y.size:
        raise ValueError(
            f"{u_name} and {y_name} must have the same length, got {u.size} and {y.size}"
        )
    return u, y


def _check_excitation(u: np.ndarray, y: np.ndarray, u_name: str, y_name: str) -> None:
    scale = max(1.0, float(np.max(np.abs(u))))
    if np.ptp(u) <= 1e-12 * scale:
        raise ValueError(
            f"{u_name} is constant ({u[0]:g}): it does not excite the motor; record a step from rest "
            f"(u = 0 first) or a PRBS (see step_input, prbs)"
        )
    yscale = max(1.0, float(np.max(np.abs(y))))
    if np.ptp(y) <= 1e-12 * yscale:
        raise ValueError(
            f"{y_name} is constant ({y[0]:g}): the motor did not move (check the supply, "
            f"the encoder, or a voltage below the friction threshold)"
        )


# ----------------------------------------------------------------------------------------------
# data container
# ----------------------------------------------------------------------------------------------
class IdentData:
    """An identification record: input u(k), output y(k) sampled every ``Ts`` seconds.

    The Python counterpart of MATLAB's ``iddata(y, u, Ts)`` used in Stojčić §4A.

    Parameters
    ----------
    u : array_like
        Input samples (the motor voltage, V), held constant over each sample period (ZOH).
    y : array_like
        Output samples (the measured angle, rad), same length as ``u``.
    Ts : float
        Sample period (s), > 0.
    input_unit, output_unit : str
        Units, kept in the JSON sidecar ("V" and "rad" by default: SI inside).
    metadata : dict, optional
        Anything JSON-able describing how the record was made (plant parameters, seed, command).

    Examples
    --------
    >>> d = IdentData(step_input(1.0, 0.005, 6.0), theta, 0.005)        # doctest: +SKIP
    >>> d.save("data/ident/step")                                       # doctest: +SKIP
    >>> fit = IdentData.load("data/ident/step").fit("pem")              # doctest: +SKIP
    """

    FORMAT = "jerklab.ident.IdentData/1"

    def __init__(self, u, y, Ts, input_unit: str = "V", output_unit: str = "rad", metadata=None):
        self.u, self.y = _pair(u, y, "u", "y", min_len=2)
        self.Ts = as_positive("Ts", Ts)
        if not isinstance(input_unit, str) or not input_unit:
            raise ValueError(f"input_unit must be a non-empty string, got {input_unit!r}")
        if not isinstance(output_unit, str) or not output_unit:
            raise ValueError(f"output_unit must be a non-empty string, got {output_unit!r}")
        self.input_unit = input_unit
        self.output_unit = output_unit
        if metadata is None:
            metadata = {}
        if not isinstance(metadata, dict):
            raise ValueError(f"metadata must be a dict, got {type(metadata).__name__}")
        try:
            json.dumps(metadata)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"metadata must be JSON-serialisable: {exc}") from None
        self.metadata = dict(metadata)

    # -- shape ---------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.u.size)

    def __len__(self) -> int:
        return self.n

    @property
    def t(self) -> np.ndarray:
        """Sample times k*Ts (s)."""
        return np.arange(self.n) * self.Ts

    @property
    def duration(self) -> float:
        """Record length n*Ts (s)."""
        return self.n * self.Ts

    def __getitem__(self, index) -> "IdentData":
        """A contiguous slice of samples (e.g. ``d[:200]`` for estimation, ``d[200:]`` to validate)."""
        if not isinstance(index, slice) or index.step not in (None, 1):
            raise ValueError("index must be a contiguous slice of samples, e.g. data[100:400]")
        md = dict(self.metadata)
        start = index.indices(self.n)[0]
        md["slice_start_sample"] = md.get("slice_start_sample", 0) + start
        return IdentData(
            self.u[index], self.y[index], self.Ts, self.input_unit, self.output_unit, md
        )

    def __repr__(self) -> str:
        return (
            f"IdentData(n={self.n}, Ts={self.Ts:g} s, duration={self.duration:g} s, "
            f"u in [{self.u.min():g}, {self.u.max():g}] {self.input_unit}, "
            f"y in [{self.y.min():g}, {self.y.max():g}] {self.output_unit})"
        )

    # -- conversions ---------------------------------------------------------------------------
    @classmethod
    def from_recording(cls, rec, Ts=None) -> "IdentData":
        """Build from a rig ``Recording`` (fields ``time``, ``position``, ``control``, ``metadata``).

        Parameters
        ----------
        rec : jerklab.rig.Recording
            An open-loop record (``rig.step(...)``) or a closed-loop move; ``control`` (V) becomes
            the input and ``position`` (rad) the output.
        Ts : float, optional
            Sample period; by default ``rec.metadata["Ts"]`` if present, else the median spacing
            of ``rec.time``. The time stamps must be uniform to 1 % of Ts.
        """
        for attr in ("time", "position", "control"):
            if not hasattr(rec, attr):
                raise ValueError(
                    f"rec must be a Recording with a '{attr}' field (got {type(rec).__name__})"
                )
        t = _signal("rec.time", rec.time, min_len=2)
        u = _signal("rec.control", rec.control, min_len=2)
        y = _signal("rec.position", rec.position, min_len=2)
        if not (t.size == u.size == y.size):
            raise ValueError(
                f"rec.time, rec.control and rec.position must have the same length, "
                f"got {t.size}, {u.size}, {y.size}"
            )
        md = getattr(rec, "metadata", None) or {}
        if not isinstance(md, dict):
            md = {}
        dt = np.diff(t)
        if Ts is None:
            Ts = md.get("Ts", md.get("ts", None))
            Ts = float(np.median(dt)) if Ts is None else Ts
        Ts = as_positive("Ts", Ts)
        if np.max(np.abs(dt - Ts)) > 0.01 * Ts:
            raise ValueError(
                f"rec.time is not uniformly sampled at Ts = {Ts:g} s "
                f"(spacing from {dt.min():g} to {dt.max():g} s)"
            )
        meta = {}
        for k, v in md.items():
            try:
                json.dumps(v)
                meta[str(k)] = v
            except (TypeError, ValueError):
                meta[str(k)] = repr(v)
        meta["source"] = "jerklab.rig.Recording"
        meta["t0"] = float(t[0])
        return cls(u, y, Ts, "V", "rad", meta)

    def fit(self, method: str = "pem", **kwargs) -> "MotorFit":
        """``fit_dc_motor(self.u, self.y, self.Ts, method, **kwargs)``."""
        return fit_dc_motor(self.u, self.y, self.Ts, method=method, **kwargs)

    # -- files ---------------------------------------------------------------------------------
    @staticmethod
    def _paths(path):
        p = pathlib.Path(path)
        if p.suffix in (".csv", ".json"):
            p = p.with_suffix("")
        return p.with_name(p.name + ".csv"), p.with_name(p.name + ".json")

    def save(self, path):
        """Write ``<path>.csv`` (columns time_s, u, y) and its JSON sidecar ``<path>.json``.

        Returns the two paths. Values are written with 17 significant digits, so a round trip is
        exact.
        """
        csv_path, json_path = self._paths(path)
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        cols = ["time_s", f"u_{self.input_unit}", f"y_{self.output_unit}"]
        table = np.column_stack([self.t, self.u, self.y])
        header = ",".join(cols)  # plain ASCII, or UTF-8 with a BOM so a spreadsheet reads "µm"
        np.savetxt(
            csv_path,
            table,
            delimiter=",",
            header=header,
            comments="",
            fmt="%.17g",
            encoding="ascii" if header.isascii() else "utf-8-sig",
        )
        side = {
            "format": self.FORMAT,
            "csv": csv_path.name,
            "columns": cols,
            "Ts": self.Ts,
            "n_samples": self.n,
            "input_unit": self.input_unit,
            "output_unit": self.output_unit,
            "metadata": self.metadata,
        }
        json_path.write_text(json.dumps(side, indent=2, sort_keys=False) + "\n")
        return csv_path, json_path

    @classmethod
    def load(cls, path) -> "IdentData":
        """Read a record written by :meth:`save` (``path`` with or without ``.csv``/``.json``)."""
        csv_path, json_path = cls._paths(path)
        if not json_path.exists():
            raise ValueError(f"path: no JSON sidecar {json_path}")
        if not csv_path.exists():
            raise ValueError(f"path: no CSV file {csv_path}")
        try:
            side = json.loads(json_path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"path: corrupt JSON sidecar {json_path}: {exc}") from None
        if side.get("format") != cls.FORMAT:
            raise ValueError(
                f"path: {json_path} is not an IdentData sidecar (format {side.get('format')!r})"
            )
        try:
            table = np.loadtxt(csv_path, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"path: corrupt CSV {csv_path}: {exc}") from None
        if table.shape[1] != 3:
            raise ValueError(f"path: {csv_path} must have 3 columns, has {table.shape[1]}")
        n = side.get("n_samples")
        if n is not None and n != table.shape[0]:
            raise ValueError(f"path: {csv_path} has {table.shape[0]} rows, sidecar says {n}")
        Ts = as_positive("Ts", side["Ts"])
        t = table[:, 0]
        if t.size > 1 and np.max(np.abs(np.diff(t) - Ts)) > 0.01 * Ts:
            raise ValueError(f"path: time column of {csv_path} is not sampled at Ts = {Ts:g} s")
        return cls(
            table[:, 1],
            table[:, 2],
            Ts,
            side.get("input_unit", "V"),
            side.get("output_unit", "rad"),
            side.get("metadata", {}),
        )

    def plot(self, axes=None):
        """Input (V) and output (rad) against time (s): :func:`jerklab.plots.plot_ident_data`."""
        return plot_ident_data(self, axes)


# ----------------------------------------------------------------------------------------------
# ARX
# ----------------------------------------------------------------------------------------------
@dataclass
class ARXResult:
    """Least-squares ARX estimate ``A(q) y(t) = B(q) u(t - nk) + e(t)`` (MATLAB's ``arx``).

    ``A = [1, a1, ..., a_na]`` and ``B = [b0, ..., b_{nb-1}]`` are polynomials in the delay q^-1:
    y(t) + a1 y(t-1) + ... = b0 u(t-nk) + b1 u(t-nk-1) + ...
    """

    A: np.ndarray
    B: np.ndarray
    na: int
    nb: int
    nk: int
    params: np.ndarray  #: [a1..a_na, b0..b_{nb-1}]
    cov: np.ndarray  #: parameter covariance lambda (Phi^T Phi)^-1
    noise_variance: float  #: lambda = SSR / (N - n_params)
    residuals: np.ndarray  #: equation errors e(t) for t = n0 .. N-1
    n_used: int  #: number of equations (rows of Phi)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of ``params`` (valid when e(t) is white)."""
        return np.sqrt(np.diag(self.cov))

    def tf(self, Ts) -> control.TransferFunction:
        """The model B(z^-1) z^-nk / A(z^-1) as a discrete python-control transfer function."""
        Ts = as_positive("Ts", Ts)
        n = max(self.na, self.nk + self.nb - 1)
        num = np.zeros(n + 1)
        num[self.nk : self.nk + self.nb] = self.B
        den = np.zeros(n + 1)
        den[: self.na + 1] = self.A
        return control.tf(num, den, Ts)

    def predict(self, y, u) -> np.ndarray:
        """One-step-ahead prediction yhat(t) for t = n0 .. N-1."""
        u, y = _pair(u, y, "u", "y", min_len=2)
        Phi, _, _ = _arx_regressors(y, u, self.na, self.nb, self.nk)
        return Phi @ self.params


def _arx_regressors(y, u, na, nb, nk):
    n0 = max(na, nk + nb - 1)
    N = y.size
    rows = N - n0
    Phi = np.empty((rows, na + nb))
    for i in range(1, na + 1):
        Phi[:, i - 1] = -y[n0 - i : N - i]
    for j in range(nb):
        d = nk + j
        Phi[:, na + j] = u[n0 - d : N - d]
    return Phi, y[n0:], n0


def arx(y, u, na, nb, nk=1) -> ARXResult:
    """Least-squares ARX fit of any order, with the parameter covariance.

    Model (MATLAB's ``arx(data, [na nb nk])``)::

        y(t) + a1 y(t-1) + ... + a_na y(t-na) = b0 u(t-nk) + ... + b_{nb-1} u(t-nk-nb+1) + e(t)

    Parameters
    ----------
    y, u : array_like
        Output and input, same length.
    na : int
        Number of poles (>= 0).
    nb : int
        Number of B coefficients (>= 0; na + nb >= 1).
    nk : int
        Input delay in samples (>= 0).

    Returns
    -------
    ARXResult
        ``cov = lambda (Phi^T Phi)^-1`` with ``lambda = SSR/(N_eq - n_params)``: the textbook
        covariance, correct when e(t) is white (Ljung, *System Identification*, §7.3, eq. 9.19).

    Raises
    ------
    ValueError
        On non-finite or mismatched data, too few samples for the orders, or a rank-deficient
        regression (the input does not excite the model: e.g. a constant input with nb >= 2).
    """
    na = as_int("na", na, minimum=0)
    nb = as_int("nb", nb, minimum=0)
    nk = as_int("nk", nk, minimum=0)
    if na + nb == 0:
        raise ValueError("na + nb must be >= 1 (nothing to estimate)")
    npar = na + nb
    u, y = _pair(u, y, "u", "y", min_len=2)
    n0 = max(na, nk + nb - 1)
    if y.size - n0 < npar + 1:
        raise ValueError(
            f"y is too short: {y.size} samples for na={na}, nb={nb}, nk={nk} "
            f"(need at least {n0 + npar + 1})"
        )
    Phi, target, n0 = _arx_regressors(y, u, na, nb, nk)
    # column scaling keeps the QR well conditioned when u and y differ by orders of magnitude
    scale = np.sqrt(np.sum(Phi**2, axis=0))
    if np.any(scale == 0.0):
        bad = int(np.flatnonzero(scale == 0.0)[0])
        which = "y" if bad < na else "u"
        raise ValueError(f"{which} is zero over the fitted window: the regression is singular")
    Q, R = np.linalg.qr(Phi / scale)
    sv = np.linalg.svd(R, compute_uv=False)
    if sv[-1] <= 1e-10 * sv[0]:
        raise ValueError(
            f"u does not excite an ARX({na},{nb},{nk}) model: the regression is rank deficient "
            f"(condition {sv[0] / max(sv[-1], 1e-300):.3g}); use a richer input (step from rest, PRBS) "
            f"or lower orders"
        )
    theta_s = np.linalg.solve(R, Q.T @ target)
    params = theta_s / scale
    res = target - Phi @ params
    dof = max(target.size - npar, 1)
    lam = float(res @ res) / dof
    Rinv = np.linalg.solve(R, np.eye(npar))
    cov = lam * (Rinv @ Rinv.T) / np.outer(scale, scale)
    A = np.concatenate([[1.0], params[:na]])
    B = params[na:].copy()
    return ARXResult(A, B, na, nb, nk, params, cov, lam, res, int(target.size))


# ----------------------------------------------------------------------------------------------
# the motor model and its exact ZOH simulation
# ----------------------------------------------------------------------------------------------
def dc_motor_zoh_coefficients(K, tau, Ts):
    """Exact ZOH discretization of Stojčić eq. 1, P(s) = K/(s(tau s + 1)).

    Returns ``(a, b1, b2)`` with a = exp(-Ts/tau) and

        theta(z)/u(z) = (b1 z^-1 + b2 z^-2) / ((1 - z^-1)(1 - a z^-1)),
        b1 = K (Ts - tau (1 - a)),     b2 = K (tau (1 - a) - a Ts),

    so the differenced angle obeys v(k) = a v(k-1) + (b1 u(k-1) + b2 u(k-2)) / Ts with
    v(k) = (theta(k) - theta(k-1)) / Ts, and b1 + b2 = K Ts (1 - a).
    """
    z = zoh_coefficients(K, tau, Ts)  # the one home: jerklab.law
    return z.a, z.b1, z.b0


def _unit_response(tau, Ts, u, omega0=0.0):
    """theta(k) of K=1, theta0=0 under ZOH input u (plus the free response to omega0 scaled by K=1)."""
    one_minus_a = -math.expm1(-Ts / tau)
    a = 1.0 - one_minus_a
    c = tau * one_minus_a
    # omega(k+1) = a omega(k) + (1-a) u(k)
    omega = signal.lfilter([0.0, one_minus_a], [1.0, -a], u)
    if omega0:
        omega = omega + omega0 * a ** np.arange(u.size)
    inc = c * omega + (Ts - c) * u
    theta = np.empty(u.size)
    theta[0] = 0.0
    np.cumsum(inc[:-1], out=theta[1:])
    return theta


def simulate_dc_motor(K, tau, Ts, u, theta0=0.0, omega0=0.0) -> np.ndarray:
    """Exact ZOH simulation of Stojčić eq. 1 (volts in, angle out), sample by sample.

    States [theta, omega] advance over one sample with u held (the exact solution)::

        omega(k+1) = a omega(k) + K (1 - a) u(k),                    a = exp(-Ts/tau)
        theta(k+1) = theta(k) + tau (1 - a) omega(k) + K (Ts - tau (1 - a)) u(k)

    This is the model the output-error fit simulates; it is ideal (no quantization, friction or
    noise: those belong to ``jerklab.plant.DCMotor``).

    Parameters
    ----------
    K : float
        Gain, rad/(V s).
    tau : float
        Mechanical time constant, s (> 0).
    Ts : float
        Sample period, s (> 0).
    u : array_like
        Input voltage samples (V), held over each period.
    theta0, omega0 : float
        Initial angle (rad) and angular velocity (rad/s).

    Returns
    -------
    ndarray
        theta(k), k = 0 .. len(u) - 1 (rad).
    """
    K = as_real("K", K)
    tau = as_positive("tau", tau)
    Ts = as_positive("Ts", Ts)
    u = _signal("u", u, min_len=1)
    theta0 = as_real("theta0", theta0)
    omega0 = as_real("omega0", omega0)
    w0 = omega0 / K if K != 0.0 else 0.0
    th = K * _unit_response(tau, Ts, u, w0) + theta0
    if K == 0.0 and omega0:
        th = th + _unit_response(tau, Ts, np.zeros_like(u), omega0)
    return th


def fit_percent(y, y_hat) -> float:
    """Normalised-RMSE fit in percent, as MATLAB's ``compare``: 100 (1 - |y - yhat| / |y - mean y|).

    100 is a perfect fit, 0 is no better than the mean, it can be negative.
    """
    y, y_hat = _pair(y, y_hat, "y", "y_hat", min_len=2)
    den = np.linalg.norm(y - y.mean())
    if den == 0.0:
        raise ValueError("y is constant: fit percent is undefined")
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / den))


def _best_theta0(y, y_model_zero_ic):
    """Initial angle that best aligns a simulation started at 0 with y (least squares)."""
    return float(np.mean(y - y_model_zero_ic))


# ----------------------------------------------------------------------------------------------
# the motor fit
# ----------------------------------------------------------------------------------------------
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
        from jerklab.plant import DCMotor

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


def _fit_arx(u, theta, Ts):
    v = np.diff(theta) / Ts
    res = arx(v, u[:-1], na=1, nb=2, nk=0)
    a = -res.A[1]
    b1, b2 = res.B
    if not 0.0 < a < 1.0:
        raise ValueError(
            f"theta: the ARX velocity fit found a pole a = {a:.4g} outside (0, 1), which no motor "
            f"K/(s(tau s+1)) gives; the data are too noisy or too coarse for ARX (try method='pem')"
        )
    bs = b1 + b2
    K = bs / (1.0 - a)
    tau = -Ts / math.log(a)
    # delta method on (a, b1, b2) -> (K, tau)
    J = np.array(
        [
            [bs / (1.0 - a) ** 2, 1.0 / (1.0 - a), 1.0 / (1.0 - a)],
            [Ts / (a * math.log(a) ** 2), 0.0, 0.0],
        ]
    )
    cov = J @ res.cov @ J.T
    return K, tau, cov, res


def _pem_model(u, theta, Ts, fit_theta0, friction):
    """Simulated angle as a function of p = [K, ln tau, (theta0), (f_c)]."""
    su = np.sign(u)

    lo, hi = math.log(Ts * 1e-4), math.log(Ts * u.size * 1e4)

    def sim(p):
        K, tau = p[0], math.exp(min(max(p[1], lo), hi))  # keep tau finite on hopeless data
        i = 2
        th0 = theta[0]
        if fit_theta0:
            th0 = p[i]
            i += 1
        ue = u - p[i] * su if friction else u
        return K * _unit_response(tau, Ts, ue) + th0

    return sim


def _initial_guess(u, theta, Ts, fit_theta0, friction):
    """Variable projection over tau on a log grid: for fixed tau the angle is linear in
    K, theta0 and K f_c, so each grid point is one small least-squares problem."""
    N = u.size
    taus = np.geomspace(Ts / 20.0, max(N * Ts, 2 * Ts), 40)
    best = None
    target = theta if fit_theta0 else theta - theta[0]
    for tau in taus:
        cols = [_unit_response(tau, Ts, u)]
        if fit_theta0:
            cols.append(np.ones(N))
        if friction:
            cols.append(-_unit_response(tau, Ts, np.sign(u)))
        M = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(M, target, rcond=None)
        r = target - M @ coef
        sse = float(r @ r)
        if best is None or sse < best[0]:
            K = coef[0]
            th0 = coef[1] if fit_theta0 else theta[0]
            fc = coef[-1] / K if (friction and K != 0) else 0.0
            best = (sse, K, tau, th0, fc)
    return best[1:]


def _fit_pem(u, theta, Ts, fit_theta0, friction=False):
    sim = _pem_model(u, theta, Ts, fit_theta0, friction)
    K0, tau0, th00, fc0 = _initial_guess(u, theta, Ts, fit_theta0, friction)
    p0 = [K0, math.log(tau0)]
    if fit_theta0:
        p0.append(th00)
    if friction:
        p0.append(fc0)
    p0 = np.array(p0)

    def resid(p):
        return sim(p) - theta

    sol = optimize.least_squares(
        resid, p0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=2000
    )
    p = sol.x
    # Jacobian at the optimum by central differences (more accurate than the solver's own)
    J = np.empty((theta.size, p.size))
    for i in range(p.size):
        h = 1e-6 * max(abs(p[i]), 1e-3)
        dp = np.zeros_like(p)
        dp[i] = h
        J[:, i] = (sim(p + dp) - sim(p - dp)) / (2 * h)
    r = sim(p) - theta
    dof = max(theta.size - p.size, 1)
    s2 = float(r @ r) / dof
    try:
        cov_p = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov_p = np.full((p.size, p.size), np.nan)
    if not math.log(Ts * 1e-4) < p[1] < math.log(Ts * u.size * 1e4):
        raise ValueError(
            f"theta: the output-error fit ran tau to {math.exp(p[1]):.3g} s, outside any motor this "
            f"record can describe (is the angle sampled with u, does the motor have an integrator?)"
        )
    K, tau = p[0], math.exp(p[1])
    # (K, log tau) -> (K, tau)
    T = np.diag([1.0, tau])
    cov = T @ cov_p[:2, :2] @ T
    th0 = p[2] if fit_theta0 else theta[0]
    fc = fc_std = None
    if friction:
        fc, fc_std = float(p[-1]), float(math.sqrt(max(cov_p[-1, -1], 0.0)))
    return K, tau, cov, th0, sol.nfev, math.sqrt(s2), fc, fc_std, sim(p)


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


def _issue(msgs):
    import warnings

    for m in msgs:
        warnings.warn(m, IdentificationWarning, stacklevel=3)


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


# ----------------------------------------------------------------------------------------------
# the full motor model: Coulomb friction by the velocity, input offset, dead zone, delay
# ----------------------------------------------------------------------------------------------
class IdentificationWarning(UserWarning):
    """A fit finished, but its result is physically implausible or poorly determined.

    The message names the likely cause (reversed encoder or motor leads, friction larger than the
    input, a parameter at its bound, an input that does not excite the model).
    """


def _drive(u, offset=0.0, dead_zone=0.0, delay=0):
    """The voltage the motor sees: ``dz(u(k - delay) + offset)``; before the record, u(0) is held."""
    if delay:
        u = (
            np.concatenate([np.full(delay, u[0]), u[:-delay]])
            if delay < u.size
            else np.full(u.size, u[0])
        )
    x = u + offset
    if dead_zone:
        x = np.sign(x) * np.maximum(np.abs(x) - dead_zone, 0.0)
    return x


@_jit
def _coast_step(th, om, fc, K, tau, rc, dt, emc):
    """One period with the drive open: omega' = -rc omega - (K fc / tau) sign(omega), sticking at 0.

    ``rc`` = 1/tau_coast >= 0; ``emc`` = 1 - exp(-rc dt). rc > 0 is plant.advance_em with no voltage,
    time constant 1/rc and gain K/(tau rc) (the same Coulomb torque); rc = 0 is the pure Coulomb
    run-down at the constant deceleration K fc / tau, solved exactly."""
    if rc > 0.0:
        return advance_em(th, om, 0.0, fc, K / (tau * rc), 1.0 / rc, dt, emc)
    dec = K * fc / tau
    if om == 0.0:
        return th, 0.0
    s = 1.0 if om > 0.0 else -1.0
    if dec > 0.0 and abs(om) <= dec * dt:
        t_star = abs(om) / dec
        return th + 0.5 * om * t_star, 0.0
    return th + om * dt - 0.5 * s * dec * dt * dt, om - s * dec * dt


@_jit
def _sim_kernel(v, coast, fc, K, tau, rc, Ts, starts, th0, om0, out):
    """Exact ZOH simulation with Coulomb friction (plant.advance_em), restarted at each segment start.

    Where ``coast[k]`` the drive is open (:func:`_coast_step`, ``rc`` = 1/tau_coast): no voltage and
    no back-EMF braking, so the motor runs down on its mechanical friction alone."""
    em = -math.expm1(-Ts / tau)
    emc = -math.expm1(-Ts * rc)
    j = 0
    nseg = starts.size
    th = 0.0
    om = 0.0
    for k in range(v.size):
        if j < nseg and k == starts[j]:
            th = th0[j]
            om = om0[j]
            j += 1
        out[k] = th
        if coast[k]:
            th, om = _coast_step(th, om, fc, K, tau, rc, Ts, emc)
        else:
            th, om = advance_em(th, om, v[k], fc, K, tau, Ts, em)
    return out


def _simulate_segments(v, fc, K, tau, Ts, starts, th0, om0, coast=None, coast_rate=0.0):
    out = np.empty(v.size)
    if coast is None:
        coast, coast_rate = np.zeros(v.size, dtype=np.bool_), 0.0
    return _sim_kernel(
        np.ascontiguousarray(v, dtype=float),
        np.ascontiguousarray(coast, dtype=np.bool_),
        float(fc),
        float(K),
        float(tau),
        float(coast_rate),
        float(Ts),
        np.asarray(starts, dtype=np.int64),
        np.asarray(th0, dtype=float),
        np.asarray(om0, dtype=float),
        out,
    )


def _coast_mask(u, delay=0):
    """Samples at which the drive is open: the (delayed) *commanded* voltage is exactly 0."""
    return _drive(u, 0.0, 0.0, delay) == 0.0


def simulate_motor(
    K,
    tau,
    Ts,
    u,
    theta0=0.0,
    omega0=0.0,
    friction=0.0,
    offset=0.0,
    dead_zone=0.0,
    delay=0,
    tau_coast=None,
) -> np.ndarray:
    """Exact ZOH simulation of Stojčić eq. 1 with friction by velocity, offset, dead zone and delay.

    The motor obeys

        tau omega' = K (v(t) - friction sign(omega)) - omega,     theta' = omega,
        v(t) = dz(u(k - delay) + offset) on [k Ts, (k+1) Ts),  dz(x) = sign(x) max(|x| - dead_zone, 0),

    and sticks at omega = 0 while |v| <= friction (static = kinetic Coulomb friction). Between
    samples it is solved exactly (``jerklab.plant.advance_em``: the linear ZOH solution, the zero
    crossing of omega found analytically). With every extra term 0 it equals
    :func:`simulate_dc_motor`. Before the record, ``u[0]`` is held (for the delay).

    With ``tau_coast`` the drive is *open* wherever the commanded u(k - delay) is exactly 0 (a
    switch or a bridge that floats its outputs, not one that shorts the motor): no current flows,
    so there is neither a voltage nor the back-EMF braking that makes up most of 1/tau. For a motor
    with inertia J, viscous friction b, Coulomb torque T_c, torque constant k_t, back-EMF constant
    k_e and armature resistance R (inductance neglected, Stojčić eq. 1),

        driven:  J omega' = k_t (u - k_e omega)/R - b omega - T_c sign(omega)
                 -> tau = J/(b + k_t k_e/R), K = (k_t/R) tau/J, friction = T_c R/k_t;
        open:    J omega' = -b omega - T_c sign(omega)
                 -> omega' = -omega/tau_coast - (K friction/tau) sign(omega),  tau_coast = J/b,

    so the coasting motor runs down with the mechanical time constant ``tau_coast`` (>= tau) and
    the *same* Coulomb deceleration K friction / tau, and sticks when it reaches 0 (the DC motor
    model of Stojčić eq. 1 with the electrical circuit opened; see e.g. Franklin, Powell &
    Emami-Naeini, *Feedback Control of Dynamic Systems*, §2.3).

    Parameters
    ----------
    K, tau, Ts : float
        Gain rad/(V s), time constant s, sample period s.
    u : array_like
        Commanded voltage samples (V).
    theta0, omega0 : float
        Initial angle (rad) and velocity (rad/s).
    friction, offset, dead_zone : float
        Coulomb friction voltage (V, >= 0), input offset (V), dead zone (V, >= 0).
    delay : int
        Input delay in whole samples (>= 0).
    tau_coast : float, optional
        Mechanical time constant (s, > 0) while the drive is open (u = 0); ``math.inf``: no
        viscous drag, the open motor runs down at the constant Coulomb deceleration
        K friction / tau alone. None (default): the drive always holds u (u = 0 is a short
        across the motor, Stojčić eq. 1).

    Returns
    -------
    ndarray
        theta(k), k = 0 .. len(u) - 1 (rad), sampled before u[k] acts.
    """
    K = as_real("K", K)
    tau = as_positive("tau", tau)
    Ts = as_positive("Ts", Ts)
    u = _signal("u", u, min_len=1)
    theta0 = as_real("theta0", theta0)
    omega0 = as_real("omega0", omega0)
    friction = as_nonnegative("friction", friction)
    offset = as_real("offset", offset)
    dead_zone = as_nonnegative("dead_zone", dead_zone)
    delay = as_int("delay", delay, minimum=0)
    v = _drive(u, offset, dead_zone, delay)
    if tau_coast is None:
        return _simulate_segments(v, friction, K, tau, Ts, [0], [theta0], [omega0])
    if not (isinstance(tau_coast, (int, float, np.floating, np.integer)) and tau_coast == math.inf):
        tau_coast = as_positive("tau_coast", tau_coast)
    return _simulate_segments(
        v, friction, K, tau, Ts, [0], [theta0], [omega0], _coast_mask(u, delay), 1.0 / tau_coast
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


def _lowpass(Ts, cutoff):
    nyq = 0.5 / Ts
    wn = min(cutoff / nyq, 0.95)
    return signal.butter(4, wn)


def _filtered_states(theta, Ts, cutoff):
    """Zero-phase low-passed angle, velocity and acceleration at the midpoints (k + 1/2) Ts.

    The derivatives of the filtered angle (central differences about the midpoint); the input held
    on [k Ts, (k+1) Ts) belongs to the same instant. Returns (theta_mid, omega, alpha) for
    k = 1 .. N - 3 (N - 3 values).
    """
    b, a = _lowpass(Ts, cutoff)
    thf = signal.filtfilt(
        b, a, theta, padtype="odd", padlen=min(3 * max(len(a), len(b)), theta.size - 1)
    )
    w = (thf[2:-1] - thf[1:-2]) / Ts
    al = (thf[3:] - thf[2:-1] - thf[1:-2] + thf[:-3]) / (2.0 * Ts * Ts)
    return 0.5 * (thf[2:-1] + thf[1:-2]), w, al


def _idim_rows(u, theta, Ts, cutoff, delay, opts, theta_inst=None, offset_guess=0.0):
    """Rows of the inverse-dynamics regression u = (tau/K) alpha + (1/K) omega + f_c sgn(omega)
    - offset + dead_zone sgn(u + offset), all sides low-passed by the same filter (parallel
    filtering, Gautier & Janot). ``theta_inst`` (a simulated angle) builds the instruments."""
    b, a = _lowpass(Ts, cutoff)
    pad = min(3 * max(len(a), len(b)), u.size - 1)
    ud = _drive(u, 0.0, 0.0, delay)
    uf = signal.filtfilt(b, a, ud, padtype="odd", padlen=pad)[1:-2]

    def columns(th):
        _, w, al = _filtered_states(th, Ts, cutoff)
        cols = [al, w]
        if opts["friction"]:
            cols.append(
                signal.filtfilt(
                    b,
                    a,
                    np.sign(np.concatenate([[w[0]], w, [w[-1]] * 2])),
                    padtype="odd",
                    padlen=pad,
                )[1:-2]
            )
        if opts["offset"]:
            cols.append(-np.ones(w.size))
        if opts["dead_zone"]:
            cols.append(
                signal.filtfilt(b, a, np.sign(ud + offset_guess), padtype="odd", padlen=pad)[1:-2]
            )
        return np.column_stack(cols), w

    X, w = columns(theta)
    keep = np.ones(w.size, bool)
    if opts["friction"]:
        # friction is set-valued at rest: drop the samples where the motor (nearly) stands still
        wmax = float(np.max(np.abs(w)))
        keep = np.abs(w) > 0.05 * wmax
    Z = None
    if theta_inst is not None:
        Z, _ = columns(theta_inst)
        Z = Z[keep]
    return X[keep], uf[keep], Z


def _params_from_idim(p, opts):
    """(tau/K, 1/K, [f_c], [offset], [dead_zone]) -> dict of physical parameters."""
    out = {
        "K": 1.0 / p[1] if p[1] != 0 else math.inf,
        "tau": p[0] / p[1] if p[1] != 0 else math.nan,
    }
    i = 2
    for name in ("friction", "offset", "dead_zone"):
        if opts[name]:
            out[name] = float(p[i])
            i += 1
        else:
            out[name] = 0.0
    return out


def _idim(exps, Ts, delay, opts, cutoff, iv_iterations=0, segment_n=None):
    """Inverse-dynamics identification (IDIM-LS, optionally IDIM-IV) over merged experiments."""
    Xs, ys = [], []
    for u, th in exps:
        X, y, _ = _idim_rows(u, th, Ts, cutoff, delay, opts)
        Xs.append(X)
        ys.append(y)
    X = np.vstack(Xs)
    y = np.concatenate(ys)
    if X.shape[0] < X.shape[1] + 2:
        raise ValueError("theta: too few moving samples for the inverse-dynamics regression")
    p, *_ = np.linalg.lstsq(X, y, rcond=None)
    Z = None
    for _ in range(iv_iterations):
        par = _params_from_idim(p, opts)
        if not (par["K"] > 0 and par["tau"] > 0):
            break
        Xs, Zs, ys = [], [], []
        for u, th in exps:
            th_sim = _shooting_sim(u, th, Ts, par, delay, cutoff, segment_n)
            X_, y_, Z_ = _idim_rows(u, th, Ts, cutoff, delay, opts, th_sim, -par["offset"])
            Xs.append(X_)
            Zs.append(Z_)
            ys.append(y_)
        X, Z, y = np.vstack(Xs), np.vstack(Zs), np.concatenate(ys)
        try:
            p = np.linalg.solve(Z.T @ X, Z.T @ y)
        except np.linalg.LinAlgError:
            break
    r = y - X @ p
    dof = max(y.size - p.size, 1)
    s2 = float(r @ r) / dof
    if Z is None:
        cov = s2 * np.linalg.pinv(X.T @ X)
    else:
        A = np.linalg.pinv(Z.T @ X)
        cov = s2 * A @ (Z.T @ Z) @ A.T
    return p, cov, float(r @ r), X


def _shooting_sim(u, th, Ts, par, delay, cutoff, segment_n):
    """Simulate the model re-started every ``segment_n`` samples from the filtered measured state
    (the auxiliary model whose output builds the instruments of IDIM-IV)."""
    n = u.size
    L = n if segment_n is None else max(int(segment_n), 20)
    starts = np.arange(0, n, L)
    thm, w, _ = _filtered_states(th, Ts, cutoff)
    idx = np.clip(starts, 0, w.size - 1)
    v = _drive(u, par["offset"], max(par["dead_zone"], 0.0), delay)
    return _simulate_segments(
        v, max(par["friction"], 0.0), par["K"], par["tau"], Ts, starts, th[starts], w[idx]
    )


def _segment_starts(n, segment_n):
    if segment_n is None or segment_n >= n:
        return np.array([0])
    starts = np.arange(0, n, segment_n)
    if n - starts[-1] < max(segment_n // 2, 10) and starts.size > 1:
        starts = starts[:-1]  # fold a short tail into the previous segment
    return starts


def _fit_oe_ms(exps, Ts, delay, opts, init, segment_n, cutoff, max_nfev=200):
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
    # initial segment states from the filtered record
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
        xtol=1e-8,
        ftol=1e-9,
        gtol=1e-9,
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


def _diagnose(par, cov, names, u_abs_max, at_bound=(), Jg=None):
    """Physically impossible or poorly determined results -> list of messages (Ljung §16)."""
    msgs = []
    if not par["K"] > 0:
        msgs.append(
            f"K = {par['K']:.4g} rad/(V s) <= 0: the angle falls when the voltage rises. The "
            f"encoder channels (A/B) or the motor leads are probably reversed, or u was logged "
            f"with the wrong sign: flip the sign of theta (or of u) and fit again"
        )
    if not par["tau"] > 0:
        msgs.append(
            f"tau = {par['tau']:.4g} s <= 0: no motor has a negative time constant; check "
            f"that theta is the angle (not the velocity) and that the encoder and motor "
            f"leads are not reversed"
        )
    if "friction" in names and par["friction"] > u_abs_max:
        msgs.append(
            f"friction f_c = {par['friction']:.4g} V is larger than the largest input "
            f"|u| = {u_abs_max:.4g} V: the motor could never have moved. The model does not "
            f"fit these data (u not in volts? a reversed encoder? an offset or dead zone "
            f"not modelled?)"
        )
    for nm in at_bound:
        if nm == "dead_zone_max":
            msgs.append(
                f"dead_zone = {par['dead_zone']:.4g} V ran to its upper bound, the largest input "
                f"|u| = {u_abs_max:.4g} V: a dead zone that swallows the whole input would stop the "
                f"motor for good, so K ({par['K']:.3g}) was blown up against it. The input cannot "
                f"separate K from the dead zone (too few levels, or an offset or friction absorbs "
                f"it): fit without dead_zone, or record several input levels"
            )
            continue
        what = {
            "tau": "tau ran to the edge of its search range",
            "tau_coast": f"the coasting rate 1/tau_coast (tau_coast = {par.get('tau_coast', 0.0):.3g} s) "
            f"is at (or within two standard errors of) its bound 0: the open motor "
            f"shows no viscous drag. With friction, fit coast='coulomb' instead",
            "friction": f"friction f_c = {par['friction']:.3g} V is at (or within two standard "
            f"errors of) its bound 0",
            "dead_zone": f"dead_zone = {par['dead_zone']:.3g} V is at (or within two standard "
            f"errors of) its bound 0",
        }[nm]
        msgs.append(
            f"{what}: the data do not support this term (or another term absorbed it); "
            f"fit without it or record an input that shows it"
        )
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    # (all zero is a noise-free record; some zero while others are not is a rank-deficient fit)
    bad = [
        names[i]
        for i in range(len(names))
        if names[i] not in at_bound
        and (not np.isfinite(std[i]) or (std[i] == 0 and np.nanmax(std) > 0))
    ]
    if bad:
        msgs.append(
            f"singular fit: the standard error of {', '.join(bad)} is zero or undefined, so "
            f"the data do not determine {'it' if len(bad) == 1 else 'them'} (a parameter at a "
            f"bound, or several parameters trading off without limit); the values are not "
            f"estimates: fit fewer parameters or record a richer input"
        )
    elif np.all(np.isfinite(cov)):
        C = cov / np.outer(std, std)
        w, V = np.linalg.eigh(C)
        if w[0] < 1e-4:
            v = V[:, 0]
            idx = np.argsort(-np.abs(v))[:2]
            pair = " and ".join(names[i] for i in idx)
            msgs.append(
                f"ill-conditioned fit (parameter correlation matrix eigenvalue {w[0]:.1e}): "
                f"the input is not exciting enough to separate {pair}. A single step level "
                f"cannot separate K from friction or offset, a motor turning one way cannot "
                f"separate friction from offset: use two or more levels, both directions "
                f"(a PRBS about zero), or fewer parameters"
            )
    for i, nm in enumerate(names):
        val = par[nm]
        if (
            nm in ("K", "tau", "tau_coast")
            and nm not in at_bound
            and np.isfinite(std[i])
            and val != 0
            and std[i] > 0.5 * abs(val)
        ):
            msgs.append(
                f"{nm} is poorly determined ({val:.4g} ± {std[i]:.2g}): the input is not "
                f"exciting enough (too short, too small, or too slow for tau)"
            )
    return msgs


def arx_asymptotic_bias(u, K, tau, Ts, noise_std):
    """Predicted large-sample (K, tau) of the ARX velocity fit under white output noise.

    With theta_m = theta + e, e white with variance s^2, the differenced angle carries noise
    n(k) = (e(k) - e(k-1))/Ts with r_n(0) = 2 s^2/Ts^2, r_n(1) = -s^2/Ts^2, and the equation error
    n(k) - a n(k-1) is correlated with the regressor v(k-1). Least squares converges to

        p_hat = p + (Phi0^T Phi0 + N Sigma)^-1 N c,   c = [a r_n(0) - r_n(1), 0, 0],
        Sigma = diag(r_n(0), 0, 0),

    (Ljung §8.3, the "errors-in-variables" bias of equation-error methods). Here Phi0 is the
    noise-free regression built from the exact ZOH simulation of ``u``. Encoder quantization with
    step q acts, for a moving motor, like uniform noise of standard deviation q/sqrt(12).

    Returns
    -------
    (K_arx, tau_arx) : tuple of float
        What ``fit_dc_motor(..., method="arx")`` converges to on long records of this input.
    """
    K = as_real("K", K)
    tau = as_positive("tau", tau)
    Ts = as_positive("Ts", Ts)
    s = as_nonnegative("noise_std", noise_std)
    u = _signal("u", u)
    a, b1, b2 = dc_motor_zoh_coefficients(K, tau, Ts)
    theta = simulate_dc_motor(K, tau, Ts, u)
    v = np.diff(theta) / Ts
    # regression v(k) = -A1 v(k-1) + B0 u(k) + B1 u(k-1) in the indexing used by _fit_arx
    Phi, target, _ = _arx_regressors(v, u[:-1], 1, 2, 0)
    N = target.size
    r0 = 2.0 * s**2 / Ts**2
    r1 = -(s**2) / Ts**2
    Sigma = np.zeros((3, 3))
    Sigma[0, 0] = r0  # noise variance in the regressor -v(k-1)
    # E[phi_1 * eq_err] with phi_1 = -(v0(k-1) + n(k-1)), eq_err = n(k) - a n(k-1)
    c = np.array([-(r1 - a * r0), 0.0, 0.0])
    p_true = np.array([-a, b1 / Ts, b2 / Ts])
    p_lim = p_true + np.linalg.solve(Phi.T @ Phi + N * Sigma, N * c)
    a_l = -p_lim[0]
    if not 0.0 < a_l < 1.0:
        return float("nan"), float("nan")
    return float((p_lim[1] + p_lim[2]) / (1.0 - a_l)), float(-Ts / math.log(a_l))


@dataclass
class P2Fit:
    """The paper's literal structure, MATLAB ``pem(data, 'P2')``: K / ((T1 s + 1)(T2 s + 1)).

    ``K`` is in rad/V (a DC gain: the model has no integrator), ``T1 >= T2`` in s. ``at_bound`` is
    True when 1/T1 ran to (nearly) 0 — T1 over 100 times the record — i.e. the data asked for an integrator (then T1 = K = inf and
    ``model`` is the integrator model g/(s(T2 s + 1)) the bound reached).
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
    _, tau0, _, _ = _initial_guess(u, theta, Ts, True, False)
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


# ----------------------------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------------------------
@dataclass
class ResidualAnalysis:
    """Whiteness and independence tests of residuals (MATLAB's ``resid``).

    ``autocorr[k]`` is the normalised autocorrelation of e at lag k = 0..max_lag;
    ``crosscorr[i]`` the normalised cross-correlation of u(t - lag) and e(t) at
    ``cross_lags[i]`` = -max_lag..max_lag. ``auto_bound`` and ``cross_bound`` are the
    two-sided per-lag confidence bounds at ``confidence`` under the hypothesis "e white and
    independent of u" (what ``resid`` draws). With 25 lags a few excursions are expected by chance,
    so the verdicts are joint tests over all lags: ``white`` is the Ljung-Box portmanteau test
    (Q = N(N+2) sum r_k^2/(N-k) ~ chi2(max_lag)), ``independent`` the test
    zeta = N r^T R_u^+ r ~ chi2(rank R_u) (Ljung §16.6), each passed when its p-value exceeds
    1 - ``confidence``. Checked by simulation on white residuals: the whiteness test holds its level,
    the cross-correlation test is slightly conservative (about 3 % rejections at a nominal 5 %).
    Without an input (``residual_analysis(e)``) there is no independence test: ``crosscorr`` and
    ``independent`` are None and ``cross_bound`` is NaN.
    """

    lags: np.ndarray
    autocorr: np.ndarray
    cross_lags: np.ndarray
    crosscorr: np.ndarray | None
    auto_bound: float
    cross_bound: float
    confidence: float
    white: bool
    independent: bool | None
    auto_pvalue: float = float("nan")
    cross_pvalue: float | None = None

    def plot(self, axes=None, title: str | None = None):
        """The two panels of MATLAB's ``resid`` (see :func:`plot_residuals`)."""
        return plot_residuals(self, axes, title)


def _xcorr_norm(x, y, lags):
    """Normalised sample cross-correlation r(l) = sum x(t-l) y(t) / (N sx sy)."""
    x = x - x.mean()
    y = y - y.mean()
    N = x.size
    den = N * x.std() * y.std()
    out = np.empty(len(lags))
    for i, l in enumerate(lags):
        if l >= 0:
            out[i] = np.dot(x[: N - l], y[l:])
        else:
            out[i] = np.dot(x[-l:], y[: N + l])
    return out / den


def residual_analysis(
    residuals, u=None, max_lag: int = 25, confidence: float = 0.99
) -> ResidualAnalysis:
    """Residual autocorrelation and input-residual cross-correlation with confidence bounds.

    Under "e is white", each normalised autocorrelation at lag >= 1 is approximately N(0, 1/N); the
    cross-correlation of e with a coloured input u has variance sum_k r_e(k) r_u(k) / N (Ljung
    §16.6), which this uses over the computed lags. Defaults as MATLAB's ``resid`` (25 lags, 99 %).

    Parameters
    ----------
    residuals : array_like
        Model residuals e(t) = y(t) - yhat(t).
    u : array_like, optional
        The input, same length, for the independence test.
    max_lag : int
        Largest lag (>= 1, < len(residuals)/2).
    confidence : float
        Level of the two-sided bounds, in (0, 1).
    """
    e = _signal("residuals", residuals)
    max_lag = as_int("max_lag", max_lag, minimum=1)
    if 2 * max_lag >= e.size:
        raise ValueError(f"max_lag must be < len(residuals)/2 = {e.size / 2:g}, got {max_lag}")
    confidence = as_real("confidence", confidence)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if np.std(e) == 0.0:
        raise ValueError("residuals are constant: nothing to test")
    N = e.size
    z = stats.norm.ppf(0.5 + confidence / 2)
    lags = np.arange(max_lag + 1)
    ac = _xcorr_norm(e, e, lags)
    auto_bound = z / math.sqrt(N)
    k = lags[1:]
    Q = N * (N + 2) * float(np.sum(ac[1:] ** 2 / (N - k)))
    p_auto = float(stats.chi2.sf(Q, max_lag))
    white = p_auto > 1.0 - confidence
    cl = np.arange(-max_lag, max_lag + 1)
    if u is None:
        return ResidualAnalysis(
            lags, ac, cl, None, auto_bound, float("nan"), confidence, white, None, p_auto, None
        )
    u = _signal("u", u)
    if u.size != N:
        raise ValueError(f"u and residuals must have the same length, got {u.size} and {N}")
    if np.std(u) == 0.0:
        raise ValueError("u is constant: the independence test is undefined")
    cc = _xcorr_norm(u, e, cl)
    ru = _xcorr_norm(u, u, cl)
    re = _xcorr_norm(e, e, cl)
    P = max(float(np.sum(ru * re)), 1.0 / N)
    cross_bound = z * math.sqrt(P / N)
    # joint test: under independence r ~ N(0, R_u / N), R_u the Toeplitz matrix of u's correlation
    ru_pos = _xcorr_norm(u, u, np.arange(cl.size))
    Ru = linalg.toeplitz(ru_pos)
    w, V = np.linalg.eigh(Ru)
    keep = w > 1e-8 * w.max()
    proj = V[:, keep].T @ cc
    zeta = N * float(np.sum(proj**2 / w[keep]))
    p_cross = float(stats.chi2.sf(zeta, int(np.count_nonzero(keep))))
    independent = p_cross > 1.0 - confidence
    return ResidualAnalysis(
        lags, ac, cl, cc, auto_bound, cross_bound, confidence, white, independent, p_auto, p_cross
    )


@dataclass
class Validation:
    """A fitted model run on a (validation) record: simulated angle, fit %, residual tests."""

    y_sim: np.ndarray
    fit_percent: float
    residuals: np.ndarray
    analysis: ResidualAnalysis
    theta0: float
    omega0: float = 0.0


def validate(
    fit: MotorFit,
    u,
    theta,
    Ts=None,
    max_lag: int = 25,
    confidence: float = 0.99,
    initial: str = "estimate",
) -> Validation:
    """Simulate ``fit`` on a record (ideally not the one it was estimated on) and test the residuals.

    Parameters
    ----------
    fit : MotorFit
    u, theta : array_like
        The validation record (V, rad).
    Ts : float, optional
        Checked against ``fit.Ts`` if given.
    max_lag, confidence
        Passed to :func:`residual_analysis`; on a record shorter than 2 ``max_lag`` + 1 samples the
        tests use (n - 1) // 2 lags.
    initial : {"estimate", "rest"}
        "estimate" (default, as ``compare`` with ``InitialCondition='e'``): the initial angle and
        velocity are fitted by linear least squares — the response is linear in both, the free
        response to omega0 being omega0 tau (1 - a^k) — so a record may start while the motor turns
        (e.g. the second half of a PRBS). "rest": omega0 = 0, only the angle is fitted.
    """
    if not isinstance(fit, MotorFit):
        raise ValueError(f"fit must be a MotorFit, got {type(fit).__name__}")
    if initial not in ("estimate", "rest"):
        raise ValueError(f"initial must be 'estimate' or 'rest', got {initial!r}")
    u, theta = _pair(u, theta, "u", "theta")
    if Ts is not None and abs(as_positive("Ts", Ts) - fit.Ts) > 1e-9 * fit.Ts:
        raise ValueError(f"Ts = {Ts:g} s differs from the fit's Ts = {fit.Ts:g} s")
    if fit.is_linear:
        g = fit.simulate(u)
        if initial == "rest":
            M = np.ones((u.size, 1))
        else:
            k = np.arange(u.size)
            M = np.column_stack([np.ones(u.size), -fit.tau * np.expm1(-k * fit.Ts / fit.tau)])
        coef, *_ = np.linalg.lstsq(M, theta - g, rcond=None)
        th0 = float(coef[0])
        w0 = float(coef[1]) if initial == "estimate" else 0.0
        y_sim = g + M @ coef
    else:
        th0, w0 = _initial_state(fit, u, theta, initial)
        y_sim = fit.simulate(u, th0, w0)
    r = theta - y_sim
    max_lag = min(as_int("max_lag", max_lag, minimum=1), (u.size - 1) // 2)
    an = residual_analysis(r, u if np.std(u) > 0 else None, max_lag, confidence)
    return Validation(y_sim, fit_percent(theta, y_sim), r, an, th0, w0)


# plot_compare and plot_residuals live in jerklab.plots; the names here stay as aliases
# (imported at the top of this module).


# ----------------------------------------------------------------------------------------------
# several experiments; compare and resid with MATLAB's semantics
# ----------------------------------------------------------------------------------------------
class MergedData:
    """Several experiments of the same motor, for one estimate (MATLAB's ``merge``).

    Each record keeps its own time axis and initial state; :meth:`fit` passes the lists of
    inputs and outputs to :func:`fit_dc_motor`. Keep validation records out of it.
    """

    def __init__(self, experiments):
        exps = list(experiments)
        if not exps:
            raise ValueError("experiments must hold at least one IdentData")
        for i, d in enumerate(exps):
            if not isinstance(d, IdentData):
                raise ValueError(f"experiments[{i}] must be an IdentData, got {type(d).__name__}")
        Ts = exps[0].Ts
        for i, d in enumerate(exps):
            if abs(d.Ts - Ts) > 1e-9 * Ts:
                raise ValueError(
                    f"experiments[{i}] has Ts = {d.Ts:g} s, experiments[0] has {Ts:g} s: "
                    f"resample one of them first"
                )
        self.experiments = exps
        self.Ts = Ts

    def __len__(self):
        return len(self.experiments)

    def __getitem__(self, i) -> IdentData:
        return self.experiments[i]

    @property
    def u(self):
        return [d.u for d in self.experiments]

    @property
    def y(self):
        return [d.y for d in self.experiments]

    def fit(self, method: str = "pem", **kwargs) -> "MotorFit":
        """One fit over every experiment: ``fit_dc_motor([u...], [y...], Ts, method, **kwargs)``."""
        return fit_dc_motor(self.u, self.y, self.Ts, method=method, **kwargs)

    def __repr__(self):
        return f"MergedData({len(self)} experiments, Ts={self.Ts:g} s, n={[d.n for d in self.experiments]})"


def merge(*data) -> MergedData:
    """Merge several :class:`IdentData` records into one estimation set (MATLAB's ``merge``)."""
    if len(data) == 1 and isinstance(data[0], (list, tuple)):
        data = tuple(data[0])
    return MergedData(data)


def _initial_state(fit, u, y, initial):
    """Initial (theta0, omega0) of ``fit`` that best matches ``y`` (least squares, as compare's 'e')."""
    if initial == "rest":
        g = fit.simulate(u)
        return float(np.mean(y - g)), 0.0
    if fit.is_linear:
        g = fit.simulate(u)
        k = np.arange(u.size)
        M = np.column_stack([np.ones(u.size), -fit.tau * np.expm1(-k * fit.Ts / fit.tau)])
        coef, *_ = np.linalg.lstsq(M, y - g, rcond=None)
        return float(coef[0]), float(coef[1])
    w0 = (y[min(2, y.size - 1)] - y[0]) / (min(2, y.size - 1) * fit.Ts)

    def r(x):
        return fit.simulate(u, x[0], x[1]) - y

    best = None
    for start in (w0, 0.0):
        sol = optimize.least_squares(
            r, [y[0], start], method="lm", x_scale=[1.0, max(abs(w0), 1.0)]
        )
        if best is None or sol.cost < best.cost:
            best = sol
    return float(best.x[0]), float(best.x[1])


def _initial_speed(fit, u, y):
    """Initial (theta0, omega0) for a speed comparison: omega0 minimises the speed error over the
    record (the angle offset does not enter the speed; a fit of the *angle* would pick omega0 to
    cancel the drift of the integrated error, far from the measured initial speed)."""
    w = np.diff(y) / fit.Ts

    def r(x):
        return np.diff(fit.simulate(u, 0.0, x[0])) / fit.Ts - w

    best = None
    for start in (w[0], 0.0):
        sol = optimize.least_squares(r, [start], method="lm", x_scale=[max(abs(w[0]), 1.0)])
        if best is None or sol.cost < best.cost:
            best = sol
    om0 = float(best.x[0])
    return float(np.mean(y - fit.simulate(u, 0.0, om0))), om0


@_jit
def _predict_kernel(v, coast, y, fc, K, tau, rc, Ts, k, out):
    """k-step-ahead prediction: at t - k restart from the state the two measured angles
    y(t-k-1), y(t-k) imply (the angle from y, the velocity from the exact one-sample relation),
    then simulate k samples. Where ``coast`` the drive is open (``_coast_step``, rc = 1/tau_coast)."""
    em = -math.expm1(-Ts / tau)
    emc = -math.expm1(-Ts * rc)
    for t in range(k + 1, y.size):
        s = t - k
        d = y[s] - y[s - 1]
        if coast[s - 1]:
            # open drive: d = om_prev T - (K fc/tau) sgn T^2/2 (rc = 0), or the linear relation
            sg = 1.0 if d > 0.0 else (-1.0 if d < 0.0 else 0.0)
            dec = K * fc / tau
            if rc > 0.0:
                tc = 1.0 / rc
                w_inf = -dec * tc * sg
                om_prev = w_inf + (d - w_inf * Ts) / (tc * emc)
                om = w_inf + (om_prev - w_inf) * (1.0 - emc)
            else:
                om_prev = d / Ts + 0.5 * sg * dec * Ts
                om = om_prev - sg * dec * Ts
            if sg == 0.0 or om * sg < 0.0:
                om = 0.0
        else:
            vv = v[s - 1]
            if fc > 0.0:
                if d > 0.0:
                    vv = vv - fc
                elif d < 0.0:
                    vv = vv + fc
                else:
                    vv = 0.0
            c = tau * em
            om_prev = (d - K * (Ts - c) * vv) / c
            om = (1.0 - em) * om_prev + K * em * vv
            if fc > 0.0 and d == 0.0:
                om = 0.0
        th = y[s]
        for j in range(s, t):
            if coast[j]:
                th, om = _coast_step(th, om, fc, K, tau, rc, Ts, emc)
            else:
                th, om = advance_em(th, om, v[j], fc, K, tau, Ts, em)
        out[t] = th
    return out


@dataclass
class CompareResult:
    """Output of :func:`compare`: the model's output on a record and its fit %.

    ``horizon`` is None for simulation (MATLAB ``compare(data, sys)``, an infinite horizon) or
    k for the k-step-ahead prediction (``compare(data, sys, k)``).
    """

    t: np.ndarray
    y: np.ndarray
    y_hat: np.ndarray
    fit_percent: float
    horizon: int | None
    theta0: float
    omega0: float
    label: str = ""

    def plot(self, ax=None, unit: str = "rad"):
        """Measured and model output, fit % in the legend: :func:`jerklab.plots.plot_compare_result`."""
        return plot_compare_result(self, ax, unit)


def compare(
    data, fit, horizon=None, initial: str = "estimate", label: str = "", output: str = "angle"
) -> CompareResult:
    """Model output against a record and the fit %, as MATLAB's ``compare``.

    fit % = 100 (1 - ||y - yhat|| / ||y - mean(y)||) over every sample of the record.

    Parameters
    ----------
    data : IdentData or (u, y) pair
        The record (ideally not the one ``fit`` was estimated on).
    fit : MotorFit
    horizon : None or int
        None (or ``math.inf``): simulation from the estimated initial state, MATLAB's default
        infinite horizon. k >= 1: the k-step-ahead prediction yhat(t | t - k): at t - k the model is
        restarted from the state the measured angles y(t-k-1), y(t-k) imply and run k samples;
        for the linear model this is exactly the k-step predictor of the ARX form of Stojčić eq. 1,
        (1 - q^-1)(1 - a q^-1) theta = (b1 q^-1 + b2 q^-2) u + e (Ljung §3.2), i.e. MATLAB's
        ``compare(data, arx_model, k)``. The first k + 1 samples take the simulation.
    initial : {"estimate", "rest"}
        Initial state of the simulation: fitted (MATLAB's ``InitialCondition='e'``) or at rest.
    label : str
        Name of the model in the plot's legend.
    output : {"angle", "speed"}
        "angle" (default): the record's y. "speed": the mean speed over each sample period,
        diff(y)/Ts, against the model's (the angle simulation differenced; n - 1 samples), so
        a record of an integrating plant is judged on what it shows, not on its integral (whose
        fit % is always high). Only for simulation (``horizon`` None).

    Returns
    -------
    CompareResult
    """
    if not isinstance(fit, MotorFit):
        raise ValueError(f"fit must be a MotorFit, got {type(fit).__name__}")
    if initial not in ("estimate", "rest"):
        raise ValueError(f"initial must be 'estimate' or 'rest', got {initial!r}")
    if not (fit.tau > 0 and math.isfinite(fit.K)):
        raise ValueError(
            f"fit has tau = {fit.tau:.4g} s, K = {fit.K:.4g}: no motor to simulate "
            f"(see fit.warnings: {'; '.join(fit.warnings) or 'none'})"
        )
    if isinstance(data, IdentData):
        u, y, Ts = data.u, data.y, data.Ts
    elif isinstance(data, (tuple, list)) and len(data) == 2:
        u, y = _pair(data[0], data[1], "u", "y", min_len=3)
        Ts = fit.Ts
    else:
        raise ValueError(f"data must be an IdentData or a (u, y) pair, got {type(data).__name__}")
    if abs(Ts - fit.Ts) > 1e-9 * fit.Ts:
        raise ValueError(f"data.Ts = {Ts:g} s differs from the fit's Ts = {fit.Ts:g} s")
    if horizon is not None and horizon != math.inf:
        horizon = as_int("horizon", horizon, minimum=1)
    else:
        horizon = None
    if output not in ("angle", "speed"):
        raise ValueError(f"output must be 'angle' or 'speed', got {output!r}")
    if output == "speed" and horizon is not None:
        raise ValueError("horizon: output='speed' compares the simulation only (horizon=None)")
    if output == "speed" and initial == "estimate":
        th0, om0 = _initial_speed(fit, u, y)
    else:
        th0, om0 = _initial_state(fit, u, y, initial)
    y_hat = fit.simulate(u, th0, om0)
    if horizon is not None and y.size > horizon + 1:
        v = _drive(u, fit.offset, fit.dead_zone, fit.delay)
        cm = _coast_mask(u, fit.delay) if fit.tau_coast else np.zeros(u.size, dtype=np.bool_)
        rc = 1.0 / fit.tau_coast if fit.tau_coast else 0.0
        pred = _predict_kernel(
            np.ascontiguousarray(v),
            cm,
            np.ascontiguousarray(y),
            float(fit.friction),
            float(fit.K),
            float(fit.tau),
            rc,
            float(fit.Ts),
            int(horizon),
            y_hat.copy(),
        )
        y_hat = pred
    t = np.arange(y.size) * Ts
    if output == "speed":
        y, y_hat, t = np.diff(y) / Ts, np.diff(y_hat) / Ts, t[:-1] + 0.5 * Ts
    return CompareResult(t, y, y_hat, fit_percent(y, y_hat), horizon, th0, om0, label)


def resid(
    data,
    fit,
    max_lag: int = 25,
    confidence: float = 0.99,
    initial: str = "estimate",
    output: str = "angle",
) -> "ResidualAnalysis":
    """Residual tests of a model on a record, as MATLAB's ``resid``.

    The residuals are the output errors y - yhat of the simulation (the prediction errors of an
    output-error model, which is what the fits of this module are), from the estimated initial
    state. Returns :func:`residual_analysis` of them with the input: autocorrelation over lags
    0..``max_lag``, cross-correlation with u over -``max_lag``..``max_lag``, ``confidence`` bands
    (99 % by default), the whiteness and independence tests. ``result.plot()`` draws the two panels.
    ``output="speed"``: the residuals of the mean speed over each period (see :func:`compare`).
    """
    c = compare(data, fit, None, initial, output=output)
    u = data.u if isinstance(data, IdentData) else _signal("u", data[0])
    u = u[: c.y.size]
    e = c.y - c.y_hat
    max_lag = min(as_int("max_lag", max_lag, minimum=1), (e.size - 1) // 2)
    return residual_analysis(e, u if np.std(u) > 0 else None, max_lag, confidence)


# ----------------------------------------------------------------------------------------------
# real records
# ----------------------------------------------------------------------------------------------
#: PWM amplitude (of 255) of the micromouse records whose command the log lets us rebuild
#: (README_original_data.md: "max speed"); the trapezoid records (2, 4, 6) ramp the PWM at a rate
#: the log does not hold, so they cannot be used as input/output records.
MICROMOUSE_RECORDS = {
    "encoders1": (100, "rectangle, 1 s"),
    "encoders3": (100, "step"),
    "encoders5": (255, "step"),
}


def _default_real_root():
    from jerklab.resources import share_path  # the clone's data/, or the installed wheel's copy

    return share_path("data") / "real"


def _read_table(path):
    try:
        with open(path) as fh:
            header = [h.strip() for h in fh.readline().split(",")]
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ValueError(f"path: cannot read {path}: {exc}") from None
    return header, table


def micromouse_battery_voltage(root=None) -> float:
    """Median battery voltage (V) logged with the PWM sweep ``wheelSpeedCalibration3.csv``
    (LiPo 2S, the battery of the speed records; see data/real/micromouse/README.md)."""
    root = pathlib.Path(root) if root is not None else _default_real_root() / "micromouse"
    header, table = _read_table(root / "wheelSpeedCalibration3.csv")
    return float(np.median(table[:, header.index("batteryVoltage")])) / 1000.0


def load_micromouse(
    name: str,
    root=None,
    battery_voltage=None,
    counts_per_motor_rev: int = 12,
    gear_ratio: float = 29.861,
    sign: int = -1,
    pre_samples: int = 20,
) -> IdentData:
    """A measured record of the Pololu 30:1 micro gearmotor of the micromouse "Algernon" as SI data.

    The files (``data/real/micromouse``, CERN-OHL-P v2, from github.com/opatiny/micromouse) log the
    cumulative encoder count of the left motor and its mode every 5 ms; the PWM command is a known
    constant while the mode is non-zero (see ``MICROMOUSE_RECORDS``). Conversions:

    * angle (rad, gearbox output) = ``sign`` * count * 2 pi / (counts_per_motor_rev * gear_ratio):
      the magnetic encoder gives 12 counts per motor revolution when both edges of both channels
      are counted (X4), so 12 * 29.861 counts per output revolution. The left encoder counts down
      for a positive command as wired, hence ``sign=-1``; ``sign=+1`` gives the raw direction (and
      a negative K, which the fit diagnoses as a reversed encoder).
    * voltage (V) = PWM / 255 * ``battery_voltage``, the nominal mean voltage of the DRV8833's
      PWM. Default: :func:`micromouse_battery_voltage`. It is nominal: at light load the bridge's
      coasting PWM makes the speed a nonlinear function of the duty (the PWM sweep shows a dead
      band below about 50/255), so K is a gain per *nominal* volt.

    Parameters
    ----------
    name : {"encoders1", "encoders3", "encoders5"}
        Record: a 1 s rectangle at PWM 100, a step at PWM 100, a step at PWM 255.
    root : path, optional
        Folder holding the CSV files (default: the repository's data/real/micromouse).
    battery_voltage : float, optional
        Supply voltage (V).
    counts_per_motor_rev : int
        Encoder counts per motor revolution (12: Pololu magnetic encoder, X4).
    gear_ratio : float
        Gearbox ratio (29.861 for the "30:1" gearbox).
    sign : {+1, -1}
        Direction of the encoder count relative to a positive command.
    pre_samples : int
        Samples kept before the command starts (the motor at rest); the rest of the idle lead-in
        is dropped.

    Returns
    -------
    IdentData
        u in V, y in rad (output shaft), Ts = 0.005 s; metadata names the source and conversions.
    """
    if name not in MICROMOUSE_RECORDS:
        raise ValueError(
            f"name must be one of {sorted(MICROMOUSE_RECORDS)} (the trapezoid records "
            f"encoders2/4/6 do not log their PWM ramp), got {name!r}"
        )
    root = pathlib.Path(root) if root is not None else _default_real_root() / "micromouse"
    if battery_voltage is None:
        battery_voltage = micromouse_battery_voltage(root)
    battery_voltage = as_positive("battery_voltage", battery_voltage)
    counts_per_motor_rev = as_int("counts_per_motor_rev", counts_per_motor_rev, minimum=1)
    gear_ratio = as_positive("gear_ratio", gear_ratio)
    sign = as_int("sign", sign)
    if sign not in (-1, 1):
        raise ValueError(f"sign must be +1 or -1, got {sign}")
    pre_samples = as_int("pre_samples", pre_samples, minimum=0)
    header, table = _read_table(root / f"{name}.csv")
    for col in ("time", "leftEncoder", "leftMode"):
        if col not in header:
            raise ValueError(f"path: {name}.csv has no '{col}' column (columns {header})")
    t_ms = table[:, header.index("time")]
    counts = table[:, header.index("leftEncoder")]
    mode = table[:, header.index("leftMode")]
    dt = np.diff(t_ms)
    if dt.size == 0 or np.any(dt != dt[0]):
        raise ValueError(f"path: {name}.csv is not uniformly sampled")
    Ts = float(dt[0]) / 1000.0
    on = np.flatnonzero(mode != 0)
    if on.size == 0:
        raise ValueError(f"path: {name}.csv never switches the motor on")
    start = max(int(on[0]) - pre_samples, 0)
    pwm = MICROMOUSE_RECORDS[name][0]
    u = np.where(mode != 0, pwm / 255.0 * battery_voltage, 0.0)[start:]
    rad_per_count = 2.0 * math.pi / (counts_per_motor_rev * gear_ratio)
    y = sign * (counts[start:] - counts[start]) * rad_per_count
    meta = {
        "source": "github.com/opatiny/micromouse matlab/data (CERN-OHL-P v2)",
        "record": name,
        "profile": MICROMOUSE_RECORDS[name][1],
        "pwm": pwm,
        "battery_voltage_V": battery_voltage,
        "counts_per_motor_rev": counts_per_motor_rev,
        "gear_ratio": gear_ratio,
        "sign": sign,
        "rad_per_count": rad_per_count,
        "t0_ms": float(t_ms[start]),
    }
    return IdentData(u, y, Ts, "V", "rad", meta)


#: the DC motor/generator record (data/real/dc-generator): the file, the raw samples per stored row,
#: and the raw samples per PRBS clock period (the hold of the input)
DC_GENERATOR_FILE = "dc_generator_every25.csv"
DC_GENERATOR_ROW_STEP = 25
DC_GENERATOR_RAW_PER_CLOCK = 500


def load_dc_generator(root=None, decimate: int = 1, clock_period: float = 1.0) -> IdentData:
    """The measured DC motor driving a DC generator of SysIdentPy as identification data.

    Lacerda Junior, W. R., et al., "Identificação de um motor/gerador CC por meio de modelos
    polinomiais autorregressivos e redes neurais artificiais", SBAI 2017; the files ``x_cc.csv``
    (motor voltage, 0 or 5 V, a PRBS held for 500 raw samples) and ``y_cc.csv`` (a speed-like
    output, units not stated) of github.com/wilsonrljr/sysidentpy-data (MIT). The repository
    ships every 25th raw sample (``data/real/dc-generator``, README there).

    * u (V): ``x_cc``, as recorded.
    * speed: ``y_cc`` minus its median at rest (the samples before the first switch-on,
      -143.64), in the record's own unit (not stated by the authors).
    * y: the speed integrated by the trapezoidal rule from 0, so the angle-based estimators of
      this module apply: ``fit_dc_motor`` fits K (speed unit per V) and tau on it, and
      ``compare(data, fit, output="speed")`` compares the speed, ``diff(y)/Ts`` (the mean of
      two neighbouring speed samples) against the model's mean speed over each sample period.
    * time: the sample period of the record is not stated anywhere. The input is held for 500
      raw samples (its PRBS clock), so time is counted in clock periods: ``Ts`` =
      25 ``decimate`` / 500 ``clock_period``. With the default ``clock_period=1.0`` every time
      (Ts, tau) is in clock periods, *written as seconds*; pass the true clock period (s) if
      you know it.

    Parameters
    ----------
    root : path, optional
        Folder holding the CSV (default: the repository's data/real/dc-generator).
    decimate : int
        Keep every ``decimate``-th stored row (1: 20 samples per clock period, 20000 samples).
        The output is smooth, so plain decimation (no filter) loses nothing above the clock rate.
    clock_period : float
        The PRBS clock period (s); 1.0 by convention (time in clock periods).

    Returns
    -------
    IdentData
        u in V, y the integrated speed (``output_unit`` "y_cc*s"), Ts = 0.05 ``decimate``
        ``clock_period``; metadata names the source, the rest level and the conventions.
    """
    decimate = as_int("decimate", decimate, minimum=1)
    clock_period = as_positive("clock_period", clock_period)
    root = pathlib.Path(root) if root is not None else _default_real_root() / "dc-generator"
    header, table = _read_table(root / DC_GENERATOR_FILE)
    for col in ("sample", "x_cc", "y_cc"):
        if col not in header:
            raise ValueError(f"path: {DC_GENERATOR_FILE} has no '{col}' column (columns {header})")
    raw = table[:, header.index("sample")]
    if np.any(np.diff(raw) != DC_GENERATOR_ROW_STEP):
        raise ValueError(
            f"path: {DC_GENERATOR_FILE} is not every {DC_GENERATOR_ROW_STEP}th raw sample"
        )
    rows = slice(None, None, decimate)
    u = table[rows, header.index("x_cc")]
    y_cc = table[rows, header.index("y_cc")]
    if u.size < MIN_SAMPLES:
        raise ValueError(f"decimate: {decimate} leaves {u.size} samples, fewer than {MIN_SAMPLES}")
    on = np.flatnonzero(u != 0)
    if on.size == 0 or on[0] < 1:
        raise ValueError(
            f"path: {DC_GENERATOR_FILE} has no idle lead-in before the first switch-on"
        )
    rest = float(np.median(y_cc[: on[0]]))
    speed = y_cc - rest
    Ts = DC_GENERATOR_ROW_STEP * decimate / DC_GENERATOR_RAW_PER_CLOCK * clock_period
    y = np.concatenate([[0.0], np.cumsum(0.5 * Ts * (speed[1:] + speed[:-1]))])
    meta = {
        "source": "github.com/wilsonrljr/sysidentpy-data datasets/generator (MIT), commit "
        "72715362eadcf860fdbd77d88b5d7e92b6143a83",
        "paper": "Lacerda Junior et al., SBAI 2017, motor/gerador CC",
        "raw_samples_per_row": DC_GENERATOR_ROW_STEP * decimate,
        "raw_samples_per_clock": DC_GENERATOR_RAW_PER_CLOCK,
        "clock_period_s": clock_period,
        "time_unit": "PRBS clock period" if clock_period == 1.0 else "s",
        "speed_rest_level": rest,
        "output": "trapezoidal integral of (y_cc - rest)",
        "speed_unit": "y_cc (not stated by the authors)",
    }
    return IdentData(u, y, Ts, "V", "y_cc*s", meta)


# ----------------------------------------------------------------------------------------------
# input design
# ----------------------------------------------------------------------------------------------
def sample_time_range(tau):
    """Stojčić §4A rule Ts = tau/(2...5): returns (tau/5, tau/2), in s. tau = 25 ms -> 5...12.5 ms."""
    tau = as_positive("tau", tau)
    return tau / 5.0, tau / 2.0


#: the longest input record :func:`step_input` and :func:`prbs` build (samples): 10⁷ samples are
#: 14 h at Ts = 5 ms and 80 MB of float64; a longer request is refused up front
MAX_INPUT_SAMPLES = 10_000_000


def _input_samples(duration, Ts):
    """``round(duration / Ts)``, refused (naming duration and Ts) outside 2 … MAX_INPUT_SAMPLES."""
    ratio = duration / Ts
    if not ratio < MAX_INPUT_SAMPLES + 0.5:
        raise ValueError(
            f"duration / Ts = {duration:g} s / {Ts:g} s is more than MAX_INPUT_SAMPLES = "
            f"{MAX_INPUT_SAMPLES} samples; choose a shorter duration or a longer Ts"
        )
    n = int(round(ratio))
    if n < 2:
        raise ValueError(
            f"duration must be at least 2 samples of Ts ({2 * Ts:g} s), got duration={duration:g} s "
            f"with Ts={Ts:g} s"
        )
    return n


def step_input(duration, Ts, amplitude, t_step=0.05, offset=0.0) -> np.ndarray:
    """A voltage step: ``offset`` until ``t_step``, then ``offset + amplitude`` (V per sample).

    Starting at rest before the step keeps the ARX regression well posed and shows the start of the
    transient. ``round(duration / Ts)`` samples.
    """
    duration = as_positive("duration", duration)
    Ts = as_positive("Ts", Ts)
    amplitude = as_real("amplitude", amplitude)
    t_step = as_nonnegative("t_step", t_step)
    offset = as_real("offset", offset)
    n = _input_samples(duration, Ts)
    if t_step >= duration:
        raise ValueError(f"t_step must be < duration ({duration:g} s), got {t_step:g} s")
    u = np.full(n, offset)
    u[np.arange(n) * Ts >= t_step - 1e-12 * Ts] += amplitude
    return u


def prbs(duration, Ts, amplitude, offset=0.0, clock_period=None, nbits=None, seed=0) -> np.ndarray:
    """Pseudo-random binary sequence ``offset ± amplitude`` (V per sample) from a maximum-length LFSR.

    Parameters
    ----------
    duration, Ts : float
        Record length and sample period (s).
    amplitude : float
        Half the distance between the two levels (V, > 0).
    offset : float
        Centre level (V). An offset larger than the friction voltage keeps the motor turning one
        way, which keeps Coulomb friction a constant (and small) bias.
    clock_period : float, optional
        How long each bit is held (s), a whole number of samples; default Ts. A rule of thumb is
        clock_period ≈ tau/2 … tau, so the sequence's power sits under the motor's bandwidth.
    nbits : int, optional
        LFSR length (period 2^nbits - 1 bits); by default the smallest that covers the record.
    seed : int
        Selects the (non-zero) initial LFSR state, so different seeds shift the sequence.
    """
    duration = as_positive("duration", duration)
    Ts = as_positive("Ts", Ts)
    amplitude = as_positive("amplitude", amplitude)
    offset = as_real("offset", offset)
    seed = as_int("seed", seed, minimum=0)
    n = _input_samples(duration, Ts)
    if clock_period is None:
        hold = 1
    else:
        clock_period = as_positive("clock_period", clock_period)
        if clock_period > duration:
            raise ValueError(
                f"clock_period must be <= duration ({duration:g} s), got {clock_period:g} s"
            )
        hold = int(round(clock_period / Ts))
        if hold < 1 or abs(hold * Ts - clock_period) > 1e-6 * clock_period:
            raise ValueError(
                f"clock_period must be a whole multiple of Ts = {Ts:g} s, got {clock_period:g} s"
            )
    nb = -(-n // hold)
    if nbits is None:
        nbits = max(3, int(math.ceil(math.log2(nb + 1))))
        nbits = min(nbits, 32)
    else:
        nbits = as_int("nbits", nbits, minimum=2)
        if nbits > 32:
            raise ValueError(f"nbits must be <= 32, got {nbits}")
    rng = np.random.default_rng(seed)
    state = rng.integers(0, 2, size=nbits)
    if not state.any():
        state[0] = 1
    bits = signal.max_len_seq(nbits, state=state, length=nb)[0]
    levels = offset + amplitude * (2.0 * bits.astype(float) - 1.0)
    return np.repeat(levels, hold)[:n]
