"""The rig client and the virtual rig: results, recordings, errors (in process)."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest

from jerklab import protocol as P
from jerklab.controller import DigitalController, Feedforward, pole_placement_pid
from jerklab.planner import plan_sine_jerk
from jerklab.plant import DCMotor
from jerklab.rig import (
    Link,
    Recording,
    RigCommandError,
    RigTimeoutError,
    UnknownPortError,
    VirtualDevice,
    VirtualSerial,
    connect,
)
from jerklab.rig.client import Rig

K, TAU = 32.4, 0.025
CPR = 448 / (2 * math.pi)


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


@pytest.fixture
def rig(tmp_path):
    r = connect(recordings=tmp_path, progress=False)
    yield r
    r.close()


def _move():
    return plan_sine_jerk(
        10 * math.pi, 2e4, 300.0, 100.0
    )  # docs/THEORY.md example (Stojčić eq. 4): T = 47 ms


def test_connect_virtual_identity(rig):
    assert rig.is_virtual and rig.name == "jerklab-virtual"
    assert rig.info.protocol_version == P.PROTOCOL_VERSION
    assert rig.info.pwm_max == 1023 and rig.info.tick_us == 1000
    assert rig.counts_per_rev == 448 and rig.supply_voltage == 12.0


def test_step_matches_closed_form(rig):
    """Open-loop step vs the analytic ramp of eq. 1: theta = K V (t - tau (1 - e^{-t/tau}))."""
    rec = rig.step(6.0, 0.5, rest=0.05)
    assert len(rec) == 110 and rec.metadata["status"] == "complete"
    assert np.array_equal(rec.index, np.arange(110))
    v = round(6.0 / 12.0 * 1023) / 1023 * 12.0  # the PWM-quantized voltage
    assert np.all(rec.control[:10] == 0) and np.all(rec.counts[:10] == 0)
    assert np.all(rec.control[10:] == pytest.approx(v))
    t = rec.time - 0.05
    theta = np.where(t > 0, K * v * (t - TAU * (1 - np.exp(-t / TAU))), 0.0)
    # the encoder holds floor(theta * cpr): reading within one count below the truth
    assert np.all(rec.position <= theta + 1e-9)
    assert np.all(rec.position > theta - 1.0 / CPR - 1e-9)
    assert rec.reference.max() == 0.0


def test_step_identifies_the_hidden_motor(tmp_path):
    """A step from rest on a virtual motor that is not the paper's: the fit finds it."""
    from jerklab.ident import fit_dc_motor

    with connect(recordings=tmp_path, progress=False, device=DCMotor(K=27.5, tau=0.034)) as r:
        rec = r.step(6.0, 0.6)
    fit = fit_dc_motor(rec.control, rec.position, rec.Ts, method="pem")
    assert fit.K == pytest.approx(27.5, rel=0.01) and fit.tau == pytest.approx(0.034, rel=0.03)
    from jerklab.ident import IdentData

    data = IdentData.from_recording(Recording.load(rec.csv_path))  # from the files on disk
    assert data.Ts == 0.005 and len(data.u) == len(rec)


def _spec_run(profile, kpd, kid, kdd, Ts, n, vmax=12.0):
    """PROTOCOL.md "Device state machine", RUN, written out independently of the rig code:
    float32 parameters from the wire, exact ZOH plant, floor encoder, lround PWM; the PWM of
    sample k is in effect ``delay`` after the encoder was read (the board's computation delay,
    modelled by the virtual rig, plus the mean wait for Timer1's TOP where the
    double-buffered OCR1A takes the new duty), the previous one driving the
    motor until then."""
    from jerklab.rig.virtual import VirtualDevice

    delay = VirtualDevice.DUTY_DELAY
    kpd, kid, kdd = f32(kpd), f32(kid), f32(kdd)
    Kf, tf = f32(K), f32(TAU)

    def zoh(dt):
        a = math.exp(-dt / TAU)
        return (
            np.array([[1.0, TAU * (1 - a)], [0.0, a]]),
            np.array([K * (dt - TAU * (1 - a)), K * (1 - a)]),
        )

    (P1, G1), (P2, G2) = zoh(delay), zoh(Ts - delay)
    p_prev = 0
    s = profile.sample(np.arange(n) * Ts)
    x = np.zeros(2)
    i_acc = e_prev = 0.0
    counts, pwms = [], []
    for k in range(n):
        c = math.floor(x[0] * CPR + 1e-9)
        y = c / CPR
        e = s.position[k] - y
        ff = (tf * s.accel[k] + s.velocity[k]) / Kf
        i_new = i_acc + kid * e
        d = kdd * (e - e_prev)
        u = ff + kpd * e + i_new + d
        if abs(u) > vmax:
            if (e > 0) == (u > 0):
                u -= i_new - i_acc
                i_new = i_acc
            u = max(-vmax, min(vmax, u))
        i_acc, e_prev = i_new, e
        p = min(int(math.floor(abs(u) * 1023 / 12.0 + 0.5)), 1023)
        p = p if u >= 0 else -p
        counts.append(c)
        pwms.append(p)
        x = P1 @ x + G1 * (p_prev / 1023 * 12.0)
        x = P2 @ x + G2 * (p / 1023 * 12.0)
        p_prev = p
    return np.array(counts), np.array(pwms)


def test_move_follows_the_protocol_spec(rig):
    prof = _move()
    g = pole_placement_pid(K, TAU, wn=20.0).discretize(0.005)
    rec = rig.run_move(prof, g, Ts=0.005, settle=0.2)
    n = rec.metadata["plan"]["n_samples"] + rec.metadata["settle_samples"]
    assert len(rec) == n == rec.metadata["device_samples"]
    assert np.array_equal(rec.index, np.arange(n))
    counts, pwms = _spec_run(prof, g.kpd, g.kid, g.kdd, 0.005, n)
    # identical up to float64-vs-float32 round-off flipping a rare PWM level
    assert np.mean(rec.pwm == pwms) > 0.98
    assert np.max(np.abs(rec.pwm - pwms)) <= 2
    assert np.max(np.abs(rec.counts - counts)) <= 2
    # it reached the target and the reference is the closed-form profile (float32 on the wire)
    assert rec.reference == pytest.approx(prof.sample(rec.time).position, abs=2e-5)
    assert abs(rec.position[-1] - prof.distance) < 3 / CPR
    assert np.max(np.abs(rec.error)) < 0.05


def test_move_agrees_with_sim(rig):
    """The virtual rig and jerklab.sim.simulate run the same loop on the same motor (with the
    board's computation delay switched off: simulate() writes u at the sampling instant)."""
    from jerklab.sim import simulate

    prof = _move()
    g = pole_placement_pid(K, TAU, wn=20.0).discretize(0.005)
    dev = rig.link.device
    delay, dev.compute_delay = dev.compute_delay, 0.0
    try:
        rec = rig.run_move(prof, g, Ts=0.005, settle=0.2)
    finally:
        dev.compute_delay = delay
    c = DigitalController(g, feedforward=Feedforward(K, TAU), output_limit=12.0)
    sim = simulate(prof, DCMotor(), c, Ts=0.005, t_end=rec.time[-1])
    n = min(len(rec), len(sim.t))
    assert n >= len(rec) - 1
    assert np.max(np.abs(rec.position[:n] - sim.measured[:n])) <= 2.5 / CPR
    assert np.max(np.abs(rec.control[:n] - sim.u_applied[:n])) < 0.1


def test_velocity_loop_and_decimation(rig):
    from jerklab.controller import velocity_pole_placement_pid

    prof = plan_sine_jerk(20.0, 5e3, 200.0, 60.0)
    g = velocity_pole_placement_pid(K, TAU, wn=60.0).discretize(0.005)
    rec = rig.run_move(prof, g, Ts=0.005, decimation=2, settle=0.1)
    assert rec.metadata["gains"]["loop"] == "velocity"
    assert np.all(np.diff(rec.index) == 2) and rec.metadata["lost_samples"] == 0
    # a velocity loop follows the speed; the angle drifts a little but ends near the target
    assert abs(rec.position[-1] - 20.0) < 0.5


def test_recording_on_disk_while_and_after(rig, tmp_path):
    prof = _move()
    g = pole_placement_pid(K, TAU, wn=20.0)
    rec = rig.run_move(prof, g, Ts=0.005)  # continuous gains: discretized at Ts
    assert rec.csv_path.parent == tmp_path and rec.csv_path.exists() and rec.json_path.exists()
    meta = json.loads(rec.json_path.read_text())
    assert meta["status"] == "complete" and meta["n_samples"] == len(rec)
    assert meta["device"]["firmware_version"] == rig.firmware_version
    assert meta["gains"]["kpd"] == pytest.approx(g.discretize(0.005).kpd)
    assert meta["limits"]["max_voltage"] == 12.0 and meta["profile"]["kind"] == "sine_jerk"
    back = Recording.load(rec.csv_path)
    for name in ("time", "reference", "position", "control", "counts", "pwm"):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name), err_msg=name)
    copy = rec.save(tmp_path / "copy")
    again = Recording.load(copy)
    np.testing.assert_array_equal(again.position, rec.position)
    assert again.metadata["gains"] == meta["gains"]


def test_recording_dir_from_env(tmp_path, monkeypatch):
    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path / "env"))
    with connect(progress=False) as r:
        rec = r.step(1.0, 0.05)
    assert rec.csv_path.parent == tmp_path / "env"


def test_progress_bar(rig, capsys):
    rig.step(2.0, 0.1, progress=True)
    out = capsys.readouterr().out
    assert "step [" in out and "30/30 samples" in out and "complete" in out


def test_host_side_validation(rig):
    prof = _move()
    g = pole_placement_pid(K, TAU, wn=20.0)
    with pytest.raises(ValueError, match="Ts must be a multiple"):
        rig.run_move(prof, g, Ts=0.0025)
    with pytest.raises(ValueError, match="voltage"):
        rig.step(float("nan"), 0.1)
    with pytest.raises(ValueError, match="max_voltage"):
        rig.step(13.0, 0.1)
    with pytest.raises(ValueError, match="seconds"):
        rig.step(1.0, -1)
    with pytest.raises(ValueError, match="rest"):
        rig.step(1.0, 0.1, rest=-0.1)
    with pytest.raises(ValueError, match="discretized for Ts"):
        rig.run_move(prof, g.discretize(0.01), Ts=0.005)
    with pytest.raises(ValueError, match="profile"):
        rig.run_move("not a profile", g)
    # a synchronized profile is no planner's own result: the host sends its segments (protocol 5)
    rec = rig.run_move(prof.synchronized(0.005), g, Ts=0.005, path=False)
    assert rec.metadata["status"] == "complete" and rec.metadata["plan"]["planned_by"] == "host"


def test_device_nack_names_the_parameter(rig):
    with pytest.raises(RigCommandError, match=r"SetGains.*BAD_VALUE.*'Ts_us'"):
        rig._request(P.SetGains(1.0, 0.0, 0.0, 1500))
    with pytest.raises(RigCommandError, match=r"'max_voltage'"):
        rig._request(P.SetLimits(1e4, 100.0, 50.0, 30.0, 1000))
    with pytest.raises(RigCommandError, match=r"'distance'"):
        rig._request(P.Plan(float("nan"), 0), replies=(P.MsgType.PLAN_INFO,))
    with pytest.raises(RigCommandError, match="NOT_READY"):
        rig._request(P.Run(0, 1))


def test_unknown_ports():
    with pytest.raises(UnknownPortError, match="/dev/no-such-rig"):
        connect("/dev/no-such-rig")
    with pytest.raises(UnknownPortError, match="nosuch://x"):
        connect("nosuch://x")
    with pytest.raises(UnknownPortError, match="42"):
        connect(42)
    with pytest.raises(UnknownPortError, match="socket://127.0.0.1:1"):
        connect("socket://127.0.0.1:1")


def test_port_that_is_no_rig_times_out():
    # loop:// echoes our own HELLO back: a port that opens but has no jerklab rig behind it
    with pytest.raises(RigTimeoutError, match="no jerklab rig answered HELLO"):
        connect("loop://", link=Link(hello_timeout=0.3))


def test_simavr_dispatch(monkeypatch, tmp_path):
    import sys
    import types

    monkeypatch.setitem(sys.modules, "jerklab.rig.simavr", None)  # module absent
    with pytest.raises(UnknownPortError, match="simavr"):
        connect("simavr")
    # a launcher that serves the virtual rig on a pty stands in for the simulated Uno
    from jerklab.rig.server import DeviceServer

    closed = []

    class Launch:
        def __init__(self):
            self.server = DeviceServer(speed=None)
            self.port = self.server.start_pty()

        def close(self):
            closed.append(True)
            self.server.close()

    fake = types.ModuleType("jerklab.rig.simavr")
    fake.launch = Launch
    monkeypatch.setitem(sys.modules, "jerklab.rig.simavr", fake)
    with connect("simavr", recordings=tmp_path, progress=False) as r:
        assert r.name == "jerklab-virtual" and r.port.startswith("/dev/pts/")
        assert len(r.step(1.0, 0.05, rest=0)) == 10
    assert closed == [True]


def test_timeout_mid_run_keeps_samples(tmp_path):
    link = VirtualSerial(VirtualDevice(), timeout=0.05, freeze_after=2000)
    r = Rig(link, "frozen-virtual", timeout=0.3, progress=False, recordings=tmp_path)
    with pytest.raises(RigTimeoutError, match=r"no data from the rig .* saved in") as ei:
        r.run_move(_move(), pole_placement_pid(K, TAU, wn=20.0), Ts=0.005)
    rec = Recording.load(sorted(tmp_path.glob("*_move.csv"))[-1])
    assert rec.metadata["status"] == "timeout" and "no data" in rec.metadata["error"]
    assert 50 < len(rec) < 100 and np.array_equal(rec.index, np.arange(len(rec)))
    assert str(rec.csv_path) in str(ei.value)


def test_pulled_cable_in_process_keeps_samples(tmp_path):
    from jerklab.rig import RigConnectionError

    link = VirtualSerial(VirtualDevice(), timeout=0.05, pull_cable_after=3000)
    r = Rig(link, "virtual", progress=False, recordings=tmp_path)
    with pytest.raises(RigConnectionError, match="connection lost"):
        r.run_move(_move(), pole_placement_pid(K, TAU, wn=20.0), Ts=0.005)
    rec = Recording.load(sorted(tmp_path.glob("*_move.csv"))[-1])
    assert rec.metadata["status"] == "disconnected" and len(rec) > 100


def test_corrupted_link_resyncs(tmp_path):
    """Noise on the wire: frames are dropped and counted, the run completes."""
    rng = np.random.default_rng(3)

    class Noisy(VirtualSerial):
        def read(self, size=1):
            data = bytearray(super().read(size))
            for i in range(len(data)):
                if rng.random() < 2e-3:
                    data[i] ^= 1 << int(rng.integers(8))
            return bytes(data)

    r = Rig(
        Noisy(VirtualDevice(), timeout=0.05),
        "noisy",
        progress=False,
        recordings=tmp_path,
        hello_timeout=2.0,
    )
    with pytest.warns(RuntimeWarning, match=r"noisy: \d+ telemetry samples were lost"):
        rec = r.run_move(_move(), pole_placement_pid(K, TAU, wn=20.0), Ts=0.005, settle=0.1)
    md = rec.metadata
    assert md["status"] == "complete"
    assert md["host_dropped_frames"] > 0 and md["lost_samples"] > 0
    assert len(rec) + md["lost_samples"] == md["device_samples"]
    assert np.all(np.diff(rec.index) >= 1)


# ----------------------------------------------------------------------------- the device alone


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _talk(dev, msg, seq=1):
    dev.receive(P.encode(msg, seq))
    return [P.parse(f) for f in P.Decoder().feed(dev.read_output())]


def test_device_state_machine_and_watchdog():
    clock = _Clock()
    dev = VirtualDevice(clock=clock)
    assert isinstance(_talk(dev, P.Hello())[0], P.HelloReply)
    assert _talk(dev, P.Run(0, 1))[0] == P.Nack(P.MsgType.RUN, P.ErrorCode.NOT_READY, 0xFF)
    dev.receive(P.encode_frame(0x42, 3, b""))
    dev.receive(P.encode_frame(P.MsgType.SET_PLANT, 4, b"\x00"))
    dev.receive(P.encode_frame(P.MsgType.ACK, 5, b"\x01"))
    nacks = [P.parse(f) for f in P.Decoder().feed(dev.read_output())]
    assert [n.error for n in nacks] == [
        P.ErrorCode.UNKNOWN_TYPE,
        P.ErrorCode.BAD_LENGTH,
        P.ErrorCode.UNKNOWN_TYPE,
    ]
    assert _talk(dev, P.SetGains(10.0, 0.1, 50.0, 5000))[0] == P.Ack(P.MsgType.SET_GAINS)
    assert _talk(dev, P.SetLimits(2e4, 300.0, 100.0, 12.0, 200))[0] == P.Ack(P.MsgType.SET_LIMITS)
    info = _talk(dev, P.Plan(10 * math.pi, 0))[0]
    assert info.duration == pytest.approx(_move().duration, rel=1e-6)
    assert _talk(dev, P.Run(0, 1))[0] == P.Ack(P.MsgType.RUN)
    assert _talk(dev, P.SetGains(1.0, 0.0, 0.0, 5000))[0].error == P.ErrorCode.BUSY
    for _ in range(10):
        dev.tick()
    clock.t = 0.15  # host silent 150 ms < 200 ms: still running
    dev.tick()
    assert dev.active
    clock.t = 0.25  # 250 ms > 200 ms: the watchdog stops the motor
    dev.tick()
    out = [P.parse(f) for f in P.Decoder().feed(dev.read_output())]
    assert isinstance(out[-1], P.EndOfRun) and out[-1].reason == P.EndReason.HOST_TIMEOUT
    assert out[-1].samples == 11 and not dev.active and dev.pwm == 0
    assert sum(isinstance(m, P.Telemetry) for m in out) == 11


def test_device_stop_mid_run():
    dev = VirtualDevice()
    _talk(dev, P.SetGains(10.0, 0.1, 50.0, 5000))
    _talk(dev, P.Plan(5.0, 0))
    _talk(dev, P.Run(0, 1))
    dev.tick()
    dev.tick()
    assert len(P.Decoder().feed(dev.read_output())) == 2  # two TELEMETRY frames
    out = _talk(dev, P.Stop(), seq=9)
    assert out[0] == P.Ack(P.MsgType.STOP)
    assert any(
        isinstance(m, P.EndOfRun) and m.reason == P.EndReason.STOPPED and m.samples == 2
        for m in out
    )


def test_load_keeps_whole_rows_of_a_cut_file(tmp_path):
    """A crash mid-write leaves a partial last row: loading keeps every whole row."""
    rec = Recording(
        {"kind": "move", "Ts": 0.005, "counts_per_rad": CPR, "volts_per_pwm": 12 / 1023},
        tmp_path / "cut",
    )
    for k in range(50):
        rec.append(k, 0.01 * k, k, 10 * k, 0)
    rec.flush()  # no finish(): the sidecar still says "recording"
    text = rec.csv_path.read_text()
    rec.csv_path.write_text(text[:-7])  # cut inside the last row
    with pytest.warns(UserWarning, match="still says 'recording'"):
        back = Recording.load(tmp_path / "cut.json")
    assert back.metadata["status"] == "incomplete" and len(back) == 49
    np.testing.assert_array_equal(back.counts, np.arange(49))
    assert back.control[10] == pytest.approx(100 * 12 / 1023)


def test_docstring_examples():
    import doctest

    import jerklab.rig
    import jerklab.rig.recording

    for mod in (P, jerklab.rig, jerklab.rig.recording):
        result = doctest.testmod(mod)
        assert result.failed == 0 and result.attempted > 0, mod.__name__


def test_connect_stops_a_leftover_run(tmp_path):
    dev = VirtualDevice()
    dev.receive(
        P.encode(P.SetGains(10.0, 0.1, 50.0, 5000))
        + P.encode(P.Plan(50.0, 0))
        + P.encode(P.Run(0, 1))
    )
    dev.tick()
    assert dev.active
    r = Rig(VirtualSerial(dev, timeout=0.05), "virtual", progress=False, recordings=tmp_path)
    assert not dev.active and dev.pwm == 0
    assert len(r.step(1.0, 0.02, rest=0)) == 4


@pytest.mark.parametrize("kind", ["sine_jerk_optimal", "scurve", "trapezoid"])
def test_other_planners_on_the_virtual_rig(rig, kind):
    from jerklab import planner

    if kind == "trapezoid":
        prof = planner.plan_trapezoid(6.0, 200.0, 40.0)
    else:
        prof = getattr(planner, "plan_" + kind)(6.0, 5e3, 200.0, 40.0)
    rec = rig.run_move(prof, pole_placement_pid(K, TAU, wn=20.0), Ts=0.005, settle=0.2)
    assert rec.metadata["plan"]["duration"] == pytest.approx(prof.duration, rel=1e-5)
    assert rec.reference == pytest.approx(prof.sample(rec.time).position, abs=1e-5)
    assert abs(rec.position[-1] - 6.0) < 3 / CPR


def test_partial_frame_expires_on_both_sides(tmp_path):
    """A truncated frame with a large length must not hold back the next short one."""
    clock = _Clock()
    dev = VirtualDevice(clock=clock)
    long_frame = P.encode(P.SetLimits(2e4, 300.0, 100.0, 12.0, 1000), 1)
    dev.receive(long_frame[:6])  # cut: the device waits for 20 more bytes
    dev.receive(P.encode(P.Hello(), 2))  # arrives at once: still inside the cut frame
    assert dev.read_output() == b""
    clock.t = 0.03  # 30 ms of silence: the partial frame expires
    dev.tick()
    out = [(f.seq, P.parse(f)) for f in P.Decoder().feed(dev.read_output())]
    assert [seq for seq, _ in out] == [2] and isinstance(out[0][1], P.HelloReply)
    assert dev._decoder.stats.truncated == 1

    # host side: garbage that looks like the start of a long frame, then the reply to HELLO
    class Prefixed(VirtualSerial):
        first = True

        def read(self, size=1):
            if self.first:
                self.first = False
                return b"\xa5\x5a\x40\x90"  # a frame of len 64 that never comes
            return super().read(size)

    r = Rig(
        Prefixed(VirtualDevice(), timeout=0.05),
        "virtual",
        progress=False,
        recordings=tmp_path,
        hello_timeout=1.0,
    )
    assert r.name == "jerklab-virtual"
    assert r._decoder.stats.truncated == 1
    assert r._seq == 2  # one HELLO and the STOP: the first reply was not held back


def test_load_names_a_corrupt_sidecar(tmp_path):
    """A sidecar that is not JSON raises a clear error naming it and pointing at the samples."""
    rec = Recording(
        {"kind": "move", "Ts": 0.005, "counts_per_rad": CPR, "volts_per_pwm": 12 / 1023},
        tmp_path / "bad",
    )
    for k in range(5):
        rec.append(k, 0.0, k, 0, 0)
    rec.finish("complete")
    rec.json_path.write_bytes(b"\xa5Z\x11" + rec.json_path.read_bytes())
    with pytest.raises(ValueError, match=r"bad\.json is not a valid JSON sidecar.*bad\.csv"):
        Recording.load(tmp_path / "bad.csv")


@pytest.mark.slow  # seconds of runs in real time
def test_a_paced_virtual_rig_runs_in_real_time_after_a_pause():
    """At ``speed`` a run lasts its model time over the speed even when the rig idled before
    it (the idle time is no credit to run through as fast as the host reads)."""
    import time

    from jerklab.rig.options import Device

    speed = 2.0
    r = connect(device=Device(speed=speed), progress=False)
    try:
        profile = plan_sine_jerk(10.0, 5000.0, 300.0, 60.0)  # 0.54 s
        gains = pole_placement_pid(K, TAU, wn=20.0).discretize(0.005)
        time.sleep(1.0)  # idle: 2 s of model time at this speed
        t0 = time.monotonic()
        rec = r.run_move(profile, gains, path=False, settle=0.25)
        took = time.monotonic() - t0
    finally:
        r.close()
    model = len(rec) * rec.Ts
    assert rec.metadata["status"] == "complete" and model > 0.7
    assert took >= 0.9 * model / speed, (took, model)
