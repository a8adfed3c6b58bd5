"""Identification records (jerklab.ident.data): the IdentData container (CSV + JSON round trip,
bad files, built from a rig Recording, the names of its series), and the shipped data set:
reproducible from its script, and fits as its README says."""

from __future__ import annotations

import importlib.util
import json
import pathlib
import types

import numpy as np
import pytest
from _ident import K0, TAU0, TS

from jerklab import ident
from jerklab.plant import DCMotor

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


def test_identdata_roundtrip(tmp_path):
    u = ident.prbs(0.5, TS, 3.0, offset=6.0, seed=1)
    y = ident.simulate_dc_motor(K0, TAU0, TS, u) + 1e-3 * np.random.default_rng(0).normal(
        size=u.size
    )
    d = ident.IdentData(u, y, TS, metadata={"seed": 1, "note": "ö"})
    csv, js = d.save(tmp_path / "run")
    assert csv.name == "run.csv" and js.name == "run.json"
    side = json.loads(js.read_text())
    assert side["Ts"] == TS and side["n_samples"] == u.size and side["input_unit"] == "V"
    for p in (tmp_path / "run", csv, js):
        e = ident.IdentData.load(p)
        np.testing.assert_array_equal(e.u, u)
        np.testing.assert_array_equal(e.y, y)
        assert e.Ts == TS and e.metadata == {"seed": 1, "note": "ö"}
    assert d[:40].n == 40 and d[40:].metadata["slice_start_sample"] == 40
    np.testing.assert_allclose(d.t[-1], (u.size - 1) * TS)
    assert d.fit("pem").fit_percent > 99


def test_identdata_bad(tmp_path):
    with pytest.raises(ValueError, match="same length"):
        ident.IdentData(np.ones(5), np.ones(6), TS)
    with pytest.raises(ValueError, match="Ts"):
        ident.IdentData(np.ones(5), np.ones(5), -1.0)
    with pytest.raises(ValueError, match="metadata"):
        ident.IdentData(np.ones(5), np.ones(5), TS, metadata={"x": object()})
    with pytest.raises(ValueError, match="sidecar"):
        ident.IdentData.load(tmp_path / "missing")
    d = ident.IdentData(np.arange(5.0), np.ones(5), TS)
    d.save(tmp_path / "x")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(ValueError, match="corrupt"):
        ident.IdentData.load(tmp_path / "x")
    d.save(tmp_path / "x")
    (tmp_path / "x.csv").write_text("time_s,u_V,y_rad\n0,1,2\n0.005,1,oops\n")
    with pytest.raises(ValueError, match="path"):
        ident.IdentData.load(tmp_path / "x")


def test_identdata_from_recording_object():
    t = np.arange(100) * TS
    u = ident.step_input(0.5, TS, 6.0)
    rec = types.SimpleNamespace(
        time=t + 1.0,
        position=ident.simulate_dc_motor(K0, TAU0, TS, u),
        control=u,
        metadata={"Ts": TS, "port": "virtual"},
    )
    d = ident.IdentData.from_recording(rec)
    assert d.Ts == TS and d.n == 100 and d.metadata["port"] == "virtual" and d.metadata["t0"] == 1.0
    jitter = types.SimpleNamespace(
        time=t + np.r_[np.zeros(50), np.full(50, 0.2 * TS)],
        position=rec.position,
        control=u,
        metadata={},
    )
    with pytest.raises(ValueError, match="rec.time"):
        ident.IdentData.from_recording(jitter)
    with pytest.raises(ValueError, match="position"):
        ident.IdentData.from_recording(types.SimpleNamespace(time=t, control=u))


def test_identdata_from_virtual_rig_recording(tmp_path):
    """A real Recording from the virtual rig: sampling convention matches, PEM recovers K, tau."""
    from jerklab.rig import Recording, connect

    rig = connect(motor=DCMotor(seed=4), progress=False, recordings=tmp_path)
    try:
        rec = rig.step(6.0, 0.5, Ts=TS, rest=0.05)
    finally:
        rig.close()
    for r in (rec, Recording.load(rec.csv_path)):
        d = ident.IdentData.from_recording(r)
        assert d.Ts == pytest.approx(TS) and d.n == 110
        assert np.all(d.u[:10] == 0.0) and d.y[10] == 0.0 and d.y[11] > 0.0
        f = d.fit("pem")
        assert f.K == pytest.approx(K0, rel=0.01) and f.tau == pytest.approx(TAU0, rel=0.01)


def test_identdata_speaks_the_vocabulary():
    """IdentData names its series time, voltage and position (jerklab._vocab); t, u and y read and
    write them (aliases), and the constructor takes either set of names."""
    from jerklab._vocab import ALIASES

    u = ident.step_input(0.2, TS, 6.0)
    y = ident.simulate_dc_motor(K0, TAU0, TS, u)
    d = ident.IdentData(voltage=u, position=y, Ts=TS)
    np.testing.assert_array_equal(d.voltage, u)
    np.testing.assert_array_equal(d.position, y)
    np.testing.assert_allclose(d.time, np.arange(u.size) * TS)
    assert d.u is d.voltage and d.y is d.position and np.array_equal(d.t, d.time)
    old = ident.IdentData(u=u, y=y, Ts=TS)
    np.testing.assert_array_equal(old.voltage, u)
    d.u = 2 * u  # the old name writes the canonical series
    np.testing.assert_array_equal(d.voltage, 2 * u)
    assert ALIASES["jerklab.ident.data.IdentData"] == {"t": "time", "u": "voltage", "y": "position"}
    m = ident.merge(old, old[:20])
    assert [x.size for x in m.voltage] == [u.size, 20] and m.u[1] is m.voltage[1]
    assert m.position[0] is old.position
    c = ident.compare(old, ident.fit_dc_motor(u, y, TS, method="arx"))
    assert c.t is c.time and c.unit == "rad" and c.output == "angle"
    with pytest.raises(TypeError, match="voltage or its older name u"):
        ident.IdentData(u, y, TS, u=u)
    with pytest.raises(TypeError, match="position"):
        ident.IdentData(voltage=u, Ts=TS)
    with pytest.raises(TypeError, match="Ts"):
        ident.IdentData(u, y)
    with pytest.raises(ValueError, match="u and y must have the same length"):
        ident.IdentData(u=u, y=y[:-1], Ts=TS)
    with pytest.raises(ValueError, match="voltage and position must have the same length"):
        ident.IdentData(u, y[:-1], TS)


def test_identdata_from_a_recording_with_either_vocabulary():
    """A Recording names its voltage series ``voltage`` (``control`` in records of earlier
    versions): both build the same IdentData."""
    u = ident.step_input(0.5, TS, 6.0)
    y = ident.simulate_dc_motor(K0, TAU0, TS, u)
    t = np.arange(u.size) * TS
    new = types.SimpleNamespace(time=t, position=y, voltage=u, metadata={"Ts": TS})
    old = types.SimpleNamespace(time=t, position=y, control=u, metadata={"Ts": TS})
    a, b = ident.IdentData.from_recording(new), ident.IdentData.from_recording(old)
    np.testing.assert_array_equal(a.voltage, b.voltage)
    np.testing.assert_array_equal(a.position, b.position)
    with pytest.raises(ValueError, match="rec.voltage"):
        ident.IdentData.from_recording(
            types.SimpleNamespace(time=t, position=y, voltage=u[:-1], metadata={})
        )
    with pytest.raises(ValueError, match="'control' field"):
        ident.IdentData.from_recording(types.SimpleNamespace(time=t, position=y))
