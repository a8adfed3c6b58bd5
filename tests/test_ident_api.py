"""The public names of jerklab.ident before it became a package keep working.

The list is today's ``__all__`` of the former ``jerklab/ident.py``, its public constants, and the
attributes of its results that notebooks, lab worksheets, benchmarks and tests use (found with
``grep -rn "ident\\."`` over the repository); each must be importable from ``jerklab.ident`` and
behave as the one object it was (not, say, a stale copy in a submodule).
"""

from __future__ import annotations

import importlib
import inspect

import numpy as np
import pytest

from jerklab import ident

#: ``jerklab.ident.__all__`` of the single module, in its order
FORMER_ALL = [
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

#: its public constants (docs/INTERFACES.md names FIT_TS_RANGE and MAX_INPUT_SAMPLES)
FORMER_CONSTANTS = {
    "MIN_SAMPLES": 10,
    "FIT_TS_RANGE": (1e-9, 1e3),
    "MAX_INPUT_SAMPLES": 10_000_000,
    "DC_GENERATOR_FILE": "dc_generator_every25.csv",
    "DC_GENERATOR_ROW_STEP": 25,
    "DC_GENERATOR_RAW_PER_CLOCK": 500,
}

#: attributes of the results that callers read
RESULT_ATTRIBUTES = {
    "IdentData": [
        "from_recording", "load", "save", "fit", "plot", "n", "t", "u", "y", "Ts",
        "duration", "input_unit", "output_unit", "metadata", "FORMAT",
    ],
    "MotorFit": [
        "simulate", "is_linear", "std", "confidence_interval", "to_motor", "summary",
    ],
    "ARXResult": ["std", "tf", "predict"],
    "CompareResult": ["plot", "t"],
    "ResidualAnalysis": ["plot"],
    "MergedData": ["u", "y", "fit"],
}  # fmt: skip

#: the constructor keywords and fields of the result dataclasses that callers use
RESULT_FIELDS = {
    "MotorFit": [
        "K", "tau", "K_std", "tau_std", "fit_percent", "model", "method", "Ts", "theta0", "cov",
        "y_sim", "residuals", "noise_std", "arx_result", "nfev", "friction", "friction_std",
        "offset", "offset_std", "dead_zone", "dead_zone_std", "delay", "estimated",
        "covariance", "warnings", "n_segments", "n_experiments", "omega0", "tau_coast",
        "tau_coast_std",
    ],
    "CompareResult": ["y", "y_hat", "fit_percent", "horizon", "theta0", "omega0", "label"],
    "ResidualAnalysis": [
        "lags", "autocorr", "cross_lags", "crosscorr", "auto_bound", "cross_bound",
        "confidence", "white", "independent", "auto_pvalue", "cross_pvalue",
    ],
    "Validation": ["y_sim", "fit_percent", "residuals", "analysis", "theta0", "omega0"],
    "ARXResult": [
        "A", "B", "na", "nb", "nk", "params", "cov", "noise_variance", "residuals", "n_used",
    ],
    "P2Fit": [
        "K", "T1", "T2", "fit_percent", "model", "Ts", "theta0", "y_sim", "at_bound",
        "integrator_gain",
    ],
}  # fmt: skip

#: the keyword arguments of the functions, as callers pass them
SIGNATURES = {
    "fit_dc_motor": ["u", "theta", "Ts", "method"],
    "compare": ["data", "fit", "horizon", "initial", "label", "output"],
    "resid": ["data", "fit", "max_lag", "confidence", "initial", "output"],
    "validate": ["fit", "u", "theta", "Ts", "max_lag", "confidence", "initial"],
    "simulate_motor": [
        "K", "tau", "Ts", "u", "theta0", "omega0", "friction", "offset", "dead_zone", "delay",
        "tau_coast",
    ],
    "simulate_dc_motor": ["K", "tau", "Ts", "u", "theta0", "omega0"],
    "load_micromouse": [
        "name", "root", "battery_voltage", "counts_per_motor_rev", "gear_ratio", "sign",
        "pre_samples",
    ],
    "load_dc_generator": ["root", "decimate", "clock_period"],
    "prbs": ["duration", "Ts", "amplitude", "offset", "clock_period", "nbits", "seed"],
    "step_input": ["duration", "Ts", "amplitude", "t_step", "offset"],
    "arx": ["y", "u", "na", "nb", "nk"],
    "residual_analysis": ["residuals", "u", "max_lag", "confidence"],
    "plot_compare": ["data", "fits", "ax", "labels", "horizon"],
    "plot_residuals": ["analysis", "axes", "title"],
}  # fmt: skip

#: the options fit_dc_motor took as keywords
FIT_OPTIONS = [
    "fit_theta0", "friction", "offset", "delay", "dead_zone", "segment", "max_delay", "cutoff",
    "coast",
]  # fmt: skip


@pytest.mark.parametrize("name", FORMER_ALL)
def test_former_public_name_is_importable(name):
    module = importlib.import_module("jerklab.ident")
    obj = getattr(module, name)
    assert name in ident.__all__
    # the object lives in one submodule of the package and is re-exported as itself
    home = importlib.import_module(obj.__module__)
    assert obj.__module__.startswith("jerklab.ident.") and getattr(home, name) is obj


@pytest.mark.parametrize("name,value", sorted(FORMER_CONSTANTS.items()))
def test_former_constant_keeps_its_value(name, value):
    assert getattr(ident, name) == value


def test_micromouse_records_are_listed():
    assert sorted(ident.MICROMOUSE_RECORDS) == ["encoders1", "encoders3", "encoders5"]


def _instance(cls):
    """A small instance where the attributes are per instance, else the class."""
    d = ident.IdentData(np.arange(5.0), np.ones(5), 0.01)
    return {"IdentData": d, "MergedData": ident.merge(d, d)}.get(cls, getattr(ident, cls))


@pytest.mark.parametrize("cls,attrs", sorted(RESULT_ATTRIBUTES.items()))
def test_result_attributes(cls, attrs):
    obj = _instance(cls)
    assert [a for a in attrs if not hasattr(obj, a)] == []


@pytest.mark.parametrize("cls,fields", sorted(RESULT_FIELDS.items()))
def test_result_fields(cls, fields):
    params = inspect.signature(getattr(ident, cls)).parameters
    assert [f for f in fields if f not in params] == []


@pytest.mark.parametrize("func,names", sorted(SIGNATURES.items()))
def test_keyword_arguments(func, names):
    params = inspect.signature(getattr(ident, func)).parameters
    assert [n for n in names if n not in params] == []


def test_fit_options_are_keywords_still():
    """fit_dc_motor's options became the fields of FitOptions; every one is still a keyword."""
    assert [f for f in FIT_OPTIONS if f not in ident.FitOptions.__dataclass_fields__] == []
    u = ident.step_input(0.5, 0.005, 6.0)
    th = ident.simulate_dc_motor(32.4, 0.025, 0.005, u)
    kw = dict(friction=False, offset=False, delay=0, dead_zone=False, max_delay=3, cutoff=20.0)
    f = ident.fit_dc_motor(u, th, 0.005, "pem", segment=0.5, coast=False, fit_theta0=True, **kw)
    assert f.K == pytest.approx(32.4, rel=1e-6)


def test_mode_identification_names():
    """identify_mode moved from jerklab.shaping into jerklab.ident; shaping's name keeps working
    and returns the identification plus the recommended shaper."""
    from jerklab import shaping

    assert issubclass(shaping.ModeFit, ident.ModeFit)
    assert callable(shaping.identify_mode) and callable(ident.identify_mode)
    assert (
        hasattr(shaping.ModeFit, "recommend") and "shaper" in shaping.ModeFit.__dataclass_fields__
    )
    assert {"identify_mode", "ModeFit", "chirp_input", "flexible_mode"} <= set(shaping.__all__)


def test_old_series_names_read_the_canonical_ones():
    d = ident.IdentData(np.arange(5.0), np.ones(5), 0.01)
    assert d.u is d.voltage and d.y is d.position
    np.testing.assert_array_equal(d.t, d.time)


def test_the_package_imports_at_the_top():
    """No function-local jerklab import inside jerklab/ident/ but the results' ``.plot()``, each
    handing itself to jerklab.plots; and no import of jerklab.plots anywhere else in it."""
    import ast
    from pathlib import Path

    late = []
    for path in sorted(Path(ident.__file__).parent.glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for func in ast.walk(tree):
            if not isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(func):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jerklab"):
                    late.append((path.stem, func.name, node.module))
                elif isinstance(node, ast.Import) and any(
                    a.name.startswith("jerklab") for a in node.names
                ):
                    late.append((path.stem, func.name, node.names[0].name))
    assert sorted(late) == [
        ("comparison", "plot", "jerklab.plots"),
        ("data", "plot", "jerklab.plots"),
        ("validation", "plot", "jerklab.plots"),
    ]


def test_no_name_of_the_package_hides_a_module():
    """``jerklab.ident.validate`` is the function of today; each module has a name of its own, so
    ``import jerklab.ident.<module> as m`` gives the module, not a function of the same name."""
    import pkgutil
    import types

    for info in pkgutil.iter_modules(ident.__path__):
        module = importlib.import_module(f"jerklab.ident.{info.name}")
        assert isinstance(getattr(ident, info.name), types.ModuleType), info.name
        assert getattr(ident, info.name) is module
