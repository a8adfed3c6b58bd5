"""Identification records (jerklab.ident.data): IdentData's CSV + JSON round trip, its checks, the
names of jerklab._vocab and the older ones, a record built from a rig Recording; and the
shipped data set (data/ident), reproducible from its script and fitting as its README says."""

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
        ("prbs_6V_3V", "pem", False, 31.31, 0.02479, 0.005),  # friction unmodelled
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


def test_identdata_speaks_the_vocabulary_and_keeps_the_old_names():
    from jerklab._vocab import ALIASES

    u = ident.step_input(0.5, TS, 6.0)
    y = ident.simulate_dc_motor(K0, TAU0, TS, u)
    d = ident.IdentData(voltage=u, position=y, Ts=TS)
    assert d.voltage is d.u and d.position is d.y
    np.testing.assert_array_equal(d.time, d.t)
    np.testing.assert_array_equal(d.time, np.arange(u.size) * TS)
    d.y = 2 * y  # the old names write the same array
    np.testing.assert_array_equal(d.position, 2 * y)
    assert ALIASES["jerklab.ident.data.IdentData"] == {"t": "time", "u": "voltage", "y": "position"}
    with pytest.raises(ValueError, match="voltage and position"):
        ident.IdentData(np.ones(5), np.ones(6), TS)
    m = ident.merge(d, d[10:])
    assert [a.size for a in m.u] == [a.size for a in m.voltage] == [100, 90]
    c = ident.compare(d, ident.fit_dc_motor(d.voltage, d.position, TS))
    assert c.t is c.time and c.unit == "rad" and c.output == "angle"
    # a record whose voltage is called voltage (the vocabulary) or control (the older name)
    for name in ("voltage", "control"):
        rec = types.SimpleNamespace(time=d.time, position=y, metadata={"Ts": TS}, **{name: u})
        e = ident.IdentData.from_recording(rec)
        np.testing.assert_array_equal(e.voltage, u)
