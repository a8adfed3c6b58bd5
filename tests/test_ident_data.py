"""The shipped identification data set: reproducible from its script, and fits as its README says."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest

from jerklab import ident

DATA = pathlib.Path(__file__).resolve().parent.parent / "data" / "ident"


def _script():
    spec = importlib.util.spec_from_file_location("make_ident_dataset", DATA / "make_dataset.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_dataset_regenerates_identically():
    """If this fails after a change to jerklab.plant or jerklab.ident's input helpers, remake the
    records (`.venv/bin/python data/ident/make_dataset.py --only plant`) and update the README table."""
    mod = _script()
    assert mod.main(["--check", "--only", "plant"]) == 0


def test_rig_record_regenerates_identically():
    """If this fails after a change to jerklab.rig or jerklab.plant, remake the record:
    `.venv/bin/python data/ident/make_dataset.py --only rig`."""
    mod = _script()
    assert mod.main(["--check", "--only", "rig"]) == 0


def test_dataset_files_and_metadata():
    for name in ("step_6V", "prbs_6V_3V", "rig_step_6V"):
        d = ident.IdentData.load(DATA / name)
        assert d.Ts == 0.005 and d.input_unit == "V" and d.output_unit == "rad"
        assert d.metadata["plant"]["encoder_ppr"] == 448
        # encoder + noise: the angle sits within q + 5 sigma of a multiple of q
        q = 2 * np.pi / 448
        frac = d.y / q - np.round(d.y / q)
        assert np.max(np.abs(frac)) * q < 6 * 0.001


@pytest.mark.parametrize(
    "name,method,friction,K,tau,tol",
    [
        ("step_6V", "pem", False, 32.4 * (1 - 0.2 / 6.0058651), 0.025, 0.005),  # effective gain
        ("prbs_6V_3V", "pem", True, 32.4, 0.025, 0.005),
        ("step_6V", "arx", False, 31.35, 0.02455, 0.005),  # README table
        ("prbs_6V_3V", "arx", False, 31.39, 0.02417, 0.005),
        ("rig_step_6V", "pem", False, 32.4 * (1 - 0.2 / 6.0058651), 0.025, 0.003),
        ("rig_step_6V", "arx", False, 31.32, 0.02459, 0.005),
    ],
)
def test_dataset_fits_as_documented(name, method, friction, K, tau, tol):
    f = ident.IdentData.load(DATA / name).fit(method, friction=friction)
    assert f.K == pytest.approx(K, rel=tol)
    assert f.tau == pytest.approx(tau, rel=tol)
    if friction:
        assert f.friction == pytest.approx(0.2, abs=0.02)
