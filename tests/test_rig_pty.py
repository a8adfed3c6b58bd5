"""The virtual rig over real links: a pseudo-terminal opened by pyserial, a TCP socket,
the `python -m jerklab.rig serve` command, and failures (pulled cable, hung board, silent host)."""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import serial

from jerklab import protocol as P
from jerklab.controller import pole_placement_pid
from jerklab.planner import plan_sine_jerk
from jerklab.rig import Link, Recording, RigConnectionError, RigTimeoutError, connect
from jerklab.rig.server import DeviceServer

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="pseudo-terminals: Linux"
)

K, TAU = 32.4, 0.025
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _move():
    return plan_sine_jerk(10 * math.pi, 2e4, 300.0, 100.0)


def _gains():
    return pole_placement_pid(K, TAU, wn=20.0)


@pytest.fixture
def served(tmp_path):
    """Start `python -m jerklab.rig serve` in a subprocess; yield the pty path it prints."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen(
        [sys.executable, "-m", "jerklab.rig", "serve", "--speed", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/pts/"), (
            path,
            proc.stderr.read() if proc.poll() is not None else "",
        )
        yield path
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert proc.returncode == 0, proc.stderr.read()


def test_serve_subprocess_through_pyserial(served, tmp_path):
    """A plain pyserial client speaks the protocol to the served rig, then the rig client runs a
    move whose recording equals the in-process virtual rig's, sample for sample."""
    with serial.Serial(served, 115200, timeout=2.0) as s:
        s.write(P.encode(P.Hello(), seq=77))
        dec = P.Decoder()
        frames = []
        deadline = time.monotonic() + 5.0
        while not frames and time.monotonic() < deadline:
            frames = dec.feed(s.read(s.in_waiting or 1))
        reply = P.parse(frames[0])
        assert (
            frames[0].seq == 77
            and isinstance(reply, P.HelloReply)
            and reply.name == "jerklab-virtual"
        )
    with connect(
        served, recordings=tmp_path / "pty", progress=False, link=Link(timeout=10.0)
    ) as rig:
        assert rig.port == served and rig.is_virtual
        rec = rig.run_move(_move(), _gains(), Ts=0.005, settle=0.1)
    with connect(recordings=tmp_path / "inproc", progress=False) as rig:
        ref = rig.run_move(_move(), _gains(), Ts=0.005, settle=0.1)
    assert rec.metadata["status"] == "complete" and len(rec) == len(ref)
    np.testing.assert_array_equal(rec.counts, ref.counts)
    np.testing.assert_array_equal(rec.pwm, ref.pwm)
    assert Recording.load(rec.csv_path).metadata["device"]["port"] == served


def test_tcp_socket_url(tmp_path):
    with DeviceServer(speed=None) as srv:
        url = srv.start_tcp()
        assert url.startswith("socket://127.0.0.1:")
        with connect(url, recordings=tmp_path, progress=False) as rig:
            rec = rig.step(3.0, 0.2, rest=0.0)
        assert len(rec) == 40 and rec.metadata["device"]["port"] == url
        # the server accepts the next client after the first hung up
        with connect(url, recordings=tmp_path, progress=False) as rig:
            assert len(rig.step(3.0, 0.05)) == 20
            # each frame leaves at once (pyserial's socket keeps Nagle's algorithm on): a host
            # loop's answer must not wait for the board's delayed ACK
            sock = rig.link._socket
            assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0


def _pull_when(srv, n_bytes, done):
    while srv.sent_bytes < n_bytes and not done.is_set():
        time.sleep(0.002)
    srv.pull_cable()


def test_cable_pulled_mid_run_keeps_the_data(tmp_path):
    srv = DeviceServer(speed=4.0)
    path = srv.start_pty()
    rig = connect(path, recordings=tmp_path, progress=False)
    done = threading.Event()
    puller = threading.Thread(target=_pull_when, args=(srv, 200 * 22, done))
    puller.start()
    try:
        with pytest.raises(RigConnectionError, match=r"connection lost .* saved in") as ei:
            rig.run_move(_move(), _gains(), Ts=0.005)
    finally:
        done.set()
        puller.join()
        rig.close()
        srv.close()
    files = sorted(tmp_path.glob("*_move.csv"))
    assert len(files) == 1 and str(files[0]) in str(ei.value)
    rec = Recording.load(files[0])
    assert rec.metadata["status"] == "disconnected"
    # every sample that arrived is on disk, in order, and is the start of the full run; the
    # cable went at ~200 frames sent (the puller polls every 2 ms), and what was still in the
    # pty's buffer then is lost, as on a real pull (a loaded machine reads later: fewer arrive)
    assert 0 < len(rec) < 950 and len(rec) <= srv.sent_bytes // 22
    assert np.array_equal(rec.index, np.arange(len(rec)))
    with connect(recordings=tmp_path / "ref", progress=False) as ref_rig:
        ref = ref_rig.run_move(_move(), _gains(), Ts=0.005)
    np.testing.assert_array_equal(rec.counts, ref.counts[: len(rec)])


def test_hung_board_times_out_with_the_data(tmp_path):
    srv = DeviceServer(speed=None)
    path = srv.start_pty()
    rig = connect(path, recordings=tmp_path, progress=False, link=Link(timeout=0.5))
    done = threading.Event()

    def freeze():
        while srv.sent_bytes < 100 * 22 and not done.is_set():
            time.sleep(0.001)
        srv.freeze()

    th = threading.Thread(target=freeze)
    th.start()
    t0 = time.monotonic()
    try:
        with pytest.raises(RigTimeoutError, match="no data from the rig for 0.5 s"):
            rig.step(6.0, 2.0)
    finally:
        done.set()
        th.join()
        rig.close()
        srv.close()
    assert time.monotonic() - t0 < 5.0
    rec = Recording.load(sorted(tmp_path.glob("*_step.csv"))[-1])
    assert rec.metadata["status"] == "timeout" and len(rec) >= 50


def test_device_watchdog_stops_a_silent_host():
    """A host that starts a run and falls silent: the rig stops the motor by itself."""
    with DeviceServer(speed=1.0) as srv:
        path = srv.start_pty()
        with serial.Serial(path, 115200, timeout=0.05) as s:
            for i, m in enumerate(
                [
                    P.SetGains(10.0, 0.1, 50.0, 5000),
                    P.SetLimits(2e4, 300.0, 100.0, 12.0, 150),
                    P.Plan(100.0, 0),
                    P.Run(0, 1),
                ]
            ):
                s.write(P.encode(m, i))
            dec, msgs = P.Decoder(), []
            t0 = time.monotonic()
            while time.monotonic() - t0 < 3.0:
                msgs += [P.parse(f) for f in dec.feed(s.read(s.in_waiting or 1))]
                if msgs and isinstance(msgs[-1], P.EndOfRun):
                    break
        elapsed = time.monotonic() - t0
    end = msgs[-1]
    assert isinstance(end, P.EndOfRun) and end.reason == P.EndReason.HOST_TIMEOUT
    assert 0.1 < elapsed < 1.5  # ~150 ms of silence, not the whole move
    assert 5 <= end.samples <= 80  # ~30 samples of 5 ms (fewer on a loaded CPU)
    assert srv.device.pwm == 0 and not srv.device.active
