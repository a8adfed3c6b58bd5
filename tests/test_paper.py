"""jerklab.paper holds the papers' numbers once; the library's defaults must agree with it.

Each default is read where it is used (a signature, the firmware header, a module constant),
so a drift in either place fails here. The derived values are recomputed from their
definitions, and the firmware's defaults are parsed from its C++ header (an independent copy).
"""

from __future__ import annotations

import inspect
import math
import re
from pathlib import Path

import pytest

from jerklab import paper

ROOT = Path(__file__).resolve().parents[1]


def _default(func, name):
    return inspect.signature(func).parameters[name].default


# ---------------------------------------------------------------------------------- the papers
def test_stojcic_values():
    """The values printed in Stojčić §4A/§4B (typed in from the paper, not from the module)."""
    assert (paper.MOTOR_K, paper.MOTOR_TAU, paper.TS) == (32.4, 0.025, 0.005)
    assert (paper.ENCODER_PPR, paper.ENCODER_DECODING, paper.PWM_BITS) == (448, 1, 10)
    assert (paper.ZETA, paper.SIGMA_RATIO) == (1.0, 7.0)
    # T_s = τ_m/(2…5): 5 ms is τ/5
    assert paper.MOTOR_TAU / 5 <= paper.TS <= paper.MOTOR_TAU / 2
    # 12–30 V motor supply, the rig at its low end
    assert 12.0 <= paper.SUPPLY_VOLTAGE <= 30.0


def test_derived_values():
    assert paper.PWM_MAX == 1023
    # the paper's "8 kHz": phase-correct 10-bit PWM at 16 MHz, no prescaler
    assert paper.PWM_FREQUENCY == pytest.approx(7820.1, abs=0.1)
    assert paper.COUNTS_PER_RAD * 2 * math.pi == pytest.approx(448)
    assert (
        paper.LIMITS == (paper.MAX_JERK, paper.MAX_ACCEL, paper.MAX_VELOCITY) == (2e4, 300.0, 100.0)
    )


def test_xu_meckl_table_i_and_its_dc_gain():
    t = paper.PIEZO_TABLE_I
    assert dict(t) == {
        "K": 97000.0,
        "zeta_z": 0.70,
        "f_z": 1643.0,
        "zeta_1": 0.008,
        "f_1": 242.0,
        "zeta_2": 0.39,
        "f_2": 777.0,
    }
    # G(0) = K ωz²/(ω1² ω2²) = 0.18759 µm/V (a published consequence of Table I)
    g0 = t["K"] * t["f_z"] ** 2 / (t["f_1"] ** 2 * t["f_2"] ** 2) / (2 * math.pi) ** 2
    assert g0 == pytest.approx(0.18759, abs=5e-6)
    assert paper.PIEZO_TS == 2e-4 and paper.CNIA_EPS_FRACTION == 0.002
    with pytest.raises(TypeError):
        t["K"] = 1.0  # read-only


def test_yang_setup():
    s = paper.YANG_SETUP
    # N = T/(2 tc) = 2500 counts per half, V/(2N²) = 16/10000 (Yang eq. 7)
    N = s["accel_time"] / (2 * s["refresh_period"])
    assert N == pytest.approx(2500)
    assert s["max_velocity"] / (2 * N * N) == pytest.approx(16 / 10000)
    assert (s["clock_hz"], s["step_um"], s["start_count"]) == (50_000_000, 20, 300)


# --------------------------------------------------------------- the library uses the same values
def test_plant_defaults():
    from jerklab.plant import DCMotor, FlexibleDCMotor

    for cls in (DCMotor, FlexibleDCMotor):
        m = cls()
        assert (m.K, m.tau) == (paper.MOTOR_K, paper.MOTOR_TAU), cls
        assert (m.supply_voltage, m.pwm_bits) == (paper.SUPPLY_VOLTAGE, paper.PWM_BITS), cls
        assert (m.encoder_ppr, m.decoding) == (paper.ENCODER_PPR, paper.ENCODER_DECODING), cls
        assert m.counts_per_rad == pytest.approx(paper.COUNTS_PER_RAD)


def test_controller_defaults():
    from jerklab import controller as C

    assert _default(C.DigitalController, "output_limit") == paper.SUPPLY_VOLTAGE
    assert _default(C.discrete_pole_placement_pid, "Ts") == paper.TS
    assert _default(C.paper_error_scale, "Ts") == paper.TS
    assert _default(C.paper_error_scale, "encoder_ppr") == paper.ENCODER_PPR
    f = C.paper_velocity_controller
    assert (_default(f, "K"), _default(f, "tau"), _default(f, "Ts")) == (
        paper.MOTOR_K,
        paper.MOTOR_TAU,
        paper.TS,
    )
    assert (_default(f, "encoder_ppr"), _default(f, "output_limit")) == (
        paper.ENCODER_PPR,
        paper.SUPPLY_VOLTAGE,
    )
    # the paper's pulses-per-Ts error scale: 1/2.80
    assert 1 / C.paper_error_scale() == pytest.approx(2 * math.pi / (448 * 0.005))


def test_sim_and_rig_defaults():
    from jerklab import sim
    from jerklab.rig import client, options, virtual

    assert (_default(sim.perturbed_plants, "K"), _default(sim.perturbed_plants, "tau")) == (
        paper.MOTOR_K,
        paper.MOTOR_TAU,
    )
    r = client.Rig.__init__
    assert _default(r, "supply_voltage") == paper.SUPPLY_VOLTAGE
    assert _default(r, "counts_per_rev") == paper.ENCODER_PPR * paper.ENCODER_DECODING
    assert _default(r, "model") == (paper.MOTOR_K, paper.MOTOR_TAU)
    assert _default(client.Rig.step, "Ts") == paper.TS
    # configure and run_move take the period from RunSpec: the gains' own, else the paper's
    assert _default(client.Rig.run_move, "Ts") is None
    assert options.RunSpec().Ts is None and options.RunSpec().period(object()) == paper.TS
    dev = virtual.VirtualDevice()
    lim = dev.limits
    assert (lim.max_jerk, lim.max_accel, lim.max_velocity) == pytest.approx(paper.LIMITS)
    assert (dev.plant.K, dev.plant.tau) == pytest.approx((paper.MOTOR_K, paper.MOTOR_TAU), rel=1e-7)
    assert dev.plant.counts_per_rev == paper.ENCODER_PPR and dev.pwm_max == paper.PWM_MAX


def _firmware_boot_settings():
    """The firmware's boot settings by member name: DeviceSettings' members (jl_device.h, in
    order) paired with kBootSettings' initialiser (jl_device.cpp, the one image in flash)."""
    src = ROOT / "firmware" / "jerklab_rig" / "src"
    header = (src / "jl_device.h").read_text()
    body = re.search(
        r"struct __attribute__\(\(packed\)\) DeviceSettings \{(.*?)\n\};", header, re.S
    )
    assert body, "DeviceSettings not found in jl_device.h"
    names = []
    for line in body.group(1).splitlines():
        decl = line.split("//")[0].strip()
        m = re.match(r"(?:unsigned\s+)?[A-Za-z_][A-Za-z0-9_]*\s+([A-Za-z_][A-Za-z0-9_, ]*);$", decl)
        if m:
            names += [n.strip() for n in m.group(1).split(",")]
    cpp = (src / "jl_device.cpp").read_text()
    init = re.search(r"kBootSettings JL_PROGMEM = \{(.*?)\n\};", cpp, re.S)
    assert init, "kBootSettings not found in jl_device.cpp"
    values = [
        v.strip()
        for line in init.group(1).splitlines()
        for v in line.split("//")[0].split(",")
        if v.strip()
    ]
    assert len(values) == len(names), (names, values)
    return dict(zip(names, values))


def test_firmware_header_defaults():
    """The firmware's boot settings (parsed from jl_device.h and jl_device.cpp) are the
    paper's numbers."""
    boot = _firmware_boot_settings()

    def num(name):
        v = boot[name].rstrip("fFuUlL") if not boot[name].startswith("0x") else boot[name]
        return float(int(v.rstrip("UL"), 16)) if v.startswith("0x") else float(v)

    assert (num("K_"), num("tau_"), num("supply_")) == pytest.approx(
        (paper.MOTOR_K, paper.MOTOR_TAU, paper.SUPPLY_VOLTAGE), rel=1e-7
    )
    assert num("counts_per_rev_") == paper.ENCODER_PPR
    assert num("pwm_top_") == paper.PWM_MAX
    assert (num("max_jerk_"), num("max_accel_"), num("max_velocity_")) == paper.LIMITS
    # 0.5 rad as IEEE bits, the tracking-error limit at boot (PROTOCOL.md "Safety stops")
    import struct

    bits = int(boot["max_error_bits_"].rstrip("UL"), 16)
    assert struct.unpack("<f", struct.pack("<I", bits))[0] == 0.5
    ino = (ROOT / "firmware" / "jerklab_rig" / "jerklab_rig.ino").read_text()
    assert re.search(rf"#define JL_ENCODER_PPR {paper.ENCODER_PPR}\b", ino)


def test_piezo_fpga_hysteresis_use_paper():
    from jerklab import fpga, hysteresis, piezo

    assert piezo.TABLE_I == dict(paper.PIEZO_TABLE_I) and piezo.TS == paper.PIEZO_TS
    m = piezo.PZTModel()
    assert {k: getattr(m, k) for k in paper.PIEZO_TABLE_I} == dict(paper.PIEZO_TABLE_I)
    assert fpga.PAPER == dict(paper.YANG_SETUP)
    assert fpga.YangSCurve(**fpga.PAPER).half_counts == 2500
    H = hysteresis.Preisach.uniform(-10.0, 30.0, n=4)
    assert H.default_eps == pytest.approx(paper.CNIA_EPS_FRACTION * 40.0)


def test_yang_scurve_defaults_are_the_setup():
    from jerklab.fpga import YangSCurve

    sig = inspect.signature(YangSCurve)
    assert {k: sig.parameters[k].default for k in paper.YANG_SETUP} == dict(paper.YANG_SETUP)
