"""Every bad-input class of issue 31 answered by a clear error at the public boundary.

Each case below gave an AttributeError, a KeyError, a ZeroDivisionError, numpy's own message, a
NaN, an infinite estimate or a silent acceptance before the fix; each now raises an error that
names the parameter (and the limit, the file or the field), through ``jerklab._validate``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import time
import warnings

import numpy as np
import pytest

from jerklab import controller, fpga, hysteresis, piezo, planner, plant, sim
from jerklab import protocol as P
from jerklab._validate import (
    BadIndex,
    BadInput,
    as_having,
    as_index,
    as_instance,
    as_path,
    as_seed,
    at_least,
    at_most,
)
from jerklab.ident import IdentData, fit_dc_motor, simulate_dc_motor
from jerklab.rig import connect
from jerklab.rig.recording import Recording, compare


def _within(seconds, fn):
    t0 = time.monotonic()
    try:
        return fn()
    finally:
        assert time.monotonic() - t0 < seconds, f"took more than {seconds} s"


# ------------------------------------------------------------------------ the shared helpers
def test_helpers_name_the_parameter_and_what_was_expected():
    with pytest.raises(
        BadInput, match=r"cycle must be a jerklab\.piezo\.ScanCycle, got 'x' \(str\)"
    ):
        as_instance("cycle", "x", piezo.ScanCycle, "a jerklab.piezo.ScanCycle")
    with pytest.raises(BadInput, match=r"sim must be a SimResult \(with \.time\)"):
        as_having("sim", 3, ("time",), "a SimResult")
    with pytest.raises(BadInput, match="path must be a path"):
        as_path("path", 3)
    with pytest.raises(ValueError, match="empty"):
        as_path("path", "")
    with pytest.raises(BadIndex, match=r"i must be in 0\.\.1"):
        as_index("i", -1, 2)
    with pytest.raises(ValueError, match="seed must be >= 0"):
        as_seed("seed", -1)
    with pytest.raises(ValueError, match=r"n must be <= 10 \(cells\), got 11"):
        at_most("n", 11, 10, "cells")
    with pytest.raises(ValueError, match=r"Ts must be >= 1e-09 \(MIN\), got 1e-300"):
        at_least("Ts", 1e-300, 1e-9, "MIN")
    # a BadInput / BadIndex is both kinds a caller may catch
    assert issubclass(BadInput, TypeError) and issubclass(BadInput, ValueError)
    assert issubclass(BadIndex, IndexError) and issubclass(BadIndex, ValueError)
    assert as_index("i", 1, 2) == 1 and as_seed("seed", None) is None
    assert at_least("Ts", 0.02, 1e-9) == 0.02


# ------------------------------------------------------------------------ wrong types
@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: piezo.evaluate_cycle("x"), "cycle"),
        (lambda: piezo.closed_loop("x"), "cycle"),
        (lambda: fpga.simulate_verilog("x"), "model"),
        (lambda: fpga.published_divider_lockup("x"), "model"),
        (lambda: fpga.read_vcd(3, ["clk"]), "path"),
        (lambda: fpga.read_vcd("a.vcd", "clk"), "signals"),
        (lambda: compare("x", None), "rec"),
        (lambda: piezo.shape_rampup(orders="x"), "orders"),
        (lambda: piezo.shape_rampup(orders={1: "a"}), "orders[1]"),
        (lambda: Recording.load(3), "path"),
        (lambda: IdentData.load(None), "path"),
    ],
)
def test_a_wrong_type_is_named(call, name):
    with pytest.raises((TypeError, ValueError)) as info:
        call()
    assert name in str(info.value)
    assert not isinstance(info.value, AttributeError)


def test_closed_loop_names_a_wrong_hysteresis():
    cycle = _cycle()
    for bad in ("x", 3, {}):
        with pytest.raises(BadInput, match="hysteresis must be a jerklab.hysteresis.Preisach"):
            piezo.closed_loop(cycle, hysteresis=bad)
    with pytest.raises(BadInput, match="actuator"):
        piezo.closed_loop(cycle, hysteresis=None, actuator="x")
    with pytest.raises(BadInput, match="perturbed"):
        piezo.evaluate_cycle(cycle, perturbed="x")


_CYCLE = []


def _cycle():
    if not _CYCLE:
        _CYCLE.append(piezo.shape_cycle())
    return _CYCLE[0]


def test_recording_methods_and_compare_name_a_string():
    rec = Recording({"Ts": 0.005, "counts_per_rad": 71.3, "volts_per_pwm": 12 / 1023})
    rec.append(0, 0.0, 0, 0)
    with pytest.raises(BadInput, match="sim must be a jerklab.sim.SimResult"):
        compare(rec, "x")
    with pytest.raises(BadInput, match="sim must be"):
        rec.plot_comparison("x")
    with pytest.raises(BadInput, match="ax must be a matplotlib Axes"):
        rec.plot("x")
    with pytest.raises(BadInput, match="path must be a path"):
        rec.save(3.5)


# ------------------------------------------------------------------------ files
def test_ident_loader_names_file_and_field(tmp_path):
    t = np.arange(50) * 0.005
    u = np.where(t > 0.02, 6.0, 0.0)
    d = IdentData(u, simulate_dc_motor(32.4, 0.025, 0.005, u), 0.005)
    base = tmp_path / "rec"
    csv_path, json_path = d.save(base)
    assert IdentData.load(base).n == d.n
    json_path.write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"rec\.json is not an IdentData sidecar \(a JSON list"):
        IdentData.load(base)
    d.save(base)
    side = json.loads(json_path.read_text())
    del side["Ts"]
    json_path.write_text(json.dumps(side))
    with pytest.raises(ValueError, match=r"rec\.json has no field 'Ts'"):
        IdentData.load(base)
    side["Ts"] = "fast"
    json_path.write_text(json.dumps(side))
    with pytest.raises(ValueError, match=r"rec\.json field 'Ts' must be a real number"):
        IdentData.load(base)


def test_read_vcd_names_the_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="path: no VCD file at /nonexistent"):
        fpga.read_vcd("/nonexistent", ["clk"])
    (tmp_path / "x.vcd").write_text("not a dump")
    with pytest.raises(ValueError, match=r"path: .*x\.vcd is not a VCD file"):
        fpga.read_vcd(tmp_path / "x.vcd", ["clk"])


def _recording_on_disk(tmp_path, n=50):
    rec = Recording(
        {"Ts": 0.005, "counts_per_rad": 448 / (2 * math.pi), "volts_per_pwm": 12 / 1023},
        tmp_path / "run",
    )
    for k in range(n):
        rec.append(k, 0.01 * k, 3 * k, 100 + k)
    rec.finish()
    return tmp_path / "run.csv"


@pytest.mark.parametrize(
    "column", ["index", "time", "reference", "position", "counts", "control", "pwm", "flags"]
)
def test_recording_load_names_a_garbage_cell(tmp_path, column):
    from jerklab.rig.recording import COLUMNS

    csv_path = _recording_on_disk(tmp_path)
    lines = open(csv_path, newline="").read().split("\r\n")
    cells = lines[25].split(",")  # line 26 of the file, the 25th sample
    cells[COLUMNS.index(column)] = "4x2"
    lines[25] = ",".join(cells)
    with open(csv_path, "w", newline="") as f:
        f.write("\r\n".join(lines))
    with pytest.raises(ValueError, match=rf"run\.csv: line 26, column '{column}': '4x2' is not"):
        Recording.load(csv_path)


def test_recording_load_names_a_derived_column_that_disagrees(tmp_path):
    csv_path = _recording_on_disk(tmp_path)
    lines = open(csv_path, newline="").read().split("\r\n")
    cells = lines[10].split(",")
    cells[3] = repr(float(cells[3]) + 1.0)  # position no longer counts / counts_per_rad
    lines[10] = ",".join(cells)
    with open(csv_path, "w", newline="") as f:
        f.write("\r\n".join(lines))
    with pytest.raises(ValueError, match=r"line 11, column 'position': .* disagrees"):
        Recording.load(csv_path)
    assert len(Recording.load(_recording_on_disk(tmp_path / "ok"))) == 50


# ------------------------------------------------------------------------ unbounded work
def test_fpga_model_refuses_unbounded_requests_up_front():
    with pytest.raises(ValueError, match=r"MAX_TICKS"):
        _within(2, lambda: fpga.YangSCurve(accel_time=1e6, bits=62))
    with pytest.raises(ValueError, match=r"bits must be <= 62 \(fpga\.MODEL_BITS"):
        fpga.YangSCurve(bits=64, clock_hz=10**15)
    # the legal extreme: 62-bit registers at a 1 PHz clock stay exact in int64
    m = fpga.YangSCurve(bits=62, clock_hz=10**15)
    cyc = m.speed_table().cycle
    f = m.speed_table().frequency
    on = f > 0
    assert np.array_equal(cyc[on], 10**15 // f[on])  # integer division, no int64 wrap


def test_shape_rampup_refuses_orders_above_the_limit():
    with pytest.raises(ValueError, match=r"orders\[1\] must be <= 8 \(.*MAX_ROBUST_ORDER"):
        _within(2, lambda: piezo.shape_rampup(orders=50))
    with pytest.raises(ValueError, match=r"tracking_orders\[2\]"):
        piezo.shape_cycle(tracking_orders={2: 9})
    with pytest.raises(ValueError, match="orders: modes are 1 and 2"):
        piezo.shape_rampup(orders={True: 1})


def test_synchronized_refuses_a_period_below_a_nanosecond():
    from jerklab.multiaxis import plan_multi_axis

    p = planner.plan_sine_jerk(1.0, 2000.0, 300.0, 100.0)
    for prof in (p, planner.plan_scurve(1.0, 2000.0, 300.0, 100.0)):
        with pytest.raises(ValueError, match=r"Ts must be >= 1e-09 \(planner\.MIN_SYNC_TS"):
            prof.synchronized(1e-300)
    m = plan_multi_axis([1.0, 0.5], [(2000.0, 300.0, 100.0)] * 2)
    with pytest.raises(ValueError, match="MIN_SYNC_TS"):
        m.synchronized(1e-300)
    # at the limit: every phase a whole number of nanoseconds, no phase shorter
    q = p.synchronized(planner.MIN_SYNC_TS)
    n = np.asarray(q.phase_times) / planner.MIN_SYNC_TS
    assert np.all(np.abs(n - np.round(n)) <= 1e-6 * n) and q.duration >= p.duration


# ------------------------------------------------------------------------ numbers
def test_preisach_huge_span_is_named_and_a_large_one_stays_legal():
    with pytest.raises(ValueError, match="u_max - u_min"):
        hysteresis.Preisach.uniform(-1e300, 1e300)
    with pytest.raises(ValueError, match="u_max - u_min overflows"):
        hysteresis.Preisach.uniform(-1.7e308, 1.7e308)
    with pytest.raises(ValueError, match="u_max - u_min"):
        hysteresis.Preisach(-1e300, 1e300, np.ones((4, 4)))
    # 1e100: the major loop still spans the input (output in input units, gain 1)
    H = hysteresis.Preisach.uniform(-1e100, 1e100, n=10)
    assert H.apply(1e100) == pytest.approx(1e100, rel=1e-9)
    assert H.apply(-1e100) == pytest.approx(-1e100, rel=1e-9)


def test_flexible_motor_extreme_load_ratio_stays_legal():
    m = plant.FlexibleDCMotor(load_ratio=1e-300)
    Phi, Gamma = m.zoh(0.005)
    assert np.all(np.isfinite(Phi)) and np.all(np.isfinite(Gamma))
    # a load of no inertia: the motor is the rigid motor of Stojčić eq. 1
    rigid = plant.DCMotor(supply_voltage=None, pwm_bits=None, encoder_ppr=None)
    x = rigid.step_state(np.zeros(2), 3.0, 0.005)
    assert Phi[:2, :2] @ np.zeros(2) + Gamma[:2, 0] * 3.0 == pytest.approx(x, rel=1e-9)
    with pytest.raises(ValueError, match="load_ratio"):
        plant.FlexibleDCMotor(load_ratio=5e-324).zoh(0.005)


def test_motor_seed_is_named():
    for cls in (plant.DCMotor, plant.FlexibleDCMotor):
        with pytest.raises(ValueError, match="seed must be >= 0, got -1"):
            cls(seed=-1)
        with pytest.raises(ValueError, match="seed must be an integer"):
            cls(seed="x")
    assert plant.DCMotor(seed=np.random.default_rng(1)).rng is not None


def test_pole_placement_refuses_a_sigma_that_never_acts():
    with pytest.raises(ValueError, match=r"sigma must be >= controller\.SIGMA_MIN_RATIO"):
        controller.pole_placement_pid(32.4, 0.025, 20.0, sigma=1e-300)
    with pytest.raises(ValueError, match="SIGMA_MIN_RATIO"):
        controller.discrete_pole_placement_pid(32.4, 0.025, 20.0, sigma=1e-300)
    g = controller.pole_placement_pid(32.4, 0.025, 20.0, sigma=20.0 * 1e-6)
    assert g.ki > 0.0


def test_batch_profile_refuses_a_negative_index():
    b = planner.plan_batch("scurve", [1.0, 2.0], 2000.0, 300.0, 100.0)
    with pytest.raises(ValueError, match="no negative index"):
        b.profile(i=-1)
    a = planner.plan_batch_any_state("scurve", [1.0, 2.0], 2000.0, 300.0, 100.0, 1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="no negative index"):
        a.profile(-1)
    assert a.profile(0).distance == 1.0


def test_simulate_batch_refuses_a_2d_parameter():
    prof = planner.plan_sine_jerk(1.0, 2000.0, 300.0, 100.0)
    g = controller.pole_placement_pid(32.4, 0.025, 20.0).discretize(0.005)
    for name in ("K", "tau", "coulomb_friction"):
        with pytest.raises(ValueError, match=rf"{name} must be a number or a 1-D array"):
            sim.simulate_batch(prof, plant.DCMotor(), g, **{name: [[0.1, 0.2], [0.3, 0.4]]})
    with pytest.raises(ValueError, match=r"tau must be > 0 for every plant, got -0.1 at plant 1"):
        sim.simulate_batch(prof, plant.DCMotor(), g, tau=[0.025, -0.1])


def test_digital_controller_refuses_an_overflowing_reference_and_keeps_its_state():
    g = controller.pole_placement_pid(32.4, 0.025, 20.0).discretize(0.005)
    c = controller.DigitalController(g)
    ref = controller.DigitalController(g)
    for r in (0.1, 0.2):
        assert c.step(r) == ref.step(r)
    with pytest.raises(ValueError, match=r"ref_position=1e\+308.*overflows"):
        c.step(1e308)
    # the state is the one before the refused sample: the next outputs agree with a twin
    for r in (0.3, 0.4, 0.5):
        assert c.step(r) == ref.step(r)


def test_ident_refuses_data_whose_squares_overflow_and_flags_a_reversed_encoder():
    Ts = 0.005
    u = np.where(np.arange(400) * Ts > 0.05, 6.0, 0.0)
    u[200:] = -3.0
    theta = simulate_dc_motor(32.4, 0.025, Ts, u)
    with pytest.raises(ValueError, match=r"theta reaches .* MAX_SIGNAL"):
        fit_dc_motor(u, theta * 1e300, Ts)
    with pytest.raises(ValueError, match=r"u reaches"):
        fit_dc_motor(u * 1e300, theta, Ts)
    f = fit_dc_motor(u, theta * 1e100, Ts)  # large but legal: the gain scales
    assert f.K == pytest.approx(32.4e100, rel=1e-3) and math.isfinite(f.noise_std)
    assert not f.reversed
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        r = fit_dc_motor(u, -theta, Ts)
    assert r.reversed and r.K == pytest.approx(-32.4, rel=1e-3)
    assert any("reversed" in str(x.message) for x in w)


# ------------------------------------------------------------------------ rig helpers
def test_rig_helpers_name_their_parameters(tmp_path):
    prof = planner.plan_sine_jerk(1.0, 2000.0, 300.0, 100.0)
    g = controller.pole_placement_pid(32.4, 0.025, 20.0)
    rig = connect(None, progress=False)
    try:
        for bad in (0, -5, 1):
            with pytest.raises(ValueError, match=rf"window must be >= 2, got {bad}"):
                rig.wait_still(window=bad)
        with pytest.raises(ValueError, match="window must be <= 65535"):
            rig.wait_still(window=70000)
        with pytest.raises(ValueError, match="tolerance"):
            rig.wait_still(tolerance=-1)
        # a device without host-planned segments (protocol version 5, capability bit 10)
        # re-plans every move itself: it refuses an edited profile and a moving start by name
        info = rig.info
        rig.info = dataclasses.replace(
            info, capabilities=info.capabilities & ~P.Capability.HOST_SEGMENTS
        )
        with pytest.raises(
            ValueError, match=r"profile lasts .* changed after planning \(\.synchronized"
        ):
            rig.run_move(prof.synchronized(0.005), g, 0.005, path=False)
        moving = planner.plan_scurve(1.0, 2000.0, 300.0, 100.0, initial_velocity=1.0)
        with pytest.raises(ValueError, match="rest-to-rest"):
            rig.run_move(moving, g, 0.005, path=False)
        rig.info = info
        # one that has them refuses a profile that ends moving, naming final_velocity
        ends_moving = planner.plan_scurve(1.0, 2000.0, 300.0, 100.0, final_velocity=1.0)
        with pytest.raises(ValueError, match="final_velocity"):
            rig.run_move(ends_moving, g, 0.005, path=False)
        with pytest.raises(ValueError, match="feedforward"):
            rig.run_move(prof, g, 0.005, path=False, feedforward="x")
    finally:
        rig.close()


def test_a_write_error_says_what_to_do(tmp_path, monkeypatch):
    import builtins
    import errno

    from jerklab.rig.recording import RecordingIOError

    meta = {"Ts": 0.005, "counts_per_rad": 71.3, "volts_per_pwm": 12 / 1023}
    (tmp_path / "afile").write_text("")
    with pytest.raises(RecordingIOError, match="is a file, not a folder") as e:
        Recording(meta, tmp_path / "afile" / "run")
    assert e.value.errno in (errno.ENOTDIR, errno.EEXIST)
    real_open = builtins.open

    def refused(file, mode="r", *a, **k):
        if str(file).endswith("run.csv") and "w" in mode:
            raise PermissionError(errno.EACCES, "Permission denied", str(file))
        return real_open(file, mode, *a, **k)

    monkeypatch.setattr(builtins, "open", refused)
    with pytest.raises(RecordingIOError, match=r"connect\(recordings=\.\.\.\)") as e:
        Recording(meta, tmp_path / "run")
    assert e.value.errno == errno.EACCES and "run.csv" in str(e.value)


# ------------------------------------------------------------------------ the APIs probed since round 2
def test_retarget_helpers_name_their_parameters():
    from jerklab.rig import retarget as RT

    for bad in (4, -1, 2.5, "2", None, True):
        with pytest.raises(ValueError, match="kind must be PLAN's planner byte 0..3"):
            RT.rest_plan(bad, 1.0, 2000.0, 300.0, 100.0)
    with pytest.raises(ValueError, match="max_jerk"):
        RT.stop_plan(2, 1.0, 0.0, 300.0)
    with pytest.raises(ValueError, match="v0 must be >= 0"):
        RT.moving_plan(2, 1.0, -1.0, 2000.0, 300.0, 100.0)
    with pytest.raises(ValueError, match="max_velocity"):
        RT.moving_plan(2, 1.0, 1.0, 2000.0, 300.0, float("nan"))
    with pytest.raises(ValueError, match="braking distance overflows"):
        RT.stop_plan(2, 1e300, 2000.0, 300.0)
    with pytest.raises(ValueError, match="Ts_us"):
        RT.lead_samples(0)
    # a trapezoid takes no jerk; the plans agree with the planner's phase times
    p = RT.rest_plan(3, 1.0, None, 300.0, 100.0)
    q = planner.plan_trapezoid(1.0, 300.0, 100.0)
    assert p.v_peak == pytest.approx(q.peak_velocity) and p.duration == pytest.approx(q.duration)
    assert RT.lead_samples(5000) == 4 and RT.lead_samples(1000) == 14


def test_shaping_names_frequency_and_work_limits():
    from jerklab import shaping as SH

    with pytest.raises(ValueError, match="frequency_hz must be numeric"):
        SH.residual_vibration_of([0.5, 0.5], [0.0, 0.0625], "8")
    with pytest.raises(ValueError, match="MAX_CHIRP_SAMPLES"):
        _within(2, lambda: SH.chirp_input(1e9, 0.005, 3.0, 1.0, 20.0))
    with pytest.raises(ValueError, match=r"0\.5 / Ts .*Ts = 1e\+09 s"):
        SH.chirp_input(1.0, 1e9, 3.0, 1.0, 20.0)
    for f in (1e-300, 1e300):
        with pytest.raises(ValueError, match=re.escape(f"frequency_hz = {f!r} Hz")):
            SH.tuned_profile("scurve", 1.0, f, 300.0, 100.0)
    with pytest.raises(ValueError, match="kind must be"):
        SH.tuned_profile("box", 1.0, 8.0, 300.0, 100.0)
    from jerklab.multiaxis import stretch_to_duration

    with pytest.raises(ValueError, match=r"duration = 1e\+300 s"):
        stretch_to_duration(planner.plan_scurve(1.0, 2000.0, 300.0, 100.0), 1e300)


def test_lab_sweep_fit_and_handin_name_their_input(tmp_path):
    from jerklab.lab import checks as LC
    from jerklab.lab.handin import HandinError, read_handin

    # a sweep of the motor w = K (V + off - f_c sign V): the fit gives K, f_c, off back
    K, fc, off = 30.0, 0.4, 0.1
    sweep = {
        v: K * (v + off - fc * math.copysign(1.0, v)) for v in (-3.0, -2.0, -1.0, 1.0, 2.0, 3.0)
    }
    (K_, fc_, off_), _ = LC.sweep_fit(sweep)
    assert (K_, fc_, off_) == pytest.approx((K, fc, off), rel=1e-9)
    with pytest.raises(ValueError, match="both sides of 0"):
        LC.sweep_fit({1.0: 20.0, 2.0: 52.0, 3.0: 84.0, 4.0: 116.0})
    with pytest.raises(ValueError, match=r"speeds\[1\.0\]"):
        LC.sweep_fit({-2.0: -52.0, -1.0: -20.0, 1.0: float("nan"), 2.0: 52.0})
    with pytest.raises(BadInput, match="speeds must be a dict"):
        LC.sweep_fit("x")
    with pytest.raises(FileNotFoundError, match="path: no hand-in at"):
        read_handin(tmp_path / "none.zip")
    with pytest.raises(HandinError, match="is a folder"):
        read_handin(tmp_path)
    with pytest.raises(BadInput, match="path must be a path"):
        read_handin(3)


def test_broker_client_names_its_timeout():
    from jerklab.broker import BrokerRig

    for bad in (float("nan"), 0.0, -1.0, "x", None):
        with pytest.raises(ValueError, match="timeout"):
            BrokerRig("broker://127.0.0.1:1", timeout=bad)
    with pytest.raises(ValueError, match="timeout must be <= 86400"):
        BrokerRig("broker://127.0.0.1:1", timeout=1e300)


# ------------------------------------------------------------------ the class rig service, the host loop
def test_class_rig_client_names_its_bad_arguments(tmp_path):
    """The class rig service's client (the probe of ``python -m benchmarks faults``, module
    classrig): an address, a timeout, a step's numbers or a check's name that cannot be used is
    a ValueError naming it, before anything reaches the service; a voltage below float32's
    range is sent as 0 V (it would have been refused by the frame encoder)."""
    from jerklab.lab.classrig import ClassRig
    from jerklab.lab.service import ClassRigService, TokenFile

    for address in ("classrig://127.0.0.1:notaport", "classrig://127.0.0.1:70000", "classrig://:5"):
        with pytest.raises(ValueError, match="address must be 'classrig://HOST:PORT'"):
            ClassRig(address, 1, token="t")
    tokens = tmp_path / "tokens.json"
    tokens.write_text(json.dumps({"tok-ana-3c9d1e7b": "ana"}))
    with ClassRigService(TokenFile(tokens), tmp_path / "log", b"a-test-instructor-key") as svc:
        for bad in (float("nan"), float("inf"), 0.0, -1.0, "x", None, 1e300):
            with pytest.raises(ValueError, match="timeout"):
                ClassRig(svc.url, 1, token="tok-ana-3c9d1e7b", timeout=bad)
        with pytest.raises(PermissionError, match="token"):
            ClassRig(svc.url, 1, token="tok-nobody-00000000")
        rig = ClassRig(svc.url, 1, token="tok-ana-3c9d1e7b")
        try:
            for name, kw in (
                ("voltage", dict(voltage="6")),
                ("voltage", dict(voltage=None)),
                ("voltage", dict(voltage=float("nan"))),
                ("seconds", dict(seconds=[1.0])),
                ("seconds", dict(seconds=0.0)),
                ("Ts", dict(Ts=None)),
                ("rest", dict(rest=-1.0)),
            ):
                args = dict(voltage=6.0, seconds=0.1, Ts=0.005) | kw
                with pytest.raises(ValueError, match=name):
                    rig.step(args.pop("voltage"), args.pop("seconds"), path=False, **args)
            rec = rig.step(1e-300, 0.05, path=False)
            # 0.05 s of step after the default 0.05 s of rest, at 5 ms
            assert np.all(np.asarray(rec.voltage) == 0.0) and len(rec) == 20
            for bad in ("no_such_check", None, 3):
                with pytest.raises(ValueError, match="name: lab 1 has no check named") as e:
                    rig.check(bad, 1.0)
                assert isinstance(e.value, KeyError)  # as before: an unknown name is a lookup
        finally:
            rig.close()


def test_a_host_loop_voltage_below_float32_is_0_volts():
    """A law's voltage of 1e-300 V (a P law a hair from its target) is 0 V on the link, not a
    frame-encoder error that ends the run; the recording says 0 V."""
    from jerklab.rig import connect

    with connect(None, progress=False) as rig:
        rec = rig.host_loop(lambda t, p, r: 1e-300, Ts=0.01, duration=0.05, path=False)
    assert rec.metadata["status"] == "complete", rec.metadata["status"]
    assert np.all(np.asarray(rec.voltage) == 0.0)
