"""System identification of the DC motor: records, ARX, output error, inverse dynamics, validation.

Stojčić §4A (ASCII: Stojcic) identified the plant of Stojčić eq. 1,

    P(s) = K / (s (tau s + 1))        (volts -> rad)

from a voltage step recorded every 5 ms, with MATLAB's ``pem(data, 'P2')``, and got
K = 32.4 rad/(V s), tau = 0.025 s. A ``'P2'`` process model has two poles and *no* integrator;
the structure of Stojčić eq. 1 is a pole plus an integrator (MATLAB's ``'P1I'``), and that is
what this package fits; :func:`fit_p2` reproduces the paper's literal call to show where it goes
(notebooks/02_identification.ipynb). Everything is SI: volts in, radians out, seconds.

A module per concept, each re-exported here (the modules are named apart from the functions,
so ``jerklab.ident.validate`` is the function and ``jerklab.ident.validation`` its module):

======================================  =========================================================
:mod:`jerklab.ident.data`               :class:`IdentData` (CSV + JSON records, built from a rig
                                        ``Recording``), several experiments: :func:`merge`
:mod:`jerklab.ident.model`              the motor model and its exact ZOH simulation
                                        (:func:`simulate_dc_motor`, :func:`simulate_motor`:
                                        friction, offset, dead zone, delay, coasting),
                                        :class:`MotorFit`
:mod:`jerklab.ident.equation_error`     ARX: :func:`arx` of any orders, the velocity ARX fit,
                                        :func:`arx_asymptotic_bias`
:mod:`jerklab.ident.output_error`       output error (PEM) by multiple shooting, :func:`fit_p2`
:mod:`jerklab.ident.inverse_dynamics`   inverse dynamics (IDIM-LS, IDIM-IV)
:mod:`jerklab.ident.fit`                :func:`fit_dc_motor` in its steps, :class:`FitOptions`
:mod:`jerklab.ident.diagnostics`        implausible results named: :class:`IdentificationWarning`
:mod:`jerklab.ident.validation`         :func:`fit_percent`, :func:`residual_analysis`,
                                        :func:`validate`
:mod:`jerklab.ident.comparison`         :func:`compare` (simulation and k-step prediction) and
                                        :func:`resid`, with MATLAB's semantics
:mod:`jerklab.ident.datasets`           measured records: :func:`load_micromouse`,
                                        :func:`load_dc_generator`
:mod:`jerklab.ident.design`             input design: :func:`step_input`, :func:`prbs`,
                                        :func:`sample_time_range`
:mod:`jerklab.ident.mode`               the flexible mode from the encoder: :func:`identify_mode`
======================================  =========================================================

The estimators of :func:`fit_dc_motor`:

* ``method="pem"``: the output-error (simulation-error) fit: K, tau (and each segment's initial
  state) minimise sum (theta_measured - theta_simulated)^2, theta_simulated the exact ZOH
  simulation of Stojčić eq. 1. With white measurement noise this is the maximum-likelihood
  estimate and is unbiased; its covariance comes from the Jacobian at the optimum.
* ``method="arx"``: linear least squares on the differenced angle, exact on noise-free data but
  biased under output noise or encoder quantization (``arx_asymptotic_bias`` predicts by how
  much).
* ``method="idim"`` / ``"idim-iv"``: the inverse-dynamics least squares of motion control
  (Gautier & Janot), with instrumental variables for ``"idim-iv"``.

Real records (measured, closed loop, several experiments) need more than Stojčić eq. 1:
``fit_dc_motor`` also estimates Coulomb friction against the velocity (with sticking), an input
offset, a dead zone and a pure delay (:func:`simulate_motor`), by output error with multiple
shooting (each segment of the record starts from its own estimated state, so an integrating
plant cannot drift), started by the inverse dynamics. Implausible results raise an
:class:`IdentificationWarning` naming the likely cause.

The results plot themselves through ``jerklab.plots`` (``IdentData.plot``,
``CompareResult.plot``, ``ResidualAnalysis.plot``); this package never imports matplotlib, and
python-control only when a transfer function is asked for.
"""

from __future__ import annotations

from jerklab.ident._checks import MIN_SAMPLES
from jerklab.ident.comparison import CompareResult, compare, plot_compare, resid
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
from jerklab.ident.equation_error import ARXResult, arx, arx_asymptotic_bias, fit_velocity_arx
from jerklab.ident.fit import FIT_TS_RANGE, METHODS, FitOptions, fit_dc_motor
from jerklab.ident.mode import ModeFit, identify_mode, two_mass_mode
from jerklab.ident.model import (
    MotorFit,
    dc_motor_zoh_coefficients,
    simulate_dc_motor,
    simulate_motor,
)
from jerklab.ident.output_error import P2Fit, fit_p2
from jerklab.ident.validation import (
    ResidualAnalysis,
    Validation,
    fit_percent,
    plot_residuals,
    residual_analysis,
    validate,
)

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
    # added with the package
    "FitOptions",
    "fit_velocity_arx",
    "ModeFit",
    "identify_mode",
    "two_mass_mode",
    # constants
    "MIN_SAMPLES",
    "FIT_TS_RANGE",
    "METHODS",
    "MAX_INPUT_SAMPLES",
    "MICROMOUSE_RECORDS",
    "DC_GENERATOR_FILE",
    "DC_GENERATOR_ROW_STEP",
    "DC_GENERATOR_RAW_PER_CLOCK",
]
