"""The ``jerklab`` command (jerklab.cli) and the rig bring-up check (jerklab.rig.check)."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import pytest
from conftest import require_tool

from jerklab import cli
from jerklab.plant import DCMotor
from jerklab.rig import Device, Link, connect
from jerklab.rig.check import check_rig, format_report

ROOT = Path(__file__).resolve().parents[1]


def _pyproject_version():
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def test_version_is_the_pyproject_version(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"jerklab {_pyproject_version()}"


def test_unknown_command_names_the_choices(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["labb"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "lab" in err and "rig" in err and "app" in err


def test_lab_copies_every_notebook_and_data_file_then_keeps_edits(tmp_path, capsys):
    work = tmp_path / "my work"  # a space, as in "C:\Users\First Last"
    assert cli.main(["lab", str(work), "--copy-only"]) == 0
    shipped = sorted(
        p.relative_to(ROOT)
        for d in ("notebooks", "data")
        for p in (ROOT / d).rglob("*")
        if p.is_file() and ".ipynb_checkpoints" not in p.parts and "__pycache__" not in p.parts
    )
    copied = sorted(p.relative_to(work) for p in work.rglob("*") if p.is_file())
    assert copied == shipped and len(copied) > 10
    out = capsys.readouterr().out
    assert f"copied {len(shipped)} file(s); kept 0" in out
    assert "-m jupyterlab" in out and str(work) in out

    # the student edits one notebook and deletes another: the edit survives, the deleted one returns
    nb = work / "notebooks" / "01_derivation.ipynb"
    nb.write_text("my edits")
    gone = work / "notebooks" / "03_pole_placement.ipynb"
    gone.unlink()
    assert cli.main(["lab", str(work), "--copy-only"]) == 0
    out = capsys.readouterr().out
    assert nb.read_text() == "my edits"
    assert gone.read_bytes() == (ROOT / "notebooks" / "03_pole_placement.ipynb").read_bytes()
    assert f"copied 1 file(s); kept {len(shipped) - 1}" in out
    assert "kept notebooks" in out


def test_lab_default_folder_is_jerklab_home(tmp_path, monkeypatch):
    monkeypatch.setenv("JERKLAB_HOME", str(tmp_path / "home-work"))
    assert cli.main(["lab", "--copy-only"]) == 0
    assert (tmp_path / "home-work" / "notebooks" / "02_identification.ipynb").is_file()
    assert (tmp_path / "home-work" / "data" / "ident" / "step_6V.csv").is_file()


def test_lab_starts_jupyterlab_in_the_working_folder(tmp_path, monkeypatch):
    calls = []

    class FakePopen:
        def __init__(self, cmd):
            calls.append(cmd)

        def wait(self):
            return 0

    # the cli's own name only: patching subprocess.Popen itself would leak into any module that
    # binds it on first import (jupyter_client.launcher, imported by `import jupyterlab` here)
    monkeypatch.setattr(cli, "subprocess", types.SimpleNamespace(Popen=FakePopen))
    assert (
        cli.main(
            ["lab", str(tmp_path), "--no-browser", "--port", "8999", "--", "--ServerApp.ip=::1"]
        )
        == 0
    )
    cmd = calls[0]
    assert cmd[:4] == [sys.executable, "-m", "jupyterlab", str(tmp_path)]
    assert "--no-browser" in cmd and "--port=8999" in cmd and cmd[-1] == "--ServerApp.ip=::1"
    with pytest.raises(SystemExit):
        cli.main(["lab", str(tmp_path), "--prot", "8999"])  # a typo is an error, not a folder
    # developers: make lab opens the repository's notebooks/ as they are, nothing copied
    before = sorted((ROOT / "notebooks").rglob("*"))
    assert cli.main(["lab", "--no-copy", str(ROOT / "notebooks")]) == 0
    assert (
        calls[1][3] == str(ROOT / "notebooks") and sorted((ROOT / "notebooks").rglob("*")) == before
    )
    assert cli.main(["lab", "--no-copy", str(tmp_path / "nowhere")]) == 2


def test_rig_subcommands_dispatch(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["rig", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "check" in out and "serve" in out
    with pytest.raises(SystemExit):
        cli.main(["rig", "check", "--help"])
    assert "--cpr" in capsys.readouterr().out


# ----------------------------------------------------------------------------- rig check
def _virtual(motor=None, **faults):
    rig = connect(progress=False, device=motor)
    for k, v in faults.items():
        setattr(rig.link.device, k, v)
    return rig


def _check(rig, **kw):
    try:
        found = check_rig(rig, **kw)
    finally:
        rig.close()
    return {f.name: f for f in found}, format_report(found)


def test_check_passes_a_healthy_virtual_rig_with_friction(capsys):
    found, report = _check(_virtual(DCMotor(coulomb_friction=0.4)))
    assert all(f.ok for f in found.values()), report
    assert set(found) == {"firmware", "encoder", "direction", "cpr", "supply", "friction"}
    assert "dead band" in found["friction"].message  # the friction, seen and not held against K
    assert cli.main(["rig", "check", "virtual"]) == 0
    assert "all checks passed" in capsys.readouterr().out


def test_check_finds_a_reversed_encoder():
    found, report = _check(_virtual(encoder_sign=-1))
    assert not found["direction"].ok  # the virtual rig's hand turn tells the encoder from the leads
    assert "A/B swapped" in found["direction"].message
    assert "swap the encoder's A and B" in found["direction"].fix
    assert found["cpr"].ok and found["supply"].ok, report  # the rest is measured all the same


def test_check_finds_a_disconnected_encoder():
    found, report = _check(_virtual(encoder_sign=0))
    assert not found["encoder"].ok and "encoder disconnected" in found["encoder"].fix
    assert "D2" in found["encoder"].fix and "12 V supply" in found["encoder"].fix
    assert "direction" not in found and "1 check(s) failed" in report


def test_check_finds_a_weak_supply():
    found, _ = _check(_virtual(supply_fraction=0.6))
    assert found["encoder"].ok and found["direction"].ok
    assert not found["supply"].ok and "check the 12 V supply" in found["supply"].fix


@pytest.mark.parametrize("configured, actual", [(112, 448), (1792, 448)])
def test_check_finds_a_wrong_counts_per_revolution(configured, actual):
    rig = connect(
        progress=False, device=Device(counts_per_rev=configured)
    )  # the motor's encoder gives 448
    found, _ = _check(rig)
    assert not found["cpr"].ok
    assert (
        f"gave {actual} counts" in found["cpr"].message
        and f"counts_per_rev={actual}" in found["cpr"].fix
    )


def test_check_validates_its_arguments():
    rig = _virtual()
    try:
        with pytest.raises(ValueError, match="tolerance"):
            check_rig(rig, tolerance=1.0)
        with pytest.raises(ValueError, match="voltage"):
            check_rig(rig, voltage=7.0)
        with pytest.raises(ValueError, match="K"):
            check_rig(rig, K=-1)
    finally:
        rig.close()


@pytest.mark.simavr
def test_check_on_the_firmware_on_simavr():
    require_tool(
        "make",
        "cc",
        "avr-g++",
        "avr-size",
        "/usr/share/arduino/hardware/arduino/avr/cores/arduino",
        "/usr/include/simavr/sim_avr.h",
    )
    rig = connect(
        "simavr",
        progress=False,
        model=(27.5, 0.034),
        device=DCMotor(K=27.5, tau=0.034, coulomb_friction=0.3),
        link=Link(timeout=10.0),
    )
    try:
        found = {f.name: f for f in check_rig(rig, turn_counts=448)}  # a hand turn's count
        assert all(f.ok for f in found.values()), format_report(found.values())
        assert rig.firmware_version in found["firmware"].message
        # the user states 112 counts/rev for the 448-pulse encoder: the firmware decodes X1 (112 is
        # neither 2 nor 4 x 448), the encoder still gives 448 a turn
        rig.counts_per_rev = 112
        found = {f.name: f for f in check_rig(rig, turn_counts=448)}
        assert not found["cpr"].ok and "counts_per_rev=448" in found["cpr"].fix
    finally:
        rig.close()
