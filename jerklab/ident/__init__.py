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
* ``method="pem"``: the output-error (simulation-error) fit: K, tau (and the initial angle and
  velocity) minimise sum (theta_measured - theta_simulated)^2, where theta_simulated is the exact
  ZOH simulation of Stojčić eq. 1.
  With white measurement noise this is the maximum-likelihood estimate and is unbiased; its
  covariance is a sandwich about the Jacobian at the optimum that holds for coloured residuals
  (Newey-West, and the encoder's quantization simulated: :mod:`jerklab.ident.covariance`).

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
:func:`plot_residuals`), input design (:func:`step_input`, :func:`prbs`, :func:`sample_time_range`),
:func:`arx_asymptotic_bias`, and the flexible mode of motor and load (:func:`identify_mode`).
Everything is SI: volts in, radians out, seconds.

The modules, each one concept: ``data`` (IdentData, MergedData), ``model`` (the simulations),
``arx``, ``fit`` (fit_dc_motor, FitOptions) with ``motorfit`` (its result), ``oe`` (multiple
shooting) with ``covariance`` (its standard errors for coloured residuals), ``idim`` (inverse
dynamics) and ``diagnostics``, ``p2``, ``validate``, ``datasets``, ``design``, ``mode``. Results
draw themselves (``.plot()``) with ``jerklab.plots``, imported only then; this package imports
neither ``jerklab.plots`` nor matplotlib, and python-control lazily.
"""

from jerklab.ident._common import MIN_SAMPLES
from jerklab.ident.arx import ARXResult, arx, arx_asymptotic_bias
from jerklab.ident.data import IdentData, MergedData, merge
from jerklab.ident.datasets import (
    DC_GENERATOR_FILE,
    DC_GENERATOR_RAW_PER_CLOCK,
    DC_GENERATOR_ROW_STEP,
    MICROMOUSE_RECORDS,
    load_dc_generator,
    load_micromouse,
    micromouse_battery_voltage,
)
from jerklab.ident.design import MAX_INPUT_SAMPLES, prbs, sample_time_range, step_input
from jerklab.ident.diagnostics import IdentificationWarning
from jerklab.ident.fit import FIT_TS_RANGE, FitOptions, fit_dc_motor
from jerklab.ident.mode import ModeEstimate, coupled_mode, identify_mode
from jerklab.ident.model import dc_motor_zoh_coefficients, simulate_dc_motor, simulate_motor
from jerklab.ident.motorfit import MotorFit
from jerklab.ident.p2 import P2Fit, fit_p2
from jerklab.ident.validate import (
    CompareResult,
    CompareResults,
    ResidualAnalysis,
    Validation,
    compare,
    fit_percent,
    plot_compare,
    plot_residuals,
    resid,
    residual_analysis,
    validate,
)

__all__ = [
    "IdentData",
    "ARXResult",
    "arx",
    "MotorFit",
    "fit_dc_motor",
    "FitOptions",
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
    "CompareResults",
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
    "ModeEstimate",
    "identify_mode",
    "coupled_mode",
    "MIN_SAMPLES",
    "FIT_TS_RANGE",
    "MAX_INPUT_SAMPLES",
    "MICROMOUSE_RECORDS",
    "DC_GENERATOR_FILE",
    "DC_GENERATOR_ROW_STEP",
    "DC_GENERATOR_RAW_PER_CLOCK",
]
