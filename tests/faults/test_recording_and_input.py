"""Fault injection: recordings on every exit path (disk full, I/O error, Ctrl-C, a killed client,
torn and blank rows, bad metadata) and bad numbers across the public API.

Each test here failed before its fix. The disk-full tests run the real write path: the file
object the recording writes to raises ``OSError(ENOSPC)`` (``benchmarks.bench_faults.FailingFile``,
patched into ``jerklab.rig.recording.open``), and, where the machine allows mounting, a real
64 kB tmpfs fills up.
"""

from __future__ import annotations

import errno
import json
import math
import os
import subprocess
import threading
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.bench_faults import FailingFile, failing_csv_writes, kill_client_mid_run
from jerklab import protocol as P
from jerklab._validate import as_finite_array
from jerklab.controller import DiscreteGains, pole_placement_pid
from jerklab.planner import (
    MAX_BATCH_MOVES,
    MAX_SAMPLES,
    plan_batch,
    plan_scurve,
    plan_sine_jerk,
    plan_sine_jerk_optimal,
    plan_trapezoid,
)
from jerklab.plant import DCMotor
from jerklab.rig import Recording, Rig, VirtualDevice, VirtualSerial
from jerklab.rig.recording import RecordingIOError

META = {
    "kind": "demo",
    "Ts": 0.005,
    "counts_per_rad": 448 / (2 * math.pi),
    "volts_per_pwm": 12 / 1023,
}


def _rig(tmp_path, **link):
    return Rig(
        VirtualSerial(VirtualDevice(DCMotor()), timeout=0.05, **link),
        "virtual",
        progress=False,
        timeout=0.5,
        hello_timeout=1.0,
        recordings=tmp_path,
    )


def _move():
    return plan_sine_jerk(4 * math.pi, 2000.0, 300.0, 100.0), pole_placement_pid(32.4, 0.025, 20.0)


def _within(seconds, fn):
    """Run ``fn`` in a thread; fail (instead of hanging the suite) if it takes longer."""
    out = {}

    def run():
        try:
            out["value"] = fn()
        except BaseException as exc:  # noqa: BLE001
            out["error"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"no answer within {seconds} s (a hang)"
    if "error" in out:
        raise out["error"]
    return out["value"]


def _load(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        rec = Recording.load(path)
    return rec, [str(x.message) for x in w]


def _small(tmp_path, name="rec", n=20):
    rec = Recording(META, tmp_path / name)
    for i in range(n):
        rec.append(i, 0.01 * i, i, 10 * i)
    rec.finish("complete")
    return rec.csv_path


# ---------------------------------------------------------------------------- disk full, I/O errors


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EIO])
def test_write_error_mid_run_names_file_and_count_and_stops_the_rig(tmp_path, code):
    rig = _rig(tmp_path)
    prof, g = _move()
    with failing_csv_writes(4000, code), pytest.raises(RecordingIOError) as ei:
        rig.run_move(prof, g, path=tmp_path / "full")
    err = ei.value
    assert err.errno == code and str(tmp_path / "full.csv") in str(err)
    assert f"{err.samples_saved} samples saved" in str(err) and "the rig was stopped" in str(err)
    # every sample received is in memory, those flushed before the failure are in the file
    rec = err.recording
    assert len(rec) > err.samples_saved > 0
    meta = json.loads((tmp_path / "full.json").read_text())
    assert meta["status"].startswith("error: ") and os.strerror(code) in meta["status"]
    assert meta["samples_saved"] == err.samples_saved and meta["rig_stopped"] is True
    on_disk, _ = _load(tmp_path / "full.csv")
    assert len(on_disk) >= err.samples_saved
    np.testing.assert_array_equal(
        on_disk.counts[: err.samples_saved], rec.counts[: err.samples_saved]
    )
    # the device is idle: PLAN (refused while BUSY) is answered without a STOP first
    info = rig._request(P.Plan(1.0, 0), replies=(P.MsgType.PLAN_INFO,))
    assert info.duration > 0
    rig.close()


def test_write_error_in_recording_append_and_flush(tmp_path):
    rec = Recording(META, tmp_path / "r")
    rec._file = FailingFile(rec._file, 300)
    for i in range(5):
        rec.append(i, 0.0, i, 0)
    rec.flush()
    assert rec._saved == 5
    with pytest.raises(
        RecordingIOError, match=r"r\.csv: No space left on device .* 5 samples saved"
    ):
        for i in range(5, 100):
            rec.append(i, 0.0, i, 0)
    rec.append(100, 0.0, 100, 0)  # after the error: kept in memory only
    rec.finish("complete")
    meta = json.loads(rec.json_path.read_text())
    assert meta["status"].startswith("error: ") and meta["samples_saved"] == 5
    assert meta["n_samples"] == len(rec)


def test_creating_a_recording_where_it_cannot_names_the_file(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(RecordingIOError, match=r"file/rec\.csv.* 0 samples saved"):
        Recording(META, tmp_path / "file" / "rec")  # a file where a folder should be


def test_real_full_filesystem(tmp_path):
    """A 64 kB tmpfs (needs root: skipped elsewhere) fills up during a run."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    try:
        rig = _rig(tmp_path)
        prof = plan_sine_jerk(40 * math.pi, 200.0, 30.0, 10.0)  # ~1,000 rows: > 64 kB
        with pytest.raises(RecordingIOError) as ei:
            rig.run_move(prof, pole_placement_pid(32.4, 0.025, 20.0), path=mnt / "run")
        assert ei.value.errno == errno.ENOSPC and str(mnt / "run.csv") in str(ei.value)
        rig._request(P.Plan(1.0, 0), replies=(P.MsgType.PLAN_INFO,))  # not BUSY
        rig.close()
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


# ---------------------------------------------------------------------------- other exit paths


def test_ctrl_c_mid_run_ends_interrupted_and_stops(tmp_path, monkeypatch):
    rig = _rig(tmp_path)
    prof, g = _move()
    orig, calls = Recording.append, [0]

    def append(self, *a, **k):
        calls[0] += 1
        if calls[0] == 60:
            raise KeyboardInterrupt
        return orig(self, *a, **k)

    monkeypatch.setattr(Recording, "append", append)
    with pytest.raises(KeyboardInterrupt):
        rig.run_move(prof, g, path=tmp_path / "c")
    monkeypatch.setattr(Recording, "append", orig)
    meta = json.loads((tmp_path / "c.json").read_text())
    assert meta["status"] == "interrupted" and meta["n_samples"] == 59
    rig.stop()
    rig.close()


def test_killed_client_loads_as_incomplete(tmp_path):
    csv_path = kill_client_mid_run(tmp_path / "killed")
    assert json.loads((tmp_path / "killed.json").read_text())["status"] == "recording"
    rec, warns = _load(csv_path)
    assert rec.metadata["status"] == "incomplete" and rec.metadata["status_on_disk"] == "recording"
    assert any("still says 'recording'" in w for w in warns)
    assert len(rec) >= 50 and np.array_equal(rec.index, np.arange(len(rec)))


def test_torn_last_row_is_dropped_with_a_warning(tmp_path):
    p = _small(tmp_path)
    text = p.read_text()
    body = text.rstrip("\r\n")
    last = body.rsplit("\n", 1)[1]
    cut = len(body) - len(last) + [i for i, c in enumerate(last) if c == ","][6] + 1
    p.write_text(text[:cut])  # cut right after the 7th comma of the last row
    rec, warns = _load(p)
    assert len(rec) == 19 and rec.counts[-1] == 18
    assert any("line 21" in w and "torn" in w for w in warns)


def test_blank_line_is_not_a_silent_end(tmp_path):
    p = _small(tmp_path)
    lines = p.read_bytes().split(b"\r\n")
    lines.insert(10, b"")
    p.write_bytes(b"\r\n".join(lines))
    rec, warns = _load(p)
    assert len(rec) == 20  # nothing after the blank line is lost
    assert any("line 11 is blank" in w for w in warns)


def test_trailing_newline_is_fine(tmp_path):
    rec, warns = _load(_small(tmp_path))
    assert len(rec) == 20 and warns == []


@pytest.mark.parametrize(
    "field, value",
    [
        ("Ts", 0.0),
        ("Ts", -0.005),
        ("Ts", "nan"),
        ("Ts", None),
        ("counts_per_rad", 0),
        ("volts_per_pwm", "inf"),
    ],
)
def test_bad_metadata_on_load_names_field_and_file(tmp_path, field, value):
    p = _small(tmp_path)
    j = p.with_suffix(".json")
    meta = json.loads(j.read_text())
    meta[field] = value
    j.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=rf"rec\.json.*{field}"):
        Recording.load(p)


def test_missing_metadata_key_names_it(tmp_path):
    p = _small(tmp_path)
    j = p.with_suffix(".json")
    meta = json.loads(j.read_text())
    del meta["counts_per_rad"]
    j.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"rec\.json.*counts_per_rad"):
        Recording.load(p)


@pytest.mark.parametrize(
    "field, value",
    [
        ("Ts", 0.0),
        ("Ts", math.nan),
        ("counts_per_rad", 0.0),
        ("volts_per_pwm", -1.0),
        ("Ts", "0.005"),
    ],
)
def test_bad_metadata_on_save_names_field(tmp_path, field, value):
    with pytest.raises(ValueError, match=field):
        Recording(dict(META, **{field: value}), tmp_path / "x")
    assert not (tmp_path / "x.csv").exists()


def test_append_refuses_bad_samples():
    rec = Recording(META)
    for kw, name in (
        (dict(index=-1), "index"),
        (dict(index=1.5), "index"),
        (dict(reference=math.nan), "reference"),
        (dict(counts="3"), "counts"),
        (dict(flags=-1), "flags"),
    ):
        args = {**dict(index=0, reference=0.0, counts=0, pwm=0, flags=0), **kw}
        with pytest.raises(ValueError, match=name):
            rec.append(**args)
    assert len(rec) == 0


# ---------------------------------------------------------------------------- numbers: protocol, run_move


@pytest.mark.parametrize(
    "limits, field", [((1e39, 100.0), "max_accel"), ((300.0, 1e300), "max_velocity")]
)
def test_run_move_above_float32_names_the_field(tmp_path, limits, field):
    rig = _rig(tmp_path)
    prof = plan_trapezoid(1.0, *limits)
    with pytest.raises(ValueError, match=field):
        rig.run_move(prof, pole_placement_pid(32.4, 0.025, 20.0), path=False)
    d = pole_placement_pid(32.4, 0.025, 20.0).discretize(0.005)
    with pytest.raises(ValueError, match="kpd"):
        rig.run_move(
            plan_trapezoid(1.0, 300.0, 100.0), DiscreteGains(1e300, d.kid, d.kdd, d.Ts), path=False
        )
    rig.close()


_INT_FIELDS = [
    (cls, f.name, code)
    for cls in (
        P.SetPlant,
        P.SetGains,
        P.SetLimits,
        P.Plan,
        P.Run,
        P.Step,
        P.Telemetry,
        P.EndOfRun,
        P.PlanInfo,
        P.Nack,
    )
    for f, code in zip(__import__("dataclasses").fields(cls), P._field_codes(cls.FORMAT))
]


def _base(cls):
    vals = {"f": 1.5, "B": 1, "H": 7, "I": 9, "i": -3, "h": -3}
    return {
        f.name: vals[c]
        for f, c in zip(__import__("dataclasses").fields(cls), P._field_codes(cls.FORMAT))
    }


@given(
    st.sampled_from(_INT_FIELDS), st.one_of(st.integers(-(2**70), 2**70), st.floats(allow_nan=True))
)
def test_protocol_field_out_of_range_is_named_or_round_trips(field, value):
    cls, name, code = field
    kw = dict(_base(cls), **{name: value})
    try:
        frame = P.encode(cls(**kw))
    except P.ProtocolError as exc:
        assert name in str(exc)
        if code == "f":
            assert (
                isinstance(value, int)
                or math.isfinite(value)
                and (abs(value) > 3.4028234663852886e38 or 0 < abs(value) < 1e-44)
            )
        else:
            lo, hi = P._INT_RANGES[code]
            assert not isinstance(value, int) or not lo <= value <= hi
        return
    back = getattr(P.parse(P.Decoder().feed(frame)[0]), name)
    if code == "f":
        assert (
            back == pytest.approx(float(value), rel=1e-7)
            or (math.isnan(value) and math.isnan(back))
            or (math.isinf(value) and back == value)
        )
    else:
        assert back == value


def test_protocol_wrong_types_are_named():
    with pytest.raises(ValueError, match="counts_per_rev"):
        P.encode(P.SetPlant(32.4, 0.025, 12.0, 448.5))
    with pytest.raises(ValueError, match="planner"):
        P.encode(P.Plan(1.0, None))
    with pytest.raises(ValueError, match="name"):
        P.encode(P.HelloReply(1, 0, 0, 0, 0, 1000, 1023, "x" * 17))
    with pytest.raises(ValueError, match="msg_type"):
        P.encode_frame(math.nan, 0)
    with pytest.raises(TypeError, match="data"):
        P.Decoder().feed(None)
    with pytest.raises(ValueError, match="distance.*arrive as 0"):
        P.encode(P.Plan(1e-300, 0))  # would reach the device as a zero move


# ---------------------------------------------------------------------------- numbers: planners


@pytest.mark.parametrize("planner", [plan_sine_jerk, plan_sine_jerk_optimal, plan_scurve])
@pytest.mark.parametrize("name", ["max_jerk", "max_accel", "max_velocity"])
@pytest.mark.parametrize("distance", [1.0, 1e300, 1e-300])
def test_tiny_limits_give_a_finite_plan_or_a_named_error(planner, name, distance):
    kw = dict(distance=distance, max_jerk=2000.0, max_accel=300.0, max_velocity=100.0)
    kw[name] = 1e-300
    try:
        p = planner(**kw)
    except ValueError as exc:
        assert name in str(exc) and "distance" in str(exc)
        return
    assert math.isfinite(p.duration) and p.duration > 0
    assert all(math.isfinite(t) and t >= 0 for t in p.phase_times)


def test_sine_jerk_tiny_accel_is_a_value_error_not_zero_division():
    with pytest.raises(ValueError, match="max_accel=1e-300"):
        plan_sine_jerk(1.0, 2000.0, 1e-300, 100.0)


@given(
    st.floats(-1e308, 1e308),
    st.floats(1e-308, 1e308),
    st.floats(1e-308, 1e308),
    st.floats(1e-308, 1e308),
)
def test_planners_never_return_a_non_finite_plan(d, J, A, V):
    for plan in (
        lambda: plan_sine_jerk(d, J, A, V),
        lambda: plan_sine_jerk_optimal(d, J, A, V),
        lambda: plan_scurve(d, J, A, V),
        lambda: plan_trapezoid(d, A, V),
    ):
        try:
            p = plan()
        except ValueError as exc:
            assert "no finite plan" in str(exc)
            continue
        assert math.isfinite(p.duration) and (d == 0 or p.duration > 0)


def test_plan_batch_refuses_non_finite_plans_and_huge_sizes():
    for engine in ("numpy", "numba"):
        pytest.importorskip("numba") if engine == "numba" else None
        with pytest.raises(ValueError, match="move 1"):
            plan_batch("scurve", [1.0, 1e300], 2000.0, [300.0, 1e-300], 100.0, engine=engine)
    with pytest.raises(ValueError, match="MAX_BATCH_MOVES"):
        plan_batch("scurve", np.broadcast_to(1.0, (MAX_BATCH_MOVES + 1,)), 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="max_jerk"):
        plan_batch("scurve", [1.0, 2.0], [], 300.0, 100.0)


def test_discretize_refuses_huge_sample_counts():
    p = plan_sine_jerk(1.0, 2000.0, 300.0, 100.0)
    with pytest.raises(ValueError, match="MAX_SAMPLES"):
        _within(10, lambda: p.discretize(1e-300))
    with pytest.raises(ValueError, match="t_end"):
        _within(10, lambda: p.discretize(0.005, t_end=1e9))
    with pytest.raises(ValueError, match="t_end"):
        p.discretize(0.005, t_end=-1.0)
    assert len(p.discretize(p.duration / (MAX_SAMPLES // 2)).t) > 1
    with pytest.raises(ValueError, match="Ts"):
        plan_trapezoid(1.0, 300.0, 100.0).discretize(1e300)


def test_batch_profile_index_is_checked():
    b = plan_batch("scurve", [1.0, 2.0], 2000.0, 300.0, 100.0)
    assert b.profile(1).distance == 2.0
    for bad in (2, -1, -3, 1.5, "0", None):  # issue 31: no negative index from the end
        with pytest.raises(ValueError, match=r"\bi\b"):
            b.profile(bad)


# ------------------------------------------------------------ numbers: fpga, plant, piezo, hysteresis


def test_fpga_divider_refuses_instead_of_hanging():
    from jerklab.fpga import MAX_EDGES, YangSCurve, divider_edges, published_divider

    for fn in (divider_edges, published_divider):
        with pytest.raises(ValueError, match="p_end"):
            _within(10, lambda: fn([1, 100], [1000, 500], 10**9))
        with pytest.raises(ValueError, match="bits"):
            _within(10, lambda: fn([1, 100], [1000, 500], 50, bits=2**64))
        with pytest.raises(ValueError, match="starts"):
            fn([1, math.nan], [1000, 500], 50)
        with pytest.raises(ValueError, match="values"):
            fn([1, 100], ["a", "b"], 50)
    assert MAX_EDGES >= 100_000
    with pytest.raises(ValueError, match="bits"):
        _within(10, lambda: YangSCurve(bits=2**64))
    with pytest.raises(ValueError, match="step_um"):
        YangSCurve(step_um=10**9)
    with pytest.raises(ValueError, match="accel_time"):
        YangSCurve(accel_time=1e9)


def test_plant_quantize_and_measure_are_checked():
    from jerklab.plant import measure_angle, quantize_voltage

    with pytest.raises(ValueError, match="supply_voltage"):
        _within(10, lambda: quantize_voltage([1.0], -1.0, 10))  # was an endless loop
    with pytest.raises(ValueError, match="u"):
        quantize_voltage([math.nan], 12.0, 10)
    with pytest.raises(ValueError, match="pwm_bits"):
        quantize_voltage([1.0], 12.0, 2**64)
    with pytest.raises(ValueError, match="counts_per_rad"):
        measure_angle([1.0], 0.0)
    with pytest.raises(ValueError, match="theta"):
        DCMotor().measure(["a"])
    with pytest.raises(ValueError, match="x"):
        DCMotor().step_state([], 1.0, 0.005)
    with pytest.raises(ValueError, match="Ts"):
        DCMotor().discrete_tf(1e300)
    np.testing.assert_array_equal(quantize_voltage([13.0, -13.0], 12.0, 10), [12.0, -12.0])


def test_piezo_and_hysteresis_arguments_are_named():
    from jerklab import hysteresis as H
    from jerklab import piezo as Z

    with pytest.raises(TypeError, match="model"):
        Z.simulate(None, [0.0, 1.0])
    with pytest.raises(ValueError, match="Ts"):
        Z.simulate(Z.PZTModel(), [0.0, 1.0], Ts="2e-4")
    with pytest.raises(ValueError, match="Ts"):
        Z.PZTModel().zoh(1e300)
    with pytest.raises(ValueError, match="freq_scale"):
        Z.PZTModel().perturbed(1e-300)
    with pytest.raises(ValueError, match="k_r"):
        _within(10, lambda: Z.energy_optimal_return(-6.0, 10**9))
    with pytest.raises(ValueError, match="observer_speedup"):
        Z.pole_placement_gains(observer_speedup=1e9)
    with pytest.raises(ValueError, match="n"):
        _within(10, lambda: H.Preisach.uniform(-1.0, 1.0, n=10**9))
    with pytest.raises(ValueError, match="points_per_curve"):
        H.forc_experiment(H.Preisach.uniform(-1, 1, 5), -1, 1, 10, 10**9)
    with pytest.raises(ValueError, match="u"):
        H.Preisach.uniform(-1.0, 1.0, n=5).peek("0.5")
    with pytest.raises(ValueError, match="x"):
        as_finite_array("x", ["1", "2"])


# ----------------------------------------------------------------------------------------------
# h-probe2: the remaining probe cases (plant kernels, piezo, controller, ident); each failed before
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, bad",
    [
        ("theta", math.nan),
        ("omega", "1.0"),
        ("v", None),
        ("v", [1.0, 2.0]),
        ("fc", -1.0),
        ("K", 0.0),
        ("K", -1.0),
        ("tau", 0.0),
        ("tau", math.inf),
        ("dt", -1.0),
        ("dt", math.nan),
    ],
)
def test_probe2_advance_scalar_names_the_bad_argument(name, bad):
    from jerklab.plant import advance_scalar

    kw = dict(theta=0.0, omega=0.0, v=1.0, fc=0.0, K=32.4, tau=0.025, dt=0.005)
    kw[name] = bad
    with pytest.raises(ValueError, match=name):  # was a numba TypingError, ZeroDivisionError or NaN
        advance_scalar(**kw)


@pytest.mark.parametrize(
    "name, bad",
    [
        ("v", "1.0"),
        ("v", [0.0, math.inf]),
        ("K", [32.4, 0.0]),
        ("K", "3"),
        ("tau", -0.025),
        ("dt", [-1.0]),
        ("fc", [-0.1]),
        ("theta", None),
    ],
)
def test_probe2_advance_names_the_bad_argument(name, bad):
    from jerklab.plant import advance

    kw = dict(theta=0.0, omega=0.0, v=1.0, fc=0.0, K=32.4, tau=0.025, dt=0.005)
    kw[name] = bad
    with pytest.raises(ValueError, match=name):  # was accepted (text parsed, K <= 0) or NaN out
        advance(**kw)


def test_probe2_checked_kernels_still_agree_with_the_zoh_closed_form():
    # independent: the friction-free step is the ZOH solution of K/(s(tau s + 1))
    from jerklab.plant import advance, advance_scalar

    K, tau, dt, v, om0 = 32.4, 0.025, 0.005, 2.5, 3.0
    a = math.exp(-dt / tau)
    om1 = a * om0 + K * (1 - a) * v
    th1 = tau * (1 - a) * om0 + K * (dt - tau * (1 - a)) * v
    assert np.allclose(advance_scalar(0.0, om0, v, 0.0, K, tau, dt), (th1, om1), rtol=1e-12)
    th, om = advance(0.0, [om0, om0], [v, v], 0.0, [K, K], tau, dt)
    assert np.allclose(th, th1, rtol=1e-12) and np.allclose(om, om1, rtol=1e-12)


def test_probe2_piezo_refuses_unreachable_levels_up_front():
    from jerklab import piezo as Z

    # was RuntimeError("no feasible horizon") after a search over 400 horizons
    with pytest.raises(ValueError, match="b must lie within"):
        _within(10, lambda: Z.shape_return(1e300))
    with pytest.raises(ValueError, match="b must lie within"):
        _within(10, lambda: Z.energy_optimal_return(1e300, 40))
    with pytest.raises(ValueError, match="scan_start"):
        _within(10, lambda: Z.shape_rampup(scan_start=1e300))
    # the sweep still reports an unreachable y(T) as NaN (its documented answer)
    t = Z.rampup_time_vs_scan_start([1e300])
    assert np.isnan(t[0])


def test_probe2_controller_names_the_parameter():
    from jerklab import controller as C

    with pytest.raises(ValueError, match="wn"):  # was "ki must be finite, got inf"
        C.velocity_pole_placement_pid(32.4, 0.025, 1e300)
    with pytest.raises(ValueError, match="tau"):  # the singular-design message did not name tau
        C.discrete_pole_placement_pid(32.4, 1e300, 20.0)
    with pytest.raises(ValueError, match="Ts"):  # was a loop with inf polynomials
        C.PositionLoop(32.4, 0.025, pole_placement_pid(32.4, 0.025, 20.0), Ts=1e300)
    c = C.DigitalController(pole_placement_pid(32.4, 0.025, 20.0).discretize(0.005))
    for name in ("ref_position", "ref_velocity", "ref_accel", "measured_position"):
        kw = dict(ref_position=0.1, ref_velocity=0.0, ref_accel=0.0, measured_position=0.0)
        kw[name] = "1.0"
        with pytest.raises(TypeError, match=name):  # text was parsed by float()
            c.step(**kw)


def test_probe2_ident_inputs_refuse_huge_records_up_front():
    from jerklab import ident as I

    for f in (I.step_input, I.prbs):
        with pytest.raises(ValueError, match="MAX_INPUT_SAMPLES"):  # was a raw MemoryError
            _within(10, lambda: f(1e9, 0.005, 6.0))
        with pytest.raises(ValueError, match="Ts"):  # was "Maximum allowed dimension"
            _within(10, lambda: f(1.0, 1e-300, 6.0))
        with pytest.raises(ValueError, match="Ts"):  # said only "duration"
            f(1.0, 1e9, 6.0)
    with pytest.raises(ValueError, match="clock_period"):  # was OverflowError / MemoryError
        _within(10, lambda: I.prbs(1.0, 0.005, 6.0, clock_period=1e300))
    assert I.step_input(1.0, 0.005, 6.0).size == 200


def test_probe2_fit_dc_motor_refuses_a_sample_period_it_cannot_represent():
    from jerklab import ident as I

    u = np.r_[np.zeros(10), 6.0 * np.ones(200)]
    th = I.simulate_dc_motor(32.4, 0.025, 0.005, u)[: u.size]
    for Ts in (1e-300, 1e300):  # were K_std = NaN / tau_std = inf, no warning
        with pytest.raises(ValueError, match="Ts"):
            I.fit_dc_motor(u, th, Ts)
    f = I.fit_dc_motor(u, th, 0.005)  # the exact simulation is fitted back
    assert f.K == pytest.approx(32.4, rel=1e-6) and f.tau == pytest.approx(0.025, rel=1e-6)


def test_probe2_widgets_and_connect_refuse_impossible_values():
    from jerklab import rig as RG
    from jerklab import tuning as W

    for name in ("max_radius", "desired_radius"):  # |z| < 0 was classified as a verdict
        kw = dict(max_radius=0.9, desired_radius=0.9)
        kw[name] = -1.0
        with pytest.raises(ValueError, match=name):
            W.stability_verdict(**kw)
    with pytest.raises(ValueError, match="Ts"):  # was numpy LinAlgError
        W.compute_pole_placement(Ts=1e300, simulate_move=False)
    with pytest.raises(ValueError, match="hello_timeout"):  # 0 silently meant the default
        RG.connect(None, progress=False, link=RG.Link(hello_timeout=0))
    with pytest.raises(
        ValueError, match="timeout"
    ):  # was RigTimeoutError "no reply within 1e-300 s"
        RG.connect(None, progress=False, link=RG.Link(timeout=1e-300))
    RG.connect(
        None, progress=False, link=RG.Link(timeout=RG.MIN_TIMEOUT * 100, hello_timeout=1.0)
    ).close()


@pytest.mark.parametrize(
    "kw", [dict(wn=1e9), dict(sigma_ratio=1e9), dict(sigma_ratio=1e300), dict(Ts=1e9)]
)
def test_probe2_tuning_advice_far_above_the_sliders_answers_at_once(kw):
    from jerklab import tuning as T

    # was a hang: the advice listed every slider step below wn = 1e9 (1e9 values)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r = _within(20, lambda: T.compute_pole_placement(simulate_move=False, **kw))
    assert r.level == "unstable"
    for s in T.advise(
        T.paper.MOTOR_K,
        T.paper.MOTOR_TAU,
        r.params["zeta"],
        r.params["wn"],
        r.params["sigma_ratio"],
        r.params["Ts"],
        r.params["design"],
    ):
        lo, hi, _ = (
            T.SLIDER_RANGES.get(s.change, (-math.inf, math.inf, 0))
            if s.change != "Ts"
            else (T.SLIDER_RANGES["Ts_ms"][0] * 1e-3, T.SLIDER_RANGES["Ts_ms"][1] * 1e-3, 0)
        )
        if s.change != "design":
            assert lo - 1e-12 <= s.value <= hi + 1e-12 and s.max_radius < 1.0
