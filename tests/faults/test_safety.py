"""Fault injection for the safety stops and the virtual device's firmware-like behaviour
(issue 12): a reversed or disconnected encoder and a tracking-error limit stop the motor in
the firmware core (host build) and in the virtual device alike; unstable designs are refused;
partial frames expire while idle; plans are streamed and bounded; a host that does not read
loses whole telemetry frames, counted; a second TCP client is told the rig is busy; a client
that leaves stops its run; sessions longer than 256 commands wrap the sequence number."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import time
import tracemalloc

import numpy as np
import pytest
from conftest import require_tool
from hypothesis import given, settings
from hypothesis import strategies as st

from jerklab import protocol as P
from jerklab.controller import (
    discrete_pole_placement_pid,
    is_stable,
    max_pole_radius,
    pole_placement_pid,
)
from jerklab.planner import plan_sine_jerk
from jerklab.rig import Rig, RigRunError, VirtualDevice, VirtualSerial
from jerklab.rig.client import RigBusyError, RigCommandError, UnstableDesignError

K, TAU, VS = 32.4, 0.025, 12.0
CPR = 448 / (2 * math.pi)
f32 = lambda x: float(np.float32(x))  # noqa: E731


@pytest.fixture(scope="module")
def host_driver():
    require_tool("g++", "make")
    from jerklab.rig.simavr import build_firmware

    return build_firmware("host")["host"]


@pytest.fixture(scope="module", autouse=True)
def _forget_simavr_module():
    """Leave ``jerklab.rig.simavr`` un-imported afterwards (tests/test_rig.py expects it)."""
    yield
    sys.modules.pop("jerklab.rig.simavr", None)
    import jerklab.rig

    if hasattr(jerklab.rig, "simavr"):
        delattr(jerklab.rig, "simavr")


# ----------------------------------------------------------------------------- two devices, one script


def _gains(wn=20.0, Ts=0.005):
    g = pole_placement_pid(K, TAU, wn).discretize(Ts)
    return f32(g.kpd), f32(g.kid), f32(g.kdd)


def _config(g, max_error=0.5, runaway_ms=200, saturation_ms=500, max_voltage=VS, Ts_us=5000):
    return [
        P.SetPlant(K, TAU, VS, 448),
        P.SetGains(*g, Ts_us, 0, 1, 0.0),
        P.SetLimits(2e4, 300.0, 100.0, max_voltage, 0, max_error, runaway_ms, saturation_ms),
    ]


def run_host(driver, commands, ms, encoder=1):
    """The firmware core (host build) on its exact ZOH motor: (messages, pwm changes)."""
    script = [f"rx {P.encode(m, (i + 1) % 256).hex()}" for i, m in enumerate(commands)]
    script += [f"ms {int(ms)}", "quit"]
    proc = subprocess.run(
        [str(driver), "device", str(K), str(TAU), str(VS), str(encoder)],
        input="\n".join(script) + "\n",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    msgs, pwm, dec = [], [], P.Decoder()
    for line in proc.stdout.splitlines():
        kind, t, val = line.split()
        if kind == "tx":
            msgs += [(int(t), f.seq, P.parse(f)) for f in dec.feed(bytes.fromhex(val))]
        else:
            pwm.append((int(t), int(val)))
    assert dec.stats.dropped == 0
    return msgs, pwm


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def run_virtual(commands, seconds, encoder=1, Ts=0.005):
    """The same commands to the virtual device (lock-step clock); its messages.

    The host driver (firmware/host/jl_host.cpp) applies each PWM at the sample instant, so the
    virtual device runs without its model of the board's computation delay here."""
    clock = _Clock()
    dev = VirtualDevice(clock=clock, compute_delay=0.0)
    dev.encoder_sign = encoder
    out = bytearray()
    for i, m in enumerate(commands):
        dev.receive(P.encode(m, (i + 1) % 256))
    for _ in range(int(round(seconds / Ts))):
        clock.t += Ts
        dev.tick()
        out += dev.read_output()
    out += dev.read_output()
    dec = P.Decoder()
    msgs = [(f.seq, P.parse(f)) for f in dec.feed(bytes(out))]
    assert dec.stats.dropped == 0
    return msgs, dev


def _split(msgs):
    tel = [m for m in msgs if isinstance(m, P.Telemetry)]
    end = [m for m in msgs if isinstance(m, P.EndOfRun)]
    return tel, end


def _check_stop(tel, end, reason):
    """One END_OF_RUN with ``reason``; the fault sample is the last telemetry, PWM 0, flagged."""
    assert len(end) == 1 and end[0].reason == reason, end
    last = tel[-1]
    assert last.index == end[0].samples - 1
    assert last.flags & P.TELEMETRY_FAULT and last.pwm == 0
    assert all(not t.flags & P.TELEMETRY_FAULT for t in tel[:-1])
    return last


@pytest.mark.parametrize(
    "encoder, wn, limits, reason",
    [
        (
            -1,
            20.0,
            dict(max_error=0.5, runaway_ms=200),
            P.EndReason.TRACKING_ERROR,
        ),  # reversed: error grows
        (
            -1,
            20.0,
            dict(max_error=0.0, runaway_ms=50),
            P.EndReason.RUNAWAY,
        ),  # reversed, no error limit
        (
            0,
            20.0,
            dict(max_error=0.5, runaway_ms=100),
            P.EndReason.NO_MOTION,
        ),  # disconnected, short move
        (
            1,
            20.0,
            dict(max_error=2e-3, runaway_ms=200),
            P.EndReason.TRACKING_ERROR,
        ),  # a limit tighter than the loop
        (
            1,
            60.0,
            dict(max_error=0.0, runaway_ms=0, saturation_ms=500),
            P.EndReason.SATURATION,
        ),  # |z| = 1.33
    ],
)
def test_safety_stops_agree_between_firmware_core_and_virtual_device(
    host_driver, encoder, wn, limits, reason
):
    distance = f32(6.0) if encoder != 0 else f32(0.3)
    cmds = _config(_gains(wn), **limits) + [P.Plan(distance, 0), P.Run(400, 1)]
    fw, pwm = run_host(host_driver, cmds, 4000, encoder=encoder)
    py, dev = run_virtual(cmds, 4.0, encoder=encoder)
    fw_tel, fw_end = _split([m for _, _, m in fw])
    py_tel, py_end = _split([m for _, m in py])
    _check_stop(fw_tel, fw_end, reason)
    _check_stop(py_tel, py_end, reason)
    # the same sample, the same counts (float32 core vs float64 model: at most one sample apart)
    assert abs(fw_end[0].samples - py_end[0].samples) <= 1, (fw_end, py_end)
    n = min(len(fw_tel), len(py_tel)) - 1
    assert (
        np.max(np.abs(np.array([t.counts for t in fw_tel[:n]]) - [t.counts for t in py_tel[:n]]))
        <= 1
    )
    # stopped in the fault sample itself: the PWM went to 0 at that sample's tick
    ms_end = next(ms for ms, _, m in fw if isinstance(m, P.EndOfRun))
    assert pwm[-1] == (ms_end, 0) and any(v != 0 for _, v in pwm[:-1])
    assert dev.pwm == 0 and not dev.active
    for tel, end in ((fw_tel, fw_end[0]), (py_tel, py_end[0])):
        e = np.array([t.reference - t.counts / CPR for t in tel])
        if reason == P.EndReason.TRACKING_ERROR:
            # independent: the first sample whose |reference - position| exceeds the limit
            lim = f32(limits["max_error"])
            assert abs(e[-1]) > lim * (1 - 1e-5) and np.all(np.abs(e[:-1]) <= lim * (1 + 1e-5))
            assert end.detail == pytest.approx(e[-1], rel=1e-4, abs=1e-5)
        elif reason == P.EndReason.SATURATION:
            # independent: the level of clamped samples (up 1, down 1, not below 0) reaches the window
            lv = 0
            for t in tel:
                lv = lv + 1 if t.flags & P.TELEMETRY_SATURATED else max(0, lv - 1)
            assert lv == math.ceil(limits["saturation_ms"] / 5.0) and end.detail == 0
            assert tel[-1].flags & P.TELEMETRY_SATURATED
        else:
            # the window before the stop: large drive of one sign, counts against it or none
            w = math.ceil(limits["runaway_ms"] / 5.0)
            drive = np.array([t.pwm for t in tel[-w - 1 : -1]])
            assert np.all(np.abs(drive) >= 512) and len(set(np.sign(drive))) == 1
            moved = np.sign(drive[0]) * (tel[-1].counts - tel[-w - 1].counts)
            assert end.detail == moved
            assert (moved < 0) if reason == P.EndReason.RUNAWAY else (moved == 0)


def test_wired_right_the_same_move_completes(host_driver):
    """The defaults do not trip on a good loop (no false alarm on a 5-turn move, 4.5 s)."""
    cmds = _config(_gains()) + [P.Plan(f32(10 * math.pi), 0), P.Run(100, 1)]
    fw, _ = run_host(host_driver, cmds, 5200)
    py, _ = run_virtual(cmds, 5.2)
    for msgs in ([m for _, _, m in fw], [m for _, m in py]):
        tel, end = _split(msgs)
        assert len(end) == 1 and end[0].reason == P.EndReason.DONE
        assert not any(t.flags & P.TELEMETRY_FAULT for t in tel)


def test_safety_limits_are_checked_and_named(host_driver):
    bad = [
        P.SetLimits(2e4, 300.0, 100.0, 12.0, 0, -0.1, 200),
        P.SetLimits(2e4, 300.0, 100.0, 12.0, 0, math.nan, 200),
    ]
    fw, _ = run_host(host_driver, bad, 1)
    py, _ = run_virtual(bad, 0.0)
    for msgs in ([m for _, _, m in fw], [m for _, m in py]):
        assert msgs == [P.Nack(P.MsgType.SET_LIMITS, P.ErrorCode.BAD_VALUE, 5)] * 2
    assert P.payload_field_name(P.MsgType.SET_LIMITS, 5) == "max_error"


# ----------------------------------------------------------------------------- the client


def _rig(tmp_path, encoder=1, **kw):
    dev = VirtualDevice()
    dev.encoder_sign = encoder
    return Rig(VirtualSerial(dev), "virtual", progress=False, recordings=tmp_path, **kw)


def test_client_names_a_reversed_encoder(tmp_path):
    rig = _rig(tmp_path, encoder=-1)
    with pytest.raises(RigRunError, match=r"fault: runaway — encoder reversed\?") as exc:
        rig.run_move(
            plan_sine_jerk(6.0, 2e4, 300.0, 100.0),
            pole_placement_pid(K, TAU, 20.0),
            max_error=0,
            runaway_time=0.05,
        )
    rec = exc.value.recording
    assert (
        rec.metadata["status"].startswith("fault: runaway")
        and rec.metadata["end_reason"] == "RUNAWAY"
    )
    assert rec.metadata["status"] == exc.value.status
    assert rec.flags[-1] & P.TELEMETRY_FAULT and rec.pwm[-1] == 0


def test_client_names_the_tracking_error(tmp_path):
    rig = _rig(tmp_path)
    with pytest.raises(RigRunError) as exc:
        rig.run_move(
            plan_sine_jerk(6.0, 2e4, 300.0, 100.0),
            pole_placement_pid(K, TAU, 20.0),
            max_error=0.002,
        )
    status = exc.value.status
    rec = exc.value.recording
    t = rec.index[-1] * 0.005
    err = abs(rec.reference[-1] - rec.position[-1])
    assert status == f"fault: tracking error {err:.4g} rad > limit 0.002 rad at t={t:.3f} s", status
    assert err > 0.002 and np.all(np.abs(rec.reference[:-1] - rec.position[:-1]) <= 0.002)
    assert rec.metadata["limits"]["max_error"] == 0.002


def test_unstable_design_is_refused_and_forced_runs_end_in_a_fault(tmp_path):
    """Issue 12: the eq.-13 gains at wn 60 (|z| = 1.33 at Ts 5 ms) returned "complete" after
    driving +-12 V. Now run_move refuses them; forced, the run ends in a fault."""
    g = pole_placement_pid(K, TAU, 60.0)
    r = max_pole_radius(K, TAU, g, Ts=0.005)
    assert r > 1.0 and not is_stable(K, TAU, g, Ts=0.005)
    rig = _rig(tmp_path)
    prof = plan_sine_jerk(10 * math.pi, 2e4, 300.0, 100.0)
    with pytest.raises(UnstableDesignError, match=rf"\|z\| = {r:.4g} >= 1 \(eq13 design, wn = 60"):
        rig.run_move(prof, g)
    with pytest.raises(RigRunError, match=r"fault: output saturated — unstable loop\?") as exc:
        rig.run_move(prof, g, force=True)
    rec = exc.value.recording
    assert rec.metadata["status"].startswith("fault: output saturated")
    # independent: the clamp flag was set in most of the samples before the stop
    assert (
        np.mean(rec.saturated) > 0.6
        and rec.pwm[-1] == 0
        and len(rec) < 0.5 * rec.metadata["plan"]["n_samples"]
    )
    # the z-domain design beyond its range (issue 12: wn >= 30 at Ts 11 ms) is refused as well
    dz = discrete_pole_placement_pid(K, TAU, 35.0, Ts=0.011)
    with pytest.raises(UnstableDesignError, match="z-domain design, wn = 35"):
        rig.run_move(prof, dz, Ts=0.011)
    # a stable design is not refused
    assert rig.run_move(prof, pole_placement_pid(K, TAU, 20.0)).metadata["status"] == "complete"


def test_closed_loop_poles_against_python_control():
    """Our helper vs python-control's feedback of the ZOH plant and B(z)."""
    import control as ct

    g = pole_placement_pid(K, TAU, 45.0).discretize(0.005)
    plant = ct.c2d(ct.tf([K], [TAU, 1.0, 0.0]), 0.005, method="zoh")
    loop = ct.feedback(g.tf() * plant, 1)
    want = np.sort_complex(ct.poles(loop))
    from jerklab.controller import closed_loop_poles

    got = np.sort_complex(closed_loop_poles(K, TAU, g))
    assert np.allclose(got, want, atol=1e-8)
    with pytest.raises(ValueError, match="Ts is required"):
        closed_loop_poles(K, TAU, pole_placement_pid(K, TAU, 20.0))
    with pytest.raises(TypeError, match="gains must be"):
        is_stable(K, TAU, "pid", 0.005)


# ----------------------------------------------------------------------------- virtual device ~ firmware


def test_virtual_device_expires_a_partial_frame_while_idle():
    """Issue 12: the virtual device only dropped a partial frame when the next byte came; the
    firmware drops it after 20 ms of silence and finds a frame inside it (test_firmware)."""
    link = VirtualSerial(VirtualDevice(), timeout=0.5)
    cut = P.encode(P.SetGains(1.0, 0.0, 0.0, 5000), 200)[:6]  # its length holds back...
    link.write(cut + P.encode(P.Hello(), 7))  # ...a complete HELLO
    t0 = time.monotonic()
    data = link.read(64)
    frames = P.Decoder().feed(data)
    assert [(f.type, f.seq) for f in frames] == [(P.MsgType.HELLO_REPLY, 7)]
    assert 0.02 <= time.monotonic() - t0 < 0.4
    assert link.device.rx_errors == 1  # the cut frame, counted


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals: Linux")
def test_served_device_expires_a_partial_frame_while_idle():
    import os

    from jerklab.rig.server import DeviceServer

    with DeviceServer(speed=1.0) as srv:
        path = srv.start_pty()
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        try:
            import tty

            tty.setraw(fd)
            cut = P.encode(P.SetGains(1.0, 0.0, 0.0, 5000), 200)[:6]
            os.write(fd, cut + P.encode(P.Hello(), 9))
            dec, frames, deadline = P.Decoder(), [], time.monotonic() + 2.0
            os.set_blocking(fd, False)
            while not frames and time.monotonic() < deadline:
                try:
                    frames += dec.feed(os.read(fd, 256))
                except BlockingIOError:
                    time.sleep(0.01)
            assert [(f.type, f.seq) for f in frames] == [(P.MsgType.HELLO_REPLY, 9)]
        finally:
            os.close(fd)


def test_plan_longer_than_the_limit_is_refused_by_both(host_driver):
    # 1e6 rad at 1e-3 rad/s: 1e9 s, 2e11 samples at 5 ms; the limit is 2e9 samples
    cmds = [P.SetGains(1.0, 0.0, 0.0, 5000), P.SetLimits(1e-3, 1e-3, 1e-3, 12.0, 0), P.Plan(1e6, 0)]
    fw, _ = run_host(host_driver, cmds, 1)
    py, _ = run_virtual(cmds, 0.0)
    for msgs in ([m for _, _, m in fw], [m for _, m in py]):
        assert msgs[-1] == P.Nack(P.MsgType.PLAN, P.ErrorCode.TOO_LONG, 0)
    rig = Rig(VirtualSerial(VirtualDevice()), "virtual", progress=False)
    prof = plan_sine_jerk(1e6, 1e-3, 1e-3, 1e-3)
    with pytest.raises(
        RigCommandError, match=r"more than 2,000,000,000 samples \(the device's limit\)"
    ):
        rig.run_move(prof, pole_placement_pid(K, TAU, 20.0), path=False)


def test_virtual_device_memory_does_not_grow_with_the_plan():
    """Issue 12: the reference was sampled for the whole plan at RUN (3e7 samples took 6 GB).
    A plan of 4e6 samples now runs in a bounded amount of memory."""
    dev = VirtualDevice(clock=_Clock())
    for i, m in enumerate(
        [
            P.SetGains(1.0, 0.0, 0.0, 1000),
            P.SetLimits(1e3, 10.0, 0.5, 12.0, 0, 0.0, 0),
            P.Plan(2000.0, 0),
        ]
    ):
        dev.receive(P.encode(m, i))
    info = P.parse(P.Decoder().feed(dev.read_output())[-1])
    assert info.n_samples > 4_000_000
    tracemalloc.start()
    try:
        dev.receive(P.encode(P.Run(0, 1), 9))
        for _ in range(2000):
            dev.tick()
        dev.read_output()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert dev.active and peak < 2_000_000, peak


# ----------------------------------------------------------------------------- the served rig


def _read_all(sock_or_fd, seconds, dec):
    frames, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            data = sock_or_fd.recv(65536)
            if not data:
                break
            frames += dec.feed(data)
        except (BlockingIOError, socket.timeout):
            time.sleep(0.01)
    return frames


def test_second_tcp_client_is_told_the_rig_is_busy(tmp_path):
    from jerklab.rig import connect
    from jerklab.rig.server import DeviceServer

    with DeviceServer(speed=None) as srv:
        url = srv.start_tcp()
        first = connect(url, progress=False, recordings=tmp_path)
        try:
            t0 = time.monotonic()
            with pytest.raises(RigBusyError, match="rig busy: already in use by another client"):
                connect(url, progress=False, recordings=tmp_path)
            assert time.monotonic() - t0 < 2.0
            # the first client was not disturbed
            rec = first.run_move(
                plan_sine_jerk(2.0, 2e4, 300.0, 100.0),
                pole_placement_pid(K, TAU, 20.0),
                settle=0.05,
            )
            assert rec.metadata["status"] == "complete"
        finally:
            first.close()
        assert srv.refused_clients == 1
        # once the first has gone, the next client is served
        with connect(url, progress=False, recordings=tmp_path) as again:
            assert again.name == "jerklab-virtual"


def test_a_client_that_disconnects_stops_its_run():
    from jerklab.rig.server import DeviceServer

    with DeviceServer(speed=1.0) as srv:
        url = srv.start_tcp()
        host, port = url[len("socket://") :].rsplit(":", 1)
        a = socket.create_connection((host, int(port)))
        cmds = [
            P.SetGains(10.0, 0.1, 50.0, 5000),
            P.SetLimits(2e4, 300.0, 100.0, 12.0, 0),
            P.Plan(50.0, 0),
            P.Run(0, 1),
        ]
        a.sendall(b"".join(P.encode(m, i + 1) for i, m in enumerate(cmds)))
        a.settimeout(0.05)
        got = _read_all(a, 0.3, P.Decoder())
        assert any(f.type == P.MsgType.TELEMETRY for f in got) and srv.device.active
        a.close()  # host_timeout 0: no watchdog to help
        deadline = time.monotonic() + 2.0
        while srv.device.active and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not srv.device.active and srv.device.pwm == 0
        b = socket.create_connection((host, int(port)))
        b.settimeout(0.05)
        b.sendall(P.encode(P.Hello(), 1))
        got = _read_all(b, 0.4, P.Decoder())
        b.close()
        assert [f.type for f in got] == [P.MsgType.HELLO_REPLY]  # nothing of the old run


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pseudo-terminals: Linux")
def test_a_host_that_stalls_loses_whole_frames_counted(tmp_path, monkeypatch):
    """Issue 12: a host that stalled lost telemetry silently (bytes cut from the front of the
    buffer). Now whole TELEMETRY frames are dropped, counted by the server, seen by the client
    as a gap, written to the recording and warned about; END_OF_RUN still arrives."""
    from jerklab.rig import connect
    from jerklab.rig import server as S

    monkeypatch.setattr(S, "_OUT_LIMIT", 2000)
    with S.DeviceServer(speed=1.0) as srv:
        rig = connect(srv.start_pty(), progress=False, recordings=tmp_path)
        try:
            orig = rig._read_frames
            state = {"t0": None, "stalled": False}

            def stalling(wait):
                frames = orig(wait)
                if any(f.type == P.MsgType.TELEMETRY for f in frames) and state["t0"] is None:
                    state["t0"] = time.monotonic()
                if (
                    state["t0"] is not None
                    and not state["stalled"]
                    and time.monotonic() - state["t0"] > 0.2
                ):
                    # the host stalls until the server had to drop frames (the kernel's pty buffer
                    # and the server's 2 kB are full: ~1 s of telemetry), however slow the machine
                    state["stalled"] = True
                    deadline = time.monotonic() + 20.0
                    while (
                        srv.dropped_frames == 0
                        and srv.device.active
                        and time.monotonic() < deadline
                    ):
                        time.sleep(0.01)
                    time.sleep(0.2)
                return frames

            rig._read_frames = stalling
            with pytest.warns(RuntimeWarning, match=r"\d+ telemetry samples were lost"):
                rec = rig.run_move(
                    plan_sine_jerk(20.0, 2e4, 300.0, 100.0),
                    pole_placement_pid(K, TAU, 20.0),
                    Ts=0.001,
                    settle=0.05,
                    host_timeout=0,
                )  # 2.9 s, 64 kB of telemetry
        finally:
            rig.close()
    md = rec.metadata
    assert md["status"] == "complete" and md["host_dropped_frames"] == 0
    assert srv.dropped_frames > 0 and md["lost_samples"] == srv.dropped_frames
    assert len(rec) + md["lost_samples"] == md["device_samples"]


# ----------------------------------------------------------------------------- sequence-number wrap


def _long_session():
    """600 commands: the seq byte wraps twice (1..255, 0, 1, ...)."""
    cmds = []
    for i in range(600):
        cmds.append(
            [
                P.Hello(),
                P.Heartbeat(),
                P.SetPlant(K, TAU, VS, 448),
                P.SetLimits(2e4, 300.0, 100.0, 12.0, 0),
                P.Stop(),
            ][i % 5]
        )
    return cmds


def test_session_longer_than_256_commands_firmware_core(host_driver):
    cmds = _long_session()
    fw, _ = run_host(host_driver, cmds, 1)
    assert [seq for _, seq, _ in fw] == [(i + 1) % 256 for i in range(len(cmds))]
    assert all(not isinstance(m, P.Nack) for _, _, m in fw)


def test_session_longer_than_256_commands_virtual_device_and_client():
    cmds = _long_session()
    py, _ = run_virtual(cmds, 0.0)
    assert [seq for seq, _ in py] == [(i + 1) % 256 for i in range(len(cmds))]
    assert all(not isinstance(m, P.Nack) for _, m in py)
    # the client's counter wraps too and still pairs every reply with its command
    rig = Rig(VirtualSerial(VirtualDevice()), "virtual", progress=False)
    for _ in range(300):
        assert rig.hello().name == "jerklab-virtual"
    assert rig._seq == 302 % 256 and rig.ignored_frames == 0


# ----------------------------------------------------------------------------- the rule, restated


def _expected_stop(tel, limits, Ts_us=5000, max_voltage=VS):
    """PROTOCOL.md "Safety stops" restated from a run's telemetry (decimation 1): the sample and
    reason of the first stop, or (None, None)."""
    pwm_top = min(1023, math.floor(max_voltage * 1023 / VS + 0.5))
    thr = (pwm_top + 1) // 2
    n_run = -(-limits["runaway_ms"] * 1000 // Ts_us)
    n_sat = -(-limits["saturation_ms"] * 1000 // Ts_us)
    lim = f32(limits["max_error"])
    sign_run = length = moved = level = 0
    for k, t in enumerate(tel):
        e = t.reference - t.counts / CPR
        if lim > 0 and abs(e) > lim:
            return k, P.EndReason.TRACKING_ERROR
        last = tel[k - 1].pwm if k else 0
        s = 1 if last >= thr else (-1 if last <= -thr else 0)
        if n_run and s == 0:
            sign_run = length = moved = 0
        elif n_run:
            if s != sign_run:
                sign_run, length, moved = s, 0, 0
            moved += s * (t.counts - (tel[k - 1].counts if k else 0))
            length += 1
            if length >= n_run:
                if moved <= 0:
                    return k, P.EndReason.RUNAWAY if moved < 0 else P.EndReason.NO_MOTION
                length = moved = 0
        level = level + 1 if t.flags & P.TELEMETRY_SATURATED else max(0, level - 1)
        if n_sat and level >= n_sat:
            return k, P.EndReason.SATURATION
    return None, None


@settings(max_examples=40, deadline=None)
@given(
    distance=st.floats(0.2, 12.0),
    sign=st.sampled_from([1.0, -1.0]),
    encoder=st.sampled_from([1, -1, 0]),
    wn=st.sampled_from([10.0, 20.0, 60.0]),
    max_error=st.sampled_from([0.0, 0.01, 0.1, 0.5, 2.0]),
    runaway_ms=st.sampled_from([0, 20, 100, 300]),
    saturation_ms=st.sampled_from([0, 50, 500]),
    max_voltage=st.sampled_from([3.0, 12.0]),
)
def test_virtual_device_stops_where_the_rule_says(
    distance, sign, encoder, wn, max_error, runaway_ms, saturation_ms, max_voltage
):
    limits = dict(max_error=max_error, runaway_ms=runaway_ms, saturation_ms=saturation_ms)
    cmds = [
        P.SetPlant(K, TAU, VS, 448),
        P.SetGains(*_gains(wn)[:3], 5000, 0, 1, 0.0),
        P.SetLimits(2e4, 300.0, 100.0, max_voltage, 0, **limits),
        P.Plan(f32(sign * distance), 0),
        P.Run(100, 1),
    ]
    msgs, dev = run_virtual(cmds, 6.0, encoder=encoder)
    tel, end = _split([m for _, m in msgs])
    assert len(end) == 1 and not dev.active and dev.pwm == 0
    k, reason = _expected_stop(tel, limits, max_voltage=max_voltage)
    if reason is None:
        assert end[0].reason == P.EndReason.DONE
        assert not any(t.flags & P.TELEMETRY_FAULT for t in tel)
    else:
        assert (end[0].reason, end[0].samples) == (reason, k + 1)
        _check_stop(tel, end, reason)


def test_a_version_1_device_is_refused_by_name():
    """Protocol 2 changed SET_LIMITS and END_OF_RUN: a host must not drive a version-1 firmware
    (its SET_LIMITS would be NACKed BAD_LENGTH, its END_OF_RUN unreadable)."""
    import dataclasses

    from jerklab.rig import RigError

    class Version1(VirtualDevice):
        def _send(self, msg, seq=None):
            if isinstance(msg, P.HelloReply):
                msg = dataclasses.replace(msg, protocol_version=1)
            super()._send(msg, seq)

    with pytest.raises(
        RigError, match=f"device speaks protocol version 1, jerklab speaks {P.PROTOCOL_VERSION}"
    ):
        Rig(VirtualSerial(Version1()), "old-uno", progress=False)
